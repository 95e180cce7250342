"""The claim experiments' jobs, each run in its own process by :func:`polarref.core.isolated.run_isolated`
(the scorecard, :mod:`polarref.compare.claims.scorecard`, runs them): the controlled BA experiments and the
numeric evidence of the derivations. Kept apart from the methods' job set (:mod:`polarref.compare.run.jobs`)
so that running a comparison and judging the claims do not import each other.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from polarref.compare.claims.experiment_records import DerivationEvidence, Experiments
from polarref.core import records


def claim_experiments(seed: int, budget_s: float, out_json: str) -> Experiments:
    """Controlled BA experiments for the scorecard (conditioning, correlation, robustness)."""
    from polarref.compare.claims import experiments

    return experiments.run_all(seed=seed, budget_s=budget_s, out_json=Path(out_json))


def derivation_evidence(n: int, out_json: str) -> DerivationEvidence:
    """Numeric evidence on the printed view-angle equation and claim 7, from ``derivations.paper``.

    Runs in its own process: the derivations package imports SymPy/mpmath, which runtime code
    must not import.
    """
    from derivations import paper  # SymPy/mpmath: only in this job's own process

    cases = [dataclasses.asdict(c) for c in paper.all_case_evidence(n=n)]
    result = records.coerce(DerivationEvidence, {"cases": cases, "samples_per_case": n, "seed": paper.SEED})
    records.save(result, out_json)
    return result
