"""scripts/diff_reports.py: figures compared exactly, runtimes and provenance left out."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import pytest
from _scripts import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def diff_reports():
    return load_script("diff_reports")


def _write(path: Path, data) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))
    return path


def test_a_committed_report_equals_itself_and_any_figure_change_is_found(tmp_path, diff_reports, capsys):
    base = json.loads((ROOT / "reports" / "comet-small" / "metrics.json").read_text())
    a = _write(tmp_path / "a" / "metrics.json", base)
    same = copy.deepcopy(base)
    same["environment"]["git_commit"] = "0" * 40                  # provenance
    same["methods"][0]["runtime_s"] = 1e6                           # a runtime
    same["methods"][0]["stage_runtime_s"] = {"mapping": 1.0}
    same["ba_traces"][0]["points"][1]["time_s"] = 99.0
    timing = next(c for c in same["claims"] if any(f["unit"] == "s" for f in c["figures"]))
    timing["verdict"] = "supported" if timing["verdict"] != "supported" else "not supported"
    for f in timing["figures"]:            # ratios, their spread, the slack: all from the clock
        if f["unit"] != "count" and isinstance(f["value"], float):
            f["value"] *= 1.5
    worded = next(c for c in same["claims"] if "; this run: commit " in c["rationale"])
    worded["rationale"] = re.sub(r"this run: commit [0-9a-f]+", "this run: commit 0123456789", worded["rationale"])
    b = _write(tmp_path / "b" / "metrics.json", same)
    assert diff_reports.main([str(a), str(b)]) == 0
    assert diff_reports.main([str(tmp_path / "a"), str(tmp_path / "b")]) == 0   # folders
    changed = copy.deepcopy(base)
    ok = next(m for m in changed["methods"] if m["metrics"])
    ok["metrics"]["tie_points"] += 1
    c = _write(tmp_path / "c" / "metrics.json", changed)
    capsys.readouterr()
    assert diff_reports.main([str(a), str(c)]) == 1
    out = capsys.readouterr().out
    assert "metrics.tie_points" in out and out.splitlines()[-1].startswith("1 difference(s)")
    reworded = copy.deepcopy(base)   # the wording outside the provenance clause is compared
    worded = next(c for c in reworded["claims"] if "; this run: commit " in c["rationale"])
    worded["rationale"] = worded["rationale"].replace("Pre-registration:", "Preregistration:")
    counted = copy.deepcopy(base)    # a count of a timing claim is the method's, not the clock's
    timing = next(c for c in counted["claims"] if any(f["unit"] == "s" for f in c["figures"]))
    next(f for f in timing["figures"] if f["unit"] == "count")["value"] += 1
    for name, data in (("e", reworded), ("f", counted)):
        assert diff_reports.main([str(a), str(_write(tmp_path / name / "metrics.json", data))]) == 1
    tiny = copy.deepcopy(base)
    ok = next(m for m in tiny["methods"] if m["metrics"])
    ok["metrics"]["mean_reprojection_error_px"] *= 1 + 1e-13
    d = _write(tmp_path / "d" / "metrics.json", tiny)
    assert diff_reports.main([str(a), str(d)]) == 1                   # exact by default
    assert diff_reports.main(["--rtol", "1e-9", str(a), str(d)]) == 0


def test_usage_errors_exit_2(tmp_path, diff_reports, capsys):
    a = _write(tmp_path / "a.json", {"x": 1})
    assert diff_reports.main([str(a), str(tmp_path / "missing.json")]) == 2
    (tmp_path / "bad.json").write_text("{not json")
    assert diff_reports.main([str(a), str(tmp_path / "bad.json")]) == 2
    assert diff_reports.main([str(a), str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("error:") == 3


def test_json_record_names_both_sides_commits_and_the_differences(tmp_path, diff_reports):
    env_a = {"git_commit": "a" * 40, "git_dirty": False, "machine": "x"}
    a = _write(tmp_path / "a" / "metrics.json", {"environment": env_a, "n": 3, "wall_s": 1.0})
    _write(tmp_path / "b" / "metrics.json", {"environment": dict(env_a, git_commit="b" * 40), "n": 4, "wall_s": 2.0})
    out = tmp_path / "diff.json"
    assert diff_reports.main([str(a.parent), str(tmp_path / "b"), "--json", str(out)]) == 1
    got = json.loads(out.read_text())
    assert got["differences"] == ["metrics.json.n: 3 != 4"] and got["compared"] == 1
    assert [c["git_commit"] for c in got["a_commits"]] == ["a" * 40]
    assert [c["git_commit"] for c in got["b_commits"]] == ["b" * 40]
    assert got["environment"]["git_commit"] is not None
