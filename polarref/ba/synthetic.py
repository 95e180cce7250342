"""Synthetic BA problems with known truth from ``pycolmap.synthesize_dataset``."""

from __future__ import annotations

import copy

import numpy as np

from polarref.core.geometry import Rigid3, so3_exp
from polarref.model.colmap import from_pycolmap

# Sizes used by the benchmark (issue 6): cameras, points; every point is seen by every camera.
SIZES = {"synth-20": (20, 600), "synth-60": (60, 1000), "synth-200": (200, 1500)}
# Realistic sparse visibility (issue 12): each point seen by SPARSE_TRACK cameras, ~200 points per image.
SPARSE_TRACK = 4
SPARSE_SIZES = {"synth-60-sparse": (60, 3000), "synth-200-sparse": (200, 10000)}


def synthetic_reconstruction(num_cameras: int, num_points: int, *, seed: int = 0,
                             noise_px: float = 0.5, rot_deg: float = 0.1,
                             point_sigma: float = 0.02, center_sigma: float = 0.02,
                             track_length: int = -1, outlier_fraction: float = 0.0,
                             outlier_px: float = 30.0):
    """(initial, truth) Reconstructions; truth noise-free, initial perturbed.

    The keypoints of ``initial`` carry N(0, noise_px^2) per coordinate (COLMAP's
    ``synthesize_noise``), plus ``outlier_fraction`` gross outliers displaced by ``outlier_px``
    to ``2 outlier_px`` in a random direction. Poses are perturbed by ``rot_deg`` (per axis,
    Gaussian) and centres and points by ``*_sigma`` times the scene's size, deterministically
    from ``seed`` (about 20-25 px initial RMS at the defaults).
    Returns also the outlier mask per observation in track order of ``initial`` (for tests)
    as ``initial.outliers``: dict point_id -> (L,) bool.
    """
    import pycolmap

    from polarref.model import Reconstruction

    pycolmap.set_random_seed(seed)
    o = pycolmap.SyntheticDatasetOptions()
    o.num_rigs, o.num_cameras_per_rig, o.num_frames_per_rig = 1, 1, num_cameras
    o.num_points3D = num_points
    o.track_length = track_length
    o.num_points2D_without_point3D = 0
    gt_pc = pycolmap.synthesize_dataset(o)
    noisy = pycolmap.Reconstruction(gt_pc)
    if noise_px > 0:
        no = pycolmap.SyntheticNoiseOptions()
        no.point2D_stddev = noise_px
        pycolmap.synthesize_noise(no, noisy)
    truth = from_pycolmap(gt_pc)
    init = from_pycolmap(noisy)
    rng = np.random.default_rng(seed)
    ids, xyz = truth.points_array()
    size = float(np.linalg.norm(xyz.std(0))) or 1.0
    for i in sorted(init.images):
        pose = truth.images[i].cam_from_world
        Rn = so3_exp(rng.normal(0, np.radians(rot_deg), 3)) @ pose.R
        Cn = pose.center + rng.normal(0, center_sigma * size, 3)
        init.images[i].cam_from_world = Rigid3(Rn, -Rn @ Cn)
    for p in ids:
        init.points3D[int(p)].xyz = truth.points3D[int(p)].xyz + rng.normal(0, point_sigma * size, 3)
    init.outliers = {}
    if outlier_fraction > 0:
        for p in ids:
            pt = init.points3D[int(p)]
            bad = rng.random(len(pt.track)) < outlier_fraction
            init.outliers[int(p)] = bad
            for (image_id, idx) in pt.track[bad]:
                ang = rng.uniform(0, 2 * np.pi)
                mag = rng.uniform(outlier_px, 2 * outlier_px)
                kp = init.images[int(image_id)].keypoints
                kp[int(idx)] = kp[int(idx)] + mag * np.array([np.cos(ang), np.sin(ang)])
    return init, truth


def clone(rec):
    """Deep copy of a Reconstruction."""
    return copy.deepcopy(rec)


def ring_problem(num_cameras: int, num_points: int, mean_track: float, seed: int = 0):
    """A BAProblem shaped like an SfM map (issue 14's memory proxy): ``num_cameras`` PINHOLE
    cameras on a ring looking at points around the origin, each point seen by a run of
    consecutive cameras (2 + Poisson(mean_track - 2) long), 0.5 px pixel noise; poses and
    points perturbed (about 0.05 deg, 0.01 units); camera 0 fixed. Built with numpy only,
    fast at a million observations."""
    from polarref.ba.problem import BAProblem
    from polarref.camera import Camera
    from polarref.core.geometry import so3_exp
    from polarref.model.observations import Observations

    rng = np.random.default_rng(seed)
    ang = 2 * np.pi * np.arange(num_cameras) / num_cameras
    C = np.stack([10 * np.cos(ang), 10 * np.sin(ang), 0.5 * np.sin(3 * ang)], 1)
    R = np.empty((num_cameras, 3, 3))
    for i, c in enumerate(C):  # look at the origin, world z up
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R[i] = np.stack([x, np.cross(z, x), z])
    X = rng.normal(0, 1.0, (num_points, 3))
    L = np.clip(rng.poisson(mean_track - 2, num_points) + 2, 2, num_cameras)
    first = rng.integers(0, num_cameras, num_points)
    pt = np.repeat(np.arange(num_points), L)
    off = np.arange(len(pt)) - np.repeat(np.cumsum(L) - L, L)
    cam = (np.repeat(first, L) + off) % num_cameras
    cal = Camera("PINHOLE", 1600, 1200, [1000.0, 1000.0, 800.0, 600.0])
    Xc = np.einsum("mij,mj->mi", R[cam], X[pt] - C[cam])
    uv = 1000.0 * Xc[:, :2] / Xc[:, 2:] + [800.0, 600.0] + rng.normal(0, 0.5, (len(pt), 2))
    Rn = so3_exp(rng.normal(0, np.radians(0.05), (num_cameras, 3))) @ R
    Cn = C + rng.normal(0, 0.01, C.shape)
    Xn = X + rng.normal(0, 0.01, X.shape)
    fixed = np.zeros(num_cameras, bool)
    fixed[0] = True
    return BAProblem([cal] * num_cameras, Rn, Cn, Xn,
                     Observations.from_arrays(cam.astype(np.int64), pt.astype(np.int64), uv),
                     cam_fixed=fixed)
