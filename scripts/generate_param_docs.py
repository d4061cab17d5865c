#!/usr/bin/env python3
"""Regenerate config/template.yaml and the README's parameter table from the parameter table (config.py and
core/params.py), or with --check only report whether they are up to date (exit 1 if not).

    python scripts/generate_param_docs.py [--check]

The template's leading comment block and the README outside its parameter-table markers are kept as written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from additive_rsrivc_ros.config import README_PATH, TEMPLATE_PATH, readme_with_table, render_template, template_header

ROOT = Path(__file__).resolve().parents[1]


def generated() -> dict[Path, str]:
    """``{path: regenerated text}`` of the two generated files of the source tree."""
    template, readme = ROOT / TEMPLATE_PATH, ROOT / README_PATH
    return {template: render_template(template_header(template.read_text())),
            readme: readme_with_table(readme.read_text())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only report drift (exit 1), write nothing")
    args = ap.parse_args(argv)
    stale = [path for path, text in generated().items() if path.read_text() != text]
    for path, text in generated().items():
        if path in stale and not args.check:
            path.write_text(text)
    for path in stale:
        print(f"{path.relative_to(ROOT)}: {'out of date' if args.check else 'regenerated'}")
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
