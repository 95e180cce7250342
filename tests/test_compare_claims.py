"""Verdict rules of the claims scorecard, on hand-made measurements with known outcomes."""

import copy

import pytest
from test_report_build import synthetic_metrics

from polarref.compare import claims, schema


def _metrics(euclid_runtime, polar_runtime, euclid_tp=1000, polar_tp=1000, euclid_rp=5000, polar_rp=5000,
             euclid_err=0.30, polar_err=0.30, euclid_rot=0.10, polar_rot=0.10):
    data = copy.deepcopy(synthetic_metrics())
    eu, po = data["methods"][0], data["methods"][1]
    eu.update(runtime_s=euclid_runtime, tie_points=euclid_tp, reprojected_px=euclid_rp,
              mean_reprojection_error_px=euclid_err)
    po.update(runtime_s=polar_runtime, tie_points=polar_tp, reprojected_px=polar_rp,
              mean_reprojection_error_px=polar_err)
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
    (dict(polar_tp=1001, polar_rp=5001), "supported"),
    (dict(polar_tp=1001, polar_rp=5000), "not supported"),
    (dict(polar_tp=990, polar_rp=6000), "not supported"),
])
def test_more_tie_points_verdict(kw, verdict):
    assert _verdict(claims.scene_claims(_metrics(10, 10, **kw)), "C5").verdict == verdict


def test_scene_claims_not_tested_when_candidate_failed():
    m = _metrics(10, 10)
    m.methods[1].status = "failed"
    res = claims.scene_claims(m)
    assert {c.verdict for c in res} == {"not tested"}
    assert all("ours-polar did not succeed" in c.rationale for c in res)


def _evidence(printed, claim7, nan=0):
    case = dict(case="random", printed_eq3_max_err=printed, printed_eq3_nan=nan,
                printed_is_complement_max_err=1e-12, corrected_eq3_max_err=1e-12, claim7_max_err=claim7)
    return {"cases": [case], "samples_per_case": 1000}


def test_equation_verdicts():
    c1, c2 = claims.equation_claims(_evidence(1.5, 0.0), "")
    assert (c1.verdict, c2.verdict) == ("not supported", "supported")
    c1, c2 = claims.equation_claims(_evidence(1e-12, 0.3), "")
    assert (c1.verdict, c2.verdict) == ("supported", "not supported")
    c1, _ = claims.equation_claims(_evidence(1e-12, 0.0, nan=3), "")
    assert c1.verdict == "not supported"                                     # undefined somewhere
    c1, c2 = claims.equation_claims(None, "derivations crashed")
    assert c1.verdict == c2.verdict == "not tested" and "derivations crashed" in c1.rationale


def _exp(cond_eu, cond_pa, corr_eu, corr_pa, rob_eu, rob_pa):
    row = lambda cond, corr: {"cond_JtJ": cond, "cond_JtJ_scaled": cond, "cond_schur": 1.0,
                              "cond_schur_scaled": 1.0, "mean_abs_point_corr": corr,
                              "max_abs_point_corr": corr, "error": ""}
    rob = lambda eu, pa: {"euclidean": {"rotation_error_deg": eu, "errors": []},
                          "parallax": {"rotation_error_deg": pa, "errors": []}}
    return {"conditioning": {"problem": "p", "params": {"euclidean": row(cond_eu, corr_eu),
                                                        "parallax": row(cond_pa, corr_pa)}},
            "robustness": {"problem": "p", "seeds_run": 1, "outliers": rob(*rob_eu),
                           "low_parallax": rob(*rob_pa)}}


def test_experiment_verdicts():
    bad, good = [5.0, 0.1, 9.0], [0.1, 0.2, 0.3]                     # success rates 1/3 and 3/3
    c6, c7, c8 = claims.experiment_claims(_exp(100, 50, 0.5, 0.2, (bad, good), (bad, good)), "")
    assert (c6.verdict, c7.verdict, c8.verdict) == ("supported", "supported", "supported")
    c6, c7, c8 = claims.experiment_claims(_exp(100, 95, 0.5, 0.6, (good, good), (good, bad)), "")
    assert (c6.verdict, c7.verdict, c8.verdict) == ("not supported", "not supported", "not supported")
    _, _, c8 = claims.experiment_claims(_exp(1, 1, 1, 1, (bad, good), (good, good)), "")
    assert c8.verdict == "inconclusive"                                      # mixed outcomes
    rate = next(f for f in c8.figures if f.key == "outliers_parallax").value
    assert rate == pytest.approx(1.0)
    assert all(c.verdict == "not tested" for c in claims.experiment_claims(None, "timed out"))
