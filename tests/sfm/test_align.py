"""Sim(3) fits, association with a reference, gravity alignment, metric scale, pose errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry.transforms import look_at
from nsim.sfm.align import (
    apply_sim3_to_points,
    apply_sim3_to_poses,
    associate_by_name,
    associate_by_time,
    fit_sim3,
    gravity_align,
    pose_errors,
    require_matches,
    scale_from_camera_height,
    scale_from_known_distance,
    sim3_matrix,
    umeyama_sim3,
)


def _random_sim3(seed: int) -> tuple[float, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=seed).as_matrix(), rng.normal(size=3)


def _ring_poses(n: int = 24, height: float = 1.5) -> np.ndarray:
    """cam_to_world (n, 4, 4) on a circle in a z-up world, looking at the centre and a bit down."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    eye = np.stack([2 * np.cos(a), 1.5 * np.sin(a), height + 0.05 * np.sin(3 * a)], axis=1)
    return look_at(eye, np.array([0.0, 0.0, 0.8]))


def test_umeyama_recovers_a_similarity():
    s, R, t = _random_sim3(0)
    src = np.random.default_rng(1).normal(size=(20, 3))
    s2, R2, t2 = umeyama_sim3(src, apply_sim3_to_points(s, R, t, src))
    assert s2 == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    np.testing.assert_allclose(sim3_matrix(s, R, t)[:3, :3], s * R)


def test_fit_sim3_ignores_outliers():
    s, R, t = _random_sim3(2)
    rng = np.random.default_rng(3)
    src = rng.normal(size=(50, 3))
    dst = apply_sim3_to_points(s, R, t, src) + rng.normal(0, 1e-3, (50, 3))
    dst[:4] += rng.normal(0, 2.0, (4, 3))  # four wrong associations
    fit = fit_sim3(src, dst)
    assert fit.s == pytest.approx(s, rel=1e-3)
    assert not fit.inliers[:4].any() and fit.inliers[4:].all()
    assert fit.rms_m < 3e-3
    plain = fit_sim3(src, dst, robust=False)
    assert abs(plain.s / s - 1) > abs(fit.s / s - 1)


def test_apply_sim3_to_poses_keeps_rotations_and_moves_centres():
    poses = _ring_poses()
    s, R, t = _random_sim3(4)
    moved = apply_sim3_to_poses(s, R, t, poses)
    np.testing.assert_allclose(moved[:, :3, 3], apply_sim3_to_points(s, R, t, poses[:, :3, 3]))
    np.testing.assert_allclose(np.linalg.det(moved[:, :3, :3]), 1.0)
    rot, pos = pose_errors(moved, poses)
    assert rot.max() < 1e-6 and pos.max() < 1e-9


def test_pose_errors_measure_a_known_perturbation():
    gt = _ring_poses()
    est = gt.copy()
    est[5, :3, :3] = est[5, :3, :3] @ Rotation.from_euler("y", 2.0, degrees=True).as_matrix()
    s, R, t = _random_sim3(5)
    rot, pos = pose_errors(apply_sim3_to_poses(s, R, t, est), gt)
    assert rot[5] == pytest.approx(2.0, abs=1e-6)
    assert np.delete(rot, 5).max() < 1e-6 and pos.max() < 1e-9


def test_associate_by_name_and_time():
    ie, ir = associate_by_name(["frame_00003.png", "frame_00007.png", "x.png"],
                               ["images/frame_00007.png", "images/frame_00003.jpg", "images/frame_00009.png"])
    np.testing.assert_array_equal(ie, [0, 1])
    np.testing.assert_array_equal(ir, [1, 0])
    ie, ir = associate_by_time(np.array([0.0, 0.5, 1.0]), np.array([0.49, 1.02, 7.0]), max_dt_s=0.03)
    np.testing.assert_array_equal(ie, [1, 2])
    np.testing.assert_array_equal(ir, [0, 1])
    ie, _ = associate_by_time(np.array([0.0, 0.5]), np.array([100.0]), max_dt_s=0.03)
    assert len(ie) == 0
    with pytest.raises(InputError, match="ref.tum: only 0 of 2 registered frames match a reference pose by timestamp"):
        require_matches(len(ie), 2, "ref.tum", "by timestamp")


def _room_points(rng: np.random.Generator, table: bool) -> np.ndarray:
    """Sparse points of a z-up room: floor (z = 0), walls, optionally a big table top at z = 0.75."""
    floor = np.column_stack([rng.uniform(-3, 3, 300), rng.uniform(-2.5, 2.5, 300), np.zeros(300)])
    walls = []
    for x in (-3.0, 3.0):
        walls.append(np.column_stack([np.full(300, x), rng.uniform(-2.5, 2.5, 300), rng.uniform(0, 2.6, 300)]))
    for y in (-2.5, 2.5):
        walls.append(np.column_stack([rng.uniform(-3, 3, 300), np.full(300, y), rng.uniform(0, 2.6, 300)]))
    ceiling = np.column_stack([rng.uniform(-3, 3, 200), rng.uniform(-2.5, 2.5, 200), np.full(200, 2.6)])
    parts = [floor, *walls, ceiling]
    if table:  # more points than the floor: a textured table over a plain floor
        parts.append(np.column_stack([rng.uniform(-1, 1, 500), rng.uniform(-0.6, 0.6, 500), np.full(500, 0.75)]))
    pts = np.concatenate(parts)
    return pts + rng.normal(0, 0.005, pts.shape)


@pytest.mark.parametrize("table", [False, True])
def test_gravity_align_finds_the_floor(table):
    rng = np.random.default_rng(6)
    pts, poses = _room_points(rng, table), _ring_poses()
    # wobble the cameras' roll/pitch a little, then hide everything in an arbitrary similarity
    poses[:, :3, :3] = poses[:, :3, :3] @ Rotation.from_rotvec(rng.normal(0, 0.05, (len(poses), 3))).as_matrix()
    s, R, t = _random_sim3(7)
    fit = gravity_align(apply_sim3_to_points(s, R, t, pts), apply_sim3_to_poses(s, R, t, poses), seed=0)
    assert fit.floor_found and fit.floor_inliers >= 250
    # back in the original frame (up to the scale s) the floor must be z = 0 and +z up
    new_from_orig_R = fit.R @ R
    tilt_deg = np.degrees(np.arccos(np.clip(new_from_orig_R[2, 2], -1, 1)))
    assert tilt_deg < 0.5
    floor_new = apply_sim3_to_points(1.0, fit.R, fit.t, apply_sim3_to_points(s, R, t, pts[:300]))
    assert np.abs(np.median(floor_new[:, 2])) < 0.01 * s
    cams_new = apply_sim3_to_points(1.0, fit.R, fit.t, apply_sim3_to_points(s, R, t, poses[:, :3, 3]))
    assert np.median(cams_new[:, 2]) / s == pytest.approx(1.5, abs=0.02)


def test_gravity_align_without_points_uses_the_cameras():
    poses = _ring_poses()
    fit = gravity_align(np.zeros((0, 3)), poses)
    assert not fit.floor_found
    # cameras look 20-30 deg down at the centre: their mean -y is tilted from +z, so only roughly up
    assert fit.up_old[2] > 0.8


def test_metric_scale_helpers():
    assert scale_from_known_distance(np.zeros(3), np.array([0.0, 0.5, 0.0]), 2.0) == pytest.approx(4.0)
    with pytest.raises(InputError, match="coincide"):
        scale_from_known_distance(np.ones(3), np.ones(3), 1.0)
    with pytest.raises(InputError, match="expected a distance > 0"):
        scale_from_known_distance(np.zeros(3), np.ones(3), -1.0)
    poses = _ring_poses(height=0.75)
    assert scale_from_camera_height(poses, 1.5) == pytest.approx(2.0, rel=0.01)
    below = poses.copy()
    below[:, 2, 3] = -1.0
    with pytest.raises(InputError, match="not above the detected floor"):
        scale_from_camera_height(below, 1.5)


def test_robust_pose_errors_isolate_one_wrong_pose():
    gt = _ring_poses()
    est = gt.copy()
    est[3, :3, 3] += np.array([3.0, -2.0, 1.0])  # one pose registered far away
    rot, pos = pose_errors(est, gt)
    assert np.median(pos) > 0.05  # the plain fit is bent by the outlier
    rot, pos = pose_errors(est, gt, robust=True)
    assert np.delete(pos, 3).max() < 1e-9 and pos[3] > 3.0
