"""Bundle adjustment: LM + Schur complement in Euclidean, parallax, polar and angular forms."""

from polarref.ba.adapter import adjust, problem_from_reconstruction, write_back
from polarref.ba.options import PARAMS, BAOptions, BASummary, IterationRecord
from polarref.ba.problem import BAProblem, fix_gauge, prepare
from polarref.ba.entry import solve

__all__ = ["adjust", "solve", "prepare", "fix_gauge", "BAOptions", "BASummary", "BAProblem",
           "IterationRecord", "PARAMS", "problem_from_reconstruction", "write_back"]
