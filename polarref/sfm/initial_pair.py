"""Stage 5: choice of the initial image pair (many inliers AND a wide triangulation angle)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.sfm.triangulation import midpoint_two_view
from polarref.sfm.verification import TwoViewGeometry


@dataclass(frozen=True)
class InitConfig:
    """Initial pair settings."""

    min_angle_deg: tuple[float, ...] = (16.0, 8.0, 4.0, 2.0)  # tried in turn (COLMAP starts at 16)
    min_points: int = 100          # a pair qualifies with this many inliers above the angle
    max_candidates: int = 30       # pairs (by inlier count) examined


@dataclass
class InitialPair:
    pair: tuple[int, int]
    num_points: int
    min_angle_deg: float


def pair_angles_deg(geom: TwoViewGeometry, rays1: np.ndarray, rays2: np.ndarray) -> np.ndarray:
    """Triangulation angle (deg) of each inlier, NaN when parallel or behind a camera.

    Args:
        rays1, rays2: (K1, 3), (K2, 3) unit bearings of all keypoints.
    """
    pose = geom.cam2_from_cam1
    b1 = rays1[geom.inliers[:, 0]]
    b2 = rays2[geom.inliers[:, 1]] @ pose.R  # R^T b2: into camera 1's frame (= world)
    C2 = np.broadcast_to(pose.center, b1.shape)
    res = midpoint_two_view(np.zeros_like(b1), b1, C2, b2)
    r1 = res.X
    r2 = res.X - C2
    cos = np.einsum("ij,ij->i", r1, r2) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
    ang = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    ang[~res.valid] = np.nan
    return ang


def choose_initial_pair(geoms: dict[tuple[int, int], TwoViewGeometry], rays: list[np.ndarray],
                        config: InitConfig) -> InitialPair:
    """The pair with most inliers above the first angle threshold that some pair satisfies."""
    if not geoms:
        raise PolarrefError("no image pair passed geometric verification; cannot initialize")
    cands = sorted(geoms.values(), key=lambda g: (-len(g.inliers), g.pair))[: config.max_candidates]
    angles = [pair_angles_deg(g, rays[g.pair[0]], rays[g.pair[1]]) for g in cands]
    for thr in config.min_angle_deg:
        scores = [int(np.sum(a >= thr)) for a in angles]
        best = int(np.argmax(scores))
        if scores[best] >= config.min_points:
            return InitialPair(cands[best].pair, scores[best], thr)
    # Fall back: the best count at the last (smallest) angle just tried, whatever it is.
    if scores[best] < 15:
        raise PolarrefError(f"no initial pair with >= 15 points above {thr} deg triangulation angle "
                            f"(best {cands[best].pair}: {scores[best]}); the views may lack parallax")
    return InitialPair(cands[best].pair, scores[best], thr)
