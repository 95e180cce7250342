"""The README's findings on the committed comparisons are generated from their metrics.json."""

from pathlib import Path

import pytest

from polarref.compare.report.readme_findings import BEGIN, END, findings_block, readme_block, update_readme

ROOT = Path(__file__).resolve().parents[3]


def test_readme_block_matches_the_committed_json():
    block = readme_block((ROOT / "README.md").read_text())
    assert block is not None, "README lost its compare-findings markers"
    assert block == findings_block(ROOT / "reports"), (
        "README findings differ from reports/*/metrics.json: run "
        "python -m polarref.compare.report.readme_findings reports README.md")


def test_block_names_every_committed_comparison_and_its_commit():
    block = findings_block(ROOT / "reports")
    for name in ("comet-default", "comet-small", "strecha_fountain-P11-small"):
        assert f"`reports/{name}/`" in block
    assert "commit " in block and "Verdicts: C1" in block


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nstale figure 0.76\n{END}\ntail\n")
    update_readme(readme, ROOT / "reports")
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale figure" not in text
    readme.write_text("no markers\n")
    with pytest.raises(SystemExit):
        update_readme(readme, ROOT / "reports")
