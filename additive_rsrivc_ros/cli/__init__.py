"""Command-line programs (console scripts listed in ../shared/CONTRACT.md)."""
