"""BAL reader/writer, published cost figures, and the mapping to COLMAP conventions."""

import numpy as np
import pytest

from polarref.io import FormatError
from polarref.model import Observations
from polarref.io.bal import (BALProblem, bal_cost, bal_residuals, bal_to_reconstruction,
                             read_bal, write_bal)


@pytest.mark.parametrize("name, cost, shape", [
    ("problem-49-7776-pre.txt", 8.509125e5, (49, 7776, 31843)),
    ("dubrovnik-3-7-pre.txt", 2.764220e3, (3, 7, 19)),
])
def test_published_initial_cost(shared_data, name, cost, shape):
    problem = read_bal(shared_data / "bal" / name)
    assert (problem.num_cameras, problem.num_points, problem.num_observations) == shape
    # the published figures have 7 significant digits
    assert bal_cost(problem) == pytest.approx(cost, rel=6e-7)


@pytest.mark.parametrize("name", ["problem-49-7776-pre.txt", "dubrovnik-3-7-pre.txt"])
def test_mapping_to_colmap_conventions_reproduces_bal_residuals(shared_data, name):
    problem = read_bal(shared_data / "bal" / name)
    rec = bal_to_reconstruction(problem)
    res = np.linalg.norm(bal_residuals(problem), axis=1)
    err = np.empty_like(res)
    for image_id, img in rec.images.items():
        camera = rec.cameras[img.camera_id]
        sel = problem.obs.image == image_id - 1
        X = np.array([rec.points3D[int(pid)].xyz for pid in img.point3D_ids]).reshape(-1, 3)
        err[sel] = np.linalg.norm(camera.project(img.cam_from_world.apply(X)) - img.keypoints, axis=1)
    # observations behind their camera (BAL frame P_z >= 0) are NaN through a COLMAP camera
    from polarref.core.geometry import so3_exp
    P_z = (np.einsum("kij,kj->ki", so3_exp(problem.rotvec)[problem.obs.image],
                     problem.points[problem.obs.point]) + problem.t[problem.obs.image])[:, 2]
    np.testing.assert_array_equal(np.isnan(err), P_z >= 0)
    ok = ~np.isnan(err)
    np.testing.assert_allclose(err[ok], res[ok], rtol=1e-9, atol=1e-9)
    assert rec.num_observations == problem.num_observations


def test_write_read_round_trip(shared_data, tmp_path):
    problem = read_bal(shared_data / "bal" / "dubrovnik-3-7-pre.txt")
    write_bal(problem, tmp_path / "copy.txt")
    again = read_bal(tmp_path / "copy.txt")
    for field in BALProblem.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(again, field), getattr(problem, field))


def test_residual_formula_by_hand():
    # one camera at the origin, looking down BAL's -z; a point 2 units in front
    problem = BALProblem(rotvec=np.zeros((1, 3)), t=np.zeros((1, 3)),
                         intrinsics=np.array([[100.0, 0.1, 0.01]]),
                         points=np.array([[0.4, -0.2, -2.0]]),
                         obs=Observations.from_arrays([0], [0], [[20.0, -10.0]]))
    p = np.array([0.2, -0.1])  # -P[:2] / P[2]
    n2 = p @ p
    expected = 100 * (1 + 0.1 * n2 + 0.01 * n2**2) * p - [20.0, -10.0]
    np.testing.assert_allclose(bal_residuals(problem)[0], expected, rtol=1e-15)
    assert bal_cost(problem) == pytest.approx(0.5 * expected @ expected, rel=1e-15)


GOOD = "1 1 1\n0 0 1.0 2.0\n" + "\n".join(["0"] * 6 + ["100", "0", "0"] + ["1", "2", "-3"]) + "\n"


@pytest.mark.parametrize("text, line, match", [
    ("", 1, "empty file"),
    ("1 1\n", 1, "expected 3 header fields"),
    ("1 1 1\n0 0 1.0\n", 2, "expected 'camera point x y'"),
    ("1 1 1\n0 x 1.0 2.0\n", 2, "bad number"),
    ("1 1 1\n0 5 1.0 2.0\n", 2, "out of range"),
    ("1 1 2\n0 0 1.0 2.0\n", 2, "file ends after 1 of 2 observations"),
    (GOOD.replace("100", "1o0"), 9, "bad number in parameters"),
    ("\n".join(GOOD.splitlines()[:-1]) + "\n", 13, "file ends after 11 of 12"),
    (GOOD + "7\n", 15, "unexpected data after the last point"),
    ("1 1 1\n0 0 1.0 2.0\n" + "0 " * 13 + "\n", 3, "more parameter values"),
])
def test_malformed_files_name_file_and_line(tmp_path, text, line, match):
    path = tmp_path / "broken.txt"
    path.write_text(text)
    with pytest.raises(FormatError, match=match) as info:
        read_bal(path)
    assert info.value.line == line and str(path) in str(info.value)
    assert f"broken.txt:{line}:" in str(info.value)


def test_good_minimal_file_and_missing_file(tmp_path):
    path = tmp_path / "ok.txt"
    path.write_text(GOOD)
    problem = read_bal(path)
    assert problem.points.tolist() == [[1.0, 2.0, -3.0]]
    with pytest.raises(FormatError, match="file not found"):
        read_bal(tmp_path / "missing.txt")
