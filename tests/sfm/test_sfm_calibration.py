"""Cameras from EXIF (polarref.sfm.calibration) and ``polarref sfm`` on a folder of JPEGs only."""

import json
import logging

import numpy as np
import pytest
from PIL import Image

from polarref.cli import main
from polarref.core.errors import PolarrefError
from polarref.sfm.calibration import DEFAULT_FOCAL_FACTOR, cameras_from_exif, read_exif
from polarref.model.colmap import read_model

DIAG_35MM = 43.27  # COLMAP: f_px = f35 / 43.27 mm (the 36x24 mm diagonal) * image diagonal


def _jpeg(path, size=(64, 48), make=None, model=None, f35=None, seed=0):
    rgb = (np.random.default_rng(seed).random((size[1], size[0], 3)) * 255).astype(np.uint8)
    kw = {}
    if make is not None:
        ex = Image.Exif()
        ex[0x010F], ex[0x0110] = make, model
        if f35 is not None:
            ex.get_ifd(0x8769)[0xA405] = f35
        kw["exif"] = ex
    Image.fromarray(rgb).save(path, quality=95, **kw)
    return path


def test_read_exif_focal_from_35mm_equivalent(tmp_path):
    e = read_exif(_jpeg(tmp_path / "a.jpg", make="Acme", model="One", f35=28))
    assert (e.make, e.model) == ("Acme", "One")
    assert e.focal_px == pytest.approx(28 / DIAG_35MM * np.hypot(64, 48), rel=1e-9)
    assert read_exif(_jpeg(tmp_path / "b.jpg")).focal_px is None


def test_camera_grouping_modes_and_default_focal(tmp_path, caplog):
    p = [_jpeg(tmp_path / "0.jpg", make="Acme", model="One", f35=28),
         _jpeg(tmp_path / "1.jpg", make="Acme", model="One", f35=28),
         _jpeg(tmp_path / "2.jpg", make="Other", model="Two", f35=50),
         _jpeg(tmp_path / "3.jpg")]
    sizes = [(64, 48)] * 4
    with caplog.at_level(logging.INFO):
        cams, idx, src = cameras_from_exif(p, sizes)
    assert idx.tolist() == [0, 0, 1, 2] and src == ["exif", "exif", "default"]
    assert cams[1].fx == pytest.approx(50 / DIAG_35MM * 80.0)
    assert cams[2].fx == pytest.approx(DEFAULT_FOCAL_FACTOR * 64)
    assert cams[0].model == "SIMPLE_RADIAL" and cams[0].principal_point.tolist() == [32.0, 24.0]
    warnings = [r for r in caplog.records if "no EXIF focal length" in r.getMessage()]
    assert len(warnings) == 1 and "3.jpg" in warnings[0].getMessage()
    cams, idx, _ = cameras_from_exif(p, sizes, "single")
    assert idx.tolist() == [0, 0, 0, 0] and len(cams) == 1
    assert cams[0].fx == pytest.approx(28 / DIAG_35MM * 80.0)  # median of 28, 28, 50 mm
    assert cameras_from_exif(p, sizes, "per-image")[1].tolist() == [0, 1, 2, 3]
    with pytest.raises(PolarrefError, match="different sizes"):
        cameras_from_exif(p, sizes[:3] + [(48, 64)], "single")


@pytest.fixture
def jpeg_scene(request, tmp_path):
    """The small comet views as JPEGs with an EXIF block (35 mm equivalent 35 mm: about 16 %
    short of the true focal length), except view 3 which has no EXIF; no gt/, nothing else."""
    try:
        src = request.getfixturevalue("comet_small_scene")
    except (ImportError, ModuleNotFoundError) as exc:
        pytest.skip(f"comet_small_scene unavailable: {exc}")
    from polarref.model import Reconstruction

    gt = read_model(src / "gt")
    dst = tmp_path / "photos"
    dst.mkdir()
    for k, p in enumerate(sorted((src / "images").iterdir())):
        im = Image.open(p).convert("RGB")
        kw = {}
        if k != 3:
            ex = Image.Exif()
            ex[0x010F], ex[0x0110] = "PolarrefCam", "Synth 1"
            ex.get_ifd(0x8769)[0xA405] = 35
            kw["exif"] = ex
        im.save(dst / f"{p.stem}.jpg", quality=95, **kw)
    return dst, next(iter(gt.cameras.values()))


def test_sfm_on_exif_jpegs_registers_all_and_refines_camera(jpeg_scene, tmp_path, monkeypatch,
                                                            capsys, caplog):
    folder, gt_cam = jpeg_scene
    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "out"
    with caplog.at_level(logging.INFO):
        assert main(["sfm", str(folder), "--out", str(out), "--preset", "small"]) == 0
    assert sum("no EXIF focal length" in r.getMessage() for r in caplog.records) == 1
    m = json.loads((out / "metrics.json").read_text())
    assert m["status"] == "ok" and m["metrics"]["registered_images"] == 12
    assert m["refine"] == ["focal", "dist"]
    exif, default = m["cameras"]
    assert (exif["source"], exif["num_images"]) == ("exif", 11)
    assert (default["source"], default["num_images"]) == ("default", 1)
    f_gt = gt_cam.fx
    # the EXIF start is > 10 % off (baseline fails); the refined focal length is within 2 %
    assert abs(exif["initial"][0] / f_gt - 1) > 0.10
    assert abs(exif["refined"][0] / f_gt - 1) < 0.02
    assert exif["refined"][1:3] == exif["initial"][1:3]  # principal point held (COLMAP default)
    assert m["metrics"]["mean_reprojection_error_px"] < 0.5
    # intrinsics are refined only in global BAs with >= 10 registered images, never in local BA
    for b in m["ba"]:
        refined = "intrinsics" in b
        assert refined == (b["kind"] == "global" and b["num_registered"] >= 10), b["kind"]
    assert any("intrinsics" in b for b in m["ba"])
    text = capsys.readouterr().out
    assert "camera 1 (exif, 11 images): refined SIMPLE_RADIAL f=" in text
