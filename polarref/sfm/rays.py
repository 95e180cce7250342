"""Pixels <-> camera-frame rays for the SfM stages (thin layer over :class:`polarref.camera.Camera`)."""

from __future__ import annotations

import numpy as np


def mean_focal(camera) -> float:
    """Mean focal length in px (converts pixel thresholds into normalized/angular ones)."""
    return 0.5 * (float(camera.fx) + float(camera.fy))


def bearings(camera, uv: np.ndarray) -> np.ndarray:
    """Unit camera-frame rays (N, 3) of pixels uv (N, 2) (COLMAP convention); NaN if unreachable."""
    return np.asarray(camera.unproject(np.asarray(uv, dtype=np.float64).reshape(-1, 2)), dtype=np.float64)


def normalized(rays: np.ndarray) -> np.ndarray:
    """(N, 3) rays -> (N, 2) normalized coordinates x/z, y/z (NaN for z <= 0)."""
    z = rays[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(z > 1e-12, rays[:, :2] / z, np.nan)


def project(camera, X_cam: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of camera-frame points (N, 3); NaN where not visible."""
    X = np.asarray(X_cam, dtype=np.float64).reshape(-1, 3)
    uv = np.asarray(camera.project(X), dtype=np.float64).reshape(-1, 2)
    uv[~(X[:, 2] > 0)] = np.nan  # perspective SfM: a point behind the camera is never an inlier
    return uv
