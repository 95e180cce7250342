"""Stage 6: absolute pose (PnP RANSAC on normalized coordinates), then refinement.

OpenCV's P3P RANSAC finds the pose and the inliers from 2D-3D correspondences in normalized
coordinates (the camera is known and fixed); Levenberg-Marquardt then refines on the inliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.camera import Camera
from polarref.core.geometry import Rigid3, so3_exp


@dataclass(frozen=True)
class RegisterConfig:
    """PnP settings."""

    max_error_px: float = 4.0    # RANSAC reprojection threshold in px (COLMAP abs_pose_max_error 12)
    confidence: float = 0.9999   # RANSAC success probability
    max_iterations: int = 10000  # RANSAC iteration cap
    min_inliers: int = 30        # fewer: registration fails (COLMAP abs_pose_min_num_inliers)
    min_inlier_ratio: float = 0.25  # fewer inliers / correspondences: fails (COLMAP abs_pose_min_inlier_ratio)
    # threshold of the retries after the map grew; its pose is refined by local BA and its
    # observations filtered at the triangulation's threshold. Not COLMAP's 12 px: at 12 px, 7
    # mirrored 320x240 views (a second scene, a few symmetric matches to the first) registered
    # into the first scene's model; at 4 or 8 px they formed their own model (test_sfm_collections)
    retry_max_error_px: float = 8.0
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


@dataclass(frozen=True)
class FocalPoseEstimate:
    """Pose and camera of an image registered with an unknown focal length."""

    cam_from_world: Rigid3
    inliers: np.ndarray  # (M,) indices into the correspondences
    camera: Camera       # the guess with the estimated focal length


def estimate_pose_and_focal(uv: np.ndarray, X: np.ndarray, camera, config: RegisterConfig,
                            seed: int) -> FocalPoseEstimate | None:
    """Pose and focal length of an image whose focal length is only a guess.

    COLMAP's estimator (pycolmap ``estimate_and_refine_absolute_pose`` with
    ``estimate_focal_length``: P4Pf in LO-RANSAC, then refinement of pose and focal length);
    principal point and distortion stay those of ``camera``.

    Args:
        uv: (N, 2) pixels (COLMAP convention); X: (N, 3) world points.
        camera: :class:`polarref.camera.Camera` holding the guess (SIMPLE_RADIAL / PINHOLE family).
    Returns:
        The estimate, or None when RANSAC fails or finds too few inliers.
    """
    import pycolmap

    if len(uv) < max(config.min_inliers, 4):
        return None
    pcam = camera.to_pycolmap(camera_id=1)
    est = pycolmap.AbsolutePoseEstimationOptions()
    est.estimate_focal_length = True
    est.ransac.max_error = config.max_error_px
    est.ransac.confidence = config.confidence
    est.ransac.max_num_trials = config.max_iterations
    est.ransac.random_seed = int(seed) % (2 ** 31)
    ref = pycolmap.AbsolutePoseRefinementOptions()
    ref.refine_focal_length = True
    ref.refine_extra_params = False
    res = pycolmap.estimate_and_refine_absolute_pose(np.ascontiguousarray(uv, np.float64),
                                                     np.ascontiguousarray(X, np.float64), pcam, est, ref)
    if res is None:
        return None
    inl = np.flatnonzero(np.asarray(res["inlier_mask"], bool))
    params = np.asarray(pcam.params, np.float64)
    if (len(inl) < config.min_inliers or len(inl) < config.min_inlier_ratio * len(uv)
            or not np.all(np.isfinite(params)) or pcam.mean_focal_length() <= 0):
        return None
    pose = res["cam_from_world"]
    return FocalPoseEstimate(Rigid3(pose.rotation.matrix(), np.asarray(pose.translation)), inl,
                             Camera(camera.model, camera.width, camera.height, params))
