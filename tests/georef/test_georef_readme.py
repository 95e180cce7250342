"""The README's aerotriangulation findings are generated from the committed tables."""

import dataclasses
import json
from pathlib import Path

from polarref.georef.predict import PredictedRMSE
from polarref.georef.readme import BEGIN, END, findings_block, readme_block, update_readme
from polarref.georef.table import AerotriTable, Variant

ROOT = Path(__file__).resolve().parents[2]


def test_readme_block_matches_the_committed_tables():
    block = readme_block((ROOT / "README.md").read_text())
    assert block is not None, "README lost its aerotri-findings markers"
    assert block == findings_block(ROOT / "reports"), (
        "README aerotriangulation findings differ from the committed tables: run "
        "python -m polarref.georef.readme reports README.md")


def test_line_quotes_the_table_ratios(tmp_path):
    """A committed table (its first priors-only row) with the prediction halved and a realised
    prediction set: the line quotes the ratios to both."""
    src = sorted((ROOT / "reports").glob("aerotriangulation-*/aerotriangulation.json"))[0]
    t = AerotriTable.from_json(json.loads(src.read_text()))
    p = t.predicted
    half = PredictedRMSE(p.rmse_x / 2, p.rmse_y / 2, p.rmse_z / 2, p.rmse_horizontal / 2)
    ours = [r for r in t.rows if r.method == "polarref" and r.variant == Variant.PRIORS_ON]
    h = ours[0].record.check.rmse_horizontal / half.rmse_horizontal
    z = ours[0].record.check.rmse_z / half.rmse_z
    real = PredictedRMSE(1.0, 1.0, ours[0].record.check.rmse_z / 1.25, ours[0].record.check.rmse_horizontal / 0.8)
    (tmp_path / "aerotriangulation-x").mkdir()
    dataclasses.replace(t, predicted=half, realised=real, rows=(ours[0],)).write(tmp_path / "aerotriangulation-x")
    line = findings_block(tmp_path)
    assert line.count("\n") == 1 and line.startswith("- `reports/aerotriangulation-x/`")
    assert f"priors only: {h:.2f}x (horizontal) and {z:.2f}x (vertical) the expectation" in line
    assert "0.80x and 1.25x what the scene's own prior errors predict" in line


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nstale 1.71 m\n{END}\ntail\n")
    update_readme(readme, ROOT / "reports")
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale" not in text
