"""Frame invariance of the controlled verdicts (issue 30).

A verdict about parameterizations must not depend on how the world frame is placed, oriented or
scaled. :func:`polarref.compare.claims.experiments.invariance` reruns the experiments under seeded random
similarities of the world and a change of units (metres -> millimetres): every conditioning seed
(C6/C7), one timing seed (C3/C4) and one robustness cell (C5/C8) per draw. Here each draw's
verdicts are computed by the same rule functions as the scorecard's, on the experiment with that
draw's reruns in place of the original runs of the same seed/cell.

Rule: a claim keeps its verdict when the verdict is the same under every draw; otherwise its
verdict is :data:`FRAME_DEPENDENT`, with the share of draws that agree. C1/C2 evaluate identities
of angles in the camera frame on random attitudes (no world frame enters); the scene's single
runs (C3-C5) are of fixed images; neither is rerun.
"""

from __future__ import annotations

import dataclasses

from polarref.compare.claims import controlled as cx
from polarref.compare.claims import robustness as cr
from polarref.compare.claims.experiment_records import Experiments, InvarianceDraw, Robustness, Timing
from polarref.compare.schema import ClaimInvariance, ClaimResult, DrawVerdict

FRAME_DEPENDENT = "frame-dependent"
CONTROLLED = ("C3", "C4", "C5", "C6", "C7", "C8")


def decide(base: str, draws: list[str]) -> str:
    """``base`` when every draw gives it, else :data:`FRAME_DEPENDENT` (no draws: ``base``)."""
    return base if all(v == base for v in draws) else FRAME_DEPENDENT


def _with_timing(timing: Timing | None, d: InvarianceDraw) -> Timing | None:
    if timing is None or timing.error or d.timing_seed is None:
        return timing
    params = {}
    for p, form in timing.params.items():
        rows = [d.timing[p] if r.seed == d.timing_seed and p in d.timing else r for r in form.per_seed]
        params[p] = dataclasses.replace(form, per_seed=rows)
    return dataclasses.replace(timing, params=params)


def _with_robust(rob: Robustness | None, d: InvarianceDraw) -> Robustness | None:
    if rob is None or rob.error or d.robust_seed is None:
        return rob
    half = dict(getattr(rob, d.robust_half))
    cell = {}
    for p, runs in half[d.robust_level].items():
        new = [r for r in runs.runs if r.seed != d.robust_seed]
        new += d.robust[p].runs if p in d.robust else []
        cell[p] = dataclasses.replace(runs, runs=sorted(new, key=lambda r: r.seed),
                                      errors=runs.errors + (d.robust[p].errors if p in d.robust else []))
    half[d.robust_level] = cell
    return dataclasses.replace(rob, **{d.robust_half: half})


def controlled_verdicts(exp: Experiments) -> list[tuple[str, str]]:
    """(claim id, verdict) of the controlled experiments alone, by the scorecard's rules."""
    c6, c7 = cx.conditioning_claims(exp.conditioning, "not run")
    return [("C3", cx.equal_accuracy(exp.timing)[0]), ("C4", cx.speedup(exp.timing)[0]),
            ("C5", cr.more_tie_points(exp.robustness)[0]), ("C6", c6.verdict), ("C7", c7.verdict),
            ("C8", cr.robustness_claim(exp.robustness, "not run").verdict)]


def draw_verdicts(exp: Experiments, d: InvarianceDraw) -> list[tuple[str, str]]:
    """The controlled verdicts with draw ``d``'s reruns in place of the original runs."""
    if d.error:
        return [(cid, "not tested") for cid in CONTROLLED]
    moved = dataclasses.replace(exp, conditioning=d.conditioning, timing=_with_timing(exp.timing, d),
                                robustness=_with_robust(exp.robustness, d))
    return controlled_verdicts(moved)


def apply(claims: list[ClaimResult], exp: Experiments | None) -> list[ClaimResult]:
    """Attach each controlled claim's verdicts under the draws; a verdict that does not hold
    under every draw becomes :data:`FRAME_DEPENDENT` (the figures stay those of the original frame)."""
    inv = exp.invariance if exp is not None else None
    if inv is None or inv.error or not inv.draws:
        return claims
    base = dict(controlled_verdicts(exp))
    per_draw = [(d, dict(draw_verdicts(exp, d))) for d in inv.draws]
    out = []
    for c in claims:
        # only a verdict that the controlled experiment decided (not a scene-only or untested one)
        if base.get(c.claim_id, "not tested") == "not tested" or c.verdict != base[c.claim_id]:
            out.append(c)
            continue
        b = base[c.claim_id]
        vs = [v[c.claim_id] for _, v in per_draw]
        share = sum(v == b for v in vs) / len(vs)
        draws = [DrawVerdict(d.frame.index, d.frame.kind, d.frame.scale, d.frame.rotation_deg,
                             d.frame.translation, v[c.claim_id]) for d, v in per_draw]
        verdict = decide(b, vs)
        note = (f" Frame invariance: {len(vs)} draws ({sum(d.frame.kind == 'units' for d, _ in per_draw)} "
                f"change of units, the rest random rotation, translation and scale) gave the controlled verdict "
                f"'{b}' in {share:.0%} of them")
        if verdict == FRAME_DEPENDENT:
            other = sorted({v for v in vs if v != b})
            note += f" (otherwise: {', '.join(other)}), so the verdict is '{FRAME_DEPENDENT}'."
        else:
            note += ", so it holds in every frame tried."
        out.append(dataclasses.replace(c, verdict=verdict, rationale=c.rationale + note,
                                       invariance=ClaimInvariance(b, share, draws)))
    return out
