"""bench.json, bench.md and bench.png of ``polarref bench sfm`` from its cells.

Growth exponents are least-squares slopes of log(time) against log(views) (``t ~ a n^k``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable

import numpy as np

from polarref.bench.records import (BenchSfMSettings, FailedCell, MemoryFit, SfMBench, SfMCell, SfMChecks,
                                    json_default, write)  # noqa: F401 (json_default re-exported)
from polarref.core.atomic import atomic_open, atomic_write
from polarref.core.provenance import collect_record
from polarref.core.status import RunStatus

# the stages each method's wall time is split into (bench.json and the tables)
STAGES = {"ours": ("features", "matching", "verification", "tracks", "mapping"),
          "pycolmap": ("features", "matching", "mapping")}


TARGET_VIEWS = 168            # issue 14: ours <= 1.0x pycolmap's total time on the 168-view comet
TARGET_TIME_RATIO = 1.0
TARGET_TIE_RATIO = 1.5        # ... keeping >= 1.5x pycolmap's tie points
MEMORY_VIEWS, MEMORY_LIMIT_MB = 631, 2048.0   # ours <= 2 GB at 631 views
EXPONENT_RANGE, EXPONENT_LIMIT = (84, 336), 1.3  # issue 13: total-time exponent 84..336 <= 1.3


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


def _series(cells: list[SfMCell], method: str, key: Callable[[SfMCell], float | None]) -> tuple[list[int], list[float]]:
    rows = sorted((c.views, key(c)) for c in cells if c.method == method and c.status == RunStatus.OK)
    rows = [(n, y) for n, y in rows if y is not None]
    return [n for n, _ in rows], [float(y) for _, y in rows]


def _stage_time(stage: str) -> Callable[[SfMCell], float | None]:
    if stage == "total":
        return lambda c: c.total_s
    return lambda c: c.stages_s.get(stage)


def _peak(c: SfMCell) -> float:
    return c.peak_memory_mb.ru_maxrss_mb


TOTAL_RANGE = f"total_{EXPONENT_RANGE[0]}_{EXPONENT_RANGE[1]}"


def _checks_168(o: SfMCell | None, p: SfMCell | None) -> SfMChecks:
    if not (o and p):
        return SfMChecks()
    time_ratio = o.total_s / p.total_s
    tie_ratio = o.tie_points / max(p.tie_points, 1)
    ro, rp = o.rotation_error_deg_mean, p.rotation_error_deg_mean
    return SfMChecks(time_ratio_168=time_ratio, time_ratio_168_ok=time_ratio <= TARGET_TIME_RATIO,
                     # whole-process CPU seconds, steadier when loaded
                     cpu_ratio_168=o.cpu_s / p.cpu_s if o.cpu_s and p.cpu_s else None,
                     tie_ratio_168=tie_ratio, tie_ratio_168_ok=tie_ratio >= TARGET_TIE_RATIO,
                     rotation_error_168_ok=None if ro is None or rp is None else ro <= rp,
                     same_pairs_168=o.pairs_sha256 == p.pairs_sha256)


def summarize(cells: list[SfMCell], settings: BenchSfMSettings, environment, failed: list[FailedCell] = ()) -> SfMBench:
    """The bench of ``cells``: exponents per method and stage, and the done-when checks the cells allow."""
    growth: dict[str, dict[str, float | None]] = {}
    mem: dict[str, MemoryFit] = {}
    for method, stages in STAGES.items():
        g = {s: growth_exponent(*_series(cells, method, _stage_time(s))) for s in (*stages, "total")}
        g[TOTAL_RANGE] = growth_exponent(*_series(cells, method, _stage_time("total")), *EXPONENT_RANGE)
        growth[method] = g
        n, y = _series(cells, method, _peak)
        # the two largest view counts: small runs sit on the fixed floor (imports, numba)
        fit = _power_fit(n[-2:], y[-2:])
        measured = dict(zip(n, y)).get(MEMORY_VIEWS)
        mem[method] = MemoryFit(measured, None if fit is None else fit[0],
                                None if fit is None or measured is not None
                                else math.exp(fit[1]) * MEMORY_VIEWS ** fit[0])
    by = {(c.method, c.views): c for c in cells if c.status == RunStatus.OK}
    k = growth["ours"][TOTAL_RANGE]
    mb = mem["ours"].measured_mb or mem["ours"].extrapolated_mb
    source = ("measured" if mem["ours"].measured_mb else
              "extrapolated (power fit of the two largest measured cells)" if mb else "not tested")
    checks = dataclasses.replace(_checks_168(by.get(("ours", TARGET_VIEWS)), by.get(("pycolmap", TARGET_VIEWS))),
                                 ours_total_exponent_ok=None if k is None else k <= EXPONENT_LIMIT,
                                 ours_memory_631_mb=mb, ours_memory_631_source=source,
                                 ours_memory_631_ok=None if mb is None else mb <= MEMORY_LIMIT_MB)
    return SfMBench(settings, environment, sorted(cells, key=lambda c: (c.views, c.method)), list(failed),
                    growth, mem, checks)


def _fmt(x, spec=".1f") -> str:
    return "n/a" if x is None else format(x, spec)


def markdown(bench: SfMBench) -> str:
    env, st = bench.environment, bench.settings
    lines = ["# `polarref bench sfm`", "",
             f"Scene {st.scene} ({st.preset} preset), pairs: {st.pairing} overlap {st.overlap} (pycolmap imports "
             f"our pair list), {st.threads} thread per method, each cell in its own process. "
             f"Commit {env.git_commit[:10]}{' (dirty)' if env.git_dirty else ''}, "
             f"{env.cpu_count} CPUs ({env.cpu_model}).", "",
             "| method | views | registered | tie points | rot. err (deg) | total (s) | stages (s) | CPU (s) | peak MiB |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in sorted(bench.cells, key=lambda c: (c.views, c.method)):
        times = ", ".join(f"{s} {c.stages_s.get(s, 0):.1f}" for s in (*STAGES[c.method], "ba") if s in c.stages_s)
        lines.append(f"| {c.method} | {c.views} | {c.registered_images} | {c.tie_points} | "
                     f"{_fmt(c.rotation_error_deg_mean, '.3f')} | {c.total_s:.1f} | {times} | {_fmt(c.cpu_s)} | "
                     f"{_peak(c):.0f} |")
    for f in bench.failed:
        lines.append(f"| {f.method} | {f.views} | failed: {f.error} | | | | | | |")
    lines += ["", "Growth exponent k (time ~ views^k, least squares over the cells):", "",
              "| method | " + " | ".join(["stage", "k"]) + " |", "|---|---|---|"]
    for method, g in bench.growth_exponents.items():
        for s, k in g.items():
            lines.append(f"| {method} | {s} | {_fmt(k, '.2f')} |")
    c = bench.checks
    lines += ["", "Checks (issues 13 and 14):", ""]
    if c.time_ratio_168 is not None:
        lines += [f"- {TARGET_VIEWS} views: ours/pycolmap total time {c.time_ratio_168:.2f}x "
                  f"(target <= {TARGET_TIME_RATIO}: {'met' if c.time_ratio_168_ok else 'NOT met'}); "
                  f"tie points {c.tie_ratio_168:.2f}x (target >= {TARGET_TIE_RATIO}: "
                  f"{'met' if c.tie_ratio_168_ok else 'NOT met'}); rotation error ours <= pycolmap: "
                  f"{c.rotation_error_168_ok}; same pairs: {c.same_pairs_168}; CPU-time ratio "
                  f"{_fmt(c.cpu_ratio_168, '.2f')}"]
    else:
        lines.append(f"- {TARGET_VIEWS} views: not tested")
    k = bench.growth_exponents["ours"][TOTAL_RANGE]
    lines.append(f"- ours total-time exponent {EXPONENT_RANGE[0]}-{EXPONENT_RANGE[1]} views: {_fmt(k, '.2f')} "
                 f"(target <= {EXPONENT_LIMIT}: {c.ours_total_exponent_ok})")
    lines.append(f"- ours peak memory at {MEMORY_VIEWS} views: {_fmt(c.ours_memory_631_mb, '.0f')} MiB, "
                 f"{c.ours_memory_631_source} (target <= {MEMORY_LIMIT_MB:.0f}: {c.ours_memory_631_ok})")
    lines += ["", "Settings of each method are stored beside its times in `bench.json` (`method_settings`)."]
    return "\n".join(lines) + "\n"


def plot(bench: SfMBench, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, am) = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    names = list(dict.fromkeys([s for st in STAGES.values() for s in st] + ["total"]))
    color_of = {s: colors[k % len(colors)] for k, s in enumerate(names)}  # one colour per stage name
    views = sorted({c.views for c in bench.cells})
    for m, (method, stages) in enumerate(STAGES.items()):
        style = "-" if method == "ours" else "--"
        for s in (*stages, "total"):
            n, y = _series(bench.cells, method, _stage_time(s))
            if n:
                exp = bench.growth_exponents[method].get(s)
                ax.loglog(n, y, style, marker="o", color=color_of[s], lw=2.5 if s == "total" else 1.2,
                          label=f"{method} {s} (k={_fmt(exp, '.2f')})")
        n, y = _series(bench.cells, method, _peak)
        if n:
            am.loglog(n, y, style, marker="o", color=colors[m], label=method)
    for a in (ax, am):
        a.set_xticks(views, [str(v) for v in views])
        a.minorticks_off()
    ax.set(xlabel="views", ylabel="time (s)", title="time per stage vs views (ours solid, pycolmap dashed)")
    ax.legend(fontsize=6, ncol=2)
    am.axhline(MEMORY_LIMIT_MB, color="grey", lw=0.8, ls=":")
    am.set(xlabel="views", ylabel="peak memory (MiB)", title="peak memory per method process")
    am.legend(fontsize=8)
    fig.tight_layout()
    with atomic_open(path) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)


def write_outputs(out: Path, cells: list[SfMCell], failed: list[FailedCell], settings: BenchSfMSettings) -> SfMBench:
    bench = summarize(cells, settings, collect_record(seeds={"seed": settings.seed}), failed)
    write(bench, out / "bench.json")
    atomic_write(out / "bench.md", markdown(bench))
    if cells:
        plot(bench, out / "bench.png")
    return bench
