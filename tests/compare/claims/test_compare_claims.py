"""Verdict rules of the claims scorecard, on hand-made measurements with known outcomes."""

import copy
import dataclasses

import pytest
from test_report_build import synthetic_metrics

import numpy as np

from polarref.core import records
from polarref.core.status import RunStatus
from polarref.compare import schema
from polarref.compare.claims import scorecard as claims
from polarref.compare.claims import controlled as claims_experiments
from polarref.compare.claims import robustness as claims_robustness
from polarref.compare.claims.experiment_records import (Conditioning, DerivationEvidence, Experiments, FormRuns, Robustness,
                                                 Timing)


def _metrics(euclid_runtime, polar_runtime, euclid_tp=1000, polar_tp=1000, euclid_rp=5000, polar_rp=5000,
             euclid_err=0.30, polar_err=0.30, euclid_rot=0.10, polar_rot=0.10):
    data = copy.deepcopy(synthetic_metrics())
    eu, po = data["methods"][0], data["methods"][1]
    for meth, runtime, tp, rp, err in ((eu, euclid_runtime, euclid_tp, euclid_rp, euclid_err),
                                       (po, polar_runtime, polar_tp, polar_rp, polar_err)):
        meth["runtime_s"] = runtime
        meth["metrics"].update(tie_points=tp, reprojected_px=rp, mean_reprojection_error_px=err)
        if tp is None:   # an ok method without metrics (counts unknown)
            meth["metrics"] = None
    eu["gt"]["rotation_error_deg_mean"] = euclid_rot
    po["gt"]["rotation_error_deg_mean"] = polar_rot
    return schema.from_dict(data)


def _verdict(results, cid):
    return next(c for c in results if c.claim_id == cid)


@pytest.mark.parametrize("euclid, polar, verdict", [
    (10.0, 7.0, "supported"),          # x1.43 >= 1.4 * 0.9
    (10.0, 7.9, "supported"),          # x1.27 >= 1.26
    (10.0, 8.5, "inconclusive"),       # x1.18
    (10.0, 10.0, "not supported"),     # x1.0
    (10.0, 20.0, "not supported"),     # twice slower
])
def test_speedup_verdict(euclid, polar, verdict):
    res = claims.scene_claims(_metrics(euclid, polar))
    c4 = _verdict(res, "C4")
    assert c4.verdict == verdict
    ratio = next(f for f in c4.figures if f.key == "ratio_b0").value
    assert ratio == pytest.approx(euclid / polar)


@pytest.mark.parametrize("kw, verdict", [
    (dict(), "supported"),
    (dict(polar_err=0.305), "supported"),                      # +0.005 px: within 0.01 px
    (dict(polar_err=0.20), "supported"),                       # better is not a failure of "equal"
    (dict(polar_err=0.35), "not supported"),                   # +0.05 px worse
    (dict(polar_rot=0.2), "not supported"),                    # rotation error doubled
])
def test_equal_accuracy_verdict(kw, verdict):
    assert _verdict(claims.scene_claims(_metrics(10, 10, **kw)), "C3").verdict == verdict


@pytest.mark.parametrize("kw, verdict", [
    (dict(polar_tp=1010, polar_rp=5010), "supported"),
    (dict(polar_tp=1001, polar_rp=5001), "not supported"),   # +1 each: inside the max(1, 0.1 %) margin
    (dict(polar_tp=990, polar_rp=6000), "not supported"),
    (dict(polar_tp=None), "not tested"),                      # a missing count is never 0
])
def test_more_tie_points_verdict(kw, verdict):
    assert _verdict(claims.scene_claims(_metrics(10, 10, **kw)), "C5").verdict == verdict


def test_missing_reprojection_error_is_not_tested():
    m = _metrics(10, 10)
    for meth in m.methods:
        if meth.metrics is not None:   # the failed method has none
            meth.metrics.mean_reprojection_error_px = None
    assert _verdict(claims.scene_claims(m), "C3").verdict == "not tested"


def test_scene_claims_not_tested_when_candidate_failed():
    m = _metrics(10, 10)
    m.methods[1].status = "failed"
    res = claims.scene_claims(m)
    assert {c.verdict for c in res} == {"not tested"}
    assert all("ours-polar did not succeed" in c.rationale for c in res)


def _evidence(printed, claim7, nan=0):
    case = dict(case="random", printed_eq3_max_err=printed, printed_eq3_nan=nan,
                printed_is_complement_max_err=1e-12, corrected_eq3_max_err=1e-12, claim7_max_err=claim7)
    return records.coerce(DerivationEvidence, {"cases": [case], "samples_per_case": 1000})


def test_equation_verdicts():
    c1, c2 = claims.equation_claims(_evidence(1.5, 0.0), "")
    assert (c1.verdict, c2.verdict) == ("not supported", "supported")
    c1, c2 = claims.equation_claims(_evidence(1e-12, 0.3), "")
    assert (c1.verdict, c2.verdict) == ("supported", "not supported")
    c1, _ = claims.equation_claims(_evidence(1e-12, 0.0, nan=3), "")
    assert c1.verdict == "not supported"                                     # undefined somewhere
    c1, c2 = claims.equation_claims(None, "derivations crashed")
    assert c1.verdict == c2.verdict == "not tested" and "derivations crashed" in c1.rationale


def _cond(eu, pa, corr_eu, corr_pa, pa_error=""):
    row = lambda c, r: {"cond_JtJ": c, "cond_JtJ_scaled": c, "cond_schur": 1.0, "cond_schur_scaled": 1.0,
                        "mean_abs_point_corr": r, "max_abs_point_corr": r, "error": "", "cond_JtJ_block": c,
                        "mean_abs_point_corr_ray": r, "max_abs_point_corr_ray": r}
    return records.coerce(Conditioning, {
        "problem": "p", "seeds": list(range(len(eu))), "gauge": "g",
        "params": {"euclidean": {"per_seed": [row(c, r) for c, r in zip(eu, corr_eu)], "error": ""},
                   "parallax": {"per_seed": [row(c, r) for c, r in zip(pa, corr_pa)], "error": pa_error}}})


def _runs(successes, rot=0.03, flip=0.0):
    return {"runs": [{"seed": k, "success": bool(s), "rotation_error_deg": rot, "flipped_fraction": flip}
                     for k, s in enumerate(successes)], "errors": []}


def _rob(out_eu, out_pa, levels, start=None, rot_pa=0.03):
    """levels: list of (euclidean successes, parallax successes) per parallax level."""
    st = start or [0] * len(out_eu)
    unit = lambda e, p: {"start": _runs(st, rot=2.0), "euclidean": _runs(e), "parallax": _runs(p, rot=rot_pa)}  # noqa: E731
    return records.coerce(Robustness, {
        "seeds_run": len(out_eu), "success_rule": "r", "outlier_problem": "o", "parallax_problem": "l",
        "outliers": {"0.1": unit(out_eu, out_pa)},
        "low_parallax": {f"{0.3 / 10 ** i:g}": unit(e, p) for i, (e, p) in enumerate(levels)}})


# 10 seeds: with Wilson/Newcombe intervals, 3/10 vs 10/10 is a difference, 3/5 vs 5/5 would not be
ALL, NONE, SOME = [1] * 10, [0] * 10, [1, 0, 0, 1, 0, 0, 1, 0, 0, 0]


@pytest.mark.parametrize("eu, pa, verdict", [
    ([100, 120, 90], [50, 60, 40], "supported"),            # better on every seed
    ([100, 120, 90], [95, 130, 200], "not supported"),       # no seed better by > 10 %
    ([100, 120, 90], [50, 130, 85], "inconclusive"),         # seeds disagree
])
def test_conditioning_verdict_two_sided(eu, pa, verdict):
    c6, _ = claims_experiments.conditioning_claims(_cond(eu, pa, [0.5] * 3, [0.5] * 3), "")
    assert c6.verdict == verdict
    ratio = next(f for f in c6.figures if f.key == "ratio6").value
    assert ratio == pytest.approx(np.mean(np.array(pa) / np.array(eu)))
    assert f"{len(eu)} seeds" in c6.sample_size
    raw = {f.key: f.value for f in c6.figures if "raw" in f.key}
    assert raw["ratio6_raw"] == pytest.approx(ratio) and "jtj_raw_euclidean" in raw


def test_conditioning_unit_rescaling_moves_raw_not_scaled():
    """The real experiment: km instead of m changes the raw condition number, not the scaled one."""
    from polarref.compare.claims import experiments

    cond = experiments.conditioning(0, seeds=2, size=(5, 30))
    c6, _ = claims_experiments.conditioning_claims(cond, "")
    f = {x.key: x.value for x in c6.figures}
    assert f["ratio6_rescaled"] == pytest.approx(f["ratio6"], rel=1e-4)
    assert abs(np.log(f["ratio6_raw_rescaled"] / f["ratio6_raw"])) > np.log(5)   # raw moves by > 5x
    assert "rests on the Jacobi-scaled" in c6.rationale


@pytest.mark.parametrize("corr_pa, verdict", [
    ([0.2, 0.3, 0.1], "supported"), ([0.5, 0.6, 0.45], "not supported"), ([0.2, 0.6, 0.1], "inconclusive")])
def test_correlation_verdict_two_sided(corr_pa, verdict):
    _, c7 = claims_experiments.conditioning_claims(_cond([1, 1, 1], [1, 1, 1], [0.5, 0.5, 0.5], corr_pa), "")
    assert c7.verdict == verdict
    lo, hi = (next(f for f in c7.figures if f.key == k).value for k in ("corr_pa_lo", "corr_pa_hi"))
    assert (lo, hi) == (min(corr_pa), max(corr_pa))


@pytest.mark.parametrize("rob, verdict", [
    (_rob(SOME, ALL, [(ALL, ALL), (SOME, ALL)]), "supported"),          # better in both halves
    (_rob(ALL, ALL, [(ALL, ALL), (ALL, ALL)]), "inconclusive"),         # baseline always succeeds: saturated
    (_rob(NONE, NONE, [(NONE, NONE)]), "inconclusive"),                 # baseline never succeeds
    (_rob(SOME, SOME, [(SOME, SOME), (SOME, SOME)]), "not supported"),  # baseline struggles, no form better
    (_rob(SOME, SOME, [(ALL, ALL), (ALL, NONE)]), "not supported"),     # worse at low parallax
    (_rob(SOME, ALL, [(ALL, ALL), (ALL, ALL)]), "inconclusive"),        # outliers yes, parallax saturated
    (_rob(ALL, ALL, [(ALL, ALL)], rot_pa=0.01), "supported"),           # same rates, 3x lower error every seed
    (_rob(SOME, ALL, [(SOME, ALL)], start=ALL), "inconclusive"),        # the start point already succeeds
])
def test_robustness_verdict(rob, verdict):
    c8 = claims_robustness.robustness_claim(rob, "")
    assert c8.verdict == verdict
    f = {x.key: x.value for x in c8.figures}
    assert f["out0_parallax"] == pytest.approx(np.mean([r.success for r in rob.outliers["0.1"]["parallax"].runs]))
    starts = [v for k, v in f.items() if k.endswith("_start_success")]
    assert len(starts) == 1 + len(rob.low_parallax)
    assert c8.sample_size.startswith("10 seeds x (1 outlier levels + ")


def test_wilson_newcombe_and_bootstrap_against_independent_values():
    """Wilson 95 % intervals vs published values (Newcombe 1998, Table I), the difference interval
    vs its example, and the bootstrap interval of a geometric mean vs its own definition."""
    lo, hi = claims_robustness.wilson(81, 263)
    assert (lo, hi) == pytest.approx((0.2553, 0.3662), abs=5e-4)
    assert claims_robustness.wilson(0, 10) == pytest.approx((0.0, 0.2775), abs=5e-4)
    lo, hi = claims_robustness.rate_difference(56 / 70, 70, 48 / 80, 80)       # Newcombe 1998 (method 10)
    assert (lo, hi) == pytest.approx((0.0524, 0.3339), abs=5e-4)
    r = np.array([0.5, 0.6, 0.55, 0.7, 0.45])
    blo, bhi = claims_robustness.bootstrap_gm(r)
    assert blo < np.exp(np.log(r).mean()) < bhi and 0.45 <= blo and bhi <= 0.7
    assert claims_robustness.bootstrap_gm(r) == (blo, bhi)                      # seeded
    assert claims_robustness.bootstrap_gm(np.full(5, 0.3)) == pytest.approx((0.3, 0.3))


def test_tost_outcomes():
    d = np.array([0.10, 0.11, 0.09, 0.10, 0.10])
    assert claims_experiments.tost(d, 0.5)[3] == "equal"
    assert claims_experiments.tost(d, 0.05)[3] == "higher"
    assert claims_experiments.tost(-d, 0.05)[3] == "lower"
    assert claims_experiments.tost(np.array([-1.0, 1.0, -0.5, 0.6]), 0.5)[3] == "unclear"   # too wide
    m, lo, hi, _ = claims_experiments.tost(d, 1.0)
    from scipy import stats
    ref = stats.t.interval(0.90, len(d) - 1, loc=d.mean(), scale=stats.sem(d))   # independent implementation
    assert (lo, hi) == pytest.approx(ref) and m == pytest.approx(d.mean())
    assert claims_experiments.tost(np.array([0.1]), 1.0)[3] == "unclear"


def test_broken_experiments_are_not_tested_with_reason():
    assert all(c.verdict == "not tested" and "timed out" in c.rationale
               for c in claims.experiment_claims(None, "timed out"))
    exp = Experiments(0, conditioning=Conditioning(error="LinAlgError: singular"),
                      robustness=Robustness(error="ValueError: boom"))
    c6, c7, c8 = claims.experiment_claims(exp, "")
    assert (c6.verdict, c7.verdict, c8.verdict) == ("not tested",) * 3
    assert "singular" in c6.rationale and "boom" in c8.rationale
    # every form of a seed failed: nothing to compare -> not tested, never "not supported"
    cond = _cond([], [], [], [], pa_error="ValueError: x")
    assert {c.verdict for c in claims_experiments.conditioning_claims(cond, "")} == {"not tested"}
    # a robustness run with no completed runs is inconclusive, not a verdict
    rob = _rob([], [], [([], [])])
    assert claims_robustness.robustness_claim(rob, "").verdict == "inconclusive"


def _timing(rms_eu, rms_po, rot_eu, rot_po, wall_eu, wall_po):
    def rows(rms, rot, wall):
        return [{"seed": s, "final_rms_px": a, "rotation_error_deg": b, "wall_s": c, "iterations": 5}
                for s, (a, b, c) in enumerate(zip(rms, rot, wall))]
    return Experiments(0, timing=records.coerce(Timing, {"problem": "p", "params": {
        "euclidean": {"per_seed": rows(rms_eu, rot_eu, wall_eu), "runs": [], "trace": [], "error": ""},
        "polar": {"per_seed": rows(rms_po, rot_po, wall_po), "runs": [], "trace": [], "error": ""}}}))


RMS = [0.46, 0.47, 0.45, 0.48, 0.46]
ROT = [0.020, 0.030, 0.025, 0.022, 0.028]
WALL = [1.0, 1.1, 0.9, 1.0, 1.05]


@pytest.mark.parametrize("rms_po, rot_po, verdict", [
    ([r + 0.002 for r in RMS], ROT, "supported"),                        # within the 0.01 px floor
    ([r - 0.004 for r in RMS], [r + 0.002 for r in ROT], "supported"),   # within the seed spread
    ([r + 0.05 for r in RMS], ROT, "not supported"),                      # clearly worse
    ([r - 0.05 for r in RMS], ROT, "not supported"),                      # clearly better: not "equal"
    (RMS, [r + 0.02 for r in ROT], "not supported"),                      # rotation clearly worse
    ([0.46, 0.51, 0.45, 0.52, 0.45], ROT, "inconclusive"),               # mean +0.014 > tol, but noisy
])
def test_controlled_equal_accuracy_two_sided(rms_po, rot_po, verdict):
    exp = _timing(RMS, rms_po, ROT, rot_po, WALL, WALL)
    c3 = _verdict(claims.scene_claims(_metrics(10, 10, polar_rot=0.5), exp), "C3")   # scene run says worse
    assert c3.verdict == verdict
    assert "5 seeds" in c3.sample_size and "1 run per method" in c3.sample_size
    assert "single-run rule alone gives: not supported" in c3.rationale
    d = next(f for f in c3.figures if f.key == "c_final_d").value
    assert d == pytest.approx(np.mean(np.array(rms_po) - RMS))


@pytest.mark.parametrize("factor, verdict", [
    (1 / 1.5, "supported"), (1 / 1.2, "not supported"),                 # no repeats: the pre-registered 10 % slack
    (1.0, "not supported"), (2.0, "not supported"),
    ([1 / 1.0, 1 / 1.8, 1 / 1.2, 1 / 1.7, 1 / 1.3], "inconclusive")])   # interval straddles 1.4 x 0.9
def test_controlled_speedup(factor, verdict):
    f = factor if isinstance(factor, list) else [factor] * len(WALL)
    exp = _timing(RMS, RMS, ROT, ROT, WALL, [w * k for w, k in zip(WALL, f)])
    c4 = _verdict(claims.scene_claims(_metrics(10, 7), exp), "C4")       # the scene run alone says supported
    assert c4.verdict == verdict
    figs = {x.key: x.value for x in c4.figures}
    assert figs["c_ratio"] == pytest.approx(np.median(1 / np.array(f)))
    assert figs["c_gm"] == pytest.approx(np.exp(np.mean(-np.log(f))))
    assert figs["c_gm_lo"] <= figs["c_gm"] <= figs["c_gm_hi"] and figs["c_slack"] == pytest.approx(10.0)


def test_timing_slack_from_the_measured_run_to_run_spread():
    """Repeats with a known log spread give that spread and a slack of 2 SD of a two-run log ratio."""
    from polarref.compare.claims import controlled as cx

    rng = np.random.default_rng(3)
    exp = _timing(RMS, RMS, ROT, ROT, WALL, [w / 1.5 for w in WALL])
    for form in exp.timing.params.values():
        form.runs = [records.coerce(cx.Timing, {"params": {"x": {"runs": [{"wall_s": float(np.exp(rng.normal(0, 0.02))),
                                                                          "seed": s}]}}}).params["x"].runs[0]
                     for s in range(5) for _ in range(40)]
    slack, spread = cx.timing_slack(exp.timing)
    assert spread == pytest.approx(0.02, rel=0.1)
    assert slack == pytest.approx(1 - np.exp(-2 * np.sqrt(2) * spread))
    c4 = _verdict(claims.scene_claims(_metrics(10, 7), exp), "C4")
    assert c4.verdict == "supported"
    assert next(x for x in c4.figures if x.key == "c_slack").value == pytest.approx(100 * slack)
    assert "within the pre-registered one" in c4.rationale
    # a noisy machine widens the slack, but never turns a slow-down into the claimed speed-up
    slow = _timing(RMS, RMS, ROT, ROT, WALL, [w / 0.66 for w in WALL])
    for form in slow.timing.params.values():
        form.runs = [dataclasses.replace(exp.timing.params["polar"].runs[0], wall_s=float(np.exp(rng.normal(0, 0.4))),
                                         seed=s) for s in range(5) for _ in range(5)]
    c4 = _verdict(claims.scene_claims(_metrics(10, 7), slow), "C4")
    assert c4.verdict == "not supported" and "above the pre-registered one" in c4.rationale


def test_controlled_missing_falls_back_to_scene_rule():
    exp = Experiments(0, timing=Timing(error="RuntimeError: x"))
    c4 = _verdict(claims.scene_claims(_metrics(10, 7), exp), "C4")
    assert c4.verdict == "supported" and "not run" in c4.rationale


def test_derivation_evidence_is_a_typed_record_that_round_trips(tmp_path):
    from polarref.compare.claims import jobs as claim_jobs

    ev = claim_jobs.derivation_evidence(n=200, out_json=str(tmp_path / "derivations.json"))
    assert isinstance(ev, DerivationEvidence) and ev.samples_per_case == 200 and len(ev.cases) >= 3
    assert records.load(DerivationEvidence, tmp_path / "derivations.json") == ev
    c1, c2 = claims.equation_claims(ev, "")
    assert c1.verdict == "not supported" and c2.verdict == "supported"   # the printed Eq. 3 fails; claim 7 holds
    with pytest.raises(records.RecordError, match="unknown key"):
        records.coerce(DerivationEvidence, {"cases": [], "samples_per_case": 1, "bogus": 0})


@pytest.mark.parametrize("euclid, polar, polar_tp, polar_rp", [
    (10.0, 7.0, 1010, 5010), (10.0, 8.5, 1001, 5001), (10.0, 10.0, 1000, 5000), (10.0, 9.0, 990, 6000)])
def test_the_scene_scorecard_and_the_twin_tables_share_one_single_run_rule(euclid, polar, polar_tp, polar_rp):
    """The same measurements give the same C4/C5 verdict on a small scene and on a twin."""
    from polarref.compare.twins import tables as PT

    res = claims.scene_claims(_metrics(euclid, polar, polar_tp=polar_tp, polar_rp=polar_rp))

    def twin_side(name, runtime, tp, rp):
        return PT.TwinRow(name, RunStatus.OK, "", 12, 12, 0.3, runtime / 60, tp, rp)

    twin = PT.TwinTable("rosetta", 12, 30, {PT.BASELINE: twin_side(PT.BASELINE, euclid, 1000, 5000),
                                            PT.OURS: twin_side(PT.OURS, polar, polar_tp, polar_rp)})
    v = PT.verdicts(twin)
    assert v.c4.verdict == _verdict(res, "C4").verdict
    assert v.c5.verdict == _verdict(res, "C5").verdict
    assert {v.c4.verdict, v.c5.verdict} <= {"supported", "not supported", "inconclusive"}


def test_c4_without_the_same_pipeline_baseline_is_not_tested():
    m = _metrics(10.0, 7.0)
    m.methods[2] = dataclasses.replace(m.methods[0], name="pycolmap-incremental-sift")   # another baseline ran
    m.methods[0].status = "failed"   # ours-euclidean, the rule's baseline, did not
    figs = {f.key: f.value for f in _verdict(claims.scene_claims(m), "C4").figures}
    assert figs["ratio_b0"] == pytest.approx(10.0 / 7.0)   # still reported beside it
    assert _verdict(claims.scene_claims(m), "C4").verdict == "not tested"
    assert _verdict(claims.scene_claims(m), "C5").verdict == "not tested"


# ---- issue 30: the frame-dependent verdict -------------------------------------------------------

def test_frame_rule():
    from polarref.compare.claims.invariance import FRAME_DEPENDENT, decide
    assert decide("supported", ["supported"] * 21) == "supported"
    assert decide("not supported", ["not supported"] * 20 + ["inconclusive"]) == FRAME_DEPENDENT
    assert decide("supported", []) == "supported"
    assert FRAME_DEPENDENT in schema.VERDICTS
    from polarref.compare.report.render import CSS, verdict_class
    assert all(f".{verdict_class(v)}{{" in CSS for v in schema.VERDICTS)     # every verdict has a colour


def test_a_frame_dependent_measure_gets_the_frame_dependent_verdict():
    """C7 on a constructed measure that moves with the frame: 'supported' in the experiment's own
    frame, 'inconclusive' under one of three draws -> 'frame-dependent', share 2/3; the same draws
    with the measure unchanged keep 'supported'."""
    from polarref.compare.claims import invariance as ci
    from polarref.compare.claims.experiment_records import DrawFrame, Invariance, InvarianceDraw

    base = _cond([1, 1, 1], [1, 1, 1], [0.5] * 3, [0.2] * 3)
    moved = _cond([1, 1, 1], [1, 1, 1], [0.5] * 3, [0.2, 0.6, 0.2])
    draws = [InvarianceDraw(DrawFrame(k, "similarity", 2.0, 30.0, 5.0), conditioning=c)
             for k, c in enumerate((base, moved, base))]
    exp = Experiments(0, conditioning=base, invariance=Invariance(7, draws))
    c7 = ci.apply(claims.experiment_claims(exp, ""), exp)[1]
    assert c7.claim_id == "C7" and c7.verdict == ci.FRAME_DEPENDENT
    assert c7.invariance.base_verdict == "supported" and c7.invariance.agree_share == pytest.approx(2 / 3)
    assert [d.verdict for d in c7.invariance.draws] == ["supported", "inconclusive", "supported"]
    assert "frame-dependent" in c7.rationale and "67%" in c7.rationale
    steady = Experiments(0, conditioning=base, invariance=Invariance(7, [draws[0], draws[2]]))
    assert ci.apply(claims.experiment_claims(steady, ""), steady)[1].verdict == "supported"


# ---- issue 30: pre-registration and power ----------------------------------------------------------

def test_preregistration_file_drives_the_thresholds_and_seeds():
    from polarref.compare.claims import experiments
    from polarref.compare.claims import thresholds
    from polarref.compare.claims.preregistration import PREREG

    for c in PREREG.claims:
        assert c.test_seeds and not set(c.test_seeds) & set(c.pilot_seeds), c.claim_id
        assert c.measure
    assert {c.claim_id for c in PREREG.claims} == {"C3", "C4", "C5", "C6", "C7", "C8"}
    assert thresholds.RMS_MARGIN_PX == PREREG.claim("C3").value("rms_margin_px")
    assert thresholds.SPEEDUP_CLAIM == PREREG.claim("C4").value("speedup_claim") == 1.4
    assert thresholds.PAPER_TIE_REL == pytest.approx(0.0018) and thresholds.PAPER_OBS_REL == pytest.approx(0.0012)
    assert experiments.CONTROLLED_SEEDS == len(PREREG.claim("C3").test_seeds)
    assert experiments.OUTLIER_FRACTIONS == PREREG.claim("C8").outlier_levels == PREREG.claim("C5").levels
    assert np.isfinite(thresholds.PILOT_SD_RMS_PX * thresholds.PILOT_SD_LOG_SPEEDUP * thresholds.PILOT_SD_TIE_REL)


def test_preregistration_refuses_overlapping_seeds(tmp_path):
    from polarref.compare.claims.preregistration import load
    from polarref.core.errors import PolarrefError

    bad = tmp_path / "p.toml"
    bad.write_text('[C3]\nmeasure = "m"\ntest_seeds = [0, 1]\npilot_seeds = [1, 2]\n')
    with pytest.raises(PolarrefError, match=r"\[C3\].*disjoint"):
        load(bad)
    bad.write_text("[C3\n")
    with pytest.raises(PolarrefError, match="p.toml"):
        load(bad)


def test_file_commit_in_a_scratch_repository(tmp_path):
    import subprocess
    from polarref.compare.claims.preregistration import file_commit

    git = lambda *a: subprocess.run(["git", "-c", "user.email=t@t", "-c", "user.name=t", *a], cwd=tmp_path,  # noqa: E731
                                    check=True, capture_output=True, text=True).stdout.strip()
    git("init", "-q")
    f = tmp_path / "prereg.toml"
    f.write_text("a = 1\n")
    git("add", "prereg.toml")
    git("commit", "-qm", "register")
    head = git("rev-parse", "HEAD")
    (tmp_path / "other").write_text("x")
    git("add", "other")
    git("commit", "-qm", "later")            # a later commit that does not touch the file
    fc = file_commit(f)
    assert fc.commit == head and fc.modified is False and fc.date[:4].isdigit()
    f.write_text("a = 2\n")
    assert file_commit(f).modified is True


def test_mde_gives_80_percent_power_by_simulation():
    """At an effect equal to the MDE, a paired two-sided t-test at alpha 0.05 rejects in ~80 % of
    seeded simulated experiments (the MDE formula vs an independent Monte-Carlo)."""
    from scipy.stats import ttest_1samp
    from polarref.compare.claims.preregistration import mde

    n, sd = 10, 0.3
    effect = mde(sd, n, 0.05, 0.8)
    assert effect == pytest.approx((2.2622 + 0.8834) * sd / np.sqrt(n), rel=1e-4)    # t tables, 9 dof
    rng = np.random.default_rng(4)
    d = rng.normal(effect, sd, (4000, n))
    power = np.mean(ttest_1samp(d, 0.0, axis=1).pvalue < 0.05)
    assert 0.76 < power < 0.84
    assert mde(sd, 1, 0.05, 0.8) == float("inf") and mde(float("nan"), 10, 0.05, 0.8) == float("inf")


def test_underpowered_instead_of_not_supported(monkeypatch):
    from polarref.compare.claims import controlled as cx

    exp = _timing(RMS, RMS, ROT, ROT, WALL, WALL)                    # no speed-up at all
    c4 = _verdict(claims.scene_claims(_metrics(10, 10), exp), "C4")
    assert c4.verdict == "not supported"                             # the pilot's spread detects 1.4x
    mde4 = next(f for f in c4.figures if f.key == "c_mde").value
    assert 1.0 < mde4 < 1.4
    monkeypatch.setattr(cx, "PILOT_SD_LOG_SPEEDUP", 1.0)             # a pilot far noisier than the effect
    c4 = _verdict(claims.scene_claims(_metrics(10, 10), exp), "C4")
    assert c4.verdict == "underpowered" and next(f for f in c4.figures if f.key == "c_mde").value > 1.4
    fast = _timing(RMS, RMS, ROT, ROT, WALL, [w / 1.5 for w in WALL])
    assert _verdict(claims.scene_claims(_metrics(10, 10), fast), "C4").verdict == "supported"
    # C3: a noisy pilot makes an unclear result underpowered, a clear difference stays not supported
    monkeypatch.setattr(cx, "PILOT_SD_RMS_PX", 0.1)
    noisy = _timing(RMS, [0.46, 0.51, 0.45, 0.52, 0.45], ROT, ROT, WALL, WALL)
    assert _verdict(claims.scene_claims(_metrics(10, 10), noisy), "C3").verdict == "underpowered"
    worse = _timing(RMS, [r + 0.05 for r in RMS], ROT, ROT, WALL, WALL)
    c3 = _verdict(claims.scene_claims(_metrics(10, 10), worse), "C3")
    assert c3.verdict == "not supported" and "polar worse by" in c3.rationale


def test_c5_with_the_committed_pilot_is_underpowered_unless_an_interval_excludes_the_effect():
    """150 points and 10 pairs cannot detect +0.18 %: equal counts are underpowered, never 'not
    supported'; counts clearly lower (interval below +0.18 %) are 'not supported'."""
    def rob(delta_tp):
        noise = [0, 0, 0, 0, 0] if delta_tp is None else [6, -6, 4, -4, 1]
        delta_tp = delta_tp or 0
        runs = lambda tp, obs, e: {"runs": [{"seed": s, "success": True, "rotation_error_deg": 0.03,  # noqa: E731
                                             "tie_points": tp + e[s], "inlier_observations": obs + 5 * e[s]}
                                            for s in range(5)], "errors": []}
        unit = {"start": runs(10, 100, [0] * 5), "euclidean": runs(140, 900, [0] * 5),
                "polar": runs(140 + delta_tp, 900 + 6 * delta_tp, noise)}
        return records.coerce(Robustness, {"seeds_run": 5, "outliers": {"0.3": unit, "0.5": unit}, "low_parallax": {}})
    v, figs, text, n = claims_robustness.more_tie_points(rob(0))
    f = {x.key: x.value for x in figs}
    assert n == 10 and v == "underpowered" and f["c5_tp_mde"] > f["c5_tp_paper"] == pytest.approx(0.18)
    # the margin is never wider than the paper's effect (was max(0.1 %, 1 count) = 0.71 % on 140 points)
    assert f["c5_tp_margin"] == pytest.approx(0.1) and f["c5_obs_margin"] == pytest.approx(0.1)
    assert f["c5_obs_margin"] <= f["c5_obs_paper"] == pytest.approx(0.12)
    v, *_ = claims_robustness.more_tie_points(rob(-10))
    assert v == "not supported"
    v, *_ = claims_robustness.more_tie_points(rob(None))      # identical counts: [0, 0] excludes +0.18 %
    assert v == "not supported"


def _point_runs(rates, points=100, ok=True):
    """Low-parallax runs with per-point scores: ``rates`` is each seed's point success rate."""
    return {"runs": [{"seed": k, "success": ok, "rotation_error_deg": 0.03, "points_scored": points,
                      "points_depth_ok": round(r * points)} for k, r in enumerate(rates)], "errors": []}


def _rob_points(eu, pa):
    unit = lambda e, p, ok=True: {"start": _point_runs([0.5] * len(e), ok=False),   # noqa: E731
                                  "euclidean": _point_runs(e), "parallax": _point_runs(p)}
    return records.coerce(Robustness, {
        "seeds_run": len(eu), "success_rule": "r", "outlier_problem": "o", "parallax_problem": "l",
        "outliers": {"0.1": {"start": _runs([0] * 5, rot=2.0), "euclidean": _runs([1, 0, 1, 0, 1]),
                             "parallax": _runs([1, 0, 1, 0, 1])}},
        "low_parallax": {"0.003": unit(eu, pa)}})


EU_RATES = [0.40, 0.30, 0.50, 0.45, 0.35]


@pytest.mark.parametrize("pa, half", [
    ([r + 0.2 for r in EU_RATES], "supported"),          # more points right on every seed
    ([r - 0.2 for r in EU_RATES], "not supported"),      # fewer: the rule fails for the parallax form
    (EU_RATES, "not supported"),                         # same rates, same errors: no form more robust
])
def test_low_parallax_point_success_is_continuous_and_paired(pa, half):
    """Issue 30: the low-parallax half scores points (continuous rates in [0.2, 0.8] are possible),
    compares the forms per seed, and can fail."""
    rob = _rob_points(EU_RATES, pa)
    c8 = claims_robustness.robustness_claim(rob, "")
    f = {x.key: x.value for x in c8.figures}
    assert f["lp0_euclidean"] == pytest.approx(np.mean(EU_RATES))
    assert f["lp0_parallax"] == pytest.approx(np.mean(pa))
    assert f["lp0_start_success"] == 0.0                   # a failed run scores no point
    assert f["lp0_euclidean_wlo"] < np.mean(EU_RATES) < f["lp0_euclidean_whi"]
    assert f"low parallax: {half}" in c8.rationale
    assert "2 of 2 levels have a Euclidean success rate in [0.2, 0.8]" in c8.rationale


def test_point_rate_needs_the_run_to_succeed():
    runs = records.coerce(FormRuns, _point_runs([0.6, 0.3]))
    assert claims_robustness.seed_rates(runs) == claims_robustness.SeedRates((0, 1), (0.6, 0.3))
    failed = records.coerce(FormRuns, _point_runs([0.6], ok=False))
    assert claims_robustness.point_rate(failed.runs[0]) == 0.0
    binary = records.coerce(FormRuns, _runs([1, 0]))
    assert claims_robustness.seed_rates(binary) is None     # outlier runs stay per run
    lo, hi = claims_robustness.bootstrap_mean(np.array([0.1, 0.2, 0.3, 0.4]))
    assert 0.1 <= lo < 0.25 < hi <= 0.4


def _with_real(exp, *ratios_per_problem, skipped=""):
    """``exp`` with real problems whose interleaved repeats give these euclidean/polar ratios."""
    from polarref.compare.claims.experiment_records import RealProblemTiming, RealRun

    exp.timing.real = [RealProblemTiming(f"problem{i}", "n cams", "", {
        "euclidean": RealRun([1.0 * r for r in ratios], 0.5, 10, "function_tolerance"),
        "polar": RealRun([1.0] * len(ratios), 0.5, 8, "function_tolerance")})
        for i, ratios in enumerate(ratios_per_problem)]
    if skipped:
        exp.timing.real.append(RealProblemTiming("absent", skipped=skipped))
    return exp


FAST, SLOW = [1.6, 1.65, 1.55, 1.6, 1.62], [0.5, 0.52, 0.49, 0.5, 0.51]


@pytest.mark.parametrize("synthetic, real, verdict", [
    (1 / 1.5, [FAST, FAST], "supported"),            # every family at or above 1.4 x 0.9
    (1 / 1.5, [FAST, SLOW], "inconclusive"),         # a real problem contradicts the synthetic seeds
    (1.0, [SLOW, SLOW], "not supported"),
    (1.0, [FAST], "inconclusive"),                   # e.g. euclidean stalls at the iteration cap there
])
def test_controlled_speedup_with_real_problems(synthetic, real, verdict):
    exp = _with_real(_timing(RMS, RMS, ROT, ROT, WALL, [w * synthetic for w in WALL]), *real,
                     skipped="not in the reference data")
    c4 = _verdict(claims.scene_claims(_metrics(10, 7), exp), "C4")
    assert c4.verdict == verdict
    figs = {x.key: x.value for x in c4.figures}
    for i, ratios in enumerate(real):
        assert figs[f"real{i}_gm"] == pytest.approx(np.exp(np.mean(np.log(ratios))))
        assert figs[f"real{i}_lo"] < figs[f"real{i}_gm"] < figs[f"real{i}_hi"]
    assert "absent: not run (not in the reference data)" in c4.rationale


def test_seeds_needed_is_the_smallest_n_whose_mde_reaches_the_effect():
    from scipy.stats import t as student_t

    from polarref.compare.claims.preregistration import seeds_needed

    def brute(sd, effect):                     # the paired-t MDE formula, n counted up one by one
        n = 2
        while (student_t.ppf(0.975, n - 1) + student_t.ppf(0.8, n - 1)) * sd / np.sqrt(n) > effect:
            n += 1
        return n

    for sd, effect in ((1.0, 1.0), (0.112316, np.log(1.4)), (0.029282, 0.0018), (0.3, 0.01)):
        assert seeds_needed(sd, effect, 0.05, 0.8) == brute(sd, effect)
    assert seeds_needed(1.0, 1e-6, 0.05, 0.8, n_max=1000) is None          # not affordable: None
    assert seeds_needed(float("inf"), 1.0, 0.05, 0.8) is None
