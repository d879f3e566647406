"""A static camera and a person: root translation by reprojection, up and floor, metric scale."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.geometry.transforms import look_at
from nsim.human.fit import reference_body
from nsim.human.gait import walk_cycle
from nsim.human.landmarks import LANDMARK_NAMES
from nsim.human.monocular import floor_frame, place_landmarks, root_translations, static_camera
from nsim.human.motion import LocomotionLoop
from nsim.human.skeleton import forward_kinematics

HIPS = [LANDMARK_NAMES.index("left_hip"), LANDMARK_NAMES.index("right_hip")]


def _world_walk(seconds: float = 2.2, fps: float = 15.0) -> np.ndarray:
    """Landmarks (F, L, 3) of the reference body walking 2.9 m along +x on the floor."""
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, fps=fps))
    root, quats = loop.sample(np.arange(int(round(seconds * fps))) / fps)
    root = root + (-1.4, 0.0, 0.0)
    body = reference_body(1.75)
    return body.landmarks(forward_kinematics(body.skeleton, quats, root))


def _to_camera(points_world: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    w2c = np.linalg.inv(cam_to_world)
    return points_world @ w2c[:3, :3].T + w2c[:3, 3]


def test_static_camera_fov():
    cam = static_camera(640, 360, 60.0)
    assert cam.fov_deg[0] == pytest.approx(60.0)
    assert static_camera(640, 360).fov_deg[0] == pytest.approx(65.0)


def test_root_translations_recover_the_hips():
    """Hip-relative body points + their image positions give back the hips' camera position exactly."""
    cam = static_camera(640, 480, 65.0)
    rng = np.random.default_rng(0)
    body = rng.uniform(-0.5, 0.5, (4, 33, 3)) * (0.4, 1.0, 0.3)
    t = np.array([[0.2, -0.1, 3.5], [-0.6, 0.3, 5.0], [0.0, 0.0, 2.5], [1.0, 0.2, 7.0]])
    uv, _ = cam.project(body + t[:, None, :])
    w = np.ones((4, 33))
    w[1, 5:] = 0.0  # frame 1: five points only
    w[2, 4:] = 0.0
    w[2, :4] = 0.0  # frame 2: none
    got = root_translations(body, uv, w, cam)
    np.testing.assert_allclose(got[[0, 1, 3]], t[[0, 1, 3]], atol=1e-9)
    assert np.isnan(got[2]).all()


def test_floor_frame_finds_up_floor_and_camera_height():
    world = _world_walk()
    c2w = look_at((0.5, -3.5, 1.6), (0.0, 0.0, 0.9))
    cam_pts = _to_camera(world, c2w)
    frame = floor_frame(cam_pts, np.ones(cam_pts.shape[:2]))
    up_true = c2w[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # world up in camera axes
    angle = np.degrees(np.arccos(np.clip(frame.up_cam @ up_true, -1, 1)))
    assert angle < 2.0, f"up off by {angle:.2f} deg"
    assert frame.camera_height_m == pytest.approx(1.6, abs=0.03)
    # back in the world: feet on z = 0 (soles 3 cm up), heads up
    placed = cam_pts @ frame.cam_to_world[:3, :3].T + frame.cam_to_world[:3, 3]
    feet = placed[:, [LANDMARK_NAMES.index(n) for n in ("left_heel", "right_heel")], 2]
    assert feet.min() == pytest.approx(0.03, abs=0.03)
    assert placed[:, LANDMARK_NAMES.index("nose"), 2].mean() > 1.4
    R = frame.cam_to_world[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_place_landmarks_scales_to_a_known_camera_height():
    """The detector's metres may be off by a factor; a given camera height puts it right."""
    world = _world_walk()
    c2w = look_at((0.0, -4.0, 1.4), (0.0, 0.0, 0.9))
    cam = static_camera(640, 480, 70.0)
    cam_pts = _to_camera(world, c2w)
    uv, _ = cam.project(cam_pts)
    hips = cam_pts[:, HIPS].mean(axis=1, keepdims=True)
    body = 0.9 * (cam_pts - hips)  # a detector that thinks the person is 10 % smaller
    vis = np.ones(cam_pts.shape[:2])
    guessed = place_landmarks(body, uv, vis, cam)
    assert guessed.camera_height_m == pytest.approx(0.9 * 1.4, abs=0.04)
    known = place_landmarks(body, uv, vis, cam, camera_height_m=1.4)
    assert known.camera_height_m == pytest.approx(1.4)
    assert known.scale == pytest.approx(1 / 0.9, rel=0.03)
    # world distances are metric again: the walk's extent along the floor
    extent = np.ptp(known.landmarks_m[:, HIPS].mean(axis=1)[:, :2], axis=0)
    assert np.hypot(*extent) == pytest.approx(np.hypot(*np.ptp(world[:, HIPS].mean(axis=1)[:, :2], axis=0)), rel=0.05)
    with pytest.raises(ValueError, match="not both"):
        place_landmarks(body, uv, vis, cam, camera_height_m=1.4, body_height_m=1.7)
