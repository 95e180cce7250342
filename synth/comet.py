"""Comet scene: a bilobed procedural body (or a shape model) and a photographic orbit.

The procedural body is star-shaped about the origin: its radius in direction ``u`` is a smooth
maximum of the exit distances of two ellipsoid lobes that both contain the origin (the neck),
times low-frequency relief. Star-shapedness lets an icosphere be displaced radially without
folds, so the mesh stays manifold and the vertex spacing stays close to uniform.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from polarref.core.angular import direction_from_azimuth_elevation
from polarref.core.geometry import Rigid3, so3_exp
from synth import meshes
from synth.config import SceneConfig
from synth.conventions import look_at, pinhole_params
from synth.noise import ValueNoise3, albedo_from_noise

MAX_ICO_LEVEL = 8  # 655k vertices; finer textures need a shape model or a larger cell
MAX_FACES = 3_000_000  # cap for subdividing a user shape model
ALBEDO_GAIN = 1.0  # equal amplitude per octave: the finest (~4 px) octave is as strong as the coarse ones


@dataclass(frozen=True)
class Geometry:
    """What the renderer needs and what the ground truth records.

    vertices (V, 3) float64, faces (F, 3) int64, albedo (V,) in [0, 1],
    poses: COLMAP cam_from_world per view; lights: (direction of travel (3,), irradiance).
    """

    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray
    poses: list[Rigid3]
    lights: list[tuple[np.ndarray, float]]
    center: np.ndarray  # (3,) centre of the bounding sphere used for framing
    radius: float  # bounding-sphere radius (scene scale), world units
    texture_cell: float  # finest albedo cell, world units
    info: dict  # extra numbers for scene.json


def _ellipsoid_exit(u: np.ndarray, c: np.ndarray, axes: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Distance from the origin along unit rays u (N, 3) to the surface of an ellipsoid containing it."""
    p = (-c @ Q) / axes  # origin in the lobe's normalized frame
    d = (u @ Q) / axes
    a = (d * d).sum(1)
    b = 2.0 * d @ p
    cc = p @ p - 1.0
    return (-b + np.sqrt(b * b - 4 * a * cc)) / (2 * a)


def _contain_origin(c: np.ndarray, axes: np.ndarray, Q: np.ndarray, inside: float = 0.95) -> np.ndarray:
    """``c`` unchanged when the origin lies inside the ellipsoid, else scaled so that it does."""
    reach = float(np.linalg.norm((-c @ Q) / axes))  # 1 on the surface; linear in c
    return c if reach < 1.0 else c * (inside / reach)


def _smooth_max(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return a + (b - a) * h + k * h * (1.0 - h)


def procedural_body(cfg: SceneConfig, level: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilobed body, seeded, with x-extent ~``length_m``; (V (N, 3), F (M, 3))."""
    p = cfg.comet
    rng = np.random.default_rng([cfg.seed, 1])
    jit = lambda n, s: 1.0 + s * rng.uniform(-1, 1, n)  # noqa: E731
    # Lobe sizes and offsets in units of the length; both lobes contain the origin (the neck).
    ca, axa = np.array([-0.22, 0.0, 0.0]) * jit(3, 0.05), np.array([0.28, 0.23, 0.20]) * jit(3, 0.08)
    cb, axb = np.array([0.19, 0.02, 0.03]) * jit(3, 0.05), np.array([0.21, 0.18, 0.16]) * jit(3, 0.08)
    Qa = so3_exp(rng.normal(0, 0.08, 3))
    Qb = so3_exp(rng.normal(0, 0.25, 3))  # the small lobe is tilted, as on 67P
    # The jitter can push the origin (the neck) out of a lobe (9 of the first 40 seeds did),
    # and the ray-exit distance is then NaN: pull such a lobe's centre back towards the origin.
    ca, cb = _contain_origin(ca, axa, Qa), _contain_origin(cb, axb, Qb)
    U, F = meshes.icosphere(level)
    r = _smooth_max(_ellipsoid_exit(U, ca, axa, Qa), _ellipsoid_exit(U, cb, axb, Qb), 0.08)
    relief = ValueNoise3(cfg.seed * 7919 + 2, finest_cell=0.25, coarsest_cell=1.0, gain=0.7)
    bumps = ValueNoise3(cfg.seed * 7919 + 3, finest_cell=0.03, coarsest_cell=0.12, gain=0.8)
    r = r * (1.0 + p.relief * relief(U) + p.fine_relief * bumps(U))
    V = U * r[:, None]
    V *= p.length_m / np.ptp(V[:, 0])
    return V, F


def _texture_cell(cfg: SceneConfig, radius: float) -> tuple[float, float]:
    """(mean camera range to the centre, finest texture cell in world units)."""
    fx, fy, cx, cy = pinhole_params(cfg.width, cfg.height, cfg.fov_deg)
    # Framed on the image width: the long axis lies roughly across the image (z is image-up).
    rng_mean = radius / (cfg.comet.fill * cx / fx)
    footprint = (rng_mean - 0.5 * radius) / fx  # metres per pixel on the near side of the body
    return rng_mean, cfg.texture_cell_px * footprint


def _raster(cfg: SceneConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mapping-phase raster: (azimuth deg, latitude deg, relative range) per view, each (n,).

    Back-and-forth azimuth passes over the lit side, one latitude per pass, so a view overlaps
    its neighbours in the pass and the views of the passes above and below it.
    """
    p, n = cfg.comet, cfg.views
    per_pass = max(2, int(round(2 * p.arc_half_deg / p.step_deg)) + 1)
    passes = max(1, math.ceil(n / per_pass))
    k = np.arange(n)
    pass_i, j = np.divmod(k, per_pass)
    s = j / (per_pass - 1)
    s = np.where(pass_i % 2 == 0, s, 1.0 - s)
    az = p.sun_azimuth_deg + p.arc_offset_deg + (2.0 * s - 1.0) * p.arc_half_deg
    frac = pass_i / max(passes - 1, 1)
    lat = p.latitude_mean_deg + p.latitude_amp_deg * (2.0 * frac - 1.0) + rng.normal(0, 1.0, n)
    rel = 1.0 + p.range_var * np.sin(2 * np.pi * k / p.range_period_views + 1.0)
    return az, lat, rel


def orbit(cfg: SceneConfig, center: np.ndarray, radius: float, range_mean: float) -> list[Rigid3]:
    """Photographic orbit: azimuth steps, swinging latitude and range, jittered aim and roll."""
    p = cfg.comet
    rng = np.random.default_rng([cfg.seed, 4])
    n = cfg.views
    k = np.arange(n)
    if p.orbit == "raster":
        az, lat, rel = _raster(cfg, rng)
    else:
        az = p.sun_azimuth_deg + 30.0 + p.step_deg * (k - (n - 1) / 2.0)
        lat = (p.latitude_mean_deg + p.latitude_amp_deg * np.sin(2 * np.pi * k / p.latitude_period_views)
               + rng.normal(0, 1.5, n))
        rel = 1.0 + p.range_var * np.sin(2 * np.pi * k / (0.77 * p.latitude_period_views) + 1.0)
    lat = np.clip(lat, -75.0, 75.0)
    rng_k = range_mean * rel
    dirs = direction_from_azimuth_elevation(np.radians(az), np.radians(lat))
    targets = center + rng.normal(0, p.aim_jitter * radius, (n, 3))
    rolls = rng.normal(0, p.roll_jitter_deg, n)
    return [look_at(center + rng_k[i] * dirs[i], targets[i], np.array([0.0, 0.0, 1.0]), rolls[i])
            for i in range(n)]


def build(cfg: SceneConfig) -> Geometry:
    """Shape, albedo, poses and lights of the comet scene (deterministic in cfg)."""
    p = cfg.comet
    if cfg.mesh:
        V, F = meshes.read_mesh(cfg.mesh)
        source = str(cfg.mesh)
    else:
        # First a coarse body just to learn its size, then the level that resolves the texture.
        V0, _ = procedural_body(cfg, 3)
        V, F = V0, None
        source = "procedural"
    lo, hi = V.min(0), V.max(0)
    center = 0.5 * (lo + hi)
    radius = float(np.linalg.norm(V - center, axis=1).max())
    range_mean, cell = _texture_cell(cfg, radius)
    mean_r = float(np.linalg.norm(V - center, axis=1).mean())
    level = 0
    if F is None:
        # Icosphere edge ~1.1 r / 2**level; keep vertex spacing <= half the finest texture cell.
        level = int(np.clip(math.ceil(math.log2(1.1 * 1.3 * mean_r / (0.5 * cell))), 3, MAX_ICO_LEVEL))
        V, F = procedural_body(cfg, level)
    else:
        while meshes.mean_edge_length(V, F) > 0.5 * cell and 4 * len(F) <= MAX_FACES:
            V, F = meshes.subdivide(V, F)
            level += 1
        if p.fine_relief > 0:
            bumps = ValueNoise3(cfg.seed * 7919 + 3, finest_cell=0.03 * radius, coarsest_cell=0.12 * radius)
            V = V + meshes.vertex_normals(V, F) * (p.fine_relief * mean_r * bumps(V))[:, None]
    noise = ValueNoise3(cfg.seed * 7919 + 5, finest_cell=cell, coarsest_cell=radius, gain=ALBEDO_GAIN)
    albedo = albedo_from_noise(noise(V))
    poses = orbit(cfg, center, radius, range_mean)
    sun = direction_from_azimuth_elevation(math.radians(p.sun_azimuth_deg), math.radians(p.sun_elevation_deg))
    fill = direction_from_azimuth_elevation(math.radians(p.sun_azimuth_deg + 150.0), math.radians(-10.0))
    # A light of zero irradiance is dropped: each light costs a render pass.
    lights = [(-np.asarray(d), e) for d, e in ((sun, p.sun_irradiance), (fill, p.fill_irradiance)) if e > 0]
    edge = meshes.mean_edge_length(V, F)
    info = {"shape": source, "subdivision_level": level, "vertices": len(V), "faces": len(F),
            "mean_edge_m": edge, "range_mean_m": range_mean, "sun_direction": np.asarray(sun).tolist()}
    return Geometry(V, F, albedo, poses, lights, center, radius, cell, info)
