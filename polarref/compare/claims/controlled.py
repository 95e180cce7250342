"""Scorecard claims decided by the controlled BA experiments (:mod:`polarref.compare.claims.experiments`).

Verdict rules (two-sided; every threshold is a named constant):

* C3 controlled "equal accuracy" (paper form ``polar`` vs ``euclidean``, paired by seed): two
  one-sided tests (TOST) on the paired differences d = polar - euclidean of the final pixel RMS and
  of the relative-rotation error. Margins are fixed here, before any run:
  max(``RMS_MARGIN_PX``, ``RMS_MARGIN_REL`` x Euclidean mean) and max(``ROT_MARGIN_DEG``,
  ``ROT_MARGIN_REL`` x Euclidean mean). The (1 - 2 ``ALPHA``) t-interval of mean(d) decides:
  inside (-margin, margin): equal; entirely above +margin: worse; entirely below -margin:
  better; anything else: unclear. Supported when both are equal; not supported when either is
  worse or better; else inconclusive.
* C5 controlled "more tie points": on the outlier runs of C8 (paired by seed and outlier level), the
  relative differences (polar - euclidean) / euclidean of the points and of the observations that
  pass COLMAP's 4 px reprojection filter after BA; same TOST with margin min(``TIE_MARGIN_REL``,
  the paper's effect), never wider than the effect to detect. Supported when both intervals lie
  above +margin; not supported when either is equal or lower; else inconclusive; underpowered
  when the pilot's minimum detectable effect exceeds the paper's and no interval excludes it.
  The start point's counts are reported beside.
* C4 controlled "1.4x faster": per seed, ratio = median Euclidean BA time / median polar BA time
  over ``TIMING_REPEATS`` interleaved runs; the geometric mean over seeds with its 95 % t-interval;
  supported when the interval lies at or above ``SPEEDUP_CLAIM`` (1 - ``TIMING_SLACK``), not
  supported when it lies below, inconclusive otherwise. The slack a single timed run needs (two SDs
  of a single-run log ratio, from the measured run-to-run spread of the repeats) is reported and
  flagged when it exceeds ``TIMING_SLACK``; the interval, which carries that noise, decides.
* C6/C7: per seed, ratio = angular-form figure / Euclidean figure. Supported when the ratio is
  below 1 - ``MARGIN`` on every seed; not supported when it is >= 1 - ``MARGIN`` on every seed;
  inconclusive when seeds disagree. C6 uses the best angular form (lowest mean ratio; this
  choice favours the claim), C7 the parallax form, with both forms' point parameters in the same
  scene-anchored per-point frame and a distance gauge (a frame-invariant figure; issue 30).
* Every verdict from these experiments is also computed under the invariance draws (random
  similarities of the world and a change of units, :mod:`polarref.compare.claims.invariance`):
  one that does not hold under every draw becomes "frame-dependent".
* C8: every level (outlier fraction; baseline/depth) also scores the start point with the same
  success rule; a level whose start succeeds in more than ``START_MAX_SUCCESS`` of the runs
  cannot tell solvers apart and is left out of the verdict. At each remaining level a form is
  better than Euclidean when the 95 % interval of the difference of the success rates (Newcombe,
  from Wilson intervals) lies above 0 or, without such a difference, when the seeded 95 % bootstrap
  interval of the geometric-mean paired rotation-error ratio lies below 1 (worse: the mirror
  image); else equal. Levels are pre-registered from the pilot where the Euclidean success rate
  lay in [0.2, 0.8]. A form is more
  robust when it is better at >= 1 level and worse at none. Each half is supported when some
  angular form is more robust; inconclusive when no form differs and the Euclidean baseline
  succeeds always or never at every level (the experiment could not separate them); else not
  supported. C8 is supported when both halves are, not supported when both are not, else
  inconclusive.
"""

from __future__ import annotations

import numpy as np

from polarref.compare.claims.experiment_records import Conditioning, Experiments, Robustness, Timing
from polarref.compare.schema import ClaimResult, Figure

# Equivalence and difference margins, declared before any run, live in thresholds.py:
from polarref.compare.claims.preregistration import mde, seeds_needed
from polarref.compare.claims.thresholds import (ALPHA, MARGIN, MDE_ALPHA, MDE_POWER,  # noqa: F401
                                         PAPER_SPEEDUP, PILOT_SD_LOG_SPEEDUP, PILOT_SD_ROT_DEG, PILOT_SD_RMS_PX,
                                         RMS_MARGIN_PX, RMS_MARGIN_REL, ROT_MARGIN_DEG, ROT_MARGIN_REL,
                                         SPEEDUP_CLAIM, START_MAX_SUCCESS, TIE_MARGIN_REL,
                                         TIMING_SLACK)

UNDERPOWERED = "underpowered"
POWER_TEXT = f"{MDE_POWER:.0%} power, two-sided alpha {MDE_ALPHA:g}, standard deviation from the pilot seeds"


def powered(verdict: str, detectable: bool, decided: bool = False) -> str:
    """A verdict that did not find the claimed effect is "underpowered" when the experiment could
    not have detected an effect of the paper's size (issue 30), never "not supported" then;
    unless an interval already excludes the paper's effect (``decided``)."""
    return verdict if detectable or decided or verdict == "supported" else UNDERPOWERED

PAPER_FORM = "polar"


def fig(key: str, label: str, value, unit: str = "") -> Figure:
    v = None if value is None else float(value)
    return Figure(key, label, v if v is None or np.isfinite(v) else None, unit)


def not_tested(cid: str, claim: str, source: str, test: str, reason: str) -> ClaimResult:
    return ClaimResult(cid, claim, source, test, [], "0", "not tested", f"Not tested: {reason}")


# ---- C3/C4 controlled part ------------------------------------------------------------------

def paired_series(timing: Timing, key: str, cand: str = PAPER_FORM, base: str = "euclidean"):
    """(candidate, baseline) arrays over the seeds both forms completed."""
    ps = timing.params
    c = {r.seed: getattr(r, key) for r in ps[cand].per_seed} if cand in ps else {}
    b = {r.seed: getattr(r, key) for r in ps[base].per_seed} if base in ps else {}
    seeds = sorted(s for s in set(c) & set(b) if c[s] is not None and b[s] is not None)
    return np.array([c[s] for s in seeds], float), np.array([b[s] for s in seeds], float)


def tost(d, margin: float, alpha: float = ALPHA) -> tuple[float, float, float, str]:
    """Mean, interval (lo, hi) at 1 - 2 ``alpha`` and outcome of the paired differences ``d``.

    Outcome: "equal" (interval inside (-margin, margin)), "higher"/"lower" (interval beyond
    +margin / -margin), "unclear" otherwise or with fewer than 2 pairs.
    """
    from scipy.stats import t as student_t

    d = np.asarray(d, float)
    if len(d) < 2:
        m = float(d.mean()) if len(d) else float("nan")
        return m, float("nan"), float("nan"), "unclear"
    m = float(d.mean())
    half = float(student_t.ppf(1 - alpha, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
    lo, hi = m - half, m + half
    outcome = ("equal" if -margin < lo and hi < margin else "higher" if lo > margin else
               "lower" if hi < -margin else "unclear")
    return m, lo, hi, outcome


def equal_accuracy(timing: Timing | None) -> tuple[str, list[Figure], str, int]:
    """Controlled C3 verdict (TOST), figures, text (with placeholders) and the number of seeds."""
    if timing is None or timing.error:
        return "not tested", [], "controlled experiment did not run", 0
    figs, outcomes, parts, detectable = [], [], [], True
    for key, unit, floor, rel, name, sd in (
            ("final_rms_px", "px", RMS_MARGIN_PX, RMS_MARGIN_REL, "final RMS", PILOT_SD_RMS_PX),
            ("rotation_error_deg", "deg", ROT_MARGIN_DEG, ROT_MARGIN_REL, "relative-rotation error", PILOT_SD_ROT_DEG)):
        c, b = paired_series(timing, key)
        n = len(c)
        if n < 2:
            return "inconclusive", figs, f"fewer than 2 seeds completed by both forms ({n})", n
        margin = max(floor, rel * float(np.mean(b)))
        d, lo, hi, o = tost(c - b, margin)
        outcome = {"higher": "worse", "lower": "better"}.get(o, o)
        k = key.split("_")[0]
        figs += [fig(f"c_{k}_polar", f"controlled: polar median {name}", np.median(c), unit),
                 fig(f"c_{k}_eu", f"controlled: euclidean median {name}", np.median(b), unit),
                 fig(f"c_{k}_d", f"controlled: mean paired difference polar - euclidean, {name}", d, unit),
                 fig(f"c_{k}_ci_lo", f"controlled: {1 - 2 * ALPHA:.0%} CI of that difference, lower, {name}", lo, unit),
                 fig(f"c_{k}_ci_hi", f"controlled: {1 - 2 * ALPHA:.0%} CI of that difference, upper, {name}", hi, unit),
                 fig(f"c_{k}_margin", f"controlled: equivalence margin (pre-registered), {name}", margin, unit),
                 fig(f"c_{k}_mde", f"controlled: minimum detectable difference ({POWER_TEXT}), {name}",
                     mde(sd, n, MDE_ALPHA, MDE_POWER), unit),
                 fig(f"c_{k}_n_needed", f"controlled: seeds needed for a minimum detectable difference at the margin, "
                     f"{name}", seeds_needed(sd, margin, MDE_ALPHA, MDE_POWER), "count")]
        detectable &= mde(sd, n, MDE_ALPHA, MDE_POWER) <= margin
        outcomes.append(outcome)
        worse = (f"; polar worse by {{c_{k}_d}} [{{c_{k}_ci_lo}}, {{c_{k}_ci_hi}}]" if lo > 0 else
                 f"; polar better by {{c_{k}_d}} [{{c_{k}_ci_lo}}, {{c_{k}_ci_hi}}]" if hi < 0 else "")
        parts.append(f"{name} {{c_{k}_polar}} vs {{c_{k}_eu}} (paired difference {{c_{k}_d}}, {1 - 2 * ALPHA:.0%} CI "
                     f"{{c_{k}_ci_lo}} to {{c_{k}_ci_hi}}, margin +-{{c_{k}_margin}} = max({floor:g} {unit}, "
                     f"{rel:.0%} of the Euclidean mean), minimum detectable difference {{c_{k}_mde}} ({{c_{k}_n_needed}} seeds "
                     f"needed to detect the margin, {n} run): "
                     + ("equivalent within the margin" if outcome == "equal" else outcome) + worse + ")")
    verdict = ("supported" if all(o == "equal" for o in outcomes) else
               "not supported" if any(o in ("worse", "better") for o in outcomes) else "inconclusive")
    decided = any(o in ("worse", "better") for o in outcomes)    # an interval beyond the margin
    return powered(verdict, detectable, decided), figs, (
        "Controlled BA, polar vs euclidean paired by seed, two one-sided tests: " + "; ".join(parts)
        + ". Equal = the interval lies inside the margin; worse/better = it lies beyond it; an interval that "
        "excludes 0 is reported as a difference even inside the margin. Underpowered when the minimum "
        "detectable difference exceeds the margin"), n


def timing_slack(timing: Timing) -> tuple[float, float | None]:
    """(slack, spread): ``spread`` = pooled SD of log wall time over each form's repeats on one seed
    (the run-to-run noise of one timed run); slack = 1 - exp(-2 sqrt(2) spread), two SDs of the log
    ratio of two single runs. Without repeats: the pre-registered ``TIMING_SLACK`` and None."""
    dev, dof = 0.0, 0
    for form in timing.params.values():
        by_seed: dict[int, list[float]] = {}
        for run in form.runs:
            if run.wall_s and run.wall_s > 0:
                by_seed.setdefault(run.seed, []).append(np.log(run.wall_s))
        for walls in by_seed.values():
            if len(walls) >= 2:
                dev += float(np.sum((np.array(walls) - np.mean(walls)) ** 2))
                dof += len(walls) - 1
    if not dof:
        return TIMING_SLACK, None
    spread = float(np.sqrt(dev / dof))
    return float(1 - np.exp(-2 * np.sqrt(2) * spread)), spread


def geometric_interval(r: np.ndarray) -> tuple[float, float, float]:
    """Geometric mean of the ratios ``r`` and its two-sided (1 - ``MDE_ALPHA``) t-interval."""
    from scipy.stats import t as student_t

    x = np.log(r)
    g = float(np.exp(x.mean()))
    if len(x) < 2:
        return g, float("nan"), float("nan")
    half = float(student_t.ppf(1 - MDE_ALPHA / 2, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)))
    return g, float(np.exp(x.mean() - half)), float(np.exp(x.mean() + half))


def speedup(timing: Timing | None) -> tuple[str, list[Figure], str, int]:
    """Controlled C4 verdict from BA-only wall times (median of repeats, per seed)."""
    if timing is None or timing.error:
        return "not tested", [], "controlled experiment did not run", 0
    c, b = paired_series(timing, "wall_s")
    ci, bi = paired_series(timing, "iterations")
    if not len(c):
        return "inconclusive", [], "no seed completed by both forms", 0
    r = b / c
    figs = [fig("c_ratio", "controlled BA-only speed-up euclidean/polar, median over seeds", np.median(r), "x"),
            fig("c_ratio_min", "controlled speed-up, lowest seed", r.min(), "x"),
            fig("c_ratio_max", "controlled speed-up, highest seed", r.max(), "x"),
            fig("c_it_polar", "controlled: polar median iterations", np.median(ci), "count"),
            fig("c_it_eu", "controlled: euclidean median iterations", np.median(bi), "count")]
    for p, v in timing.params.items():
        w = [x.wall_s for x in v.per_seed if x.wall_s is not None]
        if w:
            figs.append(fig(f"ba_{p}", f"controlled BA-only median wall time, {p}", np.median(w), "s"))
    slack, spread = timing_slack(timing)
    g, lo, hi = geometric_interval(r)
    # The interval over seeds already carries the run-to-run noise; the measured single-run slack is
    # reported (and flagged when it exceeds the pre-registered one), never used to lower the bar:
    # under heavy load it reached 69 %, which would have called a 0.66x slow-down "1.4x faster".
    bar = SPEEDUP_CLAIM * (1 - TIMING_SLACK)
    figs += [fig("c_gm", "controlled speed-up, geometric mean over seeds", g, "x"),
             fig("c_gm_lo", f"controlled speed-up, {1 - MDE_ALPHA:.0%} CI lower", lo, "x"),
             fig("c_gm_hi", f"controlled speed-up, {1 - MDE_ALPHA:.0%} CI upper", hi, "x"),
             fig("c_spread", "run-to-run spread of one timed run (SD of log wall time over the interleaved repeats, "
                 "pooled)", spread),
             fig("c_slack", "single-run slack: 2 SD of a single-run log ratio (measured; the pre-registered value "
                 "without repeats)", 100 * slack, "%"),
             fig("c_slack_prereg", "pre-registered single-run slack", 100 * TIMING_SLACK, "%")]
    verdict = _against_bar(lo, hi, bar)
    real_verdicts, real_parts = real_speedups(timing, bar, figs)
    families = [verdict] + real_verdicts
    verdict = ("supported" if all(v == "supported" for v in families) else
               "not supported" if all(v == "not supported" for v in families) else "inconclusive")
    m_mde = float(np.exp(mde(PILOT_SD_LOG_SPEEDUP, len(r), MDE_ALPHA, MDE_POWER)))
    figs += [fig("c_mde", f"controlled: minimum detectable speed-up ({POWER_TEXT}, on log ratios)", m_mde, "x"),
             fig("c_paper", "the paper's speed-up (Table 1: 77 -> 56 min)", PAPER_SPEEDUP, "x"),
             fig("c_n_needed", "controlled: seeds needed for a minimum detectable speed-up at the paper's",
                 seeds_needed(PILOT_SD_LOG_SPEEDUP, float(np.log(PAPER_SPEEDUP)), MDE_ALPHA, MDE_POWER), "count")]
    verdict = powered(verdict, m_mde <= PAPER_SPEEDUP)
    text = (f"Minimum detectable speed-up {{c_mde}} vs the paper's {{c_paper}} ({{c_n_needed}} seeds needed to "
            f"detect it, {len(r)} run). "
            "Controlled BA-only speed-up euclidean/polar: geometric mean {c_gm} "
            f"({1 - MDE_ALPHA:.0%} CI {{c_gm_lo}} - {{c_gm_hi}}); supported when the interval lies at or above "
            f"{SPEEDUP_CLAIM} x (1 - {{c_slack_prereg}}), not supported when it lies below. The measured run-to-run "
            "spread {c_spread} of the interleaved repeats makes the slack a single timed run needs {c_slack} "
            + ("(above the pre-registered one: single-run C4 figures here are within the noise)"
               if slack > TIMING_SLACK else "(within the pre-registered one)") + "; median {c_ratio} "
            "(range {c_ratio_min} - {c_ratio_max}); "
            "median iterations {c_it_polar} (polar) vs {c_it_eu} (euclidean); median BA wall time "
            + ", ".join("{ba_" + p + "} " + p for p in timing.params if any(f.key == f"ba_{p}" for f in figs))
            + ". Real problems (each a family of its own; C4 is supported when every family's interval lies at or "
            "above the bar, not supported when every one lies below it, else inconclusive): "
            + ("; ".join(real_parts) or "none pre-registered"))
    return verdict, figs, text, len(r)


def _against_bar(lo: float, hi: float, bar: float) -> str:
    return ("supported" if np.isfinite(lo) and lo >= bar else
            "not supported" if np.isfinite(hi) and hi < bar else "inconclusive")


def real_speedups(timing: Timing, bar: float, figs: list[Figure]) -> tuple[list[str], list[str]]:
    """C4 on each real problem that ran: the verdict of the geometric mean of the interleaved
    repeats' ratios euclidean/polar (95 % t-interval) against ``bar``, and its text (with
    placeholders; the figures are appended to ``figs``). Problems that did not run: text only."""
    verdicts, parts = [], []
    for i, rp in enumerate(timing.real):
        eu, po = rp.forms.get("euclidean"), rp.forms.get(PAPER_FORM)
        if rp.skipped or eu is None or po is None or not eu.walls or not po.walls:
            parts.append(f"{rp.name}: not run ({rp.skipped or 'a form did not run'})")
            continue
        n = min(len(eu.walls), len(po.walls))
        g, lo, hi = geometric_interval(np.array(eu.walls[:n]) / np.array(po.walls[:n]))
        k = f"real{i}"
        figs += [fig(f"{k}_gm", f"{rp.name}: speed-up euclidean/polar, geometric mean over {n} interleaved repeats", g, "x"),
                 fig(f"{k}_lo", f"{rp.name}: that speed-up, {1 - MDE_ALPHA:.0%} CI lower", lo, "x"),
                 fig(f"{k}_hi", f"{rp.name}: that speed-up, {1 - MDE_ALPHA:.0%} CI upper", hi, "x"),
                 fig(f"{k}_t_eu", f"{rp.name}: euclidean median BA wall time", np.median(eu.walls), "s"),
                 fig(f"{k}_t_polar", f"{rp.name}: polar median BA wall time", np.median(po.walls), "s"),
                 fig(f"{k}_it_eu", f"{rp.name}: euclidean LM iterations", eu.iterations, "count"),
                 fig(f"{k}_it_polar", f"{rp.name}: polar LM iterations", po.iterations, "count"),
                 fig(f"{k}_rms_eu", f"{rp.name}: euclidean final pixel RMS", eu.final_rms_px, "px"),
                 fig(f"{k}_rms_polar", f"{rp.name}: polar final pixel RMS", po.final_rms_px, "px")]
        v = _against_bar(lo, hi, bar)
        verdicts.append(v)
        parts.append(f"{rp.name} ({rp.description}): {{{k}_gm}} ({{{k}_lo}} - {{{k}_hi}}; {{{k}_t_eu}} vs "
                     f"{{{k}_t_polar}}), euclidean {{{k}_it_eu}} iterations to {{{k}_rms_eu}} RMS ({eu.termination}), "
                     f"polar {{{k}_it_polar}} to {{{k}_rms_polar}} ({po.termination}): {v}")
    return verdicts, parts


# ---- C6/C7 ----------------------------------------------------------------------------------

def _per_seed(cond: Conditioning, p: str, key: str, variant: str = "per_seed") -> np.ndarray:
    """``key`` of form ``p`` per seed (an undefined figure, e.g. an infinite condition number, is inf)."""
    rows = getattr(cond.params[p], variant) if p in cond.params else []
    return np.array([np.inf if getattr(r, key) is None else getattr(r, key) for r in rows], float)


def _ratio_verdict(ratios: np.ndarray) -> str:
    if not len(ratios):
        return "inconclusive"
    if (ratios < 1 - MARGIN).all():
        return "supported"
    if (ratios >= 1 - MARGIN).all():
        return "not supported"
    return "inconclusive"


def _mean_range(key: str, label: str, vals: np.ndarray, unit: str = "") -> list[Figure]:
    return [fig(f"{key}", f"{label}: mean over seeds", vals.mean() if len(vals) else None, unit),
            fig(f"{key}_lo", f"{label}: lowest seed", vals.min() if len(vals) else None, unit),
            fig(f"{key}_hi", f"{label}: highest seed", vals.max() if len(vals) else None, unit)]


C6 = ("C6", "Angular coordinates make BA numerically better conditioned (Discussion 4.1 (2), (4))",
      "Discussion 4.1 (2), (4)", "Condition number of the Gauss-Newton matrix J^T J and of the reduced camera "
      "system (Schur complement) at the true solution of seeded synthetic problems, raw, Jacobi-scaled "
      "(unit-free) and block-Jacobi-scaled (unit- and frame-free; decides), per parameterization. Gauge: one "
      "camera's pose (6 DoF) and, for the scale, one centre coordinate of a second camera (the solver's) or "
      "its distance to the first (frame-free, for the block-scaled number).")
C7 = ("C7", "Parallax-angle landmarks reduce the correlation of the structure variables (Sec. 1.2.2)",
      "Section 1.2.2 (after Zhao et al. 2015)", "Mean |correlation coefficient| between the three parameters "
      "of each point, from the point blocks of (J^T J)^-1 (marginal covariance) at the true solution of seeded "
      "problems; XYZ vs (azimuth, elevation, parallax angle), both expressed in one scene-anchored per-point frame.")
def _c6(cond: Conditioning, ratios: dict[str, np.ndarray], errs: dict[str, str], size: str) -> ClaimResult:
    # a lean record (the invariance draws) has no raw numbers: inf / inf, reported as undefined
    with np.errstate(invalid="ignore"):
        return _c6_figures(cond, ratios, errs, size)


def _c6_figures(cond: Conditioning, ratios: dict[str, np.ndarray], errs: dict[str, str], size: str) -> ClaimResult:
    # Ties (parallax and angular landmarks share J^T J up to rounding) go to the first form.
    low = min(r.mean() for r in ratios.values())
    best = next(p for p in ratios if ratios[p].mean() <= low * (1 + 1e-6))
    scale = cond.unit_rescale
    figs = []
    for p in ["euclidean"] + list(ratios):
        figs += _mean_range(f"jtj_{p}", f"{p}: cond(J^T J), Jacobi-scaled", _per_seed(cond, p, "cond_JtJ_scaled"))
        figs += _mean_range(f"schur_{p}", f"{p}: cond(reduced camera system), Jacobi-scaled",
                            _per_seed(cond, p, "cond_schur_scaled"))
        figs += _mean_range(f"jtj_raw_{p}", f"{p}: cond(J^T J), raw (scene units)", _per_seed(cond, p, "cond_JtJ"))
        figs += _mean_range(f"schur_raw_{p}", f"{p}: cond(reduced camera system), raw (scene units)",
                            _per_seed(cond, p, "cond_schur"))
    for p in ["euclidean"] + list(ratios):
        figs += _mean_range(f"block_{p}", f"{p}: cond(J^T J), block-Jacobi-scaled, distance gauge",
                            _per_seed(cond, p, "cond_JtJ_block"))
    figs += _mean_range("ratio6_block", f"{best}/euclidean ratio of cond(J^T J) block-scaled (decides)", ratios[best])
    figs += _mean_range("ratio6", f"{best}/euclidean ratio of cond(J^T J) scaled",
                        _per_seed(cond, best, "cond_JtJ_scaled") / _per_seed(cond, "euclidean", "cond_JtJ_scaled"))
    raw = _per_seed(cond, best, "cond_JtJ") / _per_seed(cond, "euclidean", "cond_JtJ")
    figs += _mean_range("ratio6_raw", f"{best}/euclidean ratio of cond(J^T J) raw, scene units", raw)
    unit_text = ""
    resc = {p: _per_seed(cond, p, "cond_JtJ", "per_seed_rescaled") for p in ("euclidean", best)}
    if scale and len(resc[best]) == len(resc["euclidean"]) == len(raw):
        raw_k = resc[best] / resc["euclidean"]
        sc_k = (_per_seed(cond, best, "cond_JtJ_scaled", "per_seed_rescaled")
                / _per_seed(cond, "euclidean", "cond_JtJ_scaled", "per_seed_rescaled"))
        figs += _mean_range("ratio6_raw_rescaled", f"{best}/euclidean ratio of cond(J^T J) raw, lengths x {scale:g}",
                            raw_k)
        figs += _mean_range("ratio6_rescaled", f"{best}/euclidean ratio of cond(J^T J) scaled, lengths x {scale:g}",
                            sc_k)
        figs.append(fig("raw_eu_rescaled", f"euclidean: cond(J^T J) raw, lengths x {scale:g}, mean over seeds",
                        resc["euclidean"].mean()))
        unit_text = (f" Unit test: the same scenes with every length x {scale:g} (metres -> kilometres): the raw "
                     "ratio moves from {ratio6_raw} (range {ratio6_raw_lo} - {ratio6_raw_hi}) to {ratio6_raw_rescaled} "
                     "({ratio6_raw_rescaled_lo} - {ratio6_raw_rescaled_hi}), the raw Euclidean number from "
                     "{jtj_raw_euclidean} to {raw_eu_rescaled}; the scaled ratio stays {ratio6} -> {ratio6_rescaled}.")
    text = (f"Best angular form ({best}), Jacobi-scaled: cond(J^T J) {{jtj_{best}}} (range {{jtj_{best}_lo}} - "
            f"{{jtj_{best}_hi}}) vs Euclidean {{jtj_euclidean}} ({{jtj_euclidean_lo}} - {{jtj_euclidean_hi}}), "
            f"per-seed ratio {{ratio6_lo}} - {{ratio6_hi}}; reduced camera system {{schur_{best}}} vs "
            "{schur_euclidean} (points are eliminated, so it depends on the residuals only, not on the point "
            "parameterization: XYZ and parallax landmarks give the same matrix, polar adds a view-angle "
            f"residual). Raw (scene units): cond(J^T J) {{jtj_raw_{best}}} vs {{jtj_raw_euclidean}}, ratio "
            "{ratio6_raw}." + unit_text + " The verdict rests on the Jacobi-scaled number: a change of units "
            "rescales columns of J, which the raw number follows (so the raw comparison can be reversed by "
            "choosing kilometres over metres) but the scaled number does not, and LM solvers (Ceres, ours) "
            "apply exactly this diagonal scaling through their damping. What the paper attributes to angles "
            "beyond units must therefore show in the scaled number. The plain Jacobi scaling still follows the "
            "orientation of the world axes (XYZ columns and the solver's scale coordinate mix under a rotation), "
            "so the verdict uses its frame-invariant form: each camera's rotation, each centre and each point "
            "scaled by the inverse square root of its 3x3 diagonal block, with the scale fixed by the distance "
            f"of the two gauge cameras: cond(J^T J) {{block_{best}}} ({{block_{best}_lo}} - {{block_{best}_hi}}) vs "
            "Euclidean {block_euclidean} ({block_euclidean_lo} - {block_euclidean_hi}), per-seed ratio "
            "{ratio6_block_lo} - {ratio6_block_hi}. "
            f"Better means a block-scaled ratio below {1 - MARGIN:.2f} on every seed. Solver's gauge: {cond.gauge}. "
            "Failed forms: " + (", ".join(f"{p} ({e})" for p, e in errs.items()) or "none") + ".")
    return ClaimResult(*C6, figs, size, _ratio_verdict(ratios[best]), text)


def _c7(pa: np.ndarray, ce: np.ndarray, pa_ray: np.ndarray, ce_ray: np.ndarray, size: str) -> ClaimResult:
    figs = (_mean_range("corr_pa_ray", "parallax: mean |corr| within a point, anchored ray frame", pa_ray)
            + _mean_range("corr_eu_ray", "XYZ in the same anchored ray frame: mean |corr| within a point", ce_ray)
            + _mean_range("ratio7", "parallax/XYZ ratio of mean |corr|, anchored ray frame (decides)", pa_ray / ce_ray)
            + _mean_range("corr_pa", "parallax: mean |corr| within a point, the solver's own frame", pa)
            + _mean_range("corr_eu", "XYZ in world axes: mean |corr| within a point", ce)
            + _mean_range("ratio7_world", "parallax (solver frame)/XYZ (world axes) ratio of mean |corr|", pa / ce))
    text = ("In the same per-point frame (first axis the ray from the main anchor, second the baseline to the "
            "associate anchor; scale fixed by the distance of the two gauge cameras, so the figures do not depend "
            "on the world frame): mean |corr| {corr_pa_ray} (parallax, range {corr_pa_ray_lo} - {corr_pa_ray_hi}) vs "
            "{corr_eu_ray} (XYZ, {corr_eu_ray_lo} - {corr_eu_ray_hi}); per-seed ratio {ratio7_lo} - {ratio7_hi}. "
            "'Reduced' requires a ratio below " f"{1 - MARGIN:.2f}" " on every seed; this frame-invariant ratio decides. "
            "Reported beside it, frame-dependent: XYZ in world axes {corr_eu} ({corr_eu_lo} - {corr_eu_hi}) and "
            "parallax in the solver's own frame (second axis from the world axis least aligned with the ray, "
            "ba/parallax.direction_frames) {corr_pa} ({corr_pa_lo} - {corr_pa_hi}), ratio {ratio7_world_lo} - "
            "{ratio7_world_hi}, under the solver's gauge (scale by one centre coordinate, chosen along the world axes).")
    return ClaimResult(*C7, figs, size, _ratio_verdict(pa_ray / ce_ray), text)


def conditioning_claims(cond: Conditioning | None, reason: str) -> list[ClaimResult]:
    if cond is None or cond.error:
        why = (cond.error if cond is not None else "") or reason
        return [not_tested(*C6, why), not_tested(*C7, why)]
    n = len(cond.seeds)
    size = f"{n} seeds ({cond.problem})"
    errs = {p: v.error for p, v in cond.params.items() if v.error}
    out = []
    eu = _per_seed(cond, "euclidean", "cond_JtJ_block")
    ratios = {p: _per_seed(cond, p, "cond_JtJ_block") / eu for p in cond.params
              if p != "euclidean" and len(_per_seed(cond, p, "cond_JtJ_block")) == len(eu) > 0}
    if not ratios:
        out.append(not_tested(*C6, "the Euclidean or every angular form failed: "
                              + ("; ".join(f"{p}: {e}" for p, e in errs.items()) or "no result")))
    else:
        out.append(_c6(cond, ratios, errs, size))
    pa = _per_seed(cond, "parallax", "mean_abs_point_corr")
    ce = _per_seed(cond, "euclidean", "mean_abs_point_corr")
    pa_ray = _per_seed(cond, "parallax", "mean_abs_point_corr_ray")
    ce_ray = _per_seed(cond, "euclidean", "mean_abs_point_corr_ray")
    if not len(pa) or len(pa) != len(ce):
        out.append(not_tested(*C7, "the Euclidean or parallax form failed in the conditioning run ("
                              + (errs.get("euclidean") or errs.get("parallax") or "no result") + ")"))
    elif not (np.isfinite(pa_ray).all() and np.isfinite(ce_ray).all()):
        out.append(not_tested(*C7, "the frame-invariant (ray-frame) correlations are missing from the record"))
    else:
        out.append(_c7(pa, ce, pa_ray, ce_ray, size))
    return out
