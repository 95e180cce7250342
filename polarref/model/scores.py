"""The records a reconstruction's scores are written as (computed by :mod:`polarref.metrics`).

They live in the data model, beside :class:`polarref.model.run.MethodRun` which embeds them;
:mod:`polarref.metrics` computes them and re-exports them under their old names.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class ImageGTErrors:
    """Errors of one registered image after the alignment to ground truth."""

    rotation_error_deg: float
    center_error_rel: float             # centre error / scene_size
    rotation_error_rotalign_deg: float  # after a rotation-only alignment (gauge-free in rotation)


@dataclass
class GTErrors:
    num_matched: int               # estimated images also present in GT (by name)
    alignment: str                 # "umeyama_centers" | "rotations_then_centers"
    num_alignment_outliers: int    # cameras left out of the final alignment fit
    scale: float                   # s of gt ~ s R est + t
    scene_size: float              # see module docstring
    rotation_error_deg_mean: float
    rotation_error_deg_median: float
    rotation_error_deg_max: float
    center_error_rel_mean: float
    center_error_rel_median: float
    center_error_rel_max: float
    rotation_error_rotalign_deg_mean: float
    rotation_error_rotalign_deg_max: float
    per_image: dict[str, ImageGTErrors]   # image name -> its errors


@dataclass
class SurfaceErrors:
    """Point-to-surface distances (undefined, NaN when computed and None when read, without points)."""

    num_points: int
    mean: float | None             # GT units
    median: float | None
    p90: float | None
    mean_rel: float | None         # mean / scene_size
    median_rel: float | None


# Version of the one metrics.json schema written by ``polarref sfm`` and ``polarref compare``:
# both embed a ReconstructionMetrics as one object under "metrics" (v1: compare spelled its own
# names per method, sfm wrote the fields at the top level; see polarref.compare.schema's v1 reader).
SCHEMA_VERSION = 2


@dataclass
class ReconstructionMetrics:
    """The scores of one reconstruction, the one record embedded in every metrics.json.

    A mean over nothing is NaN when computed and ``None`` once read back (JSON has no NaN);
    ``None`` also marks a figure an older file did not record (v1 compare files lack the
    median error and the mean track length).
    """

    num_images: int
    registered_images: int
    tie_points: int
    reprojected_px: int
    mean_reprojection_error_px: float | None
    mean_reprojection_error_px_per_point: float | None
    median_reprojection_error_px: float | None
    mean_track_length: float | None
    gt: GTErrors | None = None
    surface: SurfaceErrors | None = None

    def to_dict(self) -> dict:
        return asdict(self)
