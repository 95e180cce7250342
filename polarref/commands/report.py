"""``polarref report``: rebuild report.md, report.html and figures from DIR/metrics.json; an index; screenshots."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from polarref.core.errors import PolarrefError

NAME = "report"
HELP = ("rebuild report.md/report.html and figures of compare runs from their metrics.json (no recomputation); "
        "--index: a page over several report folders; --screenshot: screenshot.png of each report's top")

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dirs", type=Path, nargs="+", metavar="DIR",
                        help="report folder(s) written by polarref compare (with --index: the parent folder)")
    parser.add_argument("--index", action="store_true",
                        help="write DIR/index.html and index.md over every DIR/*/metrics.json (reports not rebuilt)")
    parser.add_argument("--screenshot", action="store_true",
                        help="also write DIR/screenshot.png: the top 1280x800 of report.html in headless Chromium")


def run(args: argparse.Namespace) -> int:
    from polarref.compare.report import build_report

    if args.index:
        from polarref.compare.index import build_index

        for d in args.dirs:
            written = build_index(d)
            print(f"wrote {written.html} and {written.markdown}")
        return 0
    for d in args.dirs:
        if not d.is_dir():
            raise PolarrefError(f"report folder not found: {d}")
        if not (d / "metrics.json").is_file():
            raise PolarrefError(f"no metrics.json in {d} (run polarref compare first)")
    for d in args.dirs:
        written = build_report(d)
        print(f"wrote {written.markdown} and {written.html} ({len(written.figures)} figures)")
        if args.screenshot:
            from polarref.compare.browser import screenshot

            check = screenshot(written.html, d / "screenshot.png")
            for problem in check.console_errors + [f"network request: {u}" for u in check.network_requests]:
                log.warning("%s: %s", written.html, problem)
            print(f"wrote {d / 'screenshot.png'}")
    return 0
