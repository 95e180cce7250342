"""Synthetic scenes: ground-truth geometry, pycolmap recovery, determinism, resumability, bad input."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from polarref.cli import main
from polarref.core.geometry import Rigid3, rotation_angle_deg, umeyama
from polarref.peers.colmap_sfm import ColmapSfMOptions, run_sift_sfm
from synth.config import preset
from synth.conventions import cam_from_world_from_mitsuba, look_at, mitsuba_to_world, project
from synth.render import render_scene
from synth.scene import load_scene

sys.path.insert(0, str(Path(__file__).parents[1]))
from _synth_reproj import depth_reprojection  # noqa: E402

TINY = dict(views=3, width=96, height=72, spp=4)  # seconds to render; for file-level tests


# ---- conventions --------------------------------------------------------------------------
def test_mitsuba_pose_round_trip_and_look_at():
    rng = np.random.default_rng(0)
    for _ in range(20):
        center, target = rng.normal(0, 100, 3), rng.normal(0, 10, 3)
        pose = look_at(center, target, np.array([0.0, 0.0, 1.0]), rng.normal(0, 20))
        back = cam_from_world_from_mitsuba(mitsuba_to_world(pose))
        assert np.allclose(back.R, pose.R, atol=1e-12) and np.allclose(back.t, pose.t, atol=1e-9)
        uv, z = project(np.array([500.0, 500.0, 320.0, 240.0]), pose, target)
        assert np.allclose(uv, [320.0, 240.0], atol=1e-6) and z > 0  # the target is on the axis
        M = mitsuba_to_world(pose)
        assert np.allclose(M[:3, 2], (target - center) / np.linalg.norm(target - center))
        assert np.allclose(M[:3, 0], -pose.R[0])  # Mitsuba camera +x is COLMAP's -x


# ---- ground truth ---------------------------------------------------------------------------
@pytest.mark.parametrize("pair, min_covisible", [((0, 1), 0.5), ((4, 6), 0.4), ((7, 11), 0.15)])
def test_comet_depth_reprojects_between_views(comet_small_scene, pair, min_covisible):
    scene = load_scene(comet_small_scene)
    err, n_surface = depth_reprojection(scene, *pair)
    assert len(err) > min_covisible * n_surface  # 10-40 deg apart: much of the surface is shared
    assert np.mean(err) < 0.1 and np.percentile(err, 99) < 0.5, (np.mean(err), np.percentile(err, 99))
    bad, _ = depth_reprojection(scene, *pair, flip=True)  # the wrong camera-axis convention
    assert len(bad) < 0.6 * len(err) or np.mean(bad) > 0.3


def test_uav_depth_reprojects_between_views(uav_small_scene):
    scene = load_scene(uav_small_scene)
    lines_per = scene.meta["geometry"]["images_per_line"]
    for i, j in [(0, 1), (1, 2 * lines_per - 2)]:  # along track, across lines
        err, n_surface = depth_reprojection(scene, i, j)
        assert len(err) > 0.2 * n_surface
        assert np.mean(err) < 0.1 and np.percentile(err, 99) < 0.5


def test_gt_model_loads_in_pycolmap(comet_small_scene):
    import pycolmap

    scene = load_scene(comet_small_scene)
    rec = pycolmap.Reconstruction(str(scene.gt_dir))
    assert rec.num_images() == len(scene.views) == 12
    (cam,) = rec.cameras.values()
    assert cam.model.name == "PINHOLE" and np.allclose(cam.params, scene.camera.params)
    by_name = {v.name: v.cam_from_world for v in scene.views}
    for image in rec.images.values():
        m = image.cam_from_world().matrix()
        gt = by_name[image.name]
        assert rotation_angle_deg(m[:, :3], gt.R) < 1e-6 and np.allclose(m[:, 3], gt.t, atol=1e-6)
    V, F = scene.mesh()
    assert F.max() < len(V) and len(F) > 10_000
    # Depth maps sit on the mesh: back-projected pixels of view 0 lie within ~a pixel of vertices.
    d = scene.depth(0)
    assert d.shape == (scene.camera.height, scene.camera.width) and d.dtype == np.float32
    assert 0.1 < (d > 0).mean() < 0.95


# ---- SfM recovers the ground truth -------------------------------------------------------------
def run_pycolmap(scene, work: Path, max_features: int = 4000) -> dict:
    """pycolmap SIFT + incremental mapping with the GT intrinsics fixed, scored against the GT.

    Returns {"registered", "total", "rot_err_deg" (per registered image, after a similarity
    alignment of the camera centres), "center_err_rel" (mean centre error / scene radius)}.
    """
    run = run_sift_sfm(scene.root / "images", scene.polarref_camera(), work,
                       ColmapSfMOptions(max_num_features=max_features),
                       image_names=[v.name for v in scene.views])
    rec = run.reconstruction
    if rec is None:
        return {"registered": 0, "total": len(scene.views), "rot_err_deg": np.array([np.inf]),
                "center_err_rel": np.inf}
    gt = {v.name: v.cam_from_world for v in scene.views}
    names, est = [], []
    for image in rec.images.values():
        if image.has_pose:
            m = image.cam_from_world().matrix()
            names.append(image.name)
            est.append(Rigid3(m[:, :3], m[:, 3]))
    sim = umeyama(np.array([e.center for e in est]), np.array([gt[n].center for n in names]))
    aligned = [sim.transform_pose(e) for e in est]
    rot = np.array([rotation_angle_deg(a.R, gt[n].R) for a, n in zip(aligned, names)])
    cerr = np.array([np.linalg.norm(a.center - gt[n].center) for a, n in zip(aligned, names)])
    return {"registered": len(names), "total": len(scene.views), "rot_err_deg": rot,
            "center_err_rel": float(cerr.mean() / scene.radius)}


def test_pycolmap_recovers_small_comet(comet_small_scene, tmp_path):
    res = run_pycolmap(load_scene(comet_small_scene), tmp_path / "sfm")
    assert res["registered"] == res["total"] == 12
    assert 0.0 < np.mean(res["rot_err_deg"]) < 0.3, res["rot_err_deg"]
    assert res["center_err_rel"] < 0.02


@pytest.mark.slow
@pytest.mark.parametrize("scene_name", ["comet", "uav"])
def test_pycolmap_recovers_default_scene(scene_name, tmp_path):
    out = tmp_path / scene_name
    render_scene(scene_name, out, preset(scene_name, "default"))
    res = run_pycolmap(load_scene(out), tmp_path / "sfm", max_features=8000)
    assert res["registered"] == res["total"]
    assert 0.0 < np.mean(res["rot_err_deg"]) < 0.3, res["rot_err_deg"]


# ---- determinism and resumability ----------------------------------------------------------
def _images(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((root / "images").glob("*.png"))}


def test_same_seed_same_images_in_process_variant(tmp_path):
    cfg = preset("comet", "small", **TINY)
    a, b = render_scene("comet", tmp_path / "a", cfg), render_scene("comet", tmp_path / "b", cfg)
    assert a.rendered == b.rendered == 3
    ia, ib = _images(tmp_path / "a"), _images(tmp_path / "b")
    assert ia == ib  # bitwise (box filter: no scatter-order rounding in LLVM either)
    other = render_scene("comet", tmp_path / "c", preset("comet", "small", seed=1, **TINY))
    assert other.rendered == 3 and _images(tmp_path / "c") != ia


def test_same_seed_same_images_scalar_rgb(tmp_path):
    code = ("import sys; from synth.config import preset; from synth.render import render_scene; "
            f"render_scene('comet', sys.argv[1], preset('comet', 'small', views=2, width=64, height=48, spp=2))")
    env = dict(os.environ, POLARREF_MITSUBA_VARIANT="scalar_rgb")
    for name in ("a", "b"):
        subprocess.run([sys.executable, "-c", code, str(tmp_path / name)], env=env, check=True, timeout=300)
    import json

    assert json.loads((tmp_path / "a" / "scene.json").read_text())["mitsuba_variant"] == "scalar_rgb"
    assert _images(tmp_path / "a") == _images(tmp_path / "b") and len(_images(tmp_path / "a")) == 2


def test_resume_renders_only_missing_views(tmp_path):
    cfg = preset("comet", "small", **TINY)
    out = tmp_path / "s"
    first = render_scene("comet", out, cfg)
    before = _images(out)
    (out / "images" / "0001.png").unlink()
    second = render_scene("comet", out, cfg)
    assert (second.rendered, second.skipped) == (1, 2)
    assert _images(out) == before  # the re-rendered view is bitwise the same
    third = render_scene("comet", out, cfg)
    assert (third.rendered, third.skipped) == (0, 3) and first.rendered == 3
    assert not list(out.rglob("*.tmp"))


# ---- CLI and bad input ---------------------------------------------------------------------
def test_cli_renders_and_refuses_other_parameters(tmp_path, capsys):
    out = tmp_path / "cli"
    args = ["render", "comet", "--out", str(out), "--preset", "small", "--views", "2", "--width", "64",
            "--height", "48", "--spp", "2"]
    assert main(args) == 0
    assert "images/s" in capsys.readouterr().out
    before = _images(out)
    assert main(args[:-1] + ["3"]) == 1  # other spp: refused, nothing lost
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overwrite" in err[0]
    assert _images(out) == before


@pytest.mark.parametrize("extra", [["--width", "0"], ["--height", "-3"], ["--views", "x"], ["--spp", "0"]])
def test_cli_rejects_non_positive_sizes(tmp_path, extra):
    with pytest.raises(SystemExit) as exc:
        main(["render", "comet", "--out", str(tmp_path / "o"), *extra])
    assert exc.value.code == 2


def test_cli_rejects_unknown_scene(tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["render", "mars", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2


def test_cli_bad_mesh_and_unwritable_output(tmp_path, capsys):
    base = ["render", "comet", "--preset", "small", "--views", "2", "--width", "32", "--height", "24"]
    assert main([*base, "--out", str(tmp_path / "a"), "--mesh", str(tmp_path / "missing.obj")]) == 1
    assert "missing.obj" in capsys.readouterr().err
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not a mesh\n")
    assert main([*base, "--out", str(tmp_path / "b"), "--mesh", str(junk)]) == 1
    assert "junk.obj" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main([*base, "--out", str(blocker / "sub")]) == 1
    assert "not writable" in capsys.readouterr().err


def test_shape_model_mesh_renders(shared_data, tmp_path):
    mesh = shared_data / "comet67p" / "67P_geodesynets_raw_lp_916v_m.obj"
    cfg = preset("comet", "small", mesh=str(mesh), **TINY)
    render_scene("comet", tmp_path / "m", cfg)
    scene = load_scene(tmp_path / "m")
    assert scene.meta["geometry"]["shape"] == str(mesh.resolve())
    assert 2000.0 < scene.radius < 4000.0  # 67P: ~4.1 km long
    err, n = depth_reprojection(scene, 0, 1)
    assert n > 0.1 * 96 * 72 and np.mean(err) < 0.1
