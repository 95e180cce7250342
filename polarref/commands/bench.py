"""``polarref bench ba``: our BA parameterizations vs pycolmap (Ceres) and scipy, side by side."""

from __future__ import annotations

from pathlib import Path

from polarref.core.atomic import check_writable_parent, refuse_inside_inputs
from polarref.commands._types import int_range, nonneg_int, positive_int
from polarref.core.errors import PolarrefError, UsageError

NAME = "bench"
HELP = "benchmarks: ba (bundle adjustment vs pycolmap and scipy), sfm (our SfM vs pycolmap vs views)"


def add_arguments(parser) -> None:
    from polarref.ba.losses import LOSSES

    parser.add_argument("what", choices=("ba", "sfm"), help="which benchmark")
    parser.add_argument("--problem", action="append", default=None,
                        help="problem path or synth-20/60/200, synth-60-sparse/synth-200-sparse, "
                        "scale-1e5/1e6/3e6/1e7[:SEED], twin-mappilot/rosetta/poets-park (an exported twin final BA, "
                        "scripts/twin_ba_export.py), an exported .npz (repeatable; default: the full set)")
    parser.add_argument("--quick", action="store_true", help="only the small problems")
    parser.add_argument("--loss", choices=LOSSES, default="trivial")
    parser.add_argument("--max-iterations", type=positive_int, default=100)
    parser.add_argument("--scipy-max-obs", type=nonneg_int, default=400_000,
                        help="skip scipy on problems with more observations")
    parser.add_argument("--repeat", type=positive_int, default=1,
                        help="timed runs per solver (ba) or cell (sfm), interleaved; every run is stored, "
                        "medians and ranges shown")
    parser.add_argument("--merge", action="store_true",
                        help="add/replace these problems in an existing OUT/bench.json")
    parser.add_argument("--bisect-max-obs", type=nonneg_int, default=400_000,
                        help="ba: above this many observations the time to the common target is read from "
                        "the iteration traces instead of bisection over iteration limits")
    parser.add_argument("--ceres-max-s", type=positive_int, default=600,
                        help="ba: cap on one Ceres solve's time (max_solver_time_in_seconds), recorded")
    parser.add_argument("--solvers", nargs="+", default=None, metavar="NAME",
                        help="ba: run only these solvers (forms and Ceres settings by name, e.g. euclidean "
                        "ceres-sparse-schur-1t); the others are listed as not run")
    parser.add_argument("--cache", default=None, metavar="DIR",
                        help="ba: store each solver's first full run in DIR and reuse it (resume; solvers "
                        "measured by separate processes, then tabulated together)")
    parser.add_argument("--no-cold", action="store_true",
                        help="ba: skip the cold-process timing of `polarref ba` per problem")
    parser.add_argument("--ours-threads", type=int_range(1, 64), default=1, metavar="N",
                        help="ba: BLAS threads of our forms and scipy (recorded; Ceres runs on 1 and 2 threads "
                        "either way), default 1")
    sfm = parser.add_argument_group("sfm (our SfM vs pycolmap incremental, same images and pairs)")
    sfm.add_argument("--scene", choices=("comet", "uav"), default="comet")
    sfm.add_argument("--views", type=int_range(4, 5000), nargs="+", default=[28, 84, 168, 336],
                     help="view counts (one rendered scene each)")
    sfm.add_argument("--preset", choices=("small", "default", "large"), default="default",
                     help="render preset (image size); the view count overrides its views")
    sfm.add_argument("--methods", nargs="+", choices=("ours", "pycolmap"), default=["ours", "pycolmap"])
    sfm.add_argument("--overlap", type=positive_int, default=10, help="sequential pairing overlap")
    sfm.add_argument("--seed", type=nonneg_int, default=0)
    sfm.add_argument("--cell-timeout", type=positive_int, default=None, help="seconds per (method, views) cell")
    sfm.add_argument("--parallel", type=int_range(1, 64), nargs="+", default=[1, 2],
                     help="core counts per method: ours' front-end worker threads, pycolmap's threads (default: 1 2)")
    sfm.add_argument("--max-features", type=positive_int, default=4096,
                     help="SIFT keypoints per image, the same budget for both methods")
    sfm.add_argument("--report-only", action="store_true",
                     help="run no cell: rebuild bench.json/md/png from the finished cells (a sweep stopped part-way)")
    parser.add_argument("--out", required=True, help="output folder (bench.json, bench.md; sfm: also bench.png, "
                        "cells/, bench.log)")
    parser.add_argument("--overwrite", action="store_true")


def run(args) -> int:
    if args.what == "sfm":
        return _run_sfm(args)
    from polarref.ba import BAOptions
    from polarref.bench.ba import FULL, QUICK, run_bench

    out = Path(args.out)
    if (out / "bench.json").exists() and not (args.overwrite or args.merge):
        raise PolarrefError(f"{out / 'bench.json'} exists (or use --merge to add problems to it)",
                            option="overwrite")
    if out.exists() and not out.is_dir():
        raise PolarrefError(f"{out} is not a folder (choose another output folder)")
    check_writable_parent(out / "bench.json")
    problems = args.problem or (QUICK if args.quick else FULL)
    refuse_inside_inputs(out, [p for p in problems if Path(p).exists()])
    if args.solvers:
        from polarref.bench.ba import solver_names
        unknown = sorted(set(args.solvers) - set(solver_names()))
        if unknown or ("euclidean" not in args.solvers and not args.cache):
            raise UsageError(f"--solvers: {'unknown ' + ', '.join(unknown) if unknown else 'euclidean is needed'}"
                             f" (known: {', '.join(solver_names())})")
    doc = run_bench(problems, out, BAOptions(loss=args.loss, max_iterations=args.max_iterations,
                                             blas_threads=args.ours_threads),
                        args.scipy_max_obs, repeat=args.repeat, merge=args.merge,
                        bisect_max_obs=args.bisect_max_obs, ceres_max_s=float(args.ceres_max_s),
                        cold=not args.no_cold, only=tuple(args.solvers or ()),
                        cache=Path(args.cache) if args.cache else None)
    print((out / "bench.md").read_text())
    return 0 if doc.problems else 1


def _run_sfm(args) -> int:
    """Finished cells in OUT/cells are reused (resume); --overwrite reruns every cell."""
    from polarref.bench.sfm import BenchSfMSettings, run_bench

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise PolarrefError(f"{out} is not a folder (choose another output folder)")
    check_writable_parent(out / "bench.json")
    settings = BenchSfMSettings(scene=args.scene, preset=args.preset, seed=args.seed, overlap=args.overlap,
                                max_num_features=args.max_features)
    bench = run_bench(sorted(set(args.views)), out, settings, tuple(args.methods), overwrite=args.overwrite,
                      cell_timeout_s=args.cell_timeout, parallel=tuple(sorted(set(args.parallel))),
                      repeats=args.repeat, report_only=args.report_only)
    print((out / "bench.md").read_text())
    return 0 if bench.cells and not bench.failed else 1
