"""``polarref compare rosetta|poets-park|mappilot``: the paper's Tables 1-3 redone on the twins.

Four methods on the same images and the same image pairs (chosen once from the pose priors,
:mod:`polarref.sfm.pairing`): ours with the Euclidean BA (the OpenMVG column), ours with the polar BA
("ours"), pycolmap incremental and global (its SIFT, matched on exactly our pairs). Every stage
runs in its own process (:func:`polarref.compare.runner.run_isolated`: log file, timeout, peak
memory) and leaves ``stages/<stage>.json`` when it succeeds, so a rerun after an interruption
skips finished stages. The outputs are ``paper-table.md`` / ``paper-table.json`` (see
:mod:`polarref.compare.paper_tables`) in the output folder.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import resource
import time
from dataclasses import dataclass
from pathlib import Path

from polarref.core.atomic import atomic_write
from polarref.compare import paper_readme as PR
from polarref.compare import paper_tables as PT
from polarref.core.errors import PolarrefError
from polarref.sfm.pairing import PairingConfig, pairs_file_name, priors_from_scene, read_pairs, select, write_pairs
from polarref.model.colmap import read_model
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)

PYCOLMAP_FEATURES = 4096  # the same feature budget as ours (polarref.sfm default), recorded per run
DEFAULT_TIMEOUT_S = 4 * 3600.0
# pycolmap incremental writes a snapshot every this many registered frames, so a run that outlives
# a session resumes (rosetta: > 2 h of mapping on one core); a snapshot of 600 views takes ~1-2 s
PYCOLMAP_SNAPSHOT_EVERY = 20
FEATURES_CACHED = "features (loaded from an earlier run's cache)"


@dataclass(frozen=True)
class TwinRun:
    """Settings of one twin comparison (stored in ``run.json``)."""

    twin: str
    out: str
    seed: int = 0
    methods: tuple[str, ...] = PT.METHODS
    method_timeout_s: float = DEFAULT_TIMEOUT_S
    scene_dir: str = ""  # a rendered scene folder instead of the twin's cached render (tests)
    tables_dir: str = ""  # also write <tables_dir>/<twin>/paper-table.* and <tables_dir>/README.md


def default_pairing(twin: str, meta: dict) -> PairingConfig:
    """Spatial + sequential pairs; an orbiter looks at the body centre, a UAV at the ground."""
    if twin == "rosetta" or meta.get("config", {}).get("scene") == "comet":
        return PairingConfig(method="spatial+sequential", k=10, overlap=5, look="object",
                             object_center=tuple(float(v) for v in meta["scale"]["center"]))
    return PairingConfig(method="spatial+sequential", k=12, overlap=3, look="ground", ground_z=0.0)


@dataclass
class TwinJobResult:
    """What one twin stage returns (the typed record its process writes)."""

    stage_runtime_s: dict[str, float]
    peak_rss_mb: float                  # largest resident set of the stage's process
    model_dir: str = ""                 # methods: the COLMAP text model
    verified_pairs: int | None = None   # shared stages
    skipped_images: list[str] = dataclasses.field(default_factory=list)
    feature_file: str = ""              # ours-features: the feature cache (.npz) the methods read
    # resumable stages: the runtime summed over the segments (the process's wall time is only the
    # last segment's) and how many segments (processes) the result took
    counted_wall_s: float | None = None
    segments: int = 1


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _camera(camera: dict):
    from polarref.compare.jobs import _camera as cam

    return cam(camera)


def _sfm_config(pairs_file: str, cache_dir: str, track_conflicts: str | None = None):
    """The tables' pipeline settings; ``track_conflicts`` None keeps the pipeline's default."""
    from polarref.sfm.pipeline import PRESETS

    base = PRESETS["default"]
    return dataclasses.replace(base, use_cache=True, cache_dir=cache_dir,
                               track_conflicts=track_conflicts or base.track_conflicts,
                               matching=dataclasses.replace(base.matching, pairing="file", pairs_file=pairs_file))


# ---- jobs (each runs in its own process) --------------------------------------------------------
def job_ours_features(image_dir: str, camera: dict, pairs_file: str, cache_dir: str) -> TwinJobResult:
    """Our features and verified matches on the pairs file, cached for both ``ours-*`` methods."""
    import numpy as np

    from polarref.sfm.pipeline import load_images_and_features, match_and_verify

    config, timings = _sfm_config(pairs_file, cache_dir), {}
    feats, skipped, key = load_images_and_features(Path(image_dir), config, timings)
    matches = match_and_verify(feats, [_camera(camera)], np.zeros(len(feats), np.int64), config, key, timings)
    stages = {k: float(timings[k]) for k in ("features", "matching", "verification") if k in timings}
    if timings.get("features_cached"):  # the time to load them, not to extract them: say so in the table
        stages[FEATURES_CACHED] = stages.pop("features")
    return TwinJobResult(stages,
                         _peak_mb(), verified_pairs=len(matches.geometries),
                         skipped_images=[str(x["name"]) for x in skipped],
                         feature_file=str(Path(cache_dir) / f"features-{key}.npz"))


def job_ours_sfm(image_dir: str, camera: dict, ba: str, work_dir: str, pairs_file: str, cache_dir: str,
                 track_conflicts: str | None = None) -> TwinJobResult:
    """Our incremental SfM with BA ``ba`` on the cached features/matches; model in work_dir/sfm/model.

    ``track_conflicts``: the tables use the pipeline default (None); "split" is the variant
    measured by ``scripts/twin_variant.py`` (tracks and mapping only: the caches do not depend on it)."""
    from polarref.sfm.pipeline import run_sfm, with_ba

    config = with_ba(_sfm_config(pairs_file, cache_dir, track_conflicts), ba)
    result = run_sfm(Path(image_dir), Path(work_dir) / "sfm", config, camera=_camera(camera), overwrite=True)
    t = result.report.runtime_s
    skip = {"total", "metrics", "export", "features_cached", "matches_cached", "features", "matching", "verification"}
    stages = {k: float(v) for k, v in t.items() if k not in skip and isinstance(v, (int, float))}
    ba_s = stages.pop("ba", 0.0)
    if "mapping" in stages:
        stages["mapping (excl. BA)"] = max(0.0, stages.pop("mapping") - ba_s)
    stages["bundle adjustment"] = ba_s
    return TwinJobResult(stages, _peak_mb(), model_dir=str(Path(work_dir) / "sfm" / "model"))


def job_pycolmap_db(image_dir: str, image_names: list[str], camera: dict, db_path: str, pairs_file: str,
                    seed: int) -> TwinJobResult:
    """pycolmap SIFT (our feature budget) matched on exactly our pairs, verified, into ``db_path``."""
    from polarref.peers.colmap_sfm import ColmapSfMOptions, count_verified_pairs, extract_and_match_sift

    opts = ColmapSfMOptions(seed=seed, num_threads=1, max_num_features=PYCOLMAP_FEATURES)
    stages = extract_and_match_sift(Path(image_dir), _camera(camera), Path(db_path), opts,
                                    image_names=image_names, overwrite=True, pairs_file=Path(pairs_file))
    return TwinJobResult({k: float(v) for k, v in stages.items()}, _peak_mb(),
                         verified_pairs=count_verified_pairs(Path(db_path)))


def job_pycolmap_map(db_path: str, image_dir: str, work_dir: str, mapper: str, seed: int,
                     snapshot_every: int = 0) -> TwinJobResult:
    """pycolmap mapping of a copy of ``db_path``; incremental with ``snapshot_every`` > 0 resumes
    an interrupted run from its last snapshot (:mod:`polarref.peers.colmap_resume`)."""
    from polarref.compare.jobs import pycolmap_map, write_largest_model

    if mapper != "incremental" or snapshot_every <= 0:
        out = pycolmap_map(db_path, image_dir, work_dir, mapper, seed, num_threads=1)
        return TwinJobResult(dict(out.stage_runtime_s), _peak_mb(), model_dir=out.model_dir)
    from polarref.peers.colmap_resume import map_incremental_resumable
    from polarref.peers.colmap_sfm import ColmapSfMOptions

    run, ledger = map_incremental_resumable(Path(db_path), Path(image_dir), Path(work_dir),
                                            ColmapSfMOptions(seed=seed, num_threads=1), snapshot_every)
    model = write_largest_model(run, Path(work_dir), mapper)
    return TwinJobResult(dict(run.stage_runtime_s), _peak_mb(), model_dir=str(model),
                         counted_wall_s=ledger.counted_s, segments=len(ledger.segments))


JOBS = {f.__name__: f for f in (job_ours_features, job_ours_sfm, job_pycolmap_db, job_pycolmap_map)}


@dataclass
class StageRerun:
    """An ``ours-*`` stage of a finished twin run, rerun in this process (scripts/twin_*.py)."""

    stage: dict            # the run's record of the stage (stages/<stage>.json)
    run: dict              # the run's settings (run.json)
    scene: object          # the prepared scene (images, camera, GT)
    result: TwinJobResult  # the rerun's
    wall_s: float          # the rerun's wall time


def rerun_ours_stage(run_dir: Path, ba: str, out: Path, work: Path | None = None,
                     track_conflicts: str | None = None) -> StageRerun:
    """Rerun ``ours-<ba>`` of a finished twin run on its feature/match caches with this checkout.

    ``out`` is the JSON the caller will write: an existing one is refused (:class:`PolarrefError`),
    as is a run without that stage (the error names the command that makes it)."""
    from polarref.compare.jobs import camera_to_json

    run_dir, out = Path(run_dir), Path(out)
    if out.exists():
        raise PolarrefError(f"{out} exists (remove it to measure again)")
    stage_file = run_dir / "stages" / f"ours-{ba}.json"
    if not stage_file.is_file():
        raise PolarrefError(f"{stage_file} missing: run `polarref compare <twin> --out {run_dir}` first")
    stage = json.loads(stage_file.read_text())
    run = json.loads((run_dir / "run.json").read_text())
    pairs = run_dir / json.loads((run_dir / "pairs.json").read_text())["file"]
    scene = _scene(TwinRun(**run))  # the scene the run itself prepared (run.json is a TwinRun)
    t0 = time.perf_counter()
    result = job_ours_sfm(str(scene.image_dir), camera_to_json(scene.camera), ba, str(work or out.with_suffix("")),
                          str(pairs), str(run_dir / "cache"), track_conflicts=track_conflicts)
    return StageRerun(stage, run, scene, result, time.perf_counter() - t0)


# ---- the run ----------------------------------------------------------------------------------
class _Stages:
    """Resumable stages: ``stages/<name>.json`` marks a finished one."""

    def __init__(self, out: Path, timeout_s: float):
        self.dir, self.timeout_s = out / "stages", timeout_s
        self.dir.mkdir(parents=True, exist_ok=True)

    def done(self, name: str) -> dict | None:
        f = self.dir / f"{name}.json"
        if f.is_file():
            rec = json.loads(f.read_text())
            if rec.get("status") == "ok":
                return rec
        return None

    def run(self, name: str, func: str, kwargs: dict) -> dict:
        rec = self.done(name)
        if rec is not None:
            log.info("stage %s: finished earlier (%.0f s), skipped", name, rec["wall_s"])
            return rec
        from polarref.compare.runner import run_isolated

        log.info("stage %s: started (log %s)", name, self.dir / f"{name}.log")
        from polarref.core import records
        from polarref.core.provenance import git_state

        commit, dirty = git_state()  # the code that runs the stage (its process imports this checkout)
        outcome = run_isolated(JOBS[func], kwargs, self.timeout_s, self.dir, name)
        result = records.to_dict(outcome.result) if outcome.result is not None else {}
        rec = {"stage": name, "status": outcome.status, "reason": outcome.reason, "wall_s": outcome.wall_s,
               "result": result, "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
               "git_commit": commit, "git_dirty": dirty}
        atomic_write(self.dir / f"{name}.json", json.dumps(rec, indent=1, default=str) + "\n")
        log.info("stage %s: %s in %.0f s%s", name, outcome.status, outcome.wall_s,
                 f" ({outcome.reason})" if outcome.reason else "")
        return rec


def _scene(run: TwinRun):
    from polarref.compare.scenes import prepare

    if run.scene_dir:
        return prepare(run.scene_dir, "default", run.seed)
    return prepare(run.twin, "default", run.seed)


def _pairs(run: TwinRun, scene, out: Path) -> tuple[Path, int]:
    """The scene's pairs file (chosen once; reused on reruns)."""
    meta_path = out / "pairs.json"
    if meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        path = out / meta["file"]
        if path.is_file():
            return path, len(read_pairs(path, scene.image_names))
    from synth.scene import load_scene

    meta = load_scene(scene.root).meta
    config = default_pairing(run.twin, meta)
    pair_set = select(priors_from_scene(meta), config)
    path = write_pairs(out / pairs_file_name(pair_set), pair_set, {"scene_digest": meta.get("digest")})
    atomic_write(meta_path, json.dumps({"file": path.name, "pairs": len(pair_set.pairs),
                                        "config": dataclasses.asdict(config)}, indent=1) + "\n")
    log.info("pairs: %d for %d images (%s) -> %s", len(pair_set.pairs), len(pair_set.names), config.method, path)
    return path, len(pair_set.pairs)


def mean_keypoints_db(db: Path) -> float | None:
    """Mean keypoints per image in a COLMAP database (its ``keypoints`` table), opened read-only.

    A cleanly closed database is opened immutable, so no -wal/-shm files appear in the run folder;
    with a -wal file beside it (a writer still open, or killed) SQLite has to read the log too."""
    import sqlite3

    db = Path(db)
    if not db.is_file():
        return None
    live = db.with_name(db.name + "-wal").exists()
    try:
        con = sqlite3.connect(f"file:{db.resolve()}?mode=ro{'' if live else '&immutable=1'}", uri=True)
        try:
            row = con.execute("SELECT AVG(rows), COUNT(*) FROM keypoints").fetchone()
        finally:
            con.close()
    except sqlite3.Error:
        return None
    return float(row[0]) if row and row[1] else None


def ours_mean_keypoints(feats: dict, cache: Path) -> float | None:
    """Mean keypoints per image of the cache file the features stage recorded; for older records
    (no file named) every ``features-*.npz`` in the cache, used only when they all agree."""
    recorded = (feats.get("result") or {}).get("feature_file")
    files = [Path(recorded)] if recorded else sorted(cache.glob("features-*.npz"))
    from polarref.sfm.feature_cache import mean_keypoints

    means = {mean_keypoints(f) for f in files}
    return means.pop() if len(means) == 1 else None


@dataclass
class ModelScore:
    """One model scored as the twin tables score it (GT errors after a Sim3 alignment; None
    without GT)."""

    registered: int
    tie_points: int
    reprojected_px: int
    mean_reprojection_error_px: float
    rotation_error_deg: float | None
    centre_error_rel: float | None


def score_model(model_dir: str | Path, gt) -> ModelScore:
    """The tables' scores of the COLMAP model in ``model_dir`` against ``gt``."""
    from polarref.compare.scoring import score
    from polarref.model import Reconstruction

    s = score(read_model(Path(model_dir)), gt, None)
    m, g = s.metrics, s.gt
    return ModelScore(int(m.registered_images), int(m.tie_points), int(m.reprojected_px),
                      float(m.mean_reprojection_error_px),
                      None if g is None else float(g.rotation_error_deg_mean),
                      None if g is None else float(g.center_error_rel_mean))


def _method_result(name: str, recs: list[dict], scene, gt) -> PT.MethodResult:
    """Score one method's model; its stages' times add up to its efficiency."""
    n = len(scene.image_names)
    bad = next((r for r in recs if r["status"] != "ok"), None)
    if bad is not None:
        return PT.MethodResult(name, bad["status"], f"{bad['stage']}: {bad['reason']}"[:200], n)
    stages: dict[str, float] = {}
    for r in recs:
        for k, v in r["result"].get("stage_runtime_s", {}).items():
            stages[k] = stages.get(k, 0.0) + float(v)
    # process wall times (spawn and import included); a resumed stage counts its segments instead
    wall = sum(float(r["result"].get("counted_wall_s") or r["wall_s"]) for r in recs)
    segments = max(int(r["result"].get("segments") or 1) for r in recs)
    peak = max((float(r["result"].get("peak_rss_mb") or 0.0) for r in recs), default=None)
    s = score_model(recs[-1]["result"]["model_dir"], gt)
    return PT.MethodResult(
        name, "ok", "", n, s.registered, s.mean_reprojection_error_px, wall / 60.0, s.tie_points,
        s.reprojected_px, s.rotation_error_deg, s.centre_error_rel, stages, peak, segments=segments)


def run_twin(run: TwinRun) -> PT.TwinTable:
    """Run (or resume) the comparison and write the paper table into ``run.out``."""
    from polarref.compare.jobs import camera_to_json
    from polarref.core.provenance import collect

    if run.twin not in PT.PAPER:
        raise PolarrefError(f"unknown twin {run.twin!r} (choose from {', '.join(PT.PAPER)})")
    out = Path(run.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "run.json", json.dumps(dataclasses.asdict(run), indent=1) + "\n")
    t0 = time.perf_counter()
    scene = _scene(run)
    log.info("scene %s: %d images in %s (render %.0f s)", run.twin, len(scene.image_names), scene.root, scene.render_s)
    pairs_file, n_pairs = _pairs(run, scene, out)
    st = _Stages(out, run.method_timeout_s)
    cam, img = camera_to_json(scene.camera), str(scene.image_dir)
    cache = str(out / "cache")
    recs: dict[str, list[dict]] = {}
    wanted = [m for m in PT.METHODS if m in run.methods]
    if any(m.startswith("ours-") for m in wanted):
        feats = st.run("ours-features", "job_ours_features",
                       dict(image_dir=img, camera=cam, pairs_file=str(pairs_file), cache_dir=cache))
        for m in (m for m in wanted if m.startswith("ours-")):
            recs[m] = [feats] if feats["status"] != "ok" else [feats, st.run(
                m, "job_ours_sfm", dict(image_dir=img, camera=cam, ba=m.split("-", 1)[1],
                                        work_dir=str(out / m), pairs_file=str(pairs_file), cache_dir=cache))]
    if any(m.startswith("pycolmap-") for m in wanted):
        db = st.run("pycolmap-features", "job_pycolmap_db",
                    dict(image_dir=img, image_names=list(scene.image_names), camera=cam,
                         db_path=str(out / "pycolmap" / "database.db"), pairs_file=str(pairs_file), seed=run.seed))
        for m in (m for m in wanted if m.startswith("pycolmap-")):
            recs[m] = [db] if db["status"] != "ok" else [db, st.run(
                m, "job_pycolmap_map", dict(db_path=str(out / "pycolmap" / "database.db"), image_dir=img,
                                            work_dir=str(out / m), mapper=m.split("-")[1], seed=run.seed,
                                            snapshot_every=PYCOLMAP_SNAPSHOT_EVERY))]
    methods = {m: _method_result(m, recs[m], scene, scene.gt) if m in recs else PT.MethodResult(m)
               for m in PT.METHODS}
    keypoints: dict[str, float | None] = {}  # per source (ours' cache, pycolmap's database): read once
    for m, r in methods.items():
        if r.status != RunStatus.OK:
            continue
        source = "ours" if m.startswith("ours-") else "pycolmap"
        if source not in keypoints:
            keypoints[source] = (ours_mean_keypoints(recs[m][0], Path(cache)) if source == "ours"
                                 else mean_keypoints_db(out / "pycolmap" / "database.db"))
        r.mean_keypoints = keypoints[source]
    stage_recs = {rec["stage"]: rec for rs in recs.values() for rec in rs}
    env = collect()
    provenance = {"commit": env.get("git_commit"), "dirty": env.get("git_dirty"), "machine": env.get("machine"),
                  "seed": run.seed, "pairs_file": pairs_file.name, "wall_s_this_call": round(time.perf_counter() - t0, 1),
                  "pycolmap_max_num_features": PYCOLMAP_FEATURES, "environment": env,
                  "stages": {k: {"git_commit": v.get("git_commit", ""), "git_dirty": v.get("git_dirty"),
                                 "finished_utc": v.get("finished_utc", "")} for k, v in sorted(stage_recs.items())}}
    table = PT.TwinTable(run.twin, len(scene.image_names), n_pairs, methods, provenance)
    PT.write_table(out, table)
    if run.tables_dir:  # the small committed copy (the run folder holds models, databases, caches)
        PT.write_table(Path(run.tables_dir) / run.twin, table)
        PR.write_readme(run.tables_dir)
    return table
