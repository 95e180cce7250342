"""Georeferencing: CSV formats (strict readers), check points, the georeferenced adjustment."""

import dataclasses

import numpy as np
import pytest

from polarref.ba.adapter import problem_to_reconstruction
from polarref.core.errors import PolarrefError
from polarref.georef.adjust import georeference
from polarref.georef.formats import (GroundPoint, Mark, PosePrior, Role, load_georef,
                                     omega_phi_kappa_matrix, write_gcps, write_marks, write_priors)
from tests._prior_scene import block


def _georef(b, n_control=4, prior_sigma=2.0, seed=0):
    rng = np.random.default_rng(seed)
    names = [f"img_{i:05d}" for i in range(len(b.C))]
    pri = tuple(PosePrior(n, c + rng.normal(0, prior_sigma, 3), np.full(3, prior_sigma))
                for n, c in zip(names, b.C))
    pts = tuple(GroundPoint(f"G{k}", b.G[k], np.full(3, 0.01),
                            Role.CONTROL if k < n_control else Role.CHECK) for k in range(len(b.G)))
    marks = tuple(Mark(f"G{g}", names[c], uv + rng.normal(0, 0.5, 2))
                  for c, g, uv in zip(b.gcp_cam, b.gcp_idx, b.gcp_uv))
    return names, pri, pts, marks


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    b = block(0)
    names, pri, pts, marks = _georef(b)
    d = tmp_path_factory.mktemp("georef")
    write_priors(d / "priors.csv", pri)
    write_gcps(d / "gcps.csv", pts)
    write_marks(d / "marks.csv", marks)
    return b, names, d


def test_round_trip(files):
    b, names, d = files
    g = load_georef(names, d / "priors.csv", d / "gcps.csv", d / "marks.csv")
    assert len(g.priors) == len(names) and len(g.points) == 6 and len(g.of_role(Role.CHECK)) == 2
    assert np.abs(g.points[2].xyz - b.G[2]).max() < 1e-4


def _edit(d, name, old, new, tmp):
    text = (d / name).read_text().replace(old, new, 1)
    (tmp / name).write_text(text)
    return tmp / name


@pytest.mark.parametrize("case, match", [
    ("sigma", "must be > 0"), ("unknown_image", "unknown image"), ("unknown_id", "unknown ground point"),
    ("no_obs", "has no observations"), ("prior_image", "not in the image folder"),
    ("few_control", "at least 3 control points")])
def test_bad_input_is_one_line(files, tmp_path, case, match):
    b, names, d = files
    p, g, m = d / "priors.csv", d / "gcps.csv", d / "marks.csv"
    if case == "sigma":
        g = _edit(d, "gcps.csv", ",0.01,0.01,0.01,control", ",0.01,0,0.01,control", tmp_path)
    elif case == "unknown_image":
        m = _edit(d, "marks.csv", ",img_00001,", ",img_00099,", tmp_path)
    elif case == "unknown_id":
        m = _edit(d, "marks.csv", "G1,", "G9,", tmp_path)
    elif case == "no_obs":
        m = tmp_path / "marks.csv"
        m.write_text("\n".join(l for l in (d / "marks.csv").read_text().splitlines()
                               if not l.startswith("G5,")) + "\n")
    elif case == "prior_image":
        p = _edit(d, "priors.csv", "img_00002,", "other.jpg,", tmp_path)
    elif case == "few_control":
        p = None
        text = (d / "gcps.csv").read_text().replace("control", "check")
        g = tmp_path / "gcps.csv"
        g.write_text(text.replace("check", "control", 2))
    with pytest.raises(PolarrefError, match=match) as exc:
        load_georef(names, p, g, m)
    assert "\n" not in str(exc.value)


def test_omega_phi_kappa_nadir():
    assert np.allclose(omega_phi_kappa_matrix(180.0, 0.0, 0.0), np.diag([1.0, -1.0, -1.0]))


def _rec_and_georef(n_control=4, check_shift=None):
    b = block(0)
    names, pri, pts, marks = _georef(b, n_control)
    if check_shift is not None:
        k = n_control  # the first check point
        pts = pts[:k] + (dataclasses.replace(pts[k], xyz=pts[k].xyz + check_shift),) + pts[k + 1:]
    from polarref.georef.formats import Georef
    return b, problem_to_reconstruction(b.problem), Georef(pri, pts, marks)


def test_check_points_are_never_used_by_the_adjustment():
    """Moving a check point's given 3D value by 5 m changes no estimated parameter; its
    reported error changes by that amount."""
    out = []
    for shift in (None, np.array([5.0, 0.0, 0.0])):
        b, rec, g = _rec_and_georef(check_shift=shift)
        r = georeference(rec, g, "euclidean")
        poses = np.array([np.r_[im.cam_from_world.R.ravel(), im.cam_from_world.t]
                          for _, im in sorted(rec.images.items())])
        out.append((poses, rec.points_array()[1], r))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    assert out[1][2].check.max_3d > 4.0 > 0.3 > out[0][2].check.max_3d


@pytest.mark.parametrize("form", ["euclidean", "polar"])
def test_check_point_accuracy_by_variant(form):
    """GSD 5.6 cm. Control points: check points within 3 GSD. Priors only (2 m, 8 views): the
    datum error the priors' noise predicts is that of the similarity taking the true centres to
    the prior centres, evaluated at the check points (this draw's prediction); the adjustment's
    check-point RMSE must be within 1.5x of it (+ 3 GSD for the block's own error)."""
    b, rec, g = _rec_and_georef(n_control=4)
    r = georeference(rec, g, form)
    assert r.check.count == 2 and r.num_control == 4 and r.num_priors == 8
    assert 0.001 < r.check.rmse_horizontal < 3 * 0.056
    assert 0.001 < r.check.rmse_z < 3 * 0.056
    assert 0.3 < r.sigma0 < 3.0
    b, rec, g = _rec_and_georef(n_control=0)
    r = georeference(rec, g, form, use_control=False)
    assert r.num_control == 0 and r.check.count == 6
    from polarref.core.geometry import umeyama
    sim = umeyama(b.C, np.array([p.centre for p in g.priors]))
    predicted = float(np.sqrt(((sim.apply(b.G) - b.G) ** 2).sum(1).mean()))
    rmse_3d = float(np.sqrt(r.check.rmse_x**2 + r.check.rmse_y**2 + r.check.rmse_z**2))
    assert predicted / 1.5 - 3 * 0.056 < rmse_3d < 1.5 * predicted + 3 * 0.056


# ---- priors from scene.json (`sfm --priors scene`) -----------------------------------------------
def _scene_json(tmp_path, names, rotation_sigma_deg=1.0):
    import json

    from polarref.core.geometry import Rigid3
    from synth.config import PriorParams, preset
    from synth.priors import draw_priors

    b = block(0)
    cfg = preset("uav", "small", priors=PriorParams(position_sigma_m=2.0, vertical_sigma_m=4.0,
                                                    rotation_sigma_deg=rotation_sigma_deg, correlation=0.9))
    poses = [Rigid3(R, -R @ c) for R, c in zip(b.R, b.C)]
    pri = draw_priors(cfg, poses, np.zeros(3))
    views = [{"name": n} for n in names]
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"views": views, "priors": pri}))
    return b, pri, path


def test_scene_priors_read_back(tmp_path):
    from polarref.core.geometry import Rigid3
    from polarref.georef.scene_priors import read_scene_priors, scene_prior_params

    names = [f"{i:04d}.png" for i in range(8)]
    b, pri, path = _scene_json(tmp_path, names)
    got = read_scene_priors(path, names)
    assert [p.name for p in got] == names
    for p, v, R in zip(got, pri["views"], b.R):
        assert np.array_equal(p.centre, v["center"]) and np.array_equal(p.sigma, [2.0, 2.0, 4.0])
        assert np.allclose(p.R, Rigid3.from_quat(np.array(v["qvec"]), np.zeros(3)).R, atol=1e-12)
        # the drawn attitude error is ~1 deg: the prior is near, not at, the truth
        ang = np.degrees(np.arccos(np.clip((np.trace(p.R @ R.T) - 1) / 2, -1, 1)))
        assert 0.0 < ang < 6.0 and p.sigma_angle_deg == 1.0
    prm = scene_prior_params(path)
    assert (prm.position_sigma_m, prm.vertical_sigma_m, prm.correlation) == (2.0, 4.0, 0.9)
    # no attitude noise drawn: centre priors only
    _, _, path0 = _scene_json(tmp_path, names, rotation_sigma_deg=0.0)
    assert all(p.R is None for p in read_scene_priors(path0, names))


def test_scene_priors_bad_input(tmp_path):
    import json

    from polarref.georef.scene_priors import read_scene_priors

    names = [f"{i:04d}.png" for i in range(8)]
    _, _, path = _scene_json(tmp_path, names)
    with pytest.raises(PolarrefError, match="not in the image folder"):
        read_scene_priors(path, names[:-1])
    (tmp_path / "none.json").write_text(json.dumps({"views": [], "priors": None}))
    with pytest.raises(PolarrefError, match="no pose priors in this scene"):
        read_scene_priors(tmp_path / "none.json", names)
    with pytest.raises(PolarrefError, match="cannot read"):
        read_scene_priors(tmp_path / "missing.json", names)


# ---- the priors-only prediction (georef/predict.py) ----------------------------------------------
@pytest.mark.parametrize("rho", [0.0, 0.9])
def test_priors_only_prediction_matches_umeyama_monte_carlo(rho):
    """Equal isotropic sigmas: the weighted datum fit is Umeyama's similarity, solved here in
    closed form (nonlinear, independent of the linearised propagation) for 2000 seeded draws."""
    from polarref.core.geometry import umeyama
    from polarref.georef.predict import predict_priors_only

    b = block(0, rows=3, cols=5)
    sig = 2.0
    pred = predict_priors_only(b.C, np.full(b.C.shape, sig), b.G, correlation=rho)
    rng = np.random.default_rng(7)
    n = len(b.C)
    err = []
    for _ in range(2000):
        e = np.empty((n, 3))
        e[0] = rng.normal(0, 1, 3)
        for k in range(1, n):
            e[k] = rho * e[k - 1] + np.sqrt(1 - rho**2) * rng.normal(0, 1, 3)
        sim = umeyama(b.C, b.C + sig * e)
        err.append(sim.apply(b.G) - b.G)
    rm = np.sqrt((np.concatenate(err) ** 2).mean(0))
    # 2000 draws: the sample RMSE is within ~3 % of its expectation; 8 % leaves room for linearisation
    assert abs(rm[0] / pred.rmse_x - 1) < 0.08 and abs(rm[1] / pred.rmse_y - 1) < 0.08
    assert abs(rm[2] / pred.rmse_z - 1) < 0.08
    # the correlation matters: with rho = 0.9 the prediction is far above the independent one
    if rho:
        ind = predict_priors_only(b.C, np.full(b.C.shape, sig), b.G)
        assert pred.rmse_horizontal > 1.3 * ind.rmse_horizontal


# ---- the aerotriangulation table: markdown generated from the committed JSON ---------------------
def test_committed_aerotriangulation_markdown_is_generated_from_its_json():
    import json
    from pathlib import Path

    from polarref.georef.table import AerotriTable

    found = sorted(Path(__file__).resolve().parents[2].glob("reports/aerotriangulation-*/aerotriangulation.json"))
    assert found
    for path in found:
        table = AerotriTable.from_json(json.loads(path.read_text()))
        assert table.markdown() == path.with_suffix(".md").read_text(), path
        assert table.provenance.git_dirty is False, f"{path}: generated from a dirty tree"


def test_table_round_trip_and_verdicts():
    from polarref.georef.adjust import AerotriangulationRecord, CheckPointStats
    from polarref.georef.predict import PredictedRMSE
    from polarref.core.provenance import collect_record
    from polarref.georef.table import AerotriRow, AerotriTable, MonteCarlo, Variant

    def rec(h, z, n_ctl):
        return AerotriangulationRecord("polar", n_ctl, 10, 12, 0.2, 100, CheckPointStats(
            10, h / np.sqrt(2), h / np.sqrt(2), z, h, 1.0, 2.0), "g", 3)

    pred = PredictedRMSE(1.0, 1.0, 1.0, np.sqrt(2))
    t = AerotriTable("s", 12, (("polarref polar", 12),), 0.25, "layout", (2.0, 2.0, 4.0), 0.0, None, 0.5, 0.5, 0,
                     pred, MonteCarlo(5, 1, "polar", pred, pred),
                     (AerotriRow("polarref", Variant.PRIORS_ON, rec(1.4 * np.sqrt(2), 1.6, 0)),
                      AerotriRow("polarref", Variant.PRIORS_GCPS, rec(0.49, 0.76, 10))), ("n",),
                     collect_record(seeds={"x": 1}), 0.003)
    assert AerotriTable.from_json(t.to_json()) == t
    assert "sigma 2 / 2 / 4 m (x / y / z) + 0.3% of the range" in t.markdown()
    md = t.markdown()
    # 1.4x horizontal is within 1.5x, 1.6x in Z is not; 0.49 m = 1.96 GSD <= 2, 0.76 m = 3.04 GSD > 3
    assert "horizontal 1.40x, Z 1.60x the prediction (<= 1.5x): NOT met" in md
    assert "horizontal 1.96 GSD (<= 2), Z 3.04 GSD (<= 3): NOT met" in md
    # the pooled Monte Carlo is judged both ways: 1.00x is within 1.5x, 0.5x is not
    assert "horizontal 1.00x, Z 1.00x (within 1.5x either way: met" in md
    low = PredictedRMSE(0.5, 0.5, 0.5, 0.5 * np.sqrt(2))
    md = dataclasses.replace(t, monte_carlo=MonteCarlo(5, 1, "polar", low, pred)).markdown()
    assert "horizontal 0.50x, Z 0.50x (within 1.5x either way: NOT met" in md

    # parts run side by side (one form each) join into the same table
    from polarref.georef.table import merge_tables

    a = dataclasses.replace(t, rows=t.rows[:1], monte_carlo=None, notes=("n", "a"))
    b = dataclasses.replace(t, rows=t.rows[1:], notes=("n",))
    merged = merge_tables([a, b])
    assert merged.rows == t.rows and merged.monte_carlo == t.monte_carlo and merged.notes == ("n", "a")
    assert merged.registered == t.registered
    with pytest.raises(ValueError, match="differ in gsd_m"):
        merge_tables([a, dataclasses.replace(b, gsd_m=0.3)])
    with pytest.raises(ValueError, match="different commits"):
        merge_tables([a, dataclasses.replace(b, provenance=dataclasses.replace(b.provenance, git_commit="x"))])
    with pytest.raises(ValueError, match="same row twice"):
        merge_tables([a, dataclasses.replace(b, rows=t.rows)])


# ---- seeded layouts on rendered scenes: UAV ground points, comet landmarks ------------------------
@pytest.mark.slow
def test_comet_landmarks_are_seen_where_marked(comet_small_scene, tmp_path):
    """Every landmark: on the mesh, seen in >= 3 views, its marks within 5 sigma of the exact
    projection; the same seed gives the same files."""
    import os

    from polarref.georef.formats import read_gcps, read_marks
    from polarref.model.colmap import read_model
    from synth.comet_landmarks import landmark_layout
    from synth.scene import load_scene

    for name in ("images", "gt", "depth", "mesh.ply", "scene.json"):
        os.symlink(os.path.realpath(comet_small_scene / name), tmp_path / name)
    lm, obs = landmark_layout(tmp_path, 4, 4, 0.5, 0)
    first = (lm.read_text(), obs.read_text())
    gt = read_model(tmp_path / "gt")
    by = {im.name: im for im in gt.images.values()}
    pts = read_gcps(lm)
    marks = read_marks(obs, pts, list(by))
    V, _ = load_scene(tmp_path).mesh()
    cam = load_scene(tmp_path).polarref_camera()
    assert len(pts) == 8 and sum(p.role == Role.CONTROL for p in pts) == 4
    for p in pts:
        assert np.min(np.linalg.norm(V - p.xyz, axis=1)) < 1e-3  # a mesh vertex (CSV: 0.1 mm)
        mine = [m for m in marks if m.id == p.id]
        assert len(mine) >= 3
        for m in mine:
            uv = np.asarray(cam.project(by[m.image].cam_from_world.apply(p.xyz[None])))[0]
            assert np.abs(m.uv - uv).max() < 5 * 0.5 + 1e-3
    landmark_layout(tmp_path, 4, 4, 0.5, 0)
    assert (lm.read_text(), obs.read_text()) == first


def test_sfm_priors_scene_without_priors_is_one_line(uav_small_scene, tmp_path):
    """`sfm --priors scene` on a scene whose scene.json holds no priors: exit 1, one line, nothing
    written (refused before any work)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "polarref", "--no-progress", "sfm", str(uav_small_scene),
                        "--priors", "scene", "--out", str(out)], cwd=root, capture_output=True, text=True,
                       env={**__import__("os").environ, "PYTHONPATH": str(root)}, timeout=300)
    assert p.returncode == 1, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "no pose priors in this scene" in lines[0], p.stderr
    assert not out.exists()


def test_priors_only_verdict_against_the_realised_prediction():
    """With the realised prediction the rule compares the row with what this draw's errors
    predict (within 1.5x either way) and says how often one Monte Carlo draw alone exceeds 1.5x
    the expectation; a /2 table (without it) keeps its old line."""
    from polarref.core.provenance import collect_record
    from polarref.georef.adjust import AerotriangulationRecord, CheckPointStats
    from polarref.georef.predict import PredictedRMSE
    from polarref.georef.table import AerotriRow, AerotriTable, MonteCarlo, Variant

    def stats(h, z):
        return CheckPointStats(10, h / np.sqrt(2), h / np.sqrt(2), z, h, 1.0, 2.0)

    pred = PredictedRMSE(1.0, 1.0, 1.0, np.sqrt(2))
    draws = tuple(PredictedRMSE(1.0, 1.0, z, h) for h, z in ((1.0, 0.5), (2.2, 1.6), (1.2, 2.0), (3.0, 0.9)))
    row = AerotriRow("polarref", Variant.PRIORS_ON, AerotriangulationRecord(
        "polar", 0, 10, 12, 0.2, 100, stats(1.4 * np.sqrt(2), 1.6), "g", 3))
    t = AerotriTable("s", 12, (("polarref polar", 12),), 0.25, "scene", (2.0, 2.0, 4.0), 0.9, 1.0, 0.5, 0.5, 0,
                     pred, MonteCarlo(4, 1, "polar", pred, pred, draws), (row,), ("n",),
                     collect_record(seeds={"x": 1}), 0.0, PredictedRMSE(1.0, 1.0, 1.5, 1.5))
    assert AerotriTable.from_json(t.to_json()) == t
    md = t.markdown()
    # 1.4 sqrt(2) / 1.5 = 1.32x and 1.6 / 1.5 = 1.07x the realised prediction: met; 1.40x, 1.60x
    # the expectation; draws above 1.5x: horizontal 2.2, 3.0 > 2.12 (2 of 4), vertical 1.6, 2.0 (2 of 4)
    assert ("horizontal 1.32x, Z 1.07x what this draw's prior errors predict (within 1.5x either way): met; "
            "1.40x, 1.60x the expectation over draws (one draw alone exceeds 1.5x the expectation in 2 of 4 "
            "Monte Carlo redraws horizontally, 2 of 4 vertically)") in md
    assert "This draw's own prior errors through the same linear model" in md
    low = dataclasses.replace(t, realised=PredictedRMSE(3.0, 3.0, 3.0, 3.0 * np.sqrt(2)))
    assert "what this draw's prior errors predict (within 1.5x either way): NOT met" in low.markdown()
    old = t.to_json() | {"format": "polarref-aerotriangulation/2"}
    del old["realised"]
    old["monte_carlo"] = {k: v for k, v in old["monte_carlo"].items() if k != "per_draw"}
    md2 = AerotriTable.from_json(old).markdown()
    assert "horizontal 1.40x, Z 1.60x the prediction (<= 1.5x): NOT met" in md2
