"""run_sfm(export_final_ba=...) on the small UAV scene: the file holds the mapper's last global BA
(its result is the written model's poses), solving it again with our BA reproduces that result,
its ground truth is the scene's, and the export changes nothing of the run."""

from __future__ import annotations

import numpy as np
import pytest

from polarref.ba import solve
from polarref.ba.export_problem import read_problem_file, write_problem_file
from polarref.ba.loaders import load_problem
from polarref.core.geometry import umeyama
from polarref.io.scene_folder import discover
from polarref.sfm.pipeline import PRESETS, run_sfm


@pytest.fixture(scope="module")
def exported(uav_small_scene, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("export")
    gt = discover(uav_small_scene).read_ground_truth()
    on = run_sfm(uav_small_scene / "images", None, PRESETS["small"], gt=gt, export_final_ba=tmp / "final.npz")
    return on, tmp / "final.npz", gt


def _centres(rec, ids) -> np.ndarray:
    return np.stack([rec.images[int(i)].cam_from_world.center for i in ids])


def test_file_result_is_the_mappers_final_model(exported):
    on, path, _ = exported
    pf = read_problem_file(path)
    r = pf.result
    assert pf.options.param == "euclidean" and pf.options.loss == "trivial" and pf.options.refine == ()
    assert sorted(int(i) for i in r.image_ids) == sorted(on.reconstruction.images)  # every registered image
    C = _centres(on.reconstruction, r.image_ids)
    size = np.ptp(C, axis=0).max()
    assert np.abs(C - r.C).max() <= 1e-12 * size
    last = [b for b in on.report.ba if b.kind == "global"][-1]
    assert r.final_cost == last.summary.final_cost and r.iterations == last.summary.iterations


def test_resolving_reproduces_the_mappers_final_ba(exported):
    _, path, _ = exported
    pf = read_problem_file(path)
    problem, _ = load_problem(str(path))
    s = solve(problem, pf.options.ba_options())
    r = pf.result
    assert abs(s.final_cost - r.final_cost) <= 1e-8 * r.final_cost
    assert abs(s.initial_cost - r.initial_cost) <= 1e-8 * r.initial_cost
    assert np.array_equal(problem.image_ids, r.image_ids) and np.array_equal(problem.point_ids, r.point_ids)
    size = np.ptp(r.C, axis=0).max()
    assert np.abs(problem.C - r.C).max() <= 1e-6 * size
    assert np.abs(problem.X - r.X).max() <= 1e-6 * size


def test_round_trip_of_the_exported_file_is_bitwise(exported, tmp_path):
    _, path, _ = exported
    again = tmp_path / "again.npz"
    write_problem_file(again, read_problem_file(path))
    with np.load(path) as a, np.load(again) as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            x, y = a[k], b[k]
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), k


def test_truth_is_the_scenes_and_the_result_is_near_it(exported):
    _, path, gt = exported
    pf = read_problem_file(path)
    by_name = {im.name: im.cam_from_world for im in gt.images.values()}
    want = np.stack([by_name[n].center for n in pf.image_names])
    assert np.array_equal(pf.truth_C, want)
    # the SfM result, similarity-aligned to the truth: within 1 % of the scene, and not exact
    sim = umeyama(pf.result.C, pf.truth_C)
    err = np.linalg.norm(sim.apply(pf.result.C) - pf.truth_C, axis=1)
    size = np.ptp(pf.truth_C, axis=0).max()
    assert 0 < err.max() < 0.01 * size


def test_export_changes_nothing_of_the_run(exported, uav_small_scene):
    on, _, gt = exported
    off = run_sfm(uav_small_scene / "images", None, PRESETS["small"], gt=gt)
    assert sorted(off.reconstruction.images) == sorted(on.reconstruction.images)
    for i, im in off.reconstruction.images.items():
        a, b = im.cam_from_world, on.reconstruction.images[i].cam_from_world
        assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)
    assert [b.summary.final_cost for b in off.report.ba if b.summary] == \
        [b.summary.final_cost for b in on.report.ba if b.summary]


@pytest.mark.parametrize("name, needle", [("final.txt", "*.npz"), ("exists.npz", "exists")])
def test_cli_refuses_an_unwritable_export_before_any_work(uav_small_scene, tmp_path, capsys, name, needle):
    from polarref.cli import main

    (tmp_path / "exists.npz").write_bytes(b"")
    capsys.readouterr()
    rc = main(["-q", "sfm", str(uav_small_scene), "--out", str(tmp_path / "out"), "--export-final-ba",
               str(tmp_path / name)])
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 1 and len(lines) == 1 and needle in lines[0], lines
    assert not (tmp_path / "out").exists()
