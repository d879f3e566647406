"""Conversions between nsim's convention and OpenGL / COLMAP."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.geometry.conventions import (
    OPENCV_TO_OPENGL,
    colmap_to_cam_to_world,
    opencv_to_opengl_c2w,
    opengl_to_opencv_c2w,
    principal_point_from_colmap,
    principal_point_to_colmap,
    world_to_cam_to_colmap,
)
from nsim.geometry.transforms import invert_se3, look_at, make_se3


def _poses(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    return make_se3(Rotation.random(n, random_state=rng).as_matrix(), rng.normal(size=(n, 3)))


def test_opengl_round_trip_is_exact():
    c2w = _poses(10).reshape(2, 5, 4, 4)
    np.testing.assert_array_equal(opengl_to_opencv_c2w(opencv_to_opengl_c2w(c2w)), c2w)
    np.testing.assert_array_equal(OPENCV_TO_OPENGL, np.diag([1.0, -1.0, -1.0, 1.0]))


def test_opengl_axes_meaning():
    c2w = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))  # looking along world +x, z up
    gl = opencv_to_opengl_c2w(c2w)
    np.testing.assert_allclose(-gl[:3, 2], [1.0, 0.0, 0.0], atol=1e-15)  # OpenGL looks along -z
    np.testing.assert_allclose(gl[:3, 1], [0.0, 0.0, 1.0], atol=1e-15)  # OpenGL +y is up
    np.testing.assert_array_equal(gl[:3, 3], c2w[:3, 3])
    with pytest.raises(ValueError):
        opencv_to_opengl_c2w(np.eye(3))


def test_colmap_round_trip_and_meaning():
    c2w = _poses(20)
    q, t = world_to_cam_to_colmap(c2w)
    assert q.shape == (20, 4) and t.shape == (20, 3) and (q[:, 0] >= 0).all()
    np.testing.assert_allclose(colmap_to_cam_to_world(q, t), c2w, atol=1e-12)
    # COLMAP: x_cam = R(q) x_world + t
    x_world = np.array([0.3, -1.0, 2.0])
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(R @ x_world + t, (invert_se3(c2w) @ np.append(x_world, 1.0))[:, :3], atol=1e-12)


def test_principal_point_shift():
    assert principal_point_to_colmap(319.5, 239.5) == (320.0, 240.0)
    assert principal_point_from_colmap(320.0, 240.0) == (319.5, 239.5)
