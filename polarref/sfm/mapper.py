"""Stage 7: the incremental loop (register, triangulate, local/global BA, filter, retriangulate)."""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.core.progress import track
from polarref.sfm import bundle
from polarref.sfm import rays as R_
from polarref.sfm.guided import GuidedConfig, guided_extend
from polarref.sfm.initial_pair import InitConfig, choose_initial_pair
from polarref.sfm.priors_hook import PriorHook
from polarref.sfm.registration import RegisterConfig, estimate_pose, estimate_pose_and_focal
from polarref.sfm.ba_runs import BARun, ExportedBA
from polarref.sfm.state import MapState
from polarref.sfm.verification import TwoViewGeometry

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MapperConfig:
    """Incremental mapping settings."""

    ba: str = "euclidean"              # bundle adjuster: euclidean | parallax | polar | angular | colmap
    local_ba_images: int = 6           # new image + its most covisible registered images are variable
    # LM iteration cap of a local BA. Under the Cauchy loss our IRLS steps creep (gain ratio ~2,
    # < 0.5 % decrease per step): 25 iterations cost 3x the CPU of 6 at 168 views and left the
    # 28-view comet's result unchanged (0.0479 deg either way); global BA does the rest
    local_ba_iterations: int = 6
    local_ba_loss: str = "cauchy"      # robust loss for local BA (outliers not yet filtered)
    local_ba_function_tolerance: float = 1e-6  # relative cost decrease that ends a local BA
    # global BA once the registered images or the 3D points grew by these factors since the last
    # one (COLMAP: ba_global_frames_ratio / ba_global_points_ratio 1.1; its BA is C++). The total
    # global-BA work is then ~1 / (1 - 1 / ratio) times that of the final model: 3.5x at 1.4
    global_ba_growth: float = 1.4
    global_ba_points_growth: float = 1.4
    global_ba_iterations: int = 50     # LM iteration cap of a global BA
    global_ba_loss: str = "trivial"    # global BA runs after filtering: plain least squares
    final_ba_rounds: int = 2           # rounds of (retriangulate, global BA, filter) at the end
    # intrinsics groups refined (focal, pp, dist) in global BA only, once refine_min_images
    # images are registered (a smaller set keeps its start intrinsics: on 2 images focal and
    # distortion trade off against depth, f 386 -> 807); local BA holds them. None = decided by
    # the pipeline (EXIF cameras: focal, dist as COLMAP; given/GT cameras: none)
    refine: tuple | None = None
    refine_min_images: int = 10
    # extra final rounds when intrinsics are refined (COLMAP repeats global BA + filtering up
    # to ba_global_max_refinements = 5 times). Fountain-P11, focal 10 % off: 2 rounds left
    # 0.33 % focal and 0.056 deg rotation error, 4 rounds 0.13 % and 0.026 deg
    refine_extra_rounds: int = 2
    max_registration_attempts: int = 3  # failed PnP attempts per image before giving up on it
    # when no image registers any more: global BA, track completion and re-triangulation, then
    # every unregistered image gets max_registration_attempts more tries (at the register
    # config's retry threshold), as long as the previous round registered something
    retry_rounds: int = 5
    # ... and from the first such round on, points down to this ray angle are kept (deg; the
    # triangulation's min_angle_deg, COLMAP's 1.5, holds until then). Walking forward down a
    # street (Lund, photo 16 of 29) the tracks shared with the map's last images are seen from
    # nearly one direction: 99 of them had no point (below 1.5 deg or over 2 px), 42 keypoints
    # reached 3D points, PnP needs 30 inliers; at 1.0 deg 25 of 29 photos register instead of 15
    stalled_min_angle_deg: float = 1.0
    # a camera still at its guessed focal length (no EXIF) with registered images is refined in
    # every global BA from this many registered images on (EXIF / given focal lengths wait for
    # refine_min_images)
    refine_guessed_min_images: int = 3
    # the principal point ("pp" in refine) is refined in the final rounds only, and only when every
    # camera of the map holds pp_min_images registered images: fewer views do not separate it from
    # the rotations. Fountain-P11 (GT principal point 23 px off the centre, 0.48 deg of tilt that a
    # centre-aligned rotation error counts): refined to 1.5 px of GT, rotation error 0.49 -> 0.045 deg
    pp_min_images: int = 10
    # a principal point refined farther than this fraction of the longer side from the image
    # centre is drift along the pp/rotation valley, not a lens (Lund 90 px of 1024, Sceaux 116 of
    # 2832; refined from 10 images on, Lund's moved 97 px and its k changed sign; Fountain's
    # calibrated offset is 0.75 %): reset to the centre and held
    pp_max_offset: float = 0.02
    guided: GuidedConfig = field(default_factory=GuidedConfig)  # track continuation (needs descriptors)
    init: InitConfig = field(default_factory=InitConfig)
    register: RegisterConfig = field(default_factory=RegisterConfig)


@dataclass
class MapperLog:
    initial_pair: tuple[int, int] = (-1, -1)
    registration_order: list[int] = field(default_factory=list)
    failed_registrations: dict[int, int] = field(default_factory=dict)
    ba: list[BARun] = field(default_factory=list)  # every BA run, in order (kind: local|global)
    guided_observations: int = 0  # observations added by guided matching (before filtering)
    retry_rounds: int = 0         # rounds of retries after no image registered (see MapperConfig)
    focal_estimates: dict[int, float] = field(default_factory=dict)  # camera -> focal (px) from P4Pf
    pp_refined: list[int] = field(default_factory=list)  # cameras whose principal point was refined and kept
    pp_reset: list[int] = field(default_factory=list)    # ... refined, found past pp_max_offset, reset
    final_ba: ExportedBA | None = None  # run_mapper(export_final=True): the last global BA's problem


def _image_tracks(state: MapState, image: int) -> np.ndarray:
    o = state.obs_of_kp[image]
    return state.tracks.track[o[o >= 0]]


def _global_ba(state: MapState, cfg: MapperConfig, log_: MapperLog, gauge: list[int],
               hook: PriorHook | None = None, pp: bool = False, export: bool = False) -> None:
    if hook is not None:
        hook.realign(state)
    reg = [int(i) for i in np.flatnonzero(state.registered)]
    var = [i for i in reg if i not in gauge]
    # early intrinsics are poorly constrained (COLMAP also treats its first ~10 images apart),
    # except a camera still at its guessed focal length with images in the map (the initial
    # pair's: the others get theirs from P4Pf at their first registration): PnP of its next
    # images under a guess tens of % off fails, so it is refined from refine_guessed_min_images on
    guess_in_map = bool(state.focal_guessed[state.camera_of_image[reg]].any())
    enough = len(reg) >= cfg.refine_min_images or (guess_in_map and len(reg) >= cfg.refine_guessed_min_images)
    refine = tuple(g for g in cfg.refine or () if g != "pp" or pp) if enough else ()
    info = bundle.adjust(state, var, list(gauge), cfg.ba, cfg.global_ba_iterations, cfg.global_ba_loss,
                         refine=refine, priors=hook, export=export)
    info.kind, info.num_registered = "global", len(reg)
    if export:  # the latest one is kept: after the final rounds it is the mapper's last global BA
        log_.final_ba, info.exported = info.exported, None
    log_.ba.append(info)


def _local_ba(state: MapState, image: int, cfg: MapperConfig, log_: MapperLog, gauge: list[int],
              hook: PriorHook | None = None) -> None:
    cov = state.covisibility(image)
    cov[image] = 0
    cov[~state.registered] = 0
    nbrs = [int(i) for i in np.argsort(-cov, kind="stable")[: cfg.local_ba_images - 1] if cov[i] > 0]
    variable = [i for i in [image] + nbrs if i not in gauge]
    tr = state.tracks
    var_mask = np.zeros(len(state.keypoints), bool)
    var_mask[variable] = True
    mine = np.concatenate([state.obs_of_kp[i][state.obs_of_kp[i] >= 0] for i in variable] or [np.zeros(0, np.int64)])
    pts = np.unique(tr.track[mine[state.active[mine]]])
    if not len(pts) or not variable:
        return
    o = state.obs_of_tracks(pts)
    obs_imgs = np.unique(tr.image[o[state.active[o]]])
    fixed = [int(i) for i in obs_imgs if not var_mask[i]]
    info = bundle.adjust(state, variable, fixed, cfg.ba, cfg.local_ba_iterations, cfg.local_ba_loss,
                         track_ids=pts, function_tolerance=cfg.local_ba_function_tolerance, priors=hook)
    info.kind, info.image, info.num_variable, info.num_fixed = "local", image, len(variable), len(fixed)
    log_.ba.append(info)
    state.filter(pts)


def _retriangulate(state: MapState) -> tuple[int, int]:
    """Extend existing points to consistent observations, then triangulate tracks without points."""
    ext = state.extend()
    new = state.triangulate(np.flatnonzero(~state.has_point))
    return ext, new


def _guided(state: MapState, images, descriptors, cfg: MapperConfig, out: MapperLog) -> None:
    if descriptors is not None and cfg.guided.enabled:
        out.guided_observations += guided_extend(state, images, descriptors, cfg.guided)


def _register_next(state: MapState, cfg: MapperConfig, out: MapperLog, gauge: list[int], descriptors,
                   fails: dict[int, int], tried: set[int], allowed: np.ndarray,
                   hook: PriorHook | None = None) -> bool:
    """Register the best candidate that succeeds (next-best-view order); False when none does.

    ``gauge`` is updated in place: once the priors place the map, no camera is held."""
    vis = state.num_visible()
    score = state.visibility_scores()
    ok = allowed & ~state.registered & (vis >= cfg.register.min_inliers)
    cands = [int(i) for i in np.argsort(-score, kind="stable")
             if ok[i] and fails.get(int(i), 0) < cfg.max_registration_attempts]
    for c in cands:
        rc = cfg.register
        if c in tried:
            rc = dataclasses.replace(rc, max_error_px=max(rc.max_error_px, rc.retry_max_error_px))
        obs, X = state.correspondences_2d3d(c)
        k = int(state.camera_of_image[c])
        seed = rc.seed + c + 100003 * out.retry_rounds
        if state.focal_guessed[k] and not state.registered[state.camera_of_image == k].any():
            # first image of a camera without a known focal length: P4Pf estimates it with the pose
            est = estimate_pose_and_focal(state.uv[obs], X, state.cameras[k], rc, seed)
            if est is not None:
                log.info("image %s: focal length %.1f px estimated with its pose (guess %.1f px)",
                         state.names[c], est.camera.fx, state.cameras[k].fx)
                state.set_camera(k, est.camera)
                state.focal_guessed[k] = False
                out.focal_estimates[k] = float(est.camera.fx)
        else:
            f = R_.mean_focal(state.cameras[k])
            est = estimate_pose(R_.normalized(state.ray[obs]), X, f, rc, seed)
        if est is None:
            fails[c] = fails.get(c, 0) + 1
            out.failed_registrations[c] = out.failed_registrations.get(c, 0) + 1
            tried.add(c)
            continue
        state.set_pose(c, est.cam_from_world)
        state.active[obs[est.inliers]] = True
        out.registration_order.append(c)
        state.triangulate(_image_tracks(state, c))
        state.extend(_image_tracks(state, c))
        _guided(state, [c], descriptors, cfg, out)
        if hook is not None and hook.place(state):
            gauge[:] = hook.gauge(gauge)
        _local_ba(state, c, cfg, out, gauge, hook)
        state.triangulate(_image_tracks(state, c))
        return True
    return False


def run_mapper(state: MapState, geoms: dict[tuple[int, int], TwoViewGeometry],
               cfg: MapperConfig, descriptors: list[np.ndarray] | None = None,
               hook: PriorHook | None = None, allowed: np.ndarray | None = None,
               export_final: bool = False) -> MapperLog:
    """Incremental reconstruction into ``state``; returns what happened.

    Args:
        descriptors: (K_i, 128) unit descriptors per image; enables guided matching (guided.py).
        hook: pose priors (priors_hook.py): the map is moved into their frame once they fix it,
            and every later BA carries them.
        allowed: (N,) bool, images this model may hold (default all): a second model is built
            from the images the first left out.
        export_final: keep the last global BA's problem, options and result in ``final_ba``
            (copies of the final rounds' problems; nothing else changes).

    Raises:
        PolarrefError: no initial pair, or fewer than two images registered.
    """
    out = MapperLog()
    n = len(state.keypoints)
    allowed = np.ones(n, bool) if allowed is None else np.asarray(allowed, bool)
    geoms = {p: g for p, g in geoms.items() if allowed[p[0]] and allowed[p[1]]}
    rays = [np.zeros((len(k), 3)) for k in state.keypoints]
    for i in range(n):
        o = state.obs_of_kp[i]
        rays[i][o >= 0] = state.ray[o[o >= 0]]
        if (o < 0).any():
            rays[i][o < 0] = R_.bearings(state.cameras[state.camera_of_image[i]], state.keypoints[i][o < 0])
    init = choose_initial_pair(geoms, rays, cfg.init)
    i0, i1 = init.pair
    out.initial_pair = (i0, i1)
    log.info("initial pair %s: %d points above %.1f deg", init.pair, init.num_points, init.min_angle_deg)
    state.set_pose(i0, Rigid3.identity())
    state.set_pose(i1, geoms[(i0, i1)].cam2_from_cam1)
    # Gauge (7 DoF): the pose of i0 is held fixed (6); the scale (1) is fixed by the adjuster itself
    # (pycolmap: TWO_CAMS_FROM_WORLD; polarref.ba: one centre coordinate of another camera).
    state.triangulate(np.union1d(_image_tracks(state, i0), _image_tracks(state, i1)))
    _global_ba(state, cfg, out, gauge=[i0])
    state.filter()
    if state.has_point.sum() < 15:
        raise PolarrefError(f"initial pair {init.pair} produced only {int(state.has_point.sum())} points")
    out.registration_order += [i0, i1]
    gauge = [i0]
    if hook is not None and hook.place(state):
        gauge = hook.gauge(gauge)
    n_at_global, pts_at_global = 2, int(state.has_point.sum())
    fails: dict[int, int] = {}
    tried: set[int] = set()  # images with a failed attempt: later attempts use the retry threshold
    rescued_at = -1
    for _ in track(range(int(allowed.sum()) - 2), desc="registration", total=int(allowed.sum()) - 2):
        done = _register_next(state, cfg, out, gauge, descriptors, fails, tried, allowed, hook)
        if not done and cfg.retry_rounds > out.retry_rounds and int(state.registered.sum()) != rescued_at:
            # the map grew since the images failed: complete it, then give them new tries
            rescued_at = int(state.registered.sum())
            out.retry_rounds += 1
            if state.tri.min_angle_deg > cfg.stalled_min_angle_deg:
                log.info("no image registers at %d of %d: points down to %.1f deg kept from now on", rescued_at,
                         int(allowed.sum()), cfg.stalled_min_angle_deg)
                state.tri = dataclasses.replace(state.tri, min_angle_deg=cfg.stalled_min_angle_deg)
            _global_ba(state, cfg, out, gauge, hook)
            state.filter()
            _retriangulate(state)
            _guided(state, np.flatnonzero(state.registered), descriptors, cfg, out)
            fails.clear()
            done = _register_next(state, cfg, out, gauge, descriptors, fails, tried, allowed, hook)
        if not done:
            break
        if (state.registered.sum() >= cfg.global_ba_growth * n_at_global
                or state.has_point.sum() >= cfg.global_ba_points_growth * pts_at_global):
            _global_ba(state, cfg, out, gauge, hook)
            state.filter()
            _retriangulate(state)
            _guided(state, np.flatnonzero(state.registered), descriptors, cfg, out)
            n_at_global, pts_at_global = int(state.registered.sum()), int(state.has_point.sum())
    out.failed_registrations = {k: v for k, v in out.failed_registrations.items() if not state.registered[k]}
    pp = "pp" in (cfg.refine or ()) and _pp_separable(state, cfg)
    rounds = cfg.final_ba_rounds + (cfg.refine_extra_rounds if cfg.refine else 0)
    for _ in range(rounds):
        _retriangulate(state)
        _guided(state, np.flatnonzero(state.registered), descriptors, cfg, out)
        _global_ba(state, cfg, out, gauge, hook, pp=pp, export=export_final)
        state.filter()
    if pp:
        out.pp_reset = _reset_far_principal_points(state, cfg)
        used = np.unique(state.camera_of_image[state.registered])
        out.pp_refined = [int(c) for c in used if int(c) not in out.pp_reset]
        for _ in range(cfg.final_ba_rounds if out.pp_reset else 0):  # the map settles on the held centre
            _retriangulate(state)
            _global_ba(state, cfg, out, gauge, hook, export=export_final)
            state.filter()
    if state.registered.sum() < 2:
        raise PolarrefError("fewer than two images could be registered")
    return out


def _pp_separable(state: MapState, cfg: MapperConfig) -> bool:
    """Whether every camera of the map holds enough registered images to refine its principal point."""
    counts = np.bincount(state.camera_of_image[state.registered], minlength=len(state.cameras))
    used = counts[counts > 0]
    return bool(len(used)) and int(used.min()) >= cfg.pp_min_images


def _reset_far_principal_points(state: MapState, cfg: MapperConfig) -> list[int]:
    """Cameras whose refined principal point lies past ``pp_max_offset`` of the longer side from
    the image centre, reset to the centre (the caller re-adjusts the map)."""
    reset = []
    for c in np.unique(state.camera_of_image[state.registered]):
        cam = state.cameras[int(c)]
        centred = centred_if_far(cam, cfg.pp_max_offset)
        if centred is None:
            continue
        log.info("camera %d: principal point refined %.1f px off the image centre (> %.0f %% of %d px): "
                 "taken for drift, held at the centre", int(c) + 1, _pp_offset(cam), 100 * cfg.pp_max_offset,
                 max(cam.width, cam.height))
        state.set_camera(int(c), centred)
        reset.append(int(c))
    return reset


def _pp_offset(cam) -> float:
    return float(np.linalg.norm(cam.principal_point - np.array([cam.width, cam.height]) / 2.0))


def centred_if_far(cam, max_offset: float):
    """``cam`` with its principal point at the image centre when it lies farther than
    ``max_offset`` x the longer side from it; None when it does not."""
    if _pp_offset(cam) <= max_offset * max(cam.width, cam.height):
        return None
    params = cam.params.copy()
    params[[cam.param_names.index("cx"), cam.param_names.index("cy")]] = [cam.width / 2.0, cam.height / 2.0]
    return type(cam)(cam.model, cam.width, cam.height, params)
