"""polarref.metrics: Sim3 alignment, rotation/centre errors, reprojection figures."""

import numpy as np
import pytest

from polarref import metrics as M
from polarref.camera import Camera
from polarref.core.geometry import Rigid3, Sim3, so3_exp
from polarref.model import Image, Point3D, Reconstruction


def _gt(rng, n=8, collinear=False):
    rec = Reconstruction()
    rec.cameras[1] = Camera("PINHOLE", 320, 240, np.array([300.0, 300, 160, 120]))
    for i in range(n):
        c = np.array([i * 1.0, 0.0, 0.0]) if collinear else rng.normal(size=3) * 4 + [0, 0, -10]
        R = so3_exp(rng.normal(scale=0.3, size=3))
        rec.images[i + 1] = Image(i + 1, f"{i:03d}.png", 1, Rigid3(R, -R @ c))
    return rec


def _transformed(gt, sim_est_from_gt: Sim3, rot_noise=None, rng=None):
    """The GT seen in another frame: est = s R gt + t, optional per-camera rotation perturbations."""
    est = Reconstruction(cameras=dict(gt.cameras))
    for k, im in gt.images.items():
        pose = sim_est_from_gt.transform_pose(im.cam_from_world)
        if rot_noise is not None:
            pose = Rigid3(so3_exp(rot_noise[k - 1]) @ pose.R, so3_exp(rot_noise[k - 1]) @ pose.t)
        est.images[k] = Image(k, im.name, 1, pose)
    return est


def test_exact_similarity_gives_zero_errors():
    rng = np.random.default_rng(0)
    gt = _gt(rng)
    sim = Sim3(0.37, so3_exp([0.3, -1.0, 2.0]), np.array([5.0, -2, 1]))
    e = M.gt_errors(_transformed(gt, sim), gt)
    assert e.alignment == "umeyama_centers" and e.num_matched == 8
    assert e.rotation_error_deg_max < 1e-9 and e.center_error_rel_max < 1e-9
    assert e.scale == pytest.approx(1 / 0.37, rel=1e-12)


def test_known_rotation_perturbation_is_measured():
    rng = np.random.default_rng(1)
    gt = _gt(rng)
    sim = Sim3(2.0, so3_exp([0.1, 0.2, 0.3]), np.array([1.0, 2, 3]))
    angles = np.deg2rad(np.array([0.0, 0.1, 0.2, 0.3, 0.0, 0.5, 0.0, 0.1]))
    axes = rng.normal(size=(8, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    # rotating a camera about its own centre changes R only
    est = _transformed(gt, sim)
    for k, im in est.images.items():
        c = im.cam_from_world.center
        R = so3_exp(axes[k - 1] * angles[k - 1]) @ im.cam_from_world.R
        est.images[k] = Image(k, im.name, 1, Rigid3(R, -R @ c))
    e = M.gt_errors(est, gt)
    np.testing.assert_allclose([e.per_image[f"{i:03d}.png"].rotation_error_deg for i in range(8)],
                               np.rad2deg(angles), atol=1e-9)
    assert e.center_error_rel_max < 1e-9


def test_collinear_centres_use_rotation_alignment():
    rng = np.random.default_rng(2)
    gt = _gt(rng, n=6, collinear=True)
    sim = Sim3(3.0, so3_exp([1.0, 0.5, -0.2]), np.array([0.0, 1, 2]))
    e = M.gt_errors(_transformed(gt, sim), gt)
    assert e.alignment == "rotations_then_centers"
    assert e.rotation_error_deg_max < 1e-9 and e.center_error_rel_max < 1e-9
    # umeyama alone refuses this configuration
    with pytest.raises(ValueError, match="collinear"):
        from polarref.core.geometry import umeyama
        umeyama(gt.centers(), gt.centers() * 2)


def test_one_bad_camera_does_not_spoil_the_alignment():
    rng = np.random.default_rng(3)
    gt = _gt(rng, n=10)
    est = _transformed(gt, Sim3(1.0, np.eye(3), np.zeros(3)))
    bad = est.images[4]
    est.images[4] = Image(4, bad.name, 1, Rigid3(bad.cam_from_world.R, bad.cam_from_world.t + [30.0, 0, 0]))
    e = M.gt_errors(est, gt)
    assert e.num_alignment_outliers == 1
    others = [v.center_error_rel for k, v in e.per_image.items() if k != bad.name]
    assert max(others) < 1e-9 and e.per_image[bad.name].center_error_rel > 1.0


def test_reprojection_per_observation_and_per_point():
    rng = np.random.default_rng(4)
    gt = _gt(rng, n=3)
    rec = Reconstruction(cameras=dict(gt.cameras), images={k: Image(k, im.name, 1, im.cam_from_world,
                                                                      np.zeros((2, 2)), np.full(2, -1))
                                                           for k, im in gt.images.items()})
    X = [np.array([0.0, 0, 5]), np.array([1.0, 0, 6])]
    # point 1 seen by images 1, 2, 3 with errors (0, 3, 4) px along x; point 2 by images 1, 2 with (1, 1)
    offs = {(1, 1): 0.0, (1, 2): 3.0, (1, 3): 4.0, (2, 1): 1.0, (2, 2): 1.0}
    for pid, Xp in zip((1, 2), X):
        rows = []
        for im_id in (1, 2, 3) if pid == 1 else (1, 2):
            im = rec.images[im_id]
            uv = rec.cameras[1].project(im.cam_from_world.apply(Xp))
            im.keypoints[pid - 1] = uv + [offs[(pid, im_id)], 0]
            rows.append((im_id, pid - 1))
        rec.points3D[pid] = Point3D(Xp, np.array(rows))
    m = M.evaluate(rec)
    assert m.tie_points == 2 and m.reprojected_px == 5
    assert m.mean_reprojection_error_px == pytest.approx(9.0 / 5, abs=1e-9)
    assert m.mean_reprojection_error_px_per_point == pytest.approx((7.0 / 3 + 1.0) / 2, abs=1e-9)
    assert m.mean_track_length == pytest.approx(2.5)


def test_rotation_only_alignment_ignores_a_wrong_centre_alignment():
    rng = np.random.default_rng(5)
    gt = _gt(rng, n=8)
    est = _transformed(gt, Sim3(1.0, np.eye(3), np.zeros(3)))
    # move every centre (not the rotations): the centre-based similarity absorbs part of it as a
    # rotation and reports rotation errors; the rotation-only alignment reports zero
    for k, im in est.images.items():
        c = im.cam_from_world.center + rng.normal(scale=0.5, size=3)
        est.images[k] = Image(k, im.name, 1, Rigid3(im.cam_from_world.R, -im.cam_from_world.R @ c))
    e = M.gt_errors(est, gt)
    assert e.rotation_error_rotalign_deg_max < 1e-9
    assert e.rotation_error_deg_mean > 0.1
