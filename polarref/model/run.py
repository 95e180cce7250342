"""The one record of a method's run: ``MethodRun`` (ours or a peer's, in compare, twins and benches).

A job (one process, :mod:`polarref.core.isolated`) returns a MethodRun; the shared stages
several methods read (features and matches, a feature database) return one too, named after the
stage. The record crosses process and module boundaries only as itself: written with
:func:`polarref.core.records.save` / read back strictly with :func:`read` (``to_json`` /
``from_json`` for an embedded copy). Fields a kind of run does not have keep their defaults
(``None``, ``""``, empty), never a made-up 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from polarref.core import records
from polarref.core.status import RunStatus
from polarref.model.scores import ReconstructionMetrics


@dataclass(frozen=True)
class SkippedImage:
    """An image file a stage could not read, and why."""

    name: str
    reason: str


@dataclass(frozen=True)
class TracePoint:
    """One solver iteration (for convergence plots)."""

    iteration: int
    time_s: float
    cost: float


@dataclass(frozen=True)
class MethodRun:
    """One run of a reconstruction method, or of a stage methods share.

    ``stage_runtime_s`` maps a stage label (e.g. "features", "mapping (excl. BA)", "bundle
    adjustment") to its seconds; a method's runtime is their sum. ``wall_s`` is the run's own
    process wall time where the caller measured it; a run resumed over several processes counts
    ``counted_wall_s`` (summed over its ``segments``) instead.
    """

    method: str = ""                       # method key ("ours-polar", "pycolmap-global-sift") or shared stage
    form: str = ""                         # BA form (polarref.ba.parameterization.FORMS), "ceres" for pycolmap
    status: RunStatus = RunStatus.OK
    reason: str = ""                       # why it failed / was skipped (empty when ok)
    timeout_s: float | None = None         # the wall-clock limit it ran under (None: not recorded)
    stage_runtime_s: dict[str, float] = field(default_factory=dict)
    wall_s: float | None = None
    counted_wall_s: float | None = None    # resumable runs: wall time summed over the segments
    segments: int = 1                      # processes the run took (> 1: resumed from snapshots)
    peak_rss_mb: float | None = None       # largest resident set of the run's process
    model_dir: str = ""                    # COLMAP text model ("" for a shared stage)
    verified_pairs: int | None = None      # shared stages, peers
    registered: int | None = None          # peers: registered images as the peer counts them
    num_models: int | None = None          # peers: models the mapper produced
    num_ba_runs: int | None = None         # ours: bundle adjustments run
    skipped_images: list[SkippedImage] = field(default_factory=list)
    feature_file: str = ""                 # ours' feature stage: the cache (.npz) the methods read
    final_ba_trace: list[TracePoint] | None = None  # ours: accepted steps of the final global BA
    metrics: ReconstructionMetrics | None = None    # the model scored by polarref.metrics

    @property
    def ok(self) -> bool:
        return self.status == RunStatus.OK

    @property
    def runtime_s(self) -> float:
        """The sum of the timed stages."""
        return float(sum(self.stage_runtime_s.values()))


def to_json(run: MethodRun) -> dict:
    """The JSON-able form of ``run`` (as :func:`polarref.core.records.save` writes it)."""
    return records.to_dict(run)


def from_json(data, *, label: str = "method run") -> MethodRun:
    """A MethodRun from parsed JSON, strictly (unknown key, wrong type: RecordError)."""
    return records.from_dict(MethodRun, data, label=label)


def read(path: str | Path) -> MethodRun:
    """The MethodRun saved at ``path`` (RecordError naming the file and key when it does not match)."""
    return records.load(MethodRun, path)
