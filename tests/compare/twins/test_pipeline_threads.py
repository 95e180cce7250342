"""pycolmap in the twins runs on 2 threads by default (issue 34) and the setting is stored."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from polarref.camera import Camera
from polarref.compare.twins import pipeline as P
from polarref.core import records
from polarref.core.status import RunStatus


def _capture(monkeypatch):
    seen = {}

    def fake_run(self, name, job, kwargs):
        seen[name] = kwargs
        return P.StageRecord(name, RunStatus.FAILED, "not run in this test")

    monkeypatch.setattr(P._Stages, "run", fake_run)
    return seen


def test_pycolmap_stages_get_the_runs_thread_count(tmp_path, monkeypatch):
    scene = SimpleNamespace(camera=Camera("PINHOLE", 64, 48, np.array([50.0, 50.0, 32.0, 24.0])),
                            image_dir=Path("imgs"), image_names=["a.png", "b.png"])
    for threads in (2, 1):
        seen = _capture(monkeypatch)
        run = P.TwinRun("mappilot", str(tmp_path), methods=("pycolmap-incremental-sift",), pycolmap_threads=threads)
        recs = P._run_stages(run, scene, tmp_path, tmp_path / "pairs.txt")
        assert seen["pycolmap-features"]["num_threads"] == threads
        assert recs["pycolmap-incremental-sift"][0].status == RunStatus.FAILED
    assert P.TwinRun("mappilot", "x").pycolmap_threads == 2
    # run.json of an older run (no thread field) still reads, with today's default
    (tmp_path / "run.json").write_text('{"twin": "mappilot", "out": "x"}')
    assert P.read_run(tmp_path / "run.json").pycolmap_threads == 2
    assert records.to_dict(P.TwinRun("mappilot", "x", pycolmap_threads=1))["pycolmap_threads"] == 1
