"""Per-iteration cost of the four BA forms on a twin's exported final BA problem (issue 35's
"three-slot forms <= 1.3x the Euclidean form per iteration on the twins' problems").

    PYTHONPATH=$PWD python scripts/twin_ba_forms.py PROBLEM.npz --twin mappilot \\
        --regenerate "COMMAND THAT WROTE IT" [--iterations 5] [--repeat 2] [--out reports/bench-ba-scale/twin-problems]

Every form starts from the same prepared problem and runs ``--iterations`` LM iterations (the
stopping tolerances set to 0, so each runs them all), one thread (compiled kernels are single-threaded; BLAS 1
thread); the forms are interleaved within each repeat. Per-iteration cost = (wall - set-up) /
iterations, accepted and rejected steps both counted (the record keeps how many of each). The
kernels are compiled and every form solved once (one iteration, untimed) before the first timed run.
Writes OUT.json (provenance, the problem file's sha256 and size, every run) and OUT.md, which
is :func:`markdown` of the JSON alone. With an existing OUT.json the problem is added to it
(a problem of the same twin replaced)."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from polarref.ba import BAOptions, kernels, prepare  # noqa: E402
from polarref.ba.entry import solve  # noqa: E402
from polarref.ba.export_problem import read_problem_file  # noqa: E402
from polarref.ba.parameterization import PARAMS  # noqa: E402
from polarref.bench.paired import summary_to_json  # noqa: E402
from polarref.core.atomic import atomic_write  # noqa: E402
from polarref.core.provenance import collect  # noqa: E402

PHASES = ("evaluate", "normal_equations", "schur", "solve", "update")  # per-iteration phases of BASummary.time_in
THRESHOLD = 1.3   # issue 35's bound on a three-slot form's per-iteration cost / the Euclidean form's


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def _options(form: str, iterations: int) -> BAOptions:
    """The form's defaults with the stopping tolerances at 0: the problem enters near its optimum
    (the mapper's last round), and a solve that stopped after one step would time mostly set-up."""
    return BAOptions(param=form, max_iterations=iterations, blas_threads=1, function_tolerance=0.0,
                     gradient_tolerance=0.0, parameter_tolerance=0.0)


def reproduce(pf, base) -> dict | None:
    """Our BA under the mapper's own options on the exported problem, against the mapper's
    result stored in the file (the export's check at scale); None when the file holds none."""
    if pf.result is None:
        return None
    p = base.copy()
    s = solve(p, pf.options.ba_options(), prepared=True)
    r = pf.result
    size = float((r.C.max(0) - r.C.min(0)).max())
    same = bool((p.image_ids == r.image_ids).all())
    return {"final_cost": s.final_cost, "mapper_final_cost": r.final_cost,
            "final_cost_rel_diff": abs(s.final_cost - r.final_cost) / r.final_cost,
            "iterations": s.iterations, "mapper_iterations": r.iterations, "same_cameras": same,
            "max_centre_diff_rel": float(abs(p.C - r.C).max()) / size if same else None, "wall_s": s.wall_s}


def measure(path: Path, iterations: int, repeat: int) -> tuple[dict, list[dict]]:
    pf = read_problem_file(path)
    base = prepare(pf.problem)
    facts = {"num_cameras": base.num_cameras, "num_points": base.num_points,
             "num_observations": base.num_observations, "source": pf.source,
             "mapper_options": {"param": pf.options.param, "loss": pf.options.loss,
                                "max_iterations": pf.options.max_iterations,
                                "function_tolerance": pf.options.function_tolerance},
             "mapper_final_cost": None if pf.result is None else pf.result.final_cost,
             "mapper_initial_cost": None if pf.result is None else pf.result.initial_cost}
    t0 = time.perf_counter()
    kernels.warm_up()
    facts["reproduction"] = reproduce(pf, base)
    for form in PARAMS:  # untimed: what warm_up() leaves to compile or load happens here
        solve(base.copy(), _options(form, 1), prepared=True)
    facts["warm_up_s"] = time.perf_counter() - t0
    runs = []
    for r in range(repeat):
        for form in PARAMS:
            s = solve(base.copy(), _options(form, iterations), prepared=True)
            run = {"form": form, "repeat": r, "iterations": s.iterations, "accepted": s.accepted_iterations,
                   "wall_s": s.wall_s, "setup_s": s.setup_s,
                   "per_iteration_s": (s.wall_s - s.setup_s) / max(s.iterations, 1),
                   "initial_cost": s.initial_cost, "final_cost": s.final_cost,
                   "final_pixel_cost": s.final_pixel_cost, "termination": str(s.termination),
                   "time_in": dict(s.time_in), "load_1min": os.getloadavg()[0]}
            runs.append(run)
            print(json.dumps({k: run[k] for k in ("form", "repeat", "iterations", "per_iteration_s")}), flush=True)
    return facts, runs


def summarize(runs: list[dict]) -> dict:
    """Per form: median per-iteration cost, its ratio to the Euclidean median, and the range of
    the ratios paired within a repeat."""
    return summary_to_json(runs, "per_iteration_s", "per_iteration_s_median", THRESHOLD)


def markdown(doc: dict) -> str:
    env = doc["environment"]
    out = ["# BA forms per iteration on the twins' final BA problems (issue 35)", "",
           f"Generated by `scripts/twin_ba_forms.py` from `twin-problems.json` (commit {env['git_commit'][:10]}"
           f"{', dirty' if env['git_dirty'] else ''}; {env['cpu_model'] or env['machine']}, {env['cpu_count']} cores; "
           f"threads: {doc['threads']}). Timings on a shared, loaded machine: indicative only.",
           f"Done-when bound: a three-slot form's per-iteration cost <= {doc['threshold']:g}x the Euclidean form's.", ""]
    for p in doc["problems"]:
        out += [f"## {p['twin']}: {p['num_cameras']} cameras, {p['num_points']} points, "
                f"{p['num_observations']} observations", "",
                f"Problem file (not in git): `{Path(p['file']).name}`, {p['size_bytes']} bytes, sha256 `{p['sha256']}`; "
                f"regenerate: `{p['regenerate']}`. The mapper solved it from cost {p['mapper_initial_cost']:.6g} "
                f"to {p['mapper_final_cost']:.6g}. {p['iterations_cap']} LM iterations per solve, "
                f"{p['repeat']} repeats, forms interleaved; 1-min load {p['load_1min_start']:.1f} at the start, "
                f"{p['load_1min_end']:.1f} at the end; commit {p['environment']['git_commit'][:10]}"
                f"{' (dirty)' if p['environment']['git_dirty'] else ''}.", "",
                "| form | per iteration (s, median) | / Euclidean | paired range | iterations (accepted) | <= bound |",
                "|---|---|---|---|---|---|"]
        for form, s in p["summary"].items():
            its = ", ".join(f"{r['iterations']} ({r['accepted']})" for r in p["runs"] if r["form"] == form)
            out.append(f"| {form} | {s['per_iteration_s_median']:.3f} | {s['ratio_to_euclidean']:.2f} | "
                       f"{s['ratio_paired_min']:.2f}-{s['ratio_paired_max']:.2f} | {its} | "
                       f"{'yes' if s['within_threshold'] else 'NO'} |")
        out += ["", "Seconds per iteration by solver phase (median over the repeats):", "",
                "| form | " + " | ".join(PHASES) + " |", "|---|" + "---|" * len(PHASES)]
        for form in p["summary"]:
            mine = [r for r in p["runs"] if r["form"] == form]
            cells = [statistics.median(r["time_in"].get(ph, 0.0) / r["iterations"] for r in mine) for ph in PHASES]
            out.append(f"| {form} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")
        rep = p.get("reproduction")
        if rep is not None:
            out += ["", f"Check of the export at this size: our BA under the mapper's options reaches cost "
                    f"{rep['final_cost']:.10g} in {rep['iterations']} iterations, the mapper's final BA reached "
                    f"{rep['mapper_final_cost']:.10g} in {rep['mapper_iterations']} (relative difference "
                    f"{rep['final_cost_rel_diff']:.1e}; largest centre difference {rep['max_centre_diff_rel']:.1e} "
                    "of the centres' extent)."]
        out.append("")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problem", type=Path)
    ap.add_argument("--twin", required=True)
    ap.add_argument("--regenerate", required=True, help="the exact command that wrote PROBLEM (recorded)")
    ap.add_argument("--iterations", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench-ba-scale" / "twin-problems"))
    ap.add_argument("--render-only", action="store_true", help="rewrite OUT.md from OUT.json; measure nothing")
    a = ap.parse_args()
    out = Path(a.out)
    if a.render_only:
        atomic_write(out.with_suffix(".md"), markdown(json.loads(out.with_suffix(".json").read_text())))
        return 0
    old = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else None
    env = collect(threads={"ours_blas": 1, "ours_kernels": 1})
    load = os.getloadavg()[0]
    facts, runs = measure(a.problem, a.iterations, a.repeat)
    problem = {"twin": a.twin, "file": str(a.problem), "sha256": sha256(a.problem),
               "size_bytes": a.problem.stat().st_size, "regenerate": a.regenerate, **facts,
               "iterations_cap": a.iterations, "repeat": a.repeat, "runs": runs, "summary": summarize(runs),
               "load_1min_start": load, "load_1min_end": os.getloadavg()[0], "environment": env}
    doc = {"environment": env, "threads": "1 (kernels single-threaded, BLAS 1)", "threshold": THRESHOLD,
           "problems": [p for p in (old or {}).get("problems", []) if p["twin"] != a.twin] + [problem]}
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out.with_suffix(".json"), json.dumps(doc, indent=1, default=float) + "\n")
    atomic_write(out.with_suffix(".md"), markdown(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
