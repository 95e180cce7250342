"""Property tests: random byte mutations of valid BAL, COLMAP text, ParallaxBA and PVL-BA files
give a PolarrefError naming the file, or a valid problem; never another exception.

Each reader is driven through ``load_problem``, the path ``polarref ba`` takes (reading and the
conversion to a BA problem), with a bounded, derandomized number of examples so CI is
deterministic.
"""

import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from polarref.ba.loaders import load_problem
from polarref.core.errors import PolarrefError

SETTINGS = settings(max_examples=150, derandomize=True, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])

BAL = ("2 3 4\n0 0 -10.5 3.25\n1 0 12.0 -4.0\n0 1 5.5 6.5\n1 2 -7.0 1.0\n"
       + "\n".join(["0.01", "-0.02", "0.03", "0.1", "0.2", "-5", "500", "1e-7", "0",
                    "-0.01", "0.02", "0.01", "1.1", "-0.2", "-5.5", "480", "0", "0",
                    "0.5", "0.4", "1.0", "-0.6", "0.2", "0.8", "0.1", "-0.3", "1.2"]) + "\n")

COLMAP = {
    "cameras.txt": "# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\n1 PINHOLE 100 80 120.0 120.0 50.0 40.0\n",
    "images.txt": ("# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n"
                   "1 1 0 0 0 0 0 5 1 a.png\n50.5 40.5 1 20.0 30.0 2 70.0 10.0 3\n"
                   "2 0.9998 0.02 0 0 -1 0 5 1 b.png\n52.0 41.0 1 22.5 31.0 2 68.0 12.0 3\n"
                   "3 0.9998 0 0.02 0 0 1 5 1 c.png\n49.0 38.0 1 24.0 29.0 2\n"),
    "points3D.txt": ("# POINT3D_ID X Y Z R G B ERROR TRACK[]\n"
                     "1 0.01 0.02 0.3 10 20 30 0.5 1 0 2 0 3 0\n"
                     "2 -1.2 -0.4 0.1 10 20 30 0.5 1 1 2 1 3 1\n"
                     "3 0.9 -1.3 -0.2 1 2 3 0.5 1 2 2 2\n"),
}

PARALLAXBA = {
    "intrinsic_matrix.txt": "100 0 50\n0 100 40\n0 0 1\n",
    "Cam.txt": "0 0 0 0 0 0\n0.1 0 0 1 0 0\n0 0.1 0.05 0.5 1 0\n",
    "Feature.pmba": "2 0 10 12 1 13 14\n3 0 30 32 1 33 31 2 35 30\n2 1 60 20 2 64 22\n",
}

PVLBA = {
    "cal.txt": "100 0 50\n0 100 40\n0 0 1\n",
    "Cam-3-.txt": "0 0 0 0 0 -10 1\n0.01 0 0 1 0 -10 1\n0 0.01 0 0.5 1 -10 1\n",
    "XYZ.txt": "0.1 0.2 0.3\n-0.5 0.4 0.1\n0.3 -0.2 -0.1\n",
    "Feature.txt": "2 0 10 12 1 13 14\n3 0 30 32 1 33 31 2 35 30\n2 1 60 20 2 64 22\n",
}


@st.composite
def mutated(draw, data: bytes) -> bytes:
    """``data`` after 1-4 random edits: replace, insert, delete a span, or truncate."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["replace", "insert", "delete", "truncate", "digits"]))
        pos = draw(st.integers(0, max(len(out) - 1, 0)))
        if kind == "replace" and out:
            out[pos] = draw(st.integers(0, 255))
        elif kind == "insert":
            out[pos:pos] = draw(st.binary(min_size=1, max_size=8))
        elif kind == "delete":
            del out[pos:pos + draw(st.integers(1, 16))]
        elif kind == "truncate":
            del out[pos:]
        else:  # plausible-looking damage: a number replaced by another (huge, NaN, negative...)
            token = draw(st.sampled_from([b"nan", b"inf", b"-1", b"0", b"1e308", b"99999999999",
                                          b"-0", b"1e-320", b"\xef\xbb\xbf", b"\r\n", b" "]))
            out[pos:pos + draw(st.integers(0, 3))] = token
    return bytes(out)


def _check(path) -> None:
    try:
        problem, _ = load_problem(str(path))
    except PolarrefError as exc:
        assert str(exc).strip(), "an error must say what went wrong"
        return
    assert problem is not None  # parsed: a valid problem


def _write(folder, files: dict, which: str, data: bytes):
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir()
    for name, text in files.items():
        (folder / name).write_bytes(data if name == which else text.encode())
    return folder


@pytest.mark.parametrize("which", [None])
def test_valid_seeds_parse(tmp_path, which):
    """The unmutated files are valid (so a mutation test that passes is not vacuous)."""
    (tmp_path / "p.txt").write_text(BAL)
    for files, name in ((COLMAP, "colmap"), (PARALLAXBA, "pba"), (PVLBA, "pvl")):
        _write(tmp_path / name, files, "", b"")
    for path in (tmp_path / "p.txt", tmp_path / "colmap", tmp_path / "pba", tmp_path / "pvl"):
        problem, _ = load_problem(str(path))
        assert len(problem.obs_uv) >= 4, path


@SETTINGS
@given(data=mutated(BAL.encode()))
def test_bal_mutations(tmp_path, data):
    path = tmp_path / "m.txt"
    path.write_bytes(data)
    _check(path)


FOLDER_FORMATS = {"model": COLMAP, "pba": PARALLAXBA, "pvl": PVLBA}  # folder name -> its files


@pytest.mark.parametrize("folder,which", [(d, w) for d, files in FOLDER_FORMATS.items() for w in sorted(files)])
@SETTINGS
@given(data=st.data())
def test_folder_format_mutations(tmp_path, folder, which, data):
    """COLMAP text, ParallaxBA and PVL-BA: one file of the folder mutated, the others intact."""
    files = FOLDER_FORMATS[folder]
    blob = data.draw(mutated(files[which].encode()))
    _check(_write(tmp_path / folder, files, which, blob))


def test_bal_with_byte_order_mark_reads_like_without(tmp_path):
    from polarref.io.bal import read_bal

    plain, bom = tmp_path / "a.txt", tmp_path / "b.txt"
    plain.write_text(BAL)
    bom.write_bytes(b"\xef\xbb\xbf" + BAL.encode())
    a, b = read_bal(plain), read_bal(bom)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.obs.uv, b.obs.uv)
