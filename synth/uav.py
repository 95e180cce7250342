"""UAV scene: textured height-field terrain with box buildings, lawnmower flight lines.

World frame: x east (flight lines run along x), y north, z up; the terrain's mean level is 0.
"""

from __future__ import annotations

import math

import numpy as np

from polarref.core.angular import direction_from_azimuth_elevation
from synth.comet import Geometry
from synth.config import SceneConfig
from synth.conventions import look_at, pinhole_params
from synth.noise import ValueNoise3, albedo_from_noise

MARGIN_M = 10.0  # terrain beyond the outermost image footprints
STREET_ALBEDO = 0.45  # asphalt is darker than the textured ground around it
TREE_ALBEDO = 0.6


def nadir_views(cfg: SceneConfig) -> int:
    """Views of the nadir lawnmower; the rest (oblique_fraction) are oblique cross strips."""
    return cfg.views - int(round(cfg.views * cfg.uav.oblique_fraction))


def flight_plan(cfg: SceneConfig) -> tuple[int, int, float, float]:
    """(lines, images per line, along-track spacing, line spacing) of the nadir lawnmower."""
    p = cfg.uav
    fx, _, cx, cy = pinhole_params(cfg.width, cfg.height, cfg.fov_deg)
    along_fp = 2 * cy / fx * p.altitude_m  # image height lies along the track
    across_fp = 2 * cx / fx * p.altitude_m
    n = nadir_views(cfg)
    lines = max(2, round(math.sqrt(n / 2.3)))
    per_line = math.ceil(n / lines)
    return lines, per_line, along_fp * (1 - p.forward_overlap), across_fp * (1 - p.side_overlap)


def cross_plan(cfg: SceneConfig) -> tuple[int, int, float, float]:
    """(lines, images per line, along-track spacing, line spacing) of the oblique cross strips:
    lines along y over the nadir block, the same along-track spacing, as many lines as the
    oblique views fill."""
    n = cfg.views - nadir_views(cfg)
    lines, per_line, dx, dy = flight_plan(cfg)
    if n == 0:
        return 0, 0, dx, 0.0
    per_cross = max(2, int(round((lines - 1) * dy / dx)) + 1)
    cross_lines = max(1, math.ceil(n / per_cross))
    spacing = (per_line - 1) * dx / max(cross_lines - 1, 1)
    return cross_lines, per_cross, (lines - 1) * dy / (per_cross - 1), spacing


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


def _tilted(center: np.ndarray, forward: np.ndarray, tilt_deg: float, roll_deg: float):
    """cam_from_world at ``center`` looking down, tilted ``tilt_deg`` towards ``forward``."""
    up_world = np.array([0.0, 0.0, 1.0])
    tilt = math.radians(tilt_deg)
    view_dir = -math.cos(tilt) * up_world + math.sin(tilt) * forward
    up = math.cos(tilt) * forward + math.sin(tilt) * up_world  # image-up points ahead
    return look_at(center, center + view_dir, up, roll_deg)


def _street_mask(xy: np.ndarray, block: float, width: float) -> np.ndarray:
    """(N,) bool: points on a street of the grid with period ``block`` (none when block <= 0)."""
    if block <= 0:
        return np.zeros(len(xy), bool)
    d = np.abs((xy + 0.5 * block) % block - 0.5 * block)  # distance to the nearest grid line
    return (d < 0.5 * width).any(axis=1)


def _near_street(cxy: np.ndarray, rad: float, block: float, width: float) -> bool:
    if block <= 0:
        return False
    d = np.abs((cxy + 0.5 * block) % block - 0.5 * block)
    return bool((d < 0.5 * width + rad + 1.0).any())


def _canopy(cfg: SceneConfig, xy: np.ndarray, street: np.ndarray, placed) -> np.ndarray:
    """Tree canopy height (N,) over the grid: thresholded noise blobs, none on streets or
    buildings; the noise's own fine octaves give each crown a rough, textured top."""
    p = cfg.uav
    crowns = ValueNoise3(cfg.seed * 7919 + 22, finest_cell=3.0, coarsest_cell=24.0, gain=0.7)
    c = crowns(np.c_[xy, np.zeros(len(xy))])
    open_ground = ~street
    for a, b, r in placed:
        open_ground &= np.hypot(xy[:, 0] - a, xy[:, 1] - b) > r + 1.0
    if not open_ground.any():
        return np.zeros(len(xy))
    thr = np.quantile(c[open_ground], 1.0 - p.tree_cover)
    # Smoothstep crowns: rounded tops and sloping sides, so the texture is not smeared down
    # vertical walls one grid cell wide.
    t = np.clip((c - thr) / 0.3, 0.0, 1.0)
    h = p.tree_height_m * t * t * (3.0 - 2.0 * t)
    return np.where(open_ground, h, 0.0)


def build(cfg: SceneConfig) -> Geometry:
    """Terrain, buildings, albedo, lawnmower poses and lights (deterministic in cfg)."""
    p = cfg.uav
    rng = np.random.default_rng([cfg.seed, 11])
    fx, _, cx, cy = pinhole_params(cfg.width, cfg.height, cfg.fov_deg)
    lines, per_line, dx, dy = flight_plan(cfg)
    along_fp, across_fp = 2 * cy / fx * p.altitude_m, 2 * cx / fx * p.altitude_m
    tilt = max(abs(p.oblique_deg), abs(p.oblique_strip_deg) if p.oblique_fraction > 0 else 0.0)
    tilt_reach = p.altitude_m * math.tan(math.radians(tilt))
    half = 0.5 * max(along_fp, across_fp) + tilt_reach + MARGIN_M
    x0, x1 = -half, (per_line - 1) * dx + half
    y0, y1 = -half, (lines - 1) * dy + half
    cell = cfg.texture_cell_px * (p.altitude_m - p.building_height_m[1] / 2) / fx
    step = max(0.5 * cell, math.sqrt((x1 - x0) * (y1 - y0) / p.max_grid_vertices))

    xy, F = _grid(x0, x1, y0, y1, step)
    height = ValueNoise3(cfg.seed * 7919 + 21, finest_cell=15.0, coarsest_cell=120.0, gain=0.6)
    ground = lambda q: p.terrain_relief_m * height(np.c_[q, np.zeros(len(q))])  # noqa: E731
    street = _street_mask(xy, p.block_m, p.street_width_m)
    V = np.c_[xy, ground(xy)]
    parts_V, parts_F, tint = [V], [F], [np.where(street, STREET_ALBEDO, 1.0)]
    n = len(V)
    placed: list[tuple[float, float, float]] = []
    for _ in range(p.buildings):
        for _attempt in range(50):
            size = rng.uniform(*p.building_size_m, 2)
            cxy = rng.uniform([x0 + half, y0 + half], [x1 - half + 1e-6, y1 - half + 1e-6])
            rad = 0.5 * float(np.hypot(*size))
            clear = all(np.hypot(cxy[0] - a, cxy[1] - b) > rad + r + 4.0 for a, b, r in placed)
            if clear and not _near_street(cxy, rad, p.block_m, p.street_width_m):
                break
        else:
            continue
        placed.append((cxy[0], cxy[1], rad))
        corners = cxy + rad * np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [0, 0]])
        z0 = float(ground(corners).min()) - 1.0
        z1 = float(ground(corners).max()) + rng.uniform(*p.building_height_m)
        yaw = rng.uniform(0, np.pi)
        if p.block_m > 0:  # flats line up with the street grid
            yaw = round(yaw / (0.5 * np.pi)) * 0.5 * np.pi
        bv, bf = _box(cxy, size, yaw, z0, z1, step)
        parts_V.append(bv)
        parts_F.append(bf + n)
        tint.append(np.full(len(bv), rng.uniform(0.6, 1.3)))
        n += len(bv)
    V, F, tint = np.concatenate(parts_V), np.concatenate(parts_F), np.concatenate(tint)
    if p.tree_cover > 0:
        canopy = _canopy(cfg, xy, street, placed)
        V[: len(xy), 2] += canopy
        tint[: len(xy)] = np.where(canopy > 0.3, TREE_ALBEDO, tint[: len(xy)])
    noise = ValueNoise3(cfg.seed * 7919 + 5, finest_cell=cell, coarsest_cell=60.0, gain=1.0)
    albedo = albedo_from_noise(noise(V)) * tint
    if p.field_contrast > 0:
        fields = ValueNoise3(cfg.seed * 7919 + 23, finest_cell=40.0, coarsest_cell=80.0, gain=0.7)
        # Quantized coarse noise: patches of uniform tint with sharp borders, like farm fields.
        level = np.round(3.0 * fields(np.c_[V[:, :2], np.zeros(len(V))])) / 3.0
        albedo = albedo * (1.0 + p.field_contrast * np.clip(level, -1.0, 1.0) * 0.5)
    albedo = np.clip(albedo, 0.02, 0.9)

    poses = []
    up_world = np.array([0.0, 0.0, 1.0])
    for k in range(nadir_views(cfg)):
        line, j = divmod(k, per_line)
        forward = np.array([1.0, 0.0, 0.0]) if line % 2 == 0 else np.array([-1.0, 0.0, 0.0])
        x = j * dx if line % 2 == 0 else (per_line - 1 - j) * dx
        center = np.array([x, line * dy, p.altitude_m]) + rng.normal(0, 0.3, 3)
        poses.append(_tilted(center, forward, p.oblique_deg, rng.normal(0, 1.0)))
    c_lines, c_per_line, c_dy, c_dx = cross_plan(cfg)
    for k in range(cfg.views - len(poses)):
        line, j = divmod(k, c_per_line)
        forward = np.array([0.0, 1.0, 0.0]) if line % 2 == 0 else np.array([0.0, -1.0, 0.0])
        y = j * c_dy if line % 2 == 0 else (c_per_line - 1 - j) * c_dy
        center = np.array([line * c_dx, y, p.altitude_m]) + rng.normal(0, 0.3, 3)
        poses.append(_tilted(center, forward, p.oblique_strip_deg, rng.normal(0, 1.0)))
    sun = direction_from_azimuth_elevation(math.radians(p.sun_azimuth_deg), math.radians(p.sun_elevation_deg))
    fill = direction_from_azimuth_elevation(math.radians(p.sun_azimuth_deg + 180.0), math.radians(60.0))
    lights = [(-np.asarray(d), e) for d, e in ((sun, p.sun_irradiance), (fill, p.fill_irradiance)) if e > 0]
    center = 0.5 * np.array([x0 + x1, y0 + y1, 0.0])
    radius = float(np.linalg.norm(V - center, axis=1).max())
    info = {"lines": lines, "images_per_line": per_line, "cross_lines": c_lines,
            "cross_images_per_line": c_per_line, "tree_cover": p.tree_cover, "along_track_spacing_m": dx,
            "line_spacing_m": dy, "grid_step_m": step, "buildings": len(placed),
            "vertices": len(V), "faces": len(F), "extent_m": [x0, x1, y0, y1],
            "sun_direction": np.asarray(sun).tolist()}
    return Geometry(V, F, albedo, poses, lights, center, radius, cell, info)


# --- ground control (issue 33) -------------------------------------------------------------
def gcp_layout(root, n_control: int, n_check: int, mark_sigma_px: float, seed: int,
               prior_sigma_m: float = 2.0, prior_vertical_m: float = 4.0,
               target_sigma_m: float = 0.01):
    """Seeded ground points on the rendered surface of a UAV scene folder ``root``
    (synth/ground_points.py: seen in >= 3 GT views, exact 3D, marks = GT projection +
    N(0, mark_sigma_px^2)), plus pose priors (GT centre + N(0, prior sigma^2), independent per
    view). Writes ``gcps.csv``, ``gcp_observations.csv`` and ``priors.csv`` beside ``images/``;
    returns their paths. The first ``n_control`` points (in draw order) are control, the rest check."""
    from pathlib import Path

    from polarref.georef.formats import PosePrior, write_gcps, write_marks, write_priors
    from synth.ground_points import lay_out

    root = Path(root)
    rng = np.random.default_rng([seed, 33])
    points, marks, imgs = lay_out(root, n_control, n_check, mark_sigma_px, target_sigma_m, rng)
    sig = np.array([prior_sigma_m, prior_sigma_m, prior_vertical_m])
    priors = [PosePrior(im.name, im.cam_from_world.center + rng.normal(0, 1, 3) * sig, sig)
              for im in imgs]
    out = (root / "gcps.csv", root / "gcp_observations.csv", root / "priors.csv")
    write_gcps(out[0], points)
    write_marks(out[1], marks)
    write_priors(out[2], priors)
    return out
