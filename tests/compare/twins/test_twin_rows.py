"""A twin table's row is built from the MethodRuns of the method's stages (issue 29)."""

import pytest

from polarref.compare.twins import pipeline as TP
from polarref.compare.twins import tables as PT
from polarref.core.status import RunStatus
from polarref.model.run import MethodRun
from polarref.model.scores import ReconstructionMetrics


def _metrics():
    return ReconstructionMetrics(num_images=10, registered_images=9, tie_points=500, reprojected_px=2100,
                                 mean_reprojection_error_px=0.42, mean_reprojection_error_px_per_point=0.4,
                                 median_reprojection_error_px=0.35, mean_track_length=4.2)


def test_row_sums_the_stage_runs_and_takes_their_peak_and_segments(monkeypatch):
    monkeypatch.setattr(TP, "score_model", lambda model_dir, gt: _metrics())
    feats = TP.StageRecord("ours-features", RunStatus.OK, wall_s=30.0, result=MethodRun(
        "ours-features", stage_runtime_s={"features": 10.0, "matching": 15.0}, peak_rss_mb=300.0))
    sfm = TP.StageRecord("ours-polar", RunStatus.OK, wall_s=90.0, result=MethodRun(
        "ours-polar", stage_runtime_s={"mapping (excl. BA)": 40.0, "bundle adjustment": 35.0}, peak_rss_mb=450.0,
        model_dir="m", counted_wall_s=150.0, segments=2))
    row = TP.table_row(PT.OURS, [feats, sfm], 10, None)
    assert isinstance(row, PT.TwinRow) and row.status is RunStatus.OK and row.reason == ""
    assert row.stages_s == {"features": 10.0, "matching": 15.0, "mapping (excl. BA)": 40.0, "bundle adjustment": 35.0}
    assert row.efficiency_min == pytest.approx((30.0 + 150.0) / 60.0)   # a resumed stage counts its segments
    assert (row.peak_rss_mb, row.segments, row.registered, row.tie_points) == (450.0, 2, 9, 500)
    assert row.accuracy_px == 0.42 and row.rotation_error_deg is None


def test_row_of_a_failed_stage_keeps_its_status_and_names_the_stage():
    feats = TP.StageRecord("ours-features", RunStatus.OK, wall_s=30.0, result=MethodRun("ours-features"))
    late = TP.StageRecord("ours-polar", RunStatus.TIMEOUT, "over 14400 s", wall_s=14400.0)
    row = TP.table_row(PT.OURS, [feats, late], 10, None)
    assert row.status is RunStatus.TIMEOUT and row.reason == "ours-polar: over 14400 s"
    assert row.efficiency_min is None and PT.table_cell(row, "tie_points") == "timeout"
    assert PT.status_text(PT.TwinRow(PT.BASELINE)) == PT.NOT_RUN
