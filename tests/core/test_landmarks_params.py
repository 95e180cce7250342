"""Landmark parameterizations: round trips, Jacobians vs finite differences, infinity."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polarref.core.geometry import so3_exp
from polarref.core.landmarks import (choose_associate_anchor, homogeneous_from_inverse_depth,
                                homogeneous_from_inverse_distance, homogeneous_from_parallax,
                                inverse_depth_from_xyz, inverse_distance_from_xyz,
                                parallax_from_xyz, parallax_ray, xyz_from_inverse_depth,
                                xyz_from_inverse_distance, xyz_from_parallax)


def fd(fun, x, h=1e-6):
    cols = []
    for i in range(x.shape[-1]):
        e = np.zeros(x.shape[-1])
        e[i] = h
        cols.append((fun(x + e) - fun(x - e)) / (2 * h))
    return np.stack(cols, -1)


def scene(seed, n=50):
    rng = np.random.default_rng(seed)
    R = so3_exp(rng.normal(size=3))
    C = rng.normal(size=3)
    t = -R @ C
    # points in front of the anchor camera at depths 1..50
    Xc = np.c_[rng.uniform(-1, 1, (n, 2)), np.ones(n)] * rng.uniform(1, 50, (n, 1))
    X = (Xc - t) @ R
    C_a = C + rng.normal(size=3)
    return R, t, C, C_a, X


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_round_trips(seed):
    R, t, C, C_a, X = scene(seed)
    p, _ = inverse_depth_from_xyz(X, R, t)
    np.testing.assert_allclose(xyz_from_inverse_depth(p, R, t)[0], X, rtol=1e-12, atol=1e-12)
    p, _ = inverse_distance_from_xyz(X, C)
    np.testing.assert_allclose(xyz_from_inverse_distance(p, C)[0], X, rtol=1e-12, atol=1e-12)
    p, _ = parallax_from_xyz(X, C, C_a)
    assert np.all((p[:, 2] > 0) & (p[:, 2] < np.pi))
    np.testing.assert_allclose(xyz_from_parallax(p, C, C_a)[0], X, rtol=1e-9, atol=1e-9)
    for hom in (homogeneous_from_inverse_depth(inverse_depth_from_xyz(X, R, t)[0], R, t),
                homogeneous_from_inverse_distance(inverse_distance_from_xyz(X, C)[0], C),
                homogeneous_from_parallax(p, C, C_a)):
        np.testing.assert_allclose(hom[:, :3] / hom[:, 3:], X, rtol=1e-9, atol=1e-9)


def test_parallax_definition_geometry():
    """omega is the angle at the point between the rays from C_m and C_a; the law of sines."""
    C_m, C_a = np.zeros(3), np.array([2.0, 0, 0])
    X = np.array([0.0, 0, 2.0])  # right angle at C_m: omega = 45 deg, phi_a = 90 deg
    p, _ = parallax_from_xyz(X, C_m, C_a)
    np.testing.assert_allclose(p, [0.0, np.pi / 2, np.pi / 4], atol=1e-15)
    for C_i in (C_m, C_a, np.array([5.0, 1, -1])):
        ray, _ = parallax_ray(p, C_m, C_a, C_i)
        assert np.linalg.norm(np.cross(ray, X - C_i)) < 1e-12 and ray @ (X - C_i) > 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jacobians_fd(seed):
    R, t, C, C_a, X = scene(seed, 20)
    p, J = inverse_depth_from_xyz(X, R, t)
    np.testing.assert_allclose(J, fd(lambda x: inverse_depth_from_xyz(x, R, t)[0], X), atol=1e-7)
    _, Jx, _ = xyz_from_inverse_depth(p, R, t)
    np.testing.assert_allclose(Jx, fd(lambda q: xyz_from_inverse_depth(q, R, t)[0], p, 1e-8),
                               rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(J @ Jx, np.broadcast_to(np.eye(3), J.shape), atol=1e-9)

    p, J = inverse_distance_from_xyz(X, C)
    np.testing.assert_allclose(J, fd(lambda x: inverse_distance_from_xyz(x, C)[0], X), atol=1e-7)
    _, Jx, _ = xyz_from_inverse_distance(p, C)
    np.testing.assert_allclose(Jx, fd(lambda q: xyz_from_inverse_distance(q, C)[0], p, 1e-8),
                               rtol=1e-5, atol=1e-5)

    p, J = parallax_from_xyz(X, C, C_a)
    np.testing.assert_allclose(J, fd(lambda x: parallax_from_xyz(x, C, C_a)[0], X), atol=1e-7)
    _, Jx, _ = xyz_from_parallax(p, C, C_a)
    np.testing.assert_allclose(Jx, fd(lambda q: xyz_from_parallax(q, C, C_a)[0], p, 1e-8),
                               rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(J @ Jx, np.broadcast_to(np.eye(3), J.shape), atol=1e-7)
    C_i = C + np.array([0.3, -1.0, 0.5])
    _, Jr = parallax_ray(p, C, C_a, C_i)
    np.testing.assert_allclose(Jr, fd(lambda q: parallax_ray(q, C, C_a, C_i)[0], p), atol=1e-7)


def test_points_at_infinity_are_flagged_never_inf():
    R, t, C, C_a, X = scene(3, 4)
    cases = [
        (lambda p, **k: xyz_from_inverse_depth(p, R, t, **k), np.array([[0.1, -0.2, 0.0]])),
        (lambda p, **k: xyz_from_inverse_distance(p, C, **k), np.array([[0.3, 0.2, 0.0]])),
        (lambda p, **k: xyz_from_parallax(p, C, C_a, **k), np.array([[0.3, 0.2, 0.0]])),
    ]
    for fun, p_inf in cases:
        p = np.vstack([p_inf, p_inf + [0, 0, 0.1]])
        Xo, J, at_inf = fun(p)
        assert at_inf.tolist() == [True, False]
        assert np.isnan(Xo[0]).all() and np.isnan(J[0]).all()
        assert np.isfinite(Xo[1]).all() and not np.isinf(Xo).any()
        with pytest.raises(ValueError, match="at infinity"):
            fun(p, strict=True)
    # the homogeneous forms stay finite and give the direction at infinity
    h = homogeneous_from_inverse_distance([0.3, 0.2, 0.0], C)
    np.testing.assert_allclose(h, [np.cos(0.2) * np.cos(0.3), np.cos(0.2) * np.sin(0.3),
                                   np.sin(0.2), 0.0], atol=1e-15)
    h = homogeneous_from_parallax([0.3, 0.2, 0.0], C, C_a)
    assert h[3] == 0 and np.isfinite(h).all() and np.linalg.norm(h[:3]) > 0
    h = homogeneous_from_inverse_depth([0.1, -0.2, 0.0], R, t)
    np.testing.assert_allclose(h[:3], R.T @ [0.1, -0.2, 1.0], atol=1e-15)
    # the parallax ray from any camera is finite at omega = 0 and parallel to d
    ray, J = parallax_ray([0.3, 0.2, 0.0], C, C_a, C_a + 1.0)
    assert np.isfinite(J).all()
    d = np.array([np.cos(0.2) * np.cos(0.3), np.cos(0.2) * np.sin(0.3), np.sin(0.2)])
    assert np.linalg.norm(np.cross(ray, d)) < 1e-12


def test_far_points_converge_to_infinity_smoothly():
    C_m, C_a = np.zeros(3), np.array([1.0, 0, 0])
    for dist in (1e3, 1e6, 1e9):
        X = np.array([0.0, dist, 1.0])
        p, _ = parallax_from_xyz(X, C_m, C_a)
        assert p[2] == pytest.approx(np.arctan(1 / dist), rel=1e-6)
        np.testing.assert_allclose(xyz_from_parallax(p, C_m, C_a)[0], X, rtol=1e-6, atol=1e-6 * dist)


def test_bad_input():
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        xyz_from_parallax(np.zeros(2), np.zeros(3), np.ones(3))
    p, J = inverse_depth_from_xyz(np.array([0.0, 0.0, -1.0]), np.eye(3), np.zeros(3))
    assert np.isnan(p).all() and np.isnan(J).all()  # behind the anchor
    p, _ = parallax_from_xyz(np.zeros(3), np.zeros(3), np.ones(3))
    assert np.isnan(p[2])  # point on the main anchor
    with pytest.raises(ValueError):
        choose_associate_anchor(np.ones((1, 3)))


def test_choose_associate_anchor():
    b = np.array([[0, 0, 1.0], [0.1, 0, 1], [1, 0, 1], [0.5, 0, 1]])
    assert choose_associate_anchor(b) == 2
    assert choose_associate_anchor(b, main_index=2) == 0
