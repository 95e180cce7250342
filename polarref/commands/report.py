"""``polarref report DIR``: rebuild report.md, report.html and figures from DIR/metrics.json."""

from __future__ import annotations

import argparse
from pathlib import Path

from polarref.errors import PolarrefError

NAME = "report"
HELP = "rebuild report.md/report.html and figures of a compare run from its metrics.json (no recomputation)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", type=Path, metavar="DIR", help="a report folder written by polarref compare")


def run(args: argparse.Namespace) -> int:
    from polarref.compare.report import build_report

    if not args.dir.is_dir():
        raise PolarrefError(f"report folder not found: {args.dir}")
    if not (args.dir / "metrics.json").is_file():
        raise PolarrefError(f"no metrics.json in {args.dir} (run polarref compare first)")
    written = build_report(args.dir)
    print(f"wrote {written['markdown']} and {written['html']} ({sum(k.startswith('figure:') for k in written)} figures)")
    return 0
