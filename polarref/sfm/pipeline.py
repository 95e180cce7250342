"""The SfM pipeline: configuration presets, cached stages, timings, outputs.

Entry point: :func:`run_sfm`. Features and verified matches are cached on disk, keyed by the
image contents and every setting that affects them, and reused on the next run.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core import execution
from polarref.core.atomic import (atomic_write, check_dir_target, check_writable_parent, holds_finished_result,
                                  publish_dir, refuse_inside_inputs)
from polarref.core.data import cache_root
from polarref.core.errors import PolarrefError
from polarref.model import Reconstruction
from polarref.sfm import features as F
from polarref.sfm.cache import cache_dir_for, cache_valid, code_digest, hash_parts, load_matches, save_matches, seal
from polarref.sfm.config import PRESETS, SfMConfig, with_ba  # noqa: F401 (re-exported)
from polarref.sfm import feature_cache as FC
from polarref.sfm import frontend as FE
from polarref.sfm import rays as R_
from polarref.sfm.bundle import to_reconstruction
from polarref.sfm.mapper import run_mapper
from polarref.sfm.priors_hook import prior_hook
from polarref.sfm.ba_export import write_final_ba
from polarref.sfm.report import ModelSummary, SfMReport, UnregisteredImage
from polarref.sfm.matching import match_pairs, select_pairs
from polarref.sfm.state import MapState
from polarref.sfm.tracks import build_tracks
from polarref.sfm.stages import StageClock, StageCost
from polarref.sfm.verification import TwoViewGeometry, verify_pairs
from polarref.io.scene_folder import SkippedImage
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)


@dataclass
class SfMResult:
    reconstruction: Reconstruction
    report: SfMReport      # what OUT/metrics.json holds (its JSON form: report.to_json())
    out_dir: Path | None
    stages: tuple[StageCost, ...] = ()   # every stage's wall/CPU time, peak memory, cache flag


@dataclass
class Matches:
    """Verified matches of an image set (what the pycolmap comparison imports)."""

    names: list[str]
    features: list[F.Features]
    putative: Mapping[tuple[int, int], np.ndarray]   # (i, j) -> (M, 2) int32 (sfm.matching.PairMatches)
    geometries: Mapping[tuple[int, int], TwoViewGeometry]   # sfm.verification.VerifiedPairs


# ---- camera -----------------------------------------------------------------------------------
def parse_camera(spec: str, width: int, height: int):
    """``MODEL:p1,p2,...`` (COLMAP parameter order) -> :class:`polarref.camera.Camera`."""
    from polarref.camera import Camera

    try:
        model, params = spec.split(":", 1)
        values = np.array([float(v) for v in params.replace(" ", "").split(",") if v])
        return Camera(model.strip().upper(), int(width), int(height), values)
    except (ValueError, TypeError) as exc:
        raise PolarrefError(f"camera {spec!r}: expected MODEL:p1,p2,... ({exc})", option="camera") from exc


def cameras_for_images(names: list[str], sizes: list[tuple[int, int]], camera=None,
                       gt: Reconstruction | None = None) -> tuple[list, np.ndarray]:
    """(unique cameras, camera index per image): from ``camera`` if given, else from GT by name."""
    if camera is not None:
        for n, (w, h) in zip(names, sizes):
            if (w, h) != (camera.width, camera.height):
                raise PolarrefError(f"image {n} is {w}x{h} but the camera is {camera.width}x{camera.height}")
        return [camera], np.zeros(len(names), np.int64)
    if gt is None:
        raise PolarrefError("intrinsics unknown: give camera intrinsics (MODEL:params) or a gt/ model "
                            "beside images/", option="camera")
    by_name = {im.name: im.camera_id for im in gt.images.values()}
    ids = sorted(gt.cameras)
    default = ids[0] if len(ids) == 1 else None
    idx = []
    for n, (w, h) in zip(names, sizes):
        cid = by_name.get(n, default)
        if cid is None:
            raise PolarrefError(f"image {n} is not in the ground truth and GT has several cameras")
        c = gt.cameras[cid]
        if (w, h) != (int(c.width), int(c.height)):
            # Applying intrinsics of another image size silently corrupts every ray.
            raise PolarrefError(f"image {n} is {w}x{h} but its ground-truth camera {cid} is "
                                f"{int(c.width)}x{int(c.height)}; give intrinsics for this size",
                                option="camera")
        idx.append(ids.index(cid))
    return [gt.cameras[i] for i in ids], np.array(idx, np.int64)


# ---- cache ------------------------------------------------------------------------------------
def _cache_file(config: SfMConfig, name: str) -> Path:
    """Path of a cache entry; the folder is only created when the cache is used (``use_cache``
    false never touches it, so an unwritable cache does not stop a --no-cache run)."""
    if config.use_cache:
        return cache_dir_for(config) / name
    return (Path(config.cache_dir) if config.cache_dir else cache_root() / "sfm") / name


def _parts_dir(config: SfMConfig) -> Path:
    """Where cluster tasks exchange files: the cache folder, or without the cache a scratch
    folder of this process in the system's temporary folder (local workers see it)."""
    d = (cache_dir_for(config) if config.use_cache
         else Path(tempfile.gettempdir()) / f"polarref-{os.getpid()}") / "parts"
    d.mkdir(parents=True, exist_ok=True)
    return d


# ---- stages -----------------------------------------------------------------------------------
def _read_skipped_json(path: Path) -> list[SkippedImage]:
    return [SkippedImage(str(s["name"]), str(s["reason"])) for s in json.loads(path.read_text())]


def _read_extraction_json(path: Path) -> float | None:
    """The extraction wall time stored beside a features cache entry (None: an entry from before)."""
    try:
        return float(json.loads(path.read_text())["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def load_images_and_features(image_dir: Path, config: SfMConfig,
                             clock: StageClock) -> tuple[list[F.Features], list[SkippedImage], str]:
    """Features of every readable image (cached); (features, skipped images, cache key).

    ``clock`` gets the ``features`` stage; loaded from the cache it is marked so, with the
    extraction time measured when the cache entry was made."""
    clock.start("features")
    paths = F.list_images(image_dir) if Path(image_dir).is_dir() else []
    if not paths:
        raise PolarrefError(f"no images found in {image_dir} (suffixes {', '.join(F.IMAGE_SUFFIXES)})")
    digests = [hashlib.sha256(p.read_bytes()).hexdigest() for p in paths]
    key = hash_parts("features", code_digest(F), [p.name for p in paths], digests, config.features)
    cache = _cache_file(config, f"features-{key}.npz")
    skipped_file = cache.with_suffix(".skipped.json")
    timing_file = cache.with_suffix(".extraction.json")
    if config.use_cache and cache_valid(cache) and cache_valid(skipped_file):
        # descriptors stay on disk until matching needs them (ensure_descriptors): with the
        # matches cached too, a run never reads them (631 views: 1.3 GB off the peak)
        feats = FC.load_without_descriptors(cache)
        skipped = _read_skipped_json(skipped_file)
        cached, measured = True, _read_extraction_json(timing_file)
    else:
        t0 = time.perf_counter()
        feats, skipped = _extract_all(paths, config, key)
        cached, measured = False, None
        if config.use_cache:
            F.save(cache, feats)
            seal(cache)
            atomic_write(skipped_file, json.dumps([dataclasses.asdict(s) for s in skipped]))
            seal(skipped_file)
            atomic_write(timing_file, json.dumps({"wall_s": time.perf_counter() - t0}))
    for s in skipped if len(feats) >= 2 else ():  # too few left: the one error line names them
        log.warning("skipped image %s: %s", s.name, s.reason)
    clock.stop(cached=cached, measured_s=measured)
    return feats, skipped, key


def ensure_descriptors(feats: list[F.Features], config: SfMConfig, feature_key: str) -> None:
    """Load the descriptors that :func:`load_images_and_features` left on disk (in place)."""
    if all(f.descriptors is not None for f in feats):
        return
    cache = cache_dir_for(config) / f"features-{feature_key}.npz"
    if not cache_valid(cache):
        raise PolarrefError(f"feature cache {cache} changed or vanished while in use; rerun")
    FC.load_descriptors(cache, feats)


def match_and_verify(feats: list[F.Features], cameras: list, camera_of_image: np.ndarray, config: SfMConfig,
                     feature_key: str, clock: StageClock, centers: np.ndarray | None = None) -> Matches:
    """Putative and verified matches (cached); ``clock`` gets the matching and verification stages."""
    clock.start("matching")
    cam_key = [(c.model, c.width, c.height, np.asarray(c.params).tolist()) for c in cameras]
    from polarref.sfm import matching, verification

    key = hash_parts("matches", code_digest(matching, verification), feature_key, config.matching, config.verification, cam_key,
                camera_of_image.tolist(), None if centers is None else np.round(centers, 9).tolist())
    cache = _cache_file(config, f"matches-{key}.npz")
    if config.use_cache and cache_valid(cache):
        putative, geoms = load_matches(cache)
        clock.stop(cached=True, measured_s=_read_extraction_json(cache.with_suffix(".extraction.json")))
        clock.add("verification", 0.0)
    else:
        ensure_descriptors(feats, config, feature_key)
        pairs = select_pairs(len(feats), config.matching, centers, names=[f.name for f in feats])
        focal = float(np.mean([R_.mean_focal(c) for c in cameras]))
        executor = execution.current()
        threads = FE.thread_count(config.threads)
        if executor.in_process and threads > 1:
            putative, geoms = _match_in_threads(feats, pairs, cameras, camera_of_image, focal, config, threads, clock)
        elif executor.in_process:
            putative = match_pairs([f.descriptors for f in feats], pairs, config.matching)
            clock.stop()
            clock.start("verification")
            xy = _normalized(feats, cameras, camera_of_image)
            geoms = verify_pairs(xy, putative, focal, config.verification)
            clock.stop()
        else:
            putative, geoms = _match_on_cluster(executor, feats, pairs, cameras, camera_of_image, focal, config,
                                                key, clock)
        if config.use_cache:
            save_matches(cache, putative, geoms)
            atomic_write(cache.with_suffix(".extraction.json"), json.dumps(
                {"wall_s": clock.seconds("matching") + clock.seconds("verification")}))
    return Matches([f.name for f in feats], feats, putative, geoms)


def _normalized(feats: list[F.Features], cameras: list, camera_of_image: np.ndarray) -> list[np.ndarray]:
    return [R_.normalized(R_.bearings(cameras[camera_of_image[i]], f.keypoints)) for i, f in enumerate(feats)]


def _match_in_threads(feats: list[F.Features], pairs: list[tuple[int, int]], cameras: list,
                      camera_of_image: np.ndarray, focal: float, config: SfMConfig, threads: int, clock: StageClock):
    """Matching + verification of chunks of pairs on ``threads`` threads, merged in pair order."""
    data = FE.FrontEndInput([f.descriptors for f in feats], _normalized(feats, cameras, camera_of_image), focal,
                            config.matching, config.verification)
    done = FE.match_and_verify_threaded(data, pairs, threads)
    putative = {p: m for d in done for p, m in d.putative.items()}
    geoms = {p: g for d in done for p, g in d.geometries.items()}
    # both steps ran inside the same tasks: split the stage by their CPU shares
    clock.stop()
    m_s, v_s = sum(d.matching_s for d in done), sum(d.verification_s for d in done)
    clock.split("matching", ("matching", "verification"), m_s / (m_s + v_s) if m_s + v_s > 0 else 1.0)
    return putative, geoms


def _extract_all(paths: list[Path], config: SfMConfig, key: str) -> tuple[list[F.Features], list[SkippedImage]]:
    """One task per image: in this process on the front end's threads, or on a cluster where each
    task writes its features to a file in the cache folder."""
    from polarref.sfm.tasks import ExtractTask, extract_image

    executor = execution.current()
    parts = None if executor.in_process else _parts_dir(config)
    tasks = [ExtractTask(str(p), config.features, None if parts is None else str(parts / f"features-{key}-{os.getpid()}-{i:05d}.npz"))
             for i, p in enumerate(paths)]
    feats, skipped = [], []
    run = (executor.map(extract_image, tasks, desc="features") if not executor.in_process
           else FE.thread_map(extract_image, tasks, FE.thread_count(config.threads), "features"))
    for done in run:
        if done.skipped:  # warned once, by the caller, with the cached case
            skipped.append(SkippedImage(done.name, done.skipped))
        elif done.features is not None:
            feats.append(done.features)
        else:
            feats.append(F.load(Path(done.path))[0])
            Path(done.path).unlink(missing_ok=True)
    return feats, skipped


def _match_on_cluster(executor, feats: list[F.Features], pairs: list[tuple[int, int]], cameras: list,
                      camera_of_image: np.ndarray, focal: float, config: SfMConfig, key: str, clock: StageClock):
    """Matching + verification as chunk tasks exchanging files; merged in pair order."""
    from polarref.sfm.tasks import MatchTask, chunks, match_chunk

    parts = _parts_dir(config)
    feat_file = parts / f"features-for-{key}-{os.getpid()}.npz"
    F.save(feat_file, feats)
    tasks = [MatchTask(str(feat_file), tuple(c), tuple(cameras), tuple(int(i) for i in camera_of_image), focal,
                       config.matching, config.verification, str(parts / f"matches-{key}-{os.getpid()}-{k:05d}.npz"))
             for k, c in enumerate(chunks(pairs, executor.size()))]
    done = executor.map(match_chunk, tasks, desc="matching")
    putative_all, geoms_all = {}, {}
    for d in done:
        path = Path(d.path)
        if not cache_valid(path):  # written and sealed by the worker: a bad copy on a shared disk
            raise PolarrefError(f"match chunk {path} is missing or corrupt on this machine; "
                                "the workers and this client need one shared folder")
        m, g = load_matches(path)
        putative_all.update(m)
        geoms_all.update(g)
        for p in (path, path.with_name(path.name + ".sha256")):
            p.unlink(missing_ok=True)
    feat_file.unlink(missing_ok=True)
    putative = {p: putative_all[p] for p in pairs if p in putative_all}
    geoms = {p: geoms_all[p] for p in pairs if p in geoms_all}
    # Matching and verification ran inside the same tasks: split the wall time by their CPU shares.
    clock.stop()
    m_s, v_s = sum(d.matching_s for d in done), sum(d.verification_s for d in done)
    clock.split("matching", ("matching", "verification"), m_s / (m_s + v_s) if m_s + v_s > 0 else 1.0)
    return putative, geoms


def _prepare_out(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and any(out_dir.iterdir()) and not overwrite:
        raise PolarrefError(f"output folder {out_dir} exists and is not empty", option="overwrite")
    out_dir.mkdir(parents=True, exist_ok=True)
SFM_OUTPUTS = ("model", "metrics.json")  # what a run writes into its folder (the rest is the user's)


def run_sfm(image_dir: str | Path, out_dir: str | Path | None, config: SfMConfig = SfMConfig(),
            camera=None, gt: Reconstruction | None = None,
            mesh: tuple[np.ndarray, np.ndarray] | None = None, overwrite: bool = False,
            model_format: str = "text", priors: tuple = (), image_sigma_px: float = 0.5,
            export_final_ba: str | Path | None = None) -> SfMResult:
    """Run the whole pipeline on ``image_dir`` and write ``out_dir/model`` and ``out_dir/metrics.json``.

    Args:
        image_dir: folder of images.
        out_dir: output folder (None: nothing written).
        camera: known intrinsics (:class:`polarref.camera.Camera`) shared by all images; else from gt.
        gt: ground-truth model (cameras, and poses for the aligned errors).
        mesh: (vertices, faces) of the true surface in GT coordinates, for point-to-surface errors.
        overwrite: replace a non-empty ``out_dir``. The new folder is built in a hidden
            sibling and swapped in whole when complete, so ``out_dir`` always holds one run's
            outputs: the old ones until the new ones are written, never a mix.
            It also lets ``export_final_ba`` replace an existing file.
        model_format: COLMAP ``text``, ``binary`` or ``both``; ``model/points3D.ply`` is always written.
        priors: pose priors (:class:`polarref.georef.formats.PosePrior`) used inside the mapper
            (sfm/priors_hook.py), weighted against tie points of ``image_sigma_px``: the model
            comes out in the priors' frame. Not with intrinsics refinement or ``--ba colmap``.
        export_final_ba: write the largest model's last global BA as it entered our solver, with
            its options, its result and ``gt``'s poses, to this ``.npz`` (sfm.ba_export; read by
            ``polarref ba`` and the BA bench). None (default): nothing is kept or written.
    Raises:
        PolarrefError: no images, unknown intrinsics, no initial pair, < 2 registered images.
            metrics.json is still written with what was done, unless ``out_dir`` holds a
            finished result, which is then left as it was. A failure after the
            reconstruction (GT metrics) does not raise: the model is kept and the failure is
            named in ``report.gt_skipped``.
    """
    from polarref import metrics as M

    target = Path(out_dir) if out_dir is not None else None
    if target is not None:  # fail before any work, not after it
        refuse_inside_inputs(target, [image_dir])
        check_dir_target(target, overwrite)
        check_writable_parent(target)
    if export_final_ba is not None:
        _check_export(Path(export_final_ba), overwrite, priors, config)
    t_start = time.perf_counter()
    clock = StageClock()
    from polarref.core.provenance import collect_record

    extra: list[Reconstruction] = []
    report = SfMReport(str(image_dir), config, collect_record(seeds={
        "verification": config.verification.seed, "registration": config.mapper.register.seed}))

    def _publish(rec: Reconstruction | None) -> None:
        if target is None:
            return
        with publish_dir(target, overwrite=overwrite, owned=SFM_OUTPUTS) as out:
            if rec is not None:
                clock.start("export")
                _update_point_errors(rec)
                from polarref.sfm.model_files import write_model

                write_model(rec, out / "model", model_format)
                for k, r in enumerate(extra):
                    write_model(r, out / f"model-{k + 2}", model_format)
                clock.stop()
            clock.add("total", time.perf_counter() - t_start)
            report.runtime_s = clock.to_json()
            M.write_json(out / "metrics.json", report.to_json())

    from polarref.sfm import budget as B

    config_features, rule = B.choose(config.features, SfMConfig().features, photos=camera is None and gt is None,
                                     full_size=config.full_size, sizes=B.header_sizes(image_dir))
    config = dataclasses.replace(config, features=config_features)
    try:
        feats, skipped, fkey = load_images_and_features(Path(image_dir), config, clock)
        report.feature_budget = B.describe(config.features, rule, [(f.width, f.height) for f in feats],
                                           [len(f.keypoints) for f in feats])
        report.skipped_images = list(skipped)
        report.num_images = len(feats) + len(skipped)
        if len(feats) < 2:
            why = f" ({len(skipped)} skipped, e.g. {skipped[0].name}: {skipped[0].reason})" if skipped else ""
            raise PolarrefError(f"{len(feats)} readable image(s) in {image_dir}{why}; need at least 2")
        sizes = [(f.width, f.height) for f in feats]
        if camera is None and gt is None:  # a folder of photos: cameras from EXIF, self-calibrated
            from polarref.sfm.calibration import EXIF_REFINE, cameras_from_exif

            cameras, cam_idx, sources = cameras_from_exif(
                [Path(image_dir) / f.name for f in feats], sizes, config.camera_mode)
            auto_refine = EXIF_REFINE
            guessed = np.array([k for k, src in enumerate(sources) if src == "default"], np.int64)
            config = dataclasses.replace(config, verification=dataclasses.replace(
                config.verification, uncalibrated_images=tuple(
                    int(i) for i in np.flatnonzero(np.isin(cam_idx, guessed)))))
        else:
            cameras, cam_idx = cameras_for_images([f.name for f in feats], sizes, camera, gt)
            sources, auto_refine = ["given" if camera is not None else "gt"] * len(cameras), ()
            guessed = np.zeros(0, np.int64)
        if config.mapper.refine is None:
            config = dataclasses.replace(config, mapper=dataclasses.replace(
                config.mapper, refine=auto_refine))
        initial_cameras = list(cameras)
        matches = match_and_verify(feats, cameras, cam_idx, config, fkey, clock)
        report.num_verified_pairs = len(matches.geometries)
        clock.start("tracks")
        tracks = build_tracks([len(f.keypoints) for f in feats],
                              {k: g.inliers for k, g in matches.geometries.items()},
                              conflicts=config.track_conflicts)
        clock.stop()
        report.num_tracks = int(tracks.num_tracks)
        report.num_conflicting_tracks_dropped = int(tracks.num_conflicting)
        clock.start("mapping")
        if config.mapper.guided.enabled:
            ensure_descriptors(feats, config, fkey)
        descriptors = [f.descriptors for f in feats] if config.mapper.guided.enabled else None
        if descriptors is None:
            # only guided matching reads them after matching: released before the mapper's BA
            # peak (168 comet views: ~180 of 850 MiB peak; issue 14's 2 GB target at 631 views)
            for f in feats:
                f.descriptors = None
        models = _map_all(feats, list(cameras), cam_idx, guessed, tracks, matches.geometries, config,
                          descriptors, priors, image_sigma_px, export_final_ba is not None)
        state, mlog = models[0]
        clock.stop()
        if export_final_ba is not None:
            write_final_ba(Path(export_final_ba), mlog.final_ba, [f.name for f in feats], gt,
                           f"polarref sfm {image_dir} (ba={config.mapper.ba}): last global BA of the largest model")
        clock.add("ba", float(sum(b.wall_s for _, ml in models for b in ml.ba)))
        report.initial_pair = [feats[i].name for i in mlog.initial_pair]
        report.registration_order = [feats[i].name for i in mlog.registration_order]
        report.models = [ModelSummary("model" if k == 0 else f"model-{k + 1}", int(st.registered.sum()),
                                      int(st.has_point.sum()), [feats[i].name for i in ml.registration_order],
                                      [feats[i].name for i in ml.initial_pair])
                         for k, (st, ml) in enumerate(models)]
        report.unregistered = _unregistered(models, matches.geometries, [f.name for f in feats])
        report.unregistered_images = [u.name for u in report.unregistered]
        if report.unregistered:
            log.warning("%d of %d images are in no model (%s): %s", len(report.unregistered), len(feats),
                        "listed under 'unregistered' in metrics.json",
                        "; ".join(f"{u.name}: {u.reason}" for u in report.unregistered[:5])
                        + ("; ..." if len(report.unregistered) > 5 else ""))
        if len(models) > 1:
            log.warning("the images form %d separate models (they share no registrable view); the "
                        "largest (%d images) is model/, the others model-2/ ...", len(models),
                        report.models[0].num_registered)
        report.guided_observations = int(sum(ml.guided_observations for _, ml in models))
        report.ba = mlog.ba
        from polarref.sfm.calibration import camera_reports

        report.refine = list(config.mapper.refine)
        if report.refine and not any(b.kind == "global" and b.refined_intrinsics for b in mlog.ba):
            log.warning("intrinsics not refined (%s requested): %d registered images, refinement starts at %d",
                        ",".join(report.refine), int(state.registered.sum()), config.mapper.refine_min_images)
            report.refine = []
        if "pp" in report.refine and not mlog.pp_refined:  # held: too few images, or drifted (sfm/mapper.py)
            report.refine.remove("pp")
        report.cameras = camera_reports(initial_cameras, state.cameras, sources, cam_idx,
                                        [f.name for f in feats], gt)
        rec = to_reconstruction(state, colors=[f.colors for f in feats])
        extra = [to_reconstruction(st, colors=[f.colors for f in feats]) for st, _ in models[1:]]
    except PolarrefError as exc:
        clock.close()
        report.status = RunStatus.FAILED
        report.error = str(exc)
        clock.add("total", time.perf_counter() - t_start)
        report.runtime_s = clock.to_json()
        if target is not None and holds_finished_result(target):
            # a failed rerun never replaces a finished result by its failure
            raise PolarrefError(f"{exc}; the finished result in {target} was kept", option=exc.option) from exc
        _publish(None)
        raise
    clock.start("metrics")
    report.metrics, report.gt_skipped = _score(rec, gt, mesh, report.num_images)
    clock.stop()
    report.status = RunStatus.OK
    clock.add("total", time.perf_counter() - t_start)
    report.runtime_s = clock.to_json()
    _publish(rec)
    return SfMResult(rec, report, target, tuple(clock.stages))


def _map_all(feats, cameras: list, cam_idx: np.ndarray, guessed: np.ndarray, tracks,
             geoms: dict[tuple[int, int], TwoViewGeometry], config: SfMConfig, descriptors,
             priors=(), image_sigma_px: float = 0.5, export_final: bool = False):
    """[(state, log)] of every model, largest first: each next one from the images left out.

    Every model gets its own prior hook (pose priors place each model in the priors' frame)."""
    names = [f.name for f in feats]
    def new_state(cams, guess):
        st = MapState([f.name for f in feats], list(cams), cam_idx, [f.keypoints for f in feats], tracks,
                      config.triangulation)
        st.guess_focal(guess)
        return st

    state = new_state(cameras, guessed)
    models = [(state, run_mapper(state, geoms, config.mapper, descriptors,
                                 prior_hook(priors, names, image_sigma_px, config.mapper),
                                 export_final=export_final))]
    left = ~state.registered
    while len(models) < config.max_models and left.sum() >= 2 and any(left[i] and left[j] for i, j in geoms):
        prev = models[-1][0]
        # a camera refined in one model starts the next from there; guesses stay guesses
        st = new_state(prev.cameras, np.flatnonzero(prev.focal_guessed))
        try:
            ml = run_mapper(st, geoms, config.mapper, descriptors,
                            prior_hook(priors, names, image_sigma_px, config.mapper), allowed=left,
                            export_final=export_final)
        except PolarrefError as exc:  # what is left does not make a model
            log.info("no further model from %d images: %s", int(left.sum()), exc)
            break
        models.append((st, ml))
        left &= ~st.registered
    models.sort(key=lambda m: -int(m[0].registered.sum()))
    return models


def _check_export(path: Path, overwrite: bool, priors: tuple, config: SfMConfig) -> None:
    """Refuse an export that cannot be written, before any work."""
    if path.exists() and not overwrite:
        raise PolarrefError(f"{path} exists", option="overwrite")
    if path.suffix.lower() != ".npz":
        raise PolarrefError(f"{path}: the exported BA problem is an .npz file; name it *.npz")
    if priors or config.mapper.ba == "colmap":
        raise PolarrefError("the BA export takes our adjusters without pose priors (format version 1)")
    check_writable_parent(path)


def _unregistered(models, geoms: dict[tuple[int, int], TwoViewGeometry], names: list[str]) -> list[UnregisteredImage]:
    """Every image in no model, with the reason."""
    in_model = np.zeros(len(names), bool)
    for st, _ in models:
        in_model |= st.registered
    paired = np.zeros(len(names), bool)
    for i, j in geoms:
        paired[[i, j]] = True
    failed = {k: v for _, ml in models for k, v in ml.failed_registrations.items()}
    out = []
    for i in np.flatnonzero(~in_model):
        if not paired[i]:
            why = "no verified image pair: it overlaps no other image (or too little to match)"
        elif i in failed:
            why = f"its pose could not be estimated ({failed[int(i)]} failed attempts; too few 2D-3D inliers)"
        else:
            why = "too few of its matches reached 3D points of any model"
        out.append(UnregisteredImage(names[int(i)], why))
    return out


def _score(rec: Reconstruction, gt: Reconstruction | None, mesh, num_images: int):
    """(metrics, gt_skipped) of a finished reconstruction. A GT comparison that cannot be made is
    skipped with its reason rather than losing the reconstruction."""
    from polarref import metrics as M

    if gt is not None:
        common = {im.name for im in rec.images.values()} & {im.name for im in gt.images.values()}
        if len(common) < 3:
            reason = (f"only {len(common)} registered image name(s) also in gt/ (need 3 to align); "
                      "image names must match the gt/ model")
            return M.evaluate(rec, num_images=num_images), reason
    try:
        return M.evaluate(rec, gt=gt, mesh=mesh, num_images=num_images), ""
    except (ValueError, np.linalg.LinAlgError, PolarrefError) as exc:
        return M.evaluate(rec, num_images=num_images), f"{type(exc).__name__}: {exc}"


def _update_point_errors(rec: Reconstruction) -> None:
    from polarref.metrics import mean_error_per_point, observation_errors

    errs, pidx = observation_errors(rec)
    pids = sorted(rec.points3D)
    for pid, e in zip(pids, mean_error_per_point(errs, pidx, len(pids))):
        rec.points3D[pid].error = float(e)
