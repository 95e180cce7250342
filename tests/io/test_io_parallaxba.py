"""ParallaxBA files: reading, the verified Euler convention, writing, bad input."""

import itertools
import json

import numpy as np
import pytest

from polarref.core.geometry import axis_rotation, so3_exp
from polarref.io import FormatError
from polarref.io.parallaxba import (cam_from_world_rotation, euler_from_cam_from_world,
                                    read_parallaxba, reprojection_errors, triangulate_dlt,
                                    write_parallaxba)


def test_counts_and_anchors(fakepile_files):
    p = fakepile_files
    assert (p.num_cameras, p.num_points, len(p.obs.uv)) == (47, 11318, 26050)
    assert np.array_equal(p.main_anchor, p.obs.image[p.track_start[:-1]])
    np.testing.assert_allclose(p.K, [[1071.18, 0, 646.269], [0, 1070.36, 350.651], [0, 0, 1]])
    np.testing.assert_allclose(p.R @ np.swapaxes(p.R, 1, 2), np.broadcast_to(np.eye(3), p.R.shape),
                               atol=1e-14)
    camera = p.camera()
    assert camera.model == "PINHOLE" and camera.fx == 1071.18


def _alternatives(euler):
    a, b, g = euler.T
    rot = {"x": (0, g), "y": (1, b), "z": (2, a)}
    for order in itertools.permutations("xyz"):
        for transpose in (False, True):
            for sign in (1, -1):
                R = np.eye(3)
                for ax in order:
                    R = R @ axis_rotation(rot[ax][0], sign * rot[ax][1])
                yield "".join(order), transpose, sign, np.swapaxes(R, 1, 2) if transpose else R


def test_verified_convention_beats_every_alternative(fakepile_files):
    p = fakepile_files
    e = reprojection_errors(p, triangulate_dlt(p))
    assert np.isfinite(e).all()  # every observation in front of its camera
    med = np.median(e)
    assert 0.3 < med < 1.0  # measured 0.632 px (initial, noisy demo poses)
    others = []
    for order, transpose, sign, R in _alternatives(p.euler):
        if np.allclose(R, p.R):
            continue
        ea = reprojection_errors(p, triangulate_dlt(p, R), R)
        others.append(np.nanmedian(ea))
    assert len(others) == 22  # 24 combinations, two of them equal to the verified one
    assert min(others) > 10 * med


def test_cameras_look_at_the_scene(fakepile_files):
    p = fakepile_files
    X = triangulate_dlt(p)
    to_scene = np.median(X, axis=0) - p.centers
    to_scene /= np.linalg.norm(to_scene, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.sum(p.R[:, 2, :] * to_scene, axis=1)))
    assert angle.max() < 35  # measured max 29 deg; the README read literally gives up to 163 deg
    a, b, g = p.euler.T
    literal = axis_rotation(0, g) @ axis_rotation(1, b) @ axis_rotation(2, a)
    assert np.degrees(np.arccos(np.sum(literal[:, 2, :] * to_scene, axis=1))).max() > 90


def test_euler_round_trip():
    rng = np.random.default_rng(0)
    R = so3_exp(rng.normal(size=(100, 3)))
    np.testing.assert_allclose(cam_from_world_rotation(euler_from_cam_from_world(R)), R, atol=1e-13)


def test_write_read_round_trip(fakepile_files, tmp_path):
    write_parallaxba(fakepile_files, tmp_path)
    again = read_parallaxba(tmp_path)
    for field in fakepile_files.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(again, field), getattr(fakepile_files, field))


def _folder(tmp_path, cam="0 0 0 0 0 0\n0.1 0 0 1 0 0\n", feat="2 0 1 2 1 3 4\n",
            K="100 0 50\n0 100 40\n0 0 1\n"):
    (tmp_path / "Cam.txt").write_text(cam)
    (tmp_path / "Feature.pmba").write_text(feat)
    (tmp_path / "intrinsic_matrix.txt").write_text(K)
    return tmp_path


@pytest.mark.parametrize("kwargs, fname, line, match", [
    (dict(cam="0 0 0 0 0 0\n0.1 0 0 1 0\n"), "Cam.txt", 2, "expected 6 values"),
    (dict(feat="2 0 1 2 1 3 4\n3 0 1 2 1 3 4\n"), "Feature.pmba", 2, "needs 10 fields"),
    (dict(feat="2 0 1 2 5 3 4\n"), "Feature.pmba", 1, "camera index out of range"),
    (dict(feat="2 0 1 2 0 3 4\n"), "Feature.pmba", 1, "listed twice"),
    (dict(feat="2 0 1 2 1 3 x\n"), "Feature.pmba", 1, "bad number"),
    (dict(K="100 0 50\n0 100\n0 0 1\n"), "intrinsic_matrix.txt", 2, "expected 3 K entries"),
])
def test_malformed_files_name_file_and_line(tmp_path, kwargs, fname, line, match):
    folder = _folder(tmp_path, **kwargs)
    with pytest.raises(FormatError, match=match) as info:
        read_parallaxba(folder)
    assert info.value.line == line and info.value.path.name == fname
    assert f"{fname}:{line}:" in str(info.value)


def test_minimal_good_folder(tmp_path):
    p = read_parallaxba(_folder(tmp_path))
    assert p.num_points == 1 and p.main_anchor.tolist() == [0]
    np.testing.assert_allclose(p.t[1], -p.R[1] @ [1, 0, 0])


def test_to_reconstruction(fakepile_files):
    from polarref.io.parallaxba import parallaxba_to_reconstruction
    rec = parallaxba_to_reconstruction(fakepile_files)
    assert len(rec.images) == 47 and rec.num_observations == 26050
    e_rec = np.sort(rec.reprojection_errors())
    e = np.sort(reprojection_errors(fakepile_files, triangulate_dlt(fakepile_files)))
    np.testing.assert_allclose(e_rec, e, rtol=1e-9, atol=1e-9)
    # main anchors survive: the first track element of each point is its main anchor image
    first = np.array([rec.points3D[j + 1].track[0, 0] - 1 for j in range(fakepile_files.num_points)])
    np.testing.assert_array_equal(first, fakepile_files.main_anchor)


def _numbered(tmp_path, n="90", xyz=None, K="100 0 50\n0 100 40\n0 0 1\n"):
    """A folder named like ParallaxBA's distributed datasets (README: Cam90.txt, Feature90.txt,
    cal90.txt): two cameras one unit apart along x, K fx = fy = 100, one point at (0.5, 0, 5)."""
    (tmp_path / f"Cam{n}.txt").write_text("0 0 0 0 0 0\n0 0 0 1 0 0\n")
    # u = 100 x / z + 50, v = 40: from C0 (0.5, 0, 5) -> 60; from C1 (-0.5, 0, 5) -> 40
    (tmp_path / f"Feature{n}.txt").write_text("2 0 60 40 1 40 40\n")
    (tmp_path / f"cal{n}.txt").write_text(K)
    if xyz is not None:
        (tmp_path / "XYZ.txt").write_text(xyz)
    return tmp_path


def test_distributed_naming_is_read(tmp_path):
    from polarref.io.parallaxba import find_parallaxba_files
    folder = _numbered(tmp_path)
    files = find_parallaxba_files(folder)
    assert (files.cam.name, files.feature.name, files.intrinsics.name, files.xyz) == (
        "Cam90.txt", "Feature90.txt", "cal90.txt", None)
    p = read_parallaxba(folder)
    assert (p.num_cameras, p.num_points, p.points) == (2, 1, None)
    np.testing.assert_allclose(triangulate_dlt(p), [[0.5, 0.0, 5.0]], atol=1e-9)


def test_distributed_naming_with_xyz_start_and_one_line_K(tmp_path):
    folder = _numbered(tmp_path, n="7", xyz="0.4 0.1 4.5\n", K="100 0 50 0 100 40 0 0 1\n")
    p = read_parallaxba(folder)
    np.testing.assert_array_equal(p.points, [[0.4, 0.1, 4.5]])
    np.testing.assert_array_equal(p.K, [[100, 0, 50], [0, 100, 40], [0, 0, 1]])
    e = reprojection_errors(p, p.points)
    assert e.min() > 1.0  # the start is not the solution: it comes from XYZ.txt, not DLT


def test_loader_and_cli_accept_the_distributed_naming(tmp_path):
    from polarref.ba.loaders import load_problem
    (tmp_path / "pb").mkdir()
    folder = _numbered(tmp_path / "pb", xyz="0.4 0.1 4.5\n")
    problem, truth = load_problem(str(folder))
    assert truth is None and problem.num_cameras == 2
    np.testing.assert_array_equal(problem.X, [[0.4, 0.1, 4.5]])
    from polarref.cli import main
    out = tmp_path / "ba.json"
    assert main(["ba", str(folder), "--param", "parallax", "--damping", "nielsen", "--out",
                 str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["solver"] == "lm" and data["damping"] == "nielsen"
    assert data["accepted_iterations"] + data["rejected_iterations"] == data["iterations"] >= 1
    assert all(r["damping"] > 0 and "gain" in r for r in data["trace"])
    # two views, one point (underdetermined): an exact fit from a start > 1 px off
    assert data["initial_rms_px"] > 1.0 and data["final_rms_px"] < 1e-3


@pytest.mark.parametrize("files, match", [
    ({"Cam1.txt": "0 0 0 0 0 0\n", "Feature1.txt": "1 0 1 2\n"}, "no cal1.txt"),
    ({"Cam1.txt": "", "Feature1.txt": "", "cal1.txt": "", "Cam2.txt": "", "Feature2.txt": ""},
     "several ParallaxBA problems"),
])
def test_distributed_naming_incomplete_or_ambiguous(tmp_path, files, match):
    from polarref.core.errors import PolarrefError
    from polarref.io.parallaxba import find_parallaxba_files
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(PolarrefError, match=match):
        find_parallaxba_files(tmp_path)


def test_xyz_with_wrong_count_names_the_file(tmp_path):
    folder = _numbered(tmp_path, xyz="0.4 0.1 4.5\n1 2 3\n")
    with pytest.raises(FormatError, match="2 points for 1 features") as info:
        read_parallaxba(folder)
    assert info.value.path.name == "XYZ.txt"
