"""The twin campaign's records: one :class:`CampaignCell` per (twin, seed, method), with its stages
and provenance (written by :mod:`polarref.compare.twins.campaign`, read by
:mod:`polarref.compare.twins.campaign_table`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from polarref.compare.twins import campaign_jobs as J
from polarref.core import records
from polarref.core.provenance import Provenance
from polarref.core.status import RunStatus
from polarref.model.scores import ReconstructionMetrics

FORMAT = "polarref-twin-campaign-cell/1"
OURS = ("ours-euclidean", "ours-polar")
PYCOLMAP = ("pycolmap-incremental-sift", "pycolmap-global-sift")
METHODS = OURS + PYCOLMAP


@dataclass(frozen=True)
class CellStage:
    """One stage process of a cell (``shared``: the front end every method of its family reads)."""

    job: str
    shared: bool
    status: RunStatus
    reason: str = ""
    wall_s: float = 0.0               # the process's wall time (a resumed mapping: its segments summed)
    reused: bool = False              # finished earlier in this campaign's work folder (another cell ran it)
    finished_utc: str = ""
    git_commit: str = ""
    git_dirty: bool | None = None
    result: J.StagedRun | None = None


@dataclass(frozen=True)
class CellProvenance:
    commit: str
    dirty: bool | None
    host: str
    started_utc: str
    finished_utc: str
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]
    threads: dict[str, int]
    seeds: dict[str, int]
    environment: Provenance


@dataclass(frozen=True)
class CampaignCell:
    """One (twin, seed, method) result."""

    twin: str
    size: str
    seed: int
    method: str                       # a METHODS name
    key: str                          # the file name (pycolmap: with its thread count)
    views: int
    pairs: int
    status: RunStatus
    reason: str
    wall_s: float                     # every stage process of the cell, the shared front end included
    peak_rss_mb: float | None         # as recorded; cells before the fix hold ru_maxrss: read largest_stage_mb
    ba_s: float | None                # ours: the BA inside the mapper
    render_s: float                   # not counted in wall_s (0: rendered by an earlier session)
    stages: tuple[CellStage, ...]
    metrics: ReconstructionMetrics | None
    provenance: CellProvenance
    format: str = FORMAT

    @property
    def minutes(self) -> float:
        return self.wall_s / 60.0

    @property
    def largest_stage_mb(self) -> float | None:
        """MiB: the peak of the cell's most memory-hungry stage process (:func:`stage_peak_mb`)."""
        return largest_stage_mb(self.stages)


def stage_peak_mb(stage: CellStage) -> float | None:
    """Peak memory of one stage process, MiB: the largest of its pipeline stages' sampled peaks (the
    process plus its Dask workers, as ``polarref.sfm.stages`` measures them), else the figure of
    its record. Stage records up to ee35ac1 carry ``ru_maxrss``, which Linux floors at the spawning
    runner's peak (:mod:`polarref.core.memory`): every stage of pin ee35ac1's mappilot cells read
    1,890-2,200 MiB against sampled peaks of 1,009-1,635."""
    if stage.result is None:
        return None
    sampled = [(c.peak_rss_mb or 0.0) + (c.workers_peak_rss_mb or 0.0) for c in stage.result.stages
               if c.peak_rss_mb is not None or c.workers_peak_rss_mb is not None]
    return max(sampled) if sampled else stage.result.run.peak_rss_mb


def largest_stage_mb(stages: tuple[CellStage, ...] | list[CellStage]) -> float | None:
    """MiB: the largest :func:`stage_peak_mb` over ``stages``; None where none is known."""
    peaks = [p for p in map(stage_peak_mb, stages) if p is not None]
    return max(peaks) if peaks else None


def read_cell(path: Path) -> CampaignCell:
    return records.load(CampaignCell, path)


def read_stage(path: Path) -> CellStage:
    return records.load(CellStage, path)
