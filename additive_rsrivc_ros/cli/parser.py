"""The command-line tools' argument parser: a usage error is one line on stderr and exit status 2."""

from __future__ import annotations

import argparse
import sys


class OneLineParser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` whose errors print ``<prog>: error: <message>`` without the usage dump."""

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)
