"""Clips, loops with root-motion extraction, and replay along paths."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.human.gait import walk_cycle
from nsim.human.motion import LocomotionLoop, MotionClip
from nsim.human.skeleton import as_rotation_matrices, heading_yaw, quats_from_matrices, rot_z


@pytest.fixture(scope="module")
def walk() -> MotionClip:
    return walk_cycle(1.3)


def test_sample_at_frame_times_returns_the_frames(walk):
    root, q = walk.sample(walk.times_s)
    np.testing.assert_allclose(root, walk.root_positions_m, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(q * walk.local_rotations_wxyz, -1)), 1.0, atol=1e-12)


def test_loop_extracts_root_motion_and_is_continuous(walk):
    loop = LocomotionLoop.from_clip(walk)
    assert loop.speed_mps == pytest.approx(1.3) and loop.stride_m == pytest.approx(1.3 * walk.duration_s)
    r0, q0 = loop.sample_phase(np.array([0.0]))
    r1, q1 = loop.sample_phase(np.array([1.0 - 1e-9]))
    np.testing.assert_allclose(r0, r1, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.sum(q0 * q1, -1)), 1.0, atol=1e-9)
    # endless playback at a different speed moves the root at that speed
    root, _ = loop.sample(np.array([0.0, 10.0]), speed_mps=0.9)
    assert root[1, 0] - root[0, 0] == pytest.approx(9.0, abs=0.1)


def test_loop_blends_a_seam():
    clip = walk_cycle(1.3)
    cut = MotionClip(clip.skeleton, clip.fps, clip.root_positions_m[:-6], clip.local_rotations_wxyz[:-6])
    loop = LocomotionLoop.from_clip(cut, blend_s=0.2)
    np.testing.assert_allclose(loop.residual_root_m[-1], loop.residual_root_m[0])
    steps = np.linalg.norm(np.diff(loop.residual_root_m, axis=0), axis=1)
    assert steps.max() < 0.05  # no jump at the seam


def test_pose_at_places_and_turns_the_body(walk):
    loop = LocomotionLoop.from_clip(walk)
    root, q = loop.pose_at(np.array([0.25, 0.25]), np.array([[0.0, 0.0], [3.0, 4.0]]), np.array([0.0, 1.0]))
    r_rel = rot_z(1.0)[:2, :2] @ root[0, :2] + [3.0, 4.0]
    np.testing.assert_allclose(root[1, :2], r_rel, atol=1e-12)
    yaw0 = heading_yaw(as_rotation_matrices(q[0, 0]))
    yaw1 = heading_yaw(as_rotation_matrices(q[1, 0]))
    assert yaw1 - yaw0 == pytest.approx(1.0, abs=1e-9)


def test_pose_along_path_follows_a_corner(walk):
    loop = LocomotionLoop.from_clip(walk)
    path = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0]])
    clip = loop.pose_along_path(path, speed_mps=1.0, fps=30.0)
    assert clip.duration_s == pytest.approx(6.0, abs=1 / 30)
    root = clip.root_positions_m
    assert np.linalg.norm(root[-1, :2] - [3.0, 3.0]) < 0.1
    yaw = heading_yaw(clip.rotation_matrices()[:, 0])
    assert abs(yaw[0]) < 0.2 and abs(yaw[-1] - np.pi / 2) < 0.2
    steps = np.linalg.norm(np.diff(root[:, :2], axis=0), axis=1) * 30
    assert np.median(steps) == pytest.approx(1.0, rel=0.1)


def test_clip_rejects_bad_shapes(walk):
    with pytest.raises(ValueError, match="local_rotations_wxyz"):
        MotionClip(walk.skeleton, 30.0, np.zeros((2, 3)), quats_from_matrices(np.broadcast_to(np.eye(3), (2, 3, 3, 3))))
