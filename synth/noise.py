"""Band-limited multi-octave 3D value noise for albedo and relief.

Why value noise on a lattice: its spectrum is concentrated below one cycle per cell, so the
finest octave can be pinned to ~4 image pixels. White or sub-pixel noise aliases differently in
every view and SIFT cannot match it (see shared/notes/mitsuba-3.9.md).
"""

from __future__ import annotations

import numpy as np

_TABLE = 4096  # hash table size; lattices larger than this repeat, far beyond any scene here


class ValueNoise3:
    """Seeded, deterministic multi-octave value noise ``f(X) in [-1, 1]``.

    Args:
        seed: explicit seed of the lattice values.
        finest_cell: lattice spacing of the finest octave (world units).
        coarsest_cell: the coarsest octave has at least this spacing.
        gain: amplitude ratio between an octave and the next coarser one (< 1 damps fine ones).
    """

    def __init__(self, seed: int, finest_cell: float, coarsest_cell: float, gain: float = 0.8):
        if not finest_cell > 0:
            raise ValueError(f"finest_cell must be > 0, got {finest_cell}")
        rng = np.random.default_rng(seed)
        self.perm = rng.permutation(_TABLE).astype(np.int64)
        self.values = rng.uniform(-1.0, 1.0, _TABLE)
        n = max(1, int(np.ceil(np.log2(max(coarsest_cell, finest_cell) / finest_cell))) + 1)
        self.cells = finest_cell * 2.0 ** np.arange(n)
        self.amps = gain ** np.arange(n)[::-1]  # the finest octave gets gain**(n-1)
        # Each octave gets its own lattice offset so octaves do not share zero crossings.
        self.offsets = rng.uniform(0, _TABLE, (n, 3))

    def _hash(self, i: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        p = self.perm
        return self.values[p[(p[(p[i % _TABLE] + j) % _TABLE] + k) % _TABLE]]

    def _octave(self, X: np.ndarray, cell: float, offset: np.ndarray) -> np.ndarray:
        g = X / cell + offset
        base = np.floor(g)
        f = g - base
        w = f * f * f * (f * (f * 6 - 15) + 10)  # quintic fade: C2-smooth, no lattice creases
        i, j, k = (base[:, a].astype(np.int64) for a in range(3))
        out = np.zeros(len(X))
        for di in (0, 1):
            wi = w[:, 0] if di else 1 - w[:, 0]
            for dj in (0, 1):
                wj = w[:, 1] if dj else 1 - w[:, 1]
                for dk in (0, 1):
                    wk = w[:, 2] if dk else 1 - w[:, 2]
                    out += wi * wj * wk * self._hash(i + di, j + dj, k + dk)
        return out

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Noise at points (N, 3) -> (N,), roughly in [-1, 1]."""
        X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
        total = np.zeros(len(X))
        for cell, amp, off in zip(self.cells, self.amps, self.offsets):
            total += amp * self._octave(X, cell, off)
        return total / self.amps.sum()


def albedo_from_noise(n: np.ndarray, low: float = 0.06, high: float = 0.55) -> np.ndarray:
    """Map noise (N,) to albedo (N,) spread over [low, high] by its own 0.5th/99.5th percentiles.

    Stretching by percentiles keeps the contrast the same whatever the octave count.
    """
    lo, hi = np.percentile(n, [0.5, 99.5])
    t = np.clip((n - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return low + (high - low) * t
