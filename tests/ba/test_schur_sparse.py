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


def test_pair_table_equals_sorted_keys_and_holds_no_per_pair_keys(monkeypatch):
    """The camera-pair table (schur.py ``_build_blocks``) gives the blocks of the sorted-keys
    path exactly, and its peak allocation is the int32 pair index (4 bytes per entry pair),
    not the sorted path's int64 keys and inverse (>= 16 bytes per pair)."""
    import tracemalloc

    from polarref.ba import schur
    from polarref.ba.options import BAOptions as Opts
    from polarref.ba.solver import make_param

    init, _ = synthetic_reconstruction(12, 3000, seed=3, track_length=-1)
    problem = problem_from_reconstruction(init)
    prepare(problem)
    param = make_param(problem, Opts(param="polar"))
    cam_var = problem.cam_mask.any(1)

    def build():
        tracemalloc.start()
        st = schur.SchurStructure(param.slot_cams, param.slot_cols, problem.obs_pt, cam_var,
                                  problem.num_points, 1, fast=True)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return st, peak

    table, _ = build()
    base_peak = build()[1]  # the structure's other arrays (entries, U indices) are the same
    monkeypatch.setattr(schur, "_PAIR_TABLE_MAX", 0)
    keys, keys_peak = build()
    assert table.num_pairs > 100_000 and table.pair_blk.dtype == keys.pair_blk.dtype == np.int32
    for name in ("pair_blk", "u_blk", "diag_blk", "blk_ca", "blk_cb", "bsr_order", "bsr_indices",
                 "bsr_indptr"):
        np.testing.assert_array_equal(getattr(table, name), getattr(keys, name), err_msg=name)
    assert table.K == keys.K
    assert keys_peak - base_peak >= 12 * table.num_pairs

