"""The README's SfM-speed finding is generated from reports/bench-sfm/*bench.json (issue 30)."""

import json
from pathlib import Path

import pytest

from polarref.bench.readme_sfm import BEGIN, END, findings_block, update_readme
from polarref.core.markers import read_block

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "reports" / "bench-sfm"


def test_readme_block_matches_the_committed_json():
    block = read_block((ROOT / "README.md").read_text(), BEGIN, END)
    assert block is not None, "README lost its sfm-findings markers"
    assert block == findings_block(BENCH), (
        "README SfM finding differs from reports/bench-sfm: run python -m polarref.bench.readme_sfm reports/bench-sfm README.md")


def _ratio(path: Path, views: int) -> float:
    """ours / pycolmap total time from the raw JSON (independent of the records and the generator)."""
    cells = {c["method"]: c["total_s"] for c in json.loads(path.read_text())["cells"] if c["views"] == views}
    return cells["ours"] / cells["pycolmap"]


def test_quoted_ratios_are_the_json_ratios_and_the_recheck_is_shown():
    block = findings_block(BENCH)
    assert f"**{_ratio(BENCH / 'bench.json', 168):.2f}x** pycolmap incremental's time at 168 views" in block
    rechecks = sorted(BENCH.glob("recheck-*/bench.json"))
    assert rechecks, "the committed bench has a 168-view recheck"
    for r in rechecks:
        assert f"`reports/bench-sfm/{r.parent.name}/`" in block
        assert f"**{_ratio(r, 168):.2f}x** at 168 views" in block


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nstale 0.56x\n{END}\ntail\n")
    update_readme(readme, BENCH)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale" not in text
    readme.write_text("no markers\n")
    with pytest.raises(SystemExit):
        update_readme(readme, BENCH)
