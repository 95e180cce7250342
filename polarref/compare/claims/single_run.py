"""The scorecard's single-run rules for C4 (faster) and C5 (more tie points), written once.

Both the scene scorecard (:mod:`polarref.compare.claims.scorecard`) and the twins' paper tables
(:mod:`polarref.compare.twins.tables`) decide a single timed run with these functions, so a twin
and a small scene can never be judged by two copies of a rule. Thresholds come from
:mod:`polarref.compare.claims.thresholds`. A missing value is "not tested", never 0.
"""

from __future__ import annotations

from polarref.compare.claims.thresholds import SPEEDUP_CLAIM, TIE_MARGIN_REL, TIMING_SLACK

SUPPORTED_AT = SPEEDUP_CLAIM * (1 - TIMING_SLACK)   # speed-up at or above: supported
NOT_SUPPORTED_BELOW = 1 + TIMING_SLACK              # speed-up below: not supported


def ratio(numerator: float | None, denominator: float | None) -> float | None:
    """numerator / denominator, None when either is missing or not positive."""
    if numerator is None or denominator is None or numerator <= 0 or denominator <= 0:
        return None
    return float(numerator) / float(denominator)


def speedup_verdict(baseline_s: float | None, candidate_s: float | None) -> tuple[str, float | None]:
    """C4 on one run: (verdict, speed-up baseline / candidate of the whole method's runtime).

    Supported when the speed-up is >= ``SPEEDUP_CLAIM`` x (1 - ``TIMING_SLACK``), not supported
    when it is < 1 + ``TIMING_SLACK``, inconclusive between; "not tested" without both times.
    """
    r = ratio(baseline_s, candidate_s)
    if r is None:
        return "not tested", None
    if r >= SUPPORTED_AT:
        return "supported", r
    return ("not supported" if r < NOT_SUPPORTED_BELOW else "inconclusive"), r


def tie_margin(baseline_count: float) -> float:
    """How much more than the baseline a count must be to count as "more": max(1, rel x baseline)."""
    return max(1.0, TIE_MARGIN_REL * float(baseline_count))


def more_counts_verdict(candidate_ties: int | None, baseline_ties: int | None,
                        candidate_obs: int | None, baseline_obs: int | None) -> str:
    """C5 on one run: supported when the candidate exceeds the same-pipeline baseline by more than
    :func:`tie_margin` in BOTH tie points and reprojected pixels (observations)."""
    counts = (candidate_ties, baseline_ties, candidate_obs, baseline_obs)
    if any(c is None for c in counts):
        return "not tested"
    more = all(c - b > tie_margin(b) for c, b in ((candidate_ties, baseline_ties), (candidate_obs, baseline_obs)))
    return "supported" if more else "not supported"
