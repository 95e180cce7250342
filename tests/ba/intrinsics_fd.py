"""Central differences of a self-calibrating evaluation against its intrinsics columns (shared by
the intrinsics tests)."""

from __future__ import annotations

import numpy as np


def intrinsics_columns_match_differences(w, aug, *, require_effect: bool = False) -> int:
    """Assert every free intrinsics column of ``w.evaluate`` equals central differences of the
    residuals (h = 1e-7); with ``require_effect`` also that each column moves some residual.
    Returns how many columns were checked."""
    R, C, pts = aug.R, aug.C, w.init_points()
    _, _, Jc = w.evaluate(R, C, pts)
    N, h = w.N, 1e-7
    checked = 0
    for j in range(N, len(C)):
        for c in range(3):
            if not aug.cam_mask[j, 3 + c]:
                continue
            Cp, Cm = C.copy(), C.copy()
            Cp[j, c] += h
            Cm[j, c] -= h
            num = (w.evaluate(R, Cp, pts, False)[0] - w.evaluate(R, Cm, pts, False)[0]) / (2 * h)
            ana = np.zeros_like(num)
            for s, (c0, c1) in enumerate(w.slot_cols):
                if c0 <= 3 + c < c1:
                    ana += np.where((w.slot_cams[s] == j)[:, None], Jc[s][:, :, 3 + c - c0], 0.0)
            np.testing.assert_allclose(ana, num, rtol=1e-5, atol=1e-6 * max(np.abs(num).max(), 1))
            assert not require_effect or np.abs(num).max() > 0  # the column really acts on the residuals
            checked += 1
    return checked
