"""The three-slot forms on the block-sparse reduced system (schur_sparse_jit.py): the fused
build's cross blocks and the X-space elimination into the camera-pair blocks give the LM steps
of the numpy reference (dense S, slot Jacobians, anchor cross terms: an independent
implementation) and of the dense kernel path."""

import numpy as np
import pytest

from polarref.ba import BAOptions, prepare, solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.synthetic import synthetic_reconstruction

pytest.importorskip("numba")


@pytest.fixture(scope="module")
def problem():
    init, _ = synthetic_reconstruction(24, 300, seed=7, noise_px=0.5, rot_deg=0.3,
                                       point_sigma=0.05, center_sigma=0.05, track_length=4)
    p = problem_from_reconstruction(init)
    prepare(p)
    # a camera with held columns besides the gauge's: the cross blocks' held rows/columns
    # must vanish (zero_held_blocks), not only U's and W's
    p.cam_mask[5, [1, 4]] = False
    return p


def _run(p, **kw):
    q = p.copy()
    s = solve(q, BAOptions(max_iterations=12, loss="cauchy", **kw), prepared=True)
    return s, q


@pytest.mark.parametrize("param", ["parallax", "polar"])
@pytest.mark.parametrize("schur", ["xspace", "cross"])
def test_block_sparse_three_slot_equals_dense_and_numpy(problem, param, schur):
    ref, qr = _run(problem, param=param, kernels="numpy", anchor_schur=schur)
    dense, qd = _run(problem, param=param, anchor_schur=schur)
    sparse, qs = _run(problem, param=param, anchor_schur=schur, dense_max_cameras=1)
    assert "block-sparse S" in sparse.linear_solver and "block-sparse" not in dense.linear_solver
    assert ("X-space" in sparse.linear_solver) == (schur == "xspace")
    assert sparse.iterations == dense.iterations == ref.iterations >= 3
    assert sparse.final_cost < 0.5 * sparse.initial_cost
    for s, q in ((dense, qd), (ref, qr)):
        assert abs(sparse.final_cost - s.final_cost) <= 1e-9 * s.final_cost
        scale = np.abs(q.C).max() + np.abs(q.X).max()
        np.testing.assert_allclose(qs.R, q.R, atol=1e-8)
        np.testing.assert_allclose(qs.C, q.C, atol=1e-8 * scale)
        np.testing.assert_allclose(qs.X, q.X, atol=1e-7 * scale)
    # the held columns stayed where they were
    np.testing.assert_array_equal(qs.C[5, 1], problem.C[5, 1])


def test_block_sparse_without_held_cross_terms_is_wrong(problem, monkeypatch):
    """The held-column zeroing is needed: without it the cross blocks move a held
    coordinate's equation, and the solve differs from the reference."""
    from polarref.ba import schur
    monkeypatch.setattr(schur.SchurStructure, "zero_held_blocks", lambda self, blocks: None)
    ref, _ = _run(problem, param="parallax", kernels="numpy", anchor_schur="cross")
    broken, _ = _run(problem, param="parallax", anchor_schur="cross", dense_max_cameras=1)
    assert abs(broken.final_cost - ref.final_cost) > 1e-6 * ref.final_cost
