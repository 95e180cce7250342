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

``cpu ms / accepted`` is CPU time (``time.process_time``, less disturbed by other processes
than wall time on a loaded machine) of the whole solve minus that of the same solve with
``max_iterations=0`` (setup, first evaluation, write-back), divided by the accepted
iterations: the bench's ``s_per_accepted_iteration`` in CPU time. Its ratio to Euclidean
(same path, same run) is the issue's per-iteration target; minimum over the repeats.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

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
    ap.add_argument("--paths", default="numpy,numba", help="kernel paths to run")
    args = ap.parse_args(argv)
    print(f"kernels warm-up {kernels.warm_up():.2f} s; load {os.getloadavg()[0]:.1f}\n")
    print("| problem | form | path | iters | setup ms | " + " | ".join(STAGES)
          + " | total ms / iter | numba speed-up | x Euclidean (same path) | cpu ms / accepted"
          " | cpu x Euclidean |")
    print("|---|---|---|---|---|" + "---|" * len(STAGES) + "---|---|---|---|---|")
    for spec in args.problems:
        base, _ = load_problem(_resolve(spec))
        prepare(base)
        best: dict = {}
        for _ in range(args.repeat):
            for form in args.forms.split(","):
                for path in args.paths.split(","):
                    c0 = time.process_time()
                    solve(base.copy(), BAOptions(param=form, kernels=path, max_iterations=0),
                          prepared=True)
                    c1 = time.process_time()
                    s = solve(base.copy(), BAOptions(param=form, kernels=path), prepared=True)
                    cpu = time.process_time() - c1 - (c1 - c0)
                    n = max(s.iterations, 1)
                    row = {k: s.time_in[k] / n for k in STAGES}
                    row["total"] = (s.wall_s - s.setup_s) / n
                    row["setup"], row["iters"] = s.setup_s, s.iterations
                    row["cpu"] = cpu / max(s.accepted_iterations, 1)
                    old = best.get((form, path))
                    best[(form, path)] = row if old is None else {
                        k: min(v, old[k]) for k, v in row.items()}
        for form in args.forms.split(","):
            for path in args.paths.split(","):
                r = best[(form, path)]
                up = (best[(form, "numpy")]["total"] / r["total"]
                      if (form, "numpy") in best else float("nan"))
                eu = best.get(("euclidean", path))
                rel = r["total"] / eu["total"] if eu else float("nan")
                rel_cpu = r["cpu"] / eu["cpu"] if eu else float("nan")
                print(f"| {spec} | {form} | {path} | {r['iters']} | {1e3 * r['setup']:.0f} | "
                      + " | ".join(f"{1e3 * r[k]:.1f}" for k in STAGES)
                      + f" | {1e3 * r['total']:.1f} | {up:.2f}x | {rel:.2f}x"
                      + f" | {1e3 * r['cpu']:.1f} | {rel_cpu:.2f}x |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
