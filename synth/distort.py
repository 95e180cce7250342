"""Known radial lens distortion for rendered scenes (COLMAP ``RADIAL``: f, cx, cy, k1, k2).

Mitsuba renders a pinhole image. A distorted view is made from an undistorted render on a
larger canvas with the same focal length, resampled at the undistorted position of every
distorted pixel centre (bilinear, on linear radiance before sRGB encoding). The depth map is
not resampled: the undistorted ray through every distorted pixel centre is cast against the
mesh, so depth/ stays the exact z-depth through each pixel centre of the distorted image.

Distortion: ``x_d = x_u (1 + k1 r^2 + k2 r^4)``, ``r = |x_u|`` on normalized coordinates.
"""

from __future__ import annotations

import math

import numpy as np


def distort(xu: np.ndarray, yu: np.ndarray, k1: float, k2: float) -> tuple[np.ndarray, np.ndarray]:
    r2 = xu * xu + yu * yu
    s = 1.0 + r2 * (k1 + k2 * r2)
    return xu * s, yu * s


def undistort(xd: np.ndarray, yd: np.ndarray, k1: float, k2: float,
              iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`distort` by Newton's method on the radius (monotone range only)."""
    rd = np.hypot(xd, yd)
    ru = rd.copy()
    for _ in range(iterations):
        r2 = ru * ru
        g = ru * (1.0 + r2 * (k1 + k2 * r2)) - rd
        dg = 1.0 + r2 * (3.0 * k1 + 5.0 * k2 * r2)
        ru = ru - g / dg
    scale = np.where(rd > 0, ru / np.where(rd > 0, rd, 1.0), 1.0)
    return xd * scale, yd * scale


def check_monotone(width: int, height: int, f: float, k1: float, k2: float) -> None:
    """ValueError unless the distortion is monotone out to the image corners."""
    r_corner = math.hypot(width, height) / (2.0 * f) * 1.5  # undistorted radius can exceed rd
    r = np.linspace(0.0, r_corner, 2001)
    d = 1.0 + r * r * (3.0 * k1 + 5.0 * k2 * r * r)
    if (d <= 0).any():
        raise ValueError(f"distortion k1={k1}, k2={k2} folds inside the image (not monotone)")


def pixel_rays(width: int, height: int, f: float, k1: float, k2: float) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates (H, W) of every distorted pixel centre."""
    u = (np.arange(width) + 0.5 - 0.5 * width) / f
    v = (np.arange(height) + 0.5 - 0.5 * height) / f
    xd, yd = np.meshgrid(u, v)
    return undistort(xd, yd, k1, k2)


def canvas(width: int, height: int, f: float, k1: float, k2: float) -> tuple[int, int]:
    """(width, height) of the undistorted render that covers every distorted pixel (+2 px)."""
    xu, yu = pixel_rays(width, height, f, k1, k2)
    wb = 2 * math.ceil(max(float(np.abs(xu).max()) * f + 2.0, 0.5 * width))
    hb = 2 * math.ceil(max(float(np.abs(yu).max()) * f + 2.0, 0.5 * height))
    return wb, hb


def resample(big: np.ndarray, width: int, height: int, f: float, k1: float, k2: float) -> np.ndarray:
    """The distorted (H, W, C) image from an undistorted render ``big`` (Hb, Wb, C) with the
    same focal length and its principal point at its centre."""
    import cv2

    hb, wb = big.shape[:2]
    xu, yu = pixel_rays(width, height, f, k1, k2)
    # source position in big's pixel indices (pixel centre of index i at i + 0.5)
    mx = (xu * f + 0.5 * wb - 0.5).astype(np.float32)
    my = (yu * f + 0.5 * hb - 0.5).astype(np.float32)
    return cv2.remap(np.ascontiguousarray(big, np.float32), mx, my, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def exact_depth(mi, scene, pose, width: int, height: int, f: float, k1: float,
                k2: float) -> np.ndarray:
    """float32 (H, W) z-depth of the surface through each distorted pixel centre (0: miss),
    by casting the undistorted rays against the Mitsuba scene."""
    xu, yu = pixel_rays(width, height, f, k1, k2)
    d_cam = np.stack([xu.ravel(), yu.ravel(), np.ones(xu.size)], 1)
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    d_world = d_cam @ pose.R  # R^T d per row
    o = np.broadcast_to(pose.center, d_world.shape)
    ray = mi.Ray3f(mi.Point3f(*[np.ascontiguousarray(o[:, i], np.float32) for i in range(3)]),
                   mi.Vector3f(*[np.ascontiguousarray(d_world[:, i], np.float32) for i in range(3)]))
    si = scene.ray_intersect(ray)
    t = np.array(si.t, dtype=np.float64)
    hit = np.isfinite(t) & np.array(si.is_valid(), dtype=bool)
    depth = np.where(hit, np.where(hit, t, 0.0) * d_cam[:, 2], 0.0)
    return depth.reshape(height, width).astype(np.float32)


def _digest(cfg, k1: float, k2: float) -> str:
    import hashlib
    from pathlib import Path

    from synth.render import code_version

    mine = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:10]
    return cfg.digest(f"{code_version()}+distort-{mine}-k1={k1!r}-k2={k2!r}")


def render_distorted_scene(scene: str, out, config, k1: float, k2: float = 0.0, *,
                           overwrite: bool = False):
    """:func:`synth.render.render_scene` with radial distortion (k1, k2) applied to every view.

    gt/ and scene.json carry the exact ``RADIAL`` camera ``(f, cx, cy, k1, k2)``; depth/ holds the
    exact z-depth through each distorted pixel centre (see the module docstring).
    Returns a :class:`synth.render.SceneResult`.
    """
    import dataclasses
    import time
    from pathlib import Path

    from polarref.core import progress
    from polarref.core.errors import PolarrefError
    from synth.conventions import mitsuba_to_world, pinhole_params
    from synth.mitsuba_variant import load_mitsuba
    from synth.render import (WHITE_ALBEDO, SceneResult, _encode_npy, _encode_png, _is_complete,
                              _mitsuba_scene, _prepare_out, _scene_json, _srgb8, build_geometry,
                              view_names, write_scene_files)
    from synth.scene import PinholeCamera, atomic_write_bytes

    t_start = time.perf_counter()
    cfg = config
    try:
        cfg.validate()
        f = float(pinhole_params(cfg.width, cfg.height, cfg.fov_deg)[0])
        check_monotone(cfg.width, cfg.height, f, k1, k2)
    except ValueError as exc:
        raise PolarrefError(str(exc)) from exc
    out = Path(out)
    digest = _digest(cfg, k1, k2)
    same = _prepare_out(out, digest, overwrite)
    names = view_names(cfg.views)
    if same and not overwrite and _is_complete(out, cfg.views):
        return SceneResult(out, 0, cfg.views, 0.0, time.perf_counter() - t_start, None)
    geo = build_geometry(cfg)
    W, H = cfg.width, cfg.height
    camera = PinholeCamera(W, H, np.array([f, 0.5 * W, 0.5 * H, k1, k2]), model="RADIAL")
    wb, hb = canvas(W, H, f, k1, k2)
    big_cfg = dataclasses.replace(cfg, width=wb, height=hb,
                                  fov_deg=math.degrees(2.0 * math.atan(0.5 * wb / f)))
    big = PinholeCamera(wb, hb, pinhole_params(wb, hb, big_cfg.fov_deg))
    mi, variant = load_mitsuba()
    meta = _scene_json(cfg, digest, geo, camera, variant, names)
    meta["camera"] = {"model": "RADIAL", "width": W, "height": H, "params": camera.params.tolist(),
                      "fov_x_deg": cfg.fov_deg, "distortion": {"k1": k1, "k2": k2},
                      "render": f"undistorted {wb}x{hb} render resampled (synth/distort.py)"}
    write_scene_files(out, meta, geo, camera, names)
    dists = np.array([np.linalg.norm(p.center - geo.center) for p in geo.poses])
    near = max(1e-3 * geo.radius, 0.5 * float((dists - geo.radius).min()))
    far = 4.0 * float(dists.max() + geo.radius)
    scenes, rgb_sensor, _, _ = _mitsuba_scene(mi, geo, big, near, far, big_cfg)
    exposure = np.pi * 0.95 / (WHITE_ALBEDO * max(irr for _, irr in geo.lights))
    rgb_params = mi.traverse(rgb_sensor)
    t0 = time.perf_counter()
    for i in progress.track(range(cfg.views), desc=f"render {scene} (distorted)", total=cfg.views):
        pose = geo.poses[i]
        rgb_params["to_world"] = mi.ScalarTransform4f(mitsuba_to_world(pose).tolist())
        rgb_params.update()
        img = sum(np.array(mi.render(sc, sensor=rgb_sensor, seed=cfg.seed * 100003 + i, spp=cfg.spp))
                  for sc in scenes)
        img = resample(img[..., :3], W, H, f, k1, k2)
        depth = exact_depth(mi, scenes[0], pose, W, H, f, k1, k2)
        stem = names[i][:-4]
        atomic_write_bytes(out / "depth" / f"{stem}.npy", _encode_npy(depth))
        atomic_write_bytes(out / "images" / names[i], _encode_png(_srgb8(img * exposure)))
    seconds = time.perf_counter() - t0
    return SceneResult(out, cfg.views, 0, seconds, time.perf_counter() - t_start, variant.variant)
