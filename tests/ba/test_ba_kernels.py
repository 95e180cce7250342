"""The compiled kernels (ba/kernels.py) against the numpy reference path.

* Whole solves: every parameterization, with and without a robust loss and with fixed points,
  ends at the same cost (1e-9 relative) and the same poses/points with ``kernels="numba"`` as
  with ``kernels="numpy"``, on dense and on sparse visibility (different Schur paths).
* Every form: the kernels' residuals and slot Jacobians, dense and factored (anchors), equal
  the numpy ones (1e-12).
* The Schur step of the kernel path equals the full damped normal equations assembled densely
  (the independent implementation in test_ba_convergence.py).
"""

import numpy as np
import pytest

from polarref.ba import BAOptions, prepare, solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.solver import make_param
from polarref.ba.synthetic import synthetic_reconstruction
from polarref.ba.parameterization import PARAMS as FORM_NAMES

pytest.importorskip("numba")

PARAMS = list(FORM_NAMES)


def _problem(num_cameras, num_points, track, seed=4):
    init, _ = synthetic_reconstruction(num_cameras, num_points, seed=seed, noise_px=0.5,
                                       rot_deg=0.3, point_sigma=0.05, center_sigma=0.05,
                                       track_length=track)
    p = problem_from_reconstruction(init)
    prepare(p)
    return p


@pytest.fixture(scope="module")
def problems():
    return {"dense": _problem(8, 60, -1), "sparse": _problem(24, 300, 4)}


@pytest.mark.parametrize("param", PARAMS)
@pytest.mark.parametrize("case", ["dense", "sparse", "sparse-huber-fixed"])
def test_kernel_solve_equals_numpy_solve(problems, param, case):
    p = problems["dense" if case == "dense" else "sparse"]
    opts = BAOptions(param=param, max_iterations=30)
    if case == "sparse-huber-fixed":
        p = p.copy()
        p.pt_fixed = np.zeros(p.num_points, bool)
        p.pt_fixed[::17] = True
        opts = BAOptions(param=param, max_iterations=30, loss="huber", loss_scale=2.0)
    runs = {}
    for k in ("numpy", "numba"):
        q = p.copy()
        s = solve(q, BAOptions(**{**opts.__dict__, "kernels": k}), prepared=True)
        runs[k] = (s, q)
    (a, qa), (b, qb) = runs["numpy"], runs["numba"]
    assert "numpy" in a.linear_solver and "numba" in b.linear_solver
    # sparse visibility: the entry-pair Schur kernel (three-slot forms: the fused, factored build)
    assert ("entry-pair kernel" in b.linear_solver) == (case != "dense")
    assert a.iterations == b.iterations and a.iterations >= 2
    assert b.final_cost < 0.5 * b.initial_cost  # it did solve something
    assert abs(a.final_cost - b.final_cost) <= 1e-9 * a.final_cost
    scale = np.abs(qa.C).max() + np.abs(qa.X).max()
    np.testing.assert_allclose(qb.R, qa.R, atol=1e-8)
    np.testing.assert_allclose(qb.C, qa.C, atol=1e-8 * scale)
    np.testing.assert_allclose(qb.X, qa.X, atol=1e-7 * scale)


@pytest.mark.parametrize("param", PARAMS)
def test_kernel_jacobians_equal_numpy(problems, param):
    p = problems["sparse"]
    ref = make_param(p, BAOptions(param=param, kernels="numpy"))
    fast = make_param(p, BAOptions(param=param, kernels="numba", view_angle_row="explicit"))
    assert fast.fast and not ref.fast
    pts = ref.init_points() + 1e-3  # off the initial point, every term non-trivial
    r0, Jp0, Jc0 = ref.evaluate(p.R, p.C, pts, True, factored=False)
    r1, Jp1, Jc1 = fast.evaluate(p.R, p.C, pts, True, factored=False)
    np.testing.assert_allclose(r1, r0, rtol=0, atol=1e-12 * np.abs(r0).max())
    for J1, J0 in zip([Jp1, *Jc1], [Jp0, *Jc0], strict=True):
        np.testing.assert_allclose(J1, J0, rtol=0, atol=1e-12 * np.abs(J0).max())
    if param != "euclidean":  # the factored anchors (the solver's form on the fused path)
        r1, Jp1, (Jo1, anc1) = fast.evaluate(p.R, p.C, pts, True, factored=True)
        _, _, (Jo0, anc0) = ref.evaluate(p.R, p.C, pts, True, factored=True)
        assert r1.shape == r0.shape and Jp1.shape == Jp0.shape
        for J1, J0 in ((r1, r0), (Jp1, Jp0), (Jo1, Jo0), (anc1.Ad, anc0.Ad), (anc1.h, anc0.h)):
            np.testing.assert_allclose(J1, J0, rtol=0, atol=1e-12 * np.abs(J0).max())
    np.testing.assert_allclose(fast.pixel_residuals(p.R, p.C, pts),
                               ref.pixel_residuals(p.R, p.C, pts), rtol=0, atol=1e-9)


def test_kernels_choice(monkeypatch):
    from polarref.ba import kernels
    from polarref.core.errors import PolarrefError
    assert kernels.use_kernels("auto") and kernels.use_kernels("numba")
    assert not kernels.use_kernels("numpy")
    monkeypatch.setattr(kernels, "available", lambda: False)
    assert not kernels.use_kernels("auto")
    with pytest.raises(PolarrefError, match="numba"):
        kernels.use_kernels("numba")
    with pytest.raises(ValueError, match="kernels"):
        BAOptions(kernels="fortran")


@pytest.mark.parametrize("param", ["parallax", "polar"])
def test_fused_build_accumulating_cross_blocks(problems, param, monkeypatch):
    """The fused three-slot build writes its observer x anchor blocks once per entry when no
    camera observes a point twice (every problem here); the accumulating branch, for problems
    where one does, must give the same solve (against the numpy path, 1e-9)."""
    from polarref.ba import schur
    init = schur.SchurStructure.__init__

    def accumulating(self, *a, **k):
        init(self, *a, **k)
        self.observer_unique = False

    p = problems["sparse"]
    ref = solve(p.copy(), BAOptions(param=param, max_iterations=30, kernels="numpy"),
                prepared=True)
    monkeypatch.setattr(schur.SchurStructure, "__init__", accumulating)
    got = solve(p.copy(), BAOptions(param=param, max_iterations=30, kernels="numba"),
                prepared=True)
    assert "entry-pair kernel" in got.linear_solver
    assert got.iterations == ref.iterations >= 2
    assert abs(got.final_cost - ref.final_cost) <= 1e-9 * ref.final_cost


def test_angular_kernel_rows_with_axis_chart_rows_equal_numpy(problems):
    """The compiled angular rows leave the axis-chart rows of the phi-gated observations to
    numpy: with a phi gate tight enough to gate about a third of the observations, residuals
    and factored Jacobians still equal the numpy path's (1e-12)."""
    p = problems["sparse"]
    opts = dict(param="angular", max_sigma_phi=0.005)  # gates 448 of 1,200 observations
    ref = make_param(p, BAOptions(**opts, kernels="numpy"))
    fast = make_param(p, BAOptions(**opts, kernels="numba"))
    assert fast.use_chart and 0.2 < len(fast.chart_idx) / p.num_observations < 0.8
    pts = ref.init_points() + 1e-3
    r0, Jp0, (Jo0, anc0) = ref.evaluate(p.R, p.C, pts, True, factored=True)
    r1, Jp1, (Jo1, anc1) = fast.evaluate(p.R, p.C, pts, True, factored=True)
    # the chart rows differ from the (theta, phi) rows: a kernel ignoring them fails here
    th = make_param(p, BAOptions(param="angular", kernels="numba", axis_residual="theta"))
    assert np.abs(th.evaluate(p.R, p.C, pts, True, factored=True)[0] - r0).max() > 1e-3
    for a, b in ((r1, r0), (Jp1, Jp0), (Jo1, Jo0), (anc1.Ad, anc0.Ad)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * np.abs(b).max())


@pytest.mark.parametrize("param", ["parallax", "polar", "angular"])
@pytest.mark.parametrize("unique", [True, False])
def test_fused_reduced_system_equals_numpy_camera_pairs(problems, param, unique, monkeypatch):
    """The fused three-slot Schur pass (compact [N | t] cross terms per observer entry, formed
    into the observer x anchor blocks of S) gives the reduced system (S, b) of the numpy
    path (factored anchors, camera-pair GEMMs), every block, to 1e-12 of its largest entry;
    with ``unique`` False the build accumulates its cross terms instead of writing them."""
    from polarref.ba import schur
    from polarref.ba.anchor_terms import AnchorTerms
    monkeypatch.setattr(schur, "_PAIR_S", 0.0)  # both paths by entry / camera pairs
    monkeypatch.setattr(schur, "_SEGMENT_S", 0.0)
    monkeypatch.setattr(schur, "_PAIR_KERNEL_S", 0.0)
    p = problems["sparse"]
    prm = make_param(p, BAOptions(param=param, view_angle_row="explicit"))
    pts = prm.init_points() + 1e-3
    out = []
    for fast in (False, True):
        st = schur.SchurStructure(prm.slot_cams, prm.slot_cols, p.obs_pt, p.cam_mask.any(1),
                                  p.num_points, fast=fast)
        assert st.fused == fast and not st.use_gemm
        if fast and not unique:
            st.observer_unique = False
        r, Jp, Jc = prm.evaluate(p.R, p.C, pts, True, factored=True)
        builder = st if fast else AnchorTerms(st, p.obs_pt, *prm.anchor_cams)
        mask_v = p.cam_mask[st.var_cams].astype(float)
        g_c, W, U = st.apply_mask(mask_v, *builder.build(Jc, Jp, r))
        V, g_p = st.point_terms(Jp, r)
        Vd = V + 1e-3 * np.eye(3)
        S, b, _ = st.reduced_system(U, W, Vd, g_c, g_p, np.ones((st.Nv, 6)))
        out.append((np.triu(S), b))  # the kernel fills the upper triangle (Cholesky reads it)
    (S0, b0), (S1, b1) = out
    assert np.abs(np.triu(S0, 6)).max() > 0  # cameras coupled: cross blocks are exercised
    np.testing.assert_allclose(S1, S0, rtol=0, atol=1e-12 * np.abs(S0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-12 * np.abs(b0).max())


@pytest.mark.parametrize("k", [2, 3])
def test_pixel_rows_kernel_equals_numpy_projection(k):
    """The compiled pixel rows (Projector.residuals with ``compiled``) against the numpy
    projection (projection.project) on random rays with radial distortion: the same operations
    in the same order, so equal to rounding (1e-12 relative; bitwise here), and the view-angle
    row written in place beside them equals the numpy view-angle row (angular_obs.theta_rows, polar.py)."""
    from polarref.ba import kernels
    from polarref.ba.projection import project
    rng = np.random.default_rng(3)
    M = 500
    Xc = np.c_[rng.normal(size=(M, 2)), rng.uniform(0.5, 3.0, M)]
    Xc[::7, 2] *= -1.0  # behind the camera: projected anyway (both paths)
    K = np.c_[rng.uniform(300, 900, (M, 2)), rng.uniform(100, 400, (M, 2)),
              rng.normal(0, 0.1, M), rng.normal(0, 0.01, M)]
    obs = rng.uniform(0, 500, (M, 2))
    uv, Juv = project(Xc, K)
    for jac in (True, False):
        res, J = kernels.pixel_rows(Xc, K, obs, k, jac)
        assert res.shape == (M, k) and J.shape == ((M, k, 3) if jac else (0, k, 3))
        np.testing.assert_allclose(res[:, :2], uv - obs, rtol=1e-12, atol=0)
        if jac:
            np.testing.assert_allclose(J[:, :2], Juv, rtol=1e-12, atol=1e-300)
    if k == 3:
        theta_obs, w = rng.uniform(0, 1, M), rng.uniform(0.5, 2, M)
        res, J = kernels.pixel_rows(Xc, K, obs, 3, True)
        kernels.theta_row_into(Xc, theta_obs, w, res, J, True)
        from polarref.ba.angular_obs import theta_rows
        theta, Jt = theta_rows(Xc, True)
        ref_r, ref_J = np.c_[uv - obs, (theta - theta_obs) * w], np.concatenate([Juv, (Jt * w[:, None])[:, None]], 1)
        np.testing.assert_allclose(res, ref_r, rtol=1e-12, atol=0)
        np.testing.assert_allclose(J, ref_J, rtol=1e-12, atol=1e-300)
        assert np.abs(res[:, 2]).max() > 1e-3  # the third row is really there


def test_parallax_xyz_kernel_equals_numpy(problems):
    """The compiled write-back of parallax landmarks (to_xyz with kernels) against numpy's,
    off the initial estimate and with a tenth of the points at infinity (w = 0: written FAR
    baselines out, counted)."""
    p = problems["sparse"]
    ref = make_param(p, BAOptions(param="parallax", kernels="numpy"))
    fast = make_param(p, BAOptions(param="parallax", kernels="numba"))
    pts = ref.init_points() + 1e-3
    pts[::10, 2] = 0.0
    C = p.C + 0.01
    X0, X1 = ref.to_xyz(p.R, C, pts), fast.to_xyz(p.R, C, pts)
    assert ref.num_at_infinity == fast.num_at_infinity == len(pts[::10])
    np.testing.assert_allclose(X1, X0, rtol=1e-12, atol=0)
    assert np.abs(X1 - ref.to_xyz(p.R, C, ref.init_points())).max() > 1e-3  # pts matter


def test_angular_rows_kernel_modes_equal_numpy():
    """The compiled angular rows (forms_jit._angle_rows, _chart_row) per mode against the numpy rows of
    angular.py: whitened (theta, phi) with phi wrapped across +-pi, theta alone, and the axis
    chart through its near-axis series (t < 1e-3), on the axis itself and behind the camera
    (projective ray). Equal to rounding (1e-12 of the largest)."""
    from polarref.ba import kernels
    from polarref.ba.angular_obs import axis_chart_rows, phi_rows, theta_rows, wrap
    rng = np.random.default_rng(5)
    M = 600
    Xc = np.c_[rng.normal(size=(M, 2)), rng.uniform(0.5, 3.0, M)]
    Xc[::5, 2] *= -1.0
    Xc[1::9, :2] *= 1e-5  # near the axis: the chart's series
    Xc[2::31, :2] = 0.0  # on it
    obs = np.c_[rng.uniform(0, 1, M), rng.uniform(-np.pi, np.pi, M)]
    obs[3::11, 1] = np.pi - 1e-9  # phi - phi_obs past -pi: wrapped
    W = rng.normal(size=(M, 2, 2)) + 3 * np.eye(2)
    w_theta = rng.uniform(0.5, 2, M)
    mode = rng.integers(0, 3, M).astype(np.int8)
    mode[2::31] = kernels.CHART  # phi is undefined on the axis: only the chart goes there
    theta, Jt = theta_rows(Xc, True)
    phi, Jf = phi_rows(Xc, True)
    # every other row observed near its ray: the offsets' series (forms_jit._atan_ratio), both
    # tiers, phi's across +-pi too; the rest far off (arctan2)
    near = np.zeros(M, bool)
    near[::2] = True
    near &= np.abs(Xc[:, :2]).max(1) > 1e-3
    off = rng.choice([1e-4, 1e-2, 0.1], size=(M, 2)) * rng.choice([-1.0, 1.0], size=(M, 2))
    obs[near] = np.c_[theta, wrap(phi)][near] + off[near]
    obs[near, 1] = wrap(obs[near, 1])
    cs = np.c_[np.cos(obs[:, 0]), np.sin(obs[:, 0]), np.cos(obs[:, 1]), np.sin(obs[:, 1])]
    res, J = kernels.angular_rows(Xc, obs, cs, W, w_theta, mode, True)
    res_nj, J_nj = kernels.angular_rows(Xc, obs, cs, W, w_theta, mode, False)
    e, Je = axis_chart_rows(Xc, True)
    d_ang = np.c_[theta - obs[:, 0], wrap(phi - obs[:, 1])]
    ref = {0: (np.c_[d_ang[:, 0] * w_theta, np.zeros(M)],
               np.stack([Jt * w_theta[:, None], np.zeros((M, 3))], 1)),
           1: (np.einsum("mij,mj->mi", W, d_ang), W @ np.stack([Jt, Jf], 1)),
           2: (np.einsum("mij,mj->mi", W, e - obs), W @ Je)}
    for md, (r0, J0) in ref.items():
        sel = mode == md
        np.testing.assert_allclose(res[sel], r0[sel], rtol=0, atol=1e-12 * np.abs(r0).max())
        np.testing.assert_allclose(J[sel], J0[sel], rtol=0, atol=1e-12 * np.abs(J0[sel]).max())
        if md != kernels.CHART:  # the series rows to the rounding of numpy's own difference
            sn = sel & near
            assert sn.sum() > 40
            np.testing.assert_allclose(res[sn], r0[sn], rtol=0, atol=2e-15 * np.abs(W).max())
    np.testing.assert_array_equal(res_nj, res)
    assert J_nj.shape == (0, 2, 3)
    assert np.isfinite(res[mode == kernels.CHART]).all() and np.isfinite(J).all()
    # near the axis the chart's q x y term is ~1e-10 of J: unwhitened, to rounding of its own
    near = np.zeros(M, bool)
    near[1::9] = True
    near &= (mode == kernels.CHART) & (np.abs(Xc[:, :2]).max(1) > 0)
    W[near] = np.eye(2)
    J = kernels.angular_rows(Xc, obs, cs, W, w_theta, mode, True)[1]
    assert near.sum() > 10
    np.testing.assert_allclose(J[near, 0, 1], Je[near, 0, 1], rtol=1e-9)


@pytest.mark.parametrize("gated", [False, True])
def test_angular_fused_kernel_equals_its_stages(problems, gated):
    """The angular form's one-pass evaluation (forms_jit.angular_obs, the solver's factored
    path) equals its rays, rows and chain rule run as separate kernels, bitwise: the same
    operations in the same order. ``gated`` puts about a third of the rows on the axis chart
(a few are there by default)."""
    from polarref.ba import kernels
    p = problems["sparse"]
    prm = make_param(p, BAOptions(param="angular", kernels="numba",
                                  **({"max_sigma_phi": 0.005} if gated else {})))
    assert ((prm.mode == kernels.CHART).mean() > 0.2) == gated
    pts = prm.init_points() + 1e-3
    C = p.C + 0.01
    terms = prm.point_terms_for_rows(p.R, C, pts)
    res, Jp, Jo, Ad, row_map = prm.fused_obs(p.R, C, terms)
    assert row_map is None  # angular keeps its own rows
    Cm, d, sw, cw, hd, dh_dw, dh_de, dv_dab = terms
    Xc = kernels.parallax_rays(p.R, C, p.obs_cam, p.obs_pt, Cm, sw, hd)
    r1, Jx = prm.residual_rows(Xc, True)
    Jp1, Jo1, _, _, Ad1 = kernels.parallax_jacobians(Jx, Xc, p.R, C, p.obs_cam, p.obs_pt, Cm, d,
                                                     sw, cw, dh_dw, dh_de, dv_dab, False)
    for a, b in ((res, r1), (Jp, Jp1), (Jo, Jo1), (Ad, Ad1)):
        np.testing.assert_array_equal(a, b)
    assert np.abs(res).max() > 1e-3


@pytest.mark.parametrize("param", ["euclidean", "polar"])
def test_dense_visibility_reduced_system_equals_numpy(problems, param):
    """The dsyrk path (every camera sees every point): its compiled entry factors and scatter
    (schur_panel_jit) give numpy's S and b, to 1e-13 of their largest entries."""
    from polarref.ba import schur
    p = problems["dense"]
    prm = make_param(p, BAOptions(param=param, view_angle_row="explicit", anchor_schur="cross"))
    pts = prm.init_points() + 1e-3
    out = []
    for fast in (False, True):
        st = schur.SchurStructure(prm.slot_cams, prm.slot_cols, p.obs_pt, p.cam_mask.any(1), p.num_points,
                                  fast=fast, anchored=param == "polar")
        assert st.use_gemm and not st.sparse_S
        r, Jp, Jc = prm.evaluate(p.R, p.C, pts, True, factored=param == "polar")
        if param == "polar" and not fast:
            from polarref.ba.anchor_terms import AnchorTerms
            builder = AnchorTerms(st, p.obs_pt, *prm.anchor_cams)
        else:
            builder = st
        mask_v = p.cam_mask[st.var_cams].astype(float)
        g_c, W, U = st.apply_mask(mask_v, *builder.build(Jc, Jp, r))
        V, g_p = st.point_terms(Jp, r)
        S, b, _ = st.reduced_system(U, W, V + 1e-3 * np.eye(3), g_c, g_p, np.ones((st.Nv, 6)))
        S2, _, _ = st.reduced_system(U, W, 2.0 * V + 1e-3 * np.eye(3), g_c, g_p, np.ones((st.Nv, 6)))
        out.append((np.triu(S), b, np.triu(S2)))
    (S0, b0, T0), (S1, b1, T1) = out
    assert np.abs(np.triu(S0, 6)).max() > 0 and np.abs(b0).max() > 0
    np.testing.assert_allclose(S1, S0, rtol=0, atol=1e-13 * np.abs(S0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-13 * np.abs(b0).max())
    # a second pass through the kept scatter buffer (other point blocks): nothing of the first left
    np.testing.assert_allclose(T1, T0, rtol=0, atol=1e-13 * np.abs(T0).max())
    assert np.abs(T0 - S0).max() > 1e-9 * np.abs(S0).max()
