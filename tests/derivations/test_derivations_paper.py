"""The verdicts on the paper's Eq. 3-10: symbolic identities and numeric facts behind them."""

import numpy as np
import pytest

from derivations import paper, report


@pytest.fixture(scope="module")
def symbolic():
    return {c.name: c.holds for c in paper.symbolic_checks()}


def test_all_symbolic_identities_hold(symbolic):
    assert len(symbolic) == 9
    assert all(symbolic.values()), symbolic


def _random(n=20_000, seed=0):
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(-np.pi, np.pi, n)
    beta = rng.uniform(-np.pi / 2, np.pi / 2, n)
    e_y, e_x, e_z = rng.uniform(-np.pi, np.pi, (3, n))
    return alpha, beta, e_y, e_x, e_z


def test_printed_eq3_returns_the_complement_and_acos_fixes_it():
    alpha, beta, e_y, e_x, e_z = _random()
    theta = paper.truth_theta(alpha, beta, e_y, e_x, e_z)
    printed = paper.printed_eq3(alpha, beta, e_y, e_x)
    assert np.max(np.abs(printed - theta)) > 1.0  # as printed: wrong
    assert np.max(np.abs(printed - (np.pi / 2 - theta))) < 1e-9  # it is pi/2 - theta
    assert np.max(np.abs(paper.corrected_eq3(alpha, beta, e_y, e_x) - theta)) < 1e-9


def test_sigma1_must_be_minus_sigma2_not_a_constant():
    errs = paper.sigma1_trials(n=20_000)
    assert errs["-sigma_2"] < 1e-9
    assert min(errs["+1"], errs["-1"], errs["sigma_2"]) > 0.5


def test_printed_forms_fail_at_edge_cases():
    rng = np.random.default_rng(1)
    n = 5000
    alpha, beta = rng.uniform(-np.pi, np.pi, n), rng.uniform(-1.5, 1.5, n)
    zero = np.zeros(n)
    assert np.isnan(paper.corrected_eq3(alpha, beta, zero, zero)).all()  # e = 0: v is 0/0
    e_y = np.full(n, np.pi / 2)
    e_x = rng.uniform(-np.pi, np.pi, n)
    err = np.abs(paper.corrected_eq3(alpha, beta, e_y, e_x) - paper.truth_theta(alpha, beta, e_y, e_x, 0.0))
    assert np.nanmax(err) > 0.1  # tan of the rounded pi/2
    small = 10.0 ** rng.uniform(-12, -9, n)
    assert paper.printed_e(small, small).min() == 0.0  # Eq. 4 rounds the tilt away


def test_convention_trials_single_out_intrinsic_first_rotation_about_x():
    trials = paper.convention_trials(n=3000)
    working = {(t.first_axis, t.order, t.signs) for t in trials if t.best_max_err < 1e-8}
    assert working == {("x", "intrinsic", "+,-"), ("x", "intrinsic", "-,-")}
    for t in trials:
        if t.order == "extrinsic":
            assert t.claim7_max_err > 0.1 and t.azimuth_fix == ""
        else:
            assert t.claim7_max_err < 1e-12 and t.azimuth_fix


def test_case_evidence_and_report_render(monkeypatch):
    monkeypatch.setattr(paper, "N_MPMATH", 20)
    cases = paper.all_case_evidence(n=2000)
    by = {c.case: c for c in cases}
    assert max(c.stable_all_vs_mpmath_max_err for c in cases) < 1e-15
    assert max(c.generated_max_err for c in cases) < 1e-14
    assert by["e_x = e_y = 0"].printed_eq3_nan == 2000
    assert by["random"].corrected_eq3_max_err < 1e-9
    ev = report.Evidence("x", "y", paper.symbolic_checks(), cases, paper.sigma1_trials(n=2000),
                         paper.convention_trials(n=1000), [])
    text = report.render(ev)
    assert "CHECK FAILED" not in text
    assert "**does not hold as printed**" in text and "**Holds after correction**" in text
    assert '"case": "random"' in report.to_json(ev)
