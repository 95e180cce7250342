"""Tiny analytic scenes for the dense tests: a textured plane or sphere seen by pinhole cameras.

Images are rendered exactly (ray-surface intersection per sub-pixel, 3x3 supersampling) with a
procedural 3D texture (a sum of random plane waves), so depth maps have an exact ground truth.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from polarref.core.geometry import Rigid3
from synth.conventions import look_at


class Plane:
    def __init__(self, normal, offset):
        self.n = np.asarray(normal, float) / np.linalg.norm(normal)
        self.d = float(offset)           # n . X = d

    def hit(self, o, rays):
        den = rays @ self.n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.d - o @ self.n) / den
        return np.where((t > 0) & np.isfinite(t), t, np.inf)

    def mesh(self, half: float):
        u = np.cross(self.n, [1.0, 0, 0] if abs(self.n[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(self.n, u)
        c = self.n * self.d
        g = np.linspace(-half, half, 41)
        a, b = np.meshgrid(g, g)
        V = c + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
        i = np.arange(40)[:, None] * 41 + np.arange(40)[None, :]
        i = i.ravel()
        F = np.concatenate([np.stack([i, i + 1, i + 42], 1), np.stack([i, i + 42, i + 41], 1)])
        return V, F


class Sphere:
    def __init__(self, center, radius):
        self.c = np.asarray(center, float)
        self.r = float(radius)

    def hit(self, o, rays):
        oc = o - self.c
        b = rays @ oc
        disc = b * b - (oc @ oc - self.r**2) * (rays * rays).sum(-1)
        a = (rays * rays).sum(-1)
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(disc)) / a
        return np.where((disc > 0) & (t > 0), t, np.inf)

    def mesh(self, level: int = 5):
        from synth.meshes import icosphere

        V, F = icosphere(level)
        return self.c + self.r * V, F


def texture(X: np.ndarray, wavelength: float, seed: int = 0, waves: int = 24) -> np.ndarray:
    """Grey value in [0.1, 0.9] of a sum of random 3D plane waves; wavelengths 1-3x ``wavelength``."""
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(waves, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    k = dirs * (2 * np.pi / (wavelength * rng.uniform(1, 3, waves)))[:, None]
    phase = rng.uniform(0, 2 * np.pi, waves)
    s = np.cos(X @ k.T + phase).sum(-1) / np.sqrt(waves / 2)
    return 0.5 + 0.4 * np.tanh(s / 1.5)


def render(surface, pose: Rigid3, K: np.ndarray, w: int, h: int, wavelength: float, ss: int = 3):
    """(grey uint8 (h, w), z-depth float32 (h, w), 0 where the ray misses) of ``surface``."""
    o = pose.center
    off = (np.arange(ss) + 0.5) / ss
    u = (np.arange(w)[:, None] + off[None, :]).ravel()
    v = (np.arange(h)[:, None] + off[None, :]).ravel()
    uu, vv = np.meshgrid(u, v)
    rays_c = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], -1)
    rays = rays_c @ pose.R  # world directions (z-component of the camera ray is 1)
    t = surface.hit(o, rays)
    X = o + rays * np.where(np.isfinite(t), t, 0)[..., None]
    val = np.where(np.isfinite(t), texture(X, wavelength), 0.0).reshape(h, ss, w, ss).mean((1, 3))
    # Depth at pixel centres: the exact z of the centre ray (t along a unit-z ray is z).
    uc, vc = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rc = np.stack([(uc - K[0, 2]) / K[0, 0], (vc - K[1, 2]) / K[1, 1], np.ones_like(uc)], -1) @ pose.R
    tc = surface.hit(o, rc)
    depth = np.where(np.isfinite(tc), tc, 0.0).astype(np.float32)
    return np.clip(np.round(val * 255), 0, 255).astype(np.uint8), depth


def orbit(target, distance: float, n: int, step_deg: float, elevation_deg: float = 15.0) -> list[Rigid3]:
    target = np.asarray(target, float)
    poses = []
    for i in range(n):
        a = np.radians((i - (n - 1) / 2) * step_deg)
        e = np.radians(elevation_deg * (1 if i % 2 else 0.5))
        c = target + distance * np.array([np.sin(a) * np.cos(e), -np.sin(e), -np.cos(a) * np.cos(e)])
        poses.append(look_at(c, target, np.array([0.0, -1.0, 0.0])))
    return poses


def write_scene(root: Path, surface, poses: list[Rigid3], w: int, h: int, fov_deg: float,
                wavelength: float, bounds: tuple, mesh_args=(), blank: bool = False) -> np.ndarray:
    """A scene folder ``load_scene`` reads (images/, depth/, gt/, mesh.ply, scene.json); returns K."""
    from polarref.camera import Camera
    from polarref.model import Image, Reconstruction
    from synth.meshes import write_ply

    f = 0.5 * w / np.tan(np.radians(fov_deg) / 2)
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    for sub in ("images", "depth"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    cam = Camera("PINHOLE", w, h, np.array([f, f, w / 2, h / 2]))
    rec = Reconstruction(cameras={1: cam})
    views = []
    for i, pose in enumerate(poses):
        name = f"{i:04d}.png"
        img, depth = render(surface, pose, K, w, h, wavelength)
        if blank:
            img[:] = 128
        cv2.imwrite(str(root / "images" / name), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
        np.save(root / "depth" / f"{i:04d}.npy", depth)
        rec.images[i + 1] = Image(i + 1, name, 1, pose)
        views.append({"image_id": i + 1, "name": name, "R": pose.R.tolist(), "tvec": pose.t.tolist()})
    rec.write_text(root / "gt")
    V, F = surface.mesh(*mesh_args)
    write_ply(root / "mesh.ply", V, F)
    meta = {"camera": {"width": w, "height": h, "params": [f, f, w / 2, h / 2]}, "views": views,
            "scale": {"center": list(map(float, bounds[0])), "radius": float(bounds[1])}}
    (root / "scene.json").write_text(json.dumps(meta))
    return K
