"""The scene replication of C3-C5 (polarref.compare.run.replication, issue 30)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from polarref.compare.run import replication as rp
from polarref.compare import schema
from polarref.compare.claims.preregistration import PREREG, load
from polarref.compare.run.replication_render import render
from polarref.core.errors import PolarrefError
from polarref.core.status import RunStatus

ROOT = Path(__file__).resolve().parents[3]
COMMITTED = ROOT / "reports" / "comet-small" / "metrics.json"


def _scene(folder: str, **verdicts) -> rp.SceneOutcome:
    claims = [rp.SceneClaim(k, v, "") for k, v in verdicts.items()]
    return rp.SceneOutcome(folder, folder, 0, False, RunStatus.OK if claims else RunStatus.SKIPPED, claims=claims)


def test_plan_has_three_seeds_and_the_fountain():
    plan = PREREG.replication
    assert plan is not None and len(plan.scene_seeds) >= 3 and "strecha_fountain-P11" in plan.real_sets
    assert set(plan.claims) == {"C3", "C4", "C5"} and not set(plan.claims) & set(rp.SCENE_INDEPENDENT)
    specs = rp.planned_scenes(plan, Path("/data"))
    assert [s.seed for s in specs if not s.real] == list(plan.scene_seeds)
    assert specs[-1].argument == "/data/strecha_fountain-P11" and specs[-1].real
    assert len({s.folder for s in specs}) == len(specs)


def test_replicated_only_when_every_scene_agrees():
    a = _scene("a", C3="supported", C4="not supported", C5="not supported")
    b = _scene("b", C3="supported", C4="supported", C5="not supported")
    missing = _scene("c")
    got = {r.claim_id: r.replicated for r in rp.rows([a, b], ("C3", "C4", "C5"))}
    assert got == {"C3": "yes", "C4": "no", "C5": "yes"}
    # a scene that did not run leaves the claim unreplicated, never replicated on fewer scenes
    got = {r.claim_id: r.replicated for r in rp.rows([a, a, missing], ("C3",))}
    assert got == {"C3": "no"}
    assert rp.rows([missing], ("C3",))[0].replicated == "not tested"


def test_judge_matches_the_committed_single_run_rule():
    """The scene verdicts equal what the committed scorecard states its single-run rule gives."""
    m = schema.load(COMMITTED)
    out = rp.judge(rp.SceneOutcome("x", "comet", 0, False, RunStatus.SKIPPED), m)
    assert out.status == RunStatus.OK and out.num_images == m.scene.num_images
    for c in m.claims:
        if c.claim_id in ("C3", "C4", "C5"):
            said = re.search(r"single-run rule alone gives: ([a-z ]+)\)", c.rationale)
            assert said is not None, c.claim_id
            assert out.verdict(c.claim_id) == said.group(1)
    assert all("{" not in c.text for c in out.claims)        # every placeholder filled


def test_missing_real_set_is_skipped_and_finished_scene_is_reused(tmp_path, monkeypatch):
    plan = PREREG.replication
    monkeypatch.setattr(rp, "compare_command", lambda *a: pytest.fail("compare must not run"))
    gone = rp.SceneSpec("fountain-small", str(tmp_path / "absent"), 0, True)
    out = rp.run_scene(gone, plan, tmp_path, 10)
    assert out.status == RunStatus.SKIPPED and "data not found" in out.reason
    spec = rp.SceneSpec("comet-small-seed0", "comet", 0, False)
    (tmp_path / spec.folder).mkdir()
    shutil.copy(COMMITTED, tmp_path / spec.folder / "metrics.json")
    out = rp.run_scene(spec, plan, tmp_path, 10)
    assert out.status == RunStatus.OK and out.reused and [c.claim_id for c in out.claims] == ["C3", "C4", "C5"]
    rep = rp.ReplicationReport(rp.collect_record(), "abc", False, plan.measure, plan.preset,
                               list(plan.methods), [out, out], rp.rows([out, out], plan.claims), [], 1.0,
                               [0.0] * 3, [0.0] * 3)
    text = render(rep)
    assert "| claim | comet-small-seed0 (seed 0) | comet-small-seed0 (seed 0) | replicated |" in text
    assert f"| C3 | {out.verdict('C3')} | {out.verdict('C3')} | yes |" in text


def test_malformed_replication_section_is_one_error(tmp_path):
    text = PREREG.path.read_text().replace("scene_seeds = [1, 2, 3]", "scene_seeds = [1, 1]")
    bad = tmp_path / "p.toml"
    bad.write_text(re.sub(r'real_sets = \[.*\]', "real_sets = []", text))
    with pytest.raises(PolarrefError, match="replication"):
        load(bad)


def test_cli_refuses_to_replace_a_finished_report(tmp_path):
    (tmp_path / "replication.json").write_text(json.dumps({}))
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "replication_report.py"), "--out", str(tmp_path)],
                       capture_output=True, text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin"})
    assert r.returncode == 2 and "--overwrite" in r.stderr and "Traceback" not in r.stderr
