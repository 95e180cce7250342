"""Markdown of a bench.json: the bench table and the README's speed table, from the JSON alone.

The README quotes bench figures only through :func:`readme_table` (run ``python -m
polarref.ba.bench_report reports/bench-ba/bench.json`` and paste), so no number in it can drift
from bench.json.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from polarref.ba.parameterization import PARAMS


def _rng(st: dict | None, digits: int = 3) -> str:
    if not st or st.get("median") is None:
        return "-"
    if st["n"] == 1:
        return f"{st['median']:.{digits}f}"
    return f"{st['median']:.{digits}f} ({st['min']:.{digits}f}-{st['max']:.{digits}f})"


def _settings(x: dict) -> str:
    s = x.get("settings", {})
    if x.get("kind") == "ceres":
        return (f"ftol {s.get('function_tolerance'):g}, gtol {s.get('gradient_tolerance'):g}, ptol "
                f"{s.get('parameter_tolerance'):g}, max it {s.get('max_num_iterations')}, threads "
                f"{s.get('num_threads_used', s.get('num_threads'))}, {s.get('linear_solver_used', '?')}")
    if x.get("kind") == "ours":
        return (f"ftol {s.get('function_tolerance'):g}, gtol {s.get('gradient_tolerance'):g}, ptol "
                f"{s.get('parameter_tolerance'):g}, max it {s.get('max_iterations')}, BLAS threads "
                f"{s.get('threads')}, {x['full_runs'][0].get('linear_solver', '')}")
    return ", ".join(f"{k} {v}" for k, v in s.items())


def _iters(x: dict) -> str:
    it = x.get("iterations_to_target")
    if not it:
        return "-"
    return f"{it['total']} ({it['accepted']}/{it['rejected']})"


def markdown(doc: dict) -> str:
    env = doc.get("environment", {})
    out = [f"Commit {env.get('git_commit', '?')}{' (dirty)' if env.get('git_dirty') else ''}, "
           f"{env.get('cpu_count', '?')} x {env.get('cpu_model', '?')}; settings of every solver in the "
           "table. Costs: 1/2 sum of squared pixel residuals recomputed on every output. Common cost: the "
           "highest final cost among pixel-objective solvers within 1 % of the best; t to target: wall time "
           "of a complete solve limited to the fewest iterations that reach the common cost + 0.1 % "
           "(median (min-max) over the repeats); iterations to target: total (accepted/rejected). "
           "x fastest Ceres: median t to target / the fastest Ceres setting's.", "",
           "| problem | solver | settings | final cost | full-run wall s | iters | t to target s | "
           "iters to target | x fastest Ceres | termination |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for res in doc.get("problems", []):
        name = (f"{res['problem']} ({res['num_cameras']} cams, {res['num_points']} pts, "
                f"{res['num_observations']} obs; target {res['target_cost']:.6g}; {res.get('repeat', 1)} repeats, "
                f"load {res.get('load_1min', float('nan')):.1f})")
        for x in res["rows"]:
            if "error" in x:
                out.append(f"| {name} | {x['solver']} | {x['error']} ||||||||")
                name = ""
                continue
            ratio = x.get("ratio_to_fastest_ceres")
            out.append(f"| {name} | {x['solver']} | {_settings(x)} | {x['final_cost']:.6g} | {_rng(x['wall_s'])} | "
                       f"{x['iterations']} | {_rng(x.get('time_to_target_s'))} | {_iters(x)} | "
                       f"{'-' if ratio is None else f'{ratio:.2f}'} | {x['full_runs'][0].get('termination', '')} |")
            name = ""
    out += _per_iteration_lines(doc) + _own_cost_lines(doc)
    return "\n".join(out) + "\n"


FORMS = PARAMS  # the one registry of form names


def _per_iteration_lines(doc: dict) -> list[str]:
    """Our forms' seconds per accepted iteration (full runs, median) and the ratio to the
    Euclidean form's, side by side per problem; empty for a bench.json without them."""
    probs = [r for r in doc.get("problems", []) if any("s_per_accepted_iteration" in x for x in r["rows"])]
    if not probs:
        return []
    out = ["", "Per-iteration cost (our forms, same problem, same run, 1 thread): (full-run wall - "
           "setup) / accepted iterations, median over the repeats, in ms; ratio to the Euclidean form.", "",
           "| problem | " + " | ".join(FORMS) + " |", "|---|" + "---|" * len(FORMS)]
    for res in probs:
        t = {x["solver"]: x for x in res["rows"]}
        cells = []
        for f in FORMS:
            x = t.get(f) or {}
            v = (x.get("s_per_accepted_iteration") or {}).get("median")
            ratio = x.get("per_iteration_vs_euclidean")
            cells.append("-" if v is None else f"{1e3 * v:.1f} ({ratio:.2f}x)" if ratio else f"{1e3 * v:.1f}")
        out.append(f"| {res['problem']} | " + " | ".join(cells) + " |")
    return out


def _own_cost_lines(doc: dict) -> list[str]:
    """Euclidean vs Ceres to the best Ceres final cost, where the common target was not usable."""
    probs = [r for r in doc.get("problems", []) if r.get("ceres_own_cost")]
    if not probs:
        return []
    out = ["", "Euclidean vs Ceres to Ceres' own best final cost (+0.1 %), where our Euclidean form or "
           "no Ceres setting reached the common target:", "",
           "| problem | target | euclidean t s | fastest Ceres (t s) | ratio |", "|---|---|---|---|---|"]
    for res in probs:
        o = res["ceres_own_cost"]
        e = o["rows"]["euclidean"]["time_to_target_s"]
        f = o.get("fastest_ceres")
        ft = o["rows"][f]["time_to_target_s"] if f else None
        r = o.get("euclidean_ratio_to_fastest_ceres")
        out.append(f"| {res['problem']} | {o['target_cost']:.6g} | {_rng(e)} | "
                   f"{f or 'none'} ({_rng(ft)}) | {'-' if r is None else f'{r:.2f}x'} |")
    return out


def _readme_cell(row: dict, target: float | None) -> str:
    """Ratio to the fastest Ceres; else why there is none (a form may reach a target no Ceres
    setting reaches, or stop above it: the polar objective is not the pixel cost)."""
    r = row.get("ratio_to_fastest_ceres")
    if r is not None:
        return f"{r:.2f}x"
    t = (row.get("time_to_target_s") or {}).get("median")
    if row.get("reached_target") and t is not None:
        return f"{t:.3f} s (no Ceres setting reached it)"
    cost = row.get("final_cost")
    if target and cost is not None and cost > target:
        return f"did not reach (stops {100.0 * (cost / target - 1.0):+.1f}%)"
    return "did not reach"


def readme_table(doc: dict) -> str:
    """Per problem: fastest Ceres setting and our forms' time-to-target ratios against it."""
    out = ["| problem | fastest Ceres setting (t to target, s) | euclidean | parallax | polar | angular |",
           "|---|---|---|---|---|---|"]
    for res in doc.get("problems", []):
        t = {x["solver"]: x for x in res["rows"]}
        f = res.get("fastest_ceres")
        cells = []
        for p in FORMS:
            cells.append(_readme_cell(t.get(p) or {}, res.get("target_cost")))
        head = "none reached the target" if f is None else f"{f} ({res['fastest_ceres_time_to_target_s']:.3f})"
        out.append(f"| {res['problem']} | {head} | " + " | ".join(cells) + " |")
    out += _per_iteration_lines(doc) + _own_cost_lines(doc)
    return "\n".join(out) + "\n"


BEGIN = "<!-- bench-table: generated from reports/bench-ba/bench.json, do not edit by hand -->"
END = "<!-- /bench-table -->"


def readme_block(text: str) -> str | None:
    """The generated table between the README's markers (None without markers)."""
    if BEGIN not in text or END not in text:
        return None
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")


def update_readme(readme: Path, doc: dict) -> None:
    text = readme.read_text()
    if readme_block(text) is None:
        raise SystemExit(f"{readme}: no {BEGIN!r} ... {END!r} block")
    head, rest = text.split(BEGIN, 1)
    readme.write_text(head + BEGIN + "\n" + readme_table(doc) + END + rest.split(END, 1)[1])


if __name__ == "__main__":
    bench = json.loads(Path(sys.argv[1]).read_text())
    if len(sys.argv) == 4 and sys.argv[2] == "--readme":
        update_readme(Path(sys.argv[3]), bench)
    else:
        print(readme_table(bench))
