"""The twin campaign's table: C4 and C5 on each twin as paired statistics over the seeds.

Reads the cells of one commit (:mod:`polarref.compare.twins.campaign`) and refuses any cell, or
stage, that ran at another commit or from a dirty checkout: one table, one commit. The rules and
targets are the pre-registration's ``[twins]`` section (``compare/claims/preregistration.toml``);
the statistics are the controlled claims' own (:func:`polarref.compare.claims.controlled.geometric_interval`
for C4's speed-up, :func:`~polarref.compare.claims.controlled.tost` for C5's relative differences),
with the scorecard's bar and margins (:mod:`polarref.compare.claims.thresholds`).
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.compare.claims import preregistration
from polarref.compare.claims.controlled import geometric_interval, tost
from polarref.compare.claims.single_run import SUPPORTED_AT
from polarref.compare.claims.thresholds import MDE_ALPHA, ALPHA, PAPER_OBS_REL, PAPER_TIE_REL, TIE_MARGIN_REL
from polarref.compare.twins.campaign_records import OURS, CampaignCell, read_cell
from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError
from polarref.core.status import RunStatus

FORMAT = "polarref-twin-campaign-table/1"
BASE, CAND = OURS


@dataclass(frozen=True)
class TwinsRules:
    """The pre-registration's ``[twins]`` section, as written there."""

    measure: str
    seeds: tuple[int, ...]
    twins: tuple[str, ...]
    min_paired_seeds: int
    ba_ratio_max: float
    target_min: dict[str, float]     # "<twin>/<method>" or "<twin>" -> minutes per seed
    peak_mb: dict[str, float]        # twin -> MiB of the largest stage

    def minutes(self, twin: str, method: str) -> float | None:
        return self.target_min.get(f"{twin}/{method}", self.target_min.get(twin))

    def peak(self, twin: str) -> float | None:
        return self.peak_mb.get(twin)


def rules(path: Path = preregistration.PATH) -> TwinsRules:
    """The ``[twins]`` rules (PolarrefError when the section is missing or malformed)."""
    try:
        sec = tomllib.loads(Path(path).read_text(encoding="utf-8")).get("twins")
        return records.from_dict(TwinsRules, sec, label=f"{Path(path).name} [twins]")
    except (OSError, tomllib.TOMLDecodeError, records.RecordError) as exc:
        raise PolarrefError(f"{path}: [twins] section: {exc}") from exc


@dataclass(frozen=True)
class MethodSummary:
    """One method on one twin over the seeds it finished."""

    key: str
    seeds: tuple[int, ...]
    failed: tuple[str, ...]              # "seed <k>: <reason>"
    minutes: tuple[float, ...]
    median_min: float | None
    tie_points: tuple[int, ...]
    reprojected_px: tuple[int, ...]
    registered: tuple[int, ...]
    rotation_error_deg: tuple[float, ...]
    peak_mb: float | None
    target_min: float | None
    target_met: bool | None              # every finished seed within the target (None: no target / none finished)
    threads: int | None                  # the method's parallel setting (front end / pycolmap num_threads)


@dataclass(frozen=True)
class SpeedupStats:
    """C4 on one twin: whole-method time ours-euclidean / ours-polar, paired by seed."""

    seeds: tuple[int, ...]
    ratios: tuple[float, ...]
    geometric_mean: float | None
    lo: float | None                     # 95 % t-interval on the log ratios
    hi: float | None
    bar: float
    verdict: str
    ba_ratios: tuple[float, ...]         # the mapper's BA time polar / Euclidean per seed
    ba_ratio_max: float
    ba_target_met: bool | None


@dataclass(frozen=True)
class CountStats:
    """One count of C5 on one twin: (polar - euclidean) / euclidean, paired by seed."""

    count: str
    seeds: tuple[int, ...]
    rel: tuple[float, ...]
    mean: float | None
    lo: float | None                     # 90 % t-interval (two one-sided tests)
    hi: float | None
    margin: float
    outcome: str                         # more | equal | fewer | unclear


@dataclass(frozen=True)
class TwinCampaign:
    twin: str                            # the twin, "-<size>" added for a reduced size
    views: int
    pairs: int
    methods: tuple[MethodSummary, ...]
    c4: SpeedupStats
    c5: tuple[CountStats, ...]
    c5_verdict: str
    peak_mb_max: float | None
    peak_target_met: bool | None


@dataclass(frozen=True)
class CampaignTable:
    commit: str
    cells: int
    hosts: tuple[str, ...]
    load_1min: tuple[float, float]       # lowest and highest 1-min load average at a cell's start or end
    preregistration_commit: str
    twins: tuple[TwinCampaign, ...]


def load_cells(commit_dir: Path) -> list[CampaignCell]:
    """Every cell under ``commit_dir`` (named by its commit), strictly; PolarrefError for a cell or
    a stage from another commit or a dirty checkout."""
    commit = Path(commit_dir).name
    cells = []
    for path in sorted(Path(commit_dir).glob("*/seed*/*.json")):
        cell = read_cell(path)
        commits = {(cell.provenance.commit, cell.provenance.dirty)} | {
            (s.git_commit, s.git_dirty) for s in cell.stages if s.git_commit}
        if commits != {(commit, False)}:
            bad = sorted(f"{c[:12]} (dirty: {d})" for c, d in commits if (c, d) != (commit, False))
            raise PolarrefError(f"{path}: ran at {', '.join(bad)}, not the clean {commit[:12]}: one table holds one "
                                "commit (rerun the cell there or start a campaign at that commit)")
        cells.append(cell)
    if not cells:
        raise PolarrefError(f"no cells under {commit_dir}")
    return cells


def _summary(cells: list[CampaignCell], twin: str, rr: TwinsRules) -> MethodSummary:
    ok = sorted((c for c in cells if c.status == RunStatus.OK and c.metrics is not None), key=lambda c: c.seed)
    bad = tuple(f"seed {c.seed}: {c.status} ({c.reason})" for c in cells if c not in ok)
    mins = tuple(c.minutes for c in ok)
    # the targets are the twins' (issue 34): a reduced size has none
    target = rr.minutes(twin, cells[0].method) if cells[0].size == "twin" else None
    peaks = [c.largest_stage_mb for c in ok if c.largest_stage_mb is not None]
    threads = next((s.result.settings.parallel for c in ok for s in c.stages if s.result is not None), None)
    return MethodSummary(
        cells[0].key, tuple(c.seed for c in ok), bad, mins, float(np.median(mins)) if mins else None,
        tuple(int(c.metrics.tie_points) for c in ok), tuple(int(c.metrics.reprojected_px) for c in ok),
        tuple(int(c.metrics.registered_images) for c in ok),
        tuple(float(c.metrics.gt.rotation_error_deg_mean) for c in ok if c.metrics.gt is not None),
        max(peaks) if peaks else None, target, None if target is None or not ok else all(m <= target for m in mins),
        threads)


def _paired(by: dict[str, dict[int, CampaignCell]]) -> list[tuple[int, CampaignCell, CampaignCell]]:
    b, c = by.get(BASE, {}), by.get(CAND, {})
    return [(s, b[s], c[s]) for s in sorted(set(b) & set(c))
            if b[s].status == c[s].status == RunStatus.OK and b[s].metrics is not None and c[s].metrics is not None]


def speedup_stats(pairs, rr: TwinsRules) -> SpeedupStats:
    """C4: geometric mean of euclidean/polar over the paired seeds, 95 % t-interval, against the bar."""
    r = np.array([b.wall_s / c.wall_s for _, b, c in pairs], float)
    ba = tuple(float(c.ba_s / b.ba_s) for _, b, c in pairs if b.ba_s and c.ba_s)
    g = lo = hi = None
    verdict = "not tested" if not len(r) else "inconclusive"
    if len(r):
        g, lo, hi = geometric_interval(r)
        if len(r) >= rr.min_paired_seeds:
            verdict = "supported" if lo >= SUPPORTED_AT else "not supported" if hi < SUPPORTED_AT else "inconclusive"
    fin = (lambda v: None if v is None or not np.isfinite(v) else float(v))
    return SpeedupStats(tuple(s for s, _, _ in pairs), tuple(float(x) for x in r), fin(g), fin(lo), fin(hi),
                        SUPPORTED_AT, verdict, ba, rr.ba_ratio_max, all(x <= rr.ba_ratio_max for x in ba) if ba else None)


def count_stats(pairs, count: str, paper_effect: float) -> CountStats:
    """C5, one count: TOST on the relative differences with margin min(TIE_MARGIN_REL, the paper's effect)."""
    rel = np.array([(getattr(c.metrics, count) - getattr(b.metrics, count)) / getattr(b.metrics, count)
                    for _, b, c in pairs], float)
    margin = min(TIE_MARGIN_REL, paper_effect)
    if not len(rel):
        return CountStats(count, (), (), None, None, None, margin, "unclear")
    m, lo, hi, o = tost(rel, margin)
    fin = (lambda v: None if not np.isfinite(v) else float(v))
    return CountStats(count, tuple(s for s, _, _ in pairs), tuple(float(x) for x in rel), fin(m), fin(lo), fin(hi),
                      margin, {"higher": "more", "lower": "fewer"}.get(o, o))


def c5_verdict(stats: tuple[CountStats, ...], n: int, rr: TwinsRules) -> str:
    if n == 0:
        return "not tested"
    if n < rr.min_paired_seeds:
        return "inconclusive"
    outcomes = [s.outcome for s in stats]
    return ("supported" if all(o == "more" for o in outcomes) else
            "not supported" if any(o in ("equal", "fewer") for o in outcomes) else "inconclusive")


def build(commit_dir: Path, rr: TwinsRules | None = None) -> CampaignTable:
    """The table of the cells under ``commit_dir``."""
    rr = rr or rules()
    cells = load_cells(commit_dir)
    twins = []
    for twin, size in sorted({(c.twin, c.size) for c in cells}):
        mine = [c for c in cells if (c.twin, c.size) == (twin, size)]
        by: dict[str, dict[int, CampaignCell]] = {}
        for c in mine:
            by.setdefault(c.key, {})[c.seed] = c
        summaries = tuple(_summary(list(v.values()), twin, rr) for _, v in sorted(by.items()))
        name = twin if size == "twin" else f"{twin}-{size}"
        pairs = _paired(by)
        c5 = (count_stats(pairs, "tie_points", PAPER_TIE_REL), count_stats(pairs, "reprojected_px", PAPER_OBS_REL))
        # the memory target is our pipeline's (issue 34); a peer's peak stands in its own row
        peaks = [m.peak_mb for m in summaries if m.peak_mb is not None and m.key.startswith("ours-")]
        limit = rr.peak(twin) if size == "twin" else None
        twins.append(TwinCampaign(name, mine[0].views, mine[0].pairs, summaries, speedup_stats(pairs, rr), c5,
                                  c5_verdict(c5, len(pairs), rr), max(peaks) if peaks else None,
                                  None if limit is None or not peaks else max(peaks) <= limit))
    loads = [x for c in cells for x in (c.provenance.load_before[0], c.provenance.load_after[0])]
    pre = preregistration.file_commit()
    return CampaignTable(Path(commit_dir).name, len(cells), tuple(sorted({c.provenance.host for c in cells})),
                         (min(loads), max(loads)), pre.commit, tuple(twins))


def _f(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def render(t: CampaignTable) -> str:
    lines = [f"# Twin campaign at {t.commit[:12]}", "",
             "Generated by `python -m polarref.compare.twins.campaign table` from the cells beside this file; do not "
             f"edit. {t.cells} cells, every one from the clean commit `{t.commit}`, hosts {', '.join(t.hosts)}, "
             f"1-min load {t.load_1min[0]:.1f}-{t.load_1min[1]:.1f} (a shared 2-core machine: times are indicative). "
             f"Rules: the pre-registration's [twins] section (last changed in {t.preregistration_commit[:12] or 'unknown'}).",
             ""]
    for tw in t.twins:
        lines += [f"## {tw.twin} ({tw.views} views, {tw.pairs} pairs)", "",
                  "| method | threads | seeds | minutes per seed | median | target | tie points | reprojected px "
                  "| registered | rotation error (deg) | peak MiB | failed |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for m in tw.methods:
            met = "" if m.target_met is None else (" (met)" if m.target_met else " (not met)")
            lines.append(f"| {m.key} | {m.threads if m.threads is not None else '-'} | {', '.join(map(str, m.seeds)) or '-'} | "
                         f"{', '.join(f'{x:.1f}' for x in m.minutes) or '-'} | {_f(m.median_min, '.1f')} | "
                         f"{_f(m.target_min, '.0f')}{met} | {', '.join(f'{x:,}' for x in m.tie_points) or '-'} | "
                         f"{', '.join(f'{x:,}' for x in m.reprojected_px) or '-'} | {', '.join(map(str, m.registered)) or '-'} | "
                         f"{', '.join(f'{x:.4f}' for x in m.rotation_error_deg) or '-'} | {_f(m.peak_mb, ',.0f')} | "
                         f"{'; '.join(m.failed) or '-'} |")
        c4 = tw.c4
        lines += ["", f"- C4 (polar faster, whole method): **{c4.verdict}**: speed-up Euclidean/polar per seed "
                  f"{', '.join(f'x{x:.3f}' for x in c4.ratios) or '-'}, geometric mean {_f(c4.geometric_mean, '.3f')} "
                  f"({'one seed, no interval' if c4.lo is None else f'{1 - MDE_ALPHA:.0%} CI {c4.lo:.3f} - {c4.hi:.3f}'}); supported at >= x{c4.bar:.2f}. "
                  f"BA in the mapper polar/Euclidean {', '.join(f'x{x:.2f}' for x in c4.ba_ratios) or '-'} (target <= "
                  f"x{c4.ba_ratio_max:.1f}: {'-' if c4.ba_target_met is None else 'met' if c4.ba_target_met else 'not met'})."]
        parts = [f"{s.count} {', '.join(f'{100 * x:+.3f} %' for x in s.rel) or '-'} (mean {_f(None if s.mean is None else 100 * s.mean, '+.3f')} %, "
                 f"{1 - 2 * ALPHA:.0%} CI {_f(None if s.lo is None else 100 * s.lo, '+.3f')} to "
                 f"{_f(None if s.hi is None else 100 * s.hi, '+.3f')} %, margin {100 * s.margin:.2f} %: {s.outcome})"
                 for s in tw.c5]
        lines += [f"- C5 (more tie points and reprojected px, polar vs Euclidean): **{tw.c5_verdict}**: " + "; ".join(parts) + ".",
                  f"- Peak memory of our largest stage: {_f(tw.peak_mb_max, ',.0f')} MiB (target: "
                  f"{'-' if tw.peak_target_met is None else 'met' if tw.peak_target_met else 'not met'}).", ""]
    return "\n".join(lines)


def write(table: CampaignTable, out: Path) -> None:
    atomic_write(out / "table.json", json.dumps({**records.to_dict(table), "format": FORMAT}, indent=1) + "\n")
    atomic_write(out / "table.md", render(table) + "\n")
