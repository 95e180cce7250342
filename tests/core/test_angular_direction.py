"""Direction <-> (azimuth, elevation) convention and its Jacobian."""

import warnings

import numpy as np
import pytest

from polarref.core.angular import (
    azimuth_elevation_from_direction,
    direction_from_azimuth_elevation,
    direction_jacobian,
)

N = 100_000


def _random_angles(rng, n=N):
    alpha = rng.uniform(-np.pi, np.pi, n)
    beta = rng.uniform(-np.pi / 2, np.pi / 2, n)
    return alpha, beta


def test_axes_follow_project_convention():
    d = direction_from_azimuth_elevation([0.0, np.pi / 2, 0.3], [0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(d, [[1, 0, 0], [0, 1, 0], [0, 0, 1]], atol=1e-15)
    # elevation goes toward +z, azimuth from +x toward +y
    d = direction_from_azimuth_elevation(np.pi / 4, np.pi / 6)
    np.testing.assert_allclose(d, [0.75**0.5 * 0.5**0.5, 0.75**0.5 * 0.5**0.5, 0.5], atol=1e-15)


def test_unit_norm_and_roundtrip():
    rng = np.random.default_rng(0)
    alpha, beta = _random_angles(rng)
    d = direction_from_azimuth_elevation(alpha, beta)
    assert d.shape == (N, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=2e-16 * 4)
    scale = rng.uniform(1e-3, 1e3, N)[:, None]
    a2, b2 = azimuth_elevation_from_direction(d * scale)
    assert np.max(np.abs(a2 - alpha)) < 1e-13
    assert np.max(np.abs(b2 - beta)) < 1e-13


def test_inverse_ranges_and_edges():
    a, b = azimuth_elevation_from_direction(
        [[-1, 0, 0], [-1, -0.0, 0], [0, 0, 3], [-0.0, 0, -2], [0, 0, 0], [np.nan, 0, 1]]
    )
    assert a[0] == np.pi and a[1] == np.pi  # (-pi, pi]: -pi never returned
    assert (a[2], b[2]) == (0.0, np.pi / 2)
    assert (a[3], b[3]) == (0.0, -np.pi / 2)
    assert np.isnan(a[4]) and np.isnan(b[4])
    assert np.isnan(a[5])
    rng = np.random.default_rng(1)
    a, b = azimuth_elevation_from_direction(rng.normal(size=(N, 3)))
    assert np.all((a > -np.pi) & (a <= np.pi))
    assert np.all(np.abs(b) <= np.pi / 2)


def test_broadcast_and_shapes():
    d = direction_from_azimuth_elevation(np.zeros((4, 1)), np.zeros((1, 5)))
    assert d.shape == (4, 5, 3) and d.dtype == np.float64
    assert direction_jacobian(np.zeros((2, 3)), 0.1).shape == (2, 3, 3, 2)
    a, b = azimuth_elevation_from_direction(np.ones((2, 7, 3)))
    assert a.shape == b.shape == (2, 7)
    with pytest.raises(ValueError, match="shape"):
        azimuth_elevation_from_direction(np.ones((4, 2)))


def test_jacobian_vs_central_differences():
    rng = np.random.default_rng(2)
    alpha, beta = _random_angles(rng)
    J = direction_jacobian(alpha, beta)
    h = 1e-6
    fd_a = (direction_from_azimuth_elevation(alpha + h, beta)
            - direction_from_azimuth_elevation(alpha - h, beta)) / (2 * h)
    fd_b = (direction_from_azimuth_elevation(alpha, beta + h)
            - direction_from_azimuth_elevation(alpha, beta - h)) / (2 * h)
    err = max(np.max(np.abs(J[..., 0] - fd_a)), np.max(np.abs(J[..., 1] - fd_b)))
    assert err < 1e-9
    # a wrong sign in any entry would be O(1) off; check the test can see it
    assert np.max(np.abs(-J[..., 1] - fd_b)) > 0.5


def test_nan_in_nan_out_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = direction_from_azimuth_elevation([np.nan, 0.0], [0.0, np.nan])
        J = direction_jacobian([np.nan], [0.0])
        a, b = azimuth_elevation_from_direction(np.full((3, 3), np.nan))
    assert np.all(np.isnan(d))
    assert np.isnan(J).all()
    assert np.isnan(a).all() and np.isnan(b).all()
