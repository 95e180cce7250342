"""Typed, versioned schema of ``metrics.json``: the only input of every report.

``polarref compare`` fills these dataclasses and writes them with :func:`save`;
``polarref report`` reads them back with :func:`load` and never recomputes anything.
Unknown keys and a newer ``schema_version`` are errors, so a stale or hand-edited file
fails loudly instead of rendering half a report.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import ClassVar

from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError
from polarref.metrics import SCHEMA_VERSION, ReconstructionMetrics
from polarref.core.status import RunStatus
from polarref.model.run import TracePoint  # noqa: F401 (part of the schema)

_METRIC_FIELDS = frozenset(f.name for f in fields(ReconstructionMetrics))


VERDICTS = ("supported", "not supported", "inconclusive", "not tested",
            "frame-dependent",   # issue 30: the verdict changed under a similarity of the world
            "underpowered")      # issue 30: the experiment could not detect an effect of the paper's size


@dataclass
class SceneInfo:
    """What was reconstructed."""

    name: str                 # scene key, e.g. "comet-small" or "strecha_fountain-P11"
    kind: str                 # "synthetic" or "real"
    source: str               # folder the images came from (as given on the command line)
    preset: str               # render preset or "" for a real image set
    seed: int                 # render seed (-1 for real data)
    num_images: int
    width: int                # image size actually used (after any downscaling)
    height: int
    camera_model: str         # COLMAP model name of the fixed intrinsics
    camera_params: list[float]
    has_gt: bool
    has_mesh: bool
    downscale: float = 1.0    # original width / used width
    render_s: float = 0.0     # seconds spent rendering in this run (0 when reused)
    scene_extent: float = 0.0  # GT scene size: RMS distance of GT camera centres from their centroid


@dataclass
class GtAccuracy:
    """Errors after a Sim3 alignment of the estimate to ground truth."""

    aligned_images: int
    rotation_error_deg_mean: float
    rotation_error_deg_median: float
    rotation_error_deg_max: float
    center_error_mean: float          # scene units (GT frame)
    center_error_max: float
    center_error_rel_mean: float      # center_error_mean / scene_extent
    point_to_surface_mean: float | None = None   # scene units; None without a mesh
    point_to_surface_median: float | None = None
    point_to_surface_p90: float | None = None
    point_to_surface_rel_median: float | None = None
    points_scored: int = 0


@dataclass
class Histogram:
    """Binned values (counts per [edges[i], edges[i+1]))."""

    edges: list[float]
    counts: list[int]


@dataclass
class BATrace:
    """Convergence of one bundle adjustment run."""

    label: str                # e.g. "euclidean" or "pycolmap (Ceres)"
    problem: str              # which problem the trace comes from
    points: list[TracePoint]


@dataclass
class MethodPlot:
    """Small plot data kept in metrics.json so figures can be redrawn from it alone."""

    image_names: list[str] = field(default_factory=list)
    centers_est_aligned: list[list[float]] = field(default_factory=list)  # (N, 3), GT frame
    centers_gt: list[list[float]] = field(default_factory=list)           # (N, 3)
    points_sample: list[list[float]] = field(default_factory=list)        # (<= 3000, 3), GT frame
    reproj_hist: Histogram | None = None
    rotation_err_hist: Histogram | None = None
    surface_err_hist: Histogram | None = None
    rotation_err_deg: list[float] = field(default_factory=list)   # per image, image_names order
    track_length_hist: Histogram | None = None                    # observations per 3D point


@dataclass
class MethodResult:
    """One reconstruction method run on the scene, scored by ``polarref.metrics``."""

    name: str                 # stable key, e.g. "ours-polar" or "pycolmap-incremental-sift"
    label: str                # human label for tables
    family: str               # "ours" or "pycolmap"
    features: str             # "pycolmap-sift" or "ours"
    mapper: str               # "polarref-incremental", "pycolmap-incremental", "pycolmap-global"
    ba: str                   # BA parameterization or solver ("euclidean", ..., "ceres")
    status: RunStatus
    reason: str = ""          # why it failed / was skipped (empty when ok)
    runtime_s: float | None = None       # wall time of the whole method (features to final BA)
    stage_runtime_s: dict[str, float] = field(default_factory=dict)
    timeout_s: float | None = None
    num_images: int = 0
    metrics: ReconstructionMetrics | None = None   # polarref.metrics' one record, as written by `polarref sfm`
    gt: GtAccuracy | None = None
    plot: MethodPlot | None = None

    def set_metrics(self, m: ReconstructionMetrics) -> None:
        """Embed ``m`` as it reads back from metrics.json (non-finite figures become None)."""
        self.metrics = records.from_dict(ReconstructionMetrics, records.to_dict(m), label="metrics")

    def metric(self, name: str):
        """The figure ``name`` of :attr:`metrics` (a ReconstructionMetrics field), None without metrics."""
        if name not in _METRIC_FIELDS:
            raise AttributeError(f"ReconstructionMetrics has no field {name!r}")
        return None if self.metrics is None else getattr(self.metrics, name)


@dataclass
class MethodPair:
    """Which two methods a paper-style table compares (baseline first)."""

    title: str
    baseline: str             # MethodResult.name
    candidate: str            # MethodResult.name
    note: str = ""


@dataclass
class Figure:
    """A measured figure a verdict rests on."""

    key: str                  # referenced as {key} in a claim's rationale template
    label: str
    value: float | None
    unit: str = ""            # "count" = an integer count (formatted without decimals)


# ---- issue 30: a verdict under other frames of the world --------------------------------------


@dataclass
class DrawVerdict:
    """The verdict of one claim with the experiments rerun in one other frame of the world."""

    index: int
    kind: str                 # "similarity" (seeded random rotation, translation, scale) or "units"
    scale: float
    rotation_deg: float
    translation: float
    verdict: str              # one of VERDICTS


@dataclass
class ClaimInvariance:
    """Verdicts of one claim under the invariance draws (:mod:`polarref.compare.claims.invariance`)."""

    base_verdict: str         # in the experiments' own frame
    agree_share: float        # fraction of draws with the same verdict
    draws: list[DrawVerdict]


@dataclass
class ClaimResult:
    """One claim of the paper, its test, measurements and verdict."""

    claim_id: str
    claim: str                # what the paper says
    source: str               # where it says it
    test: str                 # how we tested it
    figures: list[Figure]
    sample_size: str          # e.g. "10^5 random angles", "1 scene x 2 methods"
    verdict: str              # one of VERDICTS
    rationale: str            # template: "{key}" placeholders filled from figures at report time
    summary: str = ""         # one-line template for the scorecard; "" = first clause of the rationale
    invariance: ClaimInvariance | None = None   # issue 30; None: not rerun in other frames


@dataclass
class Environment:
    """Where and how the run happened."""

    command: str              # exact command line
    created: str              # ISO timestamp of the compare run (stored, never regenerated)
    versions: dict[str, str]  # package -> version (from polarref doctor)
    cpu_count: int
    mitsuba_variant: str
    seeds: dict[str, int]
    preset: str
    method_timeout_s: float
    total_runtime_s: float
    run_budget_s: float | None = None   # whole-run limit (None = unlimited)
    # Provenance (polarref.core.provenance.collect), taken when the run starts:
    git_commit: str = ""                # HEAD, 40 hex digits ("" outside a git checkout)
    git_dirty: bool | None = None       # tracked files differ from HEAD (None: unknown)
    cpu_model: str = ""
    machine: str = ""                   # e.g. x86_64
    platform: str = ""
    threads: dict[str, int] = field(default_factory=dict)   # stage -> threads (pycolmap, BA BLAS, ...)


@dataclass
class ViewCloud:
    """One point cloud of the 3D view, subsampled and quantized (see ``polarref.compare.report.view3d``)."""

    key: str                  # method name, "gt-surface" or "dense:<method>"
    label: str
    kind: str                 # "sparse" | "dense" | "reference"
    total: int                # points before subsampling
    count: int                # points stored
    dropped: int              # far outliers outside the quantization box, left out
    origin: list[float]       # (3,) box corner, GT frame
    step: list[float]         # (3,) scene units per quantization step
    xyz_u16: str              # base64, (count, 3) uint16 little-endian
    rgb_u8: str               # base64, (count, 3) uint8


@dataclass
class ViewCameras:
    """Registered cameras of one method (or the ground truth) in the GT frame."""

    key: str                  # method name or "gt"
    label: str
    poses: list[list[float]]  # (N, 7): centre x y z, world_from_cam quaternion w x y z


@dataclass
class View3D:
    """Data of the interactive 3D view: estimates Sim3-aligned to the ground truth."""

    seed: int                 # subsampling seed
    max_points: int           # cap per sparse cloud
    max_dense_points: int     # cap per dense cloud
    tan_half_fov: list[float]  # (2,) frustum shape: width / (2 fx), height / (2 fy)
    cameras: list[ViewCameras]
    clouds: list[ViewCloud]


@dataclass
class DenseRun:
    """One dense reconstruction, scored in the GT frame (None = not measured)."""

    name: str                              # "gt" or a method name
    status: RunStatus
    message: str = ""
    out_dir: str = ""                      # relative to the report folder
    tau: float | None = None
    tau_rel: float | None = None
    cloud_fscore: float | None = None
    cloud_precision: float | None = None
    cloud_recall: float | None = None
    accuracy_median: float | None = None
    completeness_median: float | None = None
    mesh_fscore: float | None = None
    depth_median_abs: float | None = None
    fused_points: int = 0
    dense_runtime_s: float | None = None


@dataclass
class DenseSection:
    """``polarref compare --dense``: one run per pose source (:mod:`polarref.compare.run.dense`)."""

    runs: list[DenseRun] = field(default_factory=list)


@dataclass
class MetricsFile:
    """Everything a report shows."""

    SCHEMA_VERSION: ClassVar[int] = SCHEMA_VERSION
    schema_version: int
    scene: SceneInfo
    environment: Environment
    methods: list[MethodResult]
    pairs: list[MethodPair]
    claims: list[ClaimResult]
    ba_traces: list[BATrace] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    view3d: View3D | None = None
    dense: DenseSection | None = None  # compare --dense (polarref.compare.run.dense)

    def method(self, name: str) -> MethodResult | None:
        return next((m for m in self.methods if m.name == name), None)


# ---- (de)serialisation: polarref.core.records, labelled "metrics.json" ------------------------------

def to_dict(obj) -> dict:
    return records.to_dict(obj)


# v1 (compare only) spelled the metrics per method under its own names; v2 embeds the one
# ReconstructionMetrics record under "metrics". v1 did not record the median error or the
# mean track length (None after reading).
_V1_METRICS = {"registered_images": "registered_images", "tie_points": "tie_points",
               "reprojected_px": "reprojected_px", "mean_reprojection_error_px": "mean_reprojection_error_px",
               "mean_reprojection_error_per_point_px": "mean_reprojection_error_px_per_point"}


def _upgrade_v1(data: dict) -> dict:
    """A v1 metrics.json object in the v2 layout (same values; unknown keys are left for the strict read)."""
    data = dict(data, schema_version=SCHEMA_VERSION)
    methods = []
    for m in data.get("methods", []):
        if not isinstance(m, dict):
            methods.append(m)
            continue
        m = dict(m)
        old = {new: m.pop(name, None) for name, new in _V1_METRICS.items()}
        if any(v is not None for v in old.values()):
            m["metrics"] = {"num_images": m.get("num_images", 0), **old,
                            "median_reprojection_error_px": None, "mean_track_length": None}
        methods.append(m)
    data["methods"] = methods
    return data


def from_dict(data: dict) -> MetricsFile:
    """MetricsFile from parsed JSON, strictly; a v1 file is read through :func:`_upgrade_v1`."""
    if isinstance(data, dict) and data.get("schema_version") == 1 and not isinstance(data.get("schema_version"), bool):
        data = _upgrade_v1(data)
    return records.from_dict(MetricsFile, data, label="metrics.json", where="metrics")


def dumps(metrics: MetricsFile) -> str:
    """Indented JSON with innermost number lists on one line (plot arrays stay compact)."""
    return records.dumps(metrics)


def write_text_atomic(path: Path, text: str) -> None:
    """Write UTF-8 ``text`` beside ``path`` and rename it into place (never a truncated file)."""
    atomic_write(path, text)


def save(metrics: MetricsFile, path: str | Path) -> Path:
    """Write ``metrics.json`` atomically."""
    return records.save(metrics, path)


def load(path: str | Path) -> MetricsFile:
    path = Path(path)
    if not path.is_file():
        raise PolarrefError(f"metrics file not found: {path}")
    return from_dict(records.read_json(path))
