"""The package version, in a module of its own so that the package and :mod:`.numba_cache` both import it."""

__version__ = "0.1.0"
