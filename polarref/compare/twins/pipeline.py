"""``polarref compare rosetta|poets-park|mappilot``: the paper's Tables 1-3 redone on the twins.

Four methods on the same images and the same image pairs (chosen once from the pose priors,
:mod:`polarref.sfm.pairing`): ours with the Euclidean BA (the OpenMVG column), ours with the polar BA
("ours"), pycolmap incremental and global (its SIFT, matched on exactly our pairs). Every stage
runs in its own process (:func:`polarref.core.isolated.run_isolated`: log file, timeout, peak
memory) and leaves ``stages/<stage>.json`` when it succeeds, so a rerun after an interruption
skips finished stages. The outputs are ``paper-table.md`` / ``paper-table.json`` (see
:mod:`polarref.compare.twins.tables`) in the output folder.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from polarref.compare.run import jobs
from polarref.compare.run import ours
from polarref.compare.run import presets
from polarref.core import isolated as runner
from polarref.compare.twins import readme as PR
from polarref.compare.twins import tables as PT
from polarref.compare.run.scenes import prepare
from polarref.io.scene_folder import Scene
from polarref.compare.run.scoring import score
from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError
from polarref.core.provenance import collect_record, git_state
from polarref.core.status import RunStatus
from polarref.model.colmap import read_model
from polarref.model.run import MethodRun
from polarref.model.scores import ReconstructionMetrics
from polarref.sfm.feature_cache import mean_keypoints
from polarref.sfm.pairing import PairingConfig, pairs_file_name, priors_from_scene, read_pairs, select, write_pairs
from synth.scene import load_scene

log = logging.getLogger(__name__)

PYCOLMAP_FEATURES = 4096  # the same feature budget as ours (polarref.sfm default), recorded per run
DEFAULT_TIMEOUT_S = 4 * 3600.0
# pycolmap incremental writes a snapshot every this many registered frames, so a run that outlives
# a session resumes (rosetta: > 2 h of mapping on one core); a snapshot of 600 views takes ~1-2 s
PYCOLMAP_SNAPSHOT_EVERY = 20
FEATURES_CACHED = ours.FEATURES_CACHED
PYCOLMAP_THREADS = 2  # both cores of the reference machine, like our front end


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
    # pycolmap's threads in every stage (issue 34: a user's pycolmap takes the cores; ours' front end
    # runs on both); 1 is the older tables' setting. Stored in run.json and the table's provenance.
    pycolmap_threads: int = PYCOLMAP_THREADS


def default_pairing(twin: str, meta: dict) -> PairingConfig:
    """Spatial + sequential pairs; an orbiter looks at the body centre, a UAV at the ground."""
    if twin == "rosetta" or meta.get("config", {}).get("scene") == "comet":
        return PairingConfig(method="spatial+sequential", k=10, overlap=5, look="object",
                             object_center=tuple(float(v) for v in meta["scale"]["center"]))
    return PairingConfig(method="spatial+sequential", k=12, overlap=3, look="ground", ground_z=0.0)


@dataclass(frozen=True)
class StageRecord:
    """One twin stage as ``stages/<stage>.json`` records it (a finished one is never rerun)."""

    stage: str
    status: RunStatus
    reason: str = ""
    wall_s: float = 0.0                 # the stage process's wall time
    result: MethodRun | None = None     # the job's record (ok only)
    finished_utc: str = ""
    git_commit: str = ""                # the code that ran the stage ("": written before stages kept it)
    git_dirty: bool | None = None

    @property
    def counted_wall_s(self) -> float:
        """The stage's runtime: a resumed stage counts its segments, not its last process."""
        counted = self.result.counted_wall_s if self.result is not None else None
        return float(counted if counted is not None else self.wall_s)


def _upgrade_stage(data):
    """A stage record as written before MethodRun (skipped images by name only) in today's layout."""
    result = data.get("result") if isinstance(data, dict) else None
    if isinstance(result, dict) and any(isinstance(x, str) for x in result.get("skipped_images", [])):
        skipped = [{"name": x, "reason": ""} if isinstance(x, str) else x for x in result["skipped_images"]]
        data = dict(data, result=dict(result, skipped_images=skipped))
    return data


def read_stage(path: Path) -> StageRecord:
    """The stage record at ``path``, strictly (RecordError naming the file and key)."""
    return records.from_dict(StageRecord, _upgrade_stage(records.read_json(path)), label=str(path))


@dataclass(frozen=True)
class StageRerun:
    """An ``ours-*`` stage of a finished twin run, rerun in this process (scripts/twin_*.py)."""

    stage: StageRecord     # the run's record of the stage (stages/<stage>.json)
    run: TwinRun           # the run's settings (run.json)
    scene: Scene   # the prepared scene (images, camera, GT)
    result: MethodRun      # the rerun's
    wall_s: float          # the rerun's wall time


def rerun_ours_stage(run_dir: Path, ba: str, out: Path, work: Path | None = None,
                     track_conflicts: str | None = None) -> StageRerun:
    """Rerun ``ours-<ba>`` of a finished twin run on its feature/match caches with this checkout.

    ``out`` is the JSON the caller will write: an existing one is refused (:class:`PolarrefError`),
    as is a run without that stage (the error names the command that makes it)."""
    run_dir, out = Path(run_dir), Path(out)
    if out.exists():
        raise PolarrefError(f"{out} exists (remove it to measure again)")
    stage_file = run_dir / "stages" / f"ours-{ba}.json"
    if not stage_file.is_file():
        raise PolarrefError(f"{stage_file} missing: run `polarref compare <twin> --out {run_dir}` first")
    stage = read_stage(stage_file)
    run = read_run(run_dir / "run.json")
    pairs = run_dir / records.load(PairsMeta, run_dir / "pairs.json").file
    scene = _scene(run)  # the scene the run itself prepared
    t0 = time.perf_counter()
    result = jobs.ours_sfm(str(scene.image_dir), jobs.camera_to_json(scene.camera), ba,
                           str(work or out.with_suffix("")), presets.DEFAULT.name, str(run_dir / "cache"), str(pairs),
                           track_conflicts=track_conflicts)
    return StageRerun(stage, run, scene, result, time.perf_counter() - t0)


# ---- the run ----------------------------------------------------------------------------------
class _Stages:
    """Resumable stages: ``stages/<name>.json`` with status ok marks a finished one."""

    def __init__(self, out: Path, timeout_s: float):
        self.dir, self.timeout_s = out / "stages", timeout_s
        self.dir.mkdir(parents=True, exist_ok=True)

    def done(self, name: str) -> StageRecord | None:
        f = self.dir / f"{name}.json"
        if not f.is_file():
            return None
        try:
            rec = read_stage(f)
        except records.RecordError as exc:  # not a record this code reads: run the stage again
            log.info("stage %s: %s; running it again", name, exc)
            return None
        return rec if rec.status == RunStatus.OK else None

    def run(self, name: str, job: Callable[..., MethodRun], kwargs: dict) -> StageRecord:
        rec = self.done(name)
        if rec is not None:
            log.info("stage %s: finished earlier (%.0f s), skipped", name, rec.wall_s)
            return rec
        log.info("stage %s: started (log %s)", name, self.dir / f"{name}.log")
        commit, dirty = git_state()  # the code that runs the stage (its process imports this checkout)
        outcome = runner.run_isolated(job, kwargs, self.timeout_s, self.dir, name)
        rec = StageRecord(name, outcome.status, outcome.reason, outcome.wall_s, outcome.result,
                          time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), commit, dirty)
        records.save(rec, self.dir / f"{name}.json")
        log.info("stage %s: %s in %.0f s%s", name, outcome.status, outcome.wall_s,
                 f" ({outcome.reason})" if outcome.reason else "")
        return rec


def _scene(run: TwinRun) -> Scene:
    return prepare(run.scene_dir or run.twin, presets.DEFAULT, run.seed)


def read_run(path: Path) -> TwinRun:
    """The settings a twin run recorded (``run.json``)."""
    return records.load(TwinRun, path)


@dataclass(frozen=True)
class PairsMeta:
    """``pairs.json``: the pairs file a twin run chose once (reused on reruns) and how."""

    file: str                 # name of the pairs file in the run folder
    pairs: int
    config: PairingConfig


def _pairs(run: TwinRun, scene: Scene, out: Path) -> tuple[Path, int]:
    return choose_pairs(run.twin, scene, out)


def choose_pairs(twin: str, scene: Scene, out: Path) -> tuple[Path, int]:
    """The scene's pairs file in ``out`` by the twin's pairing rule (chosen once; reused on reruns)."""
    meta_path = out / "pairs.json"
    if meta_path.is_file():
        path = out / records.load(PairsMeta, meta_path).file
        if path.is_file():
            return path, len(read_pairs(path, scene.image_names))
    meta = load_scene(scene.root).meta
    config = default_pairing(twin, meta)
    pair_set = select(priors_from_scene(meta), config)
    path = write_pairs(out / pairs_file_name(pair_set), pair_set, {"scene_digest": meta.get("digest")})
    records.save(PairsMeta(path.name, len(pair_set.pairs), config), meta_path)
    log.info("pairs: %d for %d images (%s) -> %s", len(pair_set.pairs), len(pair_set.names), config.method, path)
    return path, len(pair_set.pairs)


def mean_keypoints_db(db: Path) -> float | None:
    """Mean keypoints per image in a COLMAP database (its ``keypoints`` table), opened read-only.

    A cleanly closed database is opened immutable, so no -wal/-shm files appear in the run folder;
    with a -wal file beside it (a writer still open, or killed) SQLite has to read the log too."""
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


def ours_mean_keypoints(feature_file: str, cache: Path) -> float | None:
    """Mean keypoints per image of the cache file the features stage recorded; for older records
    (no file named: ``""``) every ``features-*.npz`` in the cache, used only when they all agree."""
    files = [Path(feature_file)] if feature_file else sorted(cache.glob("features-*.npz"))
    means = {mean_keypoints(f) for f in files}
    return means.pop() if len(means) == 1 else None


def score_model(model_dir: str | Path, gt) -> ReconstructionMetrics:
    """The tables' scores of the COLMAP model in ``model_dir`` (GT errors after a Sim3 alignment
    in ``.gt``; None without ``gt``)."""
    return score(read_model(Path(model_dir)), gt, None).metrics


def table_row(name: str, stages: list[StageRecord], num_images: int, gt) -> PT.TwinRow:
    """One method's row of the table from its stage records (shared stage first, then its own);
    the stages' times add up to its efficiency."""
    bad = next((r for r in stages if r.status != RunStatus.OK), None)
    if bad is not None:
        return PT.TwinRow(name, bad.status, f"{bad.stage}: {bad.reason}"[:200], num_images)
    runs = [r.result or MethodRun(r.stage) for r in stages]
    times: dict[str, float] = {}
    for run in runs:
        for k, v in run.stage_runtime_s.items():
            times[k] = times.get(k, 0.0) + float(v)
    # process wall times (spawn and import included); a resumed stage counts its segments instead
    wall = sum(r.counted_wall_s for r in stages)
    peak = max((run.peak_rss_mb or 0.0 for run in runs), default=None)
    m = score_model(runs[-1].model_dir, gt)
    return PT.TwinRow(
        name, status=RunStatus.OK, reason="", num_images=num_images, registered=int(m.registered_images),
        accuracy_px=float(m.mean_reprojection_error_px), efficiency_min=wall / 60.0, tie_points=int(m.tie_points),
        reprojected_px=int(m.reprojected_px),
        rotation_error_deg=None if m.gt is None else float(m.gt.rotation_error_deg_mean),
        center_error_rel=None if m.gt is None else float(m.gt.center_error_rel_mean),
        stages_s=times, peak_rss_mb=peak, segments=max(run.segments for run in runs))


def _run_stages(run: TwinRun, scene: Scene, out: Path, pairs_file: Path) -> dict[str, list[StageRecord]]:
    """Every wanted method's stage records (its shared stage, then its own unless that failed)."""
    st = _Stages(out, run.method_timeout_s)
    cam, img, cache = jobs.camera_to_json(scene.camera), str(scene.image_dir), str(out / "cache")
    db = str(out / "pycolmap" / "database.db")
    wanted = [m for m in PT.METHODS if m in run.methods]
    recs: dict[str, list[StageRecord]] = {}
    if any(m.startswith("ours-") for m in wanted):
        feats = st.run("ours-features", jobs.ours_features,
                       dict(image_dir=img, camera=cam, preset=presets.DEFAULT.name, cache_dir=cache, pairs_file=str(pairs_file)))
        for m in (m for m in wanted if m.startswith("ours-")):
            recs[m] = [feats] if feats.status != RunStatus.OK else [feats, st.run(
                m, jobs.ours_sfm, dict(image_dir=img, camera=cam, ba=m.split("-", 1)[1], work_dir=str(out / m),
                                       preset=presets.DEFAULT.name, cache_dir=cache, pairs_file=str(pairs_file)))]
    if any(m.startswith("pycolmap-") for m in wanted):
        sift = st.run("pycolmap-features", jobs.pycolmap_sift_db,
                      dict(image_dir=img, image_names=list(scene.image_names), camera=cam, db_path=db, seed=run.seed,
                           num_threads=run.pycolmap_threads, pairs_file=str(pairs_file), max_num_features=PYCOLMAP_FEATURES))
        for m in (m for m in wanted if m.startswith("pycolmap-")):
            recs[m] = [sift] if sift.status != RunStatus.OK else [sift, st.run(
                m, jobs.pycolmap_map, dict(db_path=db, image_dir=img, work_dir=str(out / m), mapper=m.split("-")[1],
                                           seed=run.seed, num_threads=run.pycolmap_threads, snapshot_every=PYCOLMAP_SNAPSHOT_EVERY))]
    return recs


def run_twin(run: TwinRun) -> PT.TwinTable:
    """Run (or resume) the comparison and write the paper table into ``run.out``."""
    if run.twin not in PT.PAPER:
        raise PolarrefError(f"unknown twin {run.twin!r} (choose from {', '.join(PT.PAPER)})")
    out = Path(run.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "run.json", json.dumps(dataclasses.asdict(run), indent=1) + "\n")
    t0 = time.perf_counter()
    scene = _scene(run)
    log.info("scene %s: %d images in %s (render %.0f s)", run.twin, len(scene.image_names), scene.root, scene.render_s)
    pairs_file, n_pairs = _pairs(run, scene, out)
    recs = _run_stages(run, scene, out, pairs_file)
    n = len(scene.image_names)
    methods = {m: table_row(m, recs[m], n, scene.gt) if m in recs else PT.TwinRow(m) for m in PT.METHODS}
    keypoints: dict[str, float | None] = {}  # per source (ours' cache, pycolmap's database): read once
    for m, r in list(methods.items()):
        if r.status != RunStatus.OK:
            continue
        source = "ours" if m.startswith("ours-") else "pycolmap"
        if source not in keypoints:
            first = recs[m][0].result
            keypoints[source] = (ours_mean_keypoints(first.feature_file if first else "", out / "cache")
                                 if source == "ours" else mean_keypoints_db(out / "pycolmap" / "database.db"))
        methods[m] = dataclasses.replace(r, mean_keypoints=keypoints[source])
    stage_recs = {rec.stage: rec for rs in recs.values() for rec in rs}
    env = collect_record(seeds={"scene": run.seed}, threads={"pycolmap": run.pycolmap_threads})
    provenance = PT.TwinProvenance(
        env.git_commit, env.git_dirty, env.machine, run.seed, pairs_file.name, round(time.perf_counter() - t0, 1),
        PYCOLMAP_FEATURES, env, {k: PT.StageProvenance(v.git_commit, v.git_dirty, v.finished_utc)
                                 for k, v in sorted(stage_recs.items())})
    table = PT.TwinTable(run.twin, n, n_pairs, methods, provenance)
    PT.write_table(out, table)
    if run.tables_dir:  # the small committed copy (the run folder holds models, databases, caches)
        PT.write_table(Path(run.tables_dir) / run.twin, table)
        PR.write_readme(run.tables_dir)
    return table
