"""The data model: Observations validation, the one flat-arrays builder, the one reprojection
rule, the Parameterization Protocol and registry, the pycolmap option builders."""

import copy

import numpy as np
import pytest

from polarref.ba import BAOptions
from polarref.ba.adapter import problem_from_reconstruction, problem_to_reconstruction
from polarref.ba.parameterization import (FORMS, PARAMS, SFM_BA_NAMES, AnchoredJacobians,
                                          BoundedPoints, Parameterization, Staged, form_class,
                                          make_param)
from polarref.ba.problem import prepare
from polarref.ba.synthetic import synthetic_reconstruction
from polarref.camera import Camera
from polarref.core.geometry import Rigid3
from polarref.model import (Image, Observations, ObservationsError, Point3D, Reconstruction,
                            build_reconstruction)
from polarref.model.colmap import from_pycolmap, read_model, to_pycolmap


def _obs(m=6):
    return Observations.from_arrays(np.arange(m) % 3, np.arange(m) // 2, np.arange(2.0 * m).reshape(m, 2))


# ---- Observations ------------------------------------------------------------------------------
def test_observations_accept_good_arrays_and_coerce_types():
    o = Observations.from_arrays([0, 1, 2], np.array([0.0, 0.0, 1.0]), [[1, 2], [3, 4], [5, 6]])
    assert o.image.dtype == np.int64 and o.point.dtype == np.int64 and o.uv.dtype == np.float64
    assert o.validate(num_images=3, num_points=2) is o and len(o) == 3


@pytest.mark.parametrize("image, point, uv, match", [
    ([0, 1], [0], [[0, 0], [1, 1]], "lengths differ"),
    ([0, 1], [0, 1], [0, 0, 1, 1], "expected"),
    ([[0, 1]], [0, 1], [[0, 0], [1, 1]], "expected"),
    ([0, 1], [0, 1], [[0, 0, 0], [1, 1, 1]], "expected"),
    ([0, 1.5], [0, 1], [[0, 0], [1, 1]], "not integers"),
    ([0, np.nan], [0, 1], [[0, 0], [1, 1]], "not integers"),
])
def test_observations_reject_bad_shapes_and_indices(image, point, uv, match):
    with pytest.raises(ObservationsError, match=match):
        Observations.from_arrays(image, point, uv)


@pytest.mark.parametrize("mutate, kwargs, match", [
    (lambda o: o.uv.__setitem__((2, 1), np.nan), {}, "observation 2: non-finite pixel"),
    (lambda o: o.uv.__setitem__((4, 0), np.inf), {}, "observation 4: non-finite pixel"),
    (lambda o: o.image.__setitem__(3, 3), {"num_images": 3}, "observation 3: image index 3 out of range 0..2"),
    (lambda o: o.point.__setitem__(5, 9), {"num_points": 3}, "observation 5: point index 9 out of range"),
    (lambda o: o.point.__setitem__(1, -1), {}, "observation 1: negative point index"),
])
def test_observations_validate_names_the_first_bad_observation(mutate, kwargs, match):
    o = _obs()
    o.validate(num_images=3, num_points=3)  # valid before the mutation
    mutate(o)
    with pytest.raises(ObservationsError, match=match):
        o.validate(**{"num_images": 3, "num_points": 3, **kwargs})


def test_nonfinite_pixels_allowed_when_asked():
    o = _obs()
    o.uv[0] = np.nan
    assert o.validate(3, 3, finite=False) is o


def test_observation_selection_helpers_against_brute_force():
    rng = np.random.default_rng(3)
    o = Observations.from_arrays(rng.integers(0, 4, 40), rng.integers(0, 7, 40), rng.normal(size=(40, 2)))
    mask = rng.random(40) < 0.5
    s = o.select(mask)
    assert np.array_equal(s.uv, o.uv[mask]) and np.array_equal(s.image, o.image[mask])
    assert np.array_equal(o.of_image(2), [k for k in range(40) if o.image[k] == 2])
    assert np.array_equal(o.of_point(5), [k for k in range(40) if o.point[k] == 5])
    slot = o.slot_in_image(4)
    for k in range(40):
        assert slot[k] == sum(o.image[q] == o.image[k] for q in range(k))
    order = o.order_by_point()
    keys = list(zip(o.point[order], o.image[order]))
    assert keys == sorted(keys)
    assert o == o.copy() and o != s


# ---- the one builder ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def synthetic():
    init, _truth = synthetic_reconstruction(5, 60, seed=4)
    return init


def test_problem_round_trips_through_the_builder(synthetic):
    p = prepare(problem_from_reconstruction(copy.deepcopy(synthetic)))
    rec = problem_to_reconstruction(p)
    q = prepare(problem_from_reconstruction(rec))
    assert q.obs == p.obs
    np.testing.assert_array_equal(q.X, p.X)
    np.testing.assert_array_equal(q.R, p.R)
    np.testing.assert_allclose(q.C, p.C, rtol=0, atol=1e-12)
    assert [c == d for c, d in zip(q.cameras, p.cameras)] == [True] * p.num_cameras


def test_shared_cameras_give_one_camera_per_group(synthetic):
    p = prepare(problem_from_reconstruction(copy.deepcopy(synthetic)))
    rec = problem_to_reconstruction(p, shared_cameras=True)
    assert len(rec.cameras) == len(set(p.cameras)) == 1
    assert {im.camera_id for im in rec.images.values()} == {1}


def test_builder_layout_by_hand():
    cam = Camera("PINHOLE", 100, 80, [90.0, 90.0, 50.0, 40.0])
    obs = Observations.from_arrays([1, 0, 1, 0], [0, 0, 1, 1], [[1, 1], [2, 2], [3, 3], [4, 4]])
    rec = build_reconstruction([cam], [0, 0], [Rigid3.identity()] * 2, ["a", "b"], obs,
                               np.array([[0, 0, 5.0], [1, 0, 5.0]]))
    assert rec.images[2].keypoints.tolist() == [[1, 1], [3, 3]]  # image 1's observations, in order
    assert rec.images[1].point3D_ids.tolist() == [1, 2]
    assert rec.points3D[1].track.tolist() == [[2, 0], [1, 0]]
    assert rec.points3D[2].track.tolist() == [[2, 1], [1, 1]]
    with pytest.raises(ObservationsError, match="point index 2 out of range"):
        build_reconstruction([cam], [0, 0], [Rigid3.identity()] * 2, ["a", "b"],
                             Observations.from_arrays([0], [2], [[0, 0]]), np.zeros((2, 3)))


def test_io_problem_round_trips(shared_data):
    """PVL-BA problem -> Reconstruction (the builder) -> BA problem: same observations."""
    from polarref.io.pvlba import read_blocks_exchange

    p = read_blocks_exchange(shared_data / "pvl_ba_bench_sample" / "sample_at.xml")
    rec = p.to_reconstruction()
    q = problem_from_reconstruction(rec)
    img = q.image_ids[q.obs.image] - 1  # back to the reader's 0-based indices
    pt = q.point_ids[q.obs.point] - 1
    a = sorted(zip(p.obs.image, p.obs.point, map(tuple, p.obs.uv)))
    b = sorted(zip(img, pt, map(tuple, q.obs.uv)))
    assert a == b and len(a) == 105
    np.testing.assert_array_equal(q.X, p.points[q.point_ids - 1])


# ---- one reprojection rule ---------------------------------------------------------------------
def test_behind_camera_is_inf_in_both_entry_points():
    from polarref.metrics import observation_errors

    cam = Camera("PINHOLE", 100, 80, [90.0, 90.0, 50.0, 40.0])
    rec = Reconstruction(cameras={1: cam})
    X = np.array([[0.1, 0.0, 4.0], [0.0, 0.2, -3.0], [0.3, 0.1, 2.0]])
    uv = cam.project(X)
    uv[1] = [10.0, 10.0]
    rec.images[1] = Image(1, "a", 1, Rigid3.identity(), uv + [[0.5, 0.0], [0, 0], [0, 0]])
    for j in (2, 0, 1):  # inserted out of id order: the order is by sorted point id
        rec.points3D[j + 1] = Point3D(X[j], np.array([[1, j]]))
    errs, pidx = observation_errors(rec)
    np.testing.assert_allclose(errs, [0.5, np.inf, 0.0], atol=1e-12)
    assert pidx.tolist() == [0, 1, 2]
    np.testing.assert_array_equal(rec.reprojection_errors(), errs)


# ---- cameras -----------------------------------------------------------------------------------
def test_foreign_camera_types_are_refused(tmp_path):
    from synth.scene import PinholeCamera

    pin = PinholeCamera(64, 48, np.array([50.0, 50.0, 32.0, 24.0]))
    with pytest.raises(TypeError, match="PinholeCamera"):
        Reconstruction(cameras={1: pin}).write_text(tmp_path / "x")


def test_synth_ground_truth_holds_polarref_cameras(tmp_path):
    from synth.scene import PinholeCamera, write_gt

    pin = PinholeCamera(64, 48, np.array([50.0, 51.0, 32.0, 24.0]))
    write_gt(tmp_path, pin, ["a.png"], [Rigid3.identity()])
    back = read_model(tmp_path / "gt")
    assert back.cameras[1] == Camera("PINHOLE", 64, 48, [50.0, 51.0, 32.0, 24.0])
    text = (tmp_path / "gt" / "cameras.txt").read_text().splitlines()[1]
    assert text == "1 PINHOLE 64 48 50.0 51.0 32.0 24.0"


# ---- parameterizations -------------------------------------------------------------------------
@pytest.mark.parametrize("name", PARAMS)
def test_every_registered_form_satisfies_the_protocol(synthetic, name):
    p = prepare(problem_from_reconstruction(copy.deepcopy(synthetic)))
    prm = make_param(p, BAOptions(param=name))
    assert isinstance(prm, Parameterization) and prm.name == name
    assert type(prm) is form_class(name)
    assert isinstance(prm, BoundedPoints) == (name != "euclidean")
    assert isinstance(prm, Staged) == (name == "angular")
    assert isinstance(prm, AnchoredJacobians) == (name != "euclidean")


def test_protocol_rejects_an_incomplete_form(synthetic):
    p = prepare(problem_from_reconstruction(copy.deepcopy(synthetic)))
    prm = make_param(p, BAOptions(param="euclidean"))

    class NoStore:
        name, k, groups, slot_cams, slot_cols = prm.name, prm.k, prm.groups, prm.slot_cams, prm.slot_cols
        init_points, evaluate, pixel_residuals, retract_points = (
            prm.init_points, prm.evaluate, prm.pixel_residuals, prm.retract_points)

    assert not isinstance(NoStore(), Parameterization)
    with pytest.raises(ValueError, match="choose euclidean, parallax, polar, angular"):
        form_class("xyz")


def test_one_registry_of_form_names():
    from polarref.ba.options import PARAMS as option_params
    from polarref.compare.run.methods import BA_PARAMS
    from polarref.sfm.bundle import BA_NAMES

    assert PARAMS == tuple(FORMS) == option_params
    assert tuple(BA_PARAMS) == PARAMS
    assert tuple(BA_NAMES) == SFM_BA_NAMES


# ---- pycolmap option builders ------------------------------------------------------------------
@pytest.mark.parametrize("loss, scale", [("trivial", 1.0), ("huber", 2.5), ("cauchy", 0.7)])
def test_bundle_adjustment_options_carry_loss_scale_and_stopping_rules(loss, scale):
    import pycolmap

    from polarref.model.colmap import CeresSettings, bundle_adjustment_options

    cs = CeresSettings("t", 1e-7, 1e-9, 1e-8, 17, 2, 1)
    o = bundle_adjustment_options(cs, loss, scale, ("focal",))
    assert o.ceres.loss_function_type == getattr(pycolmap.LossFunctionType, loss.upper())
    assert o.ceres.loss_function_scale == scale
    so = o.ceres.solver_options
    assert (so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance) == (1e-7, 1e-9, 1e-8)
    assert (so.max_num_iterations, so.num_threads) == (17, 2)
    assert o.ceres.min_num_residuals_for_cpu_multi_threading == 1
    assert o.refine_focal_length and not o.refine_principal_point and not o.refine_extra_params
    with pytest.raises(ValueError, match="unknown loss"):
        bundle_adjustment_options(cs, "tukey")


def test_pycolmap_round_trip_keeps_ids_and_poses(synthetic):
    rec = synthetic
    back = from_pycolmap(to_pycolmap(rec))
    assert sorted(back.images) == sorted(rec.images) and sorted(back.points3D) == sorted(rec.points3D)
    for i, im in rec.images.items():
        np.testing.assert_allclose(back.images[i].cam_from_world.R, im.cam_from_world.R, atol=1e-12)
        np.testing.assert_allclose(back.images[i].cam_from_world.t, im.cam_from_world.t, atol=1e-12)
    np.testing.assert_allclose(back.reprojection_errors(), rec.reprojection_errors(), atol=1e-9)


def test_flat_observations_mark_unknown_images_and_keypoints():
    cam = Camera("PINHOLE", 100, 80, [90.0, 90.0, 50.0, 40.0])
    rec = Reconstruction(cameras={1: cam})
    X = np.array([[0.1, 0.0, 4.0], [0.0, 0.2, 3.0]])
    for i in (3, 7):
        rec.images[i] = Image(i, f"{i}", 1, Rigid3.identity(), cam.project(X))
    rec.points3D[5] = Point3D(X[1], np.array([[7, 1], [9, 0], [3, 1]]))  # image 9 is not registered
    rec.points3D[2] = Point3D(X[0], np.array([[3, 0], [7, 4]]))          # keypoint 4 does not exist
    obs, image_ids, pids = rec.flat_observations()
    assert image_ids.tolist() == [3, 7] and pids.tolist() == [2, 5]
    assert obs.image.tolist() == [0, 1, 1, -1, 0] and obs.point.tolist() == [0, 0, 1, 1, 1]
    assert np.isnan(obs.uv[[1, 3]]).all() and np.isfinite(obs.uv[[0, 2, 4]]).all()
    errs, pidx = rec.observation_errors()
    np.testing.assert_allclose(errs, [0, np.inf, 0, np.inf, 0], atol=1e-12)
    p = problem_from_reconstruction(rec)
    assert p.exclusions["observations_unknown_image"] == 1
