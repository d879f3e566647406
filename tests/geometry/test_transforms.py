"""SE(3) / Sim(3) helpers: analytic cases and round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import (
    apply_sim3,
    invert_se3,
    is_rotation,
    look_at,
    make_se3,
    matrix_from_quat_wxyz,
    quat_wxyz_from_matrix,
    rotation_angle_deg,
    se3_from_quat_wxyz_t,
    umeyama,
)


def _random_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_se3(Rotation.random(n, random_state=rng).as_matrix(), rng.normal(size=(n, 3)))


def test_make_se3_broadcasts():
    R = Rotation.random(5, random_state=0).as_matrix()
    T = make_se3(R, np.array([1.0, 2.0, 3.0]))
    assert T.shape == (5, 4, 4)
    np.testing.assert_array_equal(T[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)))
    np.testing.assert_array_equal(T[:, :3, 3], np.tile([1.0, 2.0, 3.0], (5, 1)))
    Tt = make_se3(torch.from_numpy(R), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    np.testing.assert_array_equal(Tt.numpy(), T)


def test_invert_se3_round_trip():
    T = _random_poses(12).reshape(3, 4, 4, 4)
    np.testing.assert_allclose(T @ invert_se3(T), np.broadcast_to(np.eye(4), T.shape), atol=1e-12)
    np.testing.assert_allclose(invert_se3(invert_se3(T)), T, atol=1e-12)
    Tt = torch.from_numpy(T).requires_grad_()
    np.testing.assert_allclose(invert_se3(Tt).detach().numpy(), invert_se3(T), atol=1e-15)
    invert_se3(Tt).sum().backward()
    assert Tt.grad is not None


def test_quaternion_known_value():
    R = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    s = math.sqrt(0.5)
    np.testing.assert_allclose(quat_wxyz_from_matrix(R), [s, 0.0, 0.0, s], atol=1e-15)


def test_quaternion_round_trips():
    R = Rotation.random(100, random_state=1).as_matrix().reshape(10, 10, 3, 3)
    q = quat_wxyz_from_matrix(R)
    assert q.shape == (10, 10, 4) and (q[..., 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(matrix_from_quat_wxyz(q), R, atol=1e-14)
    np.testing.assert_allclose(quat_wxyz_from_matrix(matrix_from_quat_wxyz(-q)), q, atol=1e-14)
    t = np.arange(300.0).reshape(10, 10, 3)
    T = se3_from_quat_wxyz_t(q, t)
    np.testing.assert_allclose(T[..., :3, :3], R, atol=1e-14)
    np.testing.assert_array_equal(T[..., :3, 3], t)
    with pytest.raises(ValueError):
        matrix_from_quat_wxyz(np.zeros(4))


def _known_sim3():
    return 2.5, Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix(), np.array([1.0, -2.0, 0.5])


@pytest.mark.parametrize("with_scale", [True, False])
def test_umeyama_exact(with_scale):
    s, R, t = _known_sim3()
    s = s if with_scale else 1.0
    src = np.random.default_rng(0).normal(size=(50, 3))
    s_est, R_est, t_est = umeyama(src, apply_sim3(s, R, t, src), with_scale=with_scale)
    assert s_est == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t_est, t, atol=1e-12)
    assert is_rotation(R_est)


def test_umeyama_noisy():
    s, R, t = _known_sim3()
    rng = np.random.default_rng(1)
    src = rng.uniform(-5, 5, size=(500, 3))
    dst = apply_sim3(s, R, t, src) + rng.normal(scale=0.01, size=src.shape)
    s_est, R_est, t_est = umeyama(src, dst, with_scale=True)
    assert s_est == pytest.approx(s, rel=1e-3)
    assert rotation_angle_deg(R_est, R) < 0.05
    np.testing.assert_allclose(t_est, t, atol=5e-3)


def test_umeyama_reflected_target_gives_rotation():
    src = np.random.default_rng(2).normal(size=(20, 3))
    _, R, _ = umeyama(src, src * [1.0, 1.0, -1.0], with_scale=True)
    assert is_rotation(R)


@pytest.mark.parametrize(
    "src, dst, match",
    [
        (np.zeros((5, 3)), np.zeros((5, 3)), "degenerate"),
        (np.outer(np.arange(5.0), [1.0, 2.0, 3.0]), np.random.default_rng(0).normal(size=(5, 3)), "degenerate"),
        (np.ones((2, 3)), np.ones((2, 3)), "at least 3"),
        (np.ones((5, 3)), np.ones((4, 3)), "equal shape"),
    ],
)
def test_umeyama_rejects_bad_input(src, dst, match):
    with pytest.raises(ValueError, match=match):
        umeyama(src, dst, with_scale=True)


def test_apply_sim3_numpy_torch_agree():
    s, R, t = _known_sim3()
    p = np.random.default_rng(3).normal(size=(4, 7, 3))
    out = apply_sim3(s, R, t, p)
    np.testing.assert_allclose(out, s * np.einsum("ij,...j->...i", R, p) + t, atol=1e-14)
    np.testing.assert_allclose(apply_sim3(s, R, t, torch.from_numpy(p)).numpy(), out, atol=1e-14)


def test_rotation_angle_deg():
    R_a = Rotation.random(8, random_state=4).as_matrix()
    R_b = R_a @ Rotation.from_rotvec([0.0, math.radians(30), 0.0]).as_matrix()
    np.testing.assert_allclose(rotation_angle_deg(R_a, R_b), 30.0, atol=1e-10)
    assert rotation_angle_deg(np.eye(3), np.eye(3)) == 0.0
    assert rotation_angle_deg(np.eye(3), np.diag([1.0, -1.0, -1.0])) == pytest.approx(180.0)


def test_look_at_puts_target_on_optical_axis():
    eye, target = np.array([1.0, 2.0, 1.5]), np.array([-2.0, 0.5, 0.3])
    c2w = look_at(eye, target)
    assert is_rotation(c2w[:3, :3], 1e-12)
    np.testing.assert_array_equal(c2w[:3, 3], eye)
    target_cam = (invert_se3(c2w) @ np.append(target, 1.0))[:3]
    np.testing.assert_allclose(target_cam[:2], 0.0, atol=1e-12)
    assert target_cam[2] == pytest.approx(np.linalg.norm(target - eye))
    assert c2w[:3, 1] @ [0.0, 0.0, 1.0] < 0  # image +y (down) points against world up
    assert abs(c2w[:3, 0] @ [0.0, 0.0, 1.0]) < 1e-12  # no roll
    cam = Camera.pinhole_from_fov(65, 49, 60.0)
    uv, valid = cam.project(target_cam)
    assert valid and np.allclose(uv, [cam.cx, cam.cy])


def test_look_at_batched_and_degenerate():
    eyes = np.random.default_rng(5).normal(size=(6, 3))
    c2w = look_at(eyes, np.zeros(3))
    assert c2w.shape == (6, 4, 4) and is_rotation(c2w[:, :3, :3]).all()
    with pytest.raises(ValueError, match="coincide"):
        look_at(np.ones(3), np.ones(3))
    with pytest.raises(ValueError, match="parallel"):
        look_at(np.zeros(3), np.array([0.0, 0.0, -2.0]))


def test_is_rotation():
    R = Rotation.random(4, random_state=6).as_matrix()
    assert is_rotation(R).tolist() == [True] * 4
    assert is_rotation(R[0]) and is_rotation(R[0]).shape == ()
    assert not is_rotation(np.diag([1.0, 1.0, -1.0]))  # reflection
    assert not is_rotation(2.0 * np.eye(3))
    assert not is_rotation(np.full((3, 3), np.nan))
    assert is_rotation(np.eye(3) + 1e-8, tol=1e-6) and not is_rotation(np.eye(3) + 1e-4, tol=1e-6)
