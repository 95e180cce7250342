"""UAV scene: textured height-field terrain with box buildings, lawnmower flight lines.

World frame: x east (flight lines run along x), y north, z up; the terrain's mean level is 0.
"""

from __future__ import annotations

import math

import numpy as np

from polarref.angular import direction_from_azimuth_elevation
from synth.comet import Geometry
from synth.config import SceneConfig
from synth.conventions import look_at, pinhole_params
from synth.noise import ValueNoise3, albedo_from_noise

MAX_GRID_VERTICES = 1_500_000  # above this the terrain grid coarsens (texture gets blurrier)
MARGIN_M = 10.0  # terrain beyond the outermost image footprints


def flight_plan(cfg: SceneConfig) -> tuple[int, int, float, float]:
    """(lines, images per line, along-track spacing, line spacing) for ``cfg.views`` images."""
    p = cfg.uav
    fx, _, cx, cy = pinhole_params(cfg.width, cfg.height, cfg.fov_deg)
    along_fp = 2 * cy / fx * p.altitude_m  # image height lies along the track
    across_fp = 2 * cx / fx * p.altitude_m
    lines = max(2, round(math.sqrt(cfg.views / 2.3)))
    per_line = math.ceil(cfg.views / lines)
    return lines, per_line, along_fp * (1 - p.forward_overlap), across_fp * (1 - p.side_overlap)


def _grid(x0, x1, y0, y1, step):
    nx, ny = int(math.ceil((x1 - x0) / step)) + 1, int(math.ceil((y1 - y0) / step)) + 1
    xs, ys = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
    X, Y = np.meshgrid(xs, ys)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])  # counter-clockwise from +z
    return np.stack([X.ravel(), Y.ravel()], 1), F


def _box(center_xy, size, yaw, z0, z1, step):
    """Closed-top box (no bottom) with faces subdivided to ~``step``; outward winding."""
    sx, sy = size
    parts_V, parts_F, n = [], [], 0
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    # Each face: origin, two edge vectors (u, v) with u x v pointing outward.
    faces = [((-sx / 2, -sy / 2, z1), (sx, 0, 0), (0, sy, 0)),  # roof (+z)
             ((-sx / 2, -sy / 2, z0), (sx, 0, 0), (0, 0, z1 - z0)),  # south (-y)
             ((sx / 2, sy / 2, z0), (-sx, 0, 0), (0, 0, z1 - z0)),  # north (+y)
             ((sx / 2, -sy / 2, z0), (0, sy, 0), (0, 0, z1 - z0)),  # east (+x)
             ((-sx / 2, sy / 2, z0), (0, -sy, 0), (0, 0, z1 - z0))]  # west (-x)
    for o, u, v in faces:
        o, u, v = (np.array(a, float) for a in (o, u, v))
        nu = max(1, int(math.ceil(np.linalg.norm(u) / step)))
        nv = max(1, int(math.ceil(np.linalg.norm(v) / step)))
        a_, b_ = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1))
        P = o + a_.ravel()[:, None] * u + b_.ravel()[:, None] * v
        idx = np.arange(len(P)).reshape(nv + 1, nu + 1)
        q0, q1, q2, q3 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        F = np.concatenate([np.stack([q0, q1, q3], 1), np.stack([q0, q3, q2], 1)]) + n
        P = P @ Rz.T
        P[:, :2] += center_xy
        parts_V.append(P)
        parts_F.append(F)
        n += len(P)
    return np.concatenate(parts_V), np.concatenate(parts_F)


def build(cfg: SceneConfig) -> Geometry:
    """Terrain, buildings, albedo, lawnmower poses and lights (deterministic in cfg)."""
    p = cfg.uav
    rng = np.random.default_rng([cfg.seed, 11])
    fx, _, cx, cy = pinhole_params(cfg.width, cfg.height, cfg.fov_deg)
    lines, per_line, dx, dy = flight_plan(cfg)
    along_fp, across_fp = 2 * cy / fx * p.altitude_m, 2 * cx / fx * p.altitude_m
    tilt_reach = p.altitude_m * math.tan(math.radians(abs(p.oblique_deg)))
    half = 0.5 * max(along_fp, across_fp) + tilt_reach + MARGIN_M
    x0, x1 = -half, (per_line - 1) * dx + half
    y0, y1 = -half, (lines - 1) * dy + half
    cell = cfg.texture_cell_px * (p.altitude_m - p.building_height_m[1] / 2) / fx
    step = max(0.5 * cell, math.sqrt((x1 - x0) * (y1 - y0) / MAX_GRID_VERTICES))

    xy, F = _grid(x0, x1, y0, y1, step)
    height = ValueNoise3(cfg.seed * 7919 + 21, finest_cell=15.0, coarsest_cell=120.0, gain=0.6)
    ground = lambda q: p.terrain_relief_m * height(np.c_[q, np.zeros(len(q))])  # noqa: E731
    V = np.c_[xy, ground(xy)]
    parts_V, parts_F, tint = [V], [F], [np.ones(len(V))]
    n = len(V)
    placed: list[tuple[float, float, float]] = []
    for _ in range(p.buildings):
        for _attempt in range(50):
            size = rng.uniform(8.0, 22.0, 2)
            cxy = rng.uniform([x0 + half, y0 + half], [x1 - half + 1e-6, y1 - half + 1e-6])
            rad = 0.5 * float(np.hypot(*size))
            if all(np.hypot(cxy[0] - a, cxy[1] - b) > rad + r + 4.0 for a, b, r in placed):
                break
        else:
            continue
        placed.append((cxy[0], cxy[1], rad))
        corners = cxy + rad * np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [0, 0]])
        z0 = float(ground(corners).min()) - 1.0
        z1 = float(ground(corners).max()) + rng.uniform(*p.building_height_m)
        bv, bf = _box(cxy, size, rng.uniform(0, np.pi), z0, z1, step)
        parts_V.append(bv)
        parts_F.append(bf + n)
        tint.append(np.full(len(bv), rng.uniform(0.6, 1.3)))
        n += len(bv)
    V, F, tint = np.concatenate(parts_V), np.concatenate(parts_F), np.concatenate(tint)
    noise = ValueNoise3(cfg.seed * 7919 + 5, finest_cell=cell, coarsest_cell=60.0, gain=1.0)
    albedo = np.clip(albedo_from_noise(noise(V)) * tint, 0.02, 0.9)

    poses = []
    up_world = np.array([0.0, 0.0, 1.0])
    for k in range(cfg.views):
        line, j = divmod(k, per_line)
        forward = np.array([1.0, 0.0, 0.0]) if line % 2 == 0 else np.array([-1.0, 0.0, 0.0])
        x = j * dx if line % 2 == 0 else (per_line - 1 - j) * dx
        center = np.array([x, line * dy, p.altitude_m]) + rng.normal(0, 0.3, 3)
        tilt = math.radians(p.oblique_deg)
        view_dir = -math.cos(tilt) * up_world + math.sin(tilt) * forward
        up = math.cos(tilt) * forward + math.sin(tilt) * up_world  # image-up points ahead
        poses.append(look_at(center, center + view_dir, up, rng.normal(0, 1.0)))
    sun = direction_from_azimuth_elevation(math.radians(p.sun_azimuth_deg), math.radians(p.sun_elevation_deg))
    fill = direction_from_azimuth_elevation(math.radians(p.sun_azimuth_deg + 180.0), math.radians(60.0))
    lights = [(-np.asarray(sun), p.sun_irradiance), (-np.asarray(fill), p.fill_irradiance)]
    center = 0.5 * np.array([x0 + x1, y0 + y1, 0.0])
    radius = float(np.linalg.norm(V - center, axis=1).max())
    info = {"lines": lines, "images_per_line": per_line, "along_track_spacing_m": dx,
            "line_spacing_m": dy, "grid_step_m": step, "buildings": len(placed),
            "vertices": len(V), "faces": len(F), "extent_m": [x0, x1, y0, y1],
            "sun_direction": np.asarray(sun).tolist()}
    return Geometry(V, F, albedo, poses, lights, center, radius, cell, info)
