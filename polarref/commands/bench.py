"""``polarref bench ba``: our BA parameterizations vs pycolmap (Ceres) and scipy, side by side."""

from __future__ import annotations

from pathlib import Path

from polarref.atomic import check_writable_parent
from polarref.commands._types import nonneg_int, positive_int
from polarref.errors import PolarrefError

NAME = "bench"
HELP = "benchmarks (currently: ba, bundle adjustment vs pycolmap and scipy)"


def add_arguments(parser) -> None:
    from polarref.ba.losses import LOSSES

    parser.add_argument("what", choices=("ba",), help="which benchmark")
    parser.add_argument("--problem", action="append", default=None,
                        help="problem path or synth-20/60/200, synth-60-sparse/synth-200-sparse (repeatable; "
                        "default: the full set)")
    parser.add_argument("--quick", action="store_true", help="only the small problems")
    parser.add_argument("--loss", choices=LOSSES, default="trivial")
    parser.add_argument("--max-iterations", type=positive_int, default=100)
    parser.add_argument("--scipy-max-obs", type=nonneg_int, default=400_000,
                        help="skip scipy on problems with more observations")
    parser.add_argument("--repeat", type=positive_int, default=1,
                        help="timed runs per solver (interleaved); every run is stored, medians and ranges shown")
    parser.add_argument("--merge", action="store_true",
                        help="add/replace these problems in an existing OUT/bench.json")
    parser.add_argument("--out", required=True, help="output folder (bench.json, bench.md)")
    parser.add_argument("--overwrite", action="store_true")


def run(args) -> int:
    from polarref.ba import BAOptions
    from polarref.ba.bench import FULL, QUICK, run_bench

    out = Path(args.out)
    if (out / "bench.json").exists() and not (args.overwrite or args.merge):
        raise PolarrefError(f"{out / 'bench.json'} exists (or use --merge to add problems to it)",
                            option="overwrite")
    if out.exists() and not out.is_dir():
        raise PolarrefError(f"{out} is not a folder (choose another output folder)")
    check_writable_parent(out / "bench.json")
    problems = args.problem or (QUICK if args.quick else FULL)
    results = run_bench(problems, out, BAOptions(loss=args.loss,
                                                 max_iterations=args.max_iterations),
                        args.scipy_max_obs, repeat=args.repeat, merge=args.merge)
    print((out / "bench.md").read_text())
    return 0 if results else 1
