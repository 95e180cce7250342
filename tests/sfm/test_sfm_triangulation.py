"""MOCI two-view midpoint (ATBD 5.3), MOCI N-view least squares (ATBD 6.2) and DLT."""

import numpy as np
import pytest

from polarref.sfm.triangulation import (DegenerateTriangulation, dlt, midpoint_two_view,
                                        nview_least_squares, triangulation_angles_deg)


def _scene(rng, n_pts, n_cams):
    X = rng.normal(size=(n_pts, 3)) * 2.0
    C = rng.normal(size=(n_cams, 3)) * 3.0 + [0, 0, -15.0]
    return X, C


def test_midpoint_noise_free_is_exact():
    rng = np.random.default_rng(0)
    X, C = _scene(rng, 500, 2)
    C0, C1 = np.broadcast_to(C[0], X.shape), np.broadcast_to(C[1], X.shape)
    # directions of arbitrary positive length
    v0 = (X - C0) * rng.uniform(0.1, 10, (len(X), 1))
    v1 = (X - C1) * rng.uniform(0.1, 10, (len(X), 1))
    res = midpoint_two_view(C0, v0, C1, v1)
    assert res.valid.all()
    np.testing.assert_allclose(res.X, X, atol=1e-9 * 20)


def test_midpoint_matches_independent_closest_points_on_skew_lines():
    rng = np.random.default_rng(1)
    C0, C1 = rng.normal(size=(200, 3)), rng.normal(size=(200, 3)) + [5, 0, 0]
    v0, v1 = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    res = midpoint_two_view(C0, v0, C1, v1)
    # independent: minimize |C0 + a v0 - C1 - b v1|^2 by the 2x2 normal equations
    ref = []
    for c0, a0, c1, a1 in zip(C0, v0, C1, v1):
        A = np.stack([a0, -a1], 1)
        ab = np.linalg.solve(A.T @ A, A.T @ (c1 - c0))
        ref.append(0.5 * (c0 + ab[0] * a0 + c1 + ab[1] * a1))
    ref = np.array(ref)
    np.testing.assert_allclose(res.X, ref, atol=1e-9)
    # random lines: many closest points lie behind an origin; the flag must say exactly which
    a = np.einsum("ij,ij->i", ref - C0, v0)
    b = np.einsum("ij,ij->i", ref - C1, v1)
    assert 0 < res.behind.sum() < len(res.behind)
    np.testing.assert_array_equal(res.behind, (a <= 0) | (b <= 0))


def test_midpoint_parallel_and_behind_are_flagged_and_strict_raises():
    C0 = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0]])
    C1 = np.array([[1.0, 0, 0], [1, 0, 0], [1, 0, 0]])
    v0 = np.array([[0.0, 0, 1], [0, 0, 1], [-0.1, 0, -1]])
    v1 = np.array([[0.0, 0, 2], [-0.1, 0, 1], [0.1, 0, -1]])  # row0 parallel, row1 fine, row2: point behind
    res = midpoint_two_view(C0, v0, C1, v1)
    assert res.parallel.tolist() == [True, False, False]
    assert res.behind.tolist() == [False, False, True]
    assert np.isnan(res.X[0]).all() and np.isfinite(res.X[1:]).all()
    np.testing.assert_allclose(res.X[1], [0, 0, 10], atol=1e-12)
    with pytest.raises(DegenerateTriangulation, match="parallel"):
        midpoint_two_view(C0, v0, C1, v1, strict=True)
    with pytest.raises(DegenerateTriangulation, match="behind"):
        midpoint_two_view(C0[2:], v0[2:], C1[2:], v1[2:], strict=True)


@pytest.mark.parametrize("n_rays", [2, 3, 5, 12])
def test_nview_noise_free_exact(n_rays):
    rng = np.random.default_rng(n_rays)
    X, C = _scene(rng, 300, n_rays)
    group = np.repeat(np.arange(len(X)), n_rays)
    Cs = np.tile(C, (len(X), 1))
    d = X[group] - Cs
    res = nview_least_squares(Cs, d, group, len(X))
    assert res.valid.all()
    np.testing.assert_allclose(res.X, X, atol=1e-9 * 20)


def test_nview_two_rays_equals_midpoint_and_noisy_is_least_squares():
    rng = np.random.default_rng(5)
    X, C = _scene(rng, 200, 4)
    group = np.repeat(np.arange(len(X)), 4)
    Cs = np.tile(C, (len(X), 1))
    d = X[group] - Cs
    d = d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(scale=1e-3, size=d.shape)
    res = nview_least_squares(Cs, d, group, len(X))
    # 1 mrad ray noise at ~15 units -> errors of order 1e-2; far from 0 and far from 1
    err = np.linalg.norm(res.X - X, axis=1)
    assert 1e-4 < np.median(err) < 0.2
    # independent check: gradient of the sum of squared perpendicular distances vanishes
    dn = d / np.linalg.norm(d, axis=1, keepdims=True)
    r = res.X[group] - Cs
    perp = r - np.einsum("ij,ij->i", r, dn)[:, None] * dn
    grad = np.zeros_like(res.X)
    np.add.at(grad, group, perp)
    assert np.abs(grad).max() < 1e-9
    # two rays: the LS point is the ATBD 5.3 midpoint
    sel = (np.arange(len(group)) % 4) < 2
    two = nview_least_squares(Cs[sel], d[sel], group[sel], len(X))
    mid = midpoint_two_view(Cs[sel][0::2], d[sel][0::2], Cs[sel][1::2], d[sel][1::2])
    np.testing.assert_allclose(two.X, mid.X, atol=1e-9)


def test_nview_degenerate_flags():
    C = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    d = np.array([[0.0, 0, 1], [0, 0, 1], [0, 0, 1], [-1, 0, 10], [-2, 0, 10], [-3, 0, 10]])
    # group 0: three identical rays (parallel); group 1: rays meeting at (0, 0, 10)
    res = nview_least_squares(C, d, np.array([0, 0, 0, 1, 1, 1]), 2)
    assert res.parallel.tolist() == [True, False]
    np.testing.assert_allclose(res.X[1], [0, 0, 10], atol=1e-12)
    res = nview_least_squares(C[3:], -d[3:], np.array([0, 0, 0]), 1)  # meet at z = -10: behind
    assert res.behind.tolist() == [True]
    with pytest.raises(DegenerateTriangulation):
        nview_least_squares(C[3:], -d[3:], np.array([0, 0, 0]), 1, strict=True)


def test_dlt_noise_free_exact_and_behind():
    rng = np.random.default_rng(7)
    from polarref.core.geometry import so3_exp

    X = rng.normal(size=(100, 3))
    n_cam = 3
    Rs = so3_exp(rng.normal(scale=0.2, size=(n_cam, 3)))
    ts = np.array([[0, 0, 10.0], [1, 0, 10], [0, 1, 10]])
    group = np.repeat(np.arange(100), n_cam)
    cam = np.tile(np.arange(n_cam), 100)
    Xc = np.einsum("oij,oj->oi", Rs[cam], X[group]) + ts[cam]
    P = np.concatenate([Rs[cam], ts[cam][:, :, None]], 2)
    res = dlt(P, Xc[:, :2] / Xc[:, 2:], group, 100)
    assert res.valid.all()
    np.testing.assert_allclose(res.X, X, atol=1e-9)
    # the same points seen by cameras placed so that they lie behind them: flagged, not dropped
    P_back = np.concatenate([Rs[cam], (ts[cam] * [1, 1, -1])[:, :, None]], 2)
    Xb = np.einsum("oij,oj->oi", Rs[cam], X[group]) + ts[cam] * [1, 1, -1]
    res = dlt(P_back, Xb[:, :2] / Xb[:, 2:], group, 100)
    assert res.behind.all() and not res.parallel.any()
    np.testing.assert_allclose(res.X, X, atol=1e-9)
    with pytest.raises(DegenerateTriangulation, match="behind"):
        dlt(P_back, Xb[:, :2] / Xb[:, 2:], group, 100, strict=True)


def test_triangulation_angles_against_brute_force():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(50, 3))
    lens = rng.integers(2, 6, size=50)
    group = np.repeat(np.arange(50), lens)
    C = rng.normal(size=(len(group), 3)) * 5
    got = triangulation_angles_deg(X, C, group, 50)
    for g in range(50):
        r = X[g] - C[group == g]
        r /= np.linalg.norm(r, axis=1, keepdims=True)
        ref = np.degrees(np.arccos(np.clip(r @ r.T, -1, 1))).max()
        assert abs(got[g] - ref) < 1e-6


def test_triangulation_angle_of_a_point_at_a_camera_centre_is_zero_without_warning():
    # the mapper's old placeholder (0, 0, 0) for unsolved points sat at the gauge camera's
    # centre: 0/0 in the ray normalization, numpy's "invalid value" on the user's terminal
    X = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 10.0], [np.nan, 0.0, 1.0]])
    C = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0, 0, 0], [1.0, 0, 0]])
    group = np.array([0, 0, 1, 1, 2, 2])
    with np.errstate(all="raise"):
        got = triangulation_angles_deg(X, C, group, 3)
    assert got[0] == 0.0 and got[2] == 0.0
    assert got[1] == pytest.approx(np.degrees(np.arctan2(1.0, 10.0)), abs=1e-9)
