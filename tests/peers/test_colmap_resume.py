"""pycolmap incremental mapping that resumes from its snapshots (polarref.peers.colmap_resume)."""

import time

import pytest

from polarref.core import records
from polarref.compare.twins import tables as PT
from polarref.core.status import RunStatus
from polarref.peers.colmap_resume import LEDGER, MapperLedger, MapperSegment, _start_point, map_incremental_resumable
from polarref.peers.colmap_sfm import ColmapSfMOptions, extract_and_match_sift

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def small_db(comet_small_scene, tmp_path_factory):
    from polarref.compare.run.presets import DEFAULT
    from polarref.compare.run.scenes import prepare

    scene = prepare(str(comet_small_scene), DEFAULT, 0)
    db = tmp_path_factory.mktemp("resume") / "database.db"
    extract_and_match_sift(scene.image_dir, scene.camera, db, ColmapSfMOptions(seed=0, num_threads=1),
                           image_names=list(scene.image_names))
    return db, scene


def test_an_interrupted_mapping_resumes_from_its_last_snapshot(small_db, tmp_path):
    db, scene = small_db
    opts = ColmapSfMOptions(seed=0, num_threads=1)
    whole, whole_ledger = map_incremental_resumable(db, scene.image_dir, tmp_path / "whole", opts, snapshot_every=2)
    n = whole.reconstruction.num_reg_images()
    assert n == len(scene.image_names) == 12
    assert len(whole_ledger.segments) == 1 and whole_ledger.segments[0].resumed_from == ""

    work = tmp_path / "cut"
    with pytest.raises(InterruptedError):  # what a kill leaves: no model, an unfinished segment
        map_incremental_resumable(db, scene.image_dir, work, opts, snapshot_every=2, cancel_after_images=5)
    first = records.load(MapperLedger, work / LEDGER).segments[0]
    assert first.finished_epoch_s is None and first.last_snapshot
    assert 0.0 < first.counted_s < time.time() - first.start_epoch_s

    resumed, ledger = map_incremental_resumable(db, scene.image_dir, work, opts, snapshot_every=2)
    second = ledger.segments[1]
    assert second.resumed_from == first.last_snapshot
    assert 2 <= second.registered_at_start < n  # it continued a partial model, not a fresh start
    assert resumed.reconstruction.num_reg_images() == n
    assert resumed.stage_runtime_s["mapping"] == pytest.approx(first.counted_s + second.counted_s)
    # same images, same correspondences: the resumed model is as good as the uninterrupted one
    e_whole = whole.reconstruction.compute_mean_reprojection_error()
    e_resumed = resumed.reconstruction.compute_mean_reprojection_error()
    assert 0.05 < e_resumed < 1.0 and abs(e_resumed - e_whole) < 0.25 * e_whole
    assert resumed.reconstruction.num_points3D() == pytest.approx(whole.reconstruction.num_points3D(), rel=0.1)


def _ledger(work, **last):
    seg = MapperSegment("2026-01-01T00:00:00Z", 1000.0, **last)
    records.save(MapperLedger([seg]), work / LEDGER)


def test_start_point_drops_partial_snapshots_and_restarts_finished_or_lost_runs(tmp_path):
    snaps = tmp_path / "snapshots"
    for name in ("1000500", "1000900"):  # the second: written after the last callback (partial)
        (snaps / name).mkdir(parents=True)
    _ledger(tmp_path, last_snapshot="1000500", last_snapshot_epoch_s=1000.5)
    ledger, resume = _start_point(tmp_path)
    assert resume == "1000500" and len(ledger.segments) == 1
    assert sorted(p.name for p in snaps.iterdir()) == ["1000500"]

    _ledger(tmp_path, last_snapshot="1000500", finished_epoch_s=1200.0)  # finished, stage not recorded
    ledger, resume = _start_point(tmp_path)
    assert resume == "" and ledger.segments == [] and not any(snaps.iterdir())

    _ledger(tmp_path, last_snapshot="1000500")  # its snapshot is gone: nothing to continue
    assert _start_point(tmp_path)[1] == ""


def test_segments_count_time_up_to_their_last_snapshot():
    assert MapperSegment("t", 100.0, last_snapshot="1", last_snapshot_epoch_s=160.0).counted_s == 60.0
    assert MapperSegment("t", 100.0, last_snapshot="1", last_snapshot_epoch_s=160.0,
                         finished_epoch_s=200.0).counted_s == 100.0
    assert MapperSegment("t", 100.0).counted_s == 0.0  # killed before its first snapshot
    assert MapperLedger([MapperSegment("t", 0.0, finished_epoch_s=5.0),
                         MapperSegment("t", 10.0, last_snapshot_epoch_s=12.0)]).counted_s == 7.0


def test_twin_table_says_when_a_model_took_several_segments():
    kw = dict(status=RunStatus.OK, num_images=631, registered=631, accuracy_px=0.5, efficiency_min=200.0, tie_points=9,
              reprojected_px=99)
    table = PT.TwinTable("rosetta", 631, 10, {
        "pycolmap-incremental-sift": PT.TwinRow("pycolmap-incremental-sift", segments=3, **kw),
        "pycolmap-global-sift": PT.TwinRow("pycolmap-global-sift", **kw)}, None)
    md = PT.render_table(table)
    assert md.count("resumed: 3 segments") == 1 and "resumed: 1" not in md
    back = PT.TwinTable.from_dict(table.to_dict())
    assert back.methods["pycolmap-incremental-sift"].segments == 3
