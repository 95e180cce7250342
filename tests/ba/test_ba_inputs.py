"""BA bad input, adjust() on a Reconstruction, gauge, and the `polarref ba` CLI."""

import copy
import json

import numpy as np
import pytest

from polarref.ba import BAOptions, BAProblem, adjust, prepare, solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.synthetic import synthetic_reconstruction
from polarref.cli import main
from polarref.core.errors import PolarrefError
from polarref.model import Observations


@pytest.fixture(scope="module")
def scene():
    return synthetic_reconstruction(6, 80, seed=11, noise_px=0.5)


def _problem(scene):
    return problem_from_reconstruction(copy.deepcopy(scene[0]))


def test_empty_problem_is_a_clear_error():
    p = BAProblem(cameras=[], R=np.zeros((0, 3, 3)), C=np.zeros((0, 3)), X=np.zeros((0, 3)),
                  obs=Observations.empty())
    with pytest.raises(PolarrefError, match="empty"):
        solve(p, BAOptions())


def test_nan_single_and_idle_camera_are_counted(scene):
    p = _problem(scene)
    # NaN observations, a point seen once, and a camera with no observations
    p.obs_uv[:5] = np.nan
    lone = p.obs_pt == 3
    idx = np.flatnonzero(lone)
    keep = np.ones(len(p.obs_pt), bool)
    keep[idx[1:]] = False
    cam_last = p.num_cameras - 1
    keep &= p.obs_cam != cam_last
    keep[idx[0]] = True
    if p.obs_cam[idx[0]] == cam_last:
        p.obs_cam[idx[0]] = 0
    p.obs_cam, p.obs_pt, p.obs_uv = p.obs_cam[keep], p.obs_pt[keep], p.obs_uv[keep]
    s = solve(p, BAOptions())
    assert s.exclusions["observations_nonfinite"] == 5
    assert s.exclusions["points_short_track"] >= 1
    assert s.exclusions["cameras_without_observations"] == 1
    assert np.isfinite(s.final_cost) and np.isfinite(p.X).all() and np.isfinite(p.R).all()
    assert 0.3 < s.final_rms_px < 0.7


def test_nonfinite_pose_is_a_clear_error(scene):
    p = _problem(scene)
    p.C[1] = np.nan
    with pytest.raises(PolarrefError, match="non-finite camera pose"):
        solve(p, BAOptions())


def test_bad_options():
    with pytest.raises(ValueError, match="parameterization"):
        BAOptions(param="spherical")
    with pytest.raises(ValueError, match="loss"):
        BAOptions(loss="l1")


def test_gauge_is_held(scene):
    rec = copy.deepcopy(scene[0])
    ids = sorted(rec.images)
    pose0 = rec.images[ids[0]].cam_from_world
    s = adjust(rec, BAOptions())
    assert "6 DoF" in s.gauge and "1 DoF" in s.gauge
    after = rec.images[ids[0]].cam_from_world
    np.testing.assert_allclose(after.R, pose0.R, atol=1e-12)
    np.testing.assert_allclose(after.t, pose0.t, atol=1e-12)


def test_adjust_with_fixed_images_and_subset(scene):
    rec = copy.deepcopy(scene[0])
    ids = sorted(rec.images)
    for i in ids[:2]:  # fixed images at their true poses: the rest can reach the noise level
        rec.images[i].cam_from_world = scene[1].images[i].cam_from_world
    fixed_pose = rec.images[ids[1]].cam_from_world
    s = adjust(rec, BAOptions(), fixed_image_ids=ids[:2])
    assert s.num_variable_cameras == len(ids) - 2
    assert "fixed cameras" in s.gauge
    np.testing.assert_allclose(rec.images[ids[1]].cam_from_world.t, fixed_pose.t, atol=0)
    assert 0.4 <= s.final_rms_px <= 0.6
    # local BA: only two images variable
    rec2 = copy.deepcopy(scene[0])
    s2 = adjust(rec2, BAOptions(), variable_image_ids=ids[-2:])
    assert s2.num_variable_cameras <= 2 and np.isfinite(s2.final_cost)


def test_cli_writes_json(shared_data, tmp_path):
    out = tmp_path / "ba.json"
    rc = main(["ba", str(shared_data / "bal" / "dubrovnik-3-7-pre.txt"), "--param", "euclidean",
               "--out", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    for key in ("initial_cost", "final_cost", "final_rms_px", "iterations", "wall_s", "param",
                "trace"):
        assert key in d
    assert d["final_cost"] < 0.01 * d["initial_cost"]
    assert len(d["trace"]) == d["iterations"]
    # refuses to overwrite; bad option value is exit 2 (argparse)
    assert main(["ba", str(shared_data / "bal" / "dubrovnik-3-7-pre.txt"), "--out", str(out)]) == 1
    with pytest.raises(SystemExit) as e:
        main(["ba", "x.txt", "--param", "nope", "--out", str(out)])
    assert e.value.code == 2


def test_cli_missing_problem(tmp_path):
    assert main(["ba", str(tmp_path / "missing.txt"), "--out", str(tmp_path / "o.json")]) == 1
