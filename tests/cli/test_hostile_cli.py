"""Issue 31's hostile-input cases, each run out of process exactly as a user types it (no -q,
real logging and warnings, stdout and stderr as the terminal gets them).

Every row asserts the exit code (1 error, 2 usage), one line naming the problem (usage: the
last of argparse's lines), no traceback, no library warning text (OpenCV's ``[ WARN ]``, Python
``...Warning:``, pycolmap's ``Check failed``) and no output written. The rows run two at a time
in one module fixture: most of a row's cost is the interpreter importing polarref.

Cases of the issue covered elsewhere (they need a finished run first): case 1 and 5 in
test_reliability_round2.py (out into the scene, the model, depth/, gt/, images/; stale files);
case 2 there and in test_reliability_cases.py; the rest of case 3, 6, 7 and 8 in the tests at
the end of this file.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

from polarref.core.data import REPO_ROOT

GOOD_BAL = "1 1 1\n0 0 1.0 2.0\n" + "\n".join(["0"] * 5 + ["-5", "100", "0", "0", "1", "2", "-3"]) + "\n"
# two cameras (the second moved 1 along x) and one point at z = +3: behind both (BAL cameras
# look down -z)
BEHIND_BAL = ("2 1 2\n0 0 1.0 2.0\n1 0 -3.0 2.0\n" + "\n".join(["0"] * 6 + ["100", "0", "0"] + ["0"] * 3
                                                              + ["1", "0", "0", "100", "0", "0"] + ["1", "2", "3"]) + "\n")
EXAMPLE_METRICS = REPO_ROOT / "reports" / "comet-small" / "metrics.json"
WARNING_TEXT = ("Traceback", "[ WARN", "Warning:", "Check failed", "RuntimeWarning", "UserWarning")


def cli(*args: str, cwd: Path, env: dict | None = None, timeout: int = 300) -> subprocess.CompletedProcess:
    full = {**os.environ, "POLARREF_CACHE": str(cwd / "cache"), "PYTHONPATH": str(REPO_ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "polarref", *args], capture_output=True, text=True,
                          cwd=cwd, env=full, timeout=timeout)


def _file(d: Path, name: str, data: str | bytes) -> Path:
    p = d / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data.encode() if isinstance(data, str) else data)
    return p


def _scene(d: Path, names=("0000.png", "0001.png", "0002.png"), gt: bool = True) -> Path:
    """Random-texture images (64x48) and, with ``gt``, a GT model of the same names."""
    scene = d / "scene"
    (scene / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for name in names:
        cv2.imwrite(str(scene / "images" / name), rng.integers(0, 256, (48, 64, 3)).astype(np.uint8))
    if gt:
        _file(scene, "gt/cameras.txt", "1 PINHOLE 64 48 60 60 32 24\n")
        _file(scene, "gt/images.txt", "".join(f"{i + 1} 1 0 0 0 {i} 0 0 1 {n}\n\n" for i, n in enumerate(names)))
        _file(scene, "gt/points3D.txt", "")
    return scene


def _exif_scene(d: Path, f35: int) -> Path:
    from PIL import Image

    scene = d / "photos"
    (scene / "images").mkdir(parents=True)
    rng = np.random.default_rng(1)
    for i in range(3):
        ex = Image.Exif()
        ex[0x010F], ex[0x0110] = "Acme", "One"
        ex.get_ifd(0x8769)[0xA405] = f35  # FocalLengthIn35mmFilm
        rgb = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
        Image.fromarray(rgb).save(scene / "images" / f"{i:04d}.jpg", quality=95, exif=ex)
    return scene


def _text_model(d: Path, name: str = "a.png", cameras: str = "1 PINHOLE 64 48 60 60 32 24\n") -> Path:
    m = d / "model"
    _file(m, "cameras.txt", cameras)
    _file(m, "images.txt", f"1 1 0 0 0 0 0 0 1 {name}\n10 20 1\n2 1 0 0 0 1 0 0 1 b.png\n12 20 1\n")
    _file(m, "points3D.txt", "1 0 0 5 10 10 10 0.1 1 0 2 0\n")
    return m


def _metrics(d: Path, edit) -> Path:
    data = json.loads(EXAMPLE_METRICS.read_text())
    edit(data)
    return _file(d, "run/metrics.json", json.dumps(data)).parent


def _georef(d: Path, priors=None, gcps=None, marks=None) -> list[str]:
    scene = _scene(d, gt=False)
    argv = ["sfm", str(scene), "--out", str(d / "out"), "--camera", "PINHOLE:60,60,32,24"]
    for flag, text in (("--priors", priors), ("--gcps", gcps), ("--gcp-observations", marks)):
        if text is not None:
            argv += [flag, str(_file(d, flag.strip("-") + ".csv", text))]
    return argv


GCP_HEAD = "id,x,y,z,sigma_x,sigma_y,sigma_z,role\n"
GCP3 = GCP_HEAD + "".join(f"G{i},{i},0,0,0.1,0.1,0.1,control\n" for i in range(3))
MARK_HEAD = "id,image,u,v\n"
MARKS3 = MARK_HEAD + "".join(f"G{i},0000.png,10,10\n" for i in range(3))
PRIOR_HEAD = "name,x,y,z,sigma_x,sigma_y,sigma_z\n"


def _weird_status(d):
    d["methods"][0]["status"] = "weird"


def _negative_registered(d):
    d["methods"][0]["metrics"]["registered_images"] = -5


# (id, setup(dir) -> argv, exit code, text the error line must contain)
ROWS = [
    # case 1: outputs into their inputs (the rest: test_reliability_round2.py)
    ("1-dense-out-is-scene", lambda d: ["dense", str(_scene(d)), "--model", "gt", "--out", str(d / "scene"),
                                        "--overwrite"], 1, "never written into their inputs"),
    ("1-compare-out-is-scene", lambda d: ["compare", str(_scene(d)), "--out", str(d / "scene" / "images")], 1,
     "never written into their inputs"),
    ("1-render-out-holds-mesh", lambda d: ["render", "comet", "--mesh", str(_file(d, "m/m.obj", "v 0 0 0\n")),
                                           "--out", str(d / "m"), "--overwrite"], 1,
     "never written into their inputs"),
    # case 3: physically impossible inputs
    ("3-ba-points-behind", lambda d: ["ba", str(_file(d, "p.txt", BEHIND_BAL)), "--out",
                                      str(d / "out")], 1, "behind every camera"),
    ("3-exif-focal-65535", lambda d: ["sfm", str(_exif_scene(d, 65535)), "--out", str(d / "out")], 1,
     "focal length"),
    ("3-exif-focal-1", lambda d: ["sfm", str(_exif_scene(d, 1)), "--out", str(d / "out")], 1, "focal length"),
    # case 4: names with spaces in COLMAP text
    ("4-sfm-text-spaces", lambda d: ["sfm", str(_scene(d, ("my photo 0000.png", "my photo 0001.png"), gt=False)),
                                     "--out", str(d / "out"), "--format", "text"], 2, "whitespace"),
    ("4-read-text-spaces", lambda d: ["ba", str(_text_model(d, "my photo.png")), "--out", str(d / "out")], 1,
     "'my photo.png' holds whitespace"),
    ("4-compare-spaces", lambda d: ["compare", str(_scene(d, ("my photo 0000.png", "my photo 0001.png"),
                                                          gt=False)), "--out", str(d / "out")], 1,
     "'my photo 0000.png', hold whitespace"),
    # case 8: friction
    ("8-refine-bogus", lambda d: ["sfm", str(_scene(d)), "--out", str(d / "out"), "--refine", "bogus"], 2,
     "--refine"),
    ("8-camera-two-params", lambda d: ["sfm", str(_scene(d)), "--out", str(d / "out"), "--camera",
                                       "PINHOLE:1,2"], 2, "PINHOLE:1,2"),
    ("8-twin-ignores-options", lambda d: ["compare", "poets-park", "--preset", "small", "--budget", "5",
                                          "--out", str(d / "out")], 2, "--preset, --budget"),
    ("8-opencv-unreadable", lambda d: ["sfm", str(_garbage_images(d)), "--out", str(d / "out"), "--camera",
                                       "PINHOLE:60,60,32,24"], 1, "readable image"),
    ("8-opencv-dense-unreadable", lambda d: ["dense", str(_scene_with_garbage(d)), "--model", "gt", "--out",
                                             str(d / "out")], 1, "cannot read image"),
    # case 9: weak validation
    ("9-report-negative-registered", lambda d: ["report", str(_metrics(d, _negative_registered))], 1,
     "registered_images -5"),
    ("9-report-weird-status", lambda d: ["report", str(_metrics(d, _weird_status))], 1, "'weird'"),
    ("9-refine-empty", lambda d: ["sfm", str(_scene(d)), "--out", str(d / "out"), "--refine", ""], 2,
     "empty intrinsics group"),
    ("9-refine-doubled-comma", lambda d: ["sfm", str(_scene(d)), "--out", str(d / "out"), "--refine",
                                          "focal,,focal"], 2, "empty intrinsics group"),
    ("9-pycolmap-check-failed", lambda d: ["ba", str(_text_model(d, cameras="1 PINHOLE 64 48 60\n")), "--out",
                                           str(d / "out")], 1, "cameras.txt:1: PINHOLE takes 4 parameters"),
    ("9-unknown-twin", lambda d: ["compare", "poets-parc", "--out", str(d / "out")], 1,
     "rosetta, poets-park, mappilot"),
    ("9-scheduler-before-output", lambda d: ["--scheduler", "tcp://127.0.0.1:9", "sfm", str(_scene(d)),
                                             "--out", str(d / "out")], 1, "cannot reach the Dask scheduler"),
    # ground control CSVs (issue 33's options, as issue 31 asks for every new command)
    ("gcp-without-observations", lambda d: _georef(d, gcps=GCP3, marks=MARK_HEAD + "G0,0000.png,1,1\n"
                                                   "G1,0001.png,1,1\n"), 1, "ground point 'G2' has no observations"),
    ("gcp-mark-unknown-image", lambda d: _georef(d, gcps=GCP3, marks=MARKS3 + "G0,nope.png,1,1\n"), 1,
     "unknown image 'nope.png'"),
    ("gcp-mark-unknown-id", lambda d: _georef(d, gcps=GCP3, marks=MARKS3 + "G9,0000.png,1,1\n"), 1,
     "unknown ground point id 'G9'"),
    ("gcp-sigma-zero", lambda d: _georef(d, gcps=GCP3.replace("0.1,0.1,0.1,control\nG2", "0,0.1,0.1,control\nG2"),
                                         marks=MARKS3), 1, "must be > 0"),
    ("prior-unknown-image", lambda d: _georef(d, priors=PRIOR_HEAD + "other.png,0,0,0,1,1,1\n"), 1,
     "'other.png', which is not in"),
    ("gcp-two-control-no-priors", lambda d: _georef(d, gcps=GCP_HEAD + "".join(
        f"G{i},{i},0,0,0.1,0.1,0.1,control\n" for i in range(2)), marks=MARK_HEAD + "G0,0000.png,1,1\nG1,0001.png,1,1\n"),
     1, "at least 3 control points"),
]


def _scene_with_garbage(d: Path) -> Path:
    scene = _scene(d)
    (scene / "images" / "0001.png").write_bytes(b"\x89PNG but not really")
    return scene


def _garbage_images(d: Path) -> Path:
    scene = d / "junk"
    for i in range(3):
        _file(scene, f"images/{i:04d}.png", b"\x89PNG but not really" + bytes(range(50)))
    return scene


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    base = tmp_path_factory.mktemp("hostile-cli")

    def one(row):
        name, setup, _, _ = row
        d = base / name
        d.mkdir()
        argv = setup(d)
        return name, d, argv, cli(*argv, cwd=d)

    with ThreadPoolExecutor(max_workers=2) as pool:
        return {name: (d, argv, proc) for name, d, argv, proc in pool.map(one, ROWS)}


@pytest.mark.parametrize("row", ROWS, ids=[r[0] for r in ROWS])
def test_hostile_row(results, row):
    name, _, code, needle = row
    d, argv, proc = results[name]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == code, proc.stderr
    assert not any(w in proc.stderr for w in WARNING_TEXT), proc.stderr
    command = next(a for a in argv if not a.startswith("-") and a != "tcp://127.0.0.1:9")
    if code == 2:
        assert lines[-1].startswith(f"polarref {command}: error: ") and needle in lines[-1], proc.stderr
        assert all(ln.startswith(("usage:", " ")) for ln in lines[:-1]), proc.stderr
    else:
        assert len(lines) == 1, proc.stderr
        assert lines[0].startswith(f"polarref {command}: ") and needle in lines[0], proc.stderr
    out = d / "out"
    if command in ("sfm", "dense") and out.exists():  # a failed run names its failure in metrics.json only
        files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() or any(p.iterdir()))
        assert files == [".polarref-outputs", "metrics.json"], files
        assert json.loads((out / "metrics.json").read_text())["status"] == "failed"
    else:
        assert not out.exists(), sorted(out.rglob("*"))
    assert proc.stdout == ""
