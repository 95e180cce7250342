"""Scores of a reconstruction: sparse (poses, points, reprojection; :mod:`.sparse`), dense
surfaces (:mod:`.surface`) and the point-to-mesh distance both use (:mod:`.distance`)."""

from polarref.metrics.sparse import (  # noqa: F401
    COLLINEAR_RATIO,
    ImageGTErrors,
    GTErrors,
    SurfaceErrors,
    SCHEMA_VERSION,
    ReconstructionMetrics,
    observation_errors,
    mean_error_per_point,
    align_to_gt,
    scene_size,
    gt_errors,
    surface_errors,
    evaluate,
    read_metrics,
    write_json,
)
from polarref.metrics.surface import (  # noqa: F401
    SurfaceScore,
    mesh_diameter,
    sample_mesh,
    score_cloud,
    score_mesh,
)
from polarref.metrics.distance import (  # noqa: F401
    closest_points_on_triangles,
    point_to_mesh_distance,
)
