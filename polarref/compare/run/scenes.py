"""Resolve ``polarref compare``'s SCENE|DIR argument into images, fixed camera and ground truth.

* ``comet`` / ``uav`` (or nothing): a synthetic scene rendered by ``synth`` into the cache
  (``polarref.core.data.cache_root()/scenes/...``) and reused on later runs.
* a rendered scene folder (``scene.json``, ``images/``, ``gt/``, ``mesh.ply``).
* a real image set with ground truth: Strecha ``*.camera`` files (``gt_dense_cameras/``) or a
  COLMAP model in ``gt/``. Large images are downscaled by an integer factor (INTER_AREA) into
  the cache; with COLMAP's corner pixel origin the intrinsics scale exactly by 1/factor.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

from polarref.compare.run.presets import ComparePreset
from polarref.core.atomic import atomic_write
from polarref.core.data import cache_root
from polarref.core.errors import PolarrefError
from polarref.io.scene_folder import IMAGE_SUFFIXES, Scene, discover
from polarref.model.colmap import read_model

log = logging.getLogger(__name__)

SYNTHETIC = ("comet", "uav")


def synthetic_root(scene: str, preset: str, seed: int) -> Path:
    """Cache folder of a synthetic scene, keyed by its digest (``polarref render --out`` this
    folder renders exactly what ``polarref compare`` will use)."""
    from synth.config import preset as scene_preset
    from synth.render import code_version

    cfg = scene_preset(scene, preset, seed=seed)
    return cache_root() / "scenes" / f"{scene}-{preset}-seed{seed}-{cfg.digest(code_version())}"


def _synthetic(scene: str, preset: str, seed: int, name: str | None = None) -> Scene:
    """Render (or reuse) a synthetic scene in the cache; the folder is keyed by the scene digest."""
    try:
        from synth.config import preset as scene_preset
        from synth.render import render_scene
        from synth.scene import load_scene
    except ImportError as exc:
        raise PolarrefError(f"cannot render the {scene} scene: synth is not available ({exc})") from exc
    cfg = scene_preset(scene, preset, seed=seed)
    root = synthetic_root(scene, preset, seed)
    result = render_scene(scene, root, cfg)
    if result.rendered:
        log.info("rendered %d views of %s into %s in %.1f s", result.rendered, scene, root, result.total_seconds)
    loaded = load_scene(root)
    render_s = result.total_seconds if result.rendered else 0.0
    return _from_rendered(loaded, name or f"{scene}-{preset}", scene, preset, seed, render_s)


def _from_rendered(loaded, name: str, source: str, preset: str, seed: int, render_s: float) -> Scene:
    from polarref.model import Reconstruction

    gt = read_model(loaded.gt_dir) if loaded.gt_dir.is_dir() else None
    return Scene(
        root=loaded.root, image_dir=loaded.root / "images", image_names=[v.name for v in loaded.views],
        gt_kind="colmap" if gt is not None else "", rendered=True,
        mesh_path=loaded.mesh_path if loaded.mesh_path.is_file() else None,
        name=name, kind="synthetic", source=source, camera=loaded.polarref_camera(), gt=gt,
        preset=preset, seed=seed, render_s=render_s, mitsuba_variant=str(loaded.meta.get("mitsuba_variant", "")))


def _downscale_factor(width: int, height: int, max_width: int) -> int:
    """Smallest integer factor >= width / max_width that divides both sides (exact intrinsics)."""
    f = max(1, math.ceil(width / max_width))
    for k in range(f, 33):
        if width % k == 0 and height % k == 0:
            return k
    raise PolarrefError(f"cannot downscale {width}x{height} images exactly to <= {max_width} px wide "
                        "(no common integer factor <= 32); a larger preset keeps larger images", option="preset")


def _downscale(src_dir: Path, names: list[str], factor: int, dst_dir: Path) -> None:
    import cv2

    dst_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        out = dst_dir / (Path(name).stem + ".png")
        if out.is_file():
            continue
        img = cv2.imread(str(src_dir / name), cv2.IMREAD_COLOR)
        if img is None:
            raise PolarrefError(f"cannot read image {src_dir / name}")
        h, w = img.shape[:2]
        small = cv2.resize(img, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
        ok, png = cv2.imencode(".png", small)
        if not ok:
            raise PolarrefError(f"cannot encode {out} as PNG")
        atomic_write(out, png.tobytes())


def _real(folder: Path, source: str, preset: ComparePreset) -> Scene:
    from polarref.model import Image, Reconstruction

    found = discover(folder)
    image_dir, names = found.image_dir, found.image_names
    if not names:
        raise PolarrefError(f"no images (*{', *'.join(IMAGE_SUFFIXES)}) in {image_dir}")
    gt = found.read_ground_truth()
    if gt is None:
        raise PolarrefError(f"{folder} has images but no ground truth (gt/ COLMAP model or "
                            "gt_dense_cameras/*.camera); polarref compare needs the intrinsics")
    cam = next(iter(gt.cameras.values()))
    factor = _downscale_factor(int(cam.width), int(cam.height), preset.max_width)
    used_dir, used_names = image_dir, names
    if factor > 1:
        used_dir = cache_root() / "compare-inputs" / f"{folder.name}-x{factor}"
        _downscale(image_dir, names, factor, used_dir)
        used_names = [Path(n).stem + ".png" for n in names]
    fixed = cam.rescaled(1.0 / factor)  # exact with corner origin; distortion terms unchanged
    # Ground truth keyed by the names the methods will see; poses do not change with scale.
    gt_used = Reconstruction(cameras=dict(gt.cameras))
    for (image_id, im), new_name in zip(sorted(gt.images.items()), used_names if factor > 1 else names):
        gt_used.images[image_id] = Image(image_id, new_name, im.camera_id, im.cam_from_world)
    # a real folder's mesh (if any) is not in the GT frame the methods are scored in: none
    return dataclasses.replace(found, image_dir=used_dir, image_names=used_names, mesh_path=None, name=folder.name,
                               kind="real", source=source, camera=fixed, gt=gt_used, preset=preset.name, seed=-1,
                               downscale=float(factor))


def prepare(arg: str | None, preset: ComparePreset, seed: int) -> Scene:
    """Resolve SCENE|DIR (None = the default comet scene); ``preset`` sizes a synthetic scene
    and downscales real images (a twin or a rendered folder decides its own size)."""
    if arg is None or arg in SYNTHETIC:
        return _synthetic(arg or "comet", preset.name, seed)
    from synth.config import TWINS

    if arg in TWINS:  # the twin decides views, size and orbit; --preset does not apply
        return _synthetic(TWINS[arg], arg, seed, name=arg)
    path = Path(arg).expanduser()
    if not path.exists():
        raise PolarrefError(f"unknown scene {arg!r}: not a scene ({', '.join(SYNTHETIC)}), not a twin "
                            f"({', '.join(TWINS)}) and no such directory")
    if not path.is_dir():
        raise PolarrefError(f"{arg} is not a directory (give a scene name or an image folder)")
    if (path / "scene.json").is_file():
        from synth.scene import load_scene

        loaded = load_scene(path)
        meta = loaded.meta
        return _from_rendered(loaded, path.name, str(arg), str(meta.get("preset", "")),
                              int(meta.get("seed", meta.get("config", {}).get("seed", -1)) or 0), 0.0)
    return _real(path, str(arg), preset)
