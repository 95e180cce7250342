"""The README's SfM-speed finding is generated from reports/bench-sfm/level/bench.json (issues 30, 34)."""

import dataclasses
import json
from pathlib import Path

import pytest

from polarref.bench.readme_sfm import BEGIN, END, findings_block, level_line, update_readme
from polarref.bench.records import SfMChecks, read_bench
from polarref.core.markers import read_block

ROOT = Path(__file__).resolve().parents[2]
LEVEL = ROOT / "reports" / "bench-sfm" / "level"


def test_readme_block_matches_the_committed_json():
    block = read_block((ROOT / "README.md").read_text(), BEGIN, END)
    assert block is not None, "README lost its sfm-findings markers"
    assert block == findings_block(LEVEL), (
        "README SfM finding differs from reports/bench-sfm/level: "
        "run python -m polarref.bench.readme_sfm reports/bench-sfm/level README.md")


def _median(raw: dict, label: str, views: int, key: str) -> float:
    return next(r[key]["median"] for r in raw["rows"] if r["label"] == label and r["views"] == views)


def test_quoted_ratio_is_the_ratio_of_the_raw_medians():
    """Recomputed from the raw JSON, independent of the records and of the bench's own checks."""
    raw = json.loads((LEVEL / "bench.json").read_text())
    ratio = _median(raw, "ours-2w", 168, "total_s") / _median(raw, "pycolmap-2t", 168, "total_s")
    assert 0.05 < ratio < 20
    assert f"**{ratio:.2f}x** pycolmap's wall time with both on 2 cores" in findings_block(LEVEL)
    assert "Indicative only" in findings_block(LEVEL)


def test_missing_cells_say_not_tested():
    bench = read_bench(LEVEL / "bench.json")
    empty = dataclasses.replace(bench, rows=[r for r in bench.rows if r.views != 168], checks=SfMChecks())
    line = level_line(empty, "x")
    assert "not tested" in line and "**" not in line.split("tie points by one rule.")[1]


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nstale 0.56x\n{END}\ntail\n")
    update_readme(readme, LEVEL)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale" not in text
    readme.write_text("no markers\n")
    with pytest.raises(SystemExit):
        update_readme(readme, LEVEL)
