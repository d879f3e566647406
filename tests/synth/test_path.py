"""The handheld capture path: shape, heights, clearance, smoothness, where it looks."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.geometry.transforms import is_rotation, rotation_angle_deg
from nsim.synth.path import MIN_CLEARANCE_M, HandheldPathConfig, handheld_path, handheld_path_at, timestamps_s
from nsim.synth.room import ROOM_PRESETS, make_room
from tests.synth.simple_room import simple_spec

N = 200


@pytest.fixture(scope="module")
def paths():
    return {name: (make_room(name), handheld_path(make_room(name), N, seed=0)) for name in ROOM_PRESETS}


def test_shape_rotations_and_determinism(paths):
    spec, poses = paths["kitchen"]
    assert poses.shape == (N, 4, 4) and poses.dtype == np.float64
    assert np.all(is_rotation(poses[:, :3, :3]))
    np.testing.assert_array_equal(poses[:, 3], np.tile([0, 0, 0, 1.0], (N, 1)))
    np.testing.assert_array_equal(poses, handheld_path(spec, N, seed=0))
    assert not np.allclose(poses, handheld_path(spec, N, seed=1))


def test_two_heights(paths):
    cfg = HandheldPathConfig()
    for _, poses in paths.values():
        z = poses[:, 2, 3]
        first, second = z[: int(0.4 * N)], z[int(0.6 * N):]
        assert np.abs(first - cfg.eye_height_m).max() <= cfg.bob_amplitude_m + 1e-9
        assert np.abs(second - cfg.low_height_m).max() <= cfg.bob_amplitude_m / 2 + 1e-9
        assert first.std() > 0.005  # there is head bob


def test_clearance_from_every_surface(paths):
    for spec, poses in paths.values():
        eye = poses[:, :3, 3]
        size = np.array(spec.size_xyz_m)
        assert np.all(eye >= MIN_CLEARANCE_M) and np.all(eye <= size - MIN_CLEARANCE_M)  # walls, floor, ceiling
        for box in spec.boxes:
            lo, hi = np.array(box.min_xyz_m), np.array(box.max_xyz_m)
            gap = np.linalg.norm(np.maximum(np.maximum(lo - eye, eye - hi), 0.0), axis=1)  # 3D distance to the box
            assert gap.min() >= MIN_CLEARANCE_M, (spec.name, box.label)


def test_smooth_and_overlapping(paths):
    for spec, poses in paths.values():
        step_m = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
        turn_deg = rotation_angle_deg(poses[:-1, :3, :3], poses[1:, :3, :3])
        perimeter = 2 * 2 * np.pi * max(spec.walk_loop_xy_m[2:])  # two loops, generous
        assert step_m.max() < 1.5 * perimeter / N + 0.05
        assert step_m.min() > 0.02  # parallax: the camera keeps moving
        assert turn_deg.max() < 10.0


def test_looks_inwards_and_level(paths):
    for spec, poses in paths.values():
        cx, cy = spec.walk_loop_xy_m[:2]
        forward = poses[:, :3, 2]
        to_centre = np.array([cx, cy]) - poses[:, :2, 3]
        cos_yaw = np.sum(forward[:, :2] * to_centre, axis=1) / (
            np.linalg.norm(forward[:, :2], axis=1) * np.linalg.norm(to_centre, axis=1))
        assert np.degrees(np.arccos(np.clip(cos_yaw, -1, 1))).max() < 12.0
        assert np.abs(poses[:, 2, 0]).max() < np.sin(np.radians(5))  # camera x stays nearly horizontal (roll)


def test_path_between_frames(paths):
    """``handheld_path_at`` is the path at any time: the frames at k / n, smooth in between and beyond."""
    spec, poses = paths["kitchen"]
    np.testing.assert_array_equal(handheld_path_at(spec, np.arange(N) / N, seed=0), poses)
    k = 37
    fine = handheld_path_at(spec, (k + np.linspace(0.0, 1.0, 11)) / N, seed=0)
    np.testing.assert_allclose(fine[[0, -1]], poses[[k, k + 1]], atol=1e-12)
    step = np.linalg.norm(np.diff(fine[:, :3, 3], axis=0), axis=1)
    whole = np.linalg.norm(poses[k + 1, :3, 3] - poses[k, :3, 3])
    assert step.max() < 0.2 * whole and step.sum() == pytest.approx(whole, rel=0.02)
    assert rotation_angle_deg(fine[:-1, :3, :3], fine[1:, :3, :3]).max() < 0.2 * rotation_angle_deg(
        poses[k, :3, :3], poses[k + 1, :3, :3]) + 1e-9
    # before the first frame and after the last, the walk goes on smoothly (gait phase included)
    for s0 in (0.0, 1.0):
        eps = 1e-4
        edge = handheld_path_at(spec, np.array([s0 - eps, s0, s0 + eps]), seed=0)
        assert np.abs(edge[0] - edge[1]).max() < 1e-2 and np.abs(edge[2] - edge[1]).max() < 1e-2
        np.testing.assert_allclose(edge[0] - edge[1], edge[1] - edge[2], atol=1e-5)
    with pytest.raises(ValueError, match="capture_fraction"):
        handheld_path_at(spec, np.array([0.0, np.nan]))


def test_rejects_bad_requests():
    with pytest.raises(ValueError, match="n_frames"):
        handheld_path(simple_spec(), 1)
    with pytest.raises(ValueError, match="heights"):
        handheld_path(simple_spec(), 10, cfg=HandheldPathConfig(eye_height_m=2.2))
    with pytest.raises(ValueError, match="crouch_fraction"):
        HandheldPathConfig(crouch_fraction=1.0)


def test_timestamps():
    np.testing.assert_allclose(timestamps_s(4, 10.0), [0.0, 0.1, 0.2, 0.3])
    with pytest.raises(ValueError):
        timestamps_s(3, 0.0)
