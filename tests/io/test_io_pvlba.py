"""PVL-BA four-file problems and the BlocksExchange XML conversion."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from polarref.core.geometry import so3_exp
from polarref.io import FormatError
from polarref.io.pvlba import (BrownDistortion, pvl_euler_from_rotation, read_blocks_exchange,
                               read_pvlba, rotation_from_pvl_euler, write_pvlba)
from polarref.model.colmap import to_pycolmap


@pytest.fixture(scope="module")
def sample_xml(shared_data):
    return shared_data / "pvl_ba_bench_sample" / "sample_at.xml"


def _raw_xml(path):
    """Independent parse: per measurement (X, R, C, u, v) and the photogroup intrinsics."""
    root = ET.parse(path).getroot()
    pg = root.find("Block/Photogroups/Photogroup")
    f = float(pg.findtext("FocalLengthPixels"))
    pp = np.array([float(pg.findtext("PrincipalPoint/x")), float(pg.findtext("PrincipalPoint/y"))])
    dist = {k: float(pg.findtext(f"Distortion/{k}")) for k in ("K1", "K2", "K3", "P1", "P2")}
    poses = {}
    for ph in pg.findall("Photo"):
        R = np.array([[float(ph.findtext(f"Pose/Rotation/M_{i}{j}")) for j in range(3)]
                      for i in range(3)])
        C = np.array([float(ph.findtext(f"Pose/Center/{a}")) for a in "xyz"])
        poses[int(ph.findtext("Id"))] = (R, C)
    rows = []
    for tp in root.iter("TiePoint"):
        X = np.array([float(tp.findtext(f"Position/{a}")) for a in "xyz"])
        for m in tp.findall("Measurement"):
            R, C = poses[int(m.findtext("PhotoId"))]
            rows.append((R @ (X - C), float(m.findtext("x")), float(m.findtext("y"))))
    Xc = np.array([r[0] for r in rows])
    uv = np.array([r[1:] for r in rows])
    return Xc, uv, f, pp, dist, poses


def test_xml_conversion_and_initial_error(sample_xml):
    p = read_blocks_exchange(sample_xml)
    assert (p.num_images, p.num_points, len(p.obs.uv)) == (8, 30, 105)
    e = p.reprojection_errors()
    # measured: mean 0.482 px, RMS 0.567 px, max 2.05 px (undistorted, stored tie points)
    assert 0.4 < e.mean() < 0.55 and 0.5 < np.sqrt(np.mean(e**2)) < 0.65 and e.max() < 2.5
    _, _, _, _, _, poses = _raw_xml(sample_xml)
    R_xml = np.array([poses[k][0] for k in sorted(poses)])
    np.testing.assert_allclose(p.R, R_xml, atol=1e-12)  # photo ids are in file order here


def test_contextcapture_tangential_naming_is_verified(sample_xml):
    Xc, uv, f, pp, d, _ = _raw_xml(sample_xml)
    xy = Xc[:, :2] / Xc[:, 2:]
    errs = {}
    for name, (p1, p2) in {"cc": (d["P1"], d["P2"]), "opencv": (d["P2"], d["P1"])}.items():
        dist = BrownDistortion(d["K1"], d["K2"], d["K3"], p1, p2)
        errs[name] = np.linalg.norm(f * dist.distort(xy)[0] + pp - uv, axis=1).mean()
    none = np.linalg.norm(f * xy + pp - uv, axis=1).mean()
    assert errs["cc"] == pytest.approx(0.482, abs=0.005)
    assert errs["opencv"] > 1.5 * errs["cc"] and none > 20 * errs["cc"]


def test_brown_undistort_inverts_distort_and_jacobian():
    dist = BrownDistortion(0.17, -0.44, 0.23, 5.6e-4, 1.6e-4)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, (200, 2))
    xd, J = dist.distort(xy)
    np.testing.assert_allclose(dist.undistort(xd), xy, atol=1e-13)
    h = 1e-7
    Jn = np.stack([(dist.distort(xy + [h, 0])[0] - dist.distort(xy - [h, 0])[0]) / (2 * h),
                   (dist.distort(xy + [0, h])[0] - dist.distort(xy - [0, h])[0]) / (2 * h)], -1)
    np.testing.assert_allclose(J, Jn, atol=1e-7)


def test_pvl_rotation_is_a_rotation_and_round_trips():
    rng = np.random.default_rng(1)
    R = so3_exp(rng.normal(size=(200, 3)))
    np.testing.assert_allclose(rotation_from_pvl_euler(pvl_euler_from_rotation(R)), R, atol=1e-13)
    Re = rotation_from_pvl_euler(rng.uniform(-3, 3, (50, 3)))
    np.testing.assert_allclose(Re @ np.swapaxes(Re, 1, 2), np.broadcast_to(np.eye(3), Re.shape),
                               atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(Re), 1, atol=1e-14)
    # the spec's angles: ex alone tilts about the camera x axis (R[7] = -sin ex)
    assert rotation_from_pvl_euler([0, 0.3, 0])[2, 1] == pytest.approx(-np.sin(0.3))
    # characterization: R = Rz(-ez) Rx(-ex) Ry(ey) (phi-omega-kappa, documented in the module)
    from polarref.core.geometry import axis_rotation
    ey, ex, ez = rng.uniform(-3, 3, (3, 20))
    np.testing.assert_allclose(rotation_from_pvl_euler(np.stack([ey, ex, ez], -1)),
                               axis_rotation(2, -ez) @ axis_rotation(0, -ex)
                               @ axis_rotation(1, ey), atol=1e-14)


def test_four_file_round_trip(sample_xml, tmp_path):
    p = read_blocks_exchange(sample_xml)
    write_pvlba(p, tmp_path)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["Cam-8-.txt", "Feature.txt",
                                                          "XYZ.txt", "cal.txt"]
    q = read_pvlba(tmp_path)
    for field in ("K", "euler", "centers", "group", "points", "track_start"):
        np.testing.assert_array_equal(getattr(q, field), getattr(p, field))
    for field in ("image", "point", "uv"):
        np.testing.assert_array_equal(getattr(q.obs, field), getattr(p.obs, field))
    np.testing.assert_allclose(q.reprojection_errors(), p.reprojection_errors(), rtol=1e-12)


def test_incomplete_pose_photo_is_skipped(sample_xml, tmp_path):
    text = sample_xml.read_text(encoding="utf-8")
    first = text.index("<Rotation>")
    end = text.index("</Rotation>") + len("</Rotation>")
    broken = tmp_path / "skip.xml"
    broken.write_text(text[:first] + text[end:], encoding="utf-8")
    p = read_blocks_exchange(broken)
    dropped = text.count("<PhotoId>100001</PhotoId>")  # the first photo lost its rotation
    assert dropped > 0 and p.num_images == 7 and len(p.obs.uv) == 105 - dropped
    assert p.obs.image.max() <= 6 and 0.3 < p.reprojection_errors().mean() < 0.6


def _files(tmp_path, cal="100 0 50\n0 100 40\n0 0 1\n", cam="0 0 0 0 0 -5 1\n",
           xyz="0 0 0\n", feat="1 0 50 40\n", cam_name="Cam-1-.txt"):
    for name, text in (("cal.txt", cal), (cam_name, cam), ("XYZ.txt", xyz), ("Feature.txt", feat)):
        (tmp_path / name).write_text(text)
    return tmp_path


def test_minimal_four_files(tmp_path):
    p = read_pvlba(_files(tmp_path))
    assert p.reprojection_errors()[0] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("kwargs, fname, line, match", [
    (dict(cam="0 0 0 0 0 -5 2\n"), "Cam-1-.txt", 1, "camera_id 2 not in 1..1"),
    (dict(cam="0 0 0 0 0 -5\n"), "Cam-1-.txt", 1, "expected 7 values"),
    (dict(cam="0 0 0 0 0 -5 1\n0 0 0 0 0 -5 1\n"), "Cam-1-.txt", None, "says 1 images"),
    (dict(xyz="0 0\n"), "XYZ.txt", 1, "expected 3 coordinates"),
    (dict(feat="1 0 50 40\n2 0 50 40\n"), "Feature.txt", 2, "needs 7 fields"),
    (dict(feat="1 3 50 40\n"), "Feature.txt", 1, "image index"),
    (dict(cal="100 0 50\n0 100 40\n"), "cal.txt", 2, "3 rows per camera group"),
])
def test_malformed_four_files(tmp_path, kwargs, fname, line, match):
    with pytest.raises(FormatError, match=match) as info:
        read_pvlba(_files(tmp_path, **kwargs))
    assert info.value.path.name == fname and info.value.line == line


def test_malformed_xml_names_line(sample_xml, tmp_path):
    lines = sample_xml.read_text(encoding="utf-8").splitlines()
    bad = tmp_path / "bad.xml"
    bad.write_text("\n".join(lines[:30] + ["<oops>"] + lines[30:]), encoding="utf-8")
    with pytest.raises(FormatError, match="XML syntax error") as info:
        read_blocks_exchange(bad)
    assert info.value.line is not None and info.value.line >= 31
    text = sample_xml.read_text(encoding="utf-8")
    i = text.index("<FocalLengthPixels>")
    j = text.index("</FocalLengthPixels>") + len("</FocalLengthPixels>")
    nofocal = tmp_path / "nofocal.xml"
    nofocal.write_text(text[:i] + text[j:], encoding="utf-8")
    with pytest.raises(FormatError, match="lacks <FocalLengthPixels>") as info:
        read_blocks_exchange(nofocal)
    assert f"nofocal.xml:{text[:text.index('<Photogroup>')].count(chr(10)) + 1}:" in str(info.value)


def test_to_reconstruction_reprojects_the_same(sample_xml):
    p = read_blocks_exchange(sample_xml)
    rec = p.to_reconstruction()
    assert len(rec.images) == 8 and len(rec.points3D) == 30 and rec.num_observations == 105
    np.testing.assert_allclose(np.sort(rec.reprojection_errors()),
                               np.sort(p.reprojection_errors()), rtol=1e-9)
    pc = to_pycolmap(rec)  # and pycolmap accepts it
    assert pc.num_points3D() == 30
