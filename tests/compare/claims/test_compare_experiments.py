"""Claim experiments: the low-parallax problem, gauge-free errors, and tiny experiment runs."""

import json
import re
import time

import numpy as np
import pytest

from polarref.core import records
from polarref.compare.claims.experiment_records import Experiments
from polarref.compare.claims import scorecard as claims
from polarref.compare.claims import controlled as claims_experiments
from polarref.compare.claims import experiments
from polarref.compare.claims.experiment_problems import (bearing_errors_deg, depth_errors, low_parallax_problem,
                                                  observation_geometry, relative_rotation_errors_deg)
from polarref.core.geometry import Rigid3, so3_exp


@pytest.mark.parametrize("ratio", [0.3, 0.003])
def test_low_parallax_problem_geometry(ratio):
    init, truth = low_parallax_problem(6, 80, ratio, seed=3)
    g = observation_geometry(truth)
    assert g.behind_fraction == 0 and g.outside_fraction == 0
    C = np.array([im.cam_from_world.center for im in truth.images.values()])
    X = np.array([p.xyz for p in truth.points3D.values()])
    baseline = np.ptp(C[:, :2], axis=0).max()
    depth = X[:, 2].min()
    assert 0.5 * ratio < baseline / depth < 1.5 * ratio               # the parallax level asked for
    # observations of init: truth projections + 0.5 px noise, nothing else
    d = np.concatenate([init.images[i].keypoints - truth.images[i].keypoints for i in truth.images])
    assert 0.4 < d.std() < 0.6
    # initial rotations perturbed by ~0.1 deg per axis: same angular perturbation at every level
    rot = relative_rotation_errors_deg(init, truth)
    assert 0.03 < np.median(rot) < 0.5


def test_low_parallax_problem_deterministic_and_bad_input():
    a, _ = low_parallax_problem(4, 30, 0.03, seed=1)
    b, _ = low_parallax_problem(4, 30, 0.03, seed=1)
    assert all(np.array_equal(a.images[i].keypoints, b.images[i].keypoints) for i in a.images)
    with pytest.raises(ValueError, match="ratio"):
        low_parallax_problem(4, 30, 0.0, seed=1)
    with pytest.raises(ValueError, match="cameras"):
        low_parallax_problem(1, 30, 0.03, seed=1)


def test_errors_are_gauge_free():
    _, truth = low_parallax_problem(5, 40, 0.03, seed=0)
    moved = low_parallax_problem(5, 40, 0.03, seed=0)[1]
    s, Rg, tg = 3.7, so3_exp(np.array([0.3, -1.1, 0.4])), np.array([5.0, -2.0, 9.0])
    for im in moved.images.values():                   # world' = s Rg world + tg
        R, C = im.cam_from_world.R, im.cam_from_world.center
        R2, C2 = R @ Rg.T, s * Rg @ C + tg
        im.cam_from_world = Rigid3(R2, -R2 @ C2)
    for p in moved.points3D.values():
        p.xyz = s * Rg @ p.xyz + tg
    assert relative_rotation_errors_deg(moved, truth).max() < 1e-6
    assert bearing_errors_deg(moved, truth).max() < 1e-5
    # a 1 deg rotation of one camera shows up in the pairs with that camera, exactly
    im = moved.images[2]
    R = so3_exp(np.radians([1.0, 0, 0])) @ im.cam_from_world.R
    im.cam_from_world = Rigid3(R, -R @ im.cam_from_world.center)
    err = relative_rotation_errors_deg(moved, truth)
    assert np.sort(err)[-4:] == pytest.approx([1.0] * 4, abs=1e-6) and np.sort(err)[:-4].max() < 1e-6


def test_depth_errors_are_similarity_invariant_and_see_one_wrong_depth():
    from polarref.compare.claims.experiment_problems import similarity_draws

    init, truth = low_parallax_problem(5, 40, 0.003, seed=2)
    assert depth_errors(truth, truth).max() == 0.0
    base = depth_errors(init, truth)
    for T in similarity_draws(7, 3):                        # rotation, translation, scale; then units
        assert depth_errors(T.apply(init), truth) == pytest.approx(base, abs=1e-9)
    moved = T.apply(truth)
    pid = next(iter(moved.points3D))
    C = moved.images[int(moved.points3D[pid].track[0, 0])].cam_from_world.center
    # push one point 20 % farther from one of its cameras along that ray: only it moves, by log(1.2)
    # averaged over its track's cameras (the median over the points stays 0)
    moved.points3D[pid].xyz = C + 1.2 * (moved.points3D[pid].xyz - C)
    err = depth_errors(moved, truth)
    assert np.count_nonzero(err > 1e-9) == 1 and 0.0 < err[0] <= np.log(1.2) + 1e-9


def test_low_parallax_point_success_is_a_continuous_rate():
    """Issue 30: at low parallax the per-run rule succeeded always; the per-point rate is strictly
    between 0 and 1 on a level where depths are hard to recover, and 1 on an easy one."""
    from polarref.ba.synthetic import clone
    from polarref.compare.claims.robustness import point_rate

    rates = {}
    for ratio in (0.1, 0.002):
        init, truth, opts, check = experiments.robust_problem("low_parallax", ratio, 100, (6, 80))
        rec = clone(init)
        summ = experiments._adjust(rec, "euclidean", **opts)
        row = experiments._score(rec, truth, summ, check, 100)
        assert row.success and row.points_scored > 50
        rates[ratio] = point_rate(row)
        start = experiments._score_state(init, truth, 1.0, check, 100)
        assert point_rate(start) == 0.0                     # the start point fails the run rule
    assert rates[0.1] == 1.0 and 0.05 < rates[0.002] < 0.95


def test_tiny_experiments_shapes_and_finiteness(tmp_path):
    t0 = time.perf_counter()
    tim = experiments.timing(0, t0 + 100, seeds=2, repeats=2, size=(5, 40), real=False)
    cond = experiments.conditioning(0, seeds=2, size=(5, 30))
    rob = experiments.robustness(0, t0 + 100, seeds=2, ratios=(0.1, 0.001), fractions=(0.2,), outlier_size=(5, 40),
                                 parallax_size=(5, 40))
    params = experiments._params()
    for p in params:
        v = tim.params[p]
        assert v.error == "" and len(v.per_seed) == 2 and len(v.runs) == 4
        for r in v.per_seed:
            assert np.isfinite([r.wall_s, r.final_rms_px, r.rotation_error_deg]).all()
            assert 0.2 < r.final_rms_px < 0.8                     # converged to the 0.5 px noise floor
        assert len(cond.params[p].per_seed) == 2
        assert all(r.cond_JtJ_scaled is not None and r.cond_JtJ_scaled >= 1
                   for r in cond.params[p].per_seed)
        for unit in list(rob.outliers.values()) + list(rob.low_parallax.values()):
            assert len(unit[p].runs) == 2 and not unit[p].errors
    assert rob.seeds_run == 2 and set(rob.low_parallax) == {"0.1", "0.001"}
    # the reduced camera system does not depend on the point parameterization (same residuals,
    # same solution): XYZ and parallax landmarks agree; polar adds a view-angle residual
    schur = {p: cond.params[p].per_seed[0].cond_schur for p in params}
    assert schur["parallax"] == pytest.approx(schur["euclidean"], rel=1e-6)
    assert schur["polar"] != pytest.approx(schur["euclidean"], rel=1e-6)
    assert "fixed" in cond.gauge
    # the typed records round-trip through their JSON file exactly (what compare's job runner does)
    exp = Experiments(0, conditioning=cond, timing=tim, robustness=rob, wall_s={"timing": 1.5})
    back = records.load(Experiments, records.save(exp, tmp_path / "experiments.json"))
    assert back == exp and back.robustness.outliers["0.2"]["start"].runs[0].iterations is None
    assert json.loads((tmp_path / "experiments.json").read_text())["timing"]["params"]["polar"]["per_seed"][0]["seed"] == 0
    # the scorecard consumes this JSON: every claim gets a verdict and every placeholder a figure
    res = claims.scene_claims(_no_scene(), Experiments(0, timing=tim)) + claims.experiment_claims(
        Experiments(0, conditioning=cond, robustness=rob), "")
    for c in res:
        keys = {f.key for f in c.figures}
        assert set(re.findall(r"\{(\w+)\}", c.rationale)) <= keys, c.claim_id
    assert _verdicts(res)["C6"] in ("supported", "not supported", "inconclusive")
    assert "2 seeds" in [c for c in res if c.claim_id == "C3"][0].sample_size


def _no_scene():
    from test_compare_claims import _metrics
    m = _metrics(10, 10)
    m.methods[1].status = "failed"
    return m


def _verdicts(res):
    return {c.claim_id: c.verdict for c in res}


@pytest.mark.parametrize("param", ["euclidean", "parallax"])
def test_dense_jacobian_matches_loop_reference_and_gauge(param):
    """The vectorised J equals a plain loop over observations; the 7 gauge DoF are exactly removed."""
    from polarref.ba import BAOptions, problem_from_reconstruction
    from polarref.ba.problem import prepare
    from polarref.ba.solver import make_param
    from polarref.ba.synthetic import synthetic_reconstruction

    _, truth = synthetic_reconstruction(4, 20, seed=2, noise_px=0.0)
    problem = problem_from_reconstruction(truth)
    prepare(problem)
    obj = make_param(problem, BAOptions(param=param))
    J_full, dp = experiments._full_jacobian(problem, obj)
    P = problem.num_points
    A, nc = experiments.gauge_map(problem, J_full.shape[1])
    J = J_full @ A
    r, Jp, Jc = obj.evaluate(problem.R, problem.C, obj.init_points(), jac=True)
    M, k = r.shape
    N = problem.num_cameras
    ref = np.zeros((M * k, 6 * N + dp * P))
    for s, Js in enumerate(Jc):
        c0, c1 = obj.slot_cols[s]
        for m in range(M):
            ref[m * k:(m + 1) * k, 6 * obj.slot_cams[s][m] + c0:6 * obj.slot_cams[s][m] + c1] += Js[m]
    for m in range(M):
        q = problem.obs_pt[m]
        ref[m * k:(m + 1) * k, 6 * N + dp * q:6 * N + dp * (q + 1)] += Jp[m]
    free = np.concatenate([problem.cam_mask.reshape(-1), np.ones(dp * P, bool)])
    assert np.array_equal(J_full, ref) and np.array_equal(J, ref[:, free])
    assert nc == int(problem.cam_mask.sum()) == 6 * N - 7
    w_all = np.linalg.eigvalsh(ref.T @ ref)
    w_free = np.linalg.eigvalsh(J.T @ J)
    assert w_all[6] / w_all[-1] < 1e-9 < w_all[7] / w_all[-1]       # 7 gauge null directions ...
    assert w_free[0] / w_free[-1] > 1e-9                            # ... all removed by the mask
    # the frame-invariant "distance" gauge removes the same 7 and nothing else
    Ad, ncd = experiments.gauge_map(problem, J_full.shape[1], "distance")
    Jd = ref @ Ad
    assert ncd == nc and Jd.shape == J.shape
    w_d = np.linalg.eigvalsh(Jd.T @ Jd)
    assert w_d[0] / w_d[-1] > 1e-9 and np.allclose(Ad.T @ Ad, np.eye(Ad.shape[1]))


def test_start_point_fails_the_success_rule_at_every_level():
    """C8 can only come out either way if the start point itself fails (issue 12): at the scorecard's
    levels, with the scorecard's initial perturbation, the untouched start fails on every seed."""
    rob = experiments.robustness(0, time.perf_counter() + 100, seeds=2, outlier_size=(5, 40), parallax_size=(5, 40))
    units = list(rob.outliers.values()) + list(rob.low_parallax.values())
    assert len(units) == len(experiments.OUTLIER_FRACTIONS) + len(experiments.PARALLAX_RATIOS)
    for unit in units:
        start = unit["start"].runs
        assert len(start) == 2 and not any(r.success for r in start)
        assert all(r.rotation_error_deg > experiments.SUCCESS_ROT_DEG for r in start)
    for unit in rob.low_parallax.values():   # and BA gets somewhere from it (outliers on 5x40 may defeat it)
        eu, start = unit["euclidean"].runs, unit["start"].runs
        assert np.median([r.rotation_error_deg for r in eu]) < 0.5 * np.median([r.rotation_error_deg for r in start])
    for unit in rob.outliers.values():      # C5's counts: within [0, all observations]
        for r in unit["polar"].runs:
            assert 0 < r.tie_points <= 40 and 0 < r.inlier_observations <= 5 * 40
        # the start point (C5's baseline) keeps far fewer observations within 4 px than BA does
        start = np.mean([r.inlier_observations for r in unit["start"].runs])
        assert start < 0.5 * np.mean([r.inlier_observations for r in unit["euclidean"].runs])
    c8 = claims.experiment_claims(Experiments(0, robustness=rob), "")[-1]
    starts = [f.value for f in c8.figures if f.key.endswith("_start_success")]
    assert starts and max(starts) <= 0.2


# ---- issue 30: frame invariance ----------------------------------------------------------------

def _frames():
    from polarref.compare.claims.experiment_problems import similarity_draws
    return similarity_draws(5, 2)          # two random similarities, then metres -> millimetres


DECIDING = ("ratio6_block", "block_euclidean", "ratio7", "corr_pa_ray", "corr_eu_ray")


def test_c6_c7_verdicts_and_figures_do_not_depend_on_the_frame():
    """A C6/C7 problem rotated, translated and scaled (and in millimetres) gives the same verdicts
    and deciding figures to rounding; the old world-axis XYZ correlation does move (so the test
    would see a frame-dependent figure)."""
    base = claims_experiments.conditioning_claims(experiments.conditioning(0, seeds=2, size=(5, 30), units=False), "")
    fig = lambda c: {f.key: f.value for f in c.figures}                                    # noqa: E731
    moved_world = []
    for T in _frames():
        moved = claims_experiments.conditioning_claims(
            experiments.conditioning(0, seeds=2, size=(5, 30), frame=T, units=False, lean=True), "")
        for b, m in zip(base, moved):
            assert b.verdict == m.verdict, (b.claim_id, T.kind)
            fb, fm = fig(b), fig(m)
            for k in DECIDING:
                for key in (k, f"{k}_lo", f"{k}_hi"):
                    if key in fb:
                        assert fm[key] == pytest.approx(fb[key], rel=1e-6), (key, T.kind)
        moved_world.append(fig(moved[1])["corr_eu"])
    assert max(abs(w / fig(base[1])["corr_eu"] - 1) for w in moved_world) > 1e-3


def test_ray_frame_map_equals_measuring_parallax_in_the_anchored_frame():
    """The first-order map of the parallax covariance into the anchored frame equals rebuilding
    the Jacobian with the form's frame replaced by the anchored one (an independent computation)."""
    from polarref.ba import BAOptions, problem_from_reconstruction
    from polarref.ba.parallax import choose_anchors
    from polarref.ba.problem import prepare
    from polarref.ba.solver import make_param
    from polarref.ba.synthetic import synthetic_reconstruction
    from polarref.compare.claims.experiment_problems import anchored_frames

    _, truth = synthetic_reconstruction(5, 30, seed=1, noise_px=0.0)
    problem = problem_from_reconstruction(truth)
    prepare(problem)
    obj = make_param(problem, BAOptions(param="parallax"))
    J, dp = experiments._full_jacobian(problem, obj)
    A, nc = experiments.gauge_map(problem, J.shape[1], "distance")
    T = experiments.ray_frame_map(problem, obj, dp)
    cov = experiments.point_covariances(A.T @ J.T @ J @ A, nc, problem.num_points, dp)
    mapped = np.einsum("pji,pjk,pkl->pil", T, cov, T)
    main, assoc, _ = choose_anchors(problem)
    obj.frame = anchored_frames(problem.X, problem.C[main], problem.C[assoc])
    J2, _ = experiments._full_jacobian(problem, obj)
    direct = experiments.point_covariances(A.T @ J2.T @ J2 @ A, nc, problem.num_points, dp)
    assert np.allclose(mapped, direct, rtol=1e-7, atol=1e-12 * np.abs(direct).max())
    assert not np.allclose(cov, direct, rtol=1e-3)              # the solver's own frame differs
    # and the covariance through the reduced camera system equals the plain inverse
    H = A.T @ J2.T @ J2 @ A
    full = np.linalg.inv(H)[nc:, nc:].reshape(problem.num_points, dp, problem.num_points, dp)
    assert np.allclose(direct, full[np.arange(problem.num_points), :, np.arange(problem.num_points), :],
                       rtol=1e-6, atol=1e-12 * np.abs(direct).max())


def test_invariance_draws_rerun_every_controlled_experiment_in_its_frame():
    """Tiny experiments and 3 draws: each draw reran the conditioning seeds, one timing seed and one
    robustness cell; BA in a moved frame reaches the same accuracy (it is frame-equivariant), and
    every controlled claim gets a verdict per draw and the share that agrees."""
    from polarref.compare.claims import invariance as ci

    t0 = time.perf_counter()
    sizes = {"timing": (5, 40), "conditioning": (5, 30), "outliers": (5, 40), "low_parallax": (5, 40)}
    tim = experiments.timing(0, t0 + 100, seeds=2, repeats=1, size=(5, 40), real=False)
    cond = experiments.conditioning(0, seeds=2, size=(5, 30), units=False)
    rob = experiments.robustness(0, t0 + 100, seeds=1, ratios=(0.03,), fractions=(0.3,), outlier_size=(5, 40),
                                 parallax_size=(5, 40))
    inv = experiments.invariance(0, tim.seeds, rob.seeds_run, draws=2, conditioning_seeds=2, ratios=(0.03,),
                                 fractions=(0.3,), sizes=sizes)
    assert [d.frame.kind for d in inv.draws] == ["similarity", "similarity", "units"]
    assert [d.timing_seed for d in inv.draws] == [0, 1, 0] and not any(d.error for d in inv.draws)
    assert [(d.robust_half, d.robust_level) for d in inv.draws] == [("outliers", "0.3"), ("low_parallax", "0.03"),
                                                                    ("outliers", "0.3")]
    for d in inv.draws:
        assert len(d.conditioning.params["euclidean"].per_seed) == 2
        for p, row in d.timing.items():
            b = next(r for r in tim.params[p].per_seed if r.seed == d.timing_seed)
            assert row.final_rms_px == pytest.approx(b.final_rms_px, rel=1e-5)
            assert row.rotation_error_deg == pytest.approx(b.rotation_error_deg, rel=1e-2, abs=1e-4)
        base = getattr(rob, d.robust_half)[d.robust_level]
        for p, runs in d.robust.items():
            assert [r.success for r in runs.runs] == [r.success for r in base[p].runs]
    exp = Experiments(0, conditioning=cond, timing=tim, robustness=rob, invariance=inv)
    res = ci.apply(claims.experiment_claims(exp, "") + claims.scene_claims(_no_scene(), exp), exp)
    decided = [c for c in res if c.invariance is not None]
    assert {c.claim_id for c in decided} >= {"C6", "C7", "C8"}
    for c in decided:
        assert len(c.invariance.draws) == 3 and 0 <= c.invariance.agree_share <= 1
        agree = [d.verdict == c.invariance.base_verdict for d in c.invariance.draws]
        assert c.invariance.agree_share == pytest.approx(np.mean(agree))
        assert c.verdict == (c.invariance.base_verdict if all(agree) else ci.FRAME_DEPENDENT)
        assert "Frame invariance: 3 draws" in c.rationale


def test_real_timing_on_ladybug_or_skipped_with_reason(monkeypatch, tmp_path):
    from polarref.core.data import data_root

    ladybug = "bal/problem-49-7776-pre.txt"
    assert ladybug in experiments.REAL_PROBLEMS and "parallaxba_fakepile" in experiments.REAL_PROBLEMS
    with monkeypatch.context() as m:
        m.setenv("POLARREF_DATA", str(tmp_path))                 # an empty data folder: listed, not fatal
        gone = experiments.real_timing(time.perf_counter() + 100, problems=(ladybug,), repeats=1)
    assert gone[0].skipped.startswith("not in the reference data") and not gone[0].forms
    root = data_root()
    if root is None or not (root / ladybug).exists():
        pytest.skip("Ladybug-49 not in the reference data")
    (real,) = experiments.real_timing(time.perf_counter() + 100, problems=(ladybug,), repeats=2)
    assert real.description == "49 cameras, 7776 points, 31843 observations"
    for p in experiments.REAL_FORMS:
        run = real.forms[p]
        assert len(run.walls) == 2 and all(w > 0 for w in run.walls) and run.iterations >= 1
    # both forms reach the same pixel accuracy on it (polar adds a view-angle residual, so not the same cost)
    eu, po = real.forms["euclidean"].final_rms_px, real.forms["polar"].final_rms_px
    assert po == pytest.approx(eu, rel=0.05)


def test_real_problems_only_without_a_claims_budget():
    assert experiments._real_allowed(float("inf")) is True
    why = experiments._real_allowed(60.0)
    assert isinstance(why, str) and "claims budget (60 s)" in why
    tim = experiments.timing(0, time.perf_counter() + 100, seeds=1, repeats=1, size=(5, 40), real=why)
    assert [r.name for r in tim.real] == list(experiments.REAL_PROBLEMS)
    assert all(r.skipped == why and not r.forms for r in tim.real)
