"""The incremental map as flat arrays: poses, one 3D point slot per track, active observations.

Every operation (triangulate, extend, filter) is vectorized over observations. A track owns at
most one 3D point; an observation is *active* when it belongs to that point. Operations on a
subset of tracks (one image's, a local BA window's) reach their observations through a
track -> observations index instead of masking every observation of the map, so a registration
step costs what its window holds, not what the map holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.core.geometry import Rigid3
from polarref.sfm import rays as R_
from polarref.sfm.tracks import Tracks
from polarref.sfm.triangulation import (dlt, midpoint_two_view, nview_least_squares,
                                        triangulation_angles_deg)


@dataclass(frozen=True)
class TriangulationConfig:
    """How 3D points are made and kept."""

    method: str = "moci"            # "moci": ATBD 5.3 midpoint for 2 rays, ATBD 6.2 least squares for more; "dlt"
    max_error_px: float = 2.0       # an observation further than this from its point's projection is dropped
    #                                 (COLMAP: 4; 2 gave equal or better rotations on the synthetic scenes,
    #                                 e.g. UAV 0.012 vs 0.014 deg, 28-view comet 0.066 vs 0.062, rotation-aligned)
    min_angle_deg: float = 1.5      # points whose largest ray angle is below this are dropped (COLMAP 1.5)
    rejection_rounds: int = 5       # worst-observation rejection rounds when triangulating a track


class MapState:
    """Mutable map: everything the incremental loop changes."""

    def __init__(self, names: list[str], cameras: list, camera_of_image: np.ndarray,
                 keypoints: list[np.ndarray], tracks: Tracks, tri: TriangulationConfig):
        self.names = names
        self.cameras = cameras
        self.camera_of_image = np.asarray(camera_of_image, dtype=np.int64)
        self.keypoints = keypoints
        self.tracks = tracks
        self.tri = tri
        n = len(keypoints)
        self.registered = np.zeros(n, bool)
        self.R = np.tile(np.eye(3), (n, 1, 1))
        self.t = np.zeros((n, 3))
        T, O = tracks.num_tracks, len(tracks.track)
        self.X = np.full((T, 3), np.nan)
        self.has_point = np.zeros(T, bool)
        self.active = np.zeros(O, bool)
        self.uv = np.zeros((O, 2))
        self.ray = np.zeros((O, 3))
        # obs index of each keypoint (-1 = keypoint in no track), per image
        self.obs_of_kp = [np.full(len(k), -1, np.int64) for k in keypoints]
        for i in np.unique(tracks.image):
            sel = np.flatnonzero(tracks.image == i)
            self.uv[sel] = keypoints[i][tracks.keypoint[sel]]
            self.ray[sel] = R_.bearings(cameras[self.camera_of_image[i]], self.uv[sel])
            self.obs_of_kp[i][tracks.keypoint[sel]] = sel
        self._by_track: tuple[np.ndarray, np.ndarray] | None = None  # see obs_of_tracks
        # (C,) True while a camera's focal length is only the default guess (no EXIF, not given);
        # the first registration of one of its images then estimates it (mapper, registration.py)
        self.focal_guessed = np.zeros(len(cameras), bool)

    def guess_focal(self, cameras: np.ndarray) -> None:
        """Mark cameras (indices) whose focal length is only a guess."""
        self.focal_guessed[cameras] = True

    def set_camera(self, c: int, camera) -> None:
        """Replace camera ``c`` and recompute the bearings of its observations."""
        self.cameras[c] = camera
        obs = np.flatnonzero(self.camera_of_image[self.tracks.image] == c)
        self.ray[obs] = R_.bearings(camera, self.uv[obs])

    # ---- poses --------------------------------------------------------------------------
    def set_pose(self, image: int, cam_from_world: Rigid3) -> None:
        self.R[image], self.t[image] = cam_from_world.R, cam_from_world.t
        self.registered[image] = True

    def pose(self, image: int) -> Rigid3:
        return Rigid3(self.R[image], self.t[image])

    def centers(self) -> np.ndarray:
        return -np.einsum("nji,nj->ni", self.R, self.t)

    def track_mask(self, track_ids: np.ndarray | None) -> np.ndarray:
        """(T,) bool, True for ``track_ids`` (all tracks when None)."""
        if track_ids is None:
            return np.ones(self.tracks.num_tracks, bool)
        m = np.zeros(self.tracks.num_tracks, bool)
        m[np.asarray(track_ids, dtype=np.int64)] = True
        return m

    def obs_of_tracks(self, track_ids: np.ndarray | None) -> np.ndarray:
        """Ascending indices of every observation (active or not) of ``track_ids`` (None: all)."""
        tr = self.tracks
        if track_ids is None:
            return np.arange(len(tr.track))
        if self._by_track is None or len(self._by_track[0]) != len(tr.track):
            order = np.argsort(tr.track, kind="stable")
            self._by_track = (order, np.searchsorted(tr.track[order], np.arange(tr.num_tracks + 1)))
        order, start = self._by_track
        t = np.unique(np.asarray(track_ids, dtype=np.int64))
        lo, n = start[t], start[t + 1] - start[t]
        idx = np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(int(n.sum()))
        return np.sort(order[idx])

    # ---- errors ------------------------------------------------------------------------
    def errors(self, obs: np.ndarray, X: np.ndarray | None = None) -> np.ndarray:
        """Reprojection errors (len(obs),) in px of observations ``obs`` (NaN behind the camera).

        Args:
            obs: (M,) observation indices. X: (M, 3) points to use instead of the stored ones.
        """
        img = self.tracks.image[obs]
        Xw = self.X[self.tracks.track[obs]] if X is None else X
        Xc = np.einsum("mij,mj->mi", self.R[img], Xw) + self.t[img]
        err = np.full(len(obs), np.nan)
        cam = self.camera_of_image[img]
        for c in np.unique(cam):
            s = cam == c
            uv = R_.project(self.cameras[c], Xc[s])
            err[s] = np.linalg.norm(uv - self.uv[obs[s]], axis=1)
        return err

    # ---- triangulation -----------------------------------------------------------------
    def _solve(self, obs: np.ndarray, group: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Points (n, 3) and a validity mask (n,) from the observations of each group."""
        img = self.tracks.image[obs]
        C = self.centers()[img]
        d = np.einsum("mji,mj->mi", self.R[img], self.ray[obs])  # world-frame ray: R^T ray
        X = np.full((n, 3), np.nan)
        ok = np.zeros(n, bool)
        count = np.bincount(group, minlength=n)
        if self.tri.method == "dlt":
            P = np.concatenate([self.R[img], self.t[img][:, :, None]], 2)
            res = dlt(P, R_.normalized(self.ray[obs]), group, n)
            return res.X, res.valid & (count >= 2)
        two = count == 2
        if two.any():  # MOCI two-view midpoint (ATBD 5.3) on tracks with exactly two rays
            sel = two[group]
            order = np.argsort(group[sel], kind="stable")
            o2 = np.flatnonzero(sel)[order].reshape(-1, 2)
            res = midpoint_two_view(C[o2[:, 0]], d[o2[:, 0]], C[o2[:, 1]], d[o2[:, 1]])
            g2 = group[o2[:, 0]]
            X[g2], ok[g2] = res.X, res.valid
        many = count > 2
        if many.any():  # MOCI N-view least squares (ATBD 6.2)
            sel = many[group]
            remap = np.cumsum(many) - 1
            res = nview_least_squares(C[sel], d[sel], remap[group[sel]], int(many.sum()))
            X[many], ok[many] = res.X, res.valid
        return X, ok

    def triangulate(self, track_ids: np.ndarray) -> int:
        """(Re)triangulate tracks without a point from their registered observations.

        Worst observations above ``max_error_px`` are rejected one per round; a point is kept
        with >= 2 inlier observations, all in front, and a ray angle >= ``min_angle_deg``.
        Returns the number of new points.
        """
        tr = self.tracks
        track_ids = np.unique(np.asarray(track_ids, dtype=np.int64))
        track_ids = track_ids[~self.has_point[track_ids]]
        if not len(track_ids):
            return 0
        obs = self.obs_of_tracks(track_ids)
        obs = obs[self.registered[tr.image[obs]]]
        remap = np.full(tr.num_tracks, -1, np.int64)
        cnt = np.bincount(tr.track[obs], minlength=tr.num_tracks)
        good_t = np.flatnonzero(cnt >= 2)
        if not len(good_t):
            return 0
        remap[good_t] = np.arange(len(good_t))
        obs = obs[remap[tr.track[obs]] >= 0]
        n = len(good_t)
        keep = np.ones(len(obs), bool)
        for _ in range(max(1, self.tri.rejection_rounds)):
            o = obs[keep]
            g = remap[tr.track[o]]
            X, ok = self._solve(o, g, n)
            err = self.errors(o, X[g])
            err = np.where(np.isfinite(err), err, np.inf)
            worst = np.full(n, -1.0)
            np.maximum.at(worst, g, err)
            bad_g = worst > self.tri.max_error_px
            if not bad_g.any():
                break
            # drop the worst observation of each bad group (one per round; ties drop all tied)
            drop = bad_g[g] & (err >= worst[g])
            keep[np.flatnonzero(keep)[drop]] = False
        o = obs[keep]
        g = remap[tr.track[o]]
        X, ok = self._solve(o, g, n)
        err = self.errors(o, X[g])
        bad_obs = ~(err <= self.tri.max_error_px)
        ok &= np.bincount(g, weights=bad_obs, minlength=n) == 0
        ok &= np.bincount(g, minlength=n) >= 2
        ang = np.zeros(n)
        if ok.any():
            # angles of the solved points only: a placeholder for the others would sit at the
            # gauge camera's centre (the origin) and have no ray direction
            sub = ok[g]
            keep = np.flatnonzero(ok)
            remap_ok = np.full(n, -1, np.int64)
            remap_ok[keep] = np.arange(len(keep))
            ang[keep] = triangulation_angles_deg(X[keep], self.centers()[tr.image[o[sub]]], remap_ok[g[sub]],
                                                 len(keep))
        ok &= ang >= self.tri.min_angle_deg
        new_t = good_t[ok]
        self.X[new_t] = X[ok]
        self.has_point[new_t] = True
        self.active[o[ok[g]]] = True
        return int(ok.sum())

    def extend(self, track_ids: np.ndarray | None = None) -> int:
        """Add registered, inactive observations of existing points that reproject within the threshold."""
        tr = self.tracks
        obs = self.obs_of_tracks(track_ids)
        obs = obs[self.has_point[tr.track[obs]] & self.registered[tr.image[obs]] & ~self.active[obs]]
        if not len(obs):
            return 0
        err = self.errors(obs)
        add = obs[err <= self.tri.max_error_px]
        self.active[add] = True
        return len(add)

    def filter(self, track_ids: np.ndarray | None = None) -> int:
        """Drop active observations with large error, then points with < 2 observations or a small angle.

        Returns the number of points removed.
        """
        tr = self.tracks
        sel_t = self.track_mask(track_ids)
        mine = self.obs_of_tracks(track_ids)
        obs = mine[self.active[mine]]
        err = self.errors(obs)
        self.active[obs[~(err <= self.tri.max_error_px)]] = False
        pts = np.flatnonzero(self.has_point & sel_t)
        mine = mine[self.active[mine]]
        n_obs = np.bincount(tr.track[mine], minlength=tr.num_tracks)
        drop = pts[n_obs[pts] < 2]
        keep_pts = pts[n_obs[pts] >= 2]
        if len(keep_pts):
            o = mine[self.track_mask(keep_pts)[tr.track[mine]]]
            remap = np.full(tr.num_tracks, -1, np.int64)
            remap[keep_pts] = np.arange(len(keep_pts))
            ang = triangulation_angles_deg(self.X[keep_pts], self.centers()[tr.image[o]],
                                           remap[tr.track[o]], len(keep_pts))
            drop = np.concatenate([drop, keep_pts[ang < self.tri.min_angle_deg]])
        self.remove_points(drop)
        return len(drop)

    def add_observations(self, images: np.ndarray, keypoints: np.ndarray, track_ids: np.ndarray) -> None:
        """Append new active observations (keypoints in no track yet) to existing tracks.

        The observation arrays stay aligned; ``tracks`` is no longer sorted by track afterwards
        and ``tracks.start`` describes only the tracks as built (nothing in the mapper uses it).
        """
        images = np.asarray(images, np.int64)
        keypoints = np.asarray(keypoints, np.int64)
        track_ids = np.asarray(track_ids, np.int64)
        if not len(images):
            return
        tr = self.tracks
        taken = np.concatenate([self.obs_of_kp[i][keypoints[images == i]] for i in np.unique(images)])
        if (taken >= 0).any():
            raise ValueError(f"{int((taken >= 0).sum())} keypoint(s) already belong to a track")
        first = len(tr.track)
        new = np.arange(first, first + len(images))
        tr.track = np.concatenate([tr.track, track_ids])
        tr.image = np.concatenate([tr.image, images])
        tr.keypoint = np.concatenate([tr.keypoint, keypoints])
        uv = np.zeros((len(images), 2))
        ray = np.zeros((len(images), 3))
        for i in np.unique(images):
            s = images == i
            uv[s] = self.keypoints[i][keypoints[s]]
            ray[s] = R_.bearings(self.cameras[self.camera_of_image[i]], uv[s])
            self.obs_of_kp[i][keypoints[s]] = new[s]
        self.uv = np.concatenate([self.uv, uv])
        self.ray = np.concatenate([self.ray, ray])
        self.active = np.concatenate([self.active, np.ones(len(images), bool)])

    def remove_points(self, track_ids: np.ndarray) -> None:
        m = self.track_mask(track_ids)
        self.active[self.obs_of_tracks(track_ids)] = False
        self.has_point[m] = False
        self.X[m] = np.nan

    # ---- queries ------------------------------------------------------------------------
    def correspondences_2d3d(self, image: int) -> tuple[np.ndarray, np.ndarray]:
        """(obs (M,), world points (M, 3)) of ``image``'s keypoints whose track has a point."""
        tr = self.tracks
        o = self.obs_of_kp[image]
        o = o[o >= 0]
        o = o[self.has_point[tr.track[o]]]
        return o, self.X[tr.track[o]]

    def num_visible(self) -> np.ndarray:
        """(N,) per image: keypoints whose track already has a point."""
        tr = self.tracks
        return np.bincount(tr.image[self.has_point[tr.track]], minlength=len(self.keypoints))

    def visibility_scores(self, levels: int = 4) -> np.ndarray:
        """(N,) next-best-view score per image (COLMAP's visibility pyramid, Schoenberger & Frahm 2016).

        Keypoints whose track has a point are binned in 2^l x 2^l grids, l = 1..levels; each
        occupied cell scores 2^l. Many points spread over the image beat as many points in one
        corner, which PnP conditions poorly.
        """
        tr = self.tracks
        n = len(self.keypoints)
        o = np.flatnonzero(self.has_point[tr.track] & ~self.registered[tr.image])
        img = tr.image[o]
        wh = np.array([[c.width, c.height] for c in self.cameras], float)[self.camera_of_image[img]]
        uv = self.uv[o] / wh
        score = np.zeros(n)
        for lv in range(1, levels + 1):
            k = 2 ** lv
            cell = np.clip((uv * k).astype(np.int64), 0, k - 1)
            key = np.unique((img * k + cell[:, 0]) * k + cell[:, 1])
            score += k * np.bincount(key // (k * k), minlength=n)
        return score

    def covisibility(self, image: int) -> np.ndarray:
        """(N,) number of points image ``image`` shares (actively) with each image."""
        tr = self.tracks
        o = self.obs_of_kp[image]
        o = o[o >= 0]
        o = self.obs_of_tracks(tr.track[o[self.active[o]]])
        return np.bincount(tr.image[o[self.active[o]]], minlength=len(self.keypoints))
