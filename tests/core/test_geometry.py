import numpy as np
import pytest

from polarref.core.geometry import (Rigid3, quat_from_rotmat, rotation_angle_deg, rotmat_from_quat,
                               skew, so3_exp, so3_log, umeyama)


def random_rotvecs(rng, n, max_angle=np.pi - 1e-6):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(n, 1))


def test_so3_exp_log_roundtrip_including_tiny_angles():
    rng = np.random.default_rng(0)
    v = random_rotvecs(rng, 20000)
    v[:100] *= 1e-9
    R = so3_exp(v)
    assert np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max() < 1e-14
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-14)
    assert np.abs(so3_log(R) - v).max() < 1e-12


def test_so3_exp_matches_independent_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    v = random_rotvecs(rng, 1000)
    assert np.abs(so3_exp(v) - Rotation.from_rotvec(v).as_matrix()).max() < 1e-14


def test_log_near_pi_gives_same_rotation():
    rng = np.random.default_rng(2)
    v = random_rotvecs(rng, 100)
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * (np.pi - 1e-10)
    R = so3_exp(v)
    assert np.abs(so3_exp(so3_log(R)) - R).max() < 1e-12


def test_quaternion_roundtrip_and_skew():
    rng = np.random.default_rng(3)
    R = so3_exp(random_rotvecs(rng, 500))
    q = quat_from_rotmat(R)
    assert (q[:, 0] >= 0).all()
    assert np.abs(rotmat_from_quat(q) - R).max() < 1e-14
    a, b = rng.normal(size=(2, 50, 3))
    assert np.abs(skew(a) @ b[..., None] - np.cross(a, b)[..., None]).max() < 1e-14


def test_rigid_inverse_compose_center():
    rng = np.random.default_rng(4)
    T = Rigid3.from_rotvec(random_rotvecs(rng, 1)[0], rng.normal(size=3))
    X = rng.normal(size=(10, 3))
    assert np.abs(T.inverse().apply(T.apply(X)) - X).max() < 1e-14
    assert np.abs(T.apply(T.center)).max() < 1e-14  # the camera centre maps to the origin
    U = Rigid3.from_rotvec(random_rotvecs(rng, 1)[0], rng.normal(size=3))
    assert np.abs(T.compose(U).apply(X) - T.apply(U.apply(X))).max() < 1e-14


def test_rotation_angle_deg():
    R = so3_exp(np.array([0.0, 0.0, np.radians(7.5)]))
    assert rotation_angle_deg(R, np.eye(3)) == pytest.approx(7.5, abs=1e-12)


def test_umeyama_recovers_similarity_exactly_and_with_noise():
    rng = np.random.default_rng(5)
    src = rng.normal(size=(50, 3))
    R = so3_exp(random_rotvecs(rng, 1)[0])
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 3.0])
    sim = umeyama(src, dst)
    assert sim.s == pytest.approx(2.5, rel=1e-12)
    assert np.abs(sim.R - R).max() < 1e-12
    assert np.abs(sim.apply(src) - dst).max() < 1e-12
    noisy = umeyama(src, dst + rng.normal(scale=0.01, size=dst.shape))
    assert 2.49 < noisy.s < 2.51 and rotation_angle_deg(noisy.R, R) < 0.5


def test_sim3_transform_pose_keeps_projection_rays():
    rng = np.random.default_rng(6)
    src = rng.normal(size=(20, 3))
    R = so3_exp(random_rotvecs(rng, 1)[0])
    sim = umeyama(src, 3.0 * src @ R.T + 1.0)
    cam = Rigid3.from_rotvec(random_rotvecs(rng, 1)[0], rng.normal(size=3))
    X = rng.normal(size=(5, 3))
    ray_a = cam.apply(X)
    ray_b = sim.transform_pose(cam).apply(sim.apply(X))
    assert np.abs(ray_b - 3.0 * ray_a).max() < 1e-12  # same rays, scaled by s


@pytest.mark.parametrize("src,msg", [(np.zeros((2, 3)), ">= 3"),
                                     (np.outer(np.arange(5.0), [1, 2, 3]), "collinear"),
                                     (np.full((4, 3), np.nan), "non-finite")])
def test_umeyama_bad_input(src, msg):
    with pytest.raises(ValueError, match=msg):
        umeyama(src, src)
