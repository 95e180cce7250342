"""The reduced-system solvers (ba/reduced_solve.py): PCG with block-Jacobi gives the dense
Cholesky step to rounding, in every form, on the dense and on the sparse S; the size rule."""

import numpy as np
import pytest
import scipy.sparse

from polarref.ba import BAOptions, prepare, solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.parameterization import FORMS
from polarref.ba.reduced_solve import ReducedSolver, choose, diagonal_blocks, pcg
from polarref.ba.synthetic import synthetic_reconstruction


@pytest.fixture(scope="module")
def problem():
    init, _ = synthetic_reconstruction(12, 150, seed=11, noise_px=0.5, rot_deg=0.3,
                                       point_sigma=0.05, center_sigma=0.05, track_length=4)
    p = problem_from_reconstruction(init)
    prepare(p)
    return p


def _spd(n_blocks: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(6 * n_blocks, 6 * n_blocks))
    return A @ A.T + 6 * n_blocks * np.eye(6 * n_blocks)


def test_pcg_matches_direct_solve_dense_and_sparse():
    S = _spd(7, 0)
    b = np.random.default_rng(1).normal(size=len(S))
    x_ref = np.linalg.solve(S, b)
    # dense: only the upper triangle (C order) is read, as by the Cholesky: garbage below
    Su = np.triu(S) + np.tril(np.full_like(S, 1e6), -1)
    for A in (Su, scipy.sparse.csc_matrix(S)):
        res = pcg(A, b, 1e-13, 500)
        assert res.relative_residual <= 1e-13
        assert np.abs(res.x - x_ref).max() <= 1e-11 * np.abs(x_ref).max()
        assert 1 <= res.iterations <= 42  # exact arithmetic: at most n = 42


def test_pcg_block_jacobi_is_exact_on_block_diagonal():
    rng = np.random.default_rng(2)
    blocks = [(lambda a: a @ a.T + np.eye(6))(rng.normal(size=(6, 6))) for _ in range(5)]
    S = scipy.sparse.block_diag(blocks).tocsc()
    np.testing.assert_allclose(diagonal_blocks(S), np.stack(blocks), rtol=0, atol=0)
    res = pcg(S, rng.normal(size=30), 1e-14, 50)
    assert res.iterations == 1  # the preconditioner is S^-1


def test_pcg_refuses_indefinite():
    S = _spd(3, 4)
    S[0, 0] = -1.0
    assert pcg(S, np.ones(len(S)), 1e-10, 100).x is None


def test_choose_by_size():
    assert choose("auto", 700, 700, 2000) is ReducedSolver.DENSE_CHOLESKY
    assert choose("auto", 701, 700, 2000) is ReducedSolver.SPARSE_LU
    assert choose("auto", 2000, 700, 2000) is ReducedSolver.PCG
    assert choose("pcg", 5, 700, 2000) is ReducedSolver.PCG
    with pytest.raises(ValueError):
        choose("cholmod", 5, 700, 2000)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("sparse", [False, True])
def test_lm_steps_equal_dense_cholesky(problem, form, sparse):
    """Three LM iterations: the same accepted steps and poses to rounding."""
    ref_p, pcg_p = problem.copy(), problem.copy()
    base = BAOptions(param=form, max_iterations=3, function_tolerance=0.0)
    ref = solve(ref_p, base, prepared=True)
    opts = BAOptions(param=form, max_iterations=3, function_tolerance=0.0,
                     reduced_solver="pcg", pcg_rtol=1e-13,
                     dense_max_cameras=1 if sparse else 700)
    out = solve(pcg_p, opts, prepared=True)
    assert "dense Cholesky" in ref.linear_solver and "PCG block-Jacobi" in out.linear_solver
    assert [r.accepted for r in out.trace] == [r.accepted for r in ref.trace]
    assert abs(out.final_cost - ref.final_cost) <= 1e-9 * ref.final_cost
    assert ref.final_cost < 0.5 * ref.initial_cost  # the steps did something
    scale = np.abs(ref_p.C).max()
    assert np.abs(out_c := pcg_p.C - ref_p.C).max() <= 1e-8 * scale, out_c
    assert np.abs(pcg_p.R - ref_p.R).max() <= 1e-8


@pytest.mark.parametrize("form", ["euclidean", "polar"])
def test_sparse_lu_forced_equals_cholesky(problem, form):
    a, b = problem.copy(), problem.copy()
    ra = solve(a, BAOptions(param=form, max_iterations=3), prepared=True)
    rb = solve(b, BAOptions(param=form, max_iterations=3, reduced_solver="sparse-lu"),
               prepared=True)
    assert "sparse LU" in rb.linear_solver
    assert abs(ra.final_cost - rb.final_cost) <= 1e-9 * ra.final_cost


@pytest.mark.parametrize("form", ["euclidean", "polar"])
def test_block_sparse_schur_equals_numpy_sparse_system(problem, form):
    """Issue 35: the kernel path's block-sparse S (entry-pair products into camera-pair blocks,
    laid out as symmetric BSR) is the numpy path's sparse S (camera-pair GEMMs) to rounding,
    and so is b."""
    from polarref.ba import kernels
    from polarref.ba.parameterization import make_param
    from polarref.ba.schur import SchurStructure

    if not kernels.available():
        pytest.skip("numba kernels unavailable")
    p = problem
    prm = make_param(p, BAOptions(param=form))
    r, Jp, Jc = prm.evaluate(p.R, p.C, prm.init_points(), True, factored=False)
    out = []
    for fast in (False, True):
        st = SchurStructure(prm.slot_cams, prm.slot_cols, p.obs_pt, p.cam_mask.any(1), p.num_points,
                            dense_max_cameras=1, fast=fast, anchored=False)
        assert st.sparse_S and ("block-sparse" in st.linear_solver_name()) == fast
        mask_v = p.cam_mask[st.var_cams].astype(float)
        g_c, W, U = st.apply_mask(mask_v, *st.build(Jc, Jp, r))
        V, g_p = st.point_terms(Jp, r)
        Vd = V + 1e-2 * np.eye(3)
        diag_c = np.where(mask_v > 0, 0.5 + np.arange(6), 1.0)
        S, b, _ = st.reduced_system(U, W, Vd, g_c, g_p, diag_c)
        out.append((S.toarray(), b))
    (S0, b0), (S1, b1) = out
    assert np.abs(S0).max() > 0 and np.abs(S1 - S1.T).max() == 0.0      # the BSR is symmetric exactly
    np.testing.assert_allclose(S1, S0, rtol=0, atol=1e-12 * np.abs(S0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-12 * np.abs(b0).max())


def test_dense_camera_pair_blocks_equal_the_dense_kernel(problem):
    """The Euclidean dense path's products into camera-pair blocks, scattered into S, give the
    upper triangle (what the Cholesky reads) and b of the kernel writing into S directly."""
    from polarref.ba import kernels
    from polarref.ba.parameterization import make_param
    from polarref.ba.schur import SchurStructure

    if not kernels.available():
        pytest.skip("numba kernels unavailable")
    p = problem
    prm = make_param(p, BAOptions(param="euclidean"))
    r, Jp, Jc = prm.evaluate(p.R, p.C, prm.init_points(), True, factored=False)
    st = SchurStructure(prm.slot_cams, prm.slot_cols, p.obs_pt, p.cam_mask.any(1), p.num_points, fast=True)
    st.use_gemm = False
    st._build_blocks()
    mask_v = p.cam_mask[st.var_cams].astype(float)
    g_c, W, U = st.apply_mask(mask_v, *st.build(Jc, Jp, r))
    V, g_p = st.point_terms(Jp, r)
    out = []
    for blocks in (False, True):
        st.dense_blocks = blocks
        S, b, _ = st.reduced_system(U, W, V + 1e-2 * np.eye(3), g_c, g_p, np.full((st.Nv, 6), 0.3))
        out.append((np.triu(S), b))
    (S0, b0), (S1, b1) = out
    assert np.abs(S0).max() > 0
    np.testing.assert_allclose(S1, S0, rtol=0, atol=1e-12 * np.abs(S0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-12 * np.abs(b0).max())
    assert "camera-pair blocks" in st.linear_solver_name()
