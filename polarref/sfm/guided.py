"""Stage 7b: guided matching (track continuation) of existing 3D points into registered images.

Union-find tracks only hold keypoints joined by verified pairwise matches; a keypoint that
failed the ratio test (a repeated texture nearby) or belonged to a dropped conflicting component
is lost although the map already knows where its point projects. Here every 3D point without an
observation in a registered image is projected into it, and a keypoint that is in no track, lies
within ``radius_px`` of the projection and whose descriptor is near the track's descriptors is
appended to the track (COLMAP's track completion does the same through its correspondence graph).

Acceptance of a (point, keypoint) candidate:
* reprojection distance <= ``radius_px`` (at most the triangulation threshold);
* descriptor distance (to the nearest descriptor among the track's active observations)
  <= ``max_distance``;
* unambiguous: the best candidate of the point beats the second (another keypoint inside the
  radius) by Lowe's ``ratio``, and each keypoint goes to the point it matches best.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from polarref.sfm import rays as R_


@dataclass(frozen=True)
class GuidedConfig:
    """Guided matching settings."""

    enabled: bool = False         # run guided matching after registrations and global BAs (off: measured
    #                               worse on the 28-view scenes, e.g. UAV 0.0067 -> 0.0083 deg at 0.5 px, see report)
    radius_px: float = 2.0        # search radius around the projection (<= triangulation max_error_px)
    max_distance: float = 0.7     # max L2 distance of unit descriptors (COLMAP's matching default)
    ratio: float = 0.8            # best / second-best descriptor distance among the keypoints in the radius


def guided_extend(state, images, descriptors: list[np.ndarray], cfg: GuidedConfig) -> int:
    """Append unambiguous free keypoints of ``images`` to existing 3D points; returns how many.

    Args:
        state: :class:`polarref.sfm.state.MapState` (modified in place: new active observations).
        images: registered image indices to search.
        descriptors: (K_i, 128) unit descriptors of every image's keypoints.
    """
    added = 0
    for image in images:
        added += _extend_image(state, int(image), descriptors, cfg)
    return added


def _extend_image(state, image: int, descriptors: list[np.ndarray], cfg: GuidedConfig) -> int:
    tr = state.tracks
    kp = state.keypoints[image]
    free = np.flatnonzero(state.obs_of_kp[image] < 0)
    if not len(free) or not state.registered[image]:
        return 0
    # points that have no observation at all (active or not) in this image
    pts = np.flatnonzero(state.has_point & ~state.track_mask(tr.track[tr.image == image]))
    if not len(pts):
        return 0
    cam = state.cameras[state.camera_of_image[image]]
    uv = R_.project(cam, state.pose(image).apply(state.X[pts]))
    vis = np.isfinite(uv).all(1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & \
        (uv[:, 0] <= cam.width) & (uv[:, 1] <= cam.height)
    pts, uv = pts[vis], uv[vis]
    if not len(pts):
        return 0
    tree = cKDTree(kp[free])
    near = tree.query_ball_point(uv, cfg.radius_px)
    cnt = np.fromiter((len(n) for n in near), np.int64, len(near))
    if not cnt.sum():
        return 0
    p_idx = np.repeat(np.arange(len(pts)), cnt)                 # candidate pairs: point slot
    k_idx = free[np.concatenate([np.asarray(n, np.int64) for n in near if len(n)])]  # keypoint
    dist = _track_descriptor_distance(state, pts[p_idx], descriptors,
                                      np.asarray(descriptors[image][k_idx], np.float32))
    # ratio test per point among its candidates
    order = np.lexsort((dist, p_idx))
    p_s, k_s, d_s = p_idx[order], k_idx[order], dist[order]
    first = np.r_[True, p_s[1:] != p_s[:-1]]
    second = np.full(len(pts), np.inf)
    nxt = np.flatnonzero(~first & np.r_[False, first[:-1]])     # second candidate of each point
    second[p_s[nxt]] = d_s[nxt]
    best_p, best_k, best_d = p_s[first], k_s[first], d_s[first]
    ok = (best_d <= cfg.max_distance) & (best_d < cfg.ratio * second[best_p])
    best_p, best_k, best_d = best_p[ok], best_k[ok], best_d[ok]
    if not len(best_p):
        return 0
    # one point per keypoint: the best descriptor distance wins
    order = np.lexsort((best_d, best_k))
    keep = np.r_[True, best_k[order][1:] != best_k[order][:-1]]
    sel = order[keep]
    track_ids, keypoints = pts[best_p[sel]], best_k[sel]
    state.add_observations(np.full(len(track_ids), image), keypoints, track_ids)
    return len(track_ids)


def _track_descriptor_distance(state, track_ids: np.ndarray, descriptors: list[np.ndarray],
                               cand: np.ndarray) -> np.ndarray:
    """Min L2 distance (P,) between each candidate descriptor (P, D) and its track's active descriptors."""
    tr = state.tracks
    act = np.flatnonzero(state.active)
    act = act[np.argsort(tr.track[act], kind="stable")]
    t_sorted = tr.track[act]
    lo = np.searchsorted(t_sorted, track_ids, "left")
    hi = np.searchsorted(t_sorted, track_ids, "right")
    n = hi - lo
    pair = np.repeat(np.arange(len(track_ids)), n)
    obs = act[np.repeat(lo, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))]
    img, kpi = tr.image[obs], tr.keypoint[obs]
    D = np.empty((len(obs), cand.shape[1]), np.float32)
    for i in np.unique(img):
        s = img == i
        D[s] = descriptors[i][kpi[s]]
    sim = np.einsum("ij,ij->i", D, cand[pair])
    best = np.full(len(track_ids), -np.inf)
    np.maximum.at(best, pair, sim)
    return np.sqrt(np.maximum(2.0 - 2.0 * best, 0.0))
