"""Per-solve fixed costs cut without changing results (issue 35): the structure build's
unique/inverse against numpy's sort-based np.unique and the searchsorted definition of the
indices; choose_width's lower-bound skip against the unpruned rule; the dsyrk path's kept
buffer against a fresh structure and a dense reference; the cached BLAS controller."""

from unittest import mock

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from polarref.ba import schur_panel, solver
from polarref.ba.options import BAOptions
from polarref.ba.problem import prepare
from polarref.ba.schur import SchurStructure, unique_inverse
from polarref.ba.synthetic import ring_problem


@pytest.mark.parametrize("n, bound", [(5000, 400), (5000, 10_000_000), (0, 10), (1, 1)])
def test_unique_inverse_matches_numpy(n, bound):
    keys = np.random.default_rng(n + bound).integers(0, bound, n)
    uniq, inv = unique_inverse(keys, bound)
    ref_u, ref_inv = np.unique(keys, return_inverse=True)
    assert uniq.dtype == np.int64 and inv.dtype == np.int64
    np.testing.assert_array_equal(uniq, ref_u)
    np.testing.assert_array_equal(inv, ref_inv.reshape(-1))
    np.testing.assert_array_equal(uniq[inv], keys)


def test_structure_indices_by_definition():
    rng = np.random.default_rng(3)
    P, N, M = 300, 12, 2400
    obs_pt = np.sort(np.r_[np.arange(P), rng.integers(0, P, M - P)])
    slot_cams = rng.integers(0, N, (1, M))
    cam_var = np.ones(N, bool)
    cam_var[[0, 5]] = False
    st = SchurStructure(slot_cams, [(0, 6)], obs_pt, cam_var, P, 700, fast=True, anchored=False)
    vc = st.var_index[slot_cams]
    nv = st.Nv
    key = np.where(vc >= 0, obs_pt * nv + vc, -1)
    ukeys = np.unique(key[key >= 0])
    np.testing.assert_array_equal(st.entry_pt * nv + st.entry_cam, ukeys)
    np.testing.assert_array_equal(
        st.slot_entry, np.where(key >= 0, np.searchsorted(ukeys, np.maximum(key, 0)), -1))
    ukey = np.where(vc[0] >= 0, vc[0] * nv + vc[0], -1)
    allk = np.unique(ukey[ukey >= 0])
    np.testing.assert_array_equal(st.u_ca * nv + st.u_cb, allk)
    np.testing.assert_array_equal(
        st.u_pairs[0][2], np.where(ukey >= 0, np.searchsorted(allk, np.maximum(ukey, 0)), -1))
    obs_e = st.slot_entry[0][st.slot_entry[0] >= 0]
    assert st.observer_unique == (len(np.unique(obs_e)) == len(obs_e))


def _choose_width_unpruned(entry_bounds, entry_cam, num_pairs, nv):
    """choose_width's rule with every width's exact count (no lower-bound skip)."""
    best, best_s = 0, num_pairs * schur_panel._PAIR_KERNEL_S
    for w in schur_panel.WIDTHS:
        if w > nv:
            break
        s = schur_panel.estimate_s(schur_panel.window_triples(entry_bounds, entry_cam, w), w,
                                   -(-nv // w))
        if s < best_s:
            best, best_s = w, s
    return best


@pytest.mark.parametrize("track, spread", [(3, 200), (4, 200), (12, 16), (30, 40), (8, 8)])
def test_choose_width_pruning_keeps_the_choice(track, spread):
    rng = np.random.default_rng(track * 1000 + spread)
    P, nv = 400, spread
    cams = [np.sort(rng.choice(nv, size=min(track, nv), replace=False)) for _ in range(P)]
    if spread <= 40:  # runs of consecutive cameras (SfM-like): windows can win
        cams = [np.arange(s0, s0 + min(track, nv)) % nv for s0 in rng.integers(0, nv, P)]
        cams = [np.sort(c) for c in cams]
    entry_cam = np.concatenate(cams).astype(np.int64)
    counts = np.array([len(c) for c in cams])
    entry_bounds = np.r_[0, np.cumsum(counts)].astype(np.int64)
    num_pairs = int((counts * (counts + 1) // 2).sum())
    assert schur_panel.choose_width(entry_bounds, entry_cam, num_pairs, nv) == \
        _choose_width_unpruned(entry_bounds, entry_cam, num_pairs, nv)


@pytest.mark.parametrize("fast", [True, False])
def test_dsyrk_buffer_reused_across_builds_equals_fresh(fast):
    """The dsyrk path keeps its scattered Z between builds: a second build with other
    values gives bitwise the S and b of a fresh structure, and S matches U - W V^-1 W^T."""
    rng = np.random.default_rng(7)
    P, N, M = 80, 6, 480
    obs_pt = np.sort(np.r_[np.arange(P), rng.integers(0, P, M - P)])
    slot_cams = rng.integers(0, N, (1, M))
    cam_var = np.ones(N, bool)

    def make():
        st = SchurStructure(slot_cams, [(0, 6)], obs_pt, cam_var, P, 700, fast=fast,
                            anchored=False)
        st.use_gemm = True  # the path under test, whatever the cost model picks here
        return st

    def inputs(seed):
        r = np.random.default_rng(seed)
        Jc, Jp, res = r.normal(size=(M, 2, 6)), r.normal(size=(M, 2, 3)), r.normal(size=(M, 2))
        st = make()
        V, g_p = st.point_terms(Jp, res)
        g_c, W, U = st.build([Jc], Jp, res)
        return U, W, V + np.eye(3), g_c, g_p, np.full((st.Nv, 6), 0.5)

    kept = make()
    kept.reduced_system(*inputs(1))
    a = inputs(2)
    S1, b1, _ = kept.reduced_system(*a)
    S2, b2, _ = make().reduced_system(*a)
    up = np.triu_indices(len(b1))
    np.testing.assert_array_equal(S1.T[up[1], up[0]], S2.T[up[1], up[0]])
    np.testing.assert_array_equal(b1, b2)
    # reference: dense U - sum_p W_p V_p^-1 W_p^T + damping, the lower triangle of S.T
    U, W, Vd, g_c, g_p, dc = a
    st = make()
    ref = np.zeros((st.Nv, 6, st.Nv, 6))
    ref[st.u_ca, :, st.u_cb, :] = U
    for p in range(P):
        e = np.flatnonzero(st.entry_pt == p)
        Wp = np.zeros((st.Nv, 6, 3))
        Wp[st.entry_cam[e]] = W[e]
        Wp = Wp.reshape(-1, 3)
        ref = ref - (Wp @ np.linalg.solve(Vd[p], Wp.T)).reshape(ref.shape)
    ref = ref.reshape(6 * st.Nv, -1) + np.diag(dc.reshape(-1))
    lo = np.tril_indices(len(b1))
    np.testing.assert_allclose(S1.T[lo], ref[lo], rtol=1e-10, atol=1e-9)


def test_solve_limits_blas_threads_and_restores_them():
    """The cached threadpool controller still limits BLAS inside a solve and restores the
    process's setting afterwards."""
    before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    seen = []
    real = solver._solve

    def spy(*a):
        seen.append([i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"])
        return real(*a)

    p = ring_problem(6, 60, 4.0, seed=0)
    prepare(p)
    with mock.patch.object(solver, "_solve", spy):
        for _ in range(2):
            solver.solve(p.copy(), BAOptions(max_iterations=2, blas_threads=1), prepared=True)
    assert seen and all(t == 1 for s in seen for t in s)
    assert [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"] == before


def test_blas_controller_is_made_again_after_an_import():
    """A BLAS loaded by a later import must not escape the limit: the cached controller is
    rebuilt when the module table grows, and reused while it does not."""
    first = solver._blas_controller()
    assert solver._blas_controller() is first
    with mock.patch.dict("sys.modules", {"polarref_test_fake_module": object()}):
        again = solver._blas_controller()
    assert again is not first


@pytest.mark.parametrize("param", ["euclidean", "parallax", "polar", "angular"])
@pytest.mark.parametrize("loss", ["trivial", "cauchy"])
def test_summary_pixel_costs_equal_a_fresh_evaluation(param, loss):
    """The solver reads the pixel residuals out of its own evaluations where the form holds
    them (pixel_part): the summary's initial and final pixel costs are bitwise those of a
    separate pixel_residuals pass at the start and at the solution."""
    from polarref.ba.parameterization import make_param
    p = ring_problem(8, 120, 4.0, seed=2)
    prepare(p)
    rng = np.random.default_rng(0)
    p.X = p.X + rng.normal(0, 0.01, p.X.shape)
    opts = BAOptions(param=param, loss=loss, max_iterations=4, function_tolerance=0.0)
    start = make_param(p.copy(), opts)
    want0 = solver.pixel_cost(start.pixel_residuals(p.R, p.C, start.init_points()), loss, 1.0)
    q = p.copy()
    par = make_param(q, opts)
    s = solver.solve(q, opts, prepared=True, param=par)
    want1 = solver.pixel_cost(par.pixel_residuals(q.R, q.C, s.points_state), loss, 1.0)
    assert (s.initial_pixel_cost, s.initial_rms_px) == want0
    assert (s.final_pixel_cost, s.final_rms_px) == want1
    assert s.final_pixel_cost < s.initial_pixel_cost
    holds = par.pixel_part(np.zeros((3, par.k)))
    assert (holds is None) == (param == "angular")
