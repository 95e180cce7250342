"""The priors' weighted similarity (georef/datum.py) and the priors-on adjustment reaching its optimum."""

import copy

import numpy as np
import pytest
from scipy.optimize import least_squares

from polarref.ba import BAOptions, prepare, problem_from_reconstruction, solve, write_back
from polarref.ba.adapter import problem_to_reconstruction
from polarref.ba.parameterization import PARAMS
from polarref.core.geometry import so3_exp, so3_log
from polarref.georef.adjust import align_to_datum, ba_priors, georeference
from polarref.georef.datum import DatumPriors, weighted_similarity
from polarref.georef.formats import Georef, PosePrior
from tests._prior_scene import block


def _datum_priors(seed=0, n=12):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-50, 50, (n, 3)) + [4e3, -2e3, 100.0]  # far from the origin, as map grids are
    R = so3_exp(rng.normal(0, 1.0, (n, 3)))
    Q, s, t = so3_exp([0.3, -0.2, 0.5]), 1.7, np.array([10.0, -5.0, 3.0])
    dst = s * src @ Q.T + t + rng.normal(0, 2.0, (n, 3))
    W = np.array([np.linalg.inv(np.linalg.cholesky(A @ A.T + np.eye(3)))
                  for A in rng.normal(0, 2, (n, 3, 3))])
    R0 = so3_exp(rng.normal(0, 0.05, (n, 3))) @ R @ Q.T  # the cameras' attitude in the target frame
    return DatumPriors(src, dst, W, R, R0, np.full(n, np.radians(2.0)))


def test_weighted_similarity_matches_an_independent_least_squares_fit():
    """scipy's least squares, numerical Jacobian, parameters (rotation vector, t, log s) of
    x -> s R x + t, from the identity: the same minimiser as our Gauss-Newton."""
    dp = _datum_priors()

    def res(q):
        Q, s = so3_exp(q[:3]), np.exp(q[6])
        rp = np.einsum("pij,pj->pi", dp.W, s * dp.src @ Q.T + q[3:6] - dp.dst)
        ra = so3_log(dp.R @ Q.T @ dp.R0.transpose(0, 2, 1)) / dp.sigma_rad[:, None]
        return np.r_[rp.ravel(), ra.ravel()]

    c = dp.dst.mean(0) - dp.src.mean(0)
    q = least_squares(res, np.r_[0.3, -0.2, 0.5, c, 0.5], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    sim = weighted_similarity(dp)
    # to what scipy's forward differences resolve at 4 km from the origin
    assert np.abs(so3_log(sim.R @ so3_exp(q[:3]).T)).max() < 1e-7
    assert abs(np.log(sim.s) - q[6]) < 1e-7
    assert np.abs(sim.apply(dp.src) - (np.exp(q[6]) * dp.src @ so3_exp(q[:3]).T + q[3:6])).max() < 1e-5
    assert (res(q) ** 2).sum() <= (dp.residuals(sim) ** 2).sum() * (1 + 1e-10)


def test_weighted_similarity_without_attitudes_and_equal_weights_is_umeyama():
    dp = _datum_priors(1)
    dp = DatumPriors(dp.src, dp.dst, np.tile(np.eye(3) / 3.0, (len(dp.src), 1, 1)),
                     np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), np.zeros(0))
    from polarref.core.geometry import umeyama
    a, b = weighted_similarity(dp), umeyama(dp.src, dp.dst)
    assert np.abs(a.apply(dp.src) - b.apply(dp.src)).max() < 1e-8


def _free_block_and_priors():
    """A free (unconstrained) adjustment of a block whose tie points outweigh its priors by far
    (0.3 px tie noise weighted as 0.05 px: as many observations again as ~36x the points), and
    centre (2 / 2 / 4 m) and attitude (1 deg) priors drawn around the truth."""
    b = block(0, rows=3, cols=5, points=600)
    p = b.problem.copy()
    prepare(p)
    solve(p, BAOptions(param="euclidean", function_tolerance=1e-12), prepared=True)
    rng = np.random.default_rng(7)
    sig = np.array([2.0, 2.0, 4.0])
    pri = tuple(PosePrior(f"img_{i:05d}", c + rng.normal(0, sig), sig,
                          so3_exp(rng.normal(0, np.radians(1.0), 3)) @ R, 1.0)
                for i, (c, R) in enumerate(zip(b.C, b.R)))
    return problem_to_reconstruction(p), Georef(pri)


def _centres(rec):
    return np.array([rec.images[i].cam_from_world.center for i in sorted(rec.images)])


@pytest.mark.parametrize("form", PARAMS)
def test_priors_on_reaches_the_optimum_in_every_form(form):
    """Issue 33's sub-block: from a free model, the priors-only adjustment moved the centres
    by 1e-3 m in two forms and 0.78 m in the others. The optimum, by LM from the centres'
    unweighted similarity run to tolerances 1e-15: georeference (default tolerances) must land
    on it within 2e-3 m in every form (it stopped 0.1-0.3 m short when it started there; the
    polar form, whose view-angle rows reshape the block a little, stops 0.8 mm short, the
    others within 1e-5 m)."""
    rec, g = _free_block_and_priors()
    ref = copy.deepcopy(rec)
    align_to_datum(ref, g, True, True)
    pr = problem_from_reconstruction(ref)
    pr.priors = ba_priors(g, [ref.images[int(i)].name for i in pr.image_ids], 0.05, 0.5, True, False)
    prepare(pr)
    s = solve(pr, BAOptions(param=form, max_iterations=2000, function_tolerance=1e-15,
                            parameter_tolerance=1e-15, gradient_tolerance=1e-14), prepared=True)
    write_back(ref, pr)
    assert s.iterations > 20  # the reference did have to walk the valley
    georeference(rec, g, form, use_control=False, image_sigma_px=0.05)
    assert np.abs(_centres(rec) - _centres(ref)).max() < 2e-3
