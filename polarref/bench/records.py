"""The records of ``polarref bench sfm``: one cell per (method, views), and the bench they add up to.

A cell is the method's :class:`polarref.model.run.MethodRun` plus what only the bench measures;
a failed cell a FAILED MethodRun. Their JSON layout is the one the committed ``reports/bench-sfm``
files have (``cells/<method>-v<N>.json`` and ``bench.json``), written and read in one place per
record (``to_json`` / ``from_json`` through a private file record); they are read back strictly
(:mod:`polarref.core.records`), so a stale or hand-edited cell fails with a line naming the file
and the key.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.provenance import Provenance
from polarref.core.status import RunStatus
from polarref.model.run import MethodRun
# the settings record lives in the model (the twin campaign's cells hold it too); read from here as before
from polarref.model.settings import MethodSettings, Setting, flatten_settings, json_default  # noqa: F401
from polarref.sfm.stages import StageCost
from synth.config import SceneConfig


@dataclass(frozen=True)
class BenchSfMSettings:
    """What every cell shares (stored in bench.json and in each cell)."""

    scene: str = "comet"
    preset: str = "default"       # synth preset (image size, sampling); views overridden per cell
    seed: int = 0                 # render seed and both mappers' seeds
    pairing: str = "sequential"   # our pair selection, imported by pycolmap
    overlap: int = 10             # sequential overlap
    max_num_features: int = 4096  # SIFT keypoints per image, the same budget for both methods


@dataclass(frozen=True)
class PeakMemory:
    """Peak resident memory of a cell's process (MiB): ru_maxrss and /proc VmHWM (None: unknown)."""

    ru_maxrss_mb: float
    vmhwm_mb: float | None = None


# the stages each method's wall time is split into (the cells' total, bench.json and the tables)
STAGES = {"ours": ("features", "matching", "verification", "tracks", "mapping"),
          "pycolmap": ("features", "matching", "mapping")}


@dataclass(frozen=True)
class SfMCell:
    """One method variant on one view count, one repeat, run in its own process.

    ``run`` is the method's run as every comparison records it (:class:`polarref.model.run.MethodRun`):
    ``method`` ours | pycolmap, ``status``, ``stage_runtime_s`` (the method's STAGES, ours also
    "ba", part of mapping), ``wall_s``, ``peak_rss_mb`` (ru_maxrss of the cell process) and
    ``registered`` (images, as the metrics count them). The other fields are what only the bench
    measures. On disk a cell keeps the flat layout of the committed cells (:meth:`to_json`).
    """

    run: MethodRun
    views: int
    vmhwm_mb: float | None                # /proc VmHWM of the cell process (None: unknown)
    cpu_s: float | None                   # CPU seconds of the whole cell process (steadier when loaded)
    tie_points: int                       # 3D points of the model (as the metrics count them)
    observations: int
    mean_track_length: float | None
    mean_reprojection_error_px: float | None
    rotation_error_deg_mean: float | None   # after a Sim3 alignment to the ground truth
    center_error_rel_mean: float | None
    pairs: int
    pairs_sha256: str                     # the same pair list for both methods
    bench_settings: BenchSfMSettings
    method_settings: MethodSettings
    scene_root: str
    environment: Provenance               # the cell process's provenance
    parallel: int = 1                     # ours: workers; pycolmap: threads (the cell's column)
    repeat: int = 1                       # 1..R: repeats run interleaved with the other cells
    tie_points_2v: int | None = None      # 3D points seen by >= 2 registered images (one rule for both)
    tie_points_3v: int | None = None      # ... by >= 3
    stages: tuple[StageCost, ...] = ()    # every stage with CPU time and its own peak memory
    load_average: tuple[float, ...] = ()  # 1/5/15-min load average when the cell started

    @property
    def label(self) -> str:
        return variant_label(self.run.method, self.parallel)

    @property
    def total_s(self) -> float:
        """The sum of the method's STAGES ("ba" is part of "mapping")."""
        return float(sum(self.run.stage_runtime_s.get(s, 0.0) for s in STAGES[self.run.method]))

    def to_json(self) -> dict:
        """The cell file's layout (``cells/<variant>-v<N>-r<k>.json``)."""
        r = self.run
        return records.to_dict(_CellFile(
            r.method, self.views, r.status, r.stage_runtime_s, self.total_s, r.wall_s,
            PeakMemory(r.peak_rss_mb, self.vmhwm_mb), self.cpu_s, r.registered, self.tie_points, self.observations,
            self.mean_track_length, self.mean_reprojection_error_px, self.rotation_error_deg_mean,
            self.center_error_rel_mean, self.pairs, self.pairs_sha256, self.bench_settings, self.method_settings,
            self.scene_root, self.environment, self.parallel, self.repeat, self.tie_points_2v, self.tie_points_3v,
            self.stages, self.load_average))

    @staticmethod
    def from_json(data, label: str = "bench cell") -> SfMCell:
        """A cell from its file's JSON, strictly; cells of the first layout are read in today's."""
        f = records.from_dict(_CellFile, _upgrade_cell_json(data), label=label)
        run = MethodRun(f.method, status=f.status, stage_runtime_s=f.stages_s, wall_s=f.wall_s,
                        peak_rss_mb=f.peak_memory_mb.ru_maxrss_mb, registered=f.registered_images)
        cell = SfMCell(run, f.views, f.peak_memory_mb.vmhwm_mb, f.cpu_s, f.tie_points, f.observations,
                       f.mean_track_length, f.mean_reprojection_error_px, f.rotation_error_deg_mean,
                       f.center_error_rel_mean, f.pairs, f.pairs_sha256, f.bench_settings, f.method_settings,
                       f.scene_root, f.environment, f.parallel, f.repeat, f.tie_points_2v, f.tie_points_3v,
                       f.stages, f.load_average)
        if cell.total_s != f.total_s:
            raise records.RecordError(f"{label}: total_s {f.total_s} is not the sum of its stages ({cell.total_s})")
        return cell


@dataclass(frozen=True)
class _CellFile:
    """The flat JSON layout of a cell file (the committed cells'): read and written only by SfMCell."""

    method: str
    views: int
    status: RunStatus
    stages_s: dict[str, float]
    total_s: float
    wall_s: float
    peak_memory_mb: PeakMemory
    cpu_s: float | None
    registered_images: int
    tie_points: int
    observations: int
    mean_track_length: float | None
    mean_reprojection_error_px: float | None
    rotation_error_deg_mean: float | None
    center_error_rel_mean: float | None
    pairs: int
    pairs_sha256: str
    bench_settings: BenchSfMSettings
    method_settings: MethodSettings
    scene_root: str
    environment: Provenance
    parallel: int = 1
    repeat: int = 1
    tie_points_2v: int | None = None
    tie_points_3v: int | None = None
    stages: tuple[StageCost, ...] = ()
    load_average: tuple[float, ...] = ()


def variant_label(method: str, parallel: int) -> str:
    """``ours-2w`` (2 front-end worker threads), ``pycolmap-2t`` (2 threads)."""
    return f"{method}-{parallel}{'w' if method == 'ours' else 't'}"


@dataclass(frozen=True)
class FailedCell:
    """A cell whose process failed: its run (status FAILED, ``reason`` the error) and where it sat."""

    run: MethodRun
    views: int
    parallel: int = 1
    repeat: int = 1

    def to_json(self) -> dict:
        return records.to_dict(_FailedFile(self.run.method, self.views, self.run.reason, self.parallel, self.repeat))

    @staticmethod
    def from_json(data, label: str = "failed cell") -> FailedCell:
        f = records.from_dict(_FailedFile, data, label=label)
        return FailedCell(MethodRun(f.method, status=RunStatus.FAILED, reason=f.error), f.views, f.parallel, f.repeat)


@dataclass(frozen=True)
class _FailedFile:
    """The JSON layout of a failed cell in bench.json."""

    method: str
    views: int
    error: str
    parallel: int = 1
    repeat: int = 1


@dataclass(frozen=True)
class MemoryFit:
    """Peak memory at MEMORY_VIEWS: measured, or a power fit of the two largest cells."""

    measured_mb: float | None
    exponent: float | None
    extrapolated_mb: float | None


@dataclass(frozen=True)
class Spread:
    """A figure over the repeats of one cell: median and range."""

    median: float
    low: float
    high: float
    n: int


@dataclass(frozen=True)
class SfMRow:
    """One variant on one view count over its repeats (a row of bench.md)."""

    label: str                         # ours-1w, ours-2w, pycolmap-1t, pycolmap-2t
    method: str
    parallel: int
    views: int
    total_s: Spread
    cpu_s: Spread | None
    stages_s: dict[str, Spread]        # stage -> wall seconds over the repeats
    stage_peak_mb: dict[str, float]    # stage -> largest peak (main process + workers) over the repeats
    peak_mb: float                     # largest ru_maxrss of the cell process over the repeats
    registered_images: int
    tie_points_2v: int | None
    tie_points_3v: int | None
    rotation_error_deg: float | None   # median over the repeats
    load_average_1min: Spread | None   # at the cells' starts


@dataclass(frozen=True)
class SfMChecks:
    """The done-when checks of issues 13, 14 and 34 that the cells allow (None: not tested)."""

    time_ratio_168: float | None = None          # ours 2 workers / pycolmap 2 threads (medians)
    time_ratio_168_ok: bool | None = None
    time_ratio_168_1core: float | None = None    # ours 1 / pycolmap 1 thread
    cpu_ratio_168: float | None = None           # CPU seconds, 2-core columns
    tie_ratio_168: float | None = None           # tracks with >= 2 registered views, ours / pycolmap
    tie_ratio_168_ok: bool | None = None
    tie_ratio_168_3v: float | None = None        # tracks with >= 3 registered views
    rotation_error_168_ok: bool | None = None
    same_pairs_168: bool | None = None
    speedup_168: dict[str, float] = field(default_factory=dict)   # method -> time on 1 / time on 2 cores
    ours_total_exponent_ok: bool | None = None
    ours_memory_631_mb: float | None = None
    ours_memory_631_source: str = "not tested"
    ours_memory_631_ok: bool | None = None


@dataclass(frozen=True)
class SfMBench:
    """``bench.json``: every cell, the rows over repeats, growth exponents (variant -> stage -> k), checks."""

    settings: BenchSfMSettings
    environment: Provenance
    cells: list[SfMCell]
    failed: list[FailedCell] = field(default_factory=list)
    rows: list[SfMRow] = field(default_factory=list)
    growth_exponents: dict[str, dict[str, float | None]] = field(default_factory=dict)
    peak_memory: dict[str, MemoryFit] = field(default_factory=dict)
    checks: SfMChecks = SfMChecks()
    load_average: tuple[float, ...] = ()   # when bench.json was written

    def to_json(self) -> dict:
        """bench.json's layout: the cells (and failed cells) in their files' layout, the rest as it is."""
        data = records.to_dict(dataclasses.replace(self, cells=[], failed=[]))
        return dict(data, cells=[c.to_json() for c in self.cells], failed=[f.to_json() for f in self.failed])

    @staticmethod
    def from_json(data, label: str = "bench.json") -> SfMBench:
        if not isinstance(data, dict):
            raise records.RecordError(f"{label}: should be an object")
        cells = [SfMCell.from_json(c, f"{label} cells[{i}]") for i, c in enumerate(data.get("cells", []))]
        failed = [FailedCell.from_json(c, f"{label} failed[{i}]") for i, c in enumerate(data.get("failed", []))]
        rest = records.from_dict(SfMBench, dict(data, cells=[], failed=[]), label=label)
        return dataclasses.replace(rest, cells=cells, failed=failed)


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


def dumps(record: SfMCell | SfMBench) -> str:
    """The record's JSON as the bench has always written it (indent 1, option objects as text)."""
    return json.dumps(record.to_json(), indent=1, default=json_default)


def write(record: SfMCell | SfMBench, path: Path) -> None:
    atomic_write(path, dumps(record))


def _upgrade_cell_json(data):
    """A cell of the first layout (one thread, budgets per method, settings as printed dicts) in
    today's: its settings become a MethodSettings record, nothing of the measurement changes."""
    if not isinstance(data, dict) or not isinstance(data.get("method_settings"), dict) \
            or "method" in data["method_settings"]:
        return data
    old, method = data["method_settings"], data.get("method")
    flat = flatten_settings(old)
    values = dict((x.name, json.loads(x.value)) for x in flat)
    if method == "ours":
        budget, size, ignore = values.get("features.max_num_features"), values.get("features.max_image_size"), False
    else:
        budget, size = values.get("colmap_sfm_options.max_num_features"), values.get("colmap_sfm_options.max_image_size")
        ignore = bool(values.get("incremental_options.triangulation.ignore_two_view_tracks", True))
    bench = dict(data.get("bench_settings") or {})
    threads = bench.pop("threads", 1)
    bench["max_num_features"] = int(budget or 0)
    settings = MethodSettings(str(method), int(threads), int(threads), int(budget or 0), int(size or 0), ignore,
                              str(bench.get("pairing", "")), flat)
    return dict(data, cpu_s=data.get("cpu_s"), bench_settings=bench, method_settings=records.to_dict(settings))


def read_cell(path: Path) -> SfMCell:
    """The cell at ``path``, strictly (RecordError naming the file and the key); cells of the first
    layout (before equal budgets, thread columns and typed settings) are read in today's."""
    return SfMCell.from_json(records.read_json(path), label=str(path))


def read_bench(path: Path) -> SfMBench:
    """``bench.json`` at ``path``, strictly (RecordError naming the file and the key)."""
    return SfMBench.from_json(records.read_json(path), label=str(path))
