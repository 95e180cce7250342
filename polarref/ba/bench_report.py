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
from polarref.core.markers import read_block, replace_block


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
    if it.get("accepted") is None:   # read from a trace: LM steps up to the first one at the target
        return str(it["total"])
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
                f"load {res.get('load_1min', float('nan')):.1f}"
                + (f"-{res['load_1min_end']:.1f}" if "load_1min_end" in res else "")
                + ("; t to target from the full runs' iteration traces"
                   if res.get("time_to_target_method") == "iteration traces" else "") + ")")
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
    out += (_per_iteration_lines(doc) + _own_cost_lines(doc) + _tau_lines(doc) + _memory_lines(doc)
            + _roofline_lines(doc) + _cold_lines(doc))
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


def _fmt(v, spec=".3f", none="-") -> str:
    return none if v is None else format(v, spec)


def _tau_lines(doc: dict) -> list[str]:
    """Per problem and tau: each solver's time to best + tau (initial - best) and its ratio to
    the fastest Ceres setting's (medians over the repeats' full-run traces)."""
    probs = [r for r in doc.get("problems", []) if r.get("tau_summary")]
    if not probs:
        return []
    out = ["", "Time to the tau targets best + tau (initial - best) (rootBA's rule; best: the lowest final "
           "pixel cost of any pixel-objective solver), read from the full runs' iteration traces, median s "
           "(x the fastest Ceres setting at that tau); `-`: not reached, or not a pixel objective (polar, angular).",
           "", "| problem | solver | tau 1e-2 | tau 1e-3 | tau 1e-4 | iterations (1e-2/1e-3/1e-4) |",
           "|---|---|---|---|---|---|"]
    for res in probs:
        name = res["problem"]
        keys = list(res["tau_summary"])
        for x in res["rows"]:
            if "tau" not in x:
                continue
            cells, its = [], []
            for k in keys:
                t = (x["tau"].get(k, {}).get("time_s") or {}).get("median")
                r = res["tau_summary"][k]["ratio_to_fastest_ceres"].get(x["solver"])
                cells.append("-" if t is None else f"{t:.3f}" + (f" ({r:.2f}x)" if r is not None else ""))
                its.append(_fmt(x["tau"].get(k, {}).get("iterations"), "d"))
            out.append(f"| {name} | {x['solver']} | " + " | ".join(cells) + f" | {'/'.join(its)} |")
            name = ""
    return out


def _memory_lines(doc: dict) -> list[str]:
    probs = [r for r in doc.get("problems", []) if any("peak_rss_mib" in x for x in r["rows"])]
    if not probs:
        return []
    out = ["", "Peak memory added by one full solve (forked child: resident high-water mark minus the "
           "resident set at the fork), MiB; ratio: our Euclidean form / the leanest Ceres setting.", "",
           "| problem | " + " | ".join(FORMS) + " | Ceres (min-max over settings) | euclidean / min Ceres |",
           "|---|" + "---|" * (len(FORMS) + 2)]
    for res in probs:
        t = {x["solver"]: x.get("peak_rss_mib") for x in res["rows"]}
        cer = [v for n, v in t.items() if n.startswith("ceres-") and v is not None]
        e = t.get("euclidean")
        out.append(f"| {res['problem']} | " + " | ".join(_fmt(t.get(f), ".0f") for f in FORMS)
                   + f" | {_fmt(min(cer) if cer else None, '.0f')}-{_fmt(max(cer) if cer else None, '.0f')} | "
                   + f"{_fmt(e / min(cer) if cer and e and min(cer) > 0 else None, '.2f')} |")
    return out


def _roofline_lines(doc: dict) -> list[str]:
    probs = [r for r in doc.get("problems", []) if r.get("roofline")]
    if not probs:
        return []
    g = doc.get("machine", {}).get("gemm_gflops", {})
    g1 = g.get("1")
    out = ["", f"Roofline (our Euclidean form): analytic flops per LM step (roofline.py), achieved GFLOP/s "
           f"(flops x steps / time in the stage, median over the repeats) and their share of the dense "
           f"GEMM rate measured in this run: {_fmt(g1, '.1f')} GFLOP/s on 1 thread, {_fmt(g.get('2'), '.1f')} "
           f"on 2 (numpy matmul; load {_fmt(doc.get('machine', {}).get('load_1min_at_gemm'), '.1f')}).", "",
           "| problem | unknowns | reduced solver | build Gflop | Schur Gflop | factor Gflop | build GFLOP/s | "
           "Schur GFLOP/s (x GEMM 1t) | factor GFLOP/s (x GEMM 1t) |", "|---|---|---|---|---|---|---|---|---|"]
    for res in probs:
        f = res["roofline"]
        fl, gf = f["flops_per_iteration"], f["gflops"]

        def share(st):
            m = (st or {}).get("median")
            return "-" if m is None else f"{m:.2f}" + (f" ({m / g1:.2f}x)" if g1 else "")

        solver = f["linear_solver"].split(" + ")[-1].split(";")[0] if f["linear_solver"] else "?"
        out.append(f"| {res['problem']} | {f['num_unknowns']} | {solver} | {fl['build'] / 1e9:.3f} | "
                   f"{fl['schur'] / 1e9:.3f} | {_fmt(None if fl['factorisation'] is None else fl['factorisation'] / 1e9)} | "
                   f"{_fmt((gf['build'] or {}).get('median'), '.2f')} | {share(gf['schur'])} | {share(gf['factorisation'])} |")
    return out


def _cold_lines(doc: dict) -> list[str]:
    probs = [r for r in doc.get("problems", []) if r.get("cold_process")]
    if not probs:
        return []
    k = doc.get("settings", {}).get("kernels", {})
    out = ["", f"Cold process vs warm: `python -m polarref ba PROBLEM` in a fresh interpreter (process wall; "
           f"the solve's first LM step, from the solve's start) vs the same first step in the warm bench "
           f"process (euclidean, first full run). A fresh interpreter loads every compiled kernel in "
           f"{_fmt(k.get('cold_process_load_s'))} s; the bench process in {_fmt(k.get('warm_up_s'))} s, once.",
           "", "| problem | cold process wall s | cold solve s | cold first step s | warm first step s | "
           "warm solve s |", "|---|---|---|---|---|---|"]
    for res in probs:
        c = res["cold_process"]
        if "error" in c:
            out.append(f"| {res['problem']} | {c['error']} ||||| ")
            continue
        e = next((x for x in res["rows"] if x["solver"] == "euclidean"), {})
        out.append(f"| {res['problem']} | {c['process_wall_s']:.3f} | {c['solve_wall_s']:.3f} | "
                   f"{_fmt(c['first_iteration_s'])} | {_fmt(e.get('warm_first_step_s'))} | "
                   f"{_fmt((e.get('wall_s') or {}).get('median'))} |")
    return out


def profiles(doc: dict) -> dict:
    """Dolan-More performance profiles per tau: {tau key: {solver: sorted ratios t / t_best
    over the problems (inf where the solver did not reach the target)}}; t_best is the fastest
    solver on that problem at that tau. Solvers that never ran on a problem are left out of it."""
    out = {}
    for res in doc.get("problems", []):
        for key, ts in (res.get("tau_summary") or {}).items():
            times = {n: v for n, v in ts["times_s"].items() if n != "scipy"}
            ran = [x["solver"] for x in res["rows"] if "tau" in x]
            reached = [v for n, v in times.items() if v is not None and n in ran]
            if not reached:
                continue
            best = min(reached)
            for n in ran:
                v = times.get(n)
                out.setdefault(key, {}).setdefault(n, []).append(float("inf") if v is None else v / best)
    return {k: {n: sorted(v) for n, v in d.items()} for k, d in out.items()}


def profiles_figure(doc: dict, path: Path) -> bool:
    """Performance profiles (one panel per tau) as a PNG; False when there is nothing to plot."""
    prof = profiles(doc)
    if not prof:
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_prob = max(len(v) for d in prof.values() for v in d.values())
    fig, axes = plt.subplots(1, len(prof), figsize=(5 * len(prof), 4), sharey=True, squeeze=False)
    for ax, (key, d) in zip(axes[0], prof.items()):
        finite = [r for v in d.values() for r in v if r != float("inf")]
        hi = max(2.0, 1.1 * max(finite))
        for name, ratios in sorted(d.items()):
            xs = [1.0] + [r for r in ratios if r != float("inf")] + [hi]
            ys = [0.0] + [(i + 1) / len(ratios) for i in range(len(xs) - 2)]
            ys.append(ys[-1])
            ax.step(xs, ys, where="post", label=name, lw=2.2 if not name.startswith("ceres-") else 1.2,
                    ls="-" if not name.startswith("ceres-") else "--")
        ax.set_xscale("log")
        ax.set_xlim(1.0, hi)
        ax.set_ylim(0, 1.02)
        ax.set_title(f"tau = {key}")
        ax.set_xlabel("time / fastest solver's time")
    axes[0][0].set_ylabel(f"share of problems (of {n_prob})")
    axes[0][-1].legend(fontsize=6, loc="lower right")
    fig.suptitle("BA performance profiles (Dolan-More), time to best + tau (initial - best)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)
    return True


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
    block = read_block(text, BEGIN, END)
    return None if block is None else block.strip("\n")


def update_readme(readme: Path, doc: dict) -> None:
    try:
        readme.write_text(replace_block(readme.read_text(), BEGIN, END, readme_table(doc)))
    except ValueError as exc:
        raise SystemExit(f"{readme}: {exc}") from exc


def merge_docs(docs: list[dict]) -> dict:
    """One bench document from several runs' bench.json: problems in order (a later run's
    problem replaces an earlier one of the same name), each keeping its own run's provenance,
    machine figures and settings; the top level is the last run's."""
    problems = {}
    for d in docs:
        for r in d.get("problems", []):
            r = dict(r)
            r.setdefault("environment", d.get("environment"))
            r.setdefault("machine", d.get("machine"))
            r.setdefault("settings", d.get("settings"))
            problems.pop(r["problem"], None)
            problems[r["problem"]] = r
    return {**docs[-1], "problems": list(problems.values()), "merged_from": len(docs)}


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "--merge":   # --merge OUT_DIR A/bench.json B/bench.json ...
        out_dir = Path(sys.argv[2])
        merged = merge_docs([json.loads(Path(a).read_text()) for a in sys.argv[3:]])
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "bench.json").write_text(json.dumps(merged, indent=1, default=float))
        profiles_figure(merged, out_dir / "profiles.png")
        (out_dir / "bench.md").write_text(markdown(merged))
        sys.exit(0)
    bench = json.loads(Path(sys.argv[1]).read_text())
    if len(sys.argv) == 3 and sys.argv[2] == "--report":   # bench.md and profiles.png again
        folder = Path(sys.argv[1]).parent
        profiles_figure(bench, folder / "profiles.png")
        (folder / "bench.md").write_text(markdown(bench))
    elif len(sys.argv) == 4 and sys.argv[2] == "--readme":
        update_readme(Path(sys.argv[3]), bench)
    else:
        print(readme_table(bench))
