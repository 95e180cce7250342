"""Dense stage 1: load the views of a model and choose each view's stereo neighbours.

A pair is useful for plane-sweep stereo when both cameras see the same surface (their optical
axes meet it from similar sides) and the triangulation angle at the surface is neither tiny
(depth noise ~ 1 / sin(angle)) nor large (the patches no longer look alike). The score of a pair
is a Gaussian in the triangulation angle at the scene points both views look at, centred on
``best_angle_deg``, times the fraction of the reference view's scene points the source sees
(COLMAP's patch-match view selection uses the same two ingredients on the sparse points).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3

log = logging.getLogger(__name__)

MIN_VIEWS = 3  # the consistency filter needs a reference view and two sources


@dataclass
class DenseView:
    """One registered image as the dense stage uses it.

    image: (H, W) float32 grey in [0, 1]; color: (H, W, 3) uint8 RGB;
    K: (3, 3) calibration matrix at the working resolution (COLMAP pixel origin).
    """

    name: str
    cam_from_world: Rigid3
    K: np.ndarray
    image: np.ndarray
    color: np.ndarray
    scale: float  # working resolution / file resolution


@dataclass
class ViewSelection:
    """Neighbours per reference view and the depth range each view sweeps."""

    neighbors: list[list[int]]       # per view: source view indices, best first
    scores: list[list[float]]
    depth_range: np.ndarray          # (N, 2) near, far along +z, model units


def load_views(image_dir: Path, rec, scale: float = 1.0) -> list[DenseView]:
    """Views of every registered image of ``rec`` (a Reconstruction), sorted by name.

    Raises:
        PolarrefError: a camera that is not distortion-free perspective, or an unreadable image.
    """
    views = []
    for im in sorted(rec.images.values(), key=lambda i: i.name):
        cam: Camera = rec.cameras[im.camera_id]
        if not cam.is_perspective or any(abs(c) > 0 for c in cam.distortion):
            raise PolarrefError(f"camera {im.camera_id} ({cam.model}) is not an undistorted "
                                "pinhole; plane-sweep stereo needs one")
        path = image_dir / im.name
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise PolarrefError(f"cannot read image {path}")
        if bgr.shape[:2] != (cam.height, cam.width):
            raise PolarrefError(f"image {path} is {bgr.shape[1]}x{bgr.shape[0]}, "
                                f"camera {im.camera_id} says {cam.width}x{cam.height}")
        K = cam.calibration_matrix().astype(np.float64)
        if scale != 1.0:
            w, h = round(cam.width * scale), round(cam.height * scale)
            bgr = cv2.resize(bgr, (w, h), interpolation=cv2.INTER_AREA)
            # Corner pixel origin: pixel coordinates scale exactly.
            K = np.diag([w / cam.width, h / cam.height, 1.0]) @ K
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
        views.append(DenseView(im.name, im.cam_from_world, K, grey, rgb, scale))
    return views


def scene_points(rec, views: list[DenseView], bounds, max_points: int = 4000, seed: int = 0) -> np.ndarray:
    """(P, 3) points sampling the scene: the sparse points, else ``bounds``: surface points (N, 3)
    or a bounding sphere (centre (3,), radius)."""
    _, X = rec.points_array()
    rng = np.random.default_rng(seed)
    if len(X) < 20 and isinstance(bounds, np.ndarray):
        X = bounds
    if len(X) >= 20:
        return X if len(X) <= max_points else X[rng.choice(len(X), max_points, replace=False)]
    if bounds is None:
        raise PolarrefError("the model has no 3D points and no scene bounds were given; "
                            "cannot choose depth ranges")
    center, radius = bounds
    # Sample the bounding sphere's volume: depth ranges and overlaps then err on the safe side.
    d = rng.normal(size=(max_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return center + radius * d * rng.uniform(0, 1, (max_points, 1)) ** (1 / 3)


def select_views(views: list[DenseView], points: np.ndarray, num_sources: int = 4,
                 best_angle_deg: float = 14.0, sigma_deg: float = 8.0,
                 min_angle_deg: float = 2.0) -> ViewSelection:
    """Best ``num_sources`` neighbours per view and per-view depth range from ``points`` (P, 3)."""
    n = len(views)
    if n < MIN_VIEWS:
        raise PolarrefError(f"{n} registered view(s); need at least {MIN_VIEWS}")
    centers = np.array([v.cam_from_world.center for v in views])
    vis = np.zeros((n, len(points)), bool)
    near_far = np.zeros((n, 2))
    for i, v in enumerate(views):
        Xc = v.cam_from_world.apply(points)
        z = Xc[:, 2]
        uv = Xc[:, :2] / np.maximum(z, 1e-12)[:, None] @ v.K[:2, :2].T + v.K[:2, 2]
        h, w = v.image.shape
        vis[i] = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        if vis[i].sum() < 3:
            near_far[i] = np.nan
            continue
        zi = z[vis[i]]
        lo, hi = np.percentile(zi, [1, 99])
        pad = 0.05 * (hi - lo) + 1e-6 * hi
        near_far[i] = max(lo - pad, 1e-3 * hi), hi + pad
    neighbors, scores = [], []
    for i in range(n):
        row = []
        for j in range(n):
            common = vis[i] & vis[j]
            if j == i or common.sum() < 3:
                continue
            a = points[common] - centers[i]
            b = points[common] - centers[j]
            cosang = (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
            ang = float(np.degrees(np.median(np.arccos(np.clip(cosang, -1, 1)))))
            if ang < min_angle_deg:
                continue
            overlap = common.sum() / max(vis[i].sum(), 1)
            row.append((overlap * np.exp(-0.5 * ((ang - best_angle_deg) / sigma_deg) ** 2), j))
        row.sort(reverse=True)
        row = [r for r in row if r[0] > 1e-3][:num_sources]
        neighbors.append([j for _, j in row])
        scores.append([float(s) for s, _ in row])
    return ViewSelection(neighbors, scores, near_far)
