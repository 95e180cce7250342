"""Per-stage, per-iteration time of our bundle adjuster, numpy reference path vs numba kernels.

Usage: .venv/bin/python scripts/profile_ba.py [--repeat N] PROBLEM [PROBLEM ...]
(PROBLEM as in ``polarref bench ba --problem``: ``bal/problem-49-7776-pre.txt``,
``synth-200-sparse``, ``parallaxba_fakepile``, a path.)

For every problem, form and kernel path the solve runs ``--repeat`` times, interleaved; a
stage's time per LM iteration is the solver's own ``time_in`` (solver.py) divided by the
iterations, and the table shows the minimum over the repeats (the least disturbed run on a
shared machine). Stages: evaluate = residuals + Jacobians (+ cost) at each trial point;
normal = robust weighting, V, g, W, U; schur = point elimination into the reduced camera
system; solve = its Cholesky; update = back-substitution and retraction. Markdown to stdout.
"""

from __future__ import annotations

import argparse
import os
import sys

from polarref.ba import kernels
from polarref.ba.bench import _resolve
from polarref.ba.loaders import load_problem
from polarref.ba.options import PARAMS, BAOptions
from polarref.ba.problem import prepare
from polarref.ba.solver import solve

STAGES = ("evaluate", "normal_equations", "schur", "solve", "update")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problems", nargs="+")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--forms", default=",".join(PARAMS))
    args = ap.parse_args(argv)
    print(f"kernels warm-up {kernels.warm_up():.2f} s; load {os.getloadavg()[0]:.1f}\n")
    print("| problem | form | path | iters | setup ms | " + " | ".join(STAGES)
          + " | total ms / iter | numba speed-up | x Euclidean (same path) |")
    print("|---|---|---|---|---|" + "---|" * len(STAGES) + "---|---|---|")
    for spec in args.problems:
        base, _ = load_problem(_resolve(spec))
        prepare(base)
        best: dict = {}
        for _ in range(args.repeat):
            for form in args.forms.split(","):
                for path in ("numpy", "numba"):
                    s = solve(base.copy(), BAOptions(param=form, kernels=path), prepared=True)
                    n = max(s.iterations, 1)
                    row = {k: s.time_in[k] / n for k in STAGES}
                    row["total"] = (s.wall_s - s.setup_s) / n
                    row["setup"], row["iters"] = s.setup_s, s.iterations
                    old = best.get((form, path))
                    best[(form, path)] = row if old is None else {
                        k: min(v, old[k]) for k, v in row.items()}
        for form in args.forms.split(","):
            for path in ("numpy", "numba"):
                r = best[(form, path)]
                up = best[(form, "numpy")]["total"] / r["total"]
                rel = r["total"] / best[("euclidean", path)]["total"] if ("euclidean", path) in best else float("nan")
                print(f"| {spec} | {form} | {path} | {r['iters']} | {1e3 * r['setup']:.0f} | "
                      + " | ".join(f"{1e3 * r[k]:.1f}" for k in STAGES)
                      + f" | {1e3 * r['total']:.1f} | {up:.2f}x | {rel:.2f}x |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
