"""Render a scene folder with Mitsuba 3: images, depth maps and exact ground truth.

Resumable: ``scene.json`` is written first and records a digest of every parameter and of the
synth code; a later call with the same digest renders only the views whose image or depth map
is missing. Every file is written to a temporary name and renamed, so an interruption never
leaves a half-written file behind.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core.atomic import publish_dir
from polarref.core.errors import PolarrefError
from synth import meshes
from synth.config import SceneConfig, preset
from synth.conventions import mitsuba_to_world, pinhole_params
from synth.scene import SCENE_JSON, PinholeCamera, atomic_write_bytes, write_gt

log = logging.getLogger(__name__)

_CODE_FILES = ("config.py", "conventions.py", "noise.py", "meshes.py", "comet.py", "uav.py", "render.py")
_KNOWN_ENTRIES = {SCENE_JSON, "mesh.ply", "gt", "images", "depth"}
WHITE_ALBEDO = 0.55  # brightest albedo; with the sun at normal incidence it maps to ~95% white


def code_version() -> str:
    """Short hash of the synth sources that decide the rendered pixels and geometry."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in _CODE_FILES:
        path = here / name
        if path.exists():
            h.update(path.read_bytes())
    return h.hexdigest()[:10]


@dataclass(frozen=True)
class SceneResult:
    """Outcome of :func:`render_scene`."""

    root: Path
    rendered: int  # views rendered by this call
    skipped: int  # views already complete on disk
    seconds: float  # wall time spent rendering views (excludes scene building)
    total_seconds: float  # wall time of the whole call
    variant: str | None  # Mitsuba variant used (None if nothing had to be rendered)

    @property
    def images_per_s(self) -> float:
        return self.rendered / self.seconds if self.seconds > 0 else float("nan")


def view_names(n: int) -> list[str]:
    return [f"{i:04d}.png" for i in range(n)]


def _is_complete(root: Path, n: int) -> bool:
    names = view_names(n)
    return (root / "mesh.ply").is_file() and (root / "gt" / "images.txt").is_file() and all(
        (root / "images" / nm).is_file() and (root / "depth" / (nm[:-4] + ".npy")).is_file() for nm in names)


def _prepare_out(out: Path, digest: str, overwrite: bool) -> bool:
    """Check/create ``out``; return True when it already holds this very scene."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".write-test.{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise PolarrefError(f"output folder {out} is not writable: {exc.strerror or exc}") from exc
    meta_path = out / SCENE_JSON
    if meta_path.is_file():
        try:
            old = json.loads(meta_path.read_text()).get("digest")
        except (OSError, ValueError):
            old = None
        if old == digest:
            return True
        if not overwrite:
            raise PolarrefError(f"{out} holds a scene rendered with other parameters or code "
                                f"(digest {old} != {digest}); choose another output folder or replace it",
                                option="overwrite")
        return False
    foreign = sorted(p.name for p in out.iterdir() if not p.name.startswith(".") and p.name not in _KNOWN_ENTRIES)
    if foreign and not overwrite:
        raise PolarrefError(f"{out} is not empty and is not a rendered scene (found {foreign[0]!r}); "
                            f"choose a new folder or replace it", option="overwrite")
    return False


def build_geometry(cfg: SceneConfig):
    """Shape, albedo, poses and lights for ``cfg`` (no Mitsuba involved)."""
    if cfg.scene == "comet":
        from synth import comet

        return comet.build(cfg)
    from synth import uav

    return uav.build(cfg)


def _versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for pkg in ("numpy", "mitsuba", "drjit", "polarref"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = "unknown"
    return out


def _scene_json(cfg: SceneConfig, digest: str, geo, camera: PinholeCamera, variant, names) -> dict:
    views = []
    for i, (name, pose) in enumerate(zip(names, geo.poses), start=1):
        views.append({"image_id": i, "name": name, "qvec": pose.quat.tolist(), "tvec": pose.t.tolist(),
                      "R": pose.R.tolist(), "center": pose.center.tolist()})
    return {
        "format": "polarref-synth-scene/1",
        "digest": digest,
        "code_version": code_version(),
        "config": dataclasses.asdict(cfg),
        "mitsuba_variant": variant.variant,
        "mitsuba_variant_reason": variant.reason,
        "versions": _versions(),
        "units": "metres (world), pixels (images)",
        "conventions": {
            "pose": "cam_from_world, X_cam = R X_world + t; camera +x right, +y down, +z forward (COLMAP)",
            "pixels": "COLMAP: origin at the top-left corner of the first pixel; centre of (0,0) is (0.5,0.5)",
            "depth": "depth/NNNN.npy float32 (H, W): z-depth along +z of the surface through each pixel "
                     "centre, 0 = no surface",
            "points3D": "gt/points3D.txt is empty; the surface is mesh.ply",
            "lights": "directional; direction = direction of travel of the light",
        },
        "camera": {"model": "PINHOLE", "width": camera.width, "height": camera.height,
                   "params": camera.params.tolist(), "fov_x_deg": cfg.fov_deg},
        "scale": {"center": np.asarray(geo.center).tolist(), "radius": geo.radius},
        "texture_cell_m": geo.texture_cell,
        "lights": [{"direction": np.asarray(d).tolist(), "irradiance": e} for d, e in geo.lights],
        "geometry": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in geo.info.items()},
        "views": views,
        "priors": _priors(cfg, geo),
    }


def _priors(cfg: SceneConfig, geo) -> dict | None:
    # synth/priors.py is not in _CODE_FILES: the priors never decide pixels, and scene.json is
    # rewritten (priors included) whenever a render resumes.
    from synth.priors import draw_priors

    return draw_priors(cfg, geo.poses, geo.center)


def _mitsuba_scene(mi, geo, camera: PinholeCamera, near: float, far: float, cfg: SceneConfig):
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse",
                                  "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}})
    mesh = mi.Mesh("surface", len(geo.vertices), len(geo.faces), props=props)
    params = mi.traverse(mesh)
    # The buffer types differ between variants (JIT arrays vs. scalar dynamic arrays).
    float_buf, index_buf = type(params["vertex_positions"]), type(params["faces"])
    params["vertex_positions"] = float_buf(geo.vertices.astype(np.float32).ravel())
    params["faces"] = index_buf(geo.faces.astype(np.uint32).ravel())
    params.update()
    mesh.add_attribute("vertex_color", 3, float_buf(np.repeat(geo.albedo.astype(np.float32), 3)))
    # One scene per light, summed afterwards: the direct integrator picks one emitter per sample
    # at random, which with two lights of unequal power leaves heavy per-pixel noise.
    scenes = []
    for direction, irradiance in geo.lights:
        light = {"type": "directional", "direction": np.asarray(direction).tolist(),
                 "irradiance": {"type": "rgb", "value": float(irradiance)}}
        scenes.append(mi.load_dict({"type": "scene", "integrator": {"type": "direct"},
                                    "surface": mesh, "light": light}))

    def sensor(depth: bool):
        # Box filter: each pixel averages its own square only. That is a proper area
        # anti-aliasing and, unlike overlapping filters, keeps LLVM renders bitwise repeatable.
        film = {"type": "hdrfilm", "width": camera.width, "height": camera.height,
                "rfilter": {"type": "box"}, "pixel_format": "rgb"}
        # Depth: one un-jittered stratified sample sits exactly at the pixel centre.
        sampler = ({"type": "stratified", "sample_count": 1, "jitter": False} if depth
                   else {"type": "independent", "sample_count": cfg.spp})
        return mi.load_dict({"type": "perspective", "fov": cfg.fov_deg, "fov_axis": "x",
                             "near_clip": near, "far_clip": far, "film": film, "sampler": sampler})

    aov = mi.load_dict({"type": "aov", "aovs": "pos:position,dd:depth"})
    return scenes, sensor(False), sensor(True), aov


def _srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def _encode_png(rgb8: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb8[:, :, ::-1]))
    if not ok:
        raise PolarrefError("PNG encoding failed")
    return buf.tobytes()


def _encode_npy(a: np.ndarray) -> bytes:
    import io

    bio = io.BytesIO()
    np.save(bio, a)
    return bio.getvalue()


def write_scene_files(out: Path, meta: dict, geo, camera: PinholeCamera, names: list[str]) -> None:
    """Everything of a scene folder but the views: scene.json, mesh.ply, the GT model, and the
    empty images/ and depth/ folders."""
    atomic_write_bytes(out / SCENE_JSON, (json.dumps(meta, indent=1) + "\n").encode())
    meshes.write_ply(out / "mesh.ply", geo.vertices, geo.faces,
                     np.repeat(np.round(geo.albedo * 255).astype(np.uint8)[:, None], 3, 1))
    write_gt(out, camera, names, geo.poses)
    (out / "images").mkdir(exist_ok=True)
    (out / "depth").mkdir(exist_ok=True)


def _render_views(out: Path, scene: str, cfg: SceneConfig, digest: str, geo, camera, executor, variant,
                  names: list[str], overwrite: bool) -> tuple[list[int], float]:
    """Write scene.json, mesh, GT and every missing view into ``out``; (rendered views, start time).

    One task per view through ``executor`` (polarref.core.execution): in this process, or on Dask workers
    that each build the Mitsuba scene once.
    """
    write_scene_files(out, _scene_json(cfg, digest, geo, camera, variant, names), geo, camera, names)

    todo = [i for i, nm in enumerate(names) if overwrite or not (
        (out / "images" / nm).is_file() and (out / "depth" / (nm[:-4] + ".npy")).is_file())]
    t0 = time.perf_counter()
    if executor.in_process:
        _view_renderer(cfg, geo)  # reuse the geometry built above
    try:
        executor.map(render_view, [ViewTask(str(out), cfg, i, variant.variant) for i in todo],
                     desc=f"render {scene}")
    finally:
        if executor.in_process:
            _RENDERERS.clear()  # free the Mitsuba scene as before; workers keep theirs for the next task
    return todo, t0


def render_scene(scene: str, out: str | os.PathLike, config: SceneConfig | None = None, *,
                 overwrite: bool = False) -> SceneResult:
    """Render ``scene`` into folder ``out`` (resumable; see the module docstring).

    Args:
        scene: "comet" or "uav".
        out: output folder (created).
        config: scene configuration; default: ``preset(scene, "default")``.
        overwrite: re-render every view and replace a folder holding other parameters.
    Raises:
        PolarrefError: bad configuration, unwritable folder, foreign folder content, bad mesh.
    """
    t_start = time.perf_counter()
    cfg = config or preset(scene)
    if cfg.scene != scene:
        raise PolarrefError(f"config is for scene {cfg.scene!r}, not {scene!r}")
    try:
        cfg.validate()
    except ValueError as exc:
        raise PolarrefError(str(exc)) from exc
    if cfg.mesh is not None:
        cfg = dataclasses.replace(cfg, mesh=str(Path(cfg.mesh).expanduser().resolve()))
    out = Path(out)
    digest = cfg.digest(code_version())
    created = not out.exists()
    try:
        return _render(scene, out, cfg, digest, overwrite, t_start)
    except BaseException:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a failed run leaves no empty folder behind
        raise


def _render(scene: str, out: Path, cfg: SceneConfig, digest: str, overwrite: bool,
            t_start: float) -> SceneResult:
    same = _prepare_out(out, digest, overwrite)
    names = view_names(cfg.views)
    if same and not overwrite and _is_complete(out, cfg.views):
        return SceneResult(out, 0, cfg.views, 0.0, time.perf_counter() - t_start, None)

    from polarref.core import execution
    from synth.mitsuba_variant import load_mitsuba, selected_variant

    geo = build_geometry(cfg)
    camera = PinholeCamera(cfg.width, cfg.height, pinhole_params(cfg.width, cfg.height, cfg.fov_deg))
    executor = execution.current()
    if executor.in_process:
        _, variant = load_mitsuba()
    else:  # the workers load Mitsuba; they must pick this very variant (checked per task)
        variant = selected_variant()
    # Replacing a folder: render into a hidden sibling and swap it in whole at the end, so no
    # image or depth map of the old scene (more views, other size) survives beside the new ones.
    replacing = overwrite and any(out.iterdir())
    staging = (publish_dir(out, overwrite=True, owned=tuple(_KNOWN_ENTRIES)) if replacing
               else contextlib.nullcontext(out))
    with staging as root:
        todo, t0 = _render_views(root, scene, cfg, digest, geo, camera, executor, variant, names,
                                 overwrite)
    seconds = time.perf_counter() - t0
    log.info("rendered %d views in %.1f s (%s)", len(todo), seconds, variant.variant)
    return SceneResult(out, len(todo), cfg.views - len(todo), seconds, time.perf_counter() - t_start,
                       variant.variant)


# ---- one view: the task unit of polarref.core.execution ---------------------------------------------
@dataclass(frozen=True)
class ViewTask:
    """Render view ``index`` of the scene ``config`` into folder ``out`` (scene.json already there)."""

    out: str
    config: SceneConfig
    index: int
    variant: str  # Mitsuba variant recorded in scene.json; a worker using another one refuses


@dataclass(frozen=True)
class ViewDone:
    index: int
    seconds: float
    pid: int  # process that rendered it (tests and logs: which worker did the work)


class _ViewRenderer:
    """The Mitsuba scene of one configuration, built once per process and reused per view."""

    def __init__(self, cfg: SceneConfig, geo=None):
        from synth.mitsuba_variant import load_mitsuba

        from polarref.core import execution

        geo = geo if geo is not None else build_geometry(cfg)
        self.cfg, self.poses = cfg, geo.poses
        camera = PinholeCamera(cfg.width, cfg.height, pinhole_params(cfg.width, cfg.height, cfg.fov_deg))
        self.mi, variant = load_mitsuba()
        self.variant = variant.variant
        if execution.on_worker():  # one core per worker process
            import drjit

            drjit.set_thread_count(1)
        dists = np.array([np.linalg.norm(p.center - geo.center) for p in geo.poses])
        near = max(1e-3 * geo.radius, 0.5 * float((dists - geo.radius).min()))
        far = 4.0 * float(dists.max() + geo.radius)
        self.scenes, self.rgb_sensor, self.depth_sensor, self.aov = _mitsuba_scene(
            self.mi, geo, camera, near, far, cfg)
        self.exposure = np.pi * 0.95 / (WHITE_ALBEDO * max(irr for _, irr in geo.lights))
        self.params = (self.mi.traverse(self.rgb_sensor), self.mi.traverse(self.depth_sensor))

    def render(self, i: int, out: Path) -> None:
        mi, pose, cfg = self.mi, self.poses[i], self.cfg
        to_world = mi.ScalarTransform4f(mitsuba_to_world(pose).tolist())
        for params in self.params:
            params["to_world"] = to_world
            params.update()
        aovs = np.array(mi.render(self.scenes[0], sensor=self.depth_sensor, integrator=self.aov, seed=0, spp=1))
        pos, hit = aovs[..., :3].astype(np.float64), aovs[..., 3] > 0
        depth = np.where(hit, pos @ pose.R[2] + pose.t[2], 0.0).astype(np.float32)
        img = sum(np.array(mi.render(sc, sensor=self.rgb_sensor, seed=cfg.seed * 100003 + i, spp=cfg.spp))
                  for sc in self.scenes)
        stem = view_names(cfg.views)[i][:-4]
        atomic_write_bytes(out / "depth" / f"{stem}.npy", _encode_npy(depth))
        atomic_write_bytes(out / "images" / f"{stem}.png", _encode_png(_srgb8(img[..., :3] * self.exposure)))


_RENDERERS: dict[str, _ViewRenderer] = {}


def _view_renderer(cfg: SceneConfig, geo=None) -> _ViewRenderer:
    key = cfg.digest(code_version())
    if key not in _RENDERERS:
        _RENDERERS.clear()  # one scene per process is enough; a new one frees the old one
        _RENDERERS[key] = _ViewRenderer(cfg, geo)
    return _RENDERERS[key]


def render_view(task: ViewTask) -> ViewDone:
    """Render one view (a task; the process-wide scene cache makes later views cheap)."""
    t0 = time.perf_counter()
    renderer = _view_renderer(task.config)
    if renderer.variant != task.variant:
        raise PolarrefError(f"this process renders with Mitsuba variant {renderer.variant}, but the scene was "
                            f"started with {task.variant}; give every worker the same Mitsuba/LLVM set-up")
    renderer.render(task.index, Path(task.out))
    return ViewDone(task.index, time.perf_counter() - t0, os.getpid())
