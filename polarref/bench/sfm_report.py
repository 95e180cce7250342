"""bench.json, bench.md and bench.png of ``polarref bench sfm`` from its cells.

Growth exponents are least-squares slopes of log(time) against log(views) (``t ~ a n^k``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Callable

import numpy as np

from polarref.bench.records import (STAGES, BenchSfMSettings, FailedCell, MemoryFit, SfMBench, SfMCell,  # noqa: F401
                                    SfMChecks, SfMRow, Spread, json_default, variant_label, write)  # (STAGES, json_default re-exported)
from polarref.core.atomic import atomic_open, atomic_write
from polarref.core.provenance import collect_record


TARGET_VIEWS = 168            # issue 34: ours <= 1.0x pycolmap's total time on the 168-view comet, both on 2 cores
TARGET_TIME_RATIO = 1.0
TARGET_TIE_RATIO = 1.5        # ... keeping >= 1.5x pycolmap's tie points by the same rule
MEMORY_VIEWS, MEMORY_LIMIT_MB = 631, 2048.0   # ours <= 2 GB at 631 views
EXPONENT_RANGE, EXPONENT_LIMIT = (84, 336), 1.3  # issue 13: total-time exponent 84..336 <= 1.3
TOTAL_RANGE = f"total_{EXPONENT_RANGE[0]}_{EXPONENT_RANGE[1]}"


def growth_exponent(views, values, lo: float | None = None, hi: float | None = None) -> float | None:
    """Slope k of the least-squares line log(value) = log(a) + k log(views), over views in [lo, hi].

    None with fewer than two distinct view counts (or non-positive values) in the range.
    """
    v = np.asarray(views, np.float64)
    y = np.asarray(values, np.float64)
    keep = np.isfinite(y) & (y > 0) & (v > 0)
    if lo is not None:
        keep &= v >= lo
    if hi is not None:
        keep &= v <= hi
    if len(np.unique(v[keep])) < 2:
        return None
    return float(np.polyfit(np.log(v[keep]), np.log(y[keep]), 1)[0])


def _power_fit(views, values) -> tuple[float, float] | None:
    v, y = np.asarray(views, float), np.asarray(values, float)
    if len(np.unique(v)) < 2:
        return None
    k, loga = np.polyfit(np.log(v), np.log(y), 1)
    return float(k), float(loga)


def spread(values) -> Spread | None:
    v = [float(x) for x in values if x is not None]
    return Spread(float(np.median(v)), min(v), max(v), len(v)) if v else None


def _stage_peak(c: SfMCell) -> dict[str, float]:
    return {s.stage: (s.peak_rss_mb or 0.0) + (s.workers_peak_rss_mb or 0.0) for s in c.stages
            if s.peak_rss_mb is not None or s.workers_peak_rss_mb is not None}


def _cell_peak(c: SfMCell) -> float:
    """The cell process's peak: its ru_maxrss, or its largest stage peak where that is higher (cells
    of commit 836fa6a reset the kernel's peak mark, and with it ru_maxrss, at each stage)."""
    return max([c.run.peak_rss_mb] + [s.peak_rss_mb for s in c.stages if s.peak_rss_mb is not None])


def _row(group: list[SfMCell]) -> SfMRow:
    c0 = group[0]
    method = c0.run.method
    stages = [s for s in (*STAGES[method], "ba") if any(s in c.run.stage_runtime_s for c in group)]
    peaks: dict[str, float] = {}
    for c in group:
        for stage, mb in _stage_peak(c).items():
            peaks[stage] = max(peaks.get(stage, 0.0), mb)
    rot = spread(c.rotation_error_deg_mean for c in group)
    return SfMRow(c0.label, method, c0.parallel, c0.views, spread(c.total_s for c in group),
                  spread(c.cpu_s for c in group),
                  {s: spread(c.run.stage_runtime_s.get(s, 0.0) for c in group) for s in stages},
                  peaks, max(_cell_peak(c) for c in group), c0.run.registered,
                  c0.tie_points_2v, c0.tie_points_3v, None if rot is None else rot.median,
                  spread(c.load_average[0] for c in group if c.load_average))


def rows_of(cells: list[SfMCell]) -> list[SfMRow]:
    groups: dict[tuple[int, str], list[SfMCell]] = {}
    for c in cells:
        if c.run.ok:
            groups.setdefault((c.views, c.label), []).append(c)
    return [_row(sorted(g, key=lambda c: c.repeat)) for _, g in sorted(groups.items())]


def _series(rows: list[SfMRow], label: str, key: Callable[[SfMRow], float | None]) -> tuple[list[int], list[float]]:
    got = [(r.views, key(r)) for r in rows if r.label == label]
    got = [(n, y) for n, y in got if y is not None]
    return [n for n, _ in got], [float(y) for _, y in got]


def _stage_time(stage: str) -> Callable[[SfMRow], float | None]:
    if stage == "total":
        return lambda r: r.total_s.median
    return lambda r: r.stages_s[stage].median if stage in r.stages_s else None


def _pair(by: dict, views: int, parallel: int) -> tuple[SfMRow | None, SfMRow | None]:
    return by.get((views, variant_label("ours", parallel))), by.get((views, variant_label("pycolmap", parallel)))


def _checks_168(by: dict[tuple[int, str], SfMRow], cells: list[SfMCell]) -> SfMChecks:
    o2, p2 = _pair(by, TARGET_VIEWS, 2)
    o1, p1 = _pair(by, TARGET_VIEWS, 1)
    o, p = (o2, p2) if o2 and p2 else (o1, p1)
    if not (o and p):
        return SfMChecks()
    time_ratio = o2.total_s.median / p2.total_s.median if o2 and p2 else None
    tie = o.tie_points_2v / max(p.tie_points_2v, 1) if o.tie_points_2v is not None and p.tie_points_2v else None
    tie3 = o.tie_points_3v / max(p.tie_points_3v, 1) if o.tie_points_3v is not None and p.tie_points_3v else None
    speedup = {m: one.total_s.median / two.total_s.median
               for m, one, two in (("ours", o1, o2), ("pycolmap", p1, p2)) if one and two}
    sha = {c.pairs_sha256 for c in cells if c.views == TARGET_VIEWS and c.run.ok}
    return SfMChecks(
        time_ratio_168=time_ratio, time_ratio_168_ok=None if time_ratio is None else time_ratio <= TARGET_TIME_RATIO,
        time_ratio_168_1core=o1.total_s.median / p1.total_s.median if o1 and p1 else None,
        cpu_ratio_168=o.cpu_s.median / p.cpu_s.median if o.cpu_s and p.cpu_s else None,
        tie_ratio_168=tie, tie_ratio_168_ok=None if tie is None else tie >= TARGET_TIE_RATIO, tie_ratio_168_3v=tie3,
        rotation_error_168_ok=(None if o.rotation_error_deg is None or p.rotation_error_deg is None
                               else o.rotation_error_deg <= p.rotation_error_deg),
        same_pairs_168=len(sha) == 1, speedup_168=speedup)


def summarize(cells: list[SfMCell], settings: BenchSfMSettings, environment, failed: list[FailedCell] = ()) -> SfMBench:
    """The bench of ``cells``: rows over repeats, exponents per variant and stage, the checks the cells allow."""
    rows = rows_of(cells)
    growth: dict[str, dict[str, float | None]] = {}
    mem: dict[str, MemoryFit] = {}
    for label in dict.fromkeys(r.label for r in rows):
        method = next(r.method for r in rows if r.label == label)
        g = {s: growth_exponent(*_series(rows, label, _stage_time(s))) for s in (*STAGES[method], "total")}
        g[TOTAL_RANGE] = growth_exponent(*_series(rows, label, _stage_time("total")), *EXPONENT_RANGE)
        growth[label] = g
        n, y = _series(rows, label, lambda r: r.peak_mb)
        # the two largest view counts: small runs sit on the fixed floor (imports, numba)
        fit = _power_fit(n[-2:], y[-2:])
        measured = dict(zip(n, y)).get(MEMORY_VIEWS)
        mem[label] = MemoryFit(measured, None if fit is None else fit[0],
                               None if fit is None or measured is not None
                               else math.exp(fit[1]) * MEMORY_VIEWS ** fit[0])
    by = {(r.views, r.label): r for r in rows}
    ours = variant_label("ours", 1)
    k = growth.get(ours, {}).get(TOTAL_RANGE)
    fit = mem.get(ours, MemoryFit(None, None, None))
    mb = fit.measured_mb or fit.extrapolated_mb
    source = ("measured" if fit.measured_mb else
              "extrapolated (power fit of the two largest measured cells)" if mb else "not tested")
    checks = dataclasses.replace(_checks_168(by, cells),
                                 ours_total_exponent_ok=None if k is None else k <= EXPONENT_LIMIT,
                                 ours_memory_631_mb=mb, ours_memory_631_source=source,
                                 ours_memory_631_ok=None if mb is None else mb <= MEMORY_LIMIT_MB)
    return SfMBench(settings, environment, sorted(cells, key=lambda c: (c.views, c.label, c.repeat)), list(failed),
                    rows, growth, mem, checks, tuple(os.getloadavg()))


def _fmt(x, spec=".1f") -> str:
    return "n/a" if x is None else format(x, spec)


def _sp(x: Spread | None, spec=".1f") -> str:
    if x is None:
        return "n/a"
    return format(x.median, spec) if x.n == 1 else f"{x.median:{spec}} [{x.low:{spec}}-{x.high:{spec}}]"


def _ratio_line(c: SfMChecks) -> str:
    return (f"- {TARGET_VIEWS} views, both on 2 cores: ours/pycolmap total time {_fmt(c.time_ratio_168, '.2f')}x "
            f"(target <= {TARGET_TIME_RATIO}: {_met(c.time_ratio_168_ok)}; indicative only, see the load "
            f"averages); on 1 core {_fmt(c.time_ratio_168_1core, '.2f')}x; CPU-time ratio "
            f"{_fmt(c.cpu_ratio_168, '.2f')}; tie points (>= 2 views) {_fmt(c.tie_ratio_168, '.2f')}x (target >= "
            f"{TARGET_TIE_RATIO}: {_met(c.tie_ratio_168_ok)}), (>= 3 views) {_fmt(c.tie_ratio_168_3v, '.2f')}x; "
            f"rotation error ours <= pycolmap: {c.rotation_error_168_ok}; same pairs: {c.same_pairs_168}; "
            "speed-up 2 vs 1 core: " + (", ".join(f"{m} {v:.2f}x" for m, v in c.speedup_168.items()) or "n/a"))


def _met(ok: bool | None) -> str:
    return "not tested" if ok is None else "met" if ok else "NOT met"


def markdown(bench: SfMBench) -> str:
    env, st = bench.environment, bench.settings
    lines = ["# `polarref bench sfm`", "",
             f"Scene {st.scene} ({st.preset} preset), pairs: {st.pairing} overlap {st.overlap} (pycolmap imports "
             f"our pair list), SIFT budget {st.max_num_features} per image for both; ours with 1 and 2 "
             "front-end worker threads (`-1w`, `-2w`), pycolmap on 1 and 2 threads (`-1t`, `-2t`); each cell in its own "
             f"process. Commit {env.git_commit[:10]}{' (dirty)' if env.git_dirty else ''}, "
             f"{env.cpu_count} CPUs ({env.cpu_model}).", "",
             "Times are medians over the repeats with [min-max]; the machine is shared, so wall times and "
             "their ratios are indicative (load average at each cell's start in the last column). "
             "Tie points by one rule for both: 3D points seen by >= 2 (>= 3) registered images.", "",
             "| variant | views | registered | tie pts >= 2 | tie pts >= 3 | rot. err (deg) | total (s) | "
             "stages (s) | CPU (s) | peak MiB per stage | peak MiB | load 1 min |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in bench.rows:
        times = ", ".join(f"{s} {_sp(v)}" for s, v in r.stages_s.items())
        peaks = ", ".join(f"{s} {v:.0f}" for s, v in r.stage_peak_mb.items() if s in (*STAGES[r.method], "metrics"))
        lines.append(f"| {r.label} | {r.views} | {r.registered_images} | {_fmt(r.tie_points_2v, 'd')} | "
                     f"{_fmt(r.tie_points_3v, 'd')} | {_fmt(r.rotation_error_deg, '.3f')} | {_sp(r.total_s)} | "
                     f"{times} | {_sp(r.cpu_s)} | {peaks or 'n/a'} | {r.peak_mb:.0f} | {_sp(r.load_average_1min, '.2f')} |")
    for f in bench.failed:
        lines.append(f"| {variant_label(f.run.method, f.parallel)} | {f.views} | failed (repeat {f.repeat}): "
                     f"{f.run.reason} | | | | | | | | | |")
    lines += ["", "Growth exponent k (time ~ views^k, least squares over the view counts):", "",
              "| variant | stage | k |", "|---|---|---|"]
    for label, g in bench.growth_exponents.items():
        for s, k in g.items():
            if k is not None:
                lines.append(f"| {label} | {s} | {k:.2f} |")
    c = bench.checks
    lines += ["", "Checks (issues 13, 14 and 34):", ""]
    lines.append(_ratio_line(c) if c.tie_ratio_168 is not None else f"- {TARGET_VIEWS} views: not tested")
    k = bench.growth_exponents.get(variant_label("ours", 1), {}).get(TOTAL_RANGE)
    lines.append(f"- ours total-time exponent {EXPONENT_RANGE[0]}-{EXPONENT_RANGE[1]} views: {_fmt(k, '.2f')} "
                 f"(target <= {EXPONENT_LIMIT}: {c.ours_total_exponent_ok})")
    lines.append(f"- ours peak memory at {MEMORY_VIEWS} views: {_fmt(c.ours_memory_631_mb, '.0f')} MiB, "
                 f"{c.ours_memory_631_source} (target <= {MEMORY_LIMIT_MB:.0f}: {c.ours_memory_631_ok})")
    lines += ["", "The settings of each method are stored beside its times in every cell and in `bench.json` "
              "(`method_settings`: budget, image size, threads or workers, two-view tracks, pairing, and every "
              "option by name)."]
    return "\n".join(lines) + "\n"


def plot(bench: SfMBench, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, am) = plt.subplots(1, 2, figsize=(11, 4.2))
    views = sorted({r.views for r in bench.rows})
    for label in dict.fromkeys(r.label for r in bench.rows):
        style = "-" if label.startswith("ours") else "--"
        rows = [r for r in bench.rows if r.label == label]
        n = [r.views for r in rows]
        med = np.array([r.total_s.median for r in rows])
        err = np.array([[r.total_s.median - r.total_s.low for r in rows], [r.total_s.high - r.total_s.median for r in rows]])
        ax.errorbar(n, med, yerr=err, fmt=style, marker="o", capsize=3, label=label)
        am.plot(n, [r.peak_mb for r in rows], style, marker="o", label=label)
    for a in (ax, am):
        a.set_xscale("log")
        a.set_xticks(views, [str(v) for v in views])
        a.minorticks_off()
    ax.set_yscale("log")
    ax.set(xlabel="views", ylabel="total time (s)", title="total time, median and range over repeats")
    ax.legend(fontsize=8)
    am.set(xlabel="views", ylabel="peak memory (MiB)", title="peak memory per cell process")
    am.legend(fontsize=8)
    fig.tight_layout()
    with atomic_open(path) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)


def write_outputs(out: Path, cells: list[SfMCell], failed: list[FailedCell], settings: BenchSfMSettings) -> SfMBench:
    bench = summarize(cells, settings, collect_record(seeds={"seed": settings.seed}), failed)
    write(bench, out / "bench.json")
    atomic_write(out / "bench.md", markdown(bench))
    if bench.rows:
        plot(bench, out / "bench.png")
    return bench
