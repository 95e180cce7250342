"""Stage 3: geometric verification by essential-matrix RANSAC with the known camera.

Keypoints are turned into normalized coordinates with the (fixed) camera, the five-point
solver runs inside OpenCV's USAC_ACCURATE (RANSAC with local optimization; plain RANSAC
returns the best minimal-sample model, 2.5 deg off on a test where the optimum is 0.33 deg), and the cheirality test of
``recoverPose`` removes inliers that triangulate behind either camera.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from polarref.core.geometry import Rigid3
from polarref.core.progress import track
from polarref.sfm.matching import ByPair, Pair


@dataclass(frozen=True)
class VerifyConfig:
    """Essential-matrix RANSAC settings."""

    max_error_px: float = 4.0     # RANSAC threshold on the epipolar error, in px (COLMAP default; 2 px gave
    #                               shorter tracks and 0.084 vs 0.062 deg on the 28-view comet)
    confidence: float = 0.9999    # RANSAC success probability
    max_iterations: int = 10000   # RANSAC iteration cap
    min_inliers: int = 15         # fewer verified matches: the pair is dropped (COLMAP's default)
    min_inlier_ratio: float = 0.25  # fewer inliers / matches: dropped (COLMAP's default)
    seed: int = 0                 # RANSAC seed; pair (i, j) uses seed + 7919 i + j
    # images whose focal length is only a guess (no EXIF): a pair with one of them is verified by
    # a fundamental matrix (7 DoF, valid whatever the focal length; COLMAP's UNCALIBRATED case)
    # instead of an essential matrix built on the guess, which rejects true matches once the
    # guess is tens of percent off. Set by the pipeline from the cameras' sources.
    uncalibrated_images: tuple[int, ...] = ()


@dataclass
class TwoViewGeometry:
    """A verified pair: inlier matches and the relative pose ``cam2_from_cam1`` (unit baseline)."""

    pair: tuple[int, int]
    inliers: np.ndarray            # (M, 2) int keypoint indices
    cam2_from_cam1: Rigid3
    num_matches: int


def verify_pair(xy1: np.ndarray, xy2: np.ndarray, matches: np.ndarray, focal: float,
                config: VerifyConfig, seed: int, calibrated: bool = True) -> TwoViewGeometry | None:
    """Verify one pair.

    Args:
        xy1, xy2: (K1, 2), (K2, 2) normalized coordinates (x/z, y/z) of all keypoints.
        matches: (M, 2) putative matches.
        focal: mean focal length in px (converts the pixel threshold).
        calibrated: False: inliers from a fundamental matrix; the pose is then that of the
            nearest essential matrix under the guessed intrinsics (a start for the mapper).
    Returns:
        The geometry, or None when the pair fails the inlier thresholds.
    """
    import cv2

    if len(matches) < max(config.min_inliers, 5):
        return None
    p1 = np.ascontiguousarray(xy1[matches[:, 0]], dtype=np.float64)
    p2 = np.ascontiguousarray(xy2[matches[:, 1]], dtype=np.float64)
    cv2.setRNGSeed(int(seed))
    thr = config.max_error_px / focal
    if calibrated:
        E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), cv2.USAC_ACCURATE, config.confidence, thr,
                                       config.max_iterations)
    else:
        # in normalized coordinates (an isotropic affine map of the pixels) F is the same
        # epipolar geometry, and the same threshold in px / f
        # OpenCV 5's USAC_ACCURATE asserts on some 7-point samples: its plain RANSAC does not
        F, mask = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, thr, config.confidence, config.max_iterations)
        if F is None or mask is None or mask.sum() < config.min_inliers:
            return None
        # the pose: an essential matrix on F's inliers under the guess, at a threshold wide
        # enough for the guess's error (the inliers stay F's)
        s_ = mask.ravel().astype(bool)
        E, _ = cv2.findEssentialMat(p1[s_], p2[s_], np.eye(3), cv2.USAC_ACCURATE, config.confidence, 10 * thr,
                                    config.max_iterations)
    if E is None or mask is None:
        return None
    E = E[:3]  # several solutions come stacked (3k, 3): take the first
    mask = mask.ravel().astype(bool)
    if mask.sum() < config.min_inliers:
        return None
    _, R, t, pose_mask = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask.astype(np.uint8).copy())
    inl = pose_mask.ravel() > 0
    n = int(inl.sum())
    if n < config.min_inliers or n < config.min_inlier_ratio * len(matches):
        return None
    return TwoViewGeometry((0, 0), matches[inl], Rigid3(R, t.ravel()), len(matches))


@dataclass(frozen=True, eq=False)
class VerifiedPairs(ByPair[TwoViewGeometry]):
    """The pairs that passed verification, in the order they were matched, with their geometry."""


def verify_pairs(xy: list[np.ndarray], matches: Mapping[Pair, np.ndarray], focal: float,
                 config: VerifyConfig) -> VerifiedPairs:
    """Verify every matched pair; the ones that pass, in the order of ``matches``.

    Args:
        xy: per image the (K_i, 2) normalized keypoint coordinates (None for images in no pair).
        matches: pair (i, j) -> (M, 2) int keypoint indices (:class:`polarref.sfm.matching.PairMatches`).
    """
    out: dict[Pair, TwoViewGeometry] = {}
    guessed = set(config.uncalibrated_images)
    for (i, j), m in track(list(matches.items()), desc="verification"):
        g = verify_pair(xy[i], xy[j], m, focal, config, config.seed + 7919 * i + j,
                        calibrated=i not in guessed and j not in guessed)
        if g is not None:
            g.pair = (i, j)
            out[(i, j)] = g
    return VerifiedPairs(tuple(out), tuple(out.values()))
