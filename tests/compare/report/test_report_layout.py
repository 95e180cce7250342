"""Answer-first report layout, short scorecard lines, generic environment, 3D-view data, index page."""

import base64
import dataclasses
import json
import re
from collections import Counter

import numpy as np
import pytest
from test_report_build import _write, synthetic_metrics

from polarref.ba.synthetic import synthetic_reconstruction
from polarref.cli import main
from polarref.compare import schema
from polarref.compare.report import view3d
from polarref.compare.report.build import (SHORT_LINE_CHARS, build_report, commit_text, first_clause,
                                     short_line)
from polarref.core.geometry import Sim3, so3_exp

LONG = ("Success rate per form -- outliers 10%: initial RMS 12.99 px, euclidean 1.0 (0.04 deg, 10 it); "
        "outliers 30%: " + "x " * 200)


def _long_claim(data):
    c = dict(data["claims"][0], claim_id="C8", rationale=LONG, verdict="not supported")
    data["claims"].append(c)
    return data


def test_summary_comes_first_and_details_collapse(tmp_path):
    d = _write(tmp_path, _long_claim(synthetic_metrics()))
    build_report(d)
    md, page = (d / "report.md").read_text(), (d / "report.html").read_text()
    order = [md.index(s) for s in ("### Main comparison", "### Verdicts", "## Figures", "## Claims in detail",
                                   "### Methods", "### Environment")]
    assert order == sorted(order)
    summary = page[page.index('<section id="summary">'):page.index("</section>")]
    assert "<table>" in summary and "Accuracy (px)" in summary and summary.count('class="badge v-') == 2
    assert 'class="badge v-not-supported"' in summary and 'class="badge v-inconclusive"' in summary
    assert page.index('<section id="summary">') < page.index("<figure")
    assert page.count("<details>") >= 2 + 4          # one per claim + comparisons, methods, GT, environment
    assert "total runtime 12.50 s" in md              # runtime from the stored environment


def test_scorecard_cells_are_one_short_line_and_the_full_text_stays(tmp_path):
    d = _write(tmp_path, _long_claim(synthetic_metrics()))
    build_report(d)
    md = (d / "report.md").read_text()
    table = md[md.index("## Claims in detail"):].split("\n\n")[2]
    rows = [r for r in table.splitlines() if r.startswith("| C")]
    assert len(rows) == 2
    for row in rows:
        measured = re.split(r"(?<!\\)\|", row)[4].strip()
        assert 0 < len(measured) <= SHORT_LINE_CHARS and "\n" not in measured
    assert "euclidean 1.0 (0.04 deg, 10 it)" in rows[1] and "outliers 30%" not in rows[1]
    assert LONG.strip() in md                          # the whole rationale is in the claim's details


@pytest.mark.parametrize("text, expected", [
    ("A 0.5 px gain (i.e. small; see C3); rest", "A 0.5 px gain (i.e. small; see C3)"),
    ("First sentence. Second one.", "First sentence"),
    ("values 1.5 vs 2.5, i.e. worse. Next", "values 1.5 vs 2.5, i.e. worse"),
    ("no break at all", "no break at all"),
])
def test_first_clause(text, expected):
    assert first_clause(text) == expected


def test_first_clause_cuts_at_a_word():
    line = first_clause("word " * 100)
    assert line.endswith("…") and len(line) <= SHORT_LINE_CHARS and "wor…" not in line


def test_claim_summary_template_wins(tmp_path):
    m = schema.from_dict(synthetic_metrics())
    m.claims[0].summary = "speed-up {ratio}"
    assert short_line(m.claims[0]) == "speed-up 1.2345 x"


def test_environment_is_rendered_generically_with_the_commit(tmp_path):
    """Fields added to Environment later (issue 12: git provenance) appear without report changes."""
    m = schema.from_dict(synthetic_metrics())
    assert commit_text(m) == "n/a"
    Env = dataclasses.make_dataclass("Env", [("provenance", dict, dataclasses.field(default_factory=dict))],
                                    bases=(schema.Environment,))
    m.environment = Env(**dataclasses.asdict(m.environment),
                        provenance={"git_commit": "0123456789abcdef", "git_dirty": True, "host": "box"})
    assert commit_text(m) == "0123456789 (dirty)"
    d = tmp_path / "r"
    d.mkdir()
    build_report(d, m)
    md = (d / "report.md").read_text()
    assert "commit `0123456789 (dirty)`" in md
    assert "| provenance.host | box |" in md and "| versions.numpy | 2.4 |" in md


def _aligned_pair(seed=3):
    """(estimate, truth): the estimate is the truth under a known similarity, so alignment is exact."""
    _, truth = synthetic_reconstruction(10, 300, seed=seed, noise_px=0.0)
    est_from_gt = Sim3(2.5, so3_exp(np.array([0.3, -0.2, 0.5])), np.array([1.0, -2.0, 0.5]))
    est = type(truth)(cameras=dict(truth.cameras))
    for i, im in truth.images.items():
        est.images[i] = dataclasses.replace(im, cam_from_world=est_from_gt.transform_pose(im.cam_from_world))
    for k, p in truth.points3D.items():
        est.points3D[k] = dataclasses.replace(p, xyz=est_from_gt.apply(p.xyz))
    return est, truth


def test_view_data_is_aligned_quantized_and_subsampled():
    est, truth = _aligned_pair()
    view = view3d.new_view(truth, truth.cameras[1], None, seed=0)
    assert view3d.add_method(view, "ours-euclidean", "ours", est, truth, seed=0)
    gt_cams, est_cams = np.array(view.cameras[0].poses), np.array(view.cameras[1].poses)
    np.testing.assert_allclose(est_cams[:, :3], gt_cams[:, :3], atol=1e-5 * np.abs(gt_cams[:, :3]).max())
    np.testing.assert_allclose(np.abs((est_cams[:, 3:] * gt_cams[:, 3:]).sum(1)), 1.0, atol=1e-6)
    cloud = view.clouds[0]
    xyz, _ = view3d.decode_cloud(cloud)
    _, want = truth.points_array()
    assert cloud.count == cloud.total == 300 and cloud.dropped == 0
    assert np.abs(xyz - want).max() <= 0.5 * max(cloud.step) + 1e-9      # rounding, nothing else
    assert len(base64.b64decode(cloud.xyz_u16)) == 6 * 300


def test_view_cloud_cap_seed_and_outliers():
    rng = np.random.default_rng(0)
    xyz = np.vstack([rng.normal(size=(5000, 3)), [[1e6, 0, 0], [0, -1e6, 0], [np.nan, 0, 0]]])
    a = view3d.quantize_cloud("k", "k", "dense", xyz, None, seed=1, cap=1000)
    b = view3d.quantize_cloud("k", "k", "dense", xyz, None, seed=1, cap=1000)
    c = view3d.quantize_cloud("k", "k", "dense", xyz, None, seed=2, cap=1000)
    assert a.count == 1000 and a.total == 5003 and a.dropped == 3
    assert a == b and a.xyz_u16 != c.xyz_u16
    assert np.abs(view3d.decode_cloud(a)[0]).max() < 10


def test_dense_cloud_is_capped_and_replaced():
    est, truth = _aligned_pair()
    view = view3d.new_view(truth, truth.cameras[1], None, seed=0)
    pts = np.random.default_rng(1).normal(size=(view.max_dense_points + 500, 3))
    view3d.add_dense(view, "ours-euclidean", "ours", pts, None)
    view3d.add_dense(view, "ours-euclidean", "ours", pts[:100], None)
    dense = [c for c in view.clouds if c.kind == "dense"]
    assert len(dense) == 1 and dense[0].count == 100


def test_view_round_trips_through_metrics_json_and_lands_in_the_page(tmp_path):
    est, truth = _aligned_pair()
    data = synthetic_metrics()
    m = schema.from_dict(data)
    m.view3d = view3d.new_view(truth, truth.cameras[1], None, seed=0)
    view3d.add_method(m.view3d, "ours-euclidean", "ours (euclidean BA)", est, truth, 0)
    d = tmp_path / "r"
    schema.save(m, d / "metrics.json")
    assert main(["report", str(d)]) == 0                 # rebuilt from the file alone
    page = (d / "report.html").read_text()
    payload = json.loads(re.search(r'<script type="application/json" id="view3d-data">(.*?)</script>',
                                   page, re.S).group(1))
    assert payload["clouds"][0]["xyz_u16"] == m.view3d.clouds[0].xyz_u16
    assert payload["visible"] == sorted({"gt", "gt-surface", "ours-euclidean", "ours-polar"})
    assert "http://" not in page and "https://" not in page  # nothing to fetch: works offline
    assert "at most 2,000 sparse" in (d / "report.md").read_text()


def test_new_figures_from_plot_data(tmp_path):
    from polarref.compare.run.scoring import score

    est, truth = _aligned_pair()
    s = score(est, truth, None, seed=0)
    want = Counter(len(p.track) for p in est.points3D.values())
    h = s.plot.track_length_hist
    assert sum(h.counts) == len(est.points3D)
    for k, n in zip(h.edges[:-2], h.counts[:-1]):
        assert n == want.get(int(k), 0)
    assert len(s.plot.rotation_err_deg) == 10 and max(s.plot.rotation_err_deg) < 1e-6
    data = synthetic_metrics()
    for meth in data["methods"][:2]:
        meth["plot"]["rotation_err_deg"] = [0.1] * 12
        meth["plot"]["track_length_hist"] = {"edges": [2.0, 3.0, 4.0], "counts": [5, 2]}
    d = _write(tmp_path, data)
    written = build_report(d)
    assert {"per_image", "histograms"} <= {f.key for f in written.figures}


def test_index_page_over_report_folders(tmp_path, capsys):
    root = tmp_path / "all"
    for name, seed in (("one", 0), ("two", 1)):
        d = root / name
        d.mkdir(parents=True)
        data = synthetic_metrics(seed)
        data["scene"]["name"] = f"scene-{name}"
        (d / "metrics.json").write_text(json.dumps(data))
    build_report(root / "one")
    (root / "broken").mkdir()
    (root / "broken" / "metrics.json").write_text("{")
    assert main(["report", "--index", str(root)]) == 0
    md = (root / "index.md").read_text()
    assert "[one](one/report.html)" in md and "[two](two/metrics.json)" in md   # no page built for two
    assert "scene-one" in md and "scene-two" in md and "`broken`" in md and "not valid JSON" in md
    assert "| C4 | 1.4x faster | inconclusive | inconclusive |" in md
    assert '<a href="one/report.html">one</a>' in (root / "index.html").read_text()
    assert main(["report", "--index", str(tmp_path / "nothing")]) == 1
    assert "not found" in capsys.readouterr().err
