"""``polarref ba``: bundle-adjust one problem (BAL, ParallaxBA, COLMAP model) and write JSON."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from polarref.commands._types import float_range, positive_int, refine_groups
from polarref.core.errors import PolarrefError

NAME = "ba"
HELP = "bundle-adjust a BAL / ParallaxBA / PVL-BA / COLMAP problem with one parameterization"


def add_arguments(parser) -> None:
    from polarref.ba.losses import LOSSES
    from polarref.ba.options import DAMPINGS, PARAMS, SOLVERS
    parser.add_argument("problem", help="BAL .txt, ParallaxBA folder, PVL-BA folder or BlocksExchange .xml, COLMAP model folder, "
                        "a BA problem exported by `polarref sfm --export-final-ba` (.npz), or synth-20 / synth-60 / synth-200")
    parser.add_argument("--param", choices=PARAMS, default="euclidean")
    parser.add_argument("--loss", choices=LOSSES, default="trivial")
    parser.add_argument("--loss-scale", type=float_range(0.0, lo_open=True), default=1.0,
                        help="robust loss scale [px], finite and > 0")
    parser.add_argument("--max-iterations", type=positive_int, default=100)
    parser.add_argument("--solver", choices=SOLVERS, default="lm",
                        help="lm: Levenberg-Marquardt; gn: Gauss-Newton (undamped, gauge held)")
    parser.add_argument("--damping", choices=DAMPINGS, default=None,
                        help="LM damping: ceres (trust region, diag-scaled) or nielsen "
                        "(ParallaxBA: mu I); default: the form's measured best")
    parser.add_argument("--lm-gauge", choices=("free", "fixed"), default=None,
                        help="LM: release the 7 gauge DoF during the solve (result mapped back) "
                        "or hold them; default: the form's measured best")
    parser.add_argument("--staged", action="store_true", help="angular: theta first, then joint")
    parser.add_argument("--refine", type=refine_groups, default=(), metavar="GROUPS",
                        help="self-calibration: refine intrinsics groups focal,pp,dist (default none); the "
                        "principal point of a camera seen by one image only is held unless --refine-pp-single")
    parser.add_argument("--refine-pp-single", action="store_true",
                        help="with --refine pp: refine it on cameras seen by one image too (poorly constrained)")
    parser.add_argument("--out", required=True, help="output JSON path")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")


def run(args) -> int:
    from polarref.core.atomic import atomic_write, check_writable_parent, refuse_inside_inputs
    from polarref.ba import BAOptions, solve
    from polarref.ba.loaders import load_problem

    out = Path(args.out)
    if not str(args.problem).startswith("synth-"):
        refuse_inside_inputs(out, [args.problem])
    if out.is_dir():
        raise PolarrefError(f"{out} is a folder; --out takes a JSON file path")
    if out.exists() and not args.overwrite:
        raise PolarrefError(f"{out} exists", option="overwrite")
    check_writable_parent(out)
    try:
        options = BAOptions(param=args.param, loss=args.loss, loss_scale=args.loss_scale,
                            max_iterations=args.max_iterations, staged=args.staged,
                            solver=args.solver, damping=args.damping, lm_gauge=args.lm_gauge,
                            refine=args.refine, refine_pp_single=args.refine_pp_single)
    except ValueError as exc:
        raise PolarrefError(str(exc)) from exc
    problem, _ = load_problem(args.problem)
    summary = solve(problem, options)
    if not (math.isfinite(summary.initial_cost) and math.isfinite(summary.final_cost)):
        raise PolarrefError(f"{args.problem}: bundle adjustment cost is not finite (initial "
                            f"{summary.initial_cost:.6g}, final {summary.final_cost:.6g}); check the "
                            "problem for huge or degenerate values")
    data = dataclasses.asdict(summary)
    data.pop("points_state", None)
    data["problem"] = str(args.problem)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out, json.dumps(data, indent=1, default=float) + "\n")
    print(f"{args.param}: cost {summary.initial_cost:.6g} -> {summary.final_cost:.6g}, "
          f"RMS {summary.final_rms_px:.4f} px, {summary.iterations} iterations "
          f"({summary.accepted_iterations} accepted, {summary.rejected_iterations} rejected; "
          f"{summary.solver}, damping {summary.damping}), "
          f"{summary.wall_s:.3f} s ({summary.termination_text})")
    return 0
