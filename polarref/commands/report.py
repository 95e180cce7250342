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
    from polarref.compare.report.build import build_report

    if args.index:
        from polarref.compare.report.index import build_index

        for d in args.dirs:
            written = build_index(d)
            print(f"wrote {written.html} and {written.markdown}")
        return 0
    loaded = []
    for d in args.dirs:  # every input checked before any report is written
        if not d.is_dir():
            raise PolarrefError(f"report folder not found: {d}")
        if not (d / "metrics.json").is_file():
            raise PolarrefError(f"no metrics.json in {d} (run polarref compare first)")
        loaded.append(_load_checked(d / "metrics.json"))
    for d, metrics in zip(args.dirs, loaded):
        written = build_report(d, metrics)
        print(f"wrote {written.markdown} and {written.html} ({len(written.figures)} figures)")
        if args.screenshot:
            from polarref.compare.report.browser import screenshot

            check = screenshot(written.html, d / "screenshot.png")
            for problem in check.console_errors + [f"network request: {u}" for u in check.network_requests]:
                log.warning("%s: %s", written.html, problem)
            print(f"wrote {d / 'screenshot.png'}")
    return 0


def _load_checked(path: Path):
    """The metrics file, read strictly (unknown status refused there) and checked for figures no
    run can produce (a negative count, more images registered than the scene has)."""
    from polarref.compare.schema import load

    try:
        metrics = load(path)
    except PolarrefError as exc:
        text = str(exc)
        raise PolarrefError(text if str(path) in text else f"{path}: {text.removeprefix('metrics.json: ')}") from exc
    for i, m in enumerate(metrics.methods):
        problem = _impossible(m)
        if problem:
            raise PolarrefError(f"{path}: methods[{i}] ({m.name}): {problem}; the file was edited or "
                                "corrupted (rerun polarref compare)")
    return metrics


def _impossible(m) -> str | None:
    if m.runtime_s is not None and m.runtime_s < 0:
        return f"runtime_s {m.runtime_s} < 0"
    if m.num_images < 0:
        return f"num_images {m.num_images} < 0"
    r = m.metrics
    if r is None:
        return None
    for name in ("num_images", "registered_images", "tie_points", "reprojected_px"):
        if getattr(r, name) < 0:
            return f"{name} {getattr(r, name)} < 0"
    if r.registered_images > r.num_images:
        return f"registered_images {r.registered_images} > num_images {r.num_images}"
    for name in ("mean_reprojection_error_px", "mean_reprojection_error_px_per_point",
                 "median_reprojection_error_px", "mean_track_length"):
        value = getattr(r, name)
        if value is not None and value < 0:
            return f"{name} {value} < 0"
    return None
