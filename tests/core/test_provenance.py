"""Provenance: commit, dirty flag, machine, versions -- and the library never needs the CLI."""

import re
import subprocess
import sys

from polarref.core import provenance
from polarref.core.data import REPO_ROOT


def test_collect_matches_git_and_the_machine():
    env = provenance.collect(seeds={"scene": 3}, threads={"pycolmap": 1})
    head = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode == 0:          # a git checkout: the commit and dirty flag are git's own
        assert env["git_commit"] == head.stdout.strip() and re.fullmatch(r"[0-9a-f]{40}", env["git_commit"])
        status = subprocess.run(["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--untracked-files=normal"],
                                capture_output=True, text=True).stdout
        code_changed = [ln for ln in status.splitlines() if not ln[3:].startswith("reports/")]
        assert env["git_dirty"] is bool(code_changed)  # untracked count; regenerated example reports do not
    import numpy
    import pycolmap
    assert env["versions"]["numpy"] == numpy.__version__ and env["versions"]["pycolmap"] == pycolmap.__version__
    assert set(provenance.PACKAGES) | {"polarref", "python"} <= set(env["versions"])
    assert env["cpu_count"] >= 1 and env["machine"] and env["python"] == sys.version.split()[0]
    assert env["seeds"] == {"scene": 3} and env["threads"]["pycolmap"] == 1


def test_outside_a_checkout_is_unknown_not_an_error(tmp_path):
    assert provenance.git_state(tmp_path) == ("", None)


def test_library_does_not_import_the_cli():
    code = ("import sys, polarref.core.provenance, polarref.compare.run.pipeline, polarref.bench.ba, polarref.sfm.pipeline;"
            "polarref.core.provenance.collect(); assert 'polarref.cli' not in sys.modules, 'cli imported'")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT)
    assert proc.returncode == 0, proc.stderr


def test_sfm_metrics_json_records_the_environment(tmp_path):
    """Even a failed `polarref sfm` run writes metrics.json with its provenance."""
    import json

    import pytest

    from polarref.camera import Camera
    from polarref.core.errors import PolarrefError
    from polarref.sfm import run_sfm

    (tmp_path / "images").mkdir()
    with pytest.raises(PolarrefError):
        run_sfm(tmp_path / "images", tmp_path / "out", camera=Camera("PINHOLE", 100, 100, [100, 100, 50, 50]))
    env = json.loads((tmp_path / "out" / "metrics.json").read_text())["environment"]
    assert env == {**env, **{k: provenance.collect()[k] for k in ("git_commit", "cpu_count", "cpu_model", "machine")}}
    assert env["seeds"]["verification"] >= 0 and "registration" in env["seeds"]


def test_report_shows_the_stored_commit(tmp_path):
    """compare's Environment carries the provenance fields; the report's summary line shows them."""
    import dataclasses

    from test_report_build import synthetic_metrics

    from polarref.compare import schema
    from polarref.compare.report.build import commit_text

    m = schema.from_dict(synthetic_metrics())
    m.environment = dataclasses.replace(m.environment, git_commit="0123456789abcdef" * 2 + "01234567",
                                        git_dirty=True, cpu_model="cpu", machine="x86_64", threads={"pycolmap": 1})
    assert commit_text(m) == "0123456789 (dirty)"
    back = schema.from_dict(schema.to_dict(m))          # the new fields round-trip through metrics.json
    assert back.environment == m.environment


def test_an_untracked_file_makes_the_checkout_dirty(tmp_path):
    """A new, untracked module is code the commit does not hold: the run is dirty."""
    def git(*a):
        subprocess.run(["git", "-C", str(tmp_path), *a], check=True, capture_output=True)
    git("init", "-q")
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / ".gitignore").write_text("cache/\n")
    git("add", "-A")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    assert provenance.git_state(tmp_path)[1] is False
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "x.bin").write_text("ignored")
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "r.md").write_text("regenerated report")
    assert provenance.git_state(tmp_path)[1] is False       # ignored files and reports/ do not count
    (tmp_path / "b.py").write_text("y = 2\n")
    assert provenance.git_state(tmp_path)[1] is True
