"""COLMAP's OPENCV model (radial + tangential): pycolmap agreement over random parameters,
Jacobians against central differences, round trips, the fold of the valid disc, phi."""

import numpy as np
import pytest

from polarref.camera import Camera, angular_from_ray, phi_sigma, ray_from_angular
from polarref.camera.opencv import distort

pycolmap = pytest.importorskip("pycolmap")


def random_camera(rng) -> Camera:
    f = rng.uniform(200, 3000)
    return Camera("OPENCV", 4000, 3000,
                  [f, f * rng.uniform(0.9, 1.1), rng.uniform(0, 2000), rng.uniform(0, 1500),
                   rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.1),
                   rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01)])


def random_points(rng, cam, n, frac):
    theta = rng.uniform(0, frac * cam.theta_max, n)
    return ray_from_angular(theta, rng.uniform(-np.pi, np.pi, n)) * rng.uniform(0.5, 10, (n, 1))


def rel(a, b):
    return np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)), axis=-1)


def test_matches_pycolmap_for_random_params_and_points():
    rng = np.random.default_rng(11)
    worst_fwd = worst_inv = 0.0
    ours_px, colmap_px = [], []
    for _ in range(40):
        cam = random_camera(rng)
        pc = cam.to_pycolmap()
        X = random_points(rng, cam, 500, 0.7)
        uv = cam.project(X)
        assert np.isfinite(uv).all()
        worst_fwd = max(worst_fwd, rel(uv, pc.img_from_cam(X)).max())
        ray = cam.unproject(uv)
        xy = ray[:, :2] / ray[:, 2:]
        xy_ref = pc.cam_from_img(uv)
        worst_inv = max(worst_inv, rel(xy, xy_ref).max())
        # which inverse is more exact, judged by pycolmap's own forward model
        ours_px.append(np.abs(pc.img_from_cam(np.c_[xy, np.ones(len(xy))]) - uv).max())
        colmap_px.append(np.abs(pc.img_from_cam(np.c_[xy_ref, np.ones(len(xy))]) - uv).max())
    print(f"OPENCV vs pycolmap: img_from_cam {worst_fwd:.2e}, cam_from_img {worst_inv:.2e} "
          f"(relative); reprojection of the inverse: ours {max(ours_px):.1e} px, "
          f"pycolmap {max(colmap_px):.1e} px")
    assert worst_fwd <= 1e-12
    assert worst_inv <= 1e-10
    # COLMAP stops its Newton iteration once the step is below 1e-5, so it is the less exact
    assert max(ours_px) <= 1e-9 < max(colmap_px)


def test_round_trips_and_jacobians_for_random_params():
    rng = np.random.default_rng(12)
    h = 1e-6
    for _ in range(10):
        cam = random_camera(rng)
        X = random_points(rng, cam, 100, 0.8)
        uv, J = cam.project_with_jacobian(X)
        ray = cam.unproject(uv)
        np.testing.assert_allclose(cam.project(ray * 3.0), uv, rtol=1e-13, atol=1e-9)
        np.testing.assert_allclose(ray, X / np.linalg.norm(X, axis=1, keepdims=True), atol=1e-12)
        theta, phi = cam.to_angular(uv)
        np.testing.assert_allclose(cam.from_angular(theta, phi), uv, rtol=1e-13, atol=1e-9)
        # the angles are the ray's, not the pixel's angle about the principal point
        t_ref, p_ref, _ = angular_from_ray(X)
        np.testing.assert_allclose(theta, t_ref, atol=1e-12)
        np.testing.assert_allclose(np.angle(np.exp(1j * (phi - p_ref))), 0, atol=1e-11)
        num = np.stack([(cam.project(X + e) - cam.project(X - e)) / (2 * h)
                        for e in np.eye(3) * h], -1)
        np.testing.assert_allclose(J, num, rtol=1e-6, atol=1e-6 * np.abs(num).max())
        Jp = cam.project_params_jacobian(X)
        P = cam.params
        for i in range(8):
            step = 1e-6 * max(abs(P[i]), 1e-3)
            Pp, Pm = P.copy(), P.copy()
            Pp[i] += step
            Pm[i] -= step
            num = (Camera("OPENCV", 4000, 3000, Pp).project(X)
                   - Camera("OPENCV", 4000, 3000, Pm).project(X)) / (2 * step)
            np.testing.assert_allclose(Jp[..., i], num, rtol=1e-6,
                                       atol=1e-6 * np.abs(num).max() + 1e-9)
            assert np.abs(Jp[..., i]).max() > 0


def test_fold_disc():
    # without tangential terms the valid field of view is RADIAL's, exactly
    radial = Camera("RADIAL", 640, 480, [500, 320, 240, -0.2, 0.01])
    same = Camera("OPENCV", 640, 480, [500, 500, 320, 240, -0.2, 0.01, 0, 0])
    assert same.theta_max == radial.theta_max < np.pi / 2
    # with them, the disc ends where the distortion Jacobian first becomes singular
    cam = Camera("OPENCV", 640, 480, [500, 500, 320, 240, -0.2, 0.01, 0.01, -0.02])
    ru = np.tan(cam.theta_max)
    alpha = np.linspace(-np.pi, np.pi, 20001)
    J = distort(ru * np.cos(alpha), ru * np.sin(alpha), cam.distortion)[2]
    det = np.linalg.det(J)
    assert det.min() == pytest.approx(0.0, abs=1e-5) and det.max() > 0.1
    inner = distort(0.999 * ru * np.cos(alpha), 0.999 * ru * np.sin(alpha), cam.distortion)[2]
    assert np.linalg.det(inner).min() > 0
    assert cam.theta_max < same.theta_max  # the tangential terms fold it earlier
    # beyond: NaN (or ValueError with strict), like every other model past its fold
    a = alpha[np.argmin(det)]
    X = np.array([[1.01 * ru * np.cos(a), 1.01 * ru * np.sin(a), 1.0],
                  [0.99 * ru * np.cos(a), 0.99 * ru * np.sin(a), 1.0]])
    uv = cam.project(X)
    assert np.isnan(uv[0]).all() and np.isfinite(uv[1]).all()
    with pytest.raises(ValueError, match="outside the model's valid range"):
        cam.project(X, strict=True)
    np.testing.assert_allclose(cam.unproject(uv[1]), X[1] / np.linalg.norm(X[1]), atol=1e-9)
    # a pixel far beyond the folded image has no preimage in the disc
    assert np.isnan(cam.unproject(cam.principal_point + [50 * 500, 0])).all()


def test_pycolmap_round_trip_and_phi_sigma():
    cam = Camera("OPENCV", 640, 480, [500, 520, 320, 240, -0.1, 0.02, 0.004, -0.006])
    back = Camera.from_pycolmap(cam.to_pycolmap(camera_id=3))
    assert back == cam and cam.to_pycolmap(camera_id=3).camera_id == 3
    assert cam.is_perspective and cam.distortion == (-0.1, 0.02, 0.004, -0.006)
    half = cam.rescaled(0.5)
    X = np.array([[0.3, -0.2, 1.0], [-0.5, 0.4, 2.0]])
    np.testing.assert_allclose(half.project(X), 0.5 * cam.project(X), atol=1e-12)
    # phi's first-order sigma is the norm of its Jacobian row (tangential terms included)
    uv = cam.project(X)
    J = cam.to_angular_jacobian(uv)
    np.testing.assert_allclose(phi_sigma(cam, uv, 0.7), 0.7 * np.linalg.norm(J[:, 1], axis=-1),
                               rtol=1e-12)
