"""Stage 6: absolute pose (PnP RANSAC on normalized coordinates), then refinement.

OpenCV's P3P RANSAC finds the pose and the inliers from 2D-3D correspondences in normalized
coordinates (the camera is known and fixed); Levenberg-Marquardt then refines on the inliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.core.geometry import Rigid3, so3_exp


@dataclass(frozen=True)
class RegisterConfig:
    """PnP settings."""

    max_error_px: float = 4.0    # RANSAC reprojection threshold in px (COLMAP abs_pose_max_error 12)
    confidence: float = 0.9999   # RANSAC success probability
    max_iterations: int = 10000  # RANSAC iteration cap
    min_inliers: int = 30        # fewer: registration fails (COLMAP abs_pose_min_num_inliers)
    min_inlier_ratio: float = 0.25  # fewer inliers / correspondences: fails (COLMAP abs_pose_min_inlier_ratio)
    seed: int = 0                # RANSAC seed (image index is added)


@dataclass
class PoseEstimate:
    cam_from_world: Rigid3
    inliers: np.ndarray  # (M,) indices into the correspondences


def estimate_pose(xy: np.ndarray, X: np.ndarray, focal: float, config: RegisterConfig,
                  seed: int) -> PoseEstimate | None:
    """PnP RANSAC + LM refinement.

    Args:
        xy: (N, 2) normalized coordinates (x/z, y/z); X: (N, 3) world points.
        focal: mean focal length in px (converts the threshold).
    Returns:
        The pose, or None when RANSAC fails or finds too few inliers.
    """
    import cv2

    if len(xy) < max(config.min_inliers, 4):
        return None
    obj = np.ascontiguousarray(X, dtype=np.float64)
    img = np.ascontiguousarray(xy, dtype=np.float64)
    thr = config.max_error_px / focal
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, np.eye(3), None, iterationsCount=config.max_iterations,
                                             reprojectionError=thr, confidence=config.confidence,
                                             flags=cv2.SOLVEPNP_AP3P)
    if not ok or inl is None or len(inl) < config.min_inliers:
        return None
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], np.eye(3), None, rvec, tvec)
    pose = Rigid3(so3_exp(rvec.ravel()), tvec.ravel())
    # Re-derive inliers with the refined pose (cheirality included).
    Xc = pose.apply(obj)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(Xc[:, :2] / Xc[:, 2:3] - img, axis=1)
    inliers = np.flatnonzero((Xc[:, 2] > 0) & (err < thr))
    if len(inliers) < config.min_inliers or len(inliers) < config.min_inlier_ratio * len(xy):
        return None
    return PoseEstimate(pose, inliers)
