"""Issue 31 cases run out of process, as a user runs them (no -q): outputs never inside their
inputs, and a failing --overwrite rerun never loses a finished result."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from _dense_scene import Sphere, orbit, write_scene

SPHERE = Sphere([0, 0, 0], 3.0)
FAST = ["--scale", "1", "--poisson-depth", "6", "--tau", "0.01"]


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, POLARREF_CACHE=str(cwd / "cache"))
    return subprocess.run([sys.executable, "-m", "polarref", *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=300)


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("r2") / "scene"
    write_scene(root, SPHERE, orbit([0, 0, 0], 10.0, 4, 7.0), 96, 72, 30.0, wavelength=0.1,
                bounds=([0, 0, 0], 3.2), mesh_args=(3,))
    return root


@pytest.mark.parametrize("where", [".", "depth", "gt", "images", ".."])
def test_dense_out_into_scene_refused_and_scene_untouched(scene, where):
    before = _digest(scene)
    out = scene / where if where != ".." else scene.parent
    r = _cli("dense", str(scene), "--model", "gt", "--out", str(out), "--overwrite", *FAST, cwd=scene.parent)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert "outputs are never written into their inputs" in lines[0]
    assert _digest(scene) == before


def test_sfm_out_into_images_refused(scene):
    before = _digest(scene)
    for out in (scene / "images", scene / "images" / "sub"):
        r = _cli("sfm", str(scene), "--out", str(out), "--overwrite", cwd=scene.parent)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1 and "never written into their inputs" in lines[0], r.stderr
    assert _digest(scene) == before


def test_dense_out_into_model_refused(scene, tmp_path):
    model = tmp_path / "model"
    shutil.copytree(scene / "gt", model)
    before = _digest(model)
    r = _cli("dense", str(scene), "--model", str(model), "--out", str(model / "d"), *FAST, cwd=tmp_path)
    assert r.returncode == 1 and "never written into their inputs" in r.stderr, r.stderr
    assert _digest(model) == before and not (model / "d").exists()


def test_dense_failing_overwrite_keeps_finished_result(scene, tmp_path):
    out = tmp_path / "d"
    r = _cli("dense", str(scene), "--model", "gt", "--out", str(out), *FAST, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "metrics.json").read_text())["status"] == "ok"
    before = _digest(out)
    r = _cli("dense", str(scene), "--model", str(tmp_path / "typo"), "--out", str(out), "--overwrite", *FAST,
             cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "was kept" in lines[0], r.stderr
    assert _digest(out) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".d.")]  # nothing left aside


def test_dense_failed_run_then_corrected_rerun_needs_no_flag(scene, tmp_path):
    out = tmp_path / "d"
    r = _cli("dense", str(scene), "--model", str(tmp_path / "typo"), "--out", str(out), *FAST, cwd=tmp_path)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert json.loads((out / "metrics.json").read_text())["status"] == "failed"
    r = _cli("dense", str(scene), "--model", "gt", "--out", str(out), *FAST, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["status"] == "ok" and m["num_views_with_depth"] >= 3


def test_dense_overwrite_leaves_no_stale_outputs(scene, tmp_path):
    out = tmp_path / "d"
    assert _cli("dense", str(scene), "--model", "gt", "--out", str(out), *FAST, cwd=tmp_path).returncode == 0
    (out / "depth" / "stale.npy").write_bytes(b"x")  # as a previous run with other names would leave
    (out / "notes.txt").write_text("mine")
    r = _cli("dense", str(scene), "--model", "gt", "--out", str(out), "--overwrite", *FAST, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert not (out / "depth" / "stale.npy").exists()
    assert sorted(p.name for p in (out / "depth").iterdir()) == [f"{i:04d}.npy" for i in range(4)]
    assert (out / "notes.txt").read_text() == "mine"


def test_dense_error_has_no_doubled_prefix(tmp_path):
    root = tmp_path / "two"
    write_scene(root, SPHERE, orbit([0, 0, 0], 10.0, 2, 7.0), 64, 48, 30.0, wavelength=0.1,
                bounds=([0, 0, 0], 3.2), mesh_args=(3,))
    r = _cli("dense", str(root), "--model", "gt", "--out", str(tmp_path / "o"), *FAST, cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert lines[0].startswith("polarref dense: ") and "dense: dense:" not in lines[0]
    assert "need at least 3" in lines[0]


@pytest.mark.parametrize("inside", ["gt/ba.json", "gt/cameras.txt"])
def test_ba_out_into_model_refused(scene, inside):
    before = _digest(scene)
    r = _cli("ba", str(scene / "gt"), "--max-iterations", "1", "--out", str(scene / inside), cwd=scene.parent)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "never written into their inputs" in lines[0], r.stderr
    assert _digest(scene) == before


# ---- a full disk, simulated in a fresh process (tests/_enospc_cli.py) --------------------------
def _cli_full_disk(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, POLARREF_CACHE=str(cwd / "cache"),
               PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[2]), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, str((Path(__file__).parents[1] / "_enospc_cli.py")), *args],
                          capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def test_dense_full_disk_named_and_finished_result_kept(scene, tmp_path):
    out = tmp_path / "d"
    r = _cli_full_disk("dense", str(scene), "--model", "gt", "--out", str(out), *FAST, cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert "No space left on device" in lines[0] and "free disk space" in lines[0], lines[0]
    assert not out.exists() or not list(out.rglob("*.ply"))  # nothing half-written published
    assert not [p for p in tmp_path.rglob("*") if ".tmp-" in p.name]
    # a finished result, then a rerun on a full disk: the result stays as it was
    shutil.rmtree(out, ignore_errors=True)
    assert _cli("dense", str(scene), "--model", "gt", "--out", str(out), *FAST, cwd=tmp_path).returncode == 0
    before = _digest(out)
    r = _cli_full_disk("dense", str(scene), "--model", "gt", "--out", str(out), "--overwrite", *FAST, cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "No space left on device" in lines[0], r.stderr
    assert _digest(out) == before
    assert not [p for p in tmp_path.rglob("*") if ".tmp-" in p.name or p.name.startswith(".d.")]


# ---- every output-writing command, --out into its inputs: every input byte-identical -----------
BEHIND_FREE_BAL = "1 1 1\n0 0 1.0 2.0\n" + "\n".join(["0"] * 5 + ["-5", "100", "0", "0", "1", "2", "-3"]) + "\n"


def test_every_command_out_into_inputs_leaves_them_byte_identical(scene, tmp_path):
    from polarref.core.data import REPO_ROOT

    work = tmp_path / "scene"
    shutil.copytree(scene, work)
    (work / "p.txt").write_text(BEHIND_FREE_BAL)
    report = tmp_path / "report"
    report.mkdir()
    shutil.copy(REPO_ROOT / "reports" / "comet-small" / "metrics.json", report / "metrics.json")
    before, report_before = _digest(work), (report / "metrics.json").read_bytes()
    runs = [
        ("sfm", str(work), "--out", str(work / "gt"), "--overwrite"),
        ("dense", str(work), "--model", str(work / "gt"), "--out", str(work / "gt" / "d"), *FAST),
        ("ba", str(work / "gt"), "--out", str(work / "gt" / "ba.json")),
        ("compare", str(work), "--out", str(work / "images"), "--overwrite"),
        ("render", "comet", "--mesh", str(work / "mesh.ply"), "--out", str(work), "--overwrite"),
        ("bench", "ba", "--problem", str(work / "p.txt"), "--out", str(work), "--overwrite"),
    ]
    for argv in runs:
        r = _cli(*argv, cwd=tmp_path)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1 and "never written into their inputs" in lines[0], (argv, r.stderr)
    # report writes into its folder by design: its one input, metrics.json, stays as it was
    assert _cli("report", str(report), cwd=tmp_path).returncode == 0
    assert (report / "metrics.json").read_bytes() == report_before and (report / "report.md").is_file()
    assert _digest(work) == before
