"""The records of ``polarref bench sfm``: one cell per (method, views), and the bench they add up to.

Their JSON layout is the one the committed ``reports/bench-sfm`` files have (``cells/<method>-v<N>.json``
and ``bench.json``); they are read back strictly (:mod:`polarref.core.records`), so a stale or
hand-edited cell fails with a line naming the file and the key.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.provenance import Provenance
from polarref.core.status import RunStatus
from synth.config import SceneConfig


@dataclass(frozen=True)
class BenchSfMSettings:
    """What every cell shares (stored in bench.json and in each cell)."""

    scene: str = "comet"
    preset: str = "default"       # synth preset (image size, sampling); views overridden per cell
    seed: int = 0                 # render seed and both mappers' seeds
    pairing: str = "sequential"   # our pair selection, imported by pycolmap
    overlap: int = 10             # sequential overlap
    threads: int = 1              # every stage of both methods


@dataclass(frozen=True)
class PeakMemory:
    """Peak resident memory of a cell's process (MiB): ru_maxrss and /proc VmHWM (None: unknown)."""

    ru_maxrss_mb: float
    vmhwm_mb: float | None = None


@dataclass(frozen=True)
class SfMCell:
    """One method on one view count, run in its own process."""

    method: str                           # ours | pycolmap
    views: int
    status: RunStatus
    stages_s: dict[str, float]            # sfm_report.STAGES[method], ours also "ba" (part of mapping)
    total_s: float                        # sum of the method's STAGES
    wall_s: float
    peak_memory_mb: PeakMemory
    cpu_s: float | None                   # CPU seconds of the whole cell process (steadier when loaded)
    registered_images: int
    tie_points: int
    observations: int
    mean_track_length: float | None
    mean_reprojection_error_px: float | None
    rotation_error_deg_mean: float | None   # after a Sim3 alignment to the ground truth
    center_error_rel_mean: float | None
    pairs: int
    pairs_sha256: str                     # the same pair list for both methods
    bench_settings: BenchSfMSettings
    method_settings: dict[str, Any]       # the method's own option objects as they print (pycolmap's todict)
    scene_root: str
    environment: Provenance


@dataclass(frozen=True)
class FailedCell:
    method: str
    views: int
    error: str


@dataclass(frozen=True)
class MemoryFit:
    """Peak memory at MEMORY_VIEWS: measured, or a power fit of the two largest cells."""

    measured_mb: float | None
    exponent: float | None
    extrapolated_mb: float | None


@dataclass(frozen=True)
class SfMChecks:
    """The done-when checks of issues 13 and 14 that the cells allow (None: not tested)."""

    time_ratio_168: float | None = None
    time_ratio_168_ok: bool | None = None
    cpu_ratio_168: float | None = None
    tie_ratio_168: float | None = None
    tie_ratio_168_ok: bool | None = None
    rotation_error_168_ok: bool | None = None
    same_pairs_168: bool | None = None
    ours_total_exponent_ok: bool | None = None
    ours_memory_631_mb: float | None = None
    ours_memory_631_source: str = "not tested"
    ours_memory_631_ok: bool | None = None


@dataclass(frozen=True)
class SfMBench:
    """``bench.json``: every cell, the growth exponents (method -> stage -> k) and the checks."""

    settings: BenchSfMSettings
    environment: Provenance
    cells: list[SfMCell]
    failed: list[FailedCell] = field(default_factory=list)
    growth_exponents: dict[str, dict[str, float | None]] = field(default_factory=dict)
    peak_memory: dict[str, MemoryFit] = field(default_factory=dict)
    checks: SfMChecks = SfMChecks()


@dataclass(frozen=True)
class TaskOverhead:
    """Wall time per no-op task through an executor's ``map`` (scheduler round trip and bookkeeping)."""

    tasks: int
    wall_s: float
    per_task_ms: float


@dataclass(frozen=True)
class ExecutorMode:
    """``python -m polarref.bench.executor``: one execution mode (serial or N local workers)."""

    mode: str                     # "serial" or the number of workers
    workers: int
    detail: str
    cluster_start_s: float
    render_s: float
    render_views: int
    render_s_per_view: float
    features_s: float
    keypoints_total: int
    overhead: TaskOverhead
    config: SceneConfig           # the rendered scene's settings


def json_default(obj):
    """numpy scalars as numbers; paths, enums and sets of pycolmap's option dicts as text."""
    if hasattr(obj, "item") and callable(obj.item):
        return obj.item()
    if isinstance(obj, (set, frozenset, tuple)):
        return sorted(map(str, obj))
    return str(obj)


def dumps(record) -> str:
    """The record's JSON as the bench has always written it (indent 1, option objects as text)."""
    return json.dumps(records.to_dict(record), indent=1, default=json_default)


def write(record, path: Path) -> None:
    atomic_write(path, dumps(record))


def read_cell(path: Path) -> SfMCell:
    """The cell at ``path``, strictly (RecordError naming the file and the key); cells written
    before the CPU time was measured read with ``cpu_s`` None."""
    data = records.read_json(path)
    if isinstance(data, dict) and "cpu_s" not in data:
        data = dict(data, cpu_s=None)
    return records.from_dict(SfMCell, data, label=str(path))
