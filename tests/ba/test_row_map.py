"""The polar form's view-angle row as a map of its pixel rows (ba/row_map.py, issue 34): the
kernel's rows against the explicit ones, the whitening against a numpy reference and against
the three-row normal equations, and whole solves (eager and chunked) against the explicit form."""

import numpy as np
import pytest

from polarref.ba import BAOptions, chunked, kernels, prepare, row_map, solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.forms_jit import MID_T2, SERIES_MAX
from polarref.ba.schur import SchurStructure
from polarref.ba.solver import _robust, make_param
from polarref.ba.synthetic import ring_problem, synthetic_reconstruction

pytestmark = pytest.mark.skipif(not kernels.available(), reason="numba kernels unavailable")


def _rays_and_intrinsics(n=500, seed=0):
    rng = np.random.default_rng(seed)
    Xc = rng.normal(size=(n, 3)) * [1.0, 1.0, 0.3] + [0.0, 0.0, 1.0]
    Xc[::7, 2] *= -1.0  # behind the camera: the projective ray (angular_obs.py)
    Xc[::11] *= 1e4  # scale: both rows see the ray's direction only
    K = np.tile([800.0, 760.0, 320.0, 240.0, -0.08, 0.01], (n, 1)) * rng.uniform(0.9, 1.1, (n, 6))
    return Xc, K, rng.normal(size=(n, 2)) * 3 + [320, 240], rng.uniform(0.1, 1.0, n), \
        rng.uniform(100.0, 900.0, n)


def _cs(theta):
    return np.stack([np.cos(theta), np.sin(theta)], axis=1)


@pytest.mark.parametrize("near", [False, True])
def test_mapped_rows_kernel_equals_explicit_rows(near):
    Xc, K, uv, th, wt = _rays_and_intrinsics()
    if near:  # observed angles near the predicted ones: the offset's series branch
        sg = np.where(Xc[:, 2] < 0, -1.0, 1.0)[:, None]
        th = np.arctan2(np.hypot(*(sg * Xc)[:, :2].T), (sg * Xc)[:, 2])
        rng = np.random.default_rng(1)
        th = th + rng.normal(size=len(th)) * 10.0 ** rng.uniform(-9, -1, len(th))
    res, J, G = kernels.polar_rows_mapped(Xc, K, uv, th, _cs(th), wt)
    ref, J3 = kernels.pixel_rows(Xc, K, uv, 3, True)
    kernels.theta_row_into(Xc, th, wt, ref, J3, True)
    assert np.array_equal(res[:, :2], ref[:, :2])  # pixel rows: bitwise
    # the view-angle offset without arctan2 (row_map_jit._view_angle_offset): to rounding
    np.testing.assert_allclose(res[:, 2] / wt, ref[:, 2] / wt, rtol=0, atol=2e-15)
    assert np.array_equal(J, J3[:, :2])
    mapped = np.einsum("mk,mkj->mj", G, J)
    err = np.abs(mapped - J3[:, 2]).max(axis=1) / np.abs(J3[:, 2]).max(axis=1)
    assert err.max() < 1e-12
    # not a tautology: the map is specific to each observation
    shuffled = np.einsum("mk,mkj->mj", G[::-1], J)
    assert np.abs(shuffled - J3[:, 2]).max() > 1e-3 * np.abs(J3[:, 2]).max()


def test_fused_evaluation_equals_its_stages():
    """Polar's fused, mapped evaluation (rays, rows, row map and two-row chain rule in one
    pass) against the staged kernels, bitwise."""
    p = _synthetic()
    prm = make_param(p, BAOptions(param="polar"))
    pts = prm.init_points()
    terms = prm.point_terms_for_rows(p.R, p.C, pts)
    res, Jp, (Jo, anc) = prm.evaluate(p.R, p.C, pts, True, factored=True)
    Cm, d, sw, cw, hd, dh_dw, dh_de, dv_dab = terms
    Xc = kernels.parallax_rays(p.R, p.C, p.obs_cam, p.obs_pt, Cm, sw, hd)
    r2, Jx, G = kernels.polar_rows_mapped(Xc, prm.proj.K, p.obs_uv, prm.theta_obs, prm.cs_theta,
                                          prm.w_theta)
    Jp2, Jo2, _, _, Ad2 = kernels.parallax_jacobians(Jx, Xc, p.R, p.C, p.obs_cam, p.obs_pt, Cm,
                                                     d, sw, cw, dh_dw, dh_de, dv_dab, False)
    for got, ref in ((res, r2), (Jp, Jp2), (Jo, Jo2), (anc.Ad, Ad2), (anc.row_map, G)):
        assert np.array_equal(got, ref)


@pytest.mark.parametrize("weighted", [False, True])
def test_whiten_gives_the_three_row_normal_equations(weighted):
    rng = np.random.default_rng(5)
    M = 300
    r = rng.normal(size=(M, 3))
    G = rng.normal(size=(M, 2)) * 3
    J2 = rng.normal(size=(M, 2, 10))  # point (3) | observer (6) | A d (1)
    w = None
    if weighted:
        w = np.repeat(rng.uniform(0.05, 1.0, (M, 2)), [2, 1], axis=1)  # one weight per block
    Jp, Jo, Ad = J2[:, :, :3].copy(), J2[:, :, 3:9].copy(), J2[:, :, 9].copy()
    r2 = row_map.whiten(r, w, G, Jp, Jo, Ad)
    Jw = np.concatenate([Jp, Jo, Ad[:, :, None]], axis=2)
    ref_r, ref_J = row_map.whiten_reference(r, w, G, J2)
    np.testing.assert_allclose(r2, ref_r, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Jw, ref_J, rtol=1e-12, atol=1e-12)
    J3 = np.concatenate([J2, np.einsum("mk,mkj->mj", G, J2)[:, None]], axis=1)
    w2 = np.ones((M, 3)) if w is None else w ** 2
    H3 = np.einsum("mki,mk,mkj->ij", J3, w2, J3)
    b3 = np.einsum("mki,mk,mk->i", J3, w2, r)
    np.testing.assert_allclose(np.einsum("mki,mkj->ij", Jw, Jw), H3, rtol=1e-11,
                               atol=1e-11 * np.abs(H3).max())
    np.testing.assert_allclose(np.einsum("mki,mk->i", Jw, r2), b3, rtol=1e-11,
                               atol=1e-11 * np.abs(b3).max())


def _synthetic(seed=7):
    init, _ = synthetic_reconstruction(16, 200, seed=seed, noise_px=0.5, rot_deg=0.3,
                                       point_sigma=0.05, center_sigma=0.05, track_length=4)
    p = problem_from_reconstruction(init)
    prepare(p)
    return p


@pytest.mark.parametrize("loss", ["trivial", "huber"])
def test_mapped_normal_equations_equal_explicit(loss):
    """The fused kernel build of both evaluations at the same estimate: g, W, U, V, g_p."""
    p = _synthetic()
    out = {}
    for rows in ("explicit", "mapped"):
        prm = make_param(p, BAOptions(param="polar", view_angle_row=rows))
        pts = prm.init_points()
        st = SchurStructure(prm.slot_cams, prm.slot_cols, p.obs_pt, p.cam_mask.any(1),
                            p.num_points, 700, fast=True, anchored=True)
        r, Jp, (Jo, anc) = prm.evaluate(p.R, p.C, pts, True, factored=True)
        assert Jp.shape[1] == (2 if rows == "mapped" else 3) and r.shape[1] == 3
        _, w = _robust(r, prm.groups, loss, 2.0)
        if rows == "mapped":
            r = row_map.whiten(r, w, anc.row_map, Jp, Jo, anc.Ad)
        elif w is not None:
            r, Jp, Jo = r * w, Jp * w[:, :, None], Jo * w[:, :, None]
            anc = anc.scaled(w)
        V, g_p = st.point_terms(Jp, r)
        out[rows] = (*st.build([Jo, anc], Jp, r), V, g_p)
    for a, b in zip(out["explicit"], out["mapped"]):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-10 * np.abs(a).max())


def _solve(p, monkeypatch, lazy, **opts):
    monkeypatch.setattr(chunked, "MIN_OBS", 0 if lazy else 1 << 62)
    monkeypatch.setattr(chunked, "CHUNK_OBS", 41)
    q = p.copy()
    s = solve(q, BAOptions(param="polar", kernels="numba", max_iterations=12, **opts),
              prepared=True)
    return q, s


@pytest.mark.parametrize("lazy", [False, True])
@pytest.mark.parametrize("loss", ["trivial", "cauchy"])
def test_mapped_solve_equals_explicit(monkeypatch, lazy, loss):
    p = ring_problem(24, 300, 6.0, seed=3)
    prepare(p)
    a, sa = _solve(p, monkeypatch, lazy, loss=loss, view_angle_row="explicit")
    b, sb = _solve(p, monkeypatch, lazy, loss=loss, view_angle_row="mapped")
    assert sa.iterations == sb.iterations >= 2 and sb.final_cost < 0.5 * sb.initial_cost
    assert sa.accepted_iterations == sb.accepted_iterations
    ca, cb = np.array([t.cost for t in sa.trace]), np.array([t.cost for t in sb.trace])
    np.testing.assert_allclose(cb, ca, rtol=1e-10)
    scale = np.abs(a.C).max() + np.abs(a.X).max()
    np.testing.assert_allclose(b.X, a.X, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(b.R, a.R, rtol=0, atol=1e-10)


def test_option_is_checked():
    with pytest.raises(ValueError, match="view_angle_row"):
        BAOptions(view_angle_row="implicit")


def test_view_angle_offset_against_mpmath():
    """The three branches of the offset (the mid series for |t| < 0.0316, the long one for
    |t| <= 1/8, arctan beyond) against 50 digits, each branch with a third of the rays."""
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 50
    rng = np.random.default_rng(9)
    n = 420
    Xc = rng.normal(size=(n, 3)) * [1.0, 1.0, 0.4] + [0.0, 0.0, 1.0]
    Xc[::5, 2] *= -1.0
    sg = np.where(Xc[:, 2] < 0, -1.0, 1.0)[:, None]
    th_true = np.arctan2(np.hypot(*(sg * Xc)[:, :2].T), (sg * Xc)[:, 2])
    # |t| = |tan(delta)|: 1e-9 to 0.025 (mid), 0.035 to 0.11 (long), 0.16 to 1 (arctan)
    tiers = [rng.uniform(lo, hi, n // 3) for lo, hi in ((-9, -1.6), (-1.45, -0.96), (-0.8, 0))]
    delta = rng.choice([-1.0, 1.0], n) * 10.0 ** np.concatenate(tiers)
    th = th_true + delta
    res, _, _ = kernels.polar_rows_mapped(Xc, np.tile([1.0, 1, 0, 0, 0, 0], (n, 1)),
                                          np.zeros((n, 2)), th, _cs(th), np.ones(n))
    for m in range(n):
        x, y, z = (mpmath.mpf(float(v)) * int(sg[m, 0]) for v in Xc[m])
        exact = mpmath.atan2(mpmath.sqrt(x * x + y * y), z) - mpmath.mpf(float(th[m]))
        assert abs(res[m, 2] - float(exact)) <= 1e-15, (m, res[m, 2], float(exact))
    t2 = np.tan(res[:, 2]) ** 2  # the offset is atan(t)
    mid, long = (t2 < MID_T2).sum(), ((t2 >= MID_T2) & (t2 <= SERIES_MAX**2)).sum()
    assert min(mid, long, n - mid - long) >= n // 3 - 5  # each branch ran on a third
