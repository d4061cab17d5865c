"""Command-line programs (console scripts listed in docs/INTERFACE.md)."""
