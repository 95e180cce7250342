"""Scorecard claims decided by the controlled BA experiments (:mod:`polarref.compare.experiments`).

Verdict rules (two-sided; every threshold is a named constant):

* C3 controlled "equal accuracy" (paper form ``polar`` vs ``euclidean``, paired by seed): for the
  final pixel RMS and the relative-rotation error, d = mean over seeds of (polar - euclidean) and
  tol = max(floor, seed-to-seed standard deviation of the Euclidean figure), floors
  ``EQUIVALENT_PX`` / ``ROT_FLOOR_DEG``. Supported when |d| <= tol for both; not supported when
  |d| - 2 SE(d) > tol for either (clearly different, the direction is stated); else inconclusive.
* C4 controlled "1.4x faster": per seed, ratio = median Euclidean BA time / median polar BA time;
  supported when the median ratio >= ``SPEEDUP_CLAIM`` (1 - ``TIMING_SLACK``), not supported when
  it is < 1 + ``TIMING_SLACK``, inconclusive between.
* C6/C7: per seed, ratio = angular-form figure / Euclidean figure. Supported when the ratio is
  below 1 - ``MARGIN`` on every seed; not supported when it is >= 1 - ``MARGIN`` on every seed;
  inconclusive when seeds disagree. C6 uses the best angular form (lowest mean ratio; this
  choice favours the claim), C7 the parallax form.
* C8: per experiment (each outlier fraction; each parallax level) a form is better than Euclidean when its
  success rate is higher by >= ``SUCCESS_MARGIN``, worse when lower by >= it, else equal. A form
  is more robust (to outliers, to low parallax) when it is better at >= 1 level and worse at none. Each half is
  supported when some angular form is more robust, not supported otherwise; C8 is supported when
  both halves are, not supported when neither is, inconclusive when they disagree.
"""

from __future__ import annotations

import numpy as np

from polarref.compare.report import EQUIVALENT_PX  # the report's "Equivalent" px threshold, reused as the floor
from polarref.compare.schema import ClaimResult, Figure

ROT_FLOOR_DEG = 0.005
SPEEDUP_CLAIM = 1.4
TIMING_SLACK = 0.10
MARGIN = 0.10
SUCCESS_MARGIN = 0.2
PAPER_FORM = "polar"


def fig(key: str, label: str, value, unit: str = "") -> Figure:
    v = None if value is None else float(value)
    return Figure(key, label, v if v is None or np.isfinite(v) else None, unit)


def not_tested(cid: str, claim: str, source: str, test: str, reason: str) -> ClaimResult:
    return ClaimResult(cid, claim, source, test, [], "0", "not tested", f"Not tested: {reason}")


# ---- C3/C4 controlled part ------------------------------------------------------------------

def _paired(timing: dict, key: str, cand: str = PAPER_FORM, base: str = "euclidean"):
    """(candidate, baseline) arrays over the seeds both forms completed."""
    ps = timing.get("params", {})
    c = {r["seed"]: r.get(key) for r in ps.get(cand, {}).get("per_seed", [])}
    b = {r["seed"]: r.get(key) for r in ps.get(base, {}).get("per_seed", [])}
    seeds = sorted(s for s in set(c) & set(b) if c[s] is not None and b[s] is not None)
    return np.array([c[s] for s in seeds], float), np.array([b[s] for s in seeds], float)


def equal_accuracy(timing: dict | None) -> tuple[str, list[Figure], str, int]:
    """Controlled C3 verdict, figures, text (with placeholders) and the number of seeds."""
    if not timing or "params" not in timing:
        return "not tested", [], "controlled experiment did not run", 0
    figs, outcomes, parts = [], [], []
    for key, unit, floor, name in (("final_rms_px", "px", EQUIVALENT_PX, "final RMS"),
                                   ("rotation_error_deg", "deg", ROT_FLOOR_DEG, "relative-rotation error")):
        c, b = _paired(timing, key)
        n = len(c)
        if n < 2:
            return "inconclusive", figs, f"fewer than 2 seeds completed by both forms ({n})", n
        d = c - b
        se = float(d.std(ddof=1) / np.sqrt(n))
        tol = max(floor, float(b.std(ddof=1)))
        k = key.split("_")[0]
        figs += [fig(f"c_{k}_polar", f"controlled: polar median {name}", np.median(c), unit),
                 fig(f"c_{k}_eu", f"controlled: euclidean median {name}", np.median(b), unit),
                 fig(f"c_{k}_d", f"controlled: mean paired difference polar - euclidean, {name}", d.mean(), unit),
                 fig(f"c_{k}_se", f"controlled: standard error of that difference, {name}", se, unit),
                 fig(f"c_{k}_tol", f"controlled: tolerance (seed-to-seed spread or floor), {name}", tol, unit)]
        if abs(d.mean()) <= tol:
            outcomes.append("equal")
        elif abs(d.mean()) - 2 * se > tol:
            outcomes.append("worse" if d.mean() > 0 else "better")
        else:
            outcomes.append("unclear")
        parts.append(f"{name} {{c_{k}_polar}} vs {{c_{k}_eu}} (paired difference {{c_{k}_d}} +- {{c_{k}_se}}, "
                     f"tolerance {{c_{k}_tol}}: {outcomes[-1]})")
    verdict = ("supported" if all(o == "equal" for o in outcomes) else
               "not supported" if any(o in ("worse", "better") for o in outcomes) else "inconclusive")
    return verdict, figs, "Controlled BA (polar vs euclidean, medians over seeds): " + "; ".join(parts), n


def speedup(timing: dict | None) -> tuple[str, list[Figure], str, int]:
    """Controlled C4 verdict from BA-only wall times (median of repeats, per seed)."""
    if not timing or "params" not in timing:
        return "not tested", [], "controlled experiment did not run", 0
    c, b = _paired(timing, "wall_s")
    ci, bi = _paired(timing, "iterations")
    if not len(c):
        return "inconclusive", [], "no seed completed by both forms", 0
    r = b / c
    figs = [fig("c_ratio", "controlled BA-only speed-up euclidean/polar, median over seeds", np.median(r), "x"),
            fig("c_ratio_min", "controlled speed-up, lowest seed", r.min(), "x"),
            fig("c_ratio_max", "controlled speed-up, highest seed", r.max(), "x"),
            fig("c_it_polar", "controlled: polar median iterations", np.median(ci), "count"),
            fig("c_it_eu", "controlled: euclidean median iterations", np.median(bi), "count")]
    for p, v in timing["params"].items():
        w = [x["wall_s"] for x in v.get("per_seed", []) if "wall_s" in x]
        if w:
            figs.append(fig(f"ba_{p}", f"controlled BA-only median wall time, {p}", np.median(w), "s"))
    m = float(np.median(r))
    verdict = ("supported" if m >= SPEEDUP_CLAIM * (1 - TIMING_SLACK) else
               "not supported" if m < 1 + TIMING_SLACK else "inconclusive")
    text = ("Controlled BA-only speed-up euclidean/polar {c_ratio} (range {c_ratio_min} - {c_ratio_max}); "
            "median iterations {c_it_polar} (polar) vs {c_it_eu} (euclidean); median BA wall time "
            + ", ".join("{ba_" + p + "} " + p for p in timing["params"] if any(f.key == f"ba_{p}" for f in figs)))
    return verdict, figs, text, len(r)


# ---- C6/C7 ----------------------------------------------------------------------------------

def _per_seed(cond: dict, p: str, key: str) -> np.ndarray:
    return np.array([r[key] for r in cond["params"].get(p, {}).get("per_seed", [])], float)


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
      "system (Schur complement) at the true solution of seeded synthetic problems, raw and Jacobi-scaled "
      "(unit-free), per parameterization. Gauge: the columns the solver fixes are removed (one camera's pose, "
      "6 DoF, and one centre coordinate of a second camera for the scale).")
C7 = ("C7", "Parallax-angle landmarks reduce the correlation of the structure variables (Sec. 1.2.2)",
      "Section 1.2.2 (after Zhao et al. 2015)", "Mean |correlation coefficient| between the three parameters "
      "of each point, from the point blocks of (J^T J)^-1 (marginal covariance, same gauge as C6) at the true "
      "solution of seeded problems; XYZ vs (azimuth, elevation, parallax angle).")
C8 = ("C8", "Angular/parallax forms are more robust to outliers and to low parallax (Sec. 1.2.2, 4.1 (3))",
      "Section 1.2.2, Discussion 4.1 (3)", "Controlled BA per seed and form: (a) 10 % and 30 % gross outliers "
      "with the Huber loss; (b) a forward-looking rig at several baseline/depth ratios (points far away relative to the "
      "baseline), same initial perturbation in angle terms. Errors are gauge-free: relative rotations of all "
      "camera pairs and point bearings in the camera frames; success = reached the noise floor with correct "
      "geometry.")


def conditioning_claims(cond: dict | None, reason: str) -> list[ClaimResult]:
    if not cond or "params" not in cond:
        why = (cond or {}).get("error") or reason
        return [not_tested(*C6, why), not_tested(*C7, why)]
    n = len(cond.get("seeds", []))
    size = f"{n} seeds ({cond.get('problem', '')})"
    errs = {p: v["error"] for p, v in cond["params"].items() if v.get("error")}
    out = []
    eu = _per_seed(cond, "euclidean", "cond_JtJ_scaled")
    ratios = {p: _per_seed(cond, p, "cond_JtJ_scaled") / eu for p in cond["params"]
              if p != "euclidean" and len(_per_seed(cond, p, "cond_JtJ_scaled")) == len(eu) > 0}
    if not ratios:
        out.append(not_tested(*C6, "the Euclidean or every angular form failed: "
                              + ("; ".join(f"{p}: {e}" for p, e in errs.items()) or "no result")))
    else:
        # Ties (parallax and angular landmarks share J^T J up to rounding) go to the first form.
        low = min(r.mean() for r in ratios.values())
        best = next(p for p in ratios if ratios[p].mean() <= low * (1 + 1e-6))
        figs = []
        for p in ["euclidean"] + list(ratios):
            figs += _mean_range(f"jtj_{p}", f"{p}: cond(J^T J), Jacobi-scaled", _per_seed(cond, p, "cond_JtJ_scaled"))
            figs += _mean_range(f"schur_{p}", f"{p}: cond(reduced camera system), Jacobi-scaled",
                                _per_seed(cond, p, "cond_schur_scaled"))
        figs += _mean_range("ratio6", f"{best}/euclidean ratio of cond(J^T J) scaled", ratios[best])
        text = (f"Best angular form ({best}): cond(J^T J) {{jtj_{best}}} (range {{jtj_{best}_lo}} - "
                f"{{jtj_{best}_hi}}) vs Euclidean {{jtj_euclidean}} ({{jtj_euclidean_lo}} - {{jtj_euclidean_hi}}), "
                f"per-seed ratio {{ratio6_lo}} - {{ratio6_hi}}; reduced camera system {{schur_{best}}} vs "
                "{schur_euclidean} (points are eliminated, so it depends on the residuals only, not on the point "
                "parameterization: XYZ and parallax landmarks give the same matrix, polar adds a view-angle "
                f"residual). Better means a ratio below {1 - MARGIN:.2f} on every seed. "
                f"Gauge: {cond.get('gauge', '')}. Failed forms: "
                + (", ".join(f"{p} ({e})" for p, e in errs.items()) or "none") + ".")
        out.append(ClaimResult(*C6, figs, size, _ratio_verdict(ratios[best]), text))
    pa = _per_seed(cond, "parallax", "mean_abs_point_corr")
    ce = _per_seed(cond, "euclidean", "mean_abs_point_corr")
    if not len(pa) or len(pa) != len(ce):
        out.append(not_tested(*C7, "the Euclidean or parallax form failed in the conditioning run ("
                              + (errs.get("euclidean") or errs.get("parallax") or "no result") + ")"))
    else:
        figs = (_mean_range("corr_pa", "parallax: mean |corr| within a point", pa)
                + _mean_range("corr_eu", "XYZ: mean |corr| within a point", ce)
                + _mean_range("ratio7", "parallax/XYZ ratio of mean |corr|", pa / ce))
        text = ("Mean |corr| {corr_pa} (parallax, range {corr_pa_lo} - {corr_pa_hi}) vs {corr_eu} (XYZ, "
                "{corr_eu_lo} - {corr_eu_hi}); per-seed ratio {ratio7_lo} - {ratio7_hi}. 'Reduced' requires a "
                f"ratio below {1 - MARGIN:.2f} on every seed. Gauge as in C6.")
        out.append(ClaimResult(*C7, figs, size, _ratio_verdict(pa / ce), text))
    return out


# ---- C8 -------------------------------------------------------------------------------------

def _rate(v: dict):
    runs = v.get("runs", [])
    if not runs:
        return None, None, 0
    return (float(np.mean([r["success"] for r in runs])),
            float(np.median([r["rotation_error_deg"] for r in runs])), len(runs))


def _compare(a: float | None, e: float | None) -> str:
    if a is None or e is None:
        return "unknown"
    return "better" if a >= e + SUCCESS_MARGIN else "worse" if a <= e - SUCCESS_MARGIN else "equal"


def robustness_claim(rob: dict | None, reason: str) -> ClaimResult:
    if not rob or "outliers" not in rob or "low_parallax" not in rob:
        return not_tested(*C8, (rob or {}).get("error") or reason or "robustness experiment did not run")
    figs, texts, crashed, flipped = [], [], [], []
    outl = [(f"out{i}", f"outliers {float(frac):.0%}", d) for i, (frac, d) in enumerate(rob["outliers"].items())]
    units = outl + [(f"lp{i}", f"baseline/depth {lvl}", d) for i, (lvl, d) in enumerate(rob["low_parallax"].items())]
    outcome: dict[str, dict[str, str]] = {}
    for key, name, forms in units:
        rates = {p: _rate(v) for p, v in forms.items()}
        parts = []
        for p, (sr, med, n) in rates.items():
            figs += [fig(f"{key}_{p}", f"{name}: {p} success rate ({n} runs)", sr),
                     fig(f"{key}_{p}_med", f"{name}: {p} median relative-rotation error", med, "deg")]
            flips = [r.get("flipped_fraction") for r in forms[p].get("runs", []) if r.get("flipped_fraction") is not None]
            if flips:
                figs.append(fig(f"{key}_{p}_flip", f"{name}: {p} mean fraction of observations with the point "
                                "behind the camera (bearing error > 90 deg)", np.mean(flips)))
                if np.mean(flips) > 0.005:
                    flipped.append(f"{name}/{p} {{{key}_{p}_flip}}")
            its = [r["iterations"] for r in forms[p].get("runs", []) if r.get("iterations") is not None]
            figs.append(fig(f"{key}_{p}_it", f"{name}: {p} median LM iterations", np.median(its) if its else None,
                            "count"))
            parts.append(f"{p} {{{key}_{p}}} ({{{key}_{p}_med}}, {{{key}_{p}_it}} it)")
            if forms[p].get("errors"):
                crashed.append(f"{name}/{p}: {len(forms[p]['errors'])} runs raised ({forms[p]['errors'][0]})")
            if p != "euclidean":
                outcome.setdefault(p, {})[key] = _compare(sr, rates.get("euclidean", (None,))[0])
        init_rms = [r["initial_rms_px"] for r in forms.get("euclidean", {}).get("runs", []) if "initial_rms_px" in r]
        if init_rms:
            figs.append(fig(f"{key}_rms0", f"{name}: median initial pixel RMS", np.median(init_rms), "px"))
            parts.insert(0, f"initial RMS {{{key}_rms0}}")
        texts.append(f"{name}: " + ", ".join(parts))
    angular = list(outcome)
    half = {}
    for h, keys in (("outliers", [k for k, _, _ in outl]), ("low parallax", [k for k, _, _ in units[len(outl):]])):
        per_form = {p: [outcome[p].get(k, "unknown") for k in keys] for p in angular}
        if not angular or all(all(o == "unknown" for o in v) for v in per_form.values()):
            half[h] = "inconclusive"
            continue
        more = [p for p, v in per_form.items() if "better" in v and "worse" not in v]
        half[h] = "supported" if more else "not supported"
        texts.append(f"{h}: " + "; ".join(f"{p} vs euclidean " + "/".join(v) for p, v in per_form.items()))
    v8 = ("supported" if all(v == "supported" for v in half.values()) else
          "not supported" if all(v == "not supported" for v in half.values()) else "inconclusive")
    rationale = ("Success rate (median relative-rotation error, median LM iterations) per form -- " + "; ".join(texts)
                 + f". Success: {rob.get('success_rule', '')}. Better/worse = success rate differs by >= "
                 f"{SUCCESS_MARGIN:.0%}; outliers {half.get('outliers')}, low parallax {half.get('low parallax')}."
                 + (" Points ending behind the cameras (mean fraction of observations over the runs; reprojection cannot "
                    "see it, since -X projects like X): " + ", ".join(flipped) + "." if flipped else "")
                 + (" Runs that raised (solver bugs, not counted): " + "; ".join(crashed) if crashed else ""))
    nforms = len(next(iter(rob["outliers"].values()), {}))
    size = (f"{rob.get('seeds_run', 0)} seeds x ({len(outl)} outlier levels + {len(units) - len(outl)} parallax "
            f"levels) x {nforms} forms ({rob.get('outlier_problem', '')}; {rob.get('parallax_problem', '')})")
    return ClaimResult(*C8, figs, size, v8, rationale)


def experiment_claims(exp: dict | None, reason: str) -> list[ClaimResult]:
    """C6, C7 and C8 from the experiments' JSON (None: all "not tested" with ``reason``)."""
    if exp is None:
        return conditioning_claims(None, reason) + [robustness_claim(None, reason)]
    return conditioning_claims(exp.get("conditioning"), reason) + [robustness_claim(exp.get("robustness"), reason)]
