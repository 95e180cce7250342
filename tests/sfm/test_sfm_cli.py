"""``polarref sfm`` on the command line: outputs, refusal to overwrite, bad input."""

import json

import cv2
import numpy as np
import pytest

from polarref.cli import main
from polarref.model.colmap import read_model


def _cam_arg(scene):
    from polarref.model import Reconstruction

    cam = next(iter(read_model(scene / "gt").cameras.values()))
    return f"{cam.model}:" + ",".join(repr(float(v)) for v in cam.params)


def test_cli_writes_model_and_refuses_existing_out(small_copy, tmp_path, monkeypatch, capsys):
    import pycolmap

    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    (small_copy / "images" / "broken.png").write_bytes(b"not a png at all")
    out = tmp_path / "out"
    assert main(["sfm", str(small_copy), "--out", str(out), "--ba", "colmap", "--preset", "small"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["status"] == "ok"
    assert m["num_images"] == 7 and m["metrics"]["registered_images"] == 6
    assert m["skipped_images"] == [{"name": "broken.png", "reason": "unreadable (OpenCV could not decode it)"}]
    assert 0 < m["metrics"]["mean_reprojection_error_px"] < 0.6 and m["metrics"]["tie_points"] > 100
    assert m["metrics"]["gt"]["num_matched"] == 6 and m["metrics"]["gt"]["rotation_error_deg_mean"] < 1.0
    rec = pycolmap.Reconstruction(str(out / "model"))
    assert rec.num_reg_images() == 6 and rec.num_points3D() == m["metrics"]["tie_points"]
    # default --format both: text and binary model plus a coloured PLY with one vertex per point
    assert {"cameras.txt", "images.bin", "points3D.bin", "points3D.ply"} <= {p.name for p in (out / "model").iterdir()}
    head = (out / "model" / "points3D.ply").read_bytes()[:300].decode("ascii", "replace")
    assert "binary_little_endian" in head and f"element vertex {m['metrics']['tie_points']}\n" in head
    before = (out / "metrics.json").read_bytes()
    (out / "notes.txt").write_text("mine")
    assert main(["sfm", str(small_copy), "--out", str(out)]) == 1
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "metrics.json").read_bytes() == before
    # --overwrite replaces our files but never deletes the user's; --camera overrides gt intrinsics
    assert main(["sfm", str(small_copy), "--out", str(out), "--ba", "colmap", "--preset", "small",
                 "--overwrite", "--camera", _cam_arg(small_copy)]) == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert json.loads((out / "metrics.json").read_text())["metrics"]["registered_images"] == 6


def test_cli_no_images(tmp_path, capsys):
    (tmp_path / "scene" / "images").mkdir(parents=True)
    assert main(["sfm", str(tmp_path / "scene"), "--out", str(tmp_path / "out"), "--camera", "PINHOLE:100,100,50,50"]) == 1
    err = capsys.readouterr().err
    assert "no images found" in err and "images" in err
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["status"] == "failed" and "no images" in m["error"]


def test_cli_unknown_camera_and_missing_dir(tmp_path, capsys):
    assert main(["sfm", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 1
    assert "scene folder not found" in capsys.readouterr().err
    d = tmp_path / "s" / "images"
    d.mkdir(parents=True)
    cv2.imwrite(str(d / "a.png"), np.zeros((20, 30, 3), np.uint8))
    cv2.imwrite(str(d / "b.png"), np.zeros((20, 30, 3), np.uint8))
    # no camera, no gt/, no EXIF (issue 19): the default camera with a warning, then the usual
    # one-line failure for blank images (no crash)
    assert main(["sfm", str(tmp_path / "s"), "--out", str(tmp_path / "o2")]) == 1
    assert "no image pair passed geometric verification" in capsys.readouterr().err
    m = json.loads((tmp_path / "o2" / "metrics.json").read_text())
    assert m["status"] == "failed"
    # invalid option values are usage errors (issue 31): argparse's exit 2, before any work
    for opt, value, out in (("--refine", "focal,skew", "o4"), ("--camera", "PINHOLE:1,2", "o3")):
        with pytest.raises(SystemExit) as exit_info:
            main(["sfm", str(tmp_path / "s"), "--out", str(tmp_path / out), opt, value])
        assert exit_info.value.code == 2
        assert opt in capsys.readouterr().err
        assert not (tmp_path / out).exists()


def test_cli_fewer_than_two_registrable_views(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    d = tmp_path / "s" / "images"
    d.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):  # independent noise: features but no geometrically consistent matches
        cv2.imwrite(str(d / f"{i}.png"), rng.integers(0, 256, (120, 160, 3)).astype(np.uint8))
    out = tmp_path / "out"
    rc = main(["sfm", str(tmp_path / "s"), "--out", str(out), "--camera", "PINHOLE:150,150,80,60"])
    assert rc == 1
    assert "no image pair passed geometric verification" in capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())  # partial outputs kept
    assert m["status"] == "failed" and m["num_images"] == 3 and m["runtime_s"]["features"] >= 0
