"""One scene-folder discovery for sfm, compare and dense: images/ or flat, gt/ or Strecha cameras."""

import cv2
import numpy as np
import pytest

from polarref.cli import main
from polarref.core.geometry import Rigid3
from polarref.io.scene_folder import IMAGE_SUFFIXES, discover


def _rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _strecha_folder(root, names=("0000.png", "0001.png", "0002.png")):
    """Tiny images plus ``gt_dense_cameras/<name>.camera`` with known world_from_cam R and centre C."""
    (root / "images").mkdir(parents=True)
    (root / "gt_dense_cameras").mkdir()
    truth = {}
    for k, name in enumerate(names):
        cv2.imwrite(str(root / "images" / name), np.zeros((16, 24, 3), np.uint8))
        R, C = _rotation(k), np.array([k, -2.0 * k, 0.5])
        rows = ["30 0 11.5", "0 31 7.5", "0 0 1", "0 0 0", *(" ".join(f"{v:.12f}" for v in r) for r in R),
                " ".join(f"{v:.12f}" for v in C), "24 16"]
        (root / "gt_dense_cameras" / f"{name}.camera").write_text("\n".join(rows) + "\n")
        truth[name] = (R, C)
    (root / "images" / "notes.txt").write_text("not an image")
    return truth


def test_strecha_folder_is_discovered_with_its_ground_truth(tmp_path):
    truth = _strecha_folder(tmp_path / "s")
    found = discover(tmp_path / "s")
    assert found.gt_kind == "strecha" and found.image_dir == tmp_path / "s" / "images"
    assert found.image_names == sorted(truth) and not found.rendered and found.mesh_path is None
    gt = found.read_ground_truth()
    assert sorted(im.name for im in gt.images.values()) == sorted(truth)
    for im in gt.images.values():
        R, C = truth[im.name]
        np.testing.assert_allclose(im.cam_from_world.center, C, atol=1e-9)
        np.testing.assert_allclose(im.cam_from_world.inverse().R, R, atol=1e-9)
    cam = next(iter(gt.cameras.values()))
    assert (cam.width, cam.height) == (24, 16)
    np.testing.assert_allclose(cam.params, [30, 31, 12.0, 8.0])       # principal point +0.5: corner origin


def test_flat_folder_without_ground_truth(tmp_path):
    for name in ("b.JPG", "a.png", "c.exr", "d.txt"):
        (tmp_path / name).write_bytes(b"x")
    found = discover(tmp_path)
    assert found.image_dir == tmp_path and found.image_names == ["a.png", "b.JPG"]
    assert found.gt_kind == "" and found.read_ground_truth() is None
    assert ".exr" not in IMAGE_SUFFIXES        # OpenCV cannot decode EXR here: not listed anywhere


def test_sfm_command_reads_strecha_ground_truth(tmp_path, monkeypatch, capsys):
    """`polarref sfm` on a Strecha folder scores against its .camera ground truth (it used to ignore it)."""
    truth = _strecha_folder(tmp_path / "s")
    seen = {}

    def fake_run_sfm(image_dir, out, cfg, camera=None, gt=None, **kw):
        seen["image_dir"], seen["gt"] = image_dir, gt
        raise RuntimeError("stop after the inputs")

    monkeypatch.setattr("polarref.sfm.pipeline.run_sfm", fake_run_sfm)
    assert main(["sfm", str(tmp_path / "s"), "--out", str(tmp_path / "out")]) != 0
    assert "stop after the inputs" in capsys.readouterr().err
    assert seen["image_dir"] == tmp_path / "s" / "images"
    assert seen["gt"] is not None and sorted(im.name for im in seen["gt"].images.values()) == sorted(truth)


def test_missing_folder_is_a_clear_error(tmp_path, capsys):
    assert main(["sfm", str(tmp_path / "absent"), "--out", str(tmp_path / "o")]) == 1
    assert "scene folder not found" in capsys.readouterr().err
