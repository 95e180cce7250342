"""Issue 14 memory: the chunked three-slot build (ba/chunked.py) gives the eager path's results
bit for bit and keeps no (M, ...) Jacobian array alive."""

import tracemalloc

import numpy as np
import pytest

from polarref.ba import BAOptions, chunked, kernels, prepare, solve
from polarref.ba.synthetic import ring_problem

pytestmark = pytest.mark.skipif(not kernels.available(), reason="numba kernels unavailable")


def _solve(problem, monkeypatch, lazy: bool, chunk: int = 37, **opts):
    monkeypatch.setattr(chunked, "MIN_OBS", 0 if lazy else 1 << 62)
    monkeypatch.setattr(chunked, "CHUNK_OBS", chunk)
    calls = []
    build = chunked.build
    monkeypatch.setattr(chunked, "build", lambda *a: calls.append(1) or build(*a))
    p = problem.copy()
    s = solve(p, BAOptions(kernels="numba", **opts), prepared=True)
    assert bool(calls) == lazy  # the path under test really ran
    return p, s


def _problem(cams=24, points=300, track=6.0, seed=3):
    p = ring_problem(cams, points, track, seed=seed)
    prepare(p)
    return p


@pytest.mark.parametrize("param,loss", [("polar", "trivial"), ("polar", "cauchy"),
                                        ("parallax", "trivial")])
def test_chunked_build_is_bit_identical_to_eager(monkeypatch, param, loss):
    base = _problem()
    base.pt_fixed[::17] = True  # the fixed-point mask goes through the chunked build too
    a, sa = _solve(base, monkeypatch, lazy=False, param=param, loss=loss, max_iterations=8)
    b, sb = _solve(base, monkeypatch, lazy=True, param=param, loss=loss, max_iterations=8)
    assert sa.iterations == sb.iterations >= 2
    assert sa.final_cost == sb.final_cost and sa.final_cost < 0.5 * sa.initial_cost
    assert [t.cost for t in sa.trace] == [t.cost for t in sb.trace]
    for x, y in ((a.R, b.R), (a.C, b.C), (a.X, b.X)):
        assert np.array_equal(x, y)


@pytest.mark.parametrize("param,loss", [("polar", "trivial"), ("polar", "huber"), ("parallax", "cauchy")])
def test_chunked_xspace_build_is_bit_identical_to_eager(monkeypatch, param, loss):
    """Issue 34: the three-slot forms' X-space elimination runs in the chunked build too, with
    the eager X-space path's results bit for bit (no fixed points: those take the cross terms)."""
    base = _problem(seed=4)
    a, sa = _solve(base, monkeypatch, lazy=False, param=param, loss=loss, max_iterations=8)
    b, sb = _solve(base, monkeypatch, lazy=True, param=param, loss=loss, max_iterations=8)
    assert "anchors eliminated in X-space" in sa.linear_solver
    assert sb.linear_solver == sa.linear_solver and "by cross terms" not in sb.linear_solver
    assert sa.iterations == sb.iterations >= 2 and sa.final_cost < 0.5 * sa.initial_cost
    assert [t.cost for t in sa.trace] == [t.cost for t in sb.trace]
    for x, y in ((a.R, b.R), (a.C, b.C), (a.X, b.X)):
        assert np.array_equal(x, y)
    # and the step is the cross-term path's to rounding (an independent elimination)
    c, sc = _solve(base, monkeypatch, lazy=True, param=param, loss=loss, max_iterations=8, anchor_schur="cross")
    assert "X-space" not in sc.linear_solver and sc.iterations == sb.iterations
    assert sc.final_cost == pytest.approx(sb.final_cost, rel=1e-9)
    assert np.allclose(c.X, b.X, rtol=1e-6, atol=1e-9)


def test_chunked_xspace_falls_back_to_cross_terms(monkeypatch):
    """A build whose maps do not carry the anchors (an omega held at a bound with B != 0; forced
    here) is built again by cross terms: the solve is the cross-term path's, bit for bit."""
    from polarref.ba.xspace import AnchorElimination

    base = _problem(seed=6)
    a, sa = _solve(base, monkeypatch, lazy=True, param="polar", max_iterations=6, anchor_schur="cross")
    monkeypatch.setattr(AnchorElimination, "carries_maps", lambda self, active: False)
    b, sb = _solve(base, monkeypatch, lazy=True, param="polar", max_iterations=6)
    assert sb.linear_solver == sa.linear_solver and "X-space" not in sb.linear_solver   # no build in X-space
    assert [t.cost for t in sa.trace] == [t.cost for t in sb.trace]
    assert np.array_equal(a.X, b.X) and np.array_equal(a.C, b.C)


def test_chunked_build_with_rejected_steps_and_one_point_chunks(monkeypatch):
    # a tiny trust region start forces rejections/regrowth; chunk=1: every chunk one point
    base = _problem(cams=12, points=80, seed=5)
    kw = dict(param="polar", max_iterations=6, initial_trust_radius=1e-9)
    a, sa = _solve(base, monkeypatch, lazy=False, **kw)
    b, sb = _solve(base, monkeypatch, lazy=True, chunk=1, **kw)
    assert [t.accepted for t in sa.trace] == [t.accepted for t in sb.trace]
    assert np.array_equal(a.X, b.X) and np.array_equal(a.C, b.C)


def test_point_chunks_cover_points_in_order():
    counts = np.array([3, 1, 9, 2, 2, 2, 40, 1])
    bounds = np.r_[0, np.cumsum(counts)]
    ch = chunked.point_chunks(bounds, 5)
    assert ch[0][0] == 0 and ch[-1][1] == len(counts)
    assert all(a1 == b0 for (_, a1), (b0, _) in zip(ch, ch[1:]))
    for p0, p1 in ch:  # at most 5 observations unless a single point has more
        n = bounds[p1] - bounds[p0]
        assert n <= 5 or p1 - p0 == 1
    assert ch == [(0, 2), (2, 3), (3, 5), (5, 6), (6, 7), (7, 8)]


def _peak_mb(problem, monkeypatch, lazy: bool, anchor_schur: str = "xspace") -> float:
    monkeypatch.setattr(chunked, "MIN_OBS", 0 if lazy else 1 << 62)
    monkeypatch.setattr(chunked, "CHUNK_OBS", 4096)
    p = problem.copy()
    opts = BAOptions(param="polar", kernels="numba", max_iterations=3, anchor_schur=anchor_schur)
    solve(problem.copy(), opts, prepared=True)  # compile / load kernels outside the window
    tracemalloc.start()
    try:
        solve(p, opts, prepared=True)
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def test_polar_peak_allocation_is_bounded_by_the_normal_equations(monkeypatch):
    """Chunked: the peak is the normal equations (W (E, 6, 3), the compact cross terms
    [N | t] (E, 6, 4), and S) plus O(M) index structures and trial residuals (measured ~300 B per
    observation: slot/entry indices, the per-observation intrinsics, residual temporaries),
    under 400 B per observation more. The eager path with the same normal equations (anchor
    cross terms) also holds a full Jacobian set at the trial step (264 B per observation) and
    must fail that: the bound can tell them apart. The eager X-space elimination (xspace.py)
    holds no cross terms: its peak is lower by about their (E, 6, 4) array."""
    p = _problem(cams=60, points=6000, track=10.0)
    M, Nv = p.num_observations, p.num_cameras
    E = M - int((p.obs_cam == 0).sum())  # entries: the observer pairs (camera 0 is fixed)
    mb = 1.0 / 2**20
    normal = (E * (18 + 24) + (6 * Nv) ** 2) * 8 * mb  # W, [N | t]; S
    jac_set = M * 3 * 11 * 8 * mb  # residuals, res_D_point, res_D_obs, A d (k = 3)
    lazy = _peak_mb(p, monkeypatch, lazy=True)
    eager = _peak_mb(p, monkeypatch, lazy=False, anchor_schur="cross")
    eager_x = _peak_mb(p, monkeypatch, lazy=False)
    assert normal < lazy < normal + 400 * M * mb, (lazy, normal, M)
    assert eager > lazy + 0.75 * jac_set, (eager, lazy, jac_set)
    cross = E * 24 * 8 * mb
    assert eager - 1.25 * cross < eager_x < eager - 0.75 * cross, (eager_x, eager, cross)
