"""Robust losses on squared residual-block norms, Ceres' convention: cost = 1/2 sum rho(s)."""

from __future__ import annotations

import numpy as np

LOSSES = ("trivial", "huber", "cauchy")


def rho(name: str, s: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Loss value rho(s) and derivative rho'(s) for squared norms s (...) >= 0.

    Huber: s for s <= a^2, 2 a sqrt(s) - a^2 beyond; Cauchy: a^2 log(1 + s / a^2).
    """
    if name == "trivial":
        return s, np.ones_like(s)
    a2 = scale * scale
    if name == "huber":
        root = np.sqrt(s)
        inlier = s <= a2
        val = np.where(inlier, s, 2.0 * scale * root - a2)
        d1 = np.where(inlier, 1.0, scale / np.maximum(root, 1e-300))
        return val, d1
    if name == "cauchy":
        return a2 * np.log1p(s / a2), 1.0 / (1.0 + s / a2)
    raise ValueError(f"unknown loss {name!r}; choose one of {', '.join(LOSSES)}")
