"""LM in the free gauge: release the 7 similarity DoF that ``fix_gauge`` held, map back after.

Why: holding camera 0's pose and one centre coordinate of a second camera does not change the
Gauss-Newton step (it only picks one representative of the same solution), but it changes what
LM's damping penalizes. A correction that is small in the free gauge (move camera 0 a little)
becomes, with camera 0 held, a similarity motion of every other camera and point: a long step
that ``mu |dx|^2`` damps heavily. On the ParallaxBA fake pile this took the parallax form from
23 to 14 LM iterations (Ceres damping; 29 to 14 with Nielsen's) and let the Euclidean form reach
the optimum (Nielsen damping). ParallaxBA's LM does the same (no gauge constraint; ``mu I`` makes
the system definite); its Gauss-Newton mode holds the gauge, as ours does. It is an option, not
the default (options.DEFAULT_LM_GAUGE): on a forward rig at baseline/depth 3e-4 it needed
1.1-1.5x the iterations of the held gauge.

After the solve the cameras and points are moved by the similarity ``x -> s Q (x - C_a') + C_a``
that puts the anchor camera back at its held pose and the scale coordinate back at its held
value, so callers see the same gauge as before (pixel residuals are unchanged by it, ``s > 0``).
Only problems whose gauge came from ``fix_gauge`` alone are released: fixed cameras or fixed
points pin the gauge themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.ba.problem import BAProblem


@dataclass(frozen=True)
class HeldGauge:
    """What ``fix_gauge`` held: camera ``anchor``'s pose (R (3, 3), C (3,)) and centre coordinate
    ``k`` of camera ``second`` relative to the anchor's (``offset``); ``mask`` the original."""

    anchor: int
    R: np.ndarray
    C: np.ndarray
    second: int
    k: int
    offset: float
    mask: np.ndarray


def release(problem: BAProblem) -> HeldGauge | None:
    """Unmask the gauge columns of a prepared problem; None (nothing changed) where the gauge is
    not fix_gauge's camera-and-scale choice on an otherwise free problem."""
    p = problem
    if p.cam_fixed.any() or p.pt_fixed.any() or p.priors is not None:
        return None
    held = ~p.cam_mask
    rows = np.flatnonzero(held.any(1))
    if len(rows) != 2:
        return None
    full = [int(i) for i in rows if held[i].all()]
    part = [int(i) for i in rows if held[i].sum() == 1 and not held[i, :3].any()]
    if len(full) != 1 or len(part) != 1:
        return None
    a, b = full[0], part[0]
    k = int(np.flatnonzero(held[b, 3:])[0])
    out = HeldGauge(a, p.R[a].copy(), p.C[a].copy(), b, k, float(p.C[b, k] - p.C[a, k]),
                    p.cam_mask.copy())
    p.cam_mask = np.ones_like(p.cam_mask)
    return out


def restore(problem: BAProblem, held: HeldGauge) -> bool:
    """Move cameras and points (problem.R, C, X) back into the held gauge; restore the mask.
    False (solution left in the free gauge) if the scale would not be positive."""
    p, a = problem, held.anchor
    p.cam_mask = held.mask
    Q = held.R.T @ p.R[a]  # world rotation taking the solution's anchor back to its held pose
    rel = Q @ (p.C[held.second] - p.C[a])
    s = held.offset / rel[held.k] if rel[held.k] != 0 else np.nan
    if not (np.isfinite(s) and s > 0):
        return False
    Ca = p.C[a].copy()
    p.R = p.R @ Q.T
    p.C = s * (p.C - Ca) @ Q.T + held.C
    p.X = s * (p.X - Ca) @ Q.T + held.C
    p.R[a], p.C[a] = held.R, held.C  # exactly, not up to rounding
    p.C[held.second, held.k] = held.C[held.k] + held.offset
    return True
