"""``polarref compare``: our SfM (each BA form) vs pycolmap on the same images, with a report."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from polarref.commands._types import SEED, float_range, positive_float
from polarref.compare.run import presets
from polarref.core.errors import PolarrefError, UsageError
from polarref.core.status import RunStatus

NAME = "compare"
HELP = ("run our SfM (euclidean/parallax/polar/angular BA) and pycolmap (incremental, global; its "
        "SIFT and ours) on one scene and write report.md/report.html/metrics.json")

log = logging.getLogger(__name__)


def _budget(text: str) -> float:
    # -1 (the default) means "by preset"; any other negative is a typo
    return -1.0 if text.strip() in ("-1", "-1.0") else float_range(0.0)(text)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from polarref.compare.run.methods import METHOD_NAMES

    parser.add_argument("scene", nargs="?", default=None, metavar="SCENE|DIR",
                        help="comet (default), uav, a rendered scene folder, or an image set with ground "
                             "truth (images/ + gt/ COLMAP model or Strecha gt_dense_cameras/); or a twin of "
                             "the paper's datasets, rosetta, poets-park or mappilot (Tables 1-3: resumable "
                             "stages, paper-table.md; --preset, --budget, --no-claims, --dense do not apply)")
    parser.add_argument("--preset", default=presets.DEFAULT.name, choices=presets.NAMES,
                        help="synthetic scene size, real-image downscaling, time limits (default: "
                             f"{presets.DEFAULT.name})")
    parser.add_argument("--out", type=Path, default=None,
                        help="report folder (default: ./polarref-out/<scene>-<preset>); a finished one "
                             "(metrics.json) is refused without --overwrite, and updated, never wiped, with it")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results in a finished report folder (other files are kept)")
    parser.add_argument("--methods", nargs="+", default=None, metavar="METHOD", choices=METHOD_NAMES,
                        help="subset of methods (default: all): " + ", ".join(METHOD_NAMES))
    parser.add_argument("--seed", type=SEED, default=0, help="render seed and every method/experiment seed")
    parser.add_argument("--method-timeout", type=positive_float, default=None, metavar="S",
                        help="wall-clock limit per method in seconds (default by preset: "
                             + ", ".join(f"{p.name} {p.method_timeout_s:g}" for p in presets.PRESETS.values())
                             + "); a method over it is reported as timed out")
    parser.add_argument("--budget", type=_budget, default=-1.0, metavar="S",
                        help="whole-run time limit in seconds, rendering included (default by preset: "
                             + ", ".join(f"{p.name} {'none' if p.run_budget_s is None else f'{p.run_budget_s:g}'}"
                                         for p in presets.PRESETS.values())
                             + "; 0 = none); later methods get shorter limits")
    parser.add_argument("--no-claims", action="store_true", help="skip the claim experiments")
    parser.add_argument("--tables", type=Path, default=None, metavar="DIR",
                        help="twins only: also write DIR/<twin>/paper-table.md/.json and DIR/README.md "
                             "(e.g. reports/paper-tables; the run folder keeps models and caches)")
    parser.add_argument("--dense", action="store_true",
                        help="also run polarref dense from the GT, ours-euclidean and ours-polar poses "
                             "(after the budgeted run; adds a dense section and figure to the report)")


def _run_twin(args: argparse.Namespace) -> int:
    """A twin of the paper's datasets: resumable stages and the paper-layout table."""
    from polarref.compare.twins import tables as PT
    from polarref.compare.twins.pipeline import DEFAULT_TIMEOUT_S, TwinRun, run_twin

    from polarref.core.atomic import check_writable_parent

    out = args.out or Path("polarref-out") / args.scene
    check_writable_parent(out / "paper-table.json")
    wanted = tuple(m for m in (args.methods or PT.METHODS) if m in PT.METHODS)
    if not wanted:
        raise PolarrefError(f"a twin comparison runs {', '.join(PT.METHODS)}; none of them was selected")
    if args.overwrite and (out / "stages").is_dir():
        for f in (out / "stages").glob("*.json"):
            f.unlink()  # every stage runs again; models are replaced by the new runs
    out.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(out / "compare.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.getLogger("polarref").addHandler(handler)
    logging.getLogger("polarref").setLevel(min(logging.getLogger("polarref").getEffectiveLevel(), logging.INFO))
    try:
        table = run_twin(TwinRun(args.scene, str(out), seed=args.seed, methods=wanted,
                                 method_timeout_s=args.method_timeout or DEFAULT_TIMEOUT_S,
                                 tables_dir=str(args.tables or "")))
    finally:
        logging.getLogger("polarref").removeHandler(handler)
        handler.close()
    for name, m in table.methods.items():
        extra = f" ({m.reason})" if m.reason else ""
        print(f"  {name}: {m.status}{extra}")
    print(f"paper table: {out / 'paper-table.md'} (log: {out / 'compare.log'})")
    if table.methods and not any(m.status == RunStatus.OK for m in table.methods.values()):
        raise PolarrefError(f"{out}: every method failed ({len(table.methods)} of {len(table.methods)}); "
                            "the paper table names each failure")
    return 0


def _check_twin_options(args: argparse.Namespace, twin: bool) -> None:
    """Options of the other kind of run are refused, not ignored (a twin renders hundreds of
    views: ``--preset small --budget 5`` must not start that silently)."""
    if twin:
        given = [flag for flag, on in (("--preset", args.preset != presets.DEFAULT.name), ("--budget", args.budget != -1.0),
                                       ("--no-claims", args.no_claims), ("--dense", args.dense)) if on]
        if given:
            raise UsageError(f"{', '.join(given)} do(es) not apply to the twin {args.scene} (its views, size and "
                             "stages are fixed); drop them or compare a scene")
    elif args.tables is not None:
        raise UsageError("--tables applies to the twins (rosetta, poets-park, mappilot) only")


def run(args: argparse.Namespace) -> int:
    import time

    from synth.config import TWINS

    _check_twin_options(args, args.scene in TWINS)
    if args.scene in TWINS:
        return _run_twin(args)
    from polarref.compare.run.pipeline import CompareConfig, command_line, run_compare

    if args.scene is not None and Path(args.scene).expanduser().is_dir():
        _refuse_spaced_names(Path(args.scene).expanduser())
    if args.out is not None:  # before rendering, not after it
        from polarref.core.atomic import check_writable_parent, refuse_inside_inputs

        if args.scene is not None and Path(args.scene).expanduser().is_dir():
            refuse_inside_inputs(args.out, [Path(args.scene).expanduser()])

        if args.out.exists() and not args.out.is_dir():
            raise PolarrefError(f"{args.out} exists and is not a folder (choose another report folder)")
        check_writable_parent(args.out / "metrics.json")
    if args.method_timeout is not None and not args.method_timeout > 0:
        raise PolarrefError(f"--method-timeout must be > 0, got {args.method_timeout}")
    cfg = CompareConfig(scene=args.scene, preset=presets.get(args.preset), out=args.out,
                        methods=tuple(args.methods or ()), seed=args.seed,
                        method_timeout_s=args.method_timeout, claims=not args.no_claims,
                        budget_s=None if args.budget == 0 else args.budget,
                        command=command_line(), overwrite=args.overwrite, dense=args.dense)
    t0 = time.perf_counter()
    out, metrics = run_compare(cfg)
    ok = sum(m.status == RunStatus.OK for m in metrics.methods)
    print(f"{ok}/{len(metrics.methods)} methods succeeded in {time.perf_counter() - t0:.1f} s; "
          f"report: {out / 'report.html'} (and report.md, metrics.json)")
    for m in metrics.methods:
        if m.status != RunStatus.OK:
            print(f"  {m.name}: {m.status}: {m.reason}")
    for c in metrics.claims:
        print(f"  {c.claim_id} {c.verdict:<13} {c.claim}")
    if metrics.methods and not ok:
        raise PolarrefError(f"{out}: every method failed ({len(metrics.methods)} of {len(metrics.methods)}); "
                            "the report names each failure")
    return 0


def _refuse_spaced_names(scene: Path) -> None:
    """pycolmap's methods pass image names through COLMAP text (pair lists, models), which cuts a
    name at its first space: refused before rendering or matching, not after every method ran."""
    from polarref.io.scene_folder import discover, list_images
    from polarref.model.colmap_text import names_text_cannot_hold

    found = discover(scene)
    bad = names_text_cannot_hold([p.name for p in list_images(found.image_dir)])
    if bad:
        raise PolarrefError(f"{found.image_dir}: {len(bad)} image name(s), e.g. {bad[0]!r}, hold whitespace, "
                            "which the COLMAP text files of the comparison cannot hold; rename the images")
