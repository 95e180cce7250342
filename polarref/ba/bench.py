"""Benchmark: every parameterization of ours, pycolmap (Ceres) and scipy on the same problems.

Costs are all recomputed with one definition (:func:`polarref.ba.solver.pixel_cost`).
Peak memory: ``tracemalloc`` peak of Python/numpy allocations during our and scipy's solves;
for pycolmap (C++ allocations are invisible to tracemalloc) the process ``ru_maxrss``
after its run, an upper bound that includes everything loaded before.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import resource
import time
import tracemalloc
from pathlib import Path

from polarref.ba.options import PARAMS, BAOptions
from polarref.ba.problem import prepare
from polarref.ba.solver import solve

log = logging.getLogger(__name__)

QUICK = ("synth-20", "bal/dubrovnik-3-7-pre.txt")
FULL = ("bal/problem-49-7776-pre.txt", "parallaxba_fakepile", "synth-20", "synth-60", "synth-200")
SCIPY_MAX_OBS = 70_000  # scipy's lsmr-based trf is minutes beyond this; skipped (noted)


def _resolve(spec: str) -> str:
    if spec.startswith("synth-") or Path(spec).exists():
        return spec
    from polarref.data import data_path
    return str(data_path(*spec.split("/")))


def run_problem(spec: str, options: BAOptions, scipy_max_obs: int = SCIPY_MAX_OBS) -> dict:
    from polarref.ba.loaders import load_problem
    from polarref.ba.peers import run_pycolmap, run_scipy

    base, _ = load_problem(_resolve(spec))
    prepare(base)
    rows = []
    for param in PARAMS:
        pb = base.copy()
        tracemalloc.start()
        try:
            s = solve(pb, dataclasses.replace(options, param=param), prepared=True)
            peak = tracemalloc.get_traced_memory()[1]
        except Exception as exc:  # a failing form is reported, not fatal to the bench
            tracemalloc.stop()
            rows.append({"solver": param, "error": f"{type(exc).__name__}: {exc}"})
            continue
        tracemalloc.stop()
        trace = [(r.wall_s, r.cost) for r in s.trace if r.accepted]
        rows.append({"solver": param, "initial_cost": s.initial_pixel_cost,
                     "final_cost": s.final_pixel_cost, "objective_final": s.final_cost,
                     "final_rms_px": s.final_rms_px, "iterations": s.iterations,
                     "wall_s": s.wall_s, "termination": s.termination,
                     "peak_mem_mb": peak / 2**20, "mem_kind": "tracemalloc",
                     "per_iteration_s": s.wall_s / max(s.iterations, 1),
                     "pixel_objective": param in ("euclidean", "parallax"), "trace": trace,
                     "time_in": s.time_in, "linear_solver": s.linear_solver})
    r = run_pycolmap(base.copy(), options)
    rows.append({"solver": "pycolmap", "initial_cost": r.initial_cost, "final_cost": r.final_cost,
                 "final_rms_px": r.final_rms_px, "iterations": r.iterations, "wall_s": r.wall_s,
                 "termination": r.termination, "reported_cost": r.reported_cost,
                 "peak_mem_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                 "mem_kind": "maxrss"})
    if base.num_observations <= scipy_max_obs:
        tracemalloc.start()
        r = run_scipy(base.copy(), options)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        rows.append({"solver": "scipy", "initial_cost": r.initial_cost, "final_cost": r.final_cost,
                     "final_rms_px": r.final_rms_px, "iterations": r.iterations,
                     "wall_s": r.wall_s, "termination": r.termination,
                     "peak_mem_mb": peak / 2**20, "mem_kind": "tracemalloc"})
    best = min(x["final_cost"] for x in rows if "final_cost" in x)
    py = next(x for x in rows if x["solver"] == "pycolmap")
    for x in rows:
        if "final_cost" not in x:
            continue
        x["within_0.1pct_of_best"] = bool(x["final_cost"] <= best * 1.001)
        x["time_to_0.1pct_s"] = None
        if x.get("pixel_objective"):
            hit = [t for t, c in x["trace"] if c <= best * 1.001]
            x["time_to_0.1pct_s"] = hit[0] if hit else None
        elif x["within_0.1pct_of_best"] and x["solver"] in ("pycolmap", "scipy"):
            x["time_to_0.1pct_s"] = x["wall_s"]  # no per-iteration trace: upper bound
        x["ratio_to_pycolmap"] = x["wall_s"] / py["wall_s"]
    eu = next((x for x in rows if x["solver"] == "euclidean" and "per_iteration_s" in x), None)
    for x in rows:
        if eu and "per_iteration_s" in x:
            x["per_iteration_vs_euclidean"] = x["per_iteration_s"] / eu["per_iteration_s"]
    return {"problem": spec, "num_cameras": base.num_cameras, "num_points": base.num_points,
            "num_observations": base.num_observations, "best_final_cost": best, "rows": rows}


def markdown(results: list[dict]) -> str:
    out = ["| problem | solver | initial cost | final cost | RMS px | iters | wall s | "
           "t to 0.1% s | x pycolmap | s/iter vs eu | peak MB |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        name = (f"{res['problem']} ({res['num_cameras']} cams, {res['num_points']} pts, "
                f"{res['num_observations']} obs)")
        for x in res["rows"]:
            if "error" in x:
                out.append(f"| {name} | {x['solver']} | error: {x['error']} |||||||||")
                continue
            t01 = "-" if x["time_to_0.1pct_s"] is None else f"{x['time_to_0.1pct_s']:.3f}"
            pie = x.get("per_iteration_vs_euclidean")
            out.append(f"| {name} | {x['solver']} | {x['initial_cost']:.6g} | {x['final_cost']:.6g} | "
                       f"{x['final_rms_px']:.4f} | {x['iterations']} | {x['wall_s']:.3f} | {t01} | "
                       f"{x['ratio_to_pycolmap']:.2f} | {'-' if pie is None else f'{pie:.2f}'} | "
                       f"{x['peak_mem_mb']:.0f} ({x['mem_kind']}) |")
    return "\n".join(out) + "\n"


def run_bench(problems, out_dir: Path, options: BAOptions = BAOptions(),
              scipy_max_obs: int = SCIPY_MAX_OBS) -> list[dict]:
    out_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for spec in problems:
        t = time.perf_counter()
        res = run_problem(spec, options, scipy_max_obs)
        log.info("bench %s done in %.1f s", spec, time.perf_counter() - t)
        results.append(res)
        # written after every problem so an interrupted bench keeps what it measured
        (out_dir / "bench.json").write_text(json.dumps(results, indent=1, default=float))
        (out_dir / "bench.md").write_text(markdown(results))
    return results
