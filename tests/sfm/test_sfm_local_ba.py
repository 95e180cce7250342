"""The mapper's BA input straight from the map arrays, and the track -> observations index."""

import numpy as np

from polarref.ba import prepare, problem_from_reconstruction, solve
from polarref.ba.options import BAOptions
from polarref.camera import Camera
from polarref.core.geometry import Rigid3, so3_exp
from polarref.sfm import bundle
from polarref.sfm import rays as R_
from polarref.sfm.state import MapState, TriangulationConfig
from polarref.sfm.tracks import build_tracks


def _state(rng, n_img=6, n_pts=150, noise_px=0.5):
    """Six views of a point cloud, every point matched in every consecutive pair, noisy pixels."""
    cam = Camera("PINHOLE", 640, 480, np.array([500.0, 500.0, 320.0, 240.0]))
    X = rng.uniform(-2, 2, (n_pts, 3)) + [0, 0, 12]
    poses = [Rigid3(so3_exp([0.0, -0.04 * i, 0.01 * i]), [-0.6 * i + 1.5, 0.05 * i, 0.02 * i]) for i in range(n_img)]
    uv = [R_.project(cam, p.apply(X)) + rng.normal(0, noise_px, (n_pts, 2)) for p in poses]
    # a random subset of points per pair: tracks of varied length, some images miss a point
    pairs = {(i, i + 1): np.flatnonzero(rng.uniform(size=n_pts) < 0.8) for i in range(n_img - 1)}
    tracks = build_tracks([n_pts] * n_img, {k: np.stack([v, v], 1) for k, v in pairs.items()})
    state = MapState([f"{i}.png" for i in range(n_img)], [cam], np.zeros(n_img, np.int64), uv, tracks,
                     TriangulationConfig(max_error_px=4.0))
    for i, p in enumerate(poses):
        # start poses off the truth so that BA has work to do
        state.set_pose(i, Rigid3(so3_exp(rng.normal(0, 2e-3, 3)) @ p.R, p.t + rng.normal(0, 1e-2, 3)))
    state.triangulate(np.arange(tracks.num_tracks))
    return state


def test_obs_of_tracks_equals_the_mask_over_all_observations():
    rng = np.random.default_rng(1)
    state = _state(rng)
    tr = state.tracks
    for _ in range(5):
        ids = rng.choice(tr.num_tracks, size=rng.integers(1, 40), replace=True)
        np.testing.assert_array_equal(state.obs_of_tracks(ids), np.flatnonzero(np.isin(tr.track, ids)))
    np.testing.assert_array_equal(state.obs_of_tracks(None), np.arange(len(tr.track)))
    assert len(state.obs_of_tracks(np.zeros(0, np.int64))) == 0
    # appended observations (guided matching) rebuild the index
    free = np.flatnonzero(state.obs_of_kp[0] < 0)[:3]
    if len(free):
        state.add_observations(np.zeros(len(free), np.int64), free, np.arange(len(free)))
        ids = np.arange(len(free))
        np.testing.assert_array_equal(state.obs_of_tracks(ids), np.flatnonzero(np.isin(tr.track, ids)))


def test_local_problem_from_state_equals_the_reconstruction_route_and_solves_alike():
    """The direct gather must give the problem that the old MapState -> Reconstruction ->
    BAProblem route gave (same cameras, points, observations and order), so the solves agree."""
    rng = np.random.default_rng(2)
    state = _state(rng)
    variable, fixed = [2, 3], [1, 4]
    tr = state.tracks
    pts = np.unique(tr.track[state.active & np.isin(tr.image, variable)])
    direct = bundle.problem_from_state(state, variable, fixed, pts)
    rec = bundle.to_reconstruction(state, sorted(variable + fixed), pts)
    route = problem_from_reconstruction(rec, variable_image_ids=[i + 1 for i in variable],
                                        fixed_image_ids=[i + 1 for i in fixed])
    for p in (direct, route):
        prepare(p)
    np.testing.assert_array_equal(direct.image_ids, route.image_ids)
    np.testing.assert_array_equal(direct.point_ids, route.point_ids)
    np.testing.assert_array_equal(direct.obs_cam, route.obs_cam)
    np.testing.assert_array_equal(direct.obs_pt, route.obs_pt)
    np.testing.assert_array_equal(direct.obs_uv, route.obs_uv)
    np.testing.assert_array_equal(direct.cam_mask, route.cam_mask)
    np.testing.assert_allclose(direct.C, route.C, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(direct.X, route.X)
    a = solve(direct, BAOptions(loss="cauchy"), prepared=True)
    b = solve(route, BAOptions(loss="cauchy"), prepared=True)
    assert a.final_cost < 0.5 * a.initial_cost  # there was something to adjust
    assert abs(a.final_cost - b.final_cost) <= 1e-9 * b.final_cost


def test_adjust_writes_back_only_the_variable_poses_and_the_window_points():
    rng = np.random.default_rng(3)
    state = _state(rng)
    R0, t0, X0 = state.R.copy(), state.t.copy(), state.X.copy()
    tr = state.tracks
    pts = np.unique(tr.track[state.active & (tr.image == 3)])
    obs = np.flatnonzero(state.active & np.isin(tr.track, pts))
    before = state.errors(obs)
    info = bundle.adjust(state, [3], [2, 4], "euclidean", 20, "cauchy", track_ids=pts)
    assert info.summary.final_cost < info.summary.initial_cost
    moved = np.flatnonzero(np.abs(state.t - t0).max(1) > 0)
    np.testing.assert_array_equal(moved, [3])
    np.testing.assert_array_equal(state.R[[0, 1, 2, 4, 5]], R0[[0, 1, 2, 4, 5]])
    changed = np.flatnonzero(np.abs(np.nan_to_num(state.X - X0)).max(1) > 0)
    assert len(changed) and np.isin(changed, pts).all()
    # the reprojection error of the window's observations went down
    assert np.nanmean(state.errors(obs)) < np.nanmean(before)
