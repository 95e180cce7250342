"""Data and HTML of the report's interactive 3D view (sparse points, camera frusta, dense cloud).

Everything is expressed in the ground-truth frame: each method's model is mapped by the same
Sim3 that ``polarref.metrics`` uses for its scores. To keep report.html small, every cloud is
subsampled to a cap by a seeded random choice, and its coordinates are quantized to 16 bits per
axis over the cloud's own box (the 0.5-99.5 percentile box grown by its own span on each side;
the few far outliers outside it are counted and left out). The data lives in ``metrics.json``
(``view3d``), so ``polarref report DIR`` redraws the view from that file alone.

The viewer itself (``viewer.js``, written for this project, no library) draws with the canvas 2D
API into an ImageData buffer with a depth test, so it needs no WebGL and works offline.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

from polarref.compare.schema import View3D, ViewCameras, ViewCloud, to_dict
from polarref.core.geometry import quat_from_rotmat

MAX_POINTS = 2000          # per sparse cloud (one per method)
MAX_DENSE_POINTS = 30000   # per dense cloud
MAX_REFERENCE_POINTS = 3000  # GT surface (mesh vertices)
_BOX_PERCENTILES = (0.5, 99.5)
_BOX_GROW = 1.0


def _subsample(n: int, cap: int, seed: int) -> np.ndarray:
    if n <= cap:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=cap, replace=False))


def quantize_cloud(key: str, label: str, kind: str, xyz: np.ndarray, rgb: np.ndarray | None,
                   seed: int, cap: int) -> ViewCloud:
    """Subsample ``xyz`` (N, 3) (GT frame) and ``rgb`` (N, 3) uint8 to ``cap`` points and quantize."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    rgb = np.full((len(xyz), 3), 170, np.uint8) if rgb is None else np.asarray(rgb, np.uint8).reshape(-1, 3)
    finite = np.isfinite(xyz).all(1)
    total = len(xyz)
    xyz, rgb = xyz[finite], rgb[finite]
    if len(xyz):
        lo, hi = np.percentile(xyz, _BOX_PERCENTILES, axis=0)
        span = np.maximum(hi - lo, 1e-9 * max(1.0, float(np.abs(xyz).max())))
        lo, hi = lo - _BOX_GROW * span, hi + _BOX_GROW * span
        inside = ((xyz >= lo) & (xyz <= hi)).all(1)
    else:
        lo, hi, inside = np.zeros(3), np.ones(3), np.zeros(0, bool)
    dropped = int(total - inside.sum())
    xyz, rgb = xyz[inside], rgb[inside]
    keep = _subsample(len(xyz), cap, seed)
    step = (hi - lo) / 65535.0
    q = np.clip(np.rint((xyz[keep] - lo) / step), 0, 65535).astype("<u2")
    return ViewCloud(key=key, label=label, kind=kind, total=total, count=len(keep), dropped=dropped,
                     origin=[float(v) for v in lo], step=[float(v) for v in step],
                     xyz_u16=base64.b64encode(q.tobytes()).decode("ascii"),
                     rgb_u8=base64.b64encode(np.ascontiguousarray(rgb[keep]).tobytes()).decode("ascii"))


def decode_cloud(c: ViewCloud) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (count, 3) float64, rgb (count, 3) uint8) of a stored cloud (the viewer does the same)."""
    q = np.frombuffer(base64.b64decode(c.xyz_u16), dtype="<u2").reshape(-1, 3).astype(np.float64)
    rgb = np.frombuffer(base64.b64decode(c.rgb_u8), dtype=np.uint8).reshape(-1, 3)
    return np.asarray(c.origin) + q * np.asarray(c.step), rgb


def _poses(items) -> list[list[float]]:
    """[(centre (3,), world_from_cam R (3, 3))] -> rows of 7 numbers, 7 significant digits."""
    return [[float(f"{v:.7g}") for v in (*c, *quat_from_rotmat(R))] for c, R in items]


def camera_layer(key: str, label: str, rec, sim=None) -> ViewCameras:
    """Registered cameras of ``rec``; ``sim`` (polarref.core.geometry.Sim3, GT <- rec) maps them to the GT frame."""
    items = []
    for im in sorted(rec.images.values(), key=lambda i: i.name):
        pose = im.cam_from_world if sim is None else sim.transform_pose(im.cam_from_world)
        items.append((pose.center, pose.R.T))
    return ViewCameras(key=key, label=label, poses=_poses(items))


def method_layers(key: str, label: str, rec, gt, seed: int) -> tuple[ViewCameras, ViewCloud] | None:
    """Cameras and sparse points of one method in the GT frame (None when it cannot be aligned)."""
    from polarref import metrics as M

    try:
        sim = M.align_to_gt(rec, gt)[0]
    except ValueError:
        return None
    ids, xyz = rec.points_array()
    rgb = np.array([rec.points3D[int(i)].color for i in ids], dtype=np.uint8).reshape(-1, 3)
    cloud = quantize_cloud(key, label, "sparse", sim.apply(xyz) if len(xyz) else xyz, rgb, seed, MAX_POINTS)
    return camera_layer(key, label, rec, sim), cloud


def add_method(view: View3D, key: str, label: str, rec, gt, seed: int) -> bool:
    """Add one method's cameras and sparse points; False when it could not be aligned to GT."""
    layers = method_layers(key, label, rec, gt, seed)
    if layers is None:
        return False
    view.cameras.append(layers[0])
    view.clouds.append(layers[1])
    return True


def new_view(gt, camera, mesh, seed: int) -> View3D:
    """An empty view holding the GT cameras (and the GT surface's vertices when there is a mesh)."""
    view = View3D(seed=seed, max_points=MAX_POINTS, max_dense_points=MAX_DENSE_POINTS,
                  tan_half_fov=[float(camera.width / (2 * camera.fx)), float(camera.height / (2 * camera.fy))],
                  cameras=[camera_layer("gt", "ground truth", gt)], clouds=[])
    if mesh is not None:
        view.clouds.append(quantize_cloud("gt-surface", "GT surface (mesh vertices)", "reference",
                                          np.asarray(mesh[0]), None, seed, MAX_REFERENCE_POINTS))
    return view


def add_dense(view: View3D, method: str, label: str, xyz: np.ndarray, rgb: np.ndarray | None,
              seed: int | None = None) -> ViewCloud:
    """Add a dense (fused) cloud, already in the GT frame, capped at ``view.max_dense_points``."""
    cloud = quantize_cloud(f"dense:{method}", f"dense: {label}", "dense", xyz, rgb,
                           view.seed if seed is None else seed, view.max_dense_points)
    view.clouds = [c for c in view.clouds if c.key != cloud.key] + [cloud]
    return cloud


def describe(view: View3D) -> str:
    """One sentence for the report saying how the view was subsampled and quantized."""
    clouds = ", ".join(f"{c.label} {c.count:,} of {c.total:,}" + (f" ({c.dropped} far outliers left out)"
                                                                      if c.dropped else "")
                       for c in view.clouds)
    return (f"Points drawn per cloud: at most {view.max_points:,} sparse / {view.max_dense_points:,} dense, "
            f"a seeded random subset (seed {view.seed}); coordinates quantized to 16 bits per axis over each "
            "cloud's box (the 0.5-99.5 percentile box grown by its span on each side; far outliers outside "
            f"it are left out). Drawn: {clouds or 'no clouds'}.")


_JS = Path(__file__).with_name("viewer.js")


def _page_data_to_json(view: View3D, colors: dict[str, str], visible: list[str]) -> str:
    """The viewer's data (viewer.js reads it): the view's record plus the layer colours and switches."""
    return json.dumps({**to_dict(view), "colors": colors, "visible": visible}, separators=(",", ":"))


def to_html(view: View3D, colors: dict[str, str], visible: list[str]) -> str:
    """A self-contained <div> with the canvas, layer toggles, the data and the viewer script.

    Args:
        colors: layer key -> "#rrggbb" (the figures' colours, so the view and the plots agree).
        visible: layer keys switched on when the page opens.
    """
    payload = _page_data_to_json(view, colors, visible).replace("</", "<\\/")
    return ('<div id="view3d" class="view3d"><canvas id="view3d-canvas" width="960" height="540" '
            'aria-label="3D view: drag to orbit, wheel to zoom, shift-drag to pan"></canvas>'
            '<div id="view3d-controls" class="view3d-controls"></div></div>'
            f'<script type="application/json" id="view3d-data">{payload}</script>'
            f"<script>{_JS.read_text(encoding='utf-8')}</script>")


__all__ = ["MAX_POINTS", "MAX_DENSE_POINTS", "add_dense", "add_method", "decode_cloud", "describe", "method_layers",
           "new_view", "quantize_cloud", "to_html"]
