"""The typed record of one ``polarref sfm`` run (``OUT/metrics.json``).

:func:`polarref.sfm.pipeline.run_sfm` fills one :class:`SfMReport` stage by stage; the scores of
the finished model are one :class:`polarref.metrics.ReconstructionMetrics`, embedded, not copied.
The file (:meth:`SfMReport.to_json`) has the schema of ``polarref compare``'s metrics.json
for the scores: ``schema_version`` and the metrics record as one object under ``"metrics"``
(read back with :func:`polarref.metrics.read_metrics`); keys of stages that did not run are left out.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from polarref.core import records
from polarref.metrics import SCHEMA_VERSION, ReconstructionMetrics
from polarref.core.provenance import Provenance
from polarref.io.scene_folder import SkippedImage
from polarref.sfm.ba_runs import BARun, ColmapBARun  # noqa: F401 (re-exported)
from polarref.sfm.budget import FeatureBudget
from polarref.sfm.calibration import CameraReport
from polarref.sfm.config import SfMConfig
from polarref.core.status import RunStatus




@dataclass(frozen=True)
class ModelSummary:
    """One model of a run (photos that do not connect give several; the largest is ``model/``)."""

    folder: str                      # relative to the output folder: model, model-2, ...
    num_registered: int
    tie_points: int
    images: list[str]                # registered image names, in registration order
    initial_pair: list[str]


@dataclass(frozen=True)
class UnregisteredImage:
    """An image in no model, and why."""

    name: str
    reason: str


@dataclass
class SfMReport:
    """What one SfM run did and how good its model is."""

    image_dir: str
    config: SfMConfig
    environment: Provenance
    status: RunStatus = RunStatus.RUNNING
    error: str = ""                      # why it failed ("" unless failed)
    skipped_images: list[SkippedImage] = field(default_factory=list)
    num_images: int | None = None        # readable + skipped
    num_verified_pairs: int | None = None
    num_tracks: int | None = None
    num_conflicting_tracks_dropped: int | None = None
    initial_pair: list[str] | None = None
    registration_order: list[str] | None = None
    unregistered_images: list[str] | None = None
    unregistered: list[UnregisteredImage] | None = None  # the same images with the reason
    models: list[ModelSummary] | None = None   # every model, largest first (metrics: the first)
    feature_budget: FeatureBudget | None = None   # image size and keypoints used (sfm/budget.py)
    guided_observations: int | None = None
    ba: list[BARun] | None = None        # every bundle adjustment of the mapper, in order
    refine: list[str] | None = None          # intrinsics groups refined
    cameras: list[CameraReport] | None = None    # start, refined and GT intrinsics per camera
    metrics: ReconstructionMetrics | None = None   # scores of the finished model
    gt_skipped: str = ""                 # why the GT comparison was not made ("" when made or no GT)
    runtime_s: dict[str, float | bool] = field(default_factory=dict)   # stage -> s; *_cached flags

    def to_json(self) -> dict[str, Any]:
        """The metrics.json object: flat, stages that did not run and empty reasons left out."""
        out: dict[str, Any] = {"schema_version": SCHEMA_VERSION}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "metrics":
                if value is not None:
                    out["metrics"] = records.to_dict(value)
                continue
            if f.name == "ba" and value is not None:
                value = [b.to_json() for b in value]
            if value is None or (f.name in ("error", "gt_skipped") and not value):
                continue
            out[f.name] = records._clean(dataclasses.asdict(value) if dataclasses.is_dataclass(value) else
                                         [dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v
                                          for v in value] if isinstance(value, list) else value)
        return out
