"""Report generation from metrics.json alone: numbers traced to the file, determinism, bad input."""

import copy
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from polarref.cli import main
from polarref.compare import schema
from polarref.compare.report.build import (REPORT_LAYOUT, build_report, improving_accuracy, improving_count,
                                     improving_runtime)
from polarref.core.data import REPO_ROOT
from polarref.core.errors import PolarrefError

EXAMPLE = REPO_ROOT / "reports" / "comet-small"


def _method(name, label, rng, status="ok", reason=""):
    n = 12
    gt = rng.normal(size=(n, 3)) * 100
    plot = {
        "image_names": [f"{i:04d}.png" for i in range(n)],
        "centers_est_aligned": (gt + rng.normal(size=gt.shape)).round(3).tolist(),
        "centers_gt": gt.round(3).tolist(),
        "points_sample": rng.normal(size=(200, 3)).round(3).tolist(),
        "reproj_hist": {"edges": [0.0, 0.5, 1.0], "counts": [int(rng.integers(50, 99)), 7]},
        "rotation_err_hist": {"edges": [0.0, 0.1, 0.2], "counts": [9, 3]},
        "surface_err_hist": None,
    }
    ok = status == "ok"
    return {
        "name": name, "label": label, "family": "ours" if name.startswith("ours") else "pycolmap",
        "features": "ours", "mapper": "polarref-incremental", "ba": name.split("-")[-1],
        "status": status, "reason": reason,
        "runtime_s": float(rng.uniform(1, 9)) if ok else None,
        "stage_runtime_s": {"features": 0.5, "mapping": 1.25} if ok else {},
        "timeout_s": 60.0, "num_images": n,
        "metrics": {"num_images": n, "registered_images": n, "tie_points": int(rng.integers(1000, 5000)),
                    "reprojected_px": int(rng.integers(5000, 20000)),
                    "mean_reprojection_error_px": float(rng.uniform(0.1, 0.9)),
                    "mean_reprojection_error_px_per_point": float(rng.uniform(0.1, 0.9)),
                    "median_reprojection_error_px": 0.25, "mean_track_length": 3.5} if ok else None,
        "gt": {"aligned_images": n, "rotation_error_deg_mean": float(rng.uniform(0.01, 0.3)),
               "rotation_error_deg_median": 0.1, "rotation_error_deg_max": 0.4, "center_error_mean": 0.5,
               "center_error_max": 0.9, "center_error_rel_mean": 0.001, "point_to_surface_mean": None,
               "point_to_surface_median": None, "point_to_surface_p90": None,
               "point_to_surface_rel_median": None, "points_scored": 0} if ok else None,
        "plot": plot if ok else None,
    }


def synthetic_metrics(seed=0) -> dict:
    """A small, valid metrics.json as a dict (one failed method included)."""
    rng = np.random.default_rng(seed)
    methods = [_method("ours-euclidean", "ours (euclidean BA)", rng),
               _method("ours-polar", "ours (polar BA)", rng),
               _method("pycolmap-incremental-sift", "pycolmap incremental", rng, "failed",
                       "pycolmap incremental mapping registered no images")]
    return {
        "schema_version": schema.SCHEMA_VERSION,
        "scene": {"name": "toy", "kind": "synthetic", "source": "comet", "preset": "small", "seed": 0,
                  "num_images": 12, "width": 320, "height": 240, "camera_model": "PINHOLE",
                  "camera_params": [300.0, 300.0, 160.0, 120.0], "has_gt": True, "has_mesh": False,
                  "downscale": 1.0, "render_s": 0.0, "scene_extent": 100.0},
        "environment": {"command": "polarref compare comet --preset small", "created": "2026-01-01T00:00:00+00:00",
                        "versions": {"numpy": "2.4"}, "cpu_count": 2, "mitsuba_variant": "scalar_rgb",
                        "seeds": {"scene": 0}, "preset": "small", "method_timeout_s": 60.0,
                        "total_runtime_s": 12.5},
        "methods": methods,
        "pairs": [{"title": "Euclidean vs polar", "baseline": "ours-euclidean", "candidate": "ours-polar", "note": ""},
                  {"title": "pycolmap vs polar", "baseline": "pycolmap-incremental-sift",
                   "candidate": "ours-polar", "note": ""}],
        "claims": [{"claim_id": "C4", "claim": "1.4x faster", "source": "Table 1", "test": "runtime ratio",
                    "figures": [{"key": "ratio", "label": "speed-up", "value": 1.2345, "unit": "x"},
                                {"key": "n", "label": "points", "value": 4321.0, "unit": "count"}],
                    "sample_size": "1 run", "verdict": "inconclusive",
                    "rationale": "Speed-up {ratio} on {n} points."}],
        "ba_traces": [{"label": "euclidean", "problem": "p", "points": [
            {"iteration": 0, "time_s": 0.0, "cost": 100.0}, {"iteration": 1, "time_s": 0.1, "cost": 1.0}]}],
        "notes": ["a note"],
    }


def _write(tmp_path: Path, data: dict) -> Path:
    d = tmp_path / "rep"
    d.mkdir(exist_ok=True)
    (d / "metrics.json").write_text(json.dumps(data))
    return d


def test_report_numbers_come_from_metrics_json(tmp_path):
    data = synthetic_metrics()
    d = _write(tmp_path, data)
    build_report(d)
    md = (d / "report.md").read_text()
    polar = dict(data["methods"][1]["metrics"])
    assert f"{polar['mean_reprojection_error_px']:.3f}" in md
    assert f"{polar['tie_points']:,}" in md
    assert "Speed-up 1.2345 x on 4,321 points." in md           # rationale filled from figures
    assert "registered no images" in md and "failed" in md      # failed method reported with reason
    # Change numbers in metrics.json only: the rebuilt report follows.
    data["methods"][1]["metrics"]["tie_points"] = 987654
    data["methods"][1]["metrics"]["mean_reprojection_error_px"] = 0.777777
    data["claims"][0]["figures"][0]["value"] = 3.25
    data["environment"]["created"] = "2031-05-06T07:08:09+00:00"
    (d / "metrics.json").write_text(json.dumps(data))
    assert main(["report", str(d)]) == 0
    md2 = (d / "report.md").read_text()
    assert "987,654" in md2 and "0.778" in md2 and "Speed-up 3.2500 x" in md2
    assert "2031-05-06T07:08:09+00:00" in md2
    assert f"{polar['tie_points']:,}" not in md2
    # Improving column: candidate minus baseline tie points, computed from the file's values.
    base_tp = data["methods"][0]["metrics"]["tie_points"]
    assert f"↑ {987654 - base_tp:,}" in md2


def test_report_is_deterministic_and_self_contained(tmp_path):
    d = _write(tmp_path, synthetic_metrics(1))
    build_report(d)
    first = {p: (d / p).read_bytes() for p in ("report.md", "report.html")}
    build_report(d)
    assert first == {p: (d / p).read_bytes() for p in ("report.md", "report.html")}
    html = first["report.html"].decode()
    assert html.count("data:image/png;base64,") == len(list((d / "figures").glob("*.png"))) >= 3
    assert 'src="figures/' not in html                           # nothing linked outside the page
    # No date other than the stored one.
    dates = set(re.findall(r"\d{4}-\d{2}-\d{2}", first["report.md"].decode()))
    assert dates == {"2026-01-01"}


def test_existing_files_are_kept(tmp_path):
    d = _write(tmp_path, synthetic_metrics())
    (d / "my-notes.txt").write_text("keep me")
    build_report(d)
    assert (d / "my-notes.txt").read_text() == "keep me"


@pytest.mark.parametrize("mutate, message", [
    (lambda m: m.update(schema_version=99), "schema_version"),
    (lambda m: m["scene"].update(bogus=1), "unknown key"),
    (lambda m: m["methods"][0]["metrics"].update(tie_points="many"), "integer"),
    (lambda m: m["methods"][0]["metrics"].update(mean_reprojection_error_per_point_px=0.1), "unknown key"),
    (lambda m: m["methods"][0].update(tie_points=5), "unknown key"),   # v1's per-method names, in a v2 file
    (lambda m: m["environment"].update(versions=["numpy"]), r"environment\.versions should be an object"),
])
def test_bad_metrics_json_is_a_clear_error(tmp_path, mutate, message):
    data = synthetic_metrics()
    mutate(data)
    d = _write(tmp_path, data)
    with pytest.raises(PolarrefError, match=message):
        build_report(d)


def test_report_cli_bad_input(tmp_path, capsys):
    assert main(["report", str(tmp_path / "missing")]) == 1
    assert "not found" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 1
    assert "no metrics.json" in capsys.readouterr().err


def test_schema_round_trip():
    data = synthetic_metrics(2)
    m = schema.from_dict(copy.deepcopy(data))
    assert json.loads(schema.dumps(m)) == schema.to_dict(m)
    assert schema.to_dict(m)["methods"][1]["metrics"] == {**data["methods"][1]["metrics"], "gt": None, "surface": None}


def test_improving_column_rules():
    assert improving_accuracy(0.482, 0.481) == "Equivalent"          # the paper's Table 1
    assert improving_accuracy(0.50, 0.40).startswith("↑ 0.100")
    assert improving_accuracy(0.40, 0.50).startswith("↓ 0.100")
    assert improving_runtime(77.0, 56.0) == "↑ 21.00 s (×1.38)"      # Table 1: 77 -> 56
    assert improving_runtime(56.0, 77.0).startswith("↓ 21.00 s slower")
    assert improving_count(200355, 200708) == "↑ 353"
    assert improving_count(10, 4) == "↓ 6"


def test_committed_example_rebuilds_identically(tmp_path):
    """The committed example report is exactly what ``polarref report`` builds from its metrics.json.

    PNG bytes are not compared (matplotlib/freetype versions change pixels); in report.html the
    embedded images are replaced by a placeholder before the diff. An example written by an older
    report layout (``REPORT_LAYOUT``, a <meta> tag in report.html) is skipped with the command that
    regenerates it: a layout change is a deliberate regeneration, not a silent drift.
    """
    if not (EXAMPLE / "metrics.json").is_file():
        pytest.skip(f"no committed example report at {EXAMPLE}")
    found = re.search(r'name="polarref-report-layout" content="(\d+)"', (EXAMPLE / "report.html").read_text())
    if found is None or int(found.group(1)) != REPORT_LAYOUT:
        pytest.skip(f"{EXAMPLE} was built by report layout {found.group(1) if found else 1}, this code writes "
                    f"{REPORT_LAYOUT}: regenerate it with scripts/regen-reports.sh")
    d = tmp_path / "example"
    d.mkdir()
    shutil.copy(EXAMPLE / "metrics.json", d / "metrics.json")
    build_report(d)
    strip = lambda s: re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "data:image/png;base64,...", s)
    assert (d / "report.md").read_text() == (EXAMPLE / "report.md").read_text()
    assert strip((d / "report.html").read_text()) == strip((EXAMPLE / "report.html").read_text())
    assert sorted(p.name for p in (d / "figures").glob("*.png")) == \
        sorted(p.name for p in (EXAMPLE / "figures").glob("*.png"))
