"""The full Jacobian of a BA form, assembled densely from its per-slot blocks: the reference
that the Schur-complement steps of the BA tests are checked against."""

from __future__ import annotations

import numpy as np


def dense_jacobian(p, prm, Jp, Jc, masked: bool = True) -> np.ndarray:
    """(M, k, 6 N + 3 P): camera columns first (6 per camera, slot by slot, ``Jc[s]`` (M, k,
    c1 - c0) into columns ``c0:c1`` of ``prm.slot_cams[s]``), then 3 per point from ``Jp``
    (M, k, 3). ``masked``: held camera columns (``p.cam_mask``) are zeroed."""
    M, k = Jp.shape[:2]
    N, P = p.num_cameras, p.num_points
    J = np.zeros((M, k, 6 * N + 3 * P))
    m = np.arange(M)
    for s, (c0, c1) in enumerate(prm.slot_cols):
        for j in range(c0, c1):
            col = Jc[s][:, :, j - c0]
            if masked:
                col = col * p.cam_mask[prm.slot_cams[s], j][:, None]
            np.add.at(J, (m, slice(None), 6 * prm.slot_cams[s] + j), col)
    for j in range(3):
        J[m, :, 6 * N + 3 * p.obs_pt + j] = Jp[:, :, j]
    return J


def dense_lm_step(p, prm, r, Jp, Jc, mu, w=None, nielsen: bool = False):
    """(dx, g) of the damped normal equations ``(H + mu D) dx = -g`` over the free columns
    (held camera columns dropped), from :func:`dense_jacobian` with rows weighted by w (M, k);
    D = I (Nielsen / ParallaxBA) or diag(H) clipped to [1e-6, 1e32] (Ceres)."""
    M, k = r.shape
    w = np.ones_like(r) if w is None else w
    J = dense_jacobian(p, prm, Jp, Jc)
    free = np.r_[p.cam_mask.reshape(-1), np.ones(3 * p.num_points, bool)]
    J = (J * w[:, :, None]).reshape(M * k, -1)[:, free]
    H, g = J.T @ J, J.T @ (r * w).reshape(-1)
    D = np.ones(len(H)) if nielsen else np.clip(np.diag(H), 1e-6, 1e32)
    return np.linalg.solve(H + mu * np.diag(D), -g), g
