"""The polar form's compiled set-up (issue 34): observed view angles of pinhole cameras in one
pass against the camera model's numpy arithmetic, and the refusal of unusable observations."""

import copy

import numpy as np
import pytest

from polarref.ba import BAOptions, kernels, prepare
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.angular_obs import observed_view_angles
from polarref.ba.solver import make_param
from polarref.ba.synthetic import synthetic_reconstruction
from polarref.camera import Camera
from polarref.core.errors import PolarrefError

pytestmark = pytest.mark.skipif(not kernels.available(), reason="numba kernels unavailable")


def _problem(seed=3, radial=False):
    """A synthetic block; its SIMPLE_RADIAL camera swapped for a PINHOLE one (the twins' model,
    and the kernel's case) unless ``radial``."""
    init, _ = synthetic_reconstruction(12, 150, seed=seed, noise_px=0.5, rot_deg=0.3,
                                       point_sigma=0.05, center_sigma=0.05, track_length=4)
    p = problem_from_reconstruction(init)
    prepare(p)
    if not radial:
        c = p.cameras[0]
        f, cx, cy = c.params[:3]
        pin = Camera("PINHOLE", c.width, c.height, np.array([f, 1.02 * f, cx, cy]))
        p.cameras = [pin] * len(p.cameras)
    return p


def _reference(p):
    theta, grad = observed_view_angles(p)
    return theta, 1.0 / np.linalg.norm(grad, axis=1)


def test_pinhole_view_angles_equal_the_camera_model():
    p = _problem()
    assert all(c.model == "PINHOLE" for c in p.cameras)
    prm = make_param(p, BAOptions(param="polar"))
    theta, w = _reference(p)
    np.testing.assert_allclose(prm.theta_obs, theta, rtol=4e-16, atol=0)
    np.testing.assert_allclose(prm.w_theta, w, rtol=2e-15, atol=0)
    cs = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    np.testing.assert_allclose(prm.cs_theta, cs, rtol=0, atol=4e-16)
    # the numpy path (kernels off) is the reference's arithmetic, bitwise
    numpy_prm = make_param(p, BAOptions(param="polar", kernels="numpy"))
    assert np.array_equal(numpy_prm.theta_obs, theta)
    # a wrong focal length would not pass: the comparison sees the intrinsics
    K = prm.proj.K.copy()
    K[:, 0] *= 1.001
    _, w2, _, _ = kernels.pinhole_view_angles(K, p.obs_uv)
    assert np.abs(w2 / w - 1).max() > 1e-4


def test_pinhole_view_angles_refuse_the_principal_point_and_nan():
    p = _problem()
    K = make_param(p, BAOptions(param="polar")).proj.K
    for bad in ((K[0, 2], K[0, 3]), (np.nan, 10.0)):
        q = copy.copy(p)
        q.obs_uv = p.obs_uv.copy()
        q.obs_uv[5] = bad
        _, _, _, n_bad = kernels.pinhole_view_angles(K, q.obs_uv)
        assert n_bad == 1
        for kern in ("auto", "numpy"):  # both paths refuse it, with the same message
            with pytest.raises(PolarrefError, match="1 observations outside the camera model"):
                make_param(q, BAOptions(param="polar", kernels=kern))


def test_radial_cameras_take_the_camera_model():
    """k1 != 0: the camera model's own inverse (the kernel is pinhole only), bitwise."""
    p = _problem(radial=True)
    assert p.cameras[0].model == "SIMPLE_RADIAL" and p.cameras[0].params[3] != 0
    prm = make_param(p, BAOptions(param="polar"))
    theta, w = _reference(p)
    assert np.array_equal(prm.theta_obs, theta) and np.array_equal(prm.w_theta, w)
