"""Where the time of our SfM goes at twin scale: stage costs on sub-blocks, a fitted scaling model,
and the extrapolation to the twins' view counts (issue 34).

A sub-block of a UAV twin (:mod:`synth.subblock`: the twin's mesh, camera, GSD and pairing rule)
is run through our pipeline at a few sizes (``scripts/twin_scaling.py``); each run is a
:class:`BlockRun`. Per stage, the wall time is fitted as ``a * x^b`` by least squares on logs,
where ``x`` is the stage's natural size: the views for features, the image pairs for matching and
verification, the pairs for tracks (their input is the verified matches), the views for mapping and BA (less
its first call, which loads or compiles the numba kernels: a constant per process). With two sizes
the fit is exact; it is a local exponent, not a law. The pairs at a twin's full size come from its
pairing rule (:func:`pairs_per_view` times the views: spatial k-nearest plus sequential pairs give
a bounded number per view), so the extrapolation only needs the views.

Timings come from a shared, loaded machine: the records carry the load averages before and
after, and every figure here is indicative.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.provenance import Provenance
from polarref.sfm.stages import StageCost

FORMAT = "polarref-twin-scaling/1"
# stage -> the size its cost follows (see the module docstring)
DRIVERS = {"features": "views", "matching": "pairs", "verification": "pairs", "tracks": "pairs",
           "mapping (excl. BA)": "views", "ba": "views"}
FRONT_END = ("features", "matching", "verification", "tracks")   # the same for every BA form
TWIN_VIEWS = {"mappilot": 493, "rosetta": 631, "poets-park": 857}


@dataclass(frozen=True)
class BAStats:
    """The mapper's bundle adjustments of one run, by kind."""

    local_runs: int
    local_s: float
    global_runs: int
    global_s: float
    final_global_s: float          # the last global BA (the whole model)
    final_global_iterations: int
    # the mapper's first BA (two views): almost all of it loads or compiles the numba kernels, a
    # cost per process, not per view (None: not recorded; `twin_scaling.py annotate` adds it from
    # the run's metrics.json)
    first_s: float | None = None


@dataclass(frozen=True)
class BlockRun:
    """One sub-block through our pipeline with one BA form (``scripts/twin_scaling.py``)."""

    label: str                      # the block (synth.subblock.SubBlock.label)
    ba: str
    views: int
    pairs: int                      # image pairs matched (the twin's pairing rule on the block's priors)
    verified_pairs: int
    tracks: int
    observations: int               # observations of the final model's tie points
    registered: int
    tie_points: int
    rotation_error_deg: float | None
    stages: tuple[StageCost, ...]   # wall, CPU, peak memory; "ba" is part of "mapping"
    ba_stats: BAStats
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]
    threads: int                    # SfMConfig.threads (front end; 0 = every core)
    wall_s: float
    environment: Provenance

    def wall(self, stage: str) -> float | None:
        """Wall seconds of ``stage`` (None: not run or read from the cache); "mapping (excl. BA)" is
        mapping minus its BA."""
        by = {s.stage: s for s in self.stages}
        if stage == "mapping (excl. BA)":
            m, b = by.get("mapping"), by.get("ba")
            return None if m is None else max(0.0, m.wall_s - (b.wall_s if b else 0.0))
        s = by.get(stage)
        return None if s is None or s.cached else float(s.wall_s)

    def seconds(self, stage: str) -> float | None:
        """CPU seconds of ``stage``, the figure the fits use: under the shared machine's load the
        wall time is several times the work, the CPU time is not. The BA inside the mapper has no
        clock of its own: its CPU is its wall time at the mapping stage's CPU/wall rate."""
        by = {s.stage: s for s in self.stages}
        m = by.get("mapping")
        rate = (m.cpu_s / m.wall_s) if m is not None and m.cpu_s is not None and m.wall_s > 0 else None
        if stage == "ba first call":
            return None if self.ba_stats.first_s is None or rate is None else self.ba_stats.first_s * rate
        if stage in ("ba", "mapping (excl. BA)"):
            w, wb = self.wall(stage), self.wall("ba")
            if w is None or rate is None:
                return None
            return (w - (self.ba_stats.first_s or 0.0)) * rate if stage == "ba" else m.cpu_s - (wb or 0.0) * rate
        s = by.get(stage)
        return None if s is None or s.cached or s.cpu_s is None else float(s.cpu_s)

    def size(self, driver: str) -> float:
        return float({"views": self.views, "pairs": self.pairs, "observations": self.observations}[driver])


@dataclass(frozen=True)
class StageFit:
    """``seconds = coef * size^exponent`` for one stage, and its extrapolation to each twin."""

    stage: str
    driver: str
    exponent: float | None          # None: fewer than two sizes measured
    coef: float | None
    points: tuple[tuple[float, float], ...]             # (size, seconds) measured
    at_twin_s: dict[str, float | None] = field(default_factory=dict)   # twin -> predicted seconds


@dataclass(frozen=True)
class ScalingReport:
    """The committed breakdown (``twin-scaling.json``)."""

    twin: str
    ba: str
    runs: tuple[BlockRun, ...]
    pairs_per_view: float           # at the largest block (the twins' pairing: bounded per view)
    observations_per_view: float
    fits: tuple[StageFit, ...]
    total_at_twin_s: dict[str, float | None]
    note: str = ""


def fit_power(sizes, seconds) -> tuple[float | None, float | None]:
    """(exponent b, coefficient a) of ``seconds = a * sizes^b``, least squares on logs; (None, None)
    with fewer than two distinct positive sizes."""
    x, y = np.asarray(sizes, float), np.asarray(seconds, float)
    ok = (x > 0) & (y > 0)
    x, y = x[ok], y[ok]
    if len(np.unique(x)) < 2:
        return None, None
    b, log_a = np.polyfit(np.log(x), np.log(y), 1)
    return float(b), float(np.exp(log_a))


def _twin_size(driver: str, views: int, pairs_per_view: float, obs_per_view: float) -> float:
    return {"views": views, "pairs": pairs_per_view * views, "observations": obs_per_view * views}[driver]


def build(twin: str, ba: str, runs: list[BlockRun], note: str = "") -> ScalingReport:
    """Fit every stage over ``runs`` (one BA form) and extrapolate to every twin's view count."""
    mine = sorted((r for r in runs if r.ba == ba), key=lambda r: r.views)
    if not mine:
        raise ValueError(f"no runs with BA {ba!r}")
    big = mine[-1]
    ppv, opv = big.pairs / big.views, big.observations / big.views
    fits, totals = [], {t: 0.0 for t in TWIN_VIEWS}
    for stage, driver in DRIVERS.items():
        pts = tuple((r.size(driver), r.seconds(stage)) for r in mine if r.seconds(stage) is not None)
        if len(pts) < 2 and stage in FRONT_END:  # read from another form's cache: that form computed it
            pts = tuple(sorted((r.size(driver), r.seconds(stage)) for r in runs if r.seconds(stage) is not None))
        b, a = fit_power([p[0] for p in pts], [p[1] for p in pts])
        pred: dict[str, float | None] = {}
        for t, n in TWIN_VIEWS.items():
            pred[t] = None if b is None else float(a * _twin_size(driver, n, ppv, opv) ** b)
            totals[t] = None if pred[t] is None or totals[t] is None else totals[t] + pred[t]
        fits.append(StageFit(stage, driver, b, a, pts, pred))
    first = [r.seconds("ba first call") for r in mine if r.seconds("ba first call") is not None]
    if first:   # once per process: the largest block's, not scaled
        c = float(first[-1])
        fits.append(StageFit("ba first call", "once per process", 0.0, c, tuple((r.views, r.seconds("ba first call"))
                                                                              for r in mine if r.seconds("ba first call") is not None),
                             {t: c for t in TWIN_VIEWS}))
        totals = {t: None if v is None else v + c for t, v in totals.items()}
    return ScalingReport(twin, ba, tuple(mine), ppv, opv, tuple(fits), totals, note)


def write(report: ScalingReport, out_dir: Path) -> None:
    """``twin-scaling-<ba>.json`` and the markdown generated from it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write(out_dir / f"twin-scaling-{report.ba}.json",
                 json.dumps({**records.to_dict(report), "format": FORMAT}, indent=1) + "\n")
    atomic_write(out_dir / f"twin-scaling-{report.ba}.md", render(report) + "\n")


def read(path: Path) -> ScalingReport:
    data = records.read_json(path)
    return records.from_dict(ScalingReport, {k: v for k, v in data.items() if k != "format"}, label=str(path))


def _f(v: float | None, spec: str = ".1f") -> str:
    return "-" if v is None else format(v, spec)


def render(rep: ScalingReport) -> str:
    """Markdown: the measured stages per block, the fits, the extrapolation (indicative)."""
    env = rep.runs[-1].environment
    lines = [f"# Where the time goes: our SfM ({rep.ba} BA) on sub-blocks of the `{rep.twin}` twin", "",
             "Generated by `python scripts/twin_scaling.py report` from the JSON beside this file; do not edit. "
             "**Indicative**: measured on a 2-core machine that other work may have shared (load averages "
             "below); a front-end stage read from another form's cache shows '-'.", "",
             "CPU seconds per stage (wall seconds in brackets; the front end ran on "
             + (f"{rep.runs[-1].threads} threads" if rep.runs[-1].threads else "a thread per core (SfMConfig.threads 0)")
             + "):", "",
             "| block | views | pairs | verified | observations | registered | tie points | load before / after | "
             + " | ".join(DRIVERS) + " | wall (s) |", "|" + "---|" * (9 + len(DRIVERS))]
    for r in rep.runs:
        lines.append(f"| {r.label} | {r.views} | {r.pairs} | {r.verified_pairs} | {r.observations:,} | {r.registered} | "
                     f"{r.tie_points:,} | {r.load_before[0]:.1f} / {r.load_after[0]:.1f} | "
                     + " | ".join(f"{_f(r.seconds(s))} ({_f(r.wall(s))})" for s in DRIVERS) + f" | {r.wall_s:.1f} |")
    lines += ["", "CPU seconds and peak memory per stage (MiB):", ""]
    for r in rep.runs:
        lines.append(f"- {r.label}: " + ", ".join(
            f"{s.stage} {_f(s.cpu_s)} s CPU / {_f(s.peak_rss_mb, '.0f')} MiB" for s in r.stages
            if s.stage in ("features", "matching", "verification", "tracks", "mapping")))
        b = r.ba_stats
        lines.append(f"  - BA: {b.local_runs} local ({b.local_s:.1f} s), {b.global_runs} global ({b.global_s:.1f} s), "
                     f"the last global {b.final_global_s:.1f} s in {b.final_global_iterations} iterations")
    lines += ["", f"Model: CPU seconds = a x size^b per stage, b fitted on logs over the blocks (two sizes: exact, a local "
              f"exponent). Sizes: views; pairs = {rep.pairs_per_view:.2f} per view (the twins' spatial + sequential "
              f"pairing keeps a bounded number of pairs per view); observations = {rep.observations_per_view:.0f} "
              "per view. Extrapolated to the twins' view counts (poets-park and rosetta have other scenes; "
              "this is the mappilot block's rate). The front end runs on threads, so its wall time can be "
              "below its CPU time; the wall estimate below scales each stage by its wall/CPU ratio at the largest "
              "block (issue 34):", "",
              "| stage | driver | exponent b | " + " | ".join(f"{t} ({n} views), s" for t, n in TWIN_VIEWS.items()) + " |",
              "|---|---|---|" + "---|" * len(TWIN_VIEWS)]
    for f in rep.fits:
        lines.append(f"| {f.stage} | {f.driver} | {_f(f.exponent, '.2f')} | "
                     + " | ".join(_f(f.at_twin_s.get(t)) for t in TWIN_VIEWS) + " |")
    lines.append("| **total** | | | " + " | ".join(
        f"{_f(rep.total_at_twin_s.get(t))} ({_f(None if rep.total_at_twin_s.get(t) is None else rep.total_at_twin_s[t] / 60)} min)"
        for t in TWIN_VIEWS) + " |")
    walls = [_wall_estimate(rep, t) for t in TWIN_VIEWS]
    lines.append("| **wall estimate** | | | " + " | ".join(walls) + " |")
    if any(w.endswith("*") for w in walls):
        lines += ["", "\\* stages without a measured wall/CPU ratio (read from another form's cache) are counted at "
                  "their CPU time."]
    lines += ["", f"Provenance: commit {env.git_commit} (dirty: {env.git_dirty}), {env.cpu_count} CPUs ({env.cpu_model}), "
              f"threads {env.threads}, versions numpy {env.versions.get('numpy')}, pycolmap {env.versions.get('pycolmap')}."]
    if rep.note:
        lines += ["", rep.note]
    return "\n".join(lines)


def wall_ratio(rep: ScalingReport, stage: str) -> float | None:
    """Wall / CPU seconds of ``stage`` at the largest block that measured both (None: none did)."""
    for r in reversed(rep.runs):
        cpu, wall = r.seconds(stage), r.wall(stage)
        if cpu and wall is not None:
            return float(wall / cpu)
    return None


def _wall_estimate(rep: ScalingReport, twin: str) -> str:
    """Extrapolated wall seconds at ``twin``: each stage's CPU estimate times its measured wall/CPU
    ratio; a stage without one counts at CPU time (marked *)."""
    total, starred = 0.0, False
    for f in rep.fits:
        cpu = f.at_twin_s.get(twin)
        if cpu is None:
            return "-"
        ratio = wall_ratio(rep, f.stage)
        starred |= ratio is None and f.stage != "ba first call"
        total += cpu * (1.0 if ratio is None else ratio)
    return f"{total:.1f} ({total / 60:.1f} min){'*' if starred else ''}"
