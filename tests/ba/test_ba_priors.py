"""Pose priors and control points in every BA form: Jacobians, datum, limits of the weights."""

import numpy as np
import pytest

from polarref.ba import BAOptions, prepare, solve
from polarref.ba.parameterization import PARAMS
from polarref.ba.priors import PriorTerms, fixes_datum
from polarref.core.geometry import so3_exp, umeyama
from tests._prior_scene import attitude_priors, block, centre_priors, control, with_priors


def _terms(seed=0):
    b = block(seed)
    rng = np.random.default_rng(5)
    cp = centre_priors(b, 2.0)
    L = np.linalg.cholesky(np.array([[4.0, 0.5, 0.2], [0.5, 3.0, -0.4], [0.2, -0.4, 9.0]]))
    cp = type(cp)(cp.cam, cp.centre, np.tile(np.linalg.inv(L), (len(cp.cam), 1, 1)))
    p = with_priors(b, centres=cp, attitudes=attitude_priors(b, 3.0), control=control(b, range(4)))
    R = so3_exp(rng.normal(0, 0.05, (len(b.R), 3))) @ p.R  # away from the priors' minimum
    Xg = p.priors.control.X0 + rng.normal(0, 0.5, (4, 3))
    return PriorTerms(p.priors, p.cameras, 0.7), R, p.C.copy(), Xg


def _flat(res):
    return np.concatenate([res.centre.ravel(), res.attitude.ravel(), res.gcp_prior.ravel(),
                           res.gcp_pixel.ravel()])


def test_prior_and_gcp_jacobians_match_central_differences():
    t, R, C, Xg = _terms()
    J = t.jacobians(R, C, Xg)
    pr = t.pr
    h = 1e-6
    # camera columns: (dtheta, dC) of each camera, one at a time
    worst = 0.0
    for i in (0, 3, 7):
        for k in range(6):
            d = np.zeros(6)
            d[k] = h
            def at(sign):
                R2, C2 = R.copy(), C.copy()
                R2[i] = so3_exp(sign * d[:3]) @ R[i]
                C2[i] = C[i] + sign * d[3:]
                return t.residuals(R2, C2, Xg)
            rp, rm = at(1), at(-1)
            fd_c = (rp.centre - rm.centre) / (2 * h)
            fd_a = (rp.attitude - rm.attitude) / (2 * h)
            fd_p = (rp.gcp_pixel - rm.gcp_pixel) / (2 * h)
            an_c = np.zeros_like(fd_c)
            an_a = np.zeros_like(fd_a)
            an_p = np.zeros_like(fd_p)
            sc = pr.centres.cam == i
            if k >= 3:
                an_c[sc] = J.centre_D_dC[sc][:, :, k - 3]
            else:
                an_a[pr.attitudes.cam == i] = J.attitude_D_dtheta[pr.attitudes.cam == i][:, :, k]
            so = pr.control.obs_cam == i
            an_p[so] = J.pixel_D_cam[so][:, :, k]
            for fd, an in ((fd_c, an_c), (fd_a, an_a), (fd_p, an_p)):
                worst = max(worst, float(np.abs(fd - an).max() / max(1.0, np.abs(an).max())))
    assert worst < 1e-6
    assert np.abs(J.attitude_D_dtheta).max() > 1.0  # the columns tested are not all zero
    # control point columns
    for g in range(len(Xg)):
        for k in range(3):
            dX = np.zeros_like(Xg)
            dX[g, k] = h
            rp, rm = t.residuals(R, C, Xg + dX), t.residuals(R, C, Xg - dX)
            fd_g = (rp.gcp_prior - rm.gcp_prior) / (2 * h)
            fd_p = (rp.gcp_pixel - rm.gcp_pixel) / (2 * h)
            an_g = np.zeros_like(fd_g)
            an_g[g] = J.gcp_prior_D_X[g][:, k]
            an_p = np.where((pr.control.obs_gcp == g)[:, None], J.pixel_D_X[:, :, k], 0.0)
            assert np.abs(fd_g - an_g).max() < 1e-6 * max(1.0, np.abs(an_g).max())
            assert np.abs(fd_p - an_p).max() < 1e-6 * max(1.0, np.abs(an_p).max())


def test_attitude_jacobian_far_from_the_prior():
    """J_l^-1 at a 40-degree residual rotation (the small-angle identity would be 10% off)."""
    t, R, C, Xg = _terms()
    R = so3_exp(np.tile([0.4, -0.5, 0.3], (len(R), 1))) @ R
    J = t.jacobians(R, C, Xg).attitude_D_dtheta[2]
    h = 1e-6
    fd = np.empty((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        Rp, Rm = R.copy(), R.copy()
        Rp[2], Rm[2] = so3_exp(d) @ R[2], so3_exp(-d) @ R[2]
        fd[:, k] = (t.residuals(Rp, C, Xg).attitude[2] - t.residuals(Rm, C, Xg).attitude[2]) / (2 * h)
    assert np.abs(fd - J).max() < 1e-6 * np.abs(J).max()
    assert np.abs(J - J[0, 0] * np.eye(3)).max() > 0.05 * np.abs(J).max()


def _centres_rel(a, b):
    return float(np.abs(a - b).max() / np.ptp(b, axis=0).max())


def _solve(p, form, **kw):
    prepare(p)
    s = solve(p, BAOptions(param=form, function_tolerance=1e-14, gradient_tolerance=1e-14,
                           parameter_tolerance=1e-14, max_iterations=200, **kw), prepared=True)
    return s


@pytest.mark.parametrize("form", PARAMS)
def test_huge_sigmas_reproduce_the_unconstrained_solution(form):
    b = block(0)
    free = b.problem.copy()
    _solve(free, form)
    pri = with_priors(b, centres=centre_priors(b, 1e5, noise=2.0))
    s = _solve(pri, form)
    assert "datum fixed by the priors" in s.gauge
    sim = umeyama(pri.C, free.C)
    # aligned, the two solutions agree; the unaligned ones differ (the gauge was chosen apart)
    assert _centres_rel(sim.apply(pri.C), free.C) < 1e-6
    assert _centres_rel(pri.C, free.C) > 1e-4


@pytest.mark.parametrize("form", PARAMS)
def test_tiny_sigmas_pin_the_centres_to_the_priors(form):
    b = block(0)
    cp = centre_priors(b, 1e-6, noise=0.5)
    p = with_priors(b, centres=cp)
    _solve(p, form)
    assert np.abs(p.C - cp.centre).max() < 1e-5
    assert np.abs(p.C - b.C).max() > 0.2  # the priors' noise, not the truth


@pytest.mark.parametrize("form", PARAMS)
def test_control_points_alone_fix_the_datum(form):
    """Only GCPs (exact 3D, 0.5 px marks): the block lands in the control frame to ~cm."""
    b = block(0)
    p = with_priors(b, control=control(b, range(6), sigma=0.005))
    s = _solve(p, form)
    assert "6 control points" in s.gauge
    # 50 m over ground, GSD 5.6 cm: centres within 10 GSD (rotation-centre correlation of a
    # short nadir block), tie points within 5 GSD, control points within their 5 mm priors x 2
    err = np.linalg.norm(p.C - b.C, axis=1)
    assert 1e-3 < err.max() < 0.5
    assert 1e-3 < np.abs(p.X - b.X).max() < 0.28
    assert np.abs(p.control_X - b.G).max() < 0.01


def test_datum_rule():
    b = block(0)
    assert not fixes_datum(None)
    assert not fixes_datum(with_priors(b, control=control(b, [0, 1])).priors)
    assert fixes_datum(with_priors(b, control=control(b, [0, 1, 2])).priors)
    line = control(b, [0, 1, 2])
    line = type(line)(np.array([[0.0, 0, 0], [1, 1, 0], [2, 2, 0]]), line.sqrt_info,
                      line.obs_gcp, line.obs_cam, line.uv)
    assert not fixes_datum(with_priors(b, control=line).priors)
