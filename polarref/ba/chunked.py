"""Normal equations of the parallax forms built chunk by chunk (issue 14: memory at 631 views).

The eager solver evaluates the per-observation Jacobians at every trial step, while the
normal equations of the current estimate are still held (a rejected step reuses them): for the
polar form on the rosetta twin's final global BA (1.22 M observations) that is ~320 MB
(residuals (M, 3), ``res_D_point`` (M, 3, 3), ``res_D_obs`` (M, 3, 6), ``A d`` (M, 3)) plus the
chain rule's temporaries beside W and the cross-camera blocks (~530 MB), and the build needs the
whole set at once. On large problems the solver instead evaluates only the residuals at a
trial step (its cost decides acceptance) and, once a step is accepted, builds V, g and the
fused three-slot blocks (kernels.build_anchored) from runs of whole points of ``CHUNK_OBS``
observations, so no (M, ...) Jacobian array exists.

With the X-space elimination (xspace.py, ``xs``) the chunks feed the observer-only build
(``xspace_jit.build_xspace``) instead, with the anchors' maps of every point computed once
from the same per-point terms, so the three-slot forms keep the Euclidean-structured Schur
pass at scale too.

The results are bit-identical to the eager build: every per-observation value is computed by
the same code on the same inputs (a slice of the observations), and the kernels accumulate in
the same order (points ascending, observations ascending within a point); the residuals
without Jacobians come from the same rays and projections as with them (tests/ba/test_ba_memory.py
compares both paths exactly).
"""

from __future__ import annotations

import numpy as np

from polarref.ba import row_map

CHUNK_OBS = 1 << 16  # observations per chunk: ~40 MB of three-slot Jacobians and temporaries
MIN_OBS = 1 << 18  # below this the eager path (per-iteration speed, benchmarks) is kept


def applies(st, param, num_observations: int) -> bool:
    """Whether the solve runs chunked: the fused three-slot kernel build (schur.py) and a
    form that can evaluate a run of observations (``Parallax.evaluate_rows``)."""
    rows = getattr(param, "supports_rows", None)
    return (st.fast and st.fused and num_observations >= MIN_OBS and rows is not None
            and rows())


def point_chunks(obs_bounds: np.ndarray, size: int) -> list[tuple[int, int]]:
    """Runs of whole points ``[p0, p1)`` with about ``size`` observations each (at least one
    point per run). obs_bounds (P + 1,): first observation of each point, then M."""
    P = len(obs_bounds) - 1
    out, p0 = [], 0
    while p0 < P:
        p1 = int(np.searchsorted(obs_bounds, obs_bounds[p0] + size, side="right")) - 1
        p1 = min(max(p1, p0 + 1), P)
        out.append((p0, p1))
        p0 = p1
    return out


def build(st, param, R, C, pts, w, pt_free, xs=None, mask_v=None):
    """(V (P, 3, 3), g_p (P, 3), (g_c (Nv, 6), W (E, 6, 3), U (Nv, 6, 6))) at (R, C, pts),
    and ``st.cross_blocks`` for the Schur kernel, as ``SchurStructure.point_terms`` and its
    fused ``build`` give them from the whole arrays; with ``xs`` (xspace.AnchorElimination,
    mask_v (Nv, 6) the gauge mask) the observer-only blocks of ``xs.build`` instead.

    w: robust weights (M, k) or None; pt_free: (P, 1) 1 = free point, or None (all free).
    """
    from polarref.ba import kernels

    if xs is not None:
        return _build_xspace(st, param, R, C, pts, w, xs, mask_v)
    V, g_p = np.zeros((st.P, 3, 3)), np.zeros((st.P, 3))
    g_c, W, U = np.zeros((st.Nv, 6)), np.zeros((st.E, 6, 3)), np.zeros((st.B, 6, 6))
    cross = getattr(st, "cross_blocks", None)
    if cross is None:  # as SchurStructure._build_fast: [N | t] per entry, Xma per point
        cross = (np.empty((st.E, 6, 4)), np.empty((st.P, 3, 3)))
    if not st.observer_unique:
        cross[0][:] = 0.0
    h = np.zeros((st.P, 3))
    terms = param.point_terms_for_rows(R, C, pts)
    bounds = st.obs_bounds
    for p0, p1 in point_chunks(bounds, CHUNK_OBS):
        m0, m1 = int(bounds[p0]), int(bounds[p1])
        r, Jp, (J_obs, anc) = param.evaluate_rows(R, C, terms, m0, m1)
        Ad = anc.Ad
        r, Jp, J_obs, Ad = _weighted(r, Jp, J_obs, Ad, anc.row_map, None if w is None else w[m0:m1])
        op = st.obs_pt[m0:m1]
        if pt_free is not None:
            Jp = Jp * pt_free[op][:, :, None]
        r, Jp = np.ascontiguousarray(r), np.ascontiguousarray(Jp)
        kernels.point_sums(Jp, r, op, V, g_p)
        kernels.build_anchored(np.ascontiguousarray(J_obs), np.ascontiguousarray(Ad),
                               np.ascontiguousarray(anc.h[p0:p1]), Jp, r,
                               np.ascontiguousarray(st.slot_vc[:, m0:m1]),
                               np.ascontiguousarray(st.slot_entry[:, m0:m1]),
                               bounds[p0:p1 + 1] - m0, W, g_c, U, cross[0],
                               cross[1][p0:p1], st.observer_unique)
        h = anc.h  # per point, all P (the schur kernel forms the cross blocks with it)
    st.cross_blocks = cross
    st.cross_h = np.ascontiguousarray(h)
    return V, g_p, (g_c, W, U)


def _build_xspace(st, param, R, C, pts, w, xs, mask_v):
    """:func:`build` for the X-space elimination (no fixed points: the solver keeps the
    reference path for those, as the eager build does)."""
    from polarref.ba import kernels, xspace_jit

    V, g_p = np.zeros((st.P, 3, 3)), np.zeros((st.P, 3))
    g_c, W, U = np.zeros((st.Nv, 6)), np.zeros((st.E, 6, 3)), np.zeros((st.Nv, 6, 6))
    terms = param.point_terms_for_rows(R, C, pts)
    maps = param.anchor_maps_for_rows(R, C, terms)
    xs.start(maps)
    bounds, c = st.obs_bounds, np.ascontiguousarray
    for p0, p1 in point_chunks(bounds, CHUNK_OBS):
        m0, m1 = int(bounds[p0]), int(bounds[p1])
        r, Jp, (J_obs, anc) = param.evaluate_rows(R, C, terms, m0, m1)
        r, Jp, J_obs, _ = _weighted(r, Jp, J_obs, anc.Ad, anc.row_map,
                                    None if w is None else w[m0:m1], weight_ad=False)
        r, Jp, op = c(r), c(Jp), st.obs_pt[m0:m1]
        kernels.point_sums(Jp, r, op, V, g_p)
        # whole points per chunk: V, g_p of p0:p1 are complete before their anchors' share
        xspace_jit.build_xspace(c(J_obs), Jp, r, c(st.slot_vc[:, m0:m1]), c(st.slot_entry[:, m0:m1]),
                                bounds[p0:p1 + 1] - m0, mask_v, xs.maps[0][p0:p1], xs.maps[1][p0:p1],
                                V[p0:p1], g_p[p0:p1], W, g_c, U, xs.gx, xs.diag_f)
    return V, g_p, (g_c, W, U)


def _weighted(r, Jp, J_obs, Ad, G, w, weight_ad=True):
    """One chunk's rows weighted by w (its (m, k) robust weights, or None), or whitened into
    two rows where the form maps its last row (G (m, 2), row_map.py; Jacobians in place).
    ``weight_ad`` False: Ad is returned as it came (the X-space build does not read it)."""
    if G is not None:
        return row_map.whiten(r, w, G, Jp, J_obs, Ad), Jp, J_obs, Ad
    if w is None:
        return r, Jp, J_obs, Ad
    return r * w, Jp * w[:, :, None], J_obs * w[:, :, None], Ad * w if weight_ad else Ad
