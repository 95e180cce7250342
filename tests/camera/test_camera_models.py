"""Camera models: pycolmap agreement, closed forms, round trips, Jacobians, bad input."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polarref.camera import MODELS, Camera, angular_from_ray, ray_from_angular

FAMILY_R = {  # the paper's closed forms, r / f as a function of theta
    "PERSPECTIVE": np.tan,
    "SIMPLE_PINHOLE": np.tan,
    "EQUIDISTANT": lambda t: t,
    "SIMPLE_FISHEYE": lambda t: t,
    "STEREOGRAPHIC": lambda t: 2 * np.tan(t / 2),
    "EQUISOLID": lambda t: 2 * np.sin(t / 2),
    "ORTHOGRAPHIC": np.sin,
}

EXAMPLES = {
    "SIMPLE_PINHOLE": [500.0, 320.0, 240.0],
    "PINHOLE": [500.0, 520.0, 320.0, 240.0],
    "SIMPLE_RADIAL": [500.0, 320.0, 240.0, -0.1],
    "RADIAL": [500.0, 320.0, 240.0, -0.1, 0.02],
    "OPENCV": [500.0, 520.0, 320.0, 240.0, -0.1, 0.02, 0.001, -0.002],
    "OPENCV_FISHEYE": [300.0, 310.0, 320.0, 240.0, 0.05, -0.01, 0.002, -0.0003],
    "SIMPLE_FISHEYE": [300.0, 320.0, 240.0],
    "FISHEYE": [300.0, 310.0, 320.0, 240.0],
    "PERSPECTIVE": [500.0, 320.0, 240.0],
    "EQUIDISTANT": [300.0, 320.0, 240.0],
    "STEREOGRAPHIC": [250.0, 320.0, 240.0],
    "EQUISOLID": [280.0, 320.0, 240.0],
    "ORTHOGRAPHIC": [260.0, 320.0, 240.0],
}


def cam(model):
    return Camera(model, 640, 480, EXAMPLES[model])


def fd(fun, x, h):
    """Central finite differences of fun: (..., n) -> (..., m); returns (..., m, n)."""
    cols = []
    for i in range(x.shape[-1]):
        e = np.zeros(x.shape[-1])
        e[i] = h
        cols.append((fun(x + e) - fun(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


def random_rays(rng, camera, n, frac=0.9):
    theta = rng.uniform(0, frac * min(camera.theta_max, 0.9 * np.pi), n)
    phi = rng.uniform(-np.pi, np.pi, n)
    return theta, phi


def test_every_model_has_an_example():
    assert set(EXAMPLES) == set(MODELS)


@pytest.mark.parametrize("model", [m for m in MODELS if MODELS[m].colmap])
def test_matches_pycolmap(model):
    camera = cam(model)
    pc = camera.to_pycolmap()
    rng = np.random.default_rng(1)
    X = rng.normal(size=(2000, 3))
    X[:, 2] = np.abs(X[:, 2]) + 0.3  # COLMAP rejects z <= 0
    uv = camera.project(X)
    uv_ref = pc.img_from_cam(X)
    ok = np.isfinite(uv[:, 0])
    assert ok.mean() > 0.6
    scale = np.maximum(1.0, np.abs(uv_ref[ok]))
    assert np.max(np.abs(uv[ok] - uv_ref[ok]) / scale) < 1e-12
    ray_ref = pc.cam_ray_from_img(uv[ok])
    assert np.max(np.abs(camera.unproject(uv[ok]) - ray_ref)) < 1e-8  # COLMAP iterates to ~1e-10
    np.testing.assert_allclose(camera.calibration_matrix(), pc.calibration_matrix(), rtol=0, atol=0)


@pytest.mark.parametrize("model", sorted(FAMILY_R))
def test_family_closed_forms(model):
    camera = cam(model)
    theta = np.linspace(0, 0.95 * min(camera.theta_max, 0.95 * np.pi), 50)
    phi = np.linspace(-3, 3, 50)
    uv = camera.from_angular(theta, phi)
    r = np.hypot(*(uv - camera.principal_point).T)
    np.testing.assert_allclose(r, camera.fx * FAMILY_R[model](theta), rtol=1e-13, atol=1e-9)
    # the angle around the principal point, from +x (right) toward +y (down)
    ang = np.arctan2(uv[1:, 1] - camera.principal_point[1], uv[1:, 0] - camera.principal_point[0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (ang - phi[1:]))), 0, atol=1e-12)


def test_phi_sense_and_theta_on_image():
    camera = cam("PINHOLE")
    # a ray toward image-down (+y camera) has phi = +pi/2 and lands below the principal point
    theta, phi = camera.to_angular(camera.project(np.array([0.0, 0.3, 1.0])))
    assert phi == pytest.approx(np.pi / 2, abs=1e-14) and theta == pytest.approx(np.arctan(0.3))
    assert camera.from_angular(0.2, np.pi / 2)[1] > camera.principal_point[1]
    assert camera.from_angular(0.2, 0.0)[0] > camera.principal_point[0]


@pytest.mark.parametrize("model", list(MODELS))
def test_project_jacobian_fd(model):
    camera = cam(model)
    rng = np.random.default_rng(2)
    theta, phi = random_rays(rng, camera, 200, 0.8)
    X = ray_from_angular(theta, phi) * rng.uniform(0.5, 5, (200, 1))
    uv, J = camera.project_with_jacobian(X)
    assert np.isfinite(J).all()
    Jn = fd(camera.project, X, 1e-6)
    np.testing.assert_allclose(J, Jn, rtol=1e-6, atol=1e-6 * np.abs(Jn).max())
    np.testing.assert_allclose(camera.project(X), uv, rtol=0, atol=0)


@pytest.mark.parametrize("model", list(MODELS))
def test_params_jacobian_fd(model):
    camera = cam(model)
    rng = np.random.default_rng(5)
    theta, phi = random_rays(rng, camera, 100, 0.8)
    X = ray_from_angular(theta, phi) * rng.uniform(0.5, 5, (100, 1))
    X[0] = [0.0, 0.0, 2.0]  # on the axis
    J = camera.project_params_jacobian(X)
    assert J.shape == (100, 2, len(camera.params)) and np.isfinite(J).all()

    def with_params(p):
        return np.stack([Camera(model, 640, 480, q).project(X) for q in p], 0)

    P = camera.params
    h = 1e-6 * np.maximum(np.abs(P), 1e-3)
    for i in range(len(P)):
        e = np.zeros(len(P))
        e[i] = h[i]
        num = (with_params([P + e])[0] - with_params([P - e])[0]) / (2 * h[i])
        np.testing.assert_allclose(J[..., i], num, rtol=1e-6, atol=1e-6 * np.abs(num).max() + 1e-9)


@pytest.mark.parametrize("model", list(MODELS))
def test_on_axis_jacobian_is_the_limit(model):
    camera = cam(model)
    Z = 2.0
    uv, J = camera.project_with_jacobian(np.array([0.0, 0.0, Z]))
    np.testing.assert_allclose(uv, camera.principal_point, atol=1e-12)
    expected = np.array([[camera.fx / Z, 0, 0], [0, camera.fy / Z, 0]])
    np.testing.assert_allclose(J, expected, atol=1e-12)
    # continuity: a hair off the axis the Jacobian is (nearly) the same
    J2 = camera.project_jacobian(np.array([1e-9, -2e-9, Z]))
    np.testing.assert_allclose(J2, expected, rtol=1e-7, atol=1e-6)


@pytest.mark.parametrize("model", list(MODELS))
def test_angular_jacobians_fd(model):
    camera = cam(model)
    rng = np.random.default_rng(3)
    theta, phi = random_rays(rng, camera, 200, 0.8)
    theta = np.maximum(theta, 0.02)
    uv = camera.from_angular(theta, phi)
    Ja = camera.to_angular_jacobian(uv)
    to_ang = lambda p: np.stack(camera.to_angular(p), -1)  # noqa: E731
    np.testing.assert_allclose(Ja, fd(to_ang, uv, 1e-5), rtol=1e-6, atol=1e-9)
    Jf = camera.from_angular_jacobian(theta, phi)
    from_ang = lambda a: camera.from_angular(a[..., 0], a[..., 1])  # noqa: E731
    Jfn = fd(from_ang, np.stack([theta, phi], -1), 1e-7)
    np.testing.assert_allclose(Jf, Jfn, rtol=1e-6, atol=1e-5)
    # the two Jacobians are inverse to each other
    np.testing.assert_allclose(Ja @ Jf, np.broadcast_to(np.eye(2), Ja.shape), atol=1e-9)
    Ju = camera.unproject_jacobian(uv)
    np.testing.assert_allclose(Ju, fd(camera.unproject, uv, 1e-5), rtol=1e-6, atol=1e-10)


@pytest.mark.parametrize("model", list(MODELS))
def test_view_angle_with_gradient_is_the_first_angular_row(model):
    """The polar BA's lean set-up path: theta and theta_D_uv bitwise as the full angular
    Jacobian's first row, NaN at the principal point and beyond the reachable radius; the
    gradient against finite differences of theta."""
    camera = cam(model)
    rng = np.random.default_rng(5)
    theta, phi = random_rays(rng, camera, 300, 0.8)
    uv = np.concatenate([camera.from_angular(np.maximum(theta, 0.02), phi),
                         [camera.principal_point, [1e7, -1e7]]])
    th, g = camera.view_angle_with_gradient(uv)
    ang, J = camera.to_angular_with_jacobian(uv)
    assert th.shape == (len(uv),) and g.shape == (len(uv), 2)
    np.testing.assert_array_equal(th, ang[:, 0])
    np.testing.assert_array_equal(g, J[:, 0, :])
    assert np.isnan(g[-2]).all()
    theta_of = lambda p: camera.to_angular(p)[0][..., None]  # noqa: E731
    np.testing.assert_allclose(g[:-2], fd(theta_of, uv[:-2], 1e-5)[:, 0, :], rtol=1e-6, atol=1e-9)


def test_unproject_jacobian_at_principal_point():
    for model in MODELS:
        camera = cam(model)
        J = camera.unproject_jacobian(camera.principal_point)
        expected = np.array([[1 / camera.fx, 0], [0, 1 / camera.fy], [0, 0]])
        np.testing.assert_allclose(J, expected, atol=1e-15)
        assert np.isnan(camera.to_angular_jacobian(camera.principal_point)).all()


def test_angular_from_ray_jacobian_fd():
    rng = np.random.default_rng(4)
    X = rng.normal(size=(100, 3))
    theta, phi, J = angular_from_ray(X)
    np.testing.assert_allclose(ray_from_angular(theta, phi),
                               X / np.linalg.norm(X, axis=1, keepdims=True), atol=1e-15)
    f = lambda x: np.stack(angular_from_ray(x)[:2], -1)  # noqa: E731
    np.testing.assert_allclose(J, fd(f, X, 1e-6), rtol=1e-6, atol=1e-8)
    assert np.isnan(angular_from_ray(np.array([0.0, 0.0, 1.0]))[2]).all()
    assert np.isnan(angular_from_ray(np.zeros(3))[0])


# ---- hypothesis round trips ----------------------------------------------------------------

def params_strategy(model):
    f = st.floats(50, 3000)
    c = st.floats(0, 2000)
    small = {"SIMPLE_RADIAL": [st.floats(-0.3, 0.3)],
             "RADIAL": [st.floats(-0.3, 0.3), st.floats(-0.1, 0.1)],
             "OPENCV": [st.floats(-0.3, 0.3), st.floats(-0.1, 0.1),
                        st.floats(-0.01, 0.01), st.floats(-0.01, 0.01)],
             "OPENCV_FISHEYE": [st.floats(-0.1, 0.1), st.floats(-0.03, 0.03),
                                st.floats(-0.01, 0.01), st.floats(-0.003, 0.003)]}
    spec = MODELS[model]
    focals = [f, f] if spec.fy != spec.fx else [f]
    return st.tuples(*focals, c, c, *small.get(model, []))


@pytest.mark.parametrize("model", list(MODELS))
@settings(max_examples=80, deadline=None)
@given(data=st.data())
def test_round_trips(model, data):
    params = data.draw(params_strategy(model))
    camera = Camera(model, 4000, 3000, params)
    seed = data.draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    theta, phi = random_rays(rng, camera, 64, 0.9)
    uv = camera.from_angular(theta, phi)
    assert np.isfinite(uv).all()
    # 1e-9 px within 10 image sizes of the principal point (the usable field of view); beyond
    # (rays near a perspective model's 90 degrees land at 1e5+ px) 1e-9 px per 4e4 px of radius
    radius = np.linalg.norm(uv - camera.principal_point, axis=-1)
    tol = 1e-9 * np.maximum(1.0, radius / 4e4)[:, None]
    # pixel -> angular -> pixel
    t2, p2 = camera.to_angular(uv)
    assert np.all(np.abs(camera.from_angular(t2, p2) - uv) <= tol)
    assert np.max(np.abs(t2 - theta)) < 1e-10
    # theta equals the angle between unproject(uv) and +z; rays are unit
    ray = camera.unproject(uv)
    np.testing.assert_allclose(np.linalg.norm(ray, axis=-1), 1, atol=1e-14)
    np.testing.assert_allclose(np.arctan2(np.hypot(ray[:, 0], ray[:, 1]), ray[:, 2]), t2,
                               atol=1e-12)
    # project(unproject(uv)) == uv, for any positive depth
    depth = rng.uniform(0.1, 100, (64, 1))
    assert np.all(np.abs(camera.project(ray * depth) - uv) <= tol)


# ---- field of view and bad input ------------------------------------------------------------

@pytest.mark.parametrize("model", list(MODELS))
def test_out_of_fov_is_nan_or_raises(model):
    camera = cam(model)
    tm = camera.theta_max
    beyond = min(tm + 0.05, np.pi)
    X = ray_from_angular(np.array([0.3, beyond]), np.array([0.1, 0.1]))
    if beyond == np.pi and tm == np.pi:
        X[1] = [0.0, 0.0, -1.0]
    uv, J = camera.project_with_jacobian(X)
    assert np.isfinite(uv[0]).all() and np.isnan(uv[1]).all() and np.isnan(J[1]).all()
    with pytest.raises(ValueError, match="outside the model's valid range"):
        camera.project(X, strict=True)
    assert np.isnan(camera.from_angular(beyond, 0.1)).all()
    assert np.isnan(camera.from_angular(-0.1, 0.1)).all()
    with pytest.raises(ValueError):
        camera.from_angular([0.1, beyond], 0.0, strict=True)
    assert np.isnan(camera.project(np.zeros(3))).all()


def test_unreachable_pixels_are_nan():
    ortho = cam("ORTHOGRAPHIC")  # r = f sin(theta) cannot exceed f
    uv = ortho.principal_point + [1.01 * ortho.fx, 0]
    assert np.isnan(ortho.unproject(uv)).all() and np.isnan(ortho.to_angular(uv)[0])
    with pytest.raises(ValueError):
        ortho.to_angular(uv, strict=True)
    radial = Camera("SIMPLE_RADIAL", 640, 480, [500, 320, 240, -0.2])
    # D(r) = r (1 - 0.2 r^2) folds at r^2 = 1/0.6; its maximum is unreachable beyond
    rd_max = np.sqrt(1 / 0.6) * (1 - 0.2 / 0.6)
    assert radial.theta_max == pytest.approx(np.arctan(np.sqrt(1 / 0.6)), rel=1e-12)
    assert np.isnan(radial.unproject([320 + 500 * rd_max * 1.001, 240])).all()
    assert np.isfinite(radial.unproject([320 + 500 * rd_max * 0.999, 240])).all()


@pytest.mark.parametrize("kwargs, match", [
    (dict(model="NOPE", width=10, height=10, params=[1, 2, 3]), "unknown camera model"),
    (dict(model="PINHOLE", width=10, height=10, params=[1, 2, 3]), "takes 4 params"),
    (dict(model="SIMPLE_PINHOLE", width=10, height=10, params=[-5, 2, 3]), "focal length must be > 0"),
    (dict(model="PINHOLE", width=10, height=10, params=[5, 0, 2, 3]), "focal length must be > 0"),
    (dict(model="SIMPLE_PINHOLE", width=0, height=10, params=[5, 2, 3]), "width"),
    (dict(model="SIMPLE_PINHOLE", width=10, height=2.5, params=[5, 2, 3]), "height"),
    (dict(model="SIMPLE_PINHOLE", width=10, height=10, params=[5, np.nan, 3]), "finite"),
])
def test_bad_construction(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Camera(**kwargs)


def test_frozen_value_semantics_and_shapes():
    camera = cam("PINHOLE")
    with pytest.raises(ValueError):
        camera.params[0] = 3.0  # read-only
    with pytest.raises(AttributeError):
        camera.model = "SIMPLE_PINHOLE"
    assert camera == Camera("PINHOLE", 640, 480, tuple(EXAMPLES["PINHOLE"]))
    assert hash(camera) == hash(Camera("PINHOLE", 640, 480, EXAMPLES["PINHOLE"]))
    assert camera != cam("SIMPLE_PINHOLE")
    assert camera.project(np.ones((4, 5, 3))).shape == (4, 5, 2)
    assert camera.project_jacobian(np.ones((4, 5, 3))).shape == (4, 5, 2, 3)
    assert camera.unproject_jacobian(np.ones((7, 2))).shape == (7, 3, 2)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        camera.project(np.ones((4, 2)))


def test_pycolmap_conversions():
    for model in ("PERSPECTIVE", "EQUIDISTANT"):
        pc = cam(model).to_pycolmap(camera_id=7)
        assert pc.camera_id == 7
        back = Camera.from_pycolmap(pc)
        assert back.model == MODELS[model].colmap and np.array_equal(back.params, cam(model).params)
    with pytest.raises(ValueError, match="COLMAP has no model"):
        cam("STEREOGRAPHIC").to_pycolmap()
    import pycolmap
    with pytest.raises(ValueError, match="not supported"):
        Camera.from_pycolmap(pycolmap.Camera(model="FULL_OPENCV", width=10, height=10,
                                             params=[5, 5, 5, 5] + [0] * 8))


def test_rescaled_matches_resized_image():
    camera = cam("OPENCV_FISHEYE")
    half = camera.rescaled(0.5)
    X = ray_from_angular(np.array([0.4, 1.0]), np.array([0.3, -2.0]))
    np.testing.assert_allclose(half.project(X), 0.5 * camera.project(X), atol=1e-12)
    assert (half.width, half.height) == (320, 240)


def test_fold_found_with_badly_scaled_coefficients():
    # regression (hypothesis): k4 ~ 1e-38 beside k1 ~ -0.06 hid the fold from np.roots
    camera = Camera("OPENCV_FISHEYE", 4000, 3000,
                    [50, 50, 0, 0, -0.0625, 0, 6.103515625e-05, 1.1754943508222875e-38])
    k1, k3 = -0.0625, 6.103515625e-05
    # p'(t) = 1 + 3 k1 t^2 + 7 k3 t^6 (k4 negligible): check it vanishes at theta_max
    t = camera.theta_max
    assert 2.0 < t < 2.6 and abs(1 + 3 * k1 * t**2 + 7 * k3 * t**6) < 1e-12
    theta = np.linspace(0, 0.99 * t, 2001)
    uv = camera.from_angular(theta, np.zeros_like(theta))
    np.testing.assert_allclose(camera.to_angular(uv)[0], theta, atol=1e-10)


def test_fisheye_inverse_does_not_ping_pong_near_the_fold():
    # Hypothesis found it: theta_d(theta) is monotonic up to theta_max (2.4505 rad) but its
    # inflection made unguarded Newton alternate between the bracket's ends and stop 0.35 rad off
    camera = Camera("OPENCV_FISHEYE", 4000, 3000,
                    [50.0, 50.0, 0.0, 0.0, 0.0, 0.0243328, -0.00355402, 0.0])
    assert 2.45 < camera.theta_max < 2.451
    theta, phi = random_rays(np.random.default_rng(165247), camera, 64, 0.9)
    uv = camera.from_angular(theta, phi)
    t2, p2 = camera.to_angular(uv)
    assert np.max(np.abs(t2 - theta)) < 1e-10
    assert np.max(np.abs(camera.from_angular(t2, p2) - uv)) < 1e-9
