"""``polarref dense``: views -> depth maps -> consistency filter -> fused cloud -> mesh -> scores.

Outputs in OUT: ``depth/<image stem>.npy`` (filtered z-depth per view, working resolution, model
units), ``fused.ply``, ``mesh.ply`` (model frame), ``fused_gt.ply`` / ``mesh_gt.ply`` (GT frame,
when the scene has GT cameras), ``metrics.json`` (:class:`DenseMetrics`). Each file is written
as soon as its stage finishes, so a later failure leaves the earlier products in place.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from polarref.core.atomic import (atomic_open, check_dir_target, check_writable_parent, holds_finished_result,
                                  publish_dir, refuse_inside_inputs)
from polarref.dense import consistency, depth as depth_mod, fusion, meshing, scoring, views as views_mod
from polarref.dense.model_check import ModelCheck, check_model, verdict
from polarref.dense.provenance import Provenance, collect
from polarref.metrics import align_to_gt
from polarref.core.errors import PolarrefError
from polarref.core.memory import own_peak_mb
from polarref.core.progress import track
from polarref.model.colmap import read_model
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)


WORK_WIDTH = 320  # px: measured on the 640x480 comet, 0.5x keeps F within the target at 1/4 of the cost


@dataclass(frozen=True)
class DenseConfig:
    scale: float | None = None       # working resolution / image resolution; None: width -> ~WORK_WIDTH
    num_sources: int = 4             # neighbours per reference view
    depth: depth_mod.DepthOptions = depth_mod.DepthOptions()
    consistency: consistency.ConsistencyOptions = consistency.ConsistencyOptions()
    mesh: meshing.MeshOptions = meshing.MeshOptions()
    voxel_px: float = 0.5            # fusion voxel, in working-pixel footprints at the median depth
    tau_rel: float = 0.005           # F-score tolerance / GT scene diameter
    seed: int = 0                    # GT surface sampling and subsampling for scores
    score_samples: int = 60_000      # area-uniform GT surface samples (before the visibility test)


@dataclass
class DenseMetrics:
    """Everything ``metrics.json`` holds (typed; serialized by :func:`polarref.metrics.write_json`)."""

    status: RunStatus
    message: str
    scene: str
    model: str                                   # "gt" or the model folder
    config: DenseConfig
    scale: float = 0.0                           # working resolution used
    num_views: int = 0
    num_views_with_depth: int = 0
    neighbors: dict[str, list[str]] = field(default_factory=dict)
    num_fused_points: int = 0
    voxel: float = 0.0                           # model units
    mesh_vertices: int = 0
    mesh_faces: int = 0
    runtime_s: dict[str, float] = field(default_factory=dict)     # wall clock per stage
    cpu_s: dict[str, float] = field(default_factory=dict)         # process CPU time per stage (all threads)
    peak_memory_mb: float = 0.0
    warnings: list[str] = field(default_factory=list)
    model_check: ModelCheck | None = None        # does the model belong to the scene (not for --model gt)
    gt: scoring.GTScores | None = None
    provenance: Provenance | None = None

    def to_dict(self) -> dict:
        return asdict(self)


DENSE_OUTPUTS = ("depth", "fused.ply", "mesh.ply", "fused_gt.ply", "mesh_gt.ply", "metrics.json")


def _check_out(scene_dir: Path, model: str, out: Path, overwrite: bool) -> None:
    """Fail before any work: outputs never go into the scene or the model (``--out SCENE`` would
    replace the GT mesh and depth and then score the result against itself)."""
    refuse_inside_inputs(out, [scene_dir] + ([Path(model)] if model != "gt" else []))
    check_dir_target(out, overwrite)
    check_writable_parent(out)


def run_dense(scene_dir: Path, model: str, out: Path, cfg: DenseConfig = DenseConfig(), *,
              overwrite: bool = False, command: str = "") -> DenseMetrics:
    """Run the dense stage into OUT, built aside and swapped in whole when complete.

    A failure writes OUT/metrics.json naming it and re-raises, unless OUT holds a finished
    result: that is then kept as it was (the error says so).
    """
    from polarref.metrics import write_json

    scene_dir, out = Path(scene_dir), Path(out)
    if not scene_dir.is_dir():
        raise PolarrefError(f"scene folder not found: {scene_dir}")
    _check_out(scene_dir, model, out, overwrite)
    keep_finished = holds_finished_result(out)
    m = DenseMetrics(RunStatus.FAILED, "", str(scene_dir), model, cfg,
                     provenance=collect(command, {"dense": cfg.seed}, {"poisson": cfg.mesh.threads}))
    failure: PolarrefError | None = None
    with publish_dir(out, overwrite=overwrite, owned=DENSE_OUTPUTS) as tmp:
        (tmp / "depth").mkdir()
        try:
            _run(scene_dir, model, tmp, cfg, m)
            m.status = RunStatus.OK
        except PolarrefError as exc:
            m.message = str(exc).replace(str(tmp), str(out))
            if keep_finished:  # raised inside the block: the new folder is discarded
                raise PolarrefError(f"{m.message}; the finished result in {out} was kept",
                                    option=exc.option) from exc
            failure = exc
        m.peak_memory_mb = own_peak_mb()
        write_json(tmp / "metrics.json", m.to_dict())
    if failure is not None:
        raise PolarrefError(m.message, option=failure.option) from failure
    return m


def _timed(m: DenseMetrics, stage: str, t0: tuple[float, float]) -> tuple[float, float]:
    t = (time.perf_counter(), time.process_time())
    m.runtime_s[stage] = m.runtime_s.get(stage, 0.0) + t[0] - t0[0]
    m.cpu_s[stage] = m.cpu_s.get(stage, 0.0) + t[1] - t0[1]
    return t


def _load(scene_dir: Path, model: str):
    """(image_dir, rec, gt or None, loaded synthetic scene or None)."""
    from polarref.io.scene_folder import discover

    found = discover(scene_dir)
    image_dir = found.image_dir
    gt = found.read_ground_truth()
    synth_scene = None
    if (scene_dir / "scene.json").is_file():
        from synth.scene import load_scene

        synth_scene = load_scene(scene_dir)
    if model == "gt":
        if gt is None:
            raise PolarrefError(f"{scene_dir} has no ground truth (gt/ model or gt_dense_cameras/) to take "
                                "the poses from")
        rec = gt
    else:
        rec = read_model(Path(model))
    return image_dir, rec, gt, synth_scene


def _run(scene_dir: Path, model: str, out: Path, cfg: DenseConfig, m: DenseMetrics) -> None:
    t = t_all = (time.perf_counter(), time.process_time())
    image_dir, rec, gt, synth_scene = _load(scene_dir, model)
    m.num_views = len(rec.images)
    if m.num_views < views_mod.MIN_VIEWS:
        raise PolarrefError(f"the model has {m.num_views} registered view(s); need at least "
                            f"{views_mod.MIN_VIEWS}")
    width = max(c.width for c in rec.cameras.values())
    scale = cfg.scale if cfg.scale is not None else min(1.0, WORK_WIDTH / width)
    m.scale = scale
    views = views_mod.load_views(image_dir, rec, scale)
    if model != "gt":
        m.model_check = _check_model(rec, views, gt, model, scene_dir, cfg.seed, m)
    t = _timed(m, "load", t)

    bounds = None
    if synth_scene is not None and model == "gt":
        # GT cameras come without sparse points; the GT surface's vertices stand in for them (used
        # only for depth ranges and view overlap, as SfM points would be), else the bounding sphere.
        bounds = (synth_scene.center, synth_scene.radius)
        if synth_scene.mesh_path.is_file():
            bounds = synth_scene.mesh()[0]
    pts = views_mod.scene_points(rec, views, bounds, seed=cfg.seed)
    sel = views_mod.select_views(views, pts, cfg.num_sources)
    m.neighbors = {v.name: [views[j].name for j in sel.neighbors[i]] for i, v in enumerate(views)}
    alone = [v.name for i, v in enumerate(views) if len(sel.neighbors[i]) < 2 or not np.isfinite(sel.depth_range[i]).all()]
    if alone:
        m.warnings.append(f"{len(alone)} view(s) without two usable neighbours, no depth: {', '.join(alone[:5])}")
        log.warning(m.warnings[-1])
    t = _timed(m, "view_selection", t)

    maps: list[depth_mod.DepthMap | None] = [None] * len(views)
    for i in track(range(len(views)), desc="depth maps", total=len(views)):
        if views[i].name in alone:
            continue
        near, far = sel.depth_range[i]
        dm = depth_mod.estimate_depth(views[i], [views[j] for j in sel.neighbors[i]], near, far, cfg.depth)
        if not (dm.depth > 0).any():
            m.warnings.append(f"{views[i].name}: empty depth map (no pixel reached NCC {cfg.depth.min_ncc})")
            log.warning(m.warnings[-1])
        maps[i] = dm
        log.debug("%s: %d planes, %.1f%% pixels with depth", views[i].name, dm.num_planes, 100 * (dm.depth > 0).mean())
    t = _timed(m, "depth", t)

    filtered = []
    for i in track(range(len(views)), desc="consistency", total=len(views)):
        f = consistency.filter_view(i, views, maps, sel.neighbors[i], cfg.consistency)
        with atomic_open(out / "depth" / (Path(views[i].name).stem + ".npy")) as fh:
            np.save(fh, f.depth)
        filtered.append(f)
    m.num_views_with_depth = sum(1 for f in filtered if len(f.points))
    t = _timed(m, "consistency", t)
    if m.num_views_with_depth == 0:
        raise PolarrefError("no view kept a consistent depth (textureless images, wrong poses or "
                            "no overlap); depth maps kept in " + str(out / "depth"))

    depths = np.concatenate([f.depth[f.depth > 0] for f in filtered if len(f.points)])
    fx = float(np.median([v.K[0, 0] for v in views]))
    m.voxel = float(np.median(depths) / fx * cfg.voxel_px)
    cloud = fusion.fuse(filtered, m.voxel)
    m.num_fused_points = len(cloud)
    fusion.write_point_cloud(out / "fused.ply", cloud)
    t = _timed(m, "fusion", t)

    mesh = meshing.poisson_mesh(cloud, m.voxel, cfg.mesh)
    m.mesh_vertices, m.mesh_faces = len(mesh.vertices), len(mesh.faces)
    from synth.meshes import write_ply

    write_ply(out / "mesh.ply", mesh.vertices, mesh.faces, mesh.colors)
    t = _timed(m, "meshing", t)
    _timed(m, "dense_total", t_all)  # the stages so far, end to end

    if gt is not None:
        _score_gt(rec, gt, synth_scene, views, filtered, cloud, mesh, model, out, cfg, m)
        _timed(m, "scoring", t)


def _check_model(rec, views, gt, model: str, scene_dir: Path, seed: int, m: DenseMetrics) -> ModelCheck:
    """Refuse a model that does not belong to the scene before any dense work (its score would
    be meaningless), or flag it in ``m.warnings`` when only one of two checks failed."""
    sim = None
    if gt is not None:
        try:
            sim = align_to_gt(rec, gt)[0]
        except ValueError as exc:  # the GT names other images than the folder: only the patches can tell
            log.info("%s: GT reprojection check not made: %s", model, exc)
    check = check_model(rec, views, gt, sim, seed)
    refuse, flags = verdict(check)
    for note in check.notes:
        log.info("%s: %s", model, note)
    if refuse:
        raise PolarrefError(f"model {model} does not fit the scene {scene_dir}: {'; '.join(refuse)} "
                            "(a model of another scene or of other images?)")
    for flag in flags:
        m.warnings.append(f"model check: {flag}")
        log.warning(m.warnings[-1])
    return check


def _score_gt(rec, gt, synth_scene, views, filtered, cloud, mesh, model, out, cfg, m) -> None:
    from polarref.core.geometry import Sim3
    from polarref.metrics import align_to_gt
    from synth.meshes import write_ply

    if model == "gt":
        sim, method = Sim3(1.0, np.eye(3), np.zeros(3)), "identity (gt model)"
    else:
        try:
            sim, method, _, _ = align_to_gt(rec, gt)
        except ValueError as exc:
            m.warnings.append(f"no GT alignment: {exc}")
            return
    cloud_gt, mesh_gt = cloud.transformed(sim), mesh.transformed(sim)
    fusion.write_point_cloud(out / "fused_gt.ply", cloud_gt)
    write_ply(out / "mesh_gt.ply", mesh_gt.vertices, mesh_gt.faces, mesh_gt.colors)
    if synth_scene is None or not synth_scene.mesh_path.is_file():
        return
    V, F = synth_scene.mesh()
    K_full = synth_scene.polarref_camera().calibration_matrix()
    gt_views = [(v.cam_from_world, K_full, synth_scene.depth(i)) for i, v in enumerate(synth_scene.views)]
    by_name = {v.name: i for i, v in enumerate(synth_scene.views)}
    depth_maps = [(v.name, f.depth, gt_views[by_name[v.name]][2], v.scale)
                  for v, f in zip(views, filtered) if v.name in by_name]
    m.gt = scoring.score(cloud_gt, mesh_gt, V, F, gt_views, cfg.tau_rel, method, float(sim.s),
                         depth_maps, cfg.seed, cfg.score_samples)
