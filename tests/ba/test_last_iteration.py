"""The solver's last LM iteration evaluates residuals only (its Jacobians would never be read):
the flags of every evaluation, and the same solution, bitwise, as when it evaluated Jacobians
there too (the compiled residual-only passes equal the Jacobian passes' residuals)."""

import numpy as np
import pytest

from polarref.ba import BAOptions, kernels, prepare, solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.parameterization import PARAMS
from polarref.ba.solver import make_param
from polarref.ba.synthetic import synthetic_reconstruction

pytestmark = pytest.mark.skipif(not kernels.available(), reason="numba kernels unavailable")


@pytest.fixture(scope="module")
def problem():
    init, _ = synthetic_reconstruction(16, 200, seed=11, noise_px=0.5, rot_deg=0.3,
                                       point_sigma=0.05, center_sigma=0.05, track_length=5)
    p = problem_from_reconstruction(init)
    prepare(p)
    return p


def _solve(problem, form, loss, force_jac):
    """A solve capped at 3 iterations (no tolerance ends it first); the jac flag of every
    evaluation; with ``force_jac`` every evaluation takes Jacobians (the solver before)."""
    p = problem.copy()
    opts = BAOptions(param=form, loss=loss, max_iterations=3, function_tolerance=0.0,
                     gradient_tolerance=0.0, parameter_tolerance=0.0)
    param = make_param(p, opts)
    flags, evaluate = [], param.evaluate

    def recorded(R, C, pts, jac=True, factored=False):
        flags.append(jac)
        return evaluate(R, C, pts, jac=jac or force_jac, factored=factored)

    param.evaluate = recorded
    summary = solve(p, opts, prepared=True, param=param)
    return summary, p, flags


@pytest.mark.parametrize("form", PARAMS)
@pytest.mark.parametrize("loss", ["trivial", "cauchy"])
def test_the_last_iteration_skips_its_jacobians_and_changes_nothing(problem, form, loss):
    s, p, flags = _solve(problem, form, loss, force_jac=False)
    assert s.termination == "max_iterations" and s.accepted_iterations >= 1
    # one evaluation per stage start and per iteration; only each stage's last goes without
    stages = 2 if s.first_stage_termination else 1
    assert len(flags) == s.iterations + stages
    assert flags[-1] is False and flags.count(False) == stages
    ref, q, ref_flags = _solve(problem, form, loss, force_jac=True)
    assert ref_flags == flags and ref.iterations == s.iterations
    assert s.final_cost == ref.final_cost and s.final_pixel_cost == ref.final_pixel_cost
    for name in ("R", "C", "X"):
        assert np.array_equal(getattr(p, name), getattr(q, name)), name
    assert s.final_cost < s.initial_cost
