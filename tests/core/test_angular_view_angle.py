"""View angle, polar angle and the polar rotation convention of polarref.core.angular."""

import warnings

import mpmath
import numpy as np
import pytest

from polarref.core import angular as A
from polarref.core.geometry import axis_rotation

N = 100_000
TOL = 1e-12


def _truth(alpha, beta, e_y, e_x, e_z):
    """Angle between d(alpha, beta) and column 3 of rotation_from_polar_angles."""
    a = A.rotation_from_polar_angles(e_y, e_x, e_z)[..., :, 2]
    d = A.direction_from_azimuth_elevation(alpha, beta)
    return np.arctan2(np.linalg.norm(np.cross(a, d), axis=-1), np.sum(a * d, axis=-1))


def _sample(rng, n, e_y=None, e_x=None):
    u = lambda lo, hi: rng.uniform(lo, hi, n)  # noqa: E731
    e_y = u(-np.pi, np.pi) if e_y is None else np.broadcast_to(e_y, (n,))
    e_x = u(-np.pi, np.pi) if e_x is None else np.broadcast_to(e_x, (n,))
    return u(-np.pi, np.pi), u(-np.pi / 2, np.pi / 2), e_y, e_x, u(-np.pi, np.pi)


def _signed(rng, n, lo, hi):
    return rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(lo, hi, n)


EDGE_CASES = {
    "random": lambda r, n: _sample(r, n),
    "e_x = 0": lambda r, n: _sample(r, n, e_x=0.0),
    "e_y = 0": lambda r, n: _sample(r, n, e_y=0.0),
    "e_x = e_y = 0": lambda r, n: _sample(r, n, 0.0, 0.0),
    "|e_y| = pi/2": lambda r, n: _sample(r, n, e_y=r.choice([-1, 1], n) * np.pi / 2),
    "|e_y| -> pi/2": lambda r, n: _sample(r, n, e_y=r.choice([-1, 1], n) * (np.pi / 2 - 10 ** r.uniform(-12, -2, n))),
    "e -> 0": lambda r, n: _sample(r, n, _signed(r, n, -12, -3), _signed(r, n, -12, -3)),
    "negative": lambda r, n: _sample(r, n, r.uniform(-np.pi, 0, n), r.uniform(-np.pi, 0, n)),
}


@pytest.mark.parametrize("case", list(EDGE_CASES))
def test_view_angle_matches_rotation_truth(case):
    rng = np.random.default_rng(list(EDGE_CASES).index(case))
    alpha, beta, e_y, e_x, e_z = EDGE_CASES[case](rng, N)
    theta = A.view_angle(alpha, beta, e_y, e_x)
    truth = _truth(alpha, beta, e_y, e_x, e_z)
    assert theta.shape == (N,)
    assert np.max(np.abs(theta - truth)) <= TOL
    # The truth itself vs 50-digit arithmetic on a subset: both are right, not just equal.
    for i in range(0, N, N // 50):
        with mpmath.workdps(40):
            ey, ex = mpmath.mpf(float(e_y[i])), mpmath.mpf(float(e_x[i]))
            a = [-mpmath.sin(ex), mpmath.sin(ey) * mpmath.cos(ex), mpmath.cos(ey) * mpmath.cos(ex)]
            al, be = mpmath.mpf(float(alpha[i])), mpmath.mpf(float(beta[i]))
            d = [mpmath.cos(be) * mpmath.cos(al), mpmath.cos(be) * mpmath.sin(al), mpmath.sin(be)]
            ref = mpmath.acos(sum(x * y for x, y in zip(a, d)))
        assert abs(theta[i] - float(ref)) <= TOL


def test_view_angle_near_and_on_the_axis():
    rng = np.random.default_rng(11)
    n = 20_000
    e_y, e_x = rng.uniform(-np.pi, np.pi, (2, n))
    a = A.principal_axis(e_y, e_x)
    u = np.cross(a, rng.normal(size=(n, 3)))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    t = 10.0 ** rng.uniform(-9, -3, n)
    t[:100] = 0.0
    alpha, beta = A.azimuth_elevation_from_direction(np.cos(t)[:, None] * a + np.sin(t)[:, None] * u)
    theta = A.view_angle(alpha, beta, e_y, e_x)
    # alpha, beta rounding moves the direction by ~1e-16 rad; acos would be off by ~1e-8 here
    assert np.max(np.abs(theta - t)) < 1e-14
    # opposite direction: theta -> pi
    alpha2, beta2 = A.azimuth_elevation_from_direction(-a)
    assert np.max(np.abs(A.view_angle(alpha2, beta2, e_y, e_x) - np.pi)) < 1e-14


def test_rotation_convention_is_passive_intrinsic_and_colmap():
    rng = np.random.default_rng(3)
    e_y, e_x, e_z = rng.uniform(-np.pi, np.pi, (3, 1000))
    R = A.rotation_from_polar_angles(e_y, e_x, e_z)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    # unrotated: principal axis up (+z), image right = +x, image down = +y
    np.testing.assert_allclose(A.rotation_from_polar_angles(0, 0, 0), np.eye(3), atol=0)
    # e_y tilts the principal axis toward +y, e_x toward -x
    np.testing.assert_allclose(A.rotation_from_polar_angles(np.pi / 2, 0, 0)[:, 2], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(A.rotation_from_polar_angles(0, np.pi / 2, 0)[:, 2], [-1, 0, 0], atol=1e-15)
    # cam_from_world = Rz(e_z) Ry(e_x) Rx(e_y): e_z turns about the principal axis only
    np.testing.assert_allclose(R[..., :, 2], A.principal_axis(e_y, e_x), atol=1e-15)
    R0 = A.rotation_from_polar_angles(e_y, e_x, 0.0)
    c, s = np.cos(e_z), np.sin(e_z)
    # passive turn by +e_z: the camera x axis moves by -e_z about the principal axis, so a fixed
    # ray's polar angle grows by +e_z
    np.testing.assert_allclose(R[..., :, 0], c[:, None] * R0[..., :, 0] - s[:, None] * R0[..., :, 1], atol=1e-14)
    # composition order: e_y about x first
    Rx = axis_rotation(0, -e_y)
    Ry = axis_rotation(1, -e_x)
    Rz = axis_rotation(2, -e_z)
    np.testing.assert_allclose(R, Rx @ Ry @ Rz, atol=1e-15)


def test_tilt_and_axis_azimuth_match_printed_eq4_and_eq5_in_general_position():
    rng = np.random.default_rng(5)
    e_y, e_x = rng.uniform(-1.4, 1.4, (2, 10_000))
    e, psi = A.tilt_and_axis_azimuth(e_y, e_x)
    np.testing.assert_allclose(e, np.arccos(np.cos(e_y) * np.cos(e_x)), atol=1e-12)
    np.testing.assert_allclose(np.sin(psi), np.tan(e_y) / np.tan(e), atol=1e-10)
    # the stable form keeps digits where Eq. 4 rounds to 0
    e_small, _ = A.tilt_and_axis_azimuth(1e-10, -2e-10)
    assert abs(e_small - np.hypot(1e-10, 2e-10)) < 1e-24
    assert np.arccos(np.cos(1e-10) * np.cos(2e-10)) == 0.0


def test_view_angle_independent_of_e_z_and_polar_angle_additive():
    rng = np.random.default_rng(6)
    alpha, beta, e_y, e_x, e_z = _sample(rng, 10_000)
    phi0 = A.polar_angle(alpha, beta, e_y, e_x, 0.0)
    phi = A.polar_angle(alpha, beta, e_y, e_x, e_z)
    wrapped = np.angle(np.exp(1j * (phi - phi0 - e_z)))
    assert np.max(np.abs(wrapped)) < 1e-12
    assert np.all((phi > -np.pi) & (phi <= np.pi))
    assert np.max(np.abs(_truth(alpha, beta, e_y, e_x, e_z) - _truth(alpha, beta, e_y, e_x, -e_z))) < 1e-15


def test_polar_angle_is_the_pixel_angle_in_colmap_image():
    """phi = atan2(v - cy, u - cx) for a pinhole with square pixels: right = 0, down = +pi/2."""
    rng = np.random.default_rng(7)
    n = 5000
    alpha, beta, e_y, e_x, e_z = _sample(rng, n)
    R_wc = A.rotation_from_polar_angles(e_y, e_x, e_z)
    r = np.einsum("nji,nj->ni", R_wc, A.direction_from_azimuth_elevation(alpha, beta))
    front = r[:, 2] > 0.1
    f, cx, cy = 800.0, 320.5, 240.5
    u = f * r[front, 0] / r[front, 2] + cx
    v = f * r[front, 1] / r[front, 2] + cy
    phi = A.polar_angle(alpha, beta, e_y, e_x, e_z)[front]
    assert np.max(np.abs(np.angle(np.exp(1j * (phi - np.arctan2(v - cy, u - cx)))))) < 1e-12
    theta = A.view_angle(alpha, beta, e_y, e_x)[front]
    assert np.max(np.abs(theta - np.arctan(np.hypot(u - cx, v - cy) / f))) < 1e-12
    # explicit directions: a point to the right of the axis has phi = 0, below it phi = +pi/2
    t, p = A.ray_angles(np.array([[1.0, 0, 5], [0, 1.0, 5], [0, 0, 1.0], [0, 0, -1.0]]))
    np.testing.assert_allclose(p, [0, np.pi / 2, 0, 0], atol=0)
    np.testing.assert_allclose(t, [np.arctan(0.2), np.arctan(0.2), 0, np.pi], atol=1e-16)


def _fd(fn, args, k, h=1e-6):
    hi, lo = list(args), list(args)
    hi[k] = args[k] + h
    lo[k] = args[k] - h
    return np.angle(np.exp(1j * (fn(*hi) - fn(*lo)))) / (2 * h)


def test_view_and_polar_jacobians_vs_central_differences():
    rng = np.random.default_rng(8)
    alpha, beta, e_y, e_x, e_z = _sample(rng, N)
    Jt = A.view_angle_jacobian(alpha, beta, e_y, e_x)
    Jp = A.polar_angle_jacobian(alpha, beta, e_y, e_x, e_z)
    assert Jt.shape == (N, 4) and Jp.shape == (N, 5)
    theta = A.view_angle(alpha, beta, e_y, e_x)
    ok = np.sin(theta) > 1e-2  # FD is meaningless next to the cone point / phi's pole
    args = (alpha, beta, e_y, e_x, e_z)
    for k in range(4):
        fd = _fd(lambda *a: A.view_angle(*a[:4]), args, k)
        assert np.max(np.abs(Jt[ok, k] - fd[ok])) < 1e-7
    for k in range(5):
        fd = _fd(A.polar_angle, args, k)
        assert np.max(np.abs(Jp[ok, k] - fd[ok]) / np.maximum(1, np.abs(Jp[ok, k]))) < 1e-6
    np.testing.assert_allclose(Jp[:, 4], 1.0, atol=1e-12)
    # |grad theta| = 1 w.r.t. the direction: d theta/d(alpha, beta) has norm 1 in the metric of the sphere
    g = np.hypot(Jt[ok, 0] / np.cos(beta[ok]), Jt[ok, 1])
    np.testing.assert_allclose(g, 1.0, atol=1e-9)


def test_singular_point_documented_values():
    # float pi/2 leaves the landmark 6e-17 rad off the axis: finite, and d theta/d beta = -1
    Jt = A.view_angle_jacobian(0.3, np.pi / 2, 0.0, 0.0)
    assert 0 < A.view_angle(0.3, np.pi / 2, 0.0, 0.0) < 1e-16
    # by hand: d = (eps cos .3, eps sin .3, 1), a = (-e_x, e_y, 1): theta ~ |d_xy - a_xy|
    np.testing.assert_allclose(Jt, [0, -1, -np.sin(0.3), np.cos(0.3)], atol=1e-12)
    # exactly on the axis (a ray with zero x, y): theta = 0, phi reported as 0
    theta, phi = A.ray_angles(np.array([0.0, 0.0, 2.0]))
    assert theta == 0.0 and phi == 0.0


def test_nan_in_nan_out_without_warnings():
    vals = [0.1, 0.2, 0.3, 0.4, 0.5]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for k in range(5):
            args = list(vals)
            args[k] = np.nan
            assert np.isnan(A.polar_angle(*args))
            assert np.isnan(A.polar_angle_jacobian(*args)).all()
            assert np.isnan(A.rotation_from_polar_angles(*args[2:])).all() or k < 2
            if k < 4:
                assert np.isnan(A.view_angle(*args[:4]))
                assert np.isnan(A.view_angle_jacobian(*args[:4])).all()
        big = np.full(10_000, np.nan)
        assert np.isnan(A.view_angle(big, 0.0, 0.0, 0.0)).all()
        assert np.isnan(A.ray_angles(np.zeros(3))[0])


def test_shapes_broadcast():
    assert A.rotation_from_polar_angles(np.zeros((2, 3)), 0.0, np.zeros(3)).shape == (2, 3, 3, 3)
    assert A.view_angle(np.zeros((4, 1)), np.zeros(5), 0.0, 0.0).shape == (4, 5)
    assert A.view_angle_jacobian(np.zeros((4, 1)), np.zeros(5), 0.0, 0.0).shape == (4, 5, 4)
    assert A.polar_angle_jacobian(0.0, 0.1, 0.0, 0.0, np.zeros(7)).shape == (7, 5)
    with pytest.raises(ValueError, match="shape"):
        A.ray_angles(np.zeros((3, 2)))
