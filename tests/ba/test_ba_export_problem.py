"""The exported-problem file (polarref.ba.export_problem): lossless round trip, the loaders, the
bench and `polarref ba` reading it, and one line for a broken file."""

from __future__ import annotations

import numpy as np
import pytest

from polarref.ba import solve
from polarref.ba.adapter import problem_from_reconstruction
from polarref.ba.export_problem import (FORMAT, ExportedOptions, MapperResult, ProblemFile, read_problem_file,
                                        write_problem_file)
from polarref.ba.loaders import load_problem
from polarref.ba.synthetic import synthetic_reconstruction
from polarref.camera import Camera
from polarref.cli import main


def _problem_file(seed: int = 3) -> ProblemFile:
    """A synthetic problem with two camera models, held cameras and points, intrinsics groups."""
    init, truth = synthetic_reconstruction(12, 150, seed=seed, rot_deg=0.3, point_sigma=0.05, center_sigma=0.05)
    p = problem_from_reconstruction(init)
    rng = np.random.default_rng(seed)
    cam0 = p.cameras[0]
    other = Camera("OPENCV", cam0.width, cam0.height, [*cam0.params[:4], -0.01, 0.002, 1e-4, -2e-4]
                   if len(cam0.params) == 4 else [600.5, 601.25, 320.1, 239.7, -0.01, 0.002, 1e-4, -2e-4])
    p.cameras = [cam0 if k % 3 else other for k in range(p.num_cameras)]
    p.cam_fixed = rng.random(p.num_cameras) < 0.2
    p.pt_fixed = rng.random(p.num_points) < 0.05
    p.camera_group = np.array([0 if k % 3 else 1 for k in range(p.num_cameras)], np.int64)
    names = tuple(f"img {k:03d}.png" for k in range(p.num_cameras))  # a space: names are not split
    tR = np.stack([truth.images[int(i)].cam_from_world.R for i in p.image_ids])
    tC = np.stack([truth.images[int(i)].cam_from_world.center for i in p.image_ids])
    tR[1] = np.nan
    tC[1] = np.nan
    res = MapperResult(12.5, 3.25, 4, p.image_ids.copy(), p.R.copy(), p.C.copy(), p.point_ids.copy(), p.X.copy())
    return ProblemFile(p, ExportedOptions("parallax", "huber", 7, 1e-7, ("focal",)), res, names, tR, tC, "test")


def _bits(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    return a.view(np.uint8) if a.dtype.kind == "f" else a


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(_bits(a), _bits(b))


def test_round_trip_is_bitwise(tmp_path):
    pf = _problem_file()
    path = tmp_path / "p.npz"
    write_problem_file(path, pf)
    got = read_problem_file(path)
    a, b = pf.problem, got.problem
    for name in ("R", "C", "X", "cam_fixed", "pt_fixed", "image_ids", "point_ids", "camera_group"):
        assert _same(getattr(a, name), getattr(b, name)), name
    for name in ("image", "point", "uv"):
        assert _same(getattr(a.obs, name), getattr(b.obs, name)), name
    assert b.cameras == a.cameras and {c.model for c in b.cameras} == {"OPENCV", a.cameras[1].model}
    assert got.options == pf.options and got.image_names == pf.image_names and got.source == "test"
    assert _same(got.truth_R, pf.truth_R) and _same(got.truth_C, pf.truth_C)
    for name in ("image_ids", "R", "C", "point_ids", "X"):
        assert _same(getattr(got.result, name), getattr(pf.result, name)), name
    assert (got.result.initial_cost, got.result.final_cost, got.result.iterations) == (12.5, 3.25, 4)
    write_problem_file(tmp_path / "q.npz", got)  # written again: the same bytes
    assert (tmp_path / "q.npz").read_bytes() == path.read_bytes()


def test_loader_gives_the_problem_and_its_truth(tmp_path):
    pf = _problem_file()
    path = tmp_path / "p.npz"
    write_problem_file(path, pf)
    problem, truth = load_problem(str(path))
    assert _same(problem.X, pf.problem.X) and _same(problem.obs.uv, pf.problem.obs.uv)
    ids = [int(i) for i in pf.problem.image_ids]
    assert sorted(truth.images) == sorted(ids[:1] + ids[2:])  # the image without ground truth left out
    k = 5
    assert np.allclose(truth.images[ids[k]].cam_from_world.center, pf.truth_C[k], rtol=0, atol=1e-12)
    assert truth.images[ids[k]].name == pf.image_names[k]


def test_solving_the_loaded_problem_equals_solving_the_original(tmp_path):
    pf = _problem_file(seed=5)
    pf = ProblemFile(pf.problem, ExportedOptions("euclidean", "trivial", 20, 1e-6, ()), None, pf.image_names,
                     pf.truth_R, pf.truth_C, "test")
    path = tmp_path / "p.npz"
    write_problem_file(path, pf)
    loaded, _ = load_problem(str(path))
    ref = pf.problem.copy()
    s_ref = solve(ref, pf.options.ba_options())
    s = solve(loaded, read_problem_file(path).options.ba_options())
    assert s_ref.final_cost < 0.1 * s_ref.initial_cost  # it did solve something (a third of the cameras mis-modelled)
    assert s.final_cost == s_ref.final_cost and np.array_equal(loaded.C, ref.C)


@pytest.mark.parametrize("damage, needle", [
    (lambda b: b[: len(b) // 2], "not a readable BA problem file"),
    (lambda b: b"PK\x03\x04 not a zip at all", "not a readable BA problem file"),
])
def test_broken_file_is_one_line_and_nonzero(tmp_path, capsys, damage, needle):
    good = tmp_path / "good.npz"
    write_problem_file(good, _problem_file())
    bad = tmp_path / "bad.npz"
    bad.write_bytes(damage(good.read_bytes()))
    capsys.readouterr()
    rc = main(["-q", "ba", str(bad), "--out", str(tmp_path / "out.json")])
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 1 and len(lines) == 1 and needle in lines[0] and str(bad) in lines[0], lines
    assert not (tmp_path / "out.json").exists()


def test_foreign_npz_and_other_version_are_refused(tmp_path, capsys):
    np.savez(tmp_path / "foreign.npz", R=np.eye(3))
    good = tmp_path / "good.npz"
    write_problem_file(good, _problem_file())
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    np.savez(tmp_path / "v2.npz", **{**arrays, "version": np.array(2)})
    for name, needle in (("foreign.npz", f"not a {FORMAT} file"), ("v2.npz", "version 2")):
        rc = main(["-q", "ba", str(tmp_path / name), "--out", str(tmp_path / "o.json")])
        lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert rc == 1 and len(lines) == 1 and needle in lines[0], lines


def test_polarref_ba_and_the_bench_read_it(tmp_path, capsys):
    from polarref.ba.options import BAOptions
    from polarref.ba.problem import prepare
    from polarref.bench.ba import run_bench

    path = tmp_path / "p.npz"
    write_problem_file(path, _problem_file())
    assert main(["-q", "ba", str(path), "--out", str(tmp_path / "o.json"), "--max-iterations", "5"]) == 0
    assert "euclidean: cost" in capsys.readouterr().out
    doc = run_bench([str(path)], tmp_path / "bench", BAOptions(max_iterations=5, kernels="numpy"), scipy_max_obs=0,
                    cold=False, only=("euclidean",))
    prepared = prepare(read_problem_file(path).problem)
    got = doc.problems[0]
    assert (got.num_cameras, got.num_points, got.num_observations) == (
        prepared.num_cameras, prepared.num_points, prepared.num_observations)


def test_bench_resolves_a_twin_problem_from_the_cache(tmp_path, monkeypatch):
    from polarref.bench.ba import _resolve, twin_problem_path
    from polarref.core.errors import PolarrefError

    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path))
    with pytest.raises(PolarrefError, match="scripts/twin_ba_export.py mappilot mappilot"):
        _resolve("twin-mappilot")
    path = twin_problem_path("mappilot")
    path.parent.mkdir(parents=True)
    write_problem_file(path, _problem_file())
    assert _resolve("twin-mappilot") == str(path) and str(tmp_path) in str(path)
    problem, _ = load_problem(_resolve("twin-mappilot"))
    assert problem.num_observations == _problem_file().problem.num_observations
