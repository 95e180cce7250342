"""Issue 35: the angular form runs the chunked three-slot build (ba/chunked.py) at scale, as
parallax and polar do: bit for bit the eager path's results, with its whitened (theta, phi)
rows, theta-only rows and axis-chart rows sliced per chunk (Angular.row_arrays)."""

import numpy as np
import pytest
from test_ba_memory import _problem, _solve

from polarref.ba import BAOptions, kernels
from polarref.ba.solver import make_param

pytestmark = pytest.mark.skipif(not kernels.available(), reason="numba kernels unavailable")


@pytest.fixture(scope="module")
def base():
    p = _problem(seed=8)
    prm = make_param(p, BAOptions(param="angular", kernels="numba", max_sigma_phi=0.05))
    # every row kind is exercised: gated phi with chart rows, and whitened (theta, phi)
    assert len(prm.chart_idx) > 0 and prm.phi_ok.any()
    return p


@pytest.mark.parametrize("loss,anchor_schur", [("trivial", "xspace"), ("cauchy", "xspace"),
                                               ("trivial", "cross")])
def test_chunked_angular_is_bit_identical_to_eager(monkeypatch, base, loss, anchor_schur):
    kw = dict(param="angular", loss=loss, max_iterations=8, max_sigma_phi=0.05,
              anchor_schur=anchor_schur)
    a, sa = _solve(base, monkeypatch, lazy=False, **kw)
    b, sb = _solve(base, monkeypatch, lazy=True, **kw)
    assert sb.linear_solver == sa.linear_solver
    assert sa.iterations == sb.iterations >= 2 and sa.final_cost < 0.5 * sa.initial_cost
    assert [t.cost for t in sa.trace] == [t.cost for t in sb.trace]
    for x, y in ((a.R, b.R), (a.C, b.C), (a.X, b.X)):
        assert np.array_equal(x, y)


def test_chunked_angular_rows_equal_the_whole_evaluation(base):
    """evaluate_rows on a run of observations = those rows of the whole factored evaluation."""
    prm = make_param(base, BAOptions(param="angular", kernels="numba", max_sigma_phi=0.05))
    pts = prm.init_points() + [1e-3, -1e-3, 0.0]
    r, Jp, (J_obs, anc) = prm.evaluate(base.R, base.C, pts, True, factored=True)
    terms = prm.point_terms_for_rows(base.R, base.C, pts)
    m0, m1 = 37, len(r) - 11
    r2, Jp2, (J_obs2, anc2) = prm.evaluate_rows(base.R, base.C, terms, m0, m1)
    for x, y in ((r[m0:m1], r2), (Jp[m0:m1], Jp2), (J_obs[m0:m1], J_obs2), (anc.Ad[m0:m1], anc2.Ad)):
        assert np.array_equal(x, y)
    # residuals without Jacobians (the trial points' cost) from the same rows
    r3, _, _ = prm.evaluate(base.R, base.C, pts, False)
    np.testing.assert_allclose(r3, r, rtol=0, atol=1e-12 * np.abs(r).max())
