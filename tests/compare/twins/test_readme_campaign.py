"""The README's campaign finding is generated from the committed campaign cells (issue 34)."""

import json
import math
from pathlib import Path

from polarref.compare.twins.readme_campaign import BEGIN, END, findings_block, update_readme
from polarref.core.markers import read_block

ROOT = Path(__file__).resolve().parents[3]
CELLS = ROOT / "reports" / "paper-tables" / "campaign"


def _paired(twin_dir: Path) -> list[tuple[dict, dict]]:
    """(Euclidean, polar) raw cells of every seed under ``twin_dir`` where both ran ok."""
    out = []
    for seed in sorted(twin_dir.glob("seed*")):
        e, p = seed / "ours-euclidean.json", seed / "ours-polar.json"
        if e.is_file() and p.is_file():
            de, dp = json.loads(e.read_text()), json.loads(p.read_text())
            if de["status"] == dp["status"] == "ok":
                out.append((de, dp))
    return out


def test_readme_block_matches_the_committed_cells():
    block = read_block((ROOT / "README.md").read_text(), BEGIN, END)
    assert block is not None, "README lost its campaign-findings markers"
    assert block == findings_block(CELLS), (
        "README campaign finding differs from the cells: run python -m "
        "polarref.compare.twins.readme_campaign reports/paper-tables/campaign README.md")


def test_quoted_speedup_is_the_cells_geometric_mean():
    """Independently of the table code: per twin and commit, the geometric mean over the seeds
    of the raw cells' wall times (Euclidean / polar), and the mapper BA ratios' range."""
    block = findings_block(CELLS)
    checked = 0
    for twin_dir in sorted(p for p in CELLS.glob("*/*") if p.is_dir() and p.name in ("mappilot", "rosetta", "poets-park")):
        pairs = _paired(twin_dir)
        ratios = [de["wall_s"] / dp["wall_s"] for de, dp in pairs]
        ba = [dp["ba_s"] / de["ba_s"] for de, dp in pairs]
        if not ratios:
            continue
        gm = math.exp(sum(map(math.log, ratios)) / len(ratios))
        line = next(x for x in block.splitlines() if f"/{twin_dir.parent.name[:12]}/` `{twin_dir.name}`" in x)
        assert f"Euclidean/polar x{gm:.3f}" in line
        lo, hi = f"{min(ba):.2f}", f"{max(ba):.2f}"
        assert f"polar/Euclidean x{lo if lo == hi else lo + '-' + hi} " in line
        checked += 1
    assert checked >= 1, "no full-size campaign twin with both BAs committed"


def test_update_rewrites_only_between_the_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nstale\n{END}\ntail\n")
    update_readme(readme, CELLS)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "stale" not in text
    assert read_block(text, BEGIN, END) == findings_block(CELLS)


def test_peers_quoted_from_their_cells():
    """A pycolmap cell of one seed: its minutes, tie points and thread count in the twin's line."""
    block = findings_block(CELLS)
    checked = 0
    for cell in sorted(CELLS.glob("*/*/seed*/pycolmap-*.json")):
        d = json.loads(cell.read_text())
        if d["status"] != "ok" or d["twin"] not in ("mappilot", "rosetta", "poets-park"):
            continue
        seeds = sorted(p.name for p in cell.parent.parent.glob(f"seed*/{cell.name}"))
        if len(seeds) != 1:
            continue
        commit = cell.parents[2].name[:12]
        line = next(x for x in block.splitlines() if f"/{commit}/` `{d['twin']}`" in x)
        threads = cell.stem.rsplit("-t", 1)[1]
        assert (f"({threads} thread{'s' if threads != '1' else ''}) seed {d['seed']} only, "
                f"{d['wall_s'] / 60:.1f} min, {d['metrics']['tie_points']:,} tie points") in line
        checked += 1
    assert checked >= 1, "no single-seed pycolmap cell committed"


def test_one_paired_seed_claims_no_interval():
    """A twin with one paired seed states that it has no interval, and one with several quotes one."""
    block = findings_block(CELLS)
    checked = 0
    for twin_dir in sorted(p for p in CELLS.glob("*/*") if p.is_dir() and p.name in ("mappilot", "rosetta", "poets-park")):
        paired = [s for s in twin_dir.glob("seed*")
                  if (s / "ours-euclidean.json").is_file() and (s / "ours-polar.json").is_file()]
        if not paired:
            continue
        line = next(x for x in block.splitlines() if f"/{twin_dir.parent.name[:12]}/` `{twin_dir.name}`" in x)
        assert ("one seed, no interval" in line) == (len(paired) == 1)
        assert ("95% CI" in line) == (len(paired) > 1)
        checked += 1
    assert checked >= 2


def test_complete_pins_summarised_from_the_raw_cells():
    """A pin with every twin and three paired seeds gets one summary line: the mapper BA ratios'
    range over all nine seeds and how many meet x1.3, recomputed here from the raw cells; a pin
    missing a twin or a seed gets none."""
    block = findings_block(CELLS)
    summaries = [x for x in block.splitlines() if x.startswith("- Complete pin")]
    complete = 0
    for pin in sorted(p for p in CELLS.iterdir() if p.is_dir()):
        pairs = {twin: _paired(pin / twin) for twin in ("rosetta", "poets-park", "mappilot")}
        ba = [dp["ba_s"] / de["ba_s"] for twin_pairs in pairs.values() for de, dp in twin_pairs]
        line = [x for x in summaries if f"/{pin.name[:12]}/`" in x]
        if min(len(x) for x in pairs.values()) < 3:
            assert not line, pin.name
            continue
        complete += 1
        (line,) = line
        lo, hi = f"{min(ba):.2f}", f"{max(ba):.2f}"
        assert f"polar/Euclidean x{lo}-{hi}, <= x1.3 on {sum(x <= 1.3 for x in ba)} of 9 seeds." in line
    assert complete >= 1 and complete == len(summaries)
