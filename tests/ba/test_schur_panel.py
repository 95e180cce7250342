"""The panel Schur path (ba/schur_panel.py: window GEMMs) against the entry-pair kernel and an
independent dense product, and whole solves with it forced on against the kernel path.

* S (upper triangle, what the Cholesky reads) and b equal ``U - Zd Zd^T`` + damping built
  densely from explicit per-entry Z = W L^-T (1e-12 relative), and the kernel path's S, for
  several window widths, on structures with two-view tracks only, cameras that share no point
  with another (single-view points), fixed cameras, and Nv not a multiple of the width.
* Every form (the three-slot ones through the fused build's cross blocks) ends at the kernel
  path's final cost to 1e-10 relative, same iteration count.
"""

import numpy as np
import pytest

from polarref.ba import BAOptions, prepare, schur_panel, solve
from polarref.ba.parameterization import PARAMS
from polarref.ba.schur import SchurStructure, chol_inv3
from polarref.ba.synthetic import ring_problem

pytest.importorskip("numba")


def _structure(obs_cam, obs_pt, num_cameras, fixed=()):
    order = np.lexsort((obs_cam, obs_pt))
    cam, pt = obs_cam[order], obs_pt[order]
    cv = np.ones(num_cameras, bool)
    cv[list(fixed)] = False
    st = SchurStructure(cam[None], [(0, 6)], pt, cv, int(pt.max()) + 1, 10**6, fast=True)
    return st


def _inputs(st, rng):
    B = rng.standard_normal((st.B, 6, 6))
    W = rng.standard_normal((st.E, 6, 3))
    A = rng.standard_normal((st.P, 3, 3))
    Vd = A @ A.transpose(0, 2, 1) + 3 * np.eye(3)
    return B, W, Vd, rng.standard_normal((st.Nv, 6)), rng.standard_normal((st.P, 3)), \
        rng.uniform(1, 2, (st.Nv, 6))


def _dense_reference(st, U, W, Vd, g_c, g_p, diag_c):
    """U - Zd Zd^T + D and -g_c + Zd L^-1 g_p from explicit dense matrices."""
    Nv, P = st.Nv, st.P
    Wd = np.zeros((6 * Nv, 3 * P))
    for e in range(st.E):
        c, p = st.entry_cam[e], st.entry_pt[e]
        Wd[6 * c:6 * c + 6, 3 * p:3 * p + 3] = W[e]
    Vinv = np.zeros((3 * P, 3 * P))
    for p in range(P):
        Vinv[3 * p:3 * p + 3, 3 * p:3 * p + 3] = np.linalg.inv(Vd[p])
    Ud = np.zeros((Nv, 6, Nv, 6))
    Ud[st.u_ca, :, st.u_cb, :] = U
    S = Ud.reshape(6 * Nv, 6 * Nv) - Wd @ Vinv @ Wd.T + np.diag(diag_c.ravel())
    return S, -g_c.ravel() + Wd @ Vinv @ g_p.ravel()


def _cases():
    rng = np.random.default_rng(3)
    # two-view tracks on a ring of 13 cameras (consecutive pairs)
    first = rng.integers(0, 13, 80)
    two = (np.r_[first, (first + 1) % 13], np.r_[np.arange(80), np.arange(80)], 13, ())
    # tracks of 1..6 random cameras of 11, camera 10 sees only single-view points (no shared
    # point), camera 0 fixed
    cams, pts = [], []
    for p in range(120):
        k = rng.integers(1, 7)
        cams += list(rng.choice(10, k, replace=False))
        pts += [p] * k
    cams += [10] * 5
    pts += list(range(120, 125))
    mixed = (np.array(cams), np.array(pts), 11, (0,))
    return {"two-view": two, "mixed": mixed}


@pytest.mark.parametrize("case", ["two-view", "mixed"])
@pytest.mark.parametrize("width", [1, 2, 3, 4, 8, 16])
def test_panel_system_equals_dense_product_and_kernel(case, width):
    obs_cam, obs_pt, n, fixed = _cases()[case]
    st = _structure(obs_cam, obs_pt, n, fixed)
    U, W, Vd, g_c, g_p, diag_c = _inputs(st, np.random.default_rng(width))
    S_ref, b_ref = _dense_reference(st, U, W, Vd, g_c, g_p, diag_c)
    st.use_panels(0)
    assert st.panel is None and st.dense_blocks
    S_k, b_k, _ = st.reduced_system(U, W, Vd, g_c, g_p, diag_c)
    st.use_panels(width)
    assert st.panel is not None and not st.dense_blocks
    assert "window GEMMs" in st.linear_solver_name()
    S_p, b_p, _ = st.reduced_system(U, W, Vd, g_c, g_p, diag_c)
    up = np.triu_indices_from(S_ref)
    scale = np.abs(S_ref[up]).max()
    assert np.abs(S_p[up] - S_ref[up]).max() <= 1e-12 * scale
    assert np.abs(S_p[up] - S_k[up]).max() <= 1e-12 * scale
    np.testing.assert_allclose(b_p, b_ref, rtol=0, atol=1e-12 * np.abs(b_ref).max())
    # the plan's padded flops: 216 w^2 per (point, window I <= J) triple
    assert st.panel.padded_flops == 216.0 * width**2 * schur_panel.window_triples(
        st.entry_bounds, st.entry_cam, width)


def test_choose_width_keeps_kernel_for_short_scattered_tracks():
    obs_cam, obs_pt, n, fixed = _cases()["mixed"]
    st = _structure(obs_cam, obs_pt, n, fixed)
    assert st.panel is None  # tracks of 1-6 random cameras: padding loses (cost model)
    # the cost model's GEMM flops grow with the width squared per triple
    t = [schur_panel.window_triples(st.entry_bounds, st.entry_cam, w) for w in (1, 2, 4)]
    assert t[0] == st.num_pairs and t[0] >= t[1] >= t[2]


@pytest.fixture(scope="module")
def ring():
    p = ring_problem(40, 600, 9.0, seed=2)
    prepare(p)
    return p


@pytest.mark.parametrize("param", list(PARAMS))
def test_solve_with_panels_equals_kernel_path(ring, param, monkeypatch):
    runs = {}
    for width in (0, 4):
        monkeypatch.setattr(schur_panel, "choose_width", lambda *a, w=width: w)
        q = ring.copy()
        runs[width] = solve(q, BAOptions(param=param, max_iterations=8, kernels="numba"),
                            prepared=True)
    a, b = runs[0], runs[4]
    assert "window GEMMs, width 4" in b.linear_solver and "window" not in a.linear_solver
    assert b.final_cost < 0.5 * b.initial_cost
    assert a.iterations == b.iterations
    assert abs(a.final_cost - b.final_cost) <= 1e-10 * a.final_cost
