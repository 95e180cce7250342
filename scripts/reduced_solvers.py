"""Time and peak memory of each reduced-camera-system solver on one problem (issue 35).

Usage: .venv/bin/python scripts/reduced_solvers.py PROBLEM [--forms euclidean] [--solvers
       dense-cholesky,sparse-lu,pcg] [--max-iterations N] [--out reports/bench-ba-scale/reduced-solvers]
       [--overwrite]

Every (form, solver) solve runs in a forked child (``bench.ba_measure.forked``: the peak is
the memory that solve added, as in the BA bench), 1 BLAS thread, at most N LM steps, with the
solver's own clock read as process CPU time (a loaded machine's waiting drops out). Per solve:
iterations (accepted), CPU seconds per LM step of the whole solve after its setup and of the
reduced solve alone (``time_in["solve"]``), the Schur stage's, the peak MiB and the final pixel
cost. Writes OUT.json (with provenance and the load average) and OUT.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from polarref.ba import solver as solver_mod  # noqa: E402
from polarref.ba.entry import solve  # noqa: E402
from polarref.ba.loaders import load_problem  # noqa: E402
from polarref.ba.options import BAOptions  # noqa: E402
from polarref.ba.problem import prepare  # noqa: E402
from polarref.bench.ba import _resolve  # noqa: E402
from polarref.bench.ba_measure import forked  # noqa: E402
from polarref.core.records import to_dict  # noqa: E402
from profile_ba import add_out_arguments, begin, write_doc  # noqa: E402  (scripts/ is sys.path[0])


def one(base, form: str, solver: str, max_iterations: int) -> dict:
    from threadpoolctl import threadpool_limits

    def run():
        solver_mod.time = types.SimpleNamespace(perf_counter=time.process_time)
        with threadpool_limits(limits=1, user_api="blas"):
            s = solve(base.copy(), BAOptions(param=form, reduced_solver=solver, max_iterations=max_iterations),
                      prepared=True)
        return {"iterations": s.iterations, "accepted": s.accepted_iterations, "cpu_s": s.wall_s,
                "setup_cpu_s": s.setup_s, "time_in_cpu_s": dict(s.time_in), "linear_solver": s.linear_solver,
                "final_pixel_cost": s.final_pixel_cost, "initial_pixel_cost": s.initial_pixel_cost}

    t = time.perf_counter()
    out, peak = forked(run)
    steps = max(out["iterations"], 1)
    return {"form": form, "solver": solver, **out, "wall_s": time.perf_counter() - t, "peak_rss_mib": peak,
            "cpu_s_per_step": (out["cpu_s"] - out["setup_cpu_s"]) / steps,
            "solve_cpu_s_per_step": out["time_in_cpu_s"].get("solve", 0.0) / steps,
            "schur_cpu_s_per_step": out["time_in_cpu_s"].get("schur", 0.0) / steps}


def markdown(doc: dict) -> str:
    env = doc["environment"]
    out = [f"Reduced-system solvers on {doc['problem']} ({doc['num_cameras']} cameras, {doc['num_observations']} "
           f"observations), commit {env['git_commit'][:7]}{' (dirty)' if env['git_dirty'] else ''}, at most "
           f"{doc['max_iterations']} LM steps, 1 thread, process CPU time; load {doc['load_1min'][0]:.1f}-"
           f"{doc['load_1min'][1]:.1f} on {env['cpu_count']} cores (indicative). Peak: memory the solve added "
           "(forked child).", "",
           "| form | solver | steps (accepted) | CPU s / step | reduced solve CPU s / step | Schur CPU s / step "
           "| peak MiB | final pixel cost | linear solver |", "|---|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        out.append(f"| {r['form']} | {r['solver']} | {r['iterations']} ({r['accepted']}) | {r['cpu_s_per_step']:.2f} | "
                   f"{r['solve_cpu_s_per_step']:.2f} | {r['schur_cpu_s_per_step']:.2f} | {r['peak_rss_mib']:.0f} | "
                   f"{r['final_pixel_cost']:.8g} | {r['linear_solver']} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problem")
    ap.add_argument("--forms", default="euclidean")
    ap.add_argument("--solvers", default="dense-cholesky,sparse-lu,pcg")
    ap.add_argument("--max-iterations", type=int, default=5)
    add_out_arguments(ap, ROOT / "reports" / "bench-ba-scale" / "reduced-solvers")
    args = ap.parse_args(argv)
    out = Path(args.out)
    started = begin(out, args.overwrite)
    if started is None:
        return 2
    env, load0 = started
    base, _ = load_problem(_resolve(args.problem))
    prepare(base)
    rows = []
    for form in args.forms.split(","):
        for solver in args.solvers.split(","):
            rows.append(one(base, form, solver, args.max_iterations))
            print(rows[-1], flush=True)
    doc = {"command": "python scripts/reduced_solvers.py " + " ".join(sys.argv[1:]), "problem": args.problem,
           "num_cameras": base.num_cameras, "num_observations": base.num_observations,
           "max_iterations": args.max_iterations, "load_1min": [load0, os.getloadavg()[0]], "rows": rows,
           "environment": to_dict(env)}
    write_doc(out, doc, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
