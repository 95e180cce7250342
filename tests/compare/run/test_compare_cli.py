"""`polarref compare` end to end: bad input, failure capture, report folder updates.

The fast tests fake the heavy jobs (``run_isolated``) so that the orchestration, scoring with
``polarref.metrics`` and reporting are exercised in seconds; the slow test runs everything on
the small comet scene.
"""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from polarref.cli import main
from polarref.compare.run import pipeline
from polarref.compare.run import presets
from polarref.model.run import MethodRun
from polarref.core.isolated import JobOutcome


@pytest.fixture
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_unknown_scene_is_a_clear_error(tmp_path, capsys, isolated_cache):
    assert main(["compare", "no-such-scene", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "unknown scene 'no-such-scene'" in err and "comet" in err


def test_directory_without_images_is_a_clear_error(tmp_path, capsys, isolated_cache):
    (tmp_path / "empty" / "images").mkdir(parents=True)
    assert main(["compare", str(tmp_path / "empty"), "--out", str(tmp_path / "r")]) == 1
    assert "no images" in capsys.readouterr().err


def test_images_without_ground_truth_is_a_clear_error(tmp_path, capsys, isolated_cache):
    d = tmp_path / "nogt" / "images"
    d.mkdir(parents=True)
    cv2.imwrite(str(d / "a.png"), np.zeros((8, 8, 3), np.uint8))
    assert main(["compare", str(tmp_path / "nogt"), "--out", str(tmp_path / "r")]) == 1
    assert "no ground truth" in capsys.readouterr().err


def test_unknown_method_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["compare", "--methods", "nope"])
    assert exc.value.code == 2


def _toy_scene(tmp_path: Path):
    """images/ + gt/ (4 cameras, no points) and a model with points equal to the truth."""
    from polarref.ba.synthetic import synthetic_reconstruction

    _, truth = synthetic_reconstruction(4, 60, seed=3, noise_px=0.0)
    scene = tmp_path / "toy"
    (scene / "images").mkdir(parents=True)
    for im in truth.images.values():
        cv2.imwrite(str(scene / "images" / im.name), np.zeros((8, 8, 3), np.uint8))
    model = tmp_path / "model"
    truth.write_text(model)
    gt = type(truth)(cameras=dict(truth.cameras))
    for i, im in truth.images.items():
        gt.images[i] = type(im)(im.image_id, im.name, im.camera_id, im.cam_from_world)
    gt.write_text(scene / "gt")
    return scene, model, truth


def test_failed_method_is_reported_and_others_still_report(tmp_path, monkeypatch, isolated_cache, capsys):
    scene, model, truth = _toy_scene(tmp_path)
    calls, reuses = [], []

    def fake(job, kwargs, timeout_s, work_dir, tag, reuse=False):
        calls.append(job.__name__)
        reuses.append(reuse)
        name = job.__name__
        if name == "pycolmap_map":
            return JobOutcome("failed", "RuntimeError: pycolmap incremental mapping registered no images")
        if name == "ours_sfm":
            return JobOutcome("ok", "", 1.0, MethodRun(model_dir=str(model), stage_runtime_s={"mapping": 2.5, "bundle adjustment": 0.5}))
        return JobOutcome("ok", "", 1.0, MethodRun(stage_runtime_s={"features": 1.0}, verified_pairs=3))

    monkeypatch.setattr(pipeline, "run_isolated", fake)
    out = tmp_path / "report"
    out.mkdir()
    (out / "user-notes.md").write_text("mine")
    args = ["compare", str(scene), "--preset", "large", "--out", str(out), "--no-claims",
            "--methods", "ours-euclidean", "pycolmap-incremental-sift"]
    assert main(args) == 0
    m = json.loads((out / "metrics.json").read_text())
    by = {r["name"]: r for r in m["methods"]}
    eu, pc = by["ours-euclidean"], by["pycolmap-incremental-sift"]
    assert pc["status"] == "failed" and "registered no images" in pc["reason"]
    assert eu["status"] == "ok" and eu["metrics"]["registered_images"] == 4
    assert eu["metrics"]["tie_points"] == 60 and eu["metrics"]["reprojected_px"] == truth.num_observations
    assert 0.0 <= eu["gt"]["rotation_error_deg_max"] < 1e-6          # the model IS the truth
    assert eu["runtime_s"] == pytest.approx(1.0 + 3.0)               # shared features + own stages
    assert calls.count("pycolmap_sift_db") == 1 and calls.count("ours_features") == 1
    assert reuses and all(reuses)        # no --overwrite: finished jobs of an interrupted run are reused
    md = (out / "report.md").read_text()
    assert "registered no images" in md and "| failed |" in md
    assert (out / "user-notes.md").read_text() == "mine"             # updated, not wiped
    # A finished folder is refused without --overwrite (one line, exit 1, nothing touched) ...
    before = (out / "metrics.json").read_bytes()
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert (out / "metrics.json").read_bytes() == before
    # ... and updated in place with it.
    (out / "figures" / "extra.png").write_bytes(b"x")
    reuses.clear()
    assert main(args + ["--overwrite"]) == 0
    assert reuses and not any(reuses)    # --overwrite recomputes every job
    assert (out / "user-notes.md").exists() and (out / "figures" / "extra.png").exists()


@pytest.mark.slow
def test_full_compare_on_small_comet(tmp_path, isolated_cache):
    """Every method on the small comet scene (rendered here): ~2-4 min on 2 cores."""
    out = tmp_path / "comet-small"
    assert main(["compare", "comet", "--preset", "small", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    by = {r["name"]: r for r in m["methods"]}
    for name in ("ours-euclidean", "pycolmap-incremental-sift", "pycolmap-global-sift"):
        r = by[name]
        assert r["status"] == "ok", (name, r["reason"])
        assert r["metrics"]["registered_images"] == m["scene"]["num_images"]
        assert 0.0 < r["gt"]["rotation_error_deg_mean"] < 0.5
        assert 0.05 < r["metrics"]["mean_reprojection_error_px"] < 1.0
    assert len(m["claims"]) == 8
    assert all(c["verdict"] in ("supported", "not supported", "inconclusive", "not tested") for c in m["claims"])
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 4
    shutil.rmtree(out / "runs")


def test_run_budget_shortens_later_limits(tmp_path, monkeypatch, isolated_cache):
    """Under a whole-run budget the methods run in priority order and later ones get what is left."""
    scene, model, _ = _toy_scene(tmp_path)
    limits = []

    class Clock:  # every method uses its whole limit
        t = 1000.0

        def perf_counter(self):
            return self.t

    clock = Clock()

    def fake(job, kwargs, timeout_s, work_dir, tag, reuse=False):
        name = job.__name__
        if name in ("ours_sfm", "pycolmap_map"):
            limits.append(timeout_s)
            clock.t += timeout_s
            return JobOutcome("timeout", f"timed out after {timeout_s:.0f} s (process killed)", timeout_s)
        return JobOutcome("ok", "", 0.0, MethodRun(verified_pairs=0))

    monkeypatch.setattr(pipeline, "run_isolated", fake)
    monkeypatch.setattr(pipeline, "time", clock)
    out = tmp_path / "r"
    cfg = pipeline.CompareConfig(scene=str(scene), preset=presets.get("large"), out=out, claims=False, budget_s=60.0,
                                 methods=("ours-euclidean", "ours-polar", "ours-angular"))
    _, metrics = pipeline.run_compare(cfg)
    # deadline = 60 - 12 (report reserve); the first keeps 8 s for each of the two others.
    assert limits == pytest.approx([60 - 12 - 16, 8.0, 8.0])
    by = {m.name: m for m in metrics.methods}
    assert [m.name for m in metrics.methods] == ["ours-euclidean", "ours-polar", "ours-angular"]
    assert "run budget" in by["ours-angular"].reason
    assert by["ours-angular"].timeout_s == pytest.approx(limits[2])


def test_downscale_factor_is_exact():
    from polarref.compare.run.scenes import _downscale_factor

    assert _downscale_factor(3072, 2048, 1024) == 4       # 3 does not divide 2048
    assert _downscale_factor(3072, 2048, 1536) == 2
    assert _downscale_factor(640, 480, 1024) == 1
    with pytest.raises(Exception, match="exactly"):
        _downscale_factor(1031, 1033, 100)              # primes: no common factor


@pytest.mark.slow
def test_compare_on_strecha_fountain(tmp_path, isolated_cache, shared_data):
    """Real images with GT from the .camera files; pycolmap must land within 0.2 deg of GT."""
    out = tmp_path / "fountain"
    args = ["compare", str(shared_data / "strecha_fountain-P11"), "--preset", "small", "--out", str(out),
            "--no-claims", "--methods", "pycolmap-incremental-sift", "ours-euclidean"]
    assert main(args) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["scene"]["downscale"] == 4.0 and m["scene"]["width"] == 768
    for r in m["methods"]:
        assert r["status"] == "ok", (r["name"], r["reason"])
        assert r["metrics"]["registered_images"] == 11
        assert 0.0 < r["gt"]["rotation_error_deg_mean"] < 0.2


def test_default_output_is_gitignored_polarref_out(tmp_path, monkeypatch, isolated_cache):
    """Without --out the job writes ./polarref-out/<scene>/, which git ignores: the tree stays clean."""
    import subprocess
    import uuid

    from polarref.core.data import REPO_ROOT

    if not (REPO_ROOT / ".git").exists():
        pytest.skip(f"{REPO_ROOT} is not a git checkout")
    toy, model, _ = _toy_scene(tmp_path)
    scene = toy.rename(tmp_path / f"toy{uuid.uuid4().hex[:8]}")  # a name no user folder has
    monkeypatch.setattr(pipeline, "run_isolated", lambda job, kw, t, w, tag, reuse=False: JobOutcome(
        "ok", "", 1.0, MethodRun(model_dir=str(model), stage_runtime_s={"mapping": 1.0})
        if job.__name__ == "ours_sfm" else MethodRun(verified_pairs=0)))
    status = lambda: subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=REPO_ROOT,
                                    capture_output=True, text=True, check=True).stdout
    reports = sorted((p.relative_to(REPO_ROOT), p.stat().st_mtime_ns) for p in (REPO_ROOT / "reports").rglob("*"))
    before = status()
    had_out_root = (REPO_ROOT / "polarref-out").exists()
    monkeypatch.chdir(REPO_ROOT)
    out = None
    try:
        assert main(["compare", str(scene), "--no-claims", "--methods", "ours-euclidean"]) == 0
        out = REPO_ROOT / "polarref-out" / f"{scene.name}-default"
        assert (out / "metrics.json").is_file() and (out / "report.html").is_file()
        assert status() == before
    finally:
        if out is not None and out.is_dir():
            shutil.rmtree(out)
        if not had_out_root and (REPO_ROOT / "polarref-out").is_dir() and \
                not any((REPO_ROOT / "polarref-out").iterdir()):
            (REPO_ROOT / "polarref-out").rmdir()
    assert sorted((p.relative_to(REPO_ROOT), p.stat().st_mtime_ns)
                  for p in (REPO_ROOT / "reports").rglob("*")) == reports
