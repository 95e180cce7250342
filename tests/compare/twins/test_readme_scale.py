"""The README's finding at the paper's scale is generated from reports/paper-tables (issue 30)."""

import json
from pathlib import Path

import pytest

from polarref.compare.twins.readme_scale import BEGIN, END, findings_block, update_readme
from polarref.core.markers import read_block

ROOT = Path(__file__).resolve().parents[3]
TABLES = ROOT / "reports" / "paper-tables"


def test_readme_block_matches_the_committed_json():
    block = read_block((ROOT / "README.md").read_text(), BEGIN, END)
    assert block is not None, "README lost its scale-findings markers"
    assert block == findings_block(TABLES), (
        "README scale finding differs from reports/paper-tables: run "
        "python -m polarref.compare.twins.readme_scale reports/paper-tables README.md")


def test_quoted_figures_are_the_json_figures():
    """Independently of the records: minutes, tie points and the BA ratio from the raw JSON."""
    block = findings_block(TABLES)
    for f in sorted(TABLES.glob("*/paper-table.json")):
        d = json.loads(f.read_text())
        eu, po = d["methods"]["ours-euclidean"], d["methods"]["ours-polar"]
        line = next(x for x in block.splitlines() if f"/{d['twin']}/`" in x)
        assert f"ours Euclidean {eu['registered']}/{d['images']} views in {eu['efficiency_min']:.1f} min" in line
        assert f"ours polar {po['registered']}/{d['images']} views in {po['efficiency_min']:.1f} min" in line
        assert f"({po['tie_points']:,} tie points" in line
        ba = eu["stages_s"]["bundle adjustment"] / po["stages_s"]["bundle adjustment"]
        assert f"BA time Euclidean/polar x{ba:.2f}" in line


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nstale 1.7-2.5x\n{END}\ntail\n")
    update_readme(readme, TABLES)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale" not in text
    readme.write_text("no markers\n")
    with pytest.raises(SystemExit):
        update_readme(readme, TABLES)
