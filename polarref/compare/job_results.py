"""What a comparison job hands back: a shared stage's result and one method's run.

Kept apart from :mod:`polarref.compare.jobs` (which runs the jobs) so that the method modules
(:mod:`polarref.compare.ours`) can build these records without importing the job runner."""

from __future__ import annotations

from dataclasses import dataclass, field

from polarref.compare.schema import TracePoint
from polarref.io.scene_folder import SkippedImage


@dataclass
class SharedStageResult:
    """A stage several methods share (feature extraction/matching, a feature database)."""

    stage_runtime_s: dict[str, float]
    verified_pairs: int
    skipped_images: list[SkippedImage] = field(default_factory=list)


@dataclass
class MethodJobResult:
    """One reconstruction method's run: its model folder and timed stages."""

    model_dir: str                       # COLMAP text model
    stage_runtime_s: dict[str, float]
    wall_s: float | None = None          # the job's own wall time (ours only)
    num_ba_runs: int | None = None       # ours only
    num_models: int | None = None        # pycolmap only
    verified_pairs: int | None = None    # pycolmap only
    registered: int | None = None        # pycolmap only
    # ours: [iteration, wall_s, cost] of the accepted steps of the final global BA, from the initial cost
    final_ba_trace: list[TracePoint] | None = None
