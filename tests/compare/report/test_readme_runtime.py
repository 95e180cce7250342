"""The README's run-time lines are generated from the committed metrics.json."""

import json
from pathlib import Path

import pytest

from polarref.compare.report.readme_runtime import BEGIN, END, readme_block, runtime_block, update_readme

ROOT = Path(__file__).resolve().parents[3]


def test_readme_block_matches_the_committed_json():
    block = readme_block((ROOT / "README.md").read_text())
    assert block is not None, "README lost its compare-runtime markers"
    assert block == runtime_block(ROOT / "reports"), (
        "README run times differ from reports/*/metrics.json: run "
        "python -m polarref.compare.report.readme_runtime reports README.md")


def test_line_quotes_the_recorded_time_and_commit(tmp_path):
    src = ROOT / "reports" / "comet-small" / "metrics.json"
    if not src.is_file():
        pytest.skip("reports/comet-small/metrics.json is not committed")
    data = json.loads(src.read_text())
    data["environment"].update(total_runtime_s=123.456, git_commit="ab" * 20, git_dirty=True)
    (tmp_path / "comet-small").mkdir()
    (tmp_path / "comet-small" / "metrics.json").write_text(json.dumps(data))
    block = runtime_block(tmp_path)
    assert block.count("\n") == 1
    assert "123.5 s" in block and "commit ababab" in block and "dirty" in block
    assert "--out" not in block and "--overwrite" not in block


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\n246.9 s stale\n{END}\ntail\n")
    update_readme(readme, ROOT / "reports")
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale" not in text
    readme.write_text("no markers\n")
    with pytest.raises(SystemExit):
        update_readme(readme, ROOT / "reports")
