"""Every BA residual's analytic Jacobian vs central finite differences (incl. anchor cameras)."""

import numpy as np
import pytest

from polarref.ba import BAOptions, prepare
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.solver import make_param
from polarref.ba.synthetic import synthetic_reconstruction
from polarref.core.geometry import so3_exp
from polarref.ba.parameterization import PARAMS as FORM_NAMES


@pytest.fixture(scope="module")
def small_problem():
    init, _ = synthetic_reconstruction(5, 12, seed=3, noise_px=0.5, rot_deg=1.0)
    p = problem_from_reconstruction(init)
    prepare(p)
    return p


@pytest.mark.parametrize("param", list(FORM_NAMES))
def test_jacobians_match_central_differences(small_problem, param):
    p = small_problem.copy()
    prm = make_param(p, BAOptions(param=param))
    R, C, pts = p.R, p.C, prm.init_points()
    r, Jp, Jc = prm.evaluate(R, C, pts, jac=True)
    if len(Jc) < len(prm.slot_cols):  # parallax forms: anchors' Jacobians come factored
        Jc = [Jc[0], *Jc[1].dense(Jc[0], p.obs_pt)]
    h = 1e-6
    # point parameters
    for j in range(3):
        d = np.zeros_like(pts)
        d[:, j] = h
        num = (prm.evaluate(R, C, pts + d, False)[0] - prm.evaluate(R, C, pts - d, False)[0]) / (2 * h)
        np.testing.assert_allclose(Jp[:, :, j], num, rtol=1e-5, atol=1e-5 * np.abs(num).max())
    # camera parameters: sum over slots of the Jacobian columns belonging to camera n
    slots = prm.slot_cams
    for n in range(p.num_cameras):
        for j in range(6):
            dR, dC = R.copy(), C.copy()
            e = np.zeros(3)
            e[j % 3] = h
            Rp, Rm, Cp, Cm = R.copy(), R.copy(), C.copy(), C.copy()
            if j < 3:
                Rp[n] = so3_exp(e) @ R[n]
                Rm[n] = so3_exp(-e) @ R[n]
            else:
                Cp[n] += e
                Cm[n] -= e
            num = (prm.evaluate(Rp, Cp, pts, False)[0] - prm.evaluate(Rm, Cm, pts, False)[0]) / (2 * h)
            ana = np.zeros_like(num)
            for s, (c0, c1) in enumerate(prm.slot_cols):  # a slot covers columns c0:c1
                if c0 <= j < c1:
                    ana += np.where((slots[s] == n)[:, None], Jc[s][:, :, j - c0], 0.0)
            np.testing.assert_allclose(ana, num, rtol=1e-5, atol=1e-5 * max(np.abs(num).max(), 1.0))
    if param != "euclidean":
        # anchors really are coupled: some observation has a main/associate slot != observer
        assert (slots[1] != slots[0]).any() and (slots[2] != slots[0]).any()
