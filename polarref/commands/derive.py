"""``polarref derive``: regenerate ``polarref/_generated/`` from the SymPy derivations.

Generation runs in a child process with ``PYTHONHASHSEED=0`` so the emitted text is byte-for-
byte reproducible. ``--check`` regenerates into a temporary folder and fails with a unified
diff if the committed modules differ. Without ``--check`` it also writes
``reports/derivations.md`` (+ ``.json``) with the verdicts on the paper's Eq. 3-10; the report
is not part of ``--check`` because its numeric evidence depends on the platform's libm.
"""

from __future__ import annotations

import argparse
import difflib
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import polarref
from polarref.core.atomic import atomic_write, check_writable_parent
from polarref.core.errors import PolarrefError

NAME = "derive"
HELP = "regenerate polarref/_generated from derivations/ (SymPy) and write reports/derivations.md"

log = logging.getLogger(__name__)

PACKAGE_DIR = Path(polarref.__file__).resolve().parent
GENERATED_DIR = PACKAGE_DIR / "_generated"
DEFAULT_REPORT = PACKAGE_DIR.parent / "reports" / "derivations.md"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--check", action="store_true",
                        help="regenerate into a temporary folder; exit 1 with a diff if --out differs")
    parser.add_argument("--out", type=Path, default=GENERATED_DIR,
                        help=f"folder of the generated modules (default: {GENERATED_DIR})")
    parser.add_argument("--report", type=Path, default=DEFAULT_REPORT,
                        help=f"report path (default: {DEFAULT_REPORT}); a .json beside it holds the data")
    parser.add_argument("--no-report", action="store_true", help="only regenerate the modules")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace existing generated files or report that differ from the new ones")


def generate_into(folder: Path) -> float:
    """Run the generator in a child process; return its wall time in seconds."""
    env = dict(os.environ, PYTHONHASHSEED="0")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE_DIR.parent), env.get("PYTHONPATH")]))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "derivations.generate", str(folder)],
                          env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise PolarrefError(f"derivations.generate failed (exit {proc.returncode}): {proc.stderr.strip()}")
    return time.perf_counter() - t0


def diff_folders(expected: Path, actual: Path) -> str:
    """Unified diff of the *.py files of two folders ('' when identical)."""
    names = sorted({p.name for p in expected.glob("*.py")} | {p.name for p in actual.glob("*.py")})
    chunks: list[str] = []
    for name in names:
        new = (expected / name).read_text().splitlines(keepends=True) if (expected / name).exists() else []
        old = (actual / name).read_text().splitlines(keepends=True) if (actual / name).exists() else []
        chunks += difflib.unified_diff(old, new, fromfile=f"committed/{name}", tofile=f"regenerated/{name}")
    return "".join(chunks)


def _write_if_changed(target: Path, text: str, overwrite: bool) -> bool:
    if target.exists():
        if target.read_text() == text:
            return False
        if not overwrite:
            raise PolarrefError(f"{target} exists and differs from the regenerated text",
                                option="overwrite")
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(target, text)
    return True


def run(args: argparse.Namespace) -> int:
    # Output paths are checked before the (slow) generation, not after it.
    if args.out.exists() and not args.out.is_dir():
        raise PolarrefError(f"{args.out} is not a folder (choose another output folder)")
    if not args.check:
        check_writable_parent(args.out / "x.py")
        if not args.no_report:
            if args.report.is_dir():
                raise PolarrefError(f"{args.report} is a folder; the report path names a file")
            check_writable_parent(args.report)
    with tempfile.TemporaryDirectory(prefix="polarref-derive-") as tmp:
        fresh = Path(tmp)
        seconds = generate_into(fresh)
        log.info("generated %d modules in %.1f s", len(list(fresh.glob("*.py"))), seconds)
        if args.check:
            diff = diff_folders(fresh, args.out)
            if diff:
                sys.stdout.write(diff)
                print(f"polarref derive --check: {args.out} is out of date; run `polarref derive --overwrite`",
                      file=sys.stderr)
                return 1
            print(f"{args.out}: up to date (regenerated in {seconds:.1f} s)")
            return 0
        changed = [p.name for p in sorted(fresh.glob("*.py"))
                   if _write_if_changed(args.out / p.name, p.read_text(), args.overwrite)]
    print(f"generated modules in {seconds:.1f} s; changed: {', '.join(changed) or 'none'}")
    if args.no_report:
        return 0
    from derivations import report  # SymPy import only when actually deriving

    t0 = time.perf_counter()
    ev = report.collect()
    changed_json = _write_if_changed(args.report.with_suffix(".json"), report.to_json(ev), args.overwrite)
    changed_md = _write_if_changed(args.report, report.render(ev), args.overwrite)
    state = "wrote" if changed_json or changed_md else "up to date:"
    print(f"{state} {args.report} (evidence in {time.perf_counter() - t0:.1f} s)")
    return 0
