"""Unknown focal length: P4Pf registration (registration.estimate_pose_and_focal) and
F-matrix verification of guessed cameras."""

from __future__ import annotations

import numpy as np
import pytest

from polarref.camera import Camera
from polarref.core.geometry import Rigid3, so3_exp
from polarref.sfm.registration import RegisterConfig, estimate_pose_and_focal


def _points_and_pixels(rng, cam: Camera, pose: Rigid3, n: int, noise_px: float):
    X = rng.uniform(-2, 2, size=(n, 3)) + [0, 0, 8.0]
    Xw = (X - pose.t) @ pose.R  # world points whose camera-frame coordinates are X
    uv = np.asarray(cam.project(X)) + rng.normal(scale=noise_px, size=(n, 2))
    return Xw, uv


@pytest.mark.parametrize("guess_factor", [0.7, 1.3])
def test_p4pf_recovers_focal_and_pose_from_a_guess_30_percent_off(guess_factor):
    rng = np.random.default_rng(5)
    truth = Camera("SIMPLE_RADIAL", 640, 480, [700.0, 320.0, 240.0, 0.0])
    pose = Rigid3(so3_exp(np.array([0.1, -0.2, 0.05])), np.array([0.3, -0.1, 0.5]))
    Xw, uv = _points_and_pixels(rng, truth, pose, 200, 0.3)
    outliers = rng.choice(200, 40, replace=False)
    uv[outliers] = rng.uniform([0, 0], [640, 480], size=(40, 2))
    guess = Camera("SIMPLE_RADIAL", 640, 480, [700.0 * guess_factor, 320.0, 240.0, 0.0])
    est = estimate_pose_and_focal(uv, Xw, guess, RegisterConfig(), seed=1)
    assert est is not None
    assert est.camera.fx == pytest.approx(700.0, rel=0.01)
    assert est.camera.principal_point.tolist() == [320.0, 240.0]  # held, as COLMAP holds it
    dR = est.cam_from_world.R @ pose.R.T
    assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.2
    assert len(set(outliers.tolist()) & set(est.inliers.tolist())) < 3  # uniform outliers: a few fall near
    assert len(est.inliers) >= 150
    # the guess given in is left as it was
    assert guess.fx == pytest.approx(700.0 * guess_factor)


def test_p4pf_refuses_too_few_or_random_correspondences():
    rng = np.random.default_rng(2)
    guess = Camera("SIMPLE_RADIAL", 640, 480, [768.0, 320.0, 240.0, 0.0])
    X = rng.uniform(-2, 2, size=(100, 3)) + [0, 0, 8.0]
    assert estimate_pose_and_focal(rng.uniform(0, 480, (20, 2)), X[:20], guess, RegisterConfig(), 0) is None
    assert estimate_pose_and_focal(rng.uniform(0, 480, (100, 2)), X, guess, RegisterConfig(), 0) is None


