"""Surface landmarks for the comet scenes: the comet's analogue of ground control (issue 33).

A mission's landmark catalogue (e.g. Rosetta's stereophotoclinometry maplets) gives body-fixed
3D positions of surface features with a stated accuracy, identified in the images. Here they
are seeded mesh vertices seen in >= 3 GT views (synth/ground_points.py) with exact 3D, stated
1-sigma ``target_sigma_m`` and marks = GT projection + N(0, mark_sigma_px^2); written in the
``--gcps`` / ``--gcp-observations`` formats (ids ``LMK01``...), so the same adjustment uses them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.georef.formats import write_gcps, write_marks
from synth.ground_points import lay_out

LANDMARK_SIGMA_M = 1.0  # stated 1-sigma of a catalogued landmark (metres)


def landmark_layout(root, n_control: int, n_check: int, mark_sigma_px: float, seed: int,
                    target_sigma_m: float = LANDMARK_SIGMA_M) -> tuple[Path, Path]:
    """Write ``landmarks.csv`` and ``landmark_observations.csv`` beside ``images/`` of the
    rendered comet folder ``root``; returns their paths."""
    root = Path(root)
    rng = np.random.default_rng([seed, 67])
    points, marks, _ = lay_out(root, n_control, n_check, mark_sigma_px, target_sigma_m, rng, prefix="LMK")
    out = (root / "landmarks.csv", root / "landmark_observations.csv")
    write_gcps(out[0], points)
    write_marks(out[1], marks)
    return out
