"""The BA entry point: LM with intrinsics held fixed (:mod:`polarref.ba.solver`) or, when
``options.refine`` names intrinsics groups, the self-calibrating LM around it
(:mod:`polarref.ba.intrinsics`). Kept apart so that neither of those imports the other back."""

from __future__ import annotations

from polarref.ba import solver
from polarref.ba.intrinsics import solve_calibrating
from polarref.ba.options import BAOptions, BASummary
from polarref.ba.parameterization import Parameterization
from polarref.ba.problem import BAProblem
from polarref.core.errors import PolarrefError


def solve(problem: BAProblem, options: BAOptions, *, prepared: bool = False,
          param: Parameterization | None = None) -> BASummary:
    """Run LM on ``problem`` (updated in place: R, C, X, and ``cameras`` when refining)."""
    if options.refine and problem.priors is not None:
        raise PolarrefError("bundle adjustment: pose priors / control points with intrinsics "
                            "refinement are not supported (hold the intrinsics)")
    if options.refine:  # self-calibration: intrinsics blocks join the camera system
        return solve_calibrating(problem, options, prepared=prepared)
    return solver.solve(problem, options, prepared=prepared, param=param)
