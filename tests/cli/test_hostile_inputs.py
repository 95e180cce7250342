"""Every subcommand against a table of hostile inputs, through the CLI's ``main()`` in-process.

Each row asserts the exit code (1 error, 2 usage), exactly one stderr line for errors (the
usage message ends in one ``error:`` line), no traceback, the input named in the message, and
no partial output: the output path does not exist afterwards (or, for ``sfm``, holds only the
``metrics.json`` that names the failure) and no temporary sibling is left behind.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from polarref.cli import main
from polarref.core.data import REPO_ROOT

GOOD_BAL = "1 1 1\n0 0 1.0 2.0\n" + "\n".join(["0"] * 5 + ["-5", "100", "0", "0", "1", "2", "-3"]) + "\n"
EXAMPLE_METRICS = REPO_ROOT / "reports" / "comet-small" / "metrics.json"


def _file(tmp: Path, name: str, data: str | bytes) -> Path:
    p = tmp / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data.encode() if isinstance(data, str) else data)
    return p


def _blocker(tmp: Path) -> Path:
    """A plain file standing where a folder is needed."""
    return _file(tmp, "blocker", "x")


def _images(tmp: Path, n: int = 3, size=(64, 48), garbage: bool = False, gt_size=None) -> Path:
    scene = tmp / "scene"
    (scene / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        p = scene / "images" / f"{i:04d}.png"
        if garbage:
            p.write_bytes(b"\x89PNG but not really" + rng.bytes(50))
        else:
            cv2.imwrite(str(p), rng.integers(0, 256, (size[1], size[0], 3)).astype(np.uint8))
    if gt_size:
        w, h = gt_size
        (scene / "gt").mkdir()
        _file(scene, "gt/cameras.txt", f"1 PINHOLE {w} {h} {w} {w} {w / 2} {h / 2}\n")
        _file(scene, "gt/images.txt", "".join(f"{i + 1} 1 0 0 0 {i} 0 0 1 {i:04d}.png\n\n" for i in range(n)))
        _file(scene, "gt/points3D.txt", "")
    return scene


def _metrics(tmp: Path, edit) -> Path:
    d = tmp / "run"
    d.mkdir()
    data = json.loads(EXAMPLE_METRICS.read_text())
    edit(data)
    (d / "metrics.json").write_text(json.dumps(data).replace("123456.5", "1e999"))
    return d


# (id, setup(tmp) -> argv, exit code, text the error line must contain)
def _cases():
    out = lambda t: str(t / "out")  # noqa: E731  the output path that must not appear
    return [
        # ---- doctor: a hostile environment is reported, not fatal (see test_doctor_*) -----------
        # ---- derive ---------------------------------------------------------------------------
        ("derive-out-is-file", lambda t: ["derive", "--out", str(_blocker(t))], 1, "not a folder"),
        ("derive-report-under-file", lambda t: ["derive", "--out", out(t), "--report",
                                                str(_blocker(t) / "r.md")], 1, "blocker"),
        # ---- render ---------------------------------------------------------------------------
        ("render-negative-seed", lambda t: ["render", "comet", "--out", out(t), "--seed", "-1"], 2, "--seed"),
        ("render-absurd-size", lambda t: ["render", "comet", "--out", out(t), "--width", "60000",
                                          "--height", "60000"], 2, "--width"),
        ("render-nan-fov", lambda t: ["render", "comet", "--out", out(t), "--fov", "nan"], 2, "--fov"),
        ("render-one-view", lambda t: ["render", "comet", "--out", out(t), "--views", "1"], 2, "--views"),
        ("render-out-under-file", lambda t: ["render", "comet", "--out", str(_blocker(t) / "s")], 1,
         "not writable"),
        ("render-garbage-mesh", lambda t: ["render", "comet", "--out", out(t), "--mesh",
                                           str(_file(t, "m.obj", "v 1 2\nf 9 9 9\n"))], 1, "m.obj"),
        # ---- sfm ------------------------------------------------------------------------------
        ("sfm-missing-dir", lambda t: ["sfm", str(t / "nope"), "--out", out(t)], 1, "nope"),
        ("sfm-no-images", lambda t: ["sfm", str(_images(t, 0)), "--out", out(t),
                                     "--camera", "PINHOLE:50,50,32,24"], 1, "no images"),
        ("sfm-garbage-images", lambda t: ["sfm", str(_images(t, garbage=True)), "--out", out(t),
                                          "--camera", "PINHOLE:50,50,32,24"], 1, "readable image"),
        ("sfm-gt-other-size", lambda t: ["sfm", str(_images(t, gt_size=(128, 96))), "--out", out(t)], 1,
         "64x48 but its ground-truth camera 1 is 128x96"),
        ("sfm-camera-param-count", lambda t: ["sfm", str(_images(t)), "--out", out(t), "--camera",
                                              "PINHOLE:50,50,32"], 2, "PINHOLE:50,50,32"),  # usage (issue 31)
        ("sfm-garbage-camera", lambda t: ["sfm", str(_images(t)), "--out", out(t), "--camera", "PINHOLE:a,b"], 2,
         "PINHOLE:a,b"),
        ("sfm-corrupt-gt", lambda t: ["sfm", str(_corrupt_gt(t)), "--out", out(t)], 1, "gt"),
        ("sfm-out-is-file", lambda t: ["sfm", str(_images(t)), "--out", str(_blocker(t)),
                                       "--camera", "PINHOLE:50,50,32,24"], 1, "not a folder"),
        ("sfm-out-under-file", lambda t: ["sfm", str(_images(t)), "--out", str(_blocker(t) / "o"),
                                          "--camera", "PINHOLE:50,50,32,24"], 1, "not a folder"),
        ("sfm-negative-image-size", lambda t: ["sfm", str(t), "--out", out(t), "--max-image-size", "-5"], 2,
         "--max-image-size"),
        ("sfm-negative-seed", lambda t: ["sfm", str(t), "--out", out(t), "--seed", "-1"], 2, "--seed"),
        # ---- ba -------------------------------------------------------------------------------
        ("ba-missing", lambda t: ["ba", str(t / "absent.txt"), "--out", out(t)], 1, "absent.txt"),
        ("ba-empty", lambda t: ["ba", str(_file(t, "p.txt", "")), "--out", out(t)], 1, "empty file"),
        ("ba-truncated", lambda t: ["ba", str(_file(t, "p.txt", GOOD_BAL[:-8])), "--out", out(t)], 1,
         "file ends"),
        ("ba-garbage", lambda t: ["ba", str(_file(t, "p.txt", os.urandom(64).hex())), "--out", out(t)], 1,
         "p.txt:1"),
        ("ba-binary", lambda t: ["ba", str(_file(t, "p.txt", b"\xff\xfe\x00garbage")), "--out", out(t)], 1,
         "not a UTF-8"),
        ("ba-nan", lambda t: ["ba", str(_file(t, "p.txt", GOOD_BAL.replace("-3", "nan"))), "--out", out(t)], 1,
         "non-finite"),
        ("ba-huge-value", lambda t: ["ba", str(_file(t, "p.txt", GOOD_BAL.replace("-3", "1e300"))),
                                     "--out", out(t)], 1, "1e+300"),
        ("ba-huge-header", lambda t: ["ba", str(_file(t, "p.txt", "1 1000000000000 1000000000000\n0 0 1 2\n")),
                                      "--out", out(t)], 1, "file ends"),
        ("ba-zero-focal", lambda t: ["ba", str(_file(t, "p.txt", GOOD_BAL.replace("100", "0"))), "--out", out(t)],
         1, "focal length 0"),
        ("ba-negative-focal", lambda t: ["ba", str(_file(t, "p.txt", GOOD_BAL.replace("100", "-100"))),
                                         "--out", out(t)], 1, "focal length -100"),
        ("ba-loss-scale-inf", lambda t: ["ba", "synth-20", "--out", out(t), "--loss-scale", "inf"], 2,
         "--loss-scale"),
        ("ba-loss-scale-nan", lambda t: ["ba", "synth-20", "--out", out(t), "--loss-scale", "nan"], 2,
         "--loss-scale"),
        ("ba-out-is-dir", lambda t: ["ba", "synth-20", "--out", str(t)], 1, "is a folder"),
        ("ba-out-under-file", lambda t: ["ba", "synth-20", "--out", str(_blocker(t) / "o.json")], 1,
         "not a folder"),
        ("ba-garbage-colmap", lambda t: ["ba", str(_corrupt_gt(t) / "gt"), "--out", out(t)], 1, "gt"),
        # ---- bench ba -------------------------------------------------------------------------
        ("bench-missing-problem", lambda t: ["bench", "ba", "--problem", str(t / "missing.txt"),
                                             "--out", out(t)], 1, "missing.txt"),
        ("bench-garbage-problem", lambda t: ["bench", "ba", "--problem", str(_file(t, "g.txt", "x y z\n")),
                                             "--out", out(t)], 1, "g.txt:1"),
        ("bench-zero-repeat", lambda t: ["bench", "ba", "--repeat", "0", "--out", out(t)], 2, "--repeat"),
        ("bench-absurd-threads", lambda t: ["bench", "ba", "--ours-threads", "5000", "--out", out(t)], 2,
         "--ours-threads"),
        ("bench-out-under-file", lambda t: ["bench", "ba", "--problem", "synth-20", "--out",
                                            str(_blocker(t) / "b")], 1, "not a folder"),
        # ---- compare --------------------------------------------------------------------------
        ("compare-missing-scene", lambda t: ["compare", str(t / "nope"), "--out", out(t)], 1, "nope"),
        ("compare-no-images", lambda t: ["compare", str(_file(t, "j/a.txt", "x").parent), "--out", out(t)], 1,
         "no images"),
        ("compare-out-is-file", lambda t: ["compare", "comet", "--out", str(_blocker(t))], 1, "blocker"),
        ("compare-negative-timeout", lambda t: ["compare", "--method-timeout", "-1", "--out", out(t)], 2,
         "--method-timeout"),
        ("compare-negative-seed", lambda t: ["compare", "--seed", "-3", "--out", out(t)], 2, "--seed"),
        # ---- report ---------------------------------------------------------------------------
        ("report-missing-dir", lambda t: ["report", str(t / "nope")], 1, "nope"),
        ("report-no-metrics", lambda t: ["report", str(t)], 1, "no metrics.json"),
        ("report-empty-metrics", lambda t: ["report", str(_file(t, "r/metrics.json", "").parent)], 1,
         "not valid JSON"),
        ("report-truncated-metrics", lambda t: ["report", str(_file(t, "r/metrics.json",
                                                                    EXAMPLE_METRICS.read_text()[:500]).parent)],
         1, "not valid JSON"),
        ("report-non-utf8-metrics", lambda t: ["report", str(_file(t, "r/metrics.json",
                                                                   b'{"schema_version": 1, "\xff": 2}').parent)],
         1, "not UTF-8"),
        ("report-nan-runtime", lambda t: ["report", str(_metrics(t, _nan_runtime))], 1, "NaN"),
        ("report-inf-number", lambda t: ["report", str(_metrics(t, _inf_runtime))], 1, "finite number"),
        ("report-future-schema", lambda t: ["report", str(_metrics(t, _future_schema))], 1, "schema_version"),
    ]


def _nan_runtime(d):
    d["methods"][0]["runtime_s"] = math.nan


def _inf_runtime(d):
    d["methods"][0]["runtime_s"] = 123456.5  # written as 1e999: valid JSON, parses to inf


def _future_schema(d):
    d["schema_version"] = 999


def _corrupt_gt(tmp: Path) -> Path:
    scene = _images(tmp, gt_size=(64, 48))
    (scene / "gt" / "cameras.txt").write_text("1 PINHOLE sixty-four 48 1 2 3\n")
    return scene


CASES = _cases()


def _leftovers(root: Path) -> list[str]:
    return [str(p) for p in root.rglob(".*") if ".tmp-" in p.name or ".old-" in p.name]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_hostile_input(case, tmp_path, capsys, monkeypatch):
    name, setup, code, needle = case
    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    work = tmp_path / "w"
    work.mkdir()
    argv = setup(work)
    capsys.readouterr()
    if code == 2:
        with pytest.raises(SystemExit) as exc:
            main(["-q", *argv])
        rc = exc.value.code
    else:
        rc = main(["-q", *argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == code, err
    assert "Traceback" not in err
    if code == 2:
        assert lines[-1].startswith(f"polarref {argv[0]}: error: ") and needle in lines[-1], err
    else:
        assert len(lines) == 1, err
        assert lines[0].startswith(f"polarref {argv[0]}: ") and needle in lines[0], err
    out = work / "out"
    if argv[0] == "sfm" and out.exists():  # a failed sfm run names its failure in metrics.json only
        assert sorted(p.name for p in out.iterdir()) == [".polarref-outputs", "metrics.json"]
        assert json.loads((out / "metrics.json").read_text())["status"] == "failed"
    else:
        assert not out.exists(), f"{name}: partial output {sorted(out.rglob('*'))}"
    assert not _leftovers(tmp_path)


def test_doctor_survives_hostile_environment(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("POLARREF_DATA", str(_blocker(tmp_path)))
    assert main(["doctor", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["data"] is None and "blocker" in report["data_reason"]


@pytest.mark.parametrize("argv, needle", [
    (["ba", "{tmp}/p.txt", "--out", "{tmp}/o.json"], "non-finite"),
    (["report", "{tmp}/r"], "not UTF-8"),
])
def test_real_stderr_is_one_line(tmp_path, argv, needle):
    """Out of process, with logging and warnings as a user sees them: still exactly one line."""
    _file(tmp_path, "p.txt", GOOD_BAL.replace("1\n2\n-3", "inf\n2\n-3"))
    _file(tmp_path, "r/metrics.json", b"\xff\xfe{}")
    proc = subprocess.run([sys.executable, "-m", "polarref", *[a.format(tmp=tmp_path) for a in argv]],
                          capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and needle in lines[0], proc.stderr
    assert not (tmp_path / "o.json").exists()
