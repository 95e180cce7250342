"""Noisy pose priors beside the exact ground truth: GPS/INS-like (UAV) or orbit-determination-like
(comet).

Navigation errors drift rather than jump from image to image, so each error component is an
AR(1) sequence along the image order with stationary standard deviation ``sigma`` and lag-one
correlation ``rho``. The priors never decide pixels: they are drawn from the GT poses with their
own seed stream and written to ``scene.json`` (``priors``).
"""

from __future__ import annotations

import math

import numpy as np

from polarref.core.geometry import Rigid3, so3_exp
from polarref.georef.scene_priors import PRIORS_FORMAT  # one name for the writer and the reader
from synth.config import SceneConfig


def _ar1(rng: np.random.Generator, n: int, dim: int, rho: float) -> np.ndarray:
    """(n, dim) unit-variance AR(1) sequence with lag-one correlation ``rho``."""
    out = np.empty((n, dim))
    out[0] = rng.normal(0, 1, dim)
    innov = math.sqrt(max(1.0 - rho * rho, 0.0))
    for k in range(1, n):
        out[k] = rho * out[k - 1] + innov * rng.normal(0, 1, dim)
    return out


def position_sigmas(cfg: SceneConfig, centers: np.ndarray, scene_center: np.ndarray) -> np.ndarray:
    """(n, 3) 1-sigma of each view's prior centre, metres (x, y, z of the world frame)."""
    p = cfg.priors
    n = len(centers)
    if cfg.scene == "uav":
        vert = p.vertical_sigma_m or p.position_sigma_m
        return np.tile([p.position_sigma_m, p.position_sigma_m, vert], (n, 1))
    rng_m = np.linalg.norm(centers - scene_center, axis=1)
    return np.repeat((p.position_sigma_m + p.position_sigma_rel * rng_m)[:, None], 3, axis=1)


def draw_priors(cfg: SceneConfig, poses: list[Rigid3], scene_center: np.ndarray) -> dict | None:
    """Priors for ``poses`` (cam_from_world, GT) as a scene.json section; None when disabled.

    Returns ``{"format", "seed", "params", "views": [{"center", "qvec", "tvec", "center_sigma_m",
    "rotation_sigma_deg"}]}`` in image order (cam_from_world, COLMAP quaternion w, x, y, z).
    """
    p = cfg.priors
    if p.position_sigma_m <= 0 and p.position_sigma_rel <= 0 and p.rotation_sigma_deg <= 0:
        return None
    n = len(poses)
    rng = np.random.default_rng([cfg.seed, 97])  # own stream: the scene itself is untouched
    centers = np.array([q.center for q in poses])
    sig = position_sigmas(cfg, centers, np.asarray(scene_center, float))
    d_center = _ar1(rng, n, 3, p.correlation) * sig
    d_rot = _ar1(rng, n, 3, p.correlation) * math.radians(p.rotation_sigma_deg)
    views = []
    for i, pose in enumerate(poses):
        # Attitude error in the camera frame (an INS/star-tracker error rotates the camera).
        R = so3_exp(d_rot[i]) @ pose.R
        c = centers[i] + d_center[i]
        prior = Rigid3(R, -R @ c)
        views.append({"center": c.tolist(), "qvec": prior.quat.tolist(), "tvec": prior.t.tolist(),
                      "center_sigma_m": sig[i].tolist(), "rotation_sigma_deg": p.rotation_sigma_deg})
    return {"format": PRIORS_FORMAT, "seed": [cfg.seed, 97],
            "params": {"position_sigma_m": p.position_sigma_m, "position_sigma_rel": p.position_sigma_rel,
                       "vertical_sigma_m": p.vertical_sigma_m, "rotation_sigma_deg": p.rotation_sigma_deg,
                       "correlation": p.correlation},
            "views": views}
