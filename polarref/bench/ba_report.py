"""Markdown of a bench.json: the bench table and the README's speed table, from the JSON alone.

The README quotes bench figures only through :func:`readme_table` (run ``python -m
polarref.bench.ba_report reports/bench-ba/bench.json`` and paste), so no number in it can drift
from bench.json. Everything here reads the typed records of :mod:`polarref.bench.ba_records`.
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path

from polarref.ba.parameterization import PARAMS
from polarref.ba.roofline import roof
from polarref.bench.ba_records import BenchDoc, SolverKind, SolverRow, Stats, dumps_json, read_json_doc
from polarref.core.atomic import atomic_write
from polarref.core.markers import read_block, replace_block

FORMS = PARAMS  # the one registry of form names


def _rng(st: Stats | None, digits: int = 3) -> str:
    if st is None or st.median is None:
        return "-"
    if st.n == 1:
        return f"{st.median:.{digits}f}"
    return f"{st.median:.{digits}f} ({st.min:.{digits}f}-{st.max:.{digits}f})"


def _settings(x: SolverRow) -> str:
    s = x.settings
    if x.kind is SolverKind.CERES:
        return (f"ftol {s.get('function_tolerance'):g}, gtol {s.get('gradient_tolerance'):g}, ptol "
                f"{s.get('parameter_tolerance'):g}, max it {s.get('max_num_iterations')}, threads "
                f"{s.get('num_threads_used', s.get('num_threads'))}, {s.get('linear_solver_used', '?')}")
    if x.kind is SolverKind.OURS:
        return (f"ftol {s.get('function_tolerance'):g}, gtol {s.get('gradient_tolerance'):g}, ptol "
                f"{s.get('parameter_tolerance'):g}, max it {s.get('max_iterations')}, BLAS threads "
                f"{s.get('threads')}, {x.full_runs[0].linear_solver}")
    return ", ".join(f"{k} {v}" for k, v in s.items())


def _iters(x: SolverRow) -> str:
    it = x.iterations_to_target
    if not it:
        return "-"
    if it.accepted is None:   # read from a trace: LM steps up to the first one at the target
        return str(it.total)
    return f"{it.total} ({it.accepted}/{it.rejected})"


def _fmt(v, spec=".3f", none="-") -> str:
    return none if v is None else format(v, spec)


def _median(st: Stats | None) -> float | None:
    return None if st is None else st.median


def markdown(doc: BenchDoc) -> str:
    env = doc.environment
    out = [f"Commit {env.git_commit}{' (dirty)' if env.git_dirty else ''}, "
           f"{env.cpu_count} x {env.cpu_model}; settings of every solver in the "
           "table. Costs: 1/2 sum of squared pixel residuals recomputed on every output. Common cost: the "
           "highest final cost among pixel-objective solvers within 1 % of the best; t to target: wall time "
           "of a complete solve limited to the fewest iterations that reach the common cost + 0.1 % "
           "(median (min-max) over the repeats); iterations to target: total (accepted/rejected). "
           "x fastest Ceres: median t to target / the fastest Ceres setting's.", "",
           "| problem | solver | settings | final cost | full-run wall s | iters | t to target s | "
           "iters to target | x fastest Ceres | termination |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for res in doc.problems:
        load = float("nan") if res.load_1min is None else res.load_1min
        name = (f"{res.problem} ({res.num_cameras} cams, {res.num_points} pts, "
                f"{res.num_observations} obs; target {res.target_cost:.6g}; {res.repeat} repeats, "
                f"load {load:.1f}"
                + (f"-{res.load_1min_end:.1f}" if res.load_1min_end is not None else "")
                + ("; t to target from the full runs' iteration traces"
                   if res.time_to_target_method == "iteration traces" else "") + ")")
        for x in res.rows:
            if x.error is not None:
                out.append(f"| {name} | {x.solver} | {x.error} ||||||||")
                name = ""
                continue
            ratio = x.ratio_to_fastest_ceres
            out.append(f"| {name} | {x.solver} | {_settings(x)} | {x.final_cost:.6g} | {_rng(x.wall_s)} | "
                       f"{x.iterations} | {_rng(x.time_to_target_s)} | {_iters(x)} | "
                       f"{'-' if ratio is None else f'{ratio:.2f}'} | {x.full_runs[0].termination} |")
            name = ""
    out += (_scope_lines(doc) + _per_iteration_lines(doc) + _own_cost_lines(doc) + _tau_lines(doc) + _memory_lines(doc)
            + _roofline_lines(doc) + _bandwidth_lines(doc) + _cold_lines(doc))
    return "\n".join(out) + "\n"


def _per_iteration_lines(doc: BenchDoc) -> list[str]:
    """Our forms' seconds per accepted iteration (full runs, median) and the ratio to the
    Euclidean form's, side by side per problem; empty for a bench.json without them."""
    probs = [r for r in doc.problems if any(x.s_per_accepted_iteration is not None for x in r.rows)]
    if not probs:
        return []
    out = ["", "Per-iteration cost (our forms, same problem, same run, 1 thread): (full-run wall - "
           "setup) / accepted iterations, median over the repeats, in ms; ratio to the Euclidean form.", "",
           "| problem | " + " | ".join(FORMS) + " |", "|---|" + "---|" * len(FORMS)]
    for res in probs:
        cells = []
        for f in FORMS:
            x = res.row(f)
            v = None if x is None else _median(x.s_per_accepted_iteration)
            ratio = None if x is None else x.per_iteration_vs_euclidean
            cells.append("-" if v is None else f"{1e3 * v:.1f} ({ratio:.2f}x)" if ratio else f"{1e3 * v:.1f}")
        out.append(f"| {res.problem} | " + " | ".join(cells) + " |")
    return out


def _own_cost_lines(doc: BenchDoc) -> list[str]:
    """Euclidean vs Ceres to the best Ceres final cost, where the common target was not usable."""
    probs = [r for r in doc.problems if r.ceres_own_cost]
    if not probs:
        return []
    out = ["", "Euclidean vs Ceres to Ceres' own best final cost (+0.1 %), where our Euclidean form or "
           "no Ceres setting reached the common target:", "",
           "| problem | target | euclidean t s | fastest Ceres (t s) | ratio |", "|---|---|---|---|---|"]
    for res in probs:
        o = res.ceres_own_cost
        e = o.rows["euclidean"].time_to_target_s
        f = o.fastest_ceres
        ft = o.rows[f].time_to_target_s if f else None
        r = o.euclidean_ratio_to_fastest_ceres
        out.append(f"| {res.problem} | {o.target_cost:.6g} | {_rng(e)} | "
                   f"{f or 'none'} ({_rng(ft)}) | {'-' if r is None else f'{r:.2f}x'} |")
    return out


def _tau_lines(doc: BenchDoc) -> list[str]:
    """Per problem and tau: each solver's time to best + tau (initial - best) and its ratio to
    the fastest Ceres setting's (medians over the repeats' full-run traces)."""
    probs = [r for r in doc.problems if r.tau_summary]
    if not probs:
        return []
    out = ["", "Time to the tau targets best + tau (initial - best) (rootBA's rule; best: the lowest final "
           "pixel cost of any pixel-objective solver), read from the full runs' iteration traces, median s "
           "(x the fastest Ceres setting at that tau); `-`: not reached, or not a pixel objective (polar, angular).",
           "", "| problem | solver | tau 1e-2 | tau 1e-3 | tau 1e-4 | iterations (1e-2/1e-3/1e-4) |",
           "|---|---|---|---|---|---|"]
    for res in probs:
        name = res.problem
        for x in res.rows:
            if x.tau is None:
                continue
            cells, its = [], []
            for k, summary in res.tau_summary.items():
                tt = x.tau.get(k)
                t = None if tt is None else tt.time_s.median
                r = summary.ratio_to_fastest_ceres.get(x.solver)
                cells.append("-" if t is None else f"{t:.3f}" + (f" ({r:.2f}x)" if r is not None else ""))
                its.append(_fmt(None if tt is None else tt.iterations, "d"))
            out.append(f"| {name} | {x.solver} | " + " | ".join(cells) + f" | {'/'.join(its)} |")
            name = ""
    return out


def _memory_lines(doc: BenchDoc) -> list[str]:
    probs = [r for r in doc.problems if any(x.peak_rss_mib is not None for x in r.rows)]
    if not probs:
        return []
    out = ["", "Peak memory added by one full solve (forked child: resident high-water mark minus the "
           "resident set at the fork), MiB; ratio: our Euclidean form / the leanest Ceres setting.", "",
           "| problem | " + " | ".join(FORMS) + " | Ceres (min-max over settings) | euclidean / min Ceres |",
           "|---|" + "---|" * (len(FORMS) + 2)]
    for res in probs:
        t = {x.solver: x.peak_rss_mib for x in res.rows}
        cer = [v for n, v in t.items() if n.startswith("ceres-") and v is not None]
        e = t.get("euclidean")
        out.append(f"| {res.problem} | " + " | ".join(_fmt(t.get(f), ".0f") for f in FORMS)
                   + f" | {_fmt(min(cer) if cer else None, '.0f')}-{_fmt(max(cer) if cer else None, '.0f')} | "
                   + f"{_fmt(e / min(cer) if cer and e and min(cer) > 0 else None, '.2f')} |")
    return out


def _roofline_lines(doc: BenchDoc) -> list[str]:
    probs = [r for r in doc.problems if r.roofline]
    if not probs:
        return []
    m = doc.machine
    g = {} if m is None else m.gemm_gflops
    g1 = g.get("1")
    out = ["", f"Roofline (our Euclidean form): analytic flops per LM step (roofline.py), achieved GFLOP/s "
           f"(flops x steps / time in the stage, median over the repeats) and their share of the dense "
           f"GEMM rate measured in this run: {_fmt(g1, '.1f')} GFLOP/s on 1 thread, {_fmt(g.get('2'), '.1f')} "
           f"on 2 (numpy matmul; load {_fmt(None if m is None else m.load_1min_at_gemm, '.1f')}).", "",
           "| problem | unknowns | reduced solver | build Gflop | Schur Gflop | factor Gflop | build GFLOP/s | "
           "Schur GFLOP/s (x GEMM 1t) | factor GFLOP/s (x GEMM 1t) |", "|---|---|---|---|---|---|---|---|---|"]

    def share(st):
        v = _median(st)
        return "-" if v is None else f"{v:.2f}" + (f" ({v / g1:.2f}x)" if g1 else "")

    for res in probs:
        f = res.roofline
        fl, gf = f.flops_per_iteration, f.gflops
        solver = f.linear_solver.split(" + ")[-1].split(";")[0] if f.linear_solver else "?"
        out.append(f"| {res.problem} | {f.num_unknowns} | {solver} | {fl.build / 1e9:.3f} | "
                   f"{fl.schur / 1e9:.3f} | {_fmt(None if fl.factorisation is None else fl.factorisation / 1e9)} | "
                   f"{_fmt(_median(gf.build), '.2f')} | {share(gf.schur)} | {share(gf.factorisation)} |")
    return out


def _scope_lines(doc: BenchDoc) -> list[str]:
    """Where Ceres did not finish in its cap (the done-when's scope limit), and the machine load
    at the start and end of every first full run (benches that recorded it)."""
    out = [f"Scope, {r.problem}: {r.ceres_scope}." for r in doc.problems if r.ceres_scope]
    loads = [(r.problem, x.solver, x.full_runs[0]) for r in doc.problems for x in r.rows
             if x.full_runs and x.full_runs[0].load_1min is not None]
    if loads:
        out += ["", "Machine load (1-minute average) at the start and end of each solver's first full run: "
                "the machine is shared, so its times are indicative only.", "",
                "| problem | solver | load start | load end |", "|---|---|---|---|"]
        out += [f"| {p} | {n} | {run.load_1min:.1f} | {_fmt(run.load_1min_end, '.1f')} |" for p, n, run in loads]
    return ([""] if out and out[0] else []) + out


def _bandwidth_lines(doc: BenchDoc) -> list[str]:
    """The Schur stage against both roofs (roofline.py's bytes models); only for a bench that
    measured the memory bandwidth."""
    m = doc.machine
    probs = [r for r in doc.problems if r.roofline and r.roofline.schur_bytes]
    if m is None or m.triad_gbs is None or not probs:
        return []
    g1, bw = m.gemm_gflops.get("1"), m.triad_gbs
    out = ["", f"Schur stage against the bandwidth roof: arithmetic intensity (Schur flops / bytes per LM "
           f"step, roofline.py: compulsory = every array once, per update = each entry pair's 6x6 block "
           f"read and written from memory) x the STREAM triad bandwidth measured in this run, "
           f"{bw:.1f} GB/s on 1 thread (load {_fmt(m.load_1min_at_triad, '.1f')}); roof = min(GEMM 1t, "
           f"intensity x bandwidth). Achieved: the Schur GFLOP/s of the table above.", "",
           "| problem | entry pairs | pair blocks | MB compulsory / per update | flop/B compulsory / per update | "
           "roof GFLOP/s compulsory / per update | achieved GFLOP/s | x roof compulsory / per update | x GEMM 1t |",
           "|---|---|---|---|---|---|---|---|---|"]
    for res in probs:
        f = res.roofline
        by, flops, got = f.schur_bytes, f.flops_per_iteration.schur, _median(f.gflops.schur)
        ai = (flops / by.compulsory, flops / by.per_update)
        roofs = tuple(roof(a, bw, g1) if g1 else a * bw for a in ai)
        x = "-" if got is None else f"{got / roofs[0]:.2f} / {got / roofs[1]:.2f}"
        out.append(f"| {res.problem} | {by.entry_pairs} | {by.pair_blocks} | {by.compulsory / 1e6:.1f} / "
                   f"{by.per_update / 1e6:.1f} | {ai[0]:.3f} / {ai[1]:.3f} | {roofs[0]:.2f} / {roofs[1]:.2f} | "
                   f"{_fmt(got, '.2f')} | {x} | {'-' if got is None or not g1 else f'{got / g1:.2f}'} |")
    return out


def _cold_lines(doc: BenchDoc) -> list[str]:
    probs = [r for r in doc.problems if r.cold_process]
    if not probs:
        return []
    k = doc.settings.kernels
    out = ["", f"Cold process vs warm: `python -m polarref ba PROBLEM` in a fresh interpreter (process wall; "
           f"the solve's first LM step, from the solve's start) vs the same first step in the warm bench "
           f"process (euclidean, first full run). A fresh interpreter loads every compiled kernel in "
           f"{_fmt(k.cold_process_load_s)} s; the bench process in {_fmt(k.warm_up_s)} s, once.",
           "", "| problem | cold process wall s | cold solve s | cold first step s | warm first step s | "
           "warm solve s |", "|---|---|---|---|---|---|"]
    for res in probs:
        c = res.cold_process
        if c.error is not None:
            out.append(f"| {res.problem} | {c.error} ||||| ")
            continue
        e = res.row("euclidean")
        out.append(f"| {res.problem} | {c.process_wall_s:.3f} | {c.solve_wall_s:.3f} | "
                   f"{_fmt(c.first_iteration_s)} | {_fmt(None if e is None else e.warm_first_step_s)} | "
                   f"{_fmt(None if e is None else _median(e.wall_s))} |")
    return out


@dataclass(frozen=True)
class Profile:
    """Dolan-More performance profile at one tau: per solver the sorted ratios t / t_best over the
    problems (inf where the solver did not reach the target); t_best is the fastest solver on
    that problem at that tau. Solvers that never ran on a problem are left out of it."""

    tau_key: str
    ratios: dict[str, list[float]]


def profiles(doc: BenchDoc) -> tuple[Profile, ...]:
    """The performance profile of every tau the problems have, in their order."""
    acc: dict[str, dict[str, list[float]]] = {}
    for res in doc.problems:
        for key, ts in res.tau_summary.items():
            times = {n: v for n, v in ts.times_s.items() if n != "scipy"}
            ran = [x.solver for x in res.rows if x.tau is not None]
            reached = [v for n, v in times.items() if v is not None and n in ran]
            if not reached:
                continue
            best = min(reached)
            for n in ran:
                v = times.get(n)
                acc.setdefault(key, {}).setdefault(n, []).append(float("inf") if v is None else v / best)
    return tuple(Profile(k, {n: sorted(v) for n, v in d.items()}) for k, d in acc.items())


def profiles_figure(doc: BenchDoc, path: Path) -> bool:
    """Performance profiles (one panel per tau) as a PNG; False when there is nothing to plot."""
    prof = profiles(doc)
    if not prof:
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_prob = max(len(v) for p in prof for v in p.ratios.values())
    fig, axes = plt.subplots(1, len(prof), figsize=(5 * len(prof), 4), sharey=True, squeeze=False)
    for ax, p in zip(axes[0], prof):
        finite = [r for v in p.ratios.values() for r in v if r != float("inf")]
        hi = max(2.0, 1.1 * max(finite))
        for name, ratios in sorted(p.ratios.items()):
            xs = [1.0] + [r for r in ratios if r != float("inf")] + [hi]
            ys = [0.0] + [(i + 1) / len(ratios) for i in range(len(xs) - 2)]
            ys.append(ys[-1])
            ax.step(xs, ys, where="post", label=name, lw=2.2 if not name.startswith("ceres-") else 1.2,
                    ls="-" if not name.startswith("ceres-") else "--")
        ax.set_xscale("log")
        ax.set_xlim(1.0, hi)
        ax.set_ylim(0, 1.02)
        ax.set_title(f"tau = {p.tau_key}")
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


def _readme_cell(row: SolverRow | None, target: float | None) -> str:
    """Ratio to the fastest Ceres; else why there is none (a form may reach a target no Ceres
    setting reaches, or stop above it: the polar objective is not the pixel cost)."""
    if row is None:
        return "did not reach"
    r = row.ratio_to_fastest_ceres
    if r is not None:
        return f"{r:.2f}x"
    t = _median(row.time_to_target_s)
    if row.reached_target and t is not None:
        return f"{t:.3f} s (no Ceres setting reached it)"
    cost = row.final_cost
    if target and cost is not None and cost > target:
        return f"did not reach (stops {100.0 * (cost / target - 1.0):+.1f}%)"
    return "did not reach"


def readme_table(doc: BenchDoc) -> str:
    """Per problem: fastest Ceres setting and our forms' time-to-target ratios against it."""
    out = ["| problem | fastest Ceres setting (t to target, s) | euclidean | parallax | polar | angular |",
           "|---|---|---|---|---|---|"]
    for res in doc.problems:
        f = res.fastest_ceres
        cells = [_readme_cell(res.row(p), res.target_cost) for p in FORMS]
        head = "none reached the target" if f is None else f"{f} ({res.fastest_ceres_time_to_target_s:.3f})"
        out.append(f"| {res.problem} | {head} | " + " | ".join(cells) + " |")
    out += _per_iteration_lines(doc) + _own_cost_lines(doc)
    return "\n".join(out) + "\n"


BEGIN = "<!-- bench-table: generated from reports/bench-ba/bench.json, do not edit by hand -->"
END = "<!-- /bench-table -->"


def readme_block(text: str) -> str | None:
    """The generated table between the README's markers (None without markers)."""
    block = read_block(text, BEGIN, END)
    return None if block is None else block.strip("\n")


def update_readme(readme: Path, doc: BenchDoc) -> None:
    try:
        readme.write_text(replace_block(readme.read_text(), BEGIN, END, readme_table(doc)))
    except ValueError as exc:
        raise SystemExit(f"{readme}: {exc}") from exc


def merge_docs(docs: list[BenchDoc]) -> BenchDoc:
    """One bench document from several runs' bench.json: problems in order (a later run's
    problem replaces an earlier one of the same name), each keeping its own run's provenance,
    machine figures and settings; the top level is the last run's."""
    problems = {}
    for d in docs:
        for r in d.problems:
            r = dataclasses.replace(r, environment=r.environment or d.environment,
                                    machine=r.machine or d.machine, settings=r.settings or d.settings)
            problems.pop(r.problem, None)
            problems[r.problem] = r
    return dataclasses.replace(docs[-1], problems=tuple(problems.values()), merged_from=len(docs))


def write_report(doc: BenchDoc, out_dir: Path) -> None:
    """bench.json, profiles.png and bench.md of ``doc`` in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write(out_dir / "bench.json", dumps_json(doc))
    profiles_figure(doc, out_dir / "profiles.png")
    atomic_write(out_dir / "bench.md", markdown(doc))


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "--merge":   # --merge OUT_DIR A/bench.json B/bench.json ...
        write_report(merge_docs([read_json_doc(Path(a)) for a in sys.argv[3:]]), Path(sys.argv[2]))
        sys.exit(0)
    bench = read_json_doc(Path(sys.argv[1]))
    if len(sys.argv) == 3 and sys.argv[2] == "--report":   # bench.md and profiles.png again
        folder = Path(sys.argv[1]).parent
        profiles_figure(bench, folder / "profiles.png")
        (folder / "bench.md").write_text(markdown(bench))
    elif len(sys.argv) == 4 and sys.argv[2] == "--readme":
        update_readme(Path(sys.argv[3]), bench)
    else:
        print(readme_table(bench))
