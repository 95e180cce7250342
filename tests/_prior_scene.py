"""A small aerial block with known truth for the prior / control-point tests (numpy only)."""

from dataclasses import dataclass

import numpy as np

from polarref.ba import BAProblem
from polarref.ba.priors import AttitudePriors, BAPriors, CentrePriors, ControlPoints
from polarref.camera import Camera
from polarref.core.geometry import so3_exp
from polarref.model.observations import Observations

CAL = Camera("PINHOLE", 1000, 800, [900.0, 900.0, 500.0, 400.0])


@dataclass
class Block:
    problem: BAProblem  # perturbed start, 0.3 px pixel noise
    R: np.ndarray       # (N, 3, 3) true cam_from_world
    C: np.ndarray       # (N, 3) true centres
    X: np.ndarray       # (P, 3) true points
    G: np.ndarray       # (Gn, 3) true control/check points
    gcp_cam: np.ndarray
    gcp_idx: np.ndarray
    gcp_uv: np.ndarray  # exact pixels of the control points


def _project(R, C, X, cam, pt):
    Xc = np.einsum("mij,mj->mi", R[cam], X[pt] - C[cam])
    return 900.0 * Xc[:, :2] / Xc[:, 2:] + [500.0, 400.0], Xc[:, 2]


def block(seed: int = 0, rows: int = 2, cols: int = 4, points: int = 120, gcps: int = 6) -> Block:
    """Nadir strips at 50 m over a 60 x 40 m patch of gently rolling ground."""
    rng = np.random.default_rng(seed)
    cx, cy = np.meshgrid(np.linspace(0, 45, cols), np.linspace(0, 20, rows))
    C = np.stack([cx.ravel(), cy.ravel(), np.full(cx.size, 50.0)], 1)
    N = len(C)
    down = np.diag([1.0, -1.0, -1.0])  # camera z along world -z, camera x along world x
    R = so3_exp(rng.normal(0, np.radians(2.0), (N, 3))) @ down
    ground = lambda x, y: 2.0 * np.sin(x / 9.0) * np.cos(y / 7.0)  # noqa: E731
    xy = rng.uniform([-5, -8], [50, 28], (points, 2))
    X = np.c_[xy, ground(xy[:, 0], xy[:, 1])]
    gxy = rng.uniform([0, -2], [45, 22], (gcps, 2))
    G = np.c_[gxy, ground(gxy[:, 0], gxy[:, 1])]
    cam = np.repeat(np.arange(N), points)
    pt = np.tile(np.arange(points), N)
    uv, z = _project(R, C, X, cam, pt)
    vis = (z > 0) & (uv[:, 0] > 0) & (uv[:, 0] < 1000) & (uv[:, 1] > 0) & (uv[:, 1] < 800)
    cam, pt, uv = cam[vis], pt[vis], uv[vis] + rng.normal(0, 0.3, (int(vis.sum()), 2))
    gc = np.repeat(np.arange(N), gcps)
    gi = np.tile(np.arange(gcps), N)
    guv, gz = _project(R, C, G, gc, gi)
    gv = (gz > 0) & (guv[:, 0] > 0) & (guv[:, 0] < 1000) & (guv[:, 1] > 0) & (guv[:, 1] < 800)
    Rn = so3_exp(rng.normal(0, np.radians(0.2), (N, 3))) @ R
    Cn = C + rng.normal(0, 0.3, C.shape)
    Xn = X + rng.normal(0, 0.3, X.shape)
    prob = BAProblem([CAL] * N, Rn, Cn, Xn, Observations.from_arrays(cam, pt, uv))
    return Block(prob, R, C, X, G, gc[gv], gi[gv], guv[gv])


def centre_priors(b: Block, sigma: float, seed: int = 1, noise: float | None = None) -> CentrePriors:
    """Priors drawn around the true centres with ``noise`` (default sigma), stated ``sigma``."""
    rng = np.random.default_rng(seed)
    n = len(b.C)
    c0 = b.C + rng.normal(0, sigma if noise is None else noise, b.C.shape)
    return CentrePriors(np.arange(n), c0, np.tile(np.eye(3) / sigma, (n, 1, 1)))


def attitude_priors(b: Block, sigma_deg: float, seed: int = 2) -> AttitudePriors:
    rng = np.random.default_rng(seed)
    n = len(b.C)
    R0 = so3_exp(rng.normal(0, np.radians(sigma_deg), (n, 3))) @ b.R
    return AttitudePriors(np.arange(n), R0, np.full(n, np.radians(sigma_deg)))


def control(b: Block, which, sigma: float = 0.01, mark_px: float = 0.5, seed: int = 3) -> ControlPoints:
    """Control points ``which`` (indices into b.G) with exact priors and noisy marks."""
    rng = np.random.default_rng(seed)
    which = np.asarray(which)
    lut = -np.ones(len(b.G), np.int64)
    lut[which] = np.arange(len(which))
    sel = lut[b.gcp_idx] >= 0
    uv = b.gcp_uv[sel] + rng.normal(0, mark_px, (int(sel.sum()), 2))
    return ControlPoints(b.G[which], np.tile(np.eye(3) / sigma, (len(which), 1, 1)),
                         lut[b.gcp_idx[sel]], b.gcp_cam[sel], uv, mark_px,
                         tuple(f"G{k}" for k in which))


def with_priors(b: Block, **parts) -> BAProblem:
    p = b.problem.copy()
    p.priors = BAPriors(**parts)
    return p
