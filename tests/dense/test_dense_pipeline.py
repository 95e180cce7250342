"""``polarref dense`` end to end on a tiny analytic sphere scene, and its bad-input paths."""

import json

import numpy as np
import pytest

from _dense_scene import Sphere, orbit, write_scene
from polarref.cli import main
from polarref.dense.meshing import MeshOptions
from polarref.dense.pipeline import DenseConfig, run_dense  # noqa: F401
from polarref.core.errors import PolarrefError

SPHERE = Sphere([0, 0, 0], 3.0)
# Small enough for the default suite: a coarse Poisson grid and few GT samples.
FAST = DenseConfig(scale=1.0, tau_rel=0.01, score_samples=8000, mesh=MeshOptions(depth=7))


def _scene(root, n=6, blank=False, poses=None):
    poses = poses or orbit([0, 0, 0], 10.0, n, 7.0)
    write_scene(root, SPHERE, poses, 128, 96, 40.0, wavelength=0.1, bounds=([0, 0, 0], 3.2),
                mesh_args=(4,), blank=blank)
    return root


@pytest.fixture(scope="module")
def sphere_run(tmp_path_factory):
    root = _scene(tmp_path_factory.mktemp("sphere"))
    out = tmp_path_factory.mktemp("sphere_out") / "dense"  # outputs never inside the scene
    return root, out, run_dense(root, "gt", out, FAST)


def test_sphere_end_to_end(sphere_run):
    root, out, m = sphere_run
    for name in ("fused.ply", "mesh.ply", "fused_gt.ply", "mesh_gt.ply", "metrics.json"):
        assert (out / name).is_file(), name
    assert m.status == "ok" and m.num_views_with_depth == 6
    # tau = 1% of the diameter 6 = 0.06; the views cover one side, the GT samples only what >= 2 saw.
    assert m.gt.diameter == pytest.approx(6.0, rel=1e-3)
    # Measured: F 0.80 (cloud), 0.82 (mesh); recall is lost at grazing angles.
    assert m.gt.cloud.precision > 0.9 and m.gt.cloud.fscore > 0.7
    assert m.gt.mesh.fscore > 0.7
    assert 0 < m.gt.depth_median_abs < 0.02      # 0.3% of the 7-unit depth
    data = json.loads((out / "metrics.json").read_text())
    assert data["gt"]["cloud"]["fscore"] == pytest.approx(m.gt.cloud.fscore)
    assert set(data["runtime_s"]) >= {"depth", "consistency", "fusion", "meshing", "scoring"}
    assert data["provenance"]["git_commit"] and data["peak_memory_mb"] > 0


def test_fused_cloud_round_trip(sphere_run):
    from polarref.dense.fusion import read_point_cloud

    _, out, m = sphere_run
    cloud = read_point_cloud(out / "fused.ply")
    assert len(cloud) == m.num_fused_points
    # Points lie on the sphere (GT frame = model frame here) and normals point outwards.
    r = np.linalg.norm(cloud.points, axis=1)
    assert np.median(np.abs(r - 3.0)) < 0.02
    assert np.median((cloud.normals * cloud.points).sum(1) / r) > 0.9


def test_out_not_overwritten(sphere_run):
    root, out, _ = sphere_run
    with pytest.raises(PolarrefError, match="not empty"):
        run_dense(root, "gt", out, FAST)


def test_too_few_views(tmp_path, capsys):
    root = _scene(tmp_path / "two", n=2)
    rc = main(["dense", str(root), "--model", "gt", "--out", str(tmp_path / "o"), "--scale", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "2 registered view(s); need at least 3" in err[0]
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["status"] == "failed"


def test_textureless_images_keep_partial_outputs(tmp_path, capsys):
    root = _scene(tmp_path / "blank", n=4, blank=True)
    rc = main(["dense", str(root), "--model", "gt", "--out", str(tmp_path / "o"), "--scale", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and "no view kept a consistent depth" in err[-1]
    assert len(list((tmp_path / "o" / "depth").glob("*.npy"))) == 4
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["status"] == "failed" and any("empty depth map" in w for w in m["warnings"])


def test_view_without_neighbours_is_skipped(tmp_path):
    from synth.conventions import look_at

    poses = orbit([0, 0, 0], 10.0, 5, 7.0)
    # A sixth camera looking away from the sphere: no overlap with anyone.
    poses.append(look_at(np.array([0.0, 0.0, -10.0]), np.array([0.0, 0.0, -20.0]), np.array([0.0, -1.0, 0.0])))
    root = _scene(tmp_path / "away", poses=poses)
    (root / "mesh.ply").unlink()  # no scoring needed here
    m = run_dense(root, "gt", tmp_path / "o", FAST)
    assert m.status == "ok" and m.num_views_with_depth == 5
    assert any("0005.png" in w and "neighbours" in w for w in m.warnings)


@pytest.mark.slow  # ~10-30 s: redraws the whole comet-small report
def test_compare_report_dense_section(sphere_run, tmp_path):
    """The compare hook: typed ``dense`` record round-trips metrics.json; report gets table + figure."""
    import shutil

    from polarref.compare import schema
    from polarref.compare.schema import DenseRun, DenseSection
    from polarref.compare.report.build import build_report
    from polarref.core.data import REPO_ROOT

    _, out, m = sphere_run
    metrics = schema.load(REPO_ROOT / "reports" / "comet-small" / "metrics.json")
    shutil.copytree(out, tmp_path / "dense" / "gt")
    c = m.gt.cloud
    metrics.dense = DenseSection([
        DenseRun("gt", "ok", out_dir="dense/gt", tau=m.gt.tau, tau_rel=m.gt.tau_rel, cloud_fscore=c.fscore,
                 cloud_precision=c.precision, cloud_recall=c.recall, mesh_fscore=m.gt.mesh.fscore,
                 fused_points=m.num_fused_points, dense_runtime_s=m.runtime_s["dense_total"]),
        DenseRun("ours-euclidean", "failed", "dense: no view kept a consistent depth", out_dir="dense/x")])
    schema.save(metrics, tmp_path / "metrics.json")
    back = schema.load(tmp_path / "metrics.json")
    assert back.dense.runs[0].cloud_fscore == pytest.approx(c.fscore)
    paths = build_report(tmp_path, back)
    md = paths.markdown.read_text()
    assert "Dense reconstruction" in md and f"{c.fscore:.3f}" in md and "figures/dense_side_by_side.png" in md
    assert (tmp_path / "figures" / "dense_side_by_side.png").stat().st_size > 10_000
