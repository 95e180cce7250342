"""Pose priors inside the mapper (sfm/priors_hook.py): placing the map in the priors' frame, the
priors handed to each BA, and the mapped model equal to the post-hoc georeferenced optimum."""

import copy

import numpy as np
import pytest

from polarref.core.geometry import Rigid3, Sim3, so3_exp
from polarref.georef.formats import PosePrior
from polarref.sfm.priors_hook import MapperPriors, PriorHook


class _State:
    """The part of MapState the hook touches."""

    def __init__(self, R, C, X):
        n = len(R)
        self.R, self.t = R.copy(), -np.einsum("nij,nj->ni", R, C)
        self.X, self.has_point = X.copy(), np.ones(len(X), bool)
        self.registered = np.zeros(n, bool)

    def set_pose(self, i, pose):
        self.R[i], self.t[i] = pose.R, pose.t
        self.registered[i] = True

    def centers(self):
        return -np.einsum("nji,nj->ni", self.R, self.t)


def _truth(n=6, seed=0, line=False):
    rng = np.random.default_rng(seed)
    C = np.c_[np.arange(n) * 15.0, (0 if line else 1) * rng.uniform(-20, 20, n), 80 + rng.normal(0, 1, n)]
    R = so3_exp(rng.normal(0, 0.05, (n, 3))) @ np.diag([1.0, -1.0, -1.0])
    X = np.c_[rng.uniform(0, 75, 50), rng.uniform(-20, 20, 50), rng.normal(0, 2, 50)]
    return R, C, X


def _model_frame(R, C, X, sim: Sim3):
    """The truth as a mapper sees it: moved by ``sim`` (world -> model)."""
    Rm = R @ sim.R.T
    return _State(Rm, sim.apply(C), sim.apply(X))


def _priors(R, C, attitude: bool):
    names = [f"{i}.png" for i in range(len(C))]
    pri = tuple(PosePrior(n, c, np.array([2.0, 2.0, 4.0]), r if attitude else None, 1.0 if attitude else None)
                for n, c, r in zip(names, C, R))
    return MapperPriors.from_priors(pri, names, 0.5)


SIM = Sim3(0.013, so3_exp(np.array([0.4, -1.1, 2.0])), np.array([3.0, -2.0, 0.5]))


@pytest.mark.parametrize("attitude", [True, False])
def test_place_recovers_the_priors_frame_exactly(attitude):
    R, C, X = _truth()
    st = _model_frame(R, C, X, SIM)
    hook = PriorHook(_priors(R, C, attitude))
    st.registered[[0, 1]] = True
    # two cameras: enough with attitude priors (rotation from them), not without
    assert hook.place(st) is attitude
    if not attitude:
        st.registered[:] = True
        assert hook.place(st)
    reg = st.registered
    assert np.abs(st.centers()[reg] - C[reg]).max() < 1e-8 and np.abs(st.R[reg] - R[reg]).max() < 1e-10
    assert np.abs(st.X - X).max() < 1e-8
    assert hook.gauge([0]) == []


def test_collinear_centres_without_attitude_wait():
    R, C, X = _truth(line=True)
    st = _model_frame(R, C, X, SIM)
    st.registered[:] = True
    hook = PriorHook(_priors(R, C, False))
    assert not hook.place(st) and hook.gauge([0]) == [0] and not hook.placed
    assert np.abs(st.centers() - SIM.apply(C)).max() < 1e-9  # untouched


def test_realign_takes_the_datum_step():
    """After placing, a map that drifted by a similarity is moved back onto the priors."""
    R, C, X = _truth()
    st = _model_frame(R, C, X, Sim3(1.0, np.eye(3), np.zeros(3)))
    st.registered[:] = True
    hook = PriorHook(_priors(R, C, True))
    assert hook.place(st)
    drift = Sim3(1.02, so3_exp(np.array([0.0, 0.01, 0.02])), np.array([1.0, 2.0, -3.0]))
    for i in range(len(C)):
        st.set_pose(i, drift.transform_pose(Rigid3(st.R[i], st.t[i])))
    assert np.abs(st.centers() - C).max() > 1.0
    hook.realign(st)
    assert np.abs(st.centers() - C).max() < 1e-8


def test_for_problem_gives_variable_cameras_their_priors():
    R, C, X = _truth()
    hook = PriorHook(_priors(R, C, True))

    class P:
        image_ids = np.array([2, 4, 5])         # map images 1, 3, 4
        cam_fixed = np.array([False, True, False])

    assert hook.for_problem(P()) is None         # not placed yet: no priors
    st = _model_frame(R, C, X, SIM)
    st.registered[:] = True
    hook.place(st)
    bp = hook.for_problem(P())
    assert list(bp.centres.cam) == [0, 2] and list(bp.attitudes.cam) == [0, 2]
    assert np.allclose(bp.centres.centre, C[[1, 4]]) and np.allclose(bp.attitudes.R, R[[1, 4]])
    assert np.allclose(bp.centres.sqrt_info[0], np.diag([0.5, 0.5, 0.25]))


@pytest.mark.slow
def test_mapper_with_priors_ends_at_the_georeferenced_optimum(uav_small_scene, tmp_path):
    """The mapped model is in the priors' frame with no Sim3 applied, and equals what the
    post-hoc georeferencing (similarity + priors BA) makes of it, to a millimetre."""
    import os

    from polarref.georef.adjust import georeference
    from polarref.georef.formats import load_georef
    from polarref.model.colmap import read_model
    from polarref.sfm.pipeline import PRESETS, run_sfm, with_ba
    from synth.uav import gcp_layout

    for name in ("images", "gt", "depth", "mesh.ply", "scene.json"):
        os.symlink(os.path.realpath(uav_small_scene / name), tmp_path / name)
    g, m, p = gcp_layout(tmp_path, 4, 4, 0.5, 0)
    gt = read_model(tmp_path / "gt")
    geo = load_georef(sorted(im.name for im in gt.images.values()), p, g, m)
    res = run_sfm(tmp_path / "images", None, with_ba(PRESETS["default"], "euclidean"), gt=gt,
                  priors=geo.priors)
    rec = res.reconstruction
    by = {im.name: im.cam_from_world.center for im in gt.images.values()}
    d = np.array([im.cam_from_world.center - by[im.name] for im in rec.images.values()])
    # priors 2 m / 4 m on 12 views: the datum is off by metres, not by an arbitrary similarity
    assert len(d) == 12 and np.sqrt((d**2).mean()) < 6.0
    post = copy.deepcopy(rec)
    georeference(post, geo, "euclidean", use_priors=True, use_control=False)
    diff = max(np.abs(post.images[i].cam_from_world.center - rec.images[i].cam_from_world.center).max()
               for i in rec.images)
    assert diff < 1e-3
