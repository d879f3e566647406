"""Registering a robot's odometry frame in a scene from localised camera frames (synthetic, known truth);
the drift refinement on the robot-log generator's drifting odometry."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry.transforms import make_se3, rotation_angle_deg, umeyama
from nsim.sfm.drift_refinement import DriftModel, drift_nodes
from nsim.sfm.register import PosePairs, fit_pose_pairs, pose_residuals, register_trajectory
from nsim.sfm.registration_types import RegisterOptions

YAW_DEG = 30.0
SHIFT_M = np.array([0.96, 0.72, 0.0])  # 1.2 m
CLOCK_OFFSET_S = 0.03
ODOM_HZ, CAMERA_HZ = 50.0, 10.0
DURATION_S = 20.0


def _yaw(deg: float) -> np.ndarray:
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


ODOM_TO_WORLD = make_se3(_yaw(YAW_DEG), SHIFT_M)


def body_to_odom_at(t_s: np.ndarray) -> np.ndarray:
    """(T, 4, 4) a walking robot: a loop with a varying speed, turning both ways (analytic, any time)."""
    t = np.asarray(t_s, dtype=np.float64)
    phase = 2 * np.pi * t / DURATION_S + 0.3 * np.sin(2 * np.pi * t / 7.0)  # speed changes
    x = 2.0 * np.cos(phase) + 0.4 * np.cos(3 * phase)
    y = 1.5 * np.sin(2 * phase)  # a figure of eight: left and right turns
    dphase = 2 * np.pi / DURATION_S + 0.3 * 2 * np.pi / 7.0 * np.cos(2 * np.pi * t / 7.0)
    vx = (-2.0 * np.sin(phase) - 1.2 * np.sin(3 * phase)) * dphase
    vy = 3.0 * np.cos(2 * phase) * dphase
    R = Rotation.from_euler("z", np.arctan2(vy, vx)[:, None]).as_matrix()
    return make_se3(R, np.stack([x, y, np.full_like(x, 0.5)], axis=-1))


def _mount(xyz, yaw_deg: float) -> np.ndarray:
    """sensor_to_body of a camera looking along body yaw ``yaw_deg``, pitched 15 deg down (OpenCV axes)."""
    look = Rotation.from_euler("zy", [yaw_deg, 15.0], degrees=True).as_matrix()
    opencv_from_forward = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]).T  # cam axes in body
    return make_se3(look @ opencv_from_forward, np.asarray(xyz, dtype=np.float64))


FRONT = _mount([0.4, 0.05, 0.1], 20.0)
RIGHT = _mount([0.0, -0.12, 0.05], -90.0)


def make_log(seed: int = 0, *, noise_m: float = 0.01, noise_deg: float = 0.2, outliers: float = 0.2,
             body=body_to_odom_at, duration_s: float = DURATION_S, odom_scale: float = 1.0):
    """(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns) of two cameras with noise and outliers."""
    rng = np.random.default_rng(seed)
    traj_s = np.arange(0.0, duration_s, 1.0 / ODOM_HZ)
    traj_ns = 1_700_000_000_000_000_000 + np.round(traj_s * 1e9).astype(np.int64)  # epoch nanoseconds
    capture_s = np.arange(0.05, duration_s - 0.05, 1.0 / CAMERA_HZ)
    poses, stamps, mounts = [], [], []
    for mount in (FRONT, RIGHT):
        truth = ODOM_TO_WORLD @ body(capture_s) @ mount
        poses.append(truth)
        stamps.append(traj_ns[0] + np.round((capture_s + CLOCK_OFFSET_S) * 1e9).astype(np.int64))
        mounts.append(np.broadcast_to(mount, truth.shape))
    c2w, stamps_ns, s2b = np.concatenate(poses), np.concatenate(stamps), np.concatenate(mounts)
    K = len(c2w)
    c2w = c2w.copy()
    c2w[:, :3, 3] += rng.normal(0.0, noise_m, (K, 3))
    c2w[:, :3, :3] = c2w[:, :3, :3] @ Rotation.from_rotvec(rng.normal(0.0, math.radians(noise_deg), (K, 3))).as_matrix()
    bad = rng.random(K) < outliers
    c2w[bad, :3, 3] += rng.uniform(0.3, 2.0, (bad.sum(), 1)) * Rotation.random(bad.sum(), rng).apply([1.0, 0, 0])
    c2w[bad, :3, :3] = Rotation.random(bad.sum(), rng).as_matrix() @ c2w[bad, :3, :3]
    body_to_odom = body(traj_s)
    body_to_odom[:, :3, 3] *= odom_scale
    return c2w, stamps_ns, s2b, body_to_odom, traj_ns, bad


def _errors(T: np.ndarray, truth: np.ndarray = ODOM_TO_WORLD, scale: float = 1.0) -> tuple[float, float]:
    """Translation (m) and rotation (deg) error of an odom_to_world."""
    R = T[:3, :3] / scale
    return float(np.linalg.norm(T[:3, 3] - truth[:3, 3])), float(rotation_angle_deg(R, truth[:3, :3]))


def test_recovers_odom_frame_and_clock_offset():
    c2w, stamps, s2b, body, traj, bad = make_log()
    reg = register_trajectory(c2w, stamps, s2b, body, traj)
    pos_err, rot_err = _errors(reg.odom_to_world)
    assert pos_err < 0.01 and rot_err < 0.1, (pos_err, rot_err)
    assert reg.clock_offset_s == pytest.approx(CLOCK_OFFSET_S, abs=0.005)
    assert 0.0 < reg.clock_offset_std_s < 0.005
    assert reg.scale == 1.0
    # the outliers are out, the good frames in; residuals as the noise (1 cm, 0.2 deg per axis)
    assert not (reg.inliers & bad).any() and reg.inliers[reg.used & ~bad].mean() > 0.97
    assert reg.median_m < 0.03 and reg.median_deg < 0.5 and reg.ok and reg.why is None
    assert "clock offset" in reg.summary()
    # the registered trajectory lies on the truth
    np.testing.assert_allclose(reg.to_world(body)[:, :3, 3], (ODOM_TO_WORLD @ body)[:, :3, 3], atol=0.02)


def test_known_clock_offset_and_exact_data():
    c2w, stamps, s2b, body, traj, _ = make_log(noise_m=0.0, noise_deg=0.0, outliers=0.0)
    reg = register_trajectory(c2w, stamps, s2b, body, traj, RegisterOptions(clock_offset_s=CLOCK_OFFSET_S))
    pos_err, rot_err = _errors(reg.odom_to_world)
    assert pos_err < 1e-4 and rot_err < 1e-3  # linear/slerp interpolation of 50 Hz odometry only
    assert reg.clock_offset_s == CLOCK_OFFSET_S and math.isnan(reg.clock_offset_std_s)
    assert reg.used.all() and reg.inliers.all()


def test_one_camera_and_a_similarity():
    c2w, stamps, s2b, body, traj, _ = make_log(1, odom_scale=1.05)
    front = np.arange(len(c2w)) < len(c2w) // 2
    reg = register_trajectory(c2w[front], stamps[front], FRONT, body, traj, RegisterOptions(with_scale=True))
    assert reg.scale == pytest.approx(1 / 1.05, rel=2e-3)
    pos_err, rot_err = _errors(reg.odom_to_world, scale=reg.scale)
    assert pos_err < 0.01 and rot_err < 0.1
    assert reg.clock_offset_s == pytest.approx(CLOCK_OFFSET_S, abs=0.005)


def test_fit_pose_pairs_matches_umeyama_on_centres_and_needs_one_pair():
    rng = np.random.default_rng(2)
    odom = make_se3(Rotation.random(30, rng).as_matrix(), rng.normal(size=(30, 3)))
    s, R, t = 1.7, Rotation.random(random_state=3).as_matrix(), rng.normal(size=3)
    world = odom.copy()
    world[:, :3, :3] = R @ odom[:, :3, :3]
    world[:, :3, 3] = s * odom[:, :3, 3] @ R.T + t
    world[:, :3, 3] += rng.normal(0, 0.01, (30, 3))
    # rotations weighed by nothing, no mount: Umeyama on the centres (the plain reference)
    s1, R1, t1 = fit_pose_pairs(PosePairs(odom, world, odom[:, :3, 3]), True, sigma_m=1.0, sigma_rad=1e9)
    s2, R2, t2 = umeyama(odom[:, :3, 3], world[:, :3, 3], with_scale=True)
    assert s1 == pytest.approx(s2, rel=1e-9)
    np.testing.assert_allclose(R1, R2, atol=1e-9)
    np.testing.assert_allclose(t1, t2, atol=1e-9)
    # one exact pair fixes a rigid motion
    exact = odom[:1].copy()
    exact[:, :3, :3] = R @ odom[:1, :3, :3]
    exact[:, :3, 3] = odom[:1, :3, 3] @ R.T + t
    pair = PosePairs(odom[:1], exact, odom[:1, :3, 3] + 0.3)
    s3, R3, t3 = fit_pose_pairs(pair, False, 0.01, 0.01)
    np.testing.assert_allclose(R3, R, atol=1e-12)
    np.testing.assert_allclose(t3, t, atol=1e-12)
    pos, rot = pose_residuals(s3, R3, t3, pair)
    assert pos[0] < 1e-12 and rot[0] < 1e-6


def test_a_similarity_scales_the_odometry_not_the_mounts():
    rng = np.random.default_rng(8)
    body = make_se3(Rotation.random(20, rng).as_matrix(), rng.normal(size=(20, 3)))
    mount = _mount([0.4, 0.1, 0.2], 30.0)
    s, R, t = 0.8, Rotation.random(random_state=9).as_matrix(), rng.normal(size=3)
    world_body = body.copy()
    world_body[:, :3, :3] = R @ body[:, :3, :3]
    world_body[:, :3, 3] = s * body[:, :3, 3] @ R.T + t
    pairs = PosePairs(body @ mount, world_body @ mount, body[:, :3, 3])
    s1, R1, t1 = fit_pose_pairs(pairs, True, 0.01, 0.01)
    assert s1 == pytest.approx(s, rel=1e-9)
    np.testing.assert_allclose(R1, R, atol=1e-9)
    np.testing.assert_allclose(t1, t, atol=1e-9)
    pos, rot = pose_residuals(np.array([s1, 1.0]), np.stack([R1, R1]), np.stack([t1, t1]), pairs)  # (H, K)
    assert pos.shape == (2, 20) and pos[0].max() < 1e-9 and rot[0].max() < 1e-6 and pos[1].max() > 0.01


def test_a_straight_line_registers_with_a_known_offset_but_cannot_time_itself():
    def straight(t_s):
        t = np.asarray(t_s, dtype=np.float64)
        return make_se3(np.broadcast_to(np.eye(3), (len(t), 3, 3)), np.stack([0.5 * t, 0 * t, 0 * t + 0.5], -1))

    c2w, stamps, s2b, body, traj, _ = make_log(4, body=straight, outliers=0.0)
    # collinear centres: the rotations fix the roll about the line
    reg = register_trajectory(c2w, stamps, s2b, body, traj, RegisterOptions(clock_offset_s=CLOCK_OFFSET_S))
    pos_err, rot_err = _errors(reg.odom_to_world)
    assert pos_err < 0.01 and rot_err < 0.1
    # constant speed in a straight line: a clock offset is a shift along it
    with pytest.raises(InputError, match="clock offset is not determined"):
        register_trajectory(c2w, stamps, s2b, body, traj)


def test_registration_failures_are_one_line_errors():
    c2w, stamps, s2b, body, traj, _ = make_log(5)
    cases = []
    cases.append(((c2w[100:102], stamps[100:102], s2b[100:102], body, traj), RegisterOptions(),
                  "only 2 of 2 localised frames"))
    still = np.broadcast_to(body[100], body.shape).copy()  # a robot standing still: every frame in one place
    c_still = ODOM_TO_WORLD @ still[:len(c2w)] @ s2b
    cases.append(((c_still, stamps, s2b, still, traj), RegisterOptions(clock_offset_s=0.0), "lie within .* of one place"))
    noisy, *_ = make_log(6, noise_m=0.15, outliers=0.0)
    cases.append(((noisy, stamps, s2b, body, traj), RegisterOptions(clock_offset_s=CLOCK_OFFSET_S),
                  "registration residual median"))
    other = ODOM_TO_WORLD @ make_se3(Rotation.random(len(c2w), 7).as_matrix(), np.random.default_rng(7).normal(
        0, 2.0, (len(c2w), 3)))  # images from another run
    cases.append(((other, stamps, s2b, body, traj), RegisterOptions(clock_offset_s=0.0), "agree on one odometry frame"))
    late = stamps + 3_600_000_000_000  # an hour later: no frame inside the trajectory
    cases.append(((c2w, late, s2b, body, traj), RegisterOptions(), "inside the odometry trajectory"))
    for args, options, message in cases:
        with pytest.raises(InputError, match=message) as info:
            register_trajectory(*args, options)
        assert "\n" not in str(info.value)
        reg = register_trajectory(*args, options, check=False)
        assert not reg.ok and re.search(message, reg.why)
        assert reg.residual_m.shape == (len(args[0]),)
    with pytest.raises(ValueError, match="sensor_to_body"):
        register_trajectory(c2w, stamps, s2b[:3], body, traj)
    with pytest.raises(ValueError, match="strictly increasing"):
        register_trajectory(c2w, stamps, s2b, body, traj[::-1].copy())


# --------------------------------------------------------------------------------------
# Drift: the pose graph over the odometry
# --------------------------------------------------------------------------------------


def drifted_log(seed: int, faults=None, noise_m: float = 0.01, noise_deg: float = 0.2, outliers: float = 0.1):
    """The figure-of-eight run (16 m in 20 s) with the robot-log generator's drifting odometry (its default
    faults: 1 % scale, 0.2 deg/m heading bias, random walks, the odometry frame 35 deg and 1.4 m off, a 30 ms
    clock offset), two cameras localised at the true poses + noise (per axis) + outliers.

    Returns (cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns, bad, truth body_to_world (N, 4, 4),
    odom_to_world (4, 4), clock_offset_s).
    """
    from nsim.geometry.transforms import interpolate_poses
    from nsim.synth.faulty_robot_log import RobotLogFaults, odom_to_world, odometry_from_truth

    faults = RobotLogFaults() if faults is None else faults
    rng = np.random.default_rng(seed)
    traj_s = np.arange(0.0, DURATION_S, 1.0 / ODOM_HZ)
    traj_ns = 1_700_000_000_000_000_000 + np.round(traj_s * 1e9).astype(np.int64)
    truth = body_to_odom_at(traj_s)  # the true run, in the world
    body_to_odom = odometry_from_truth(truth, traj_s, faults, np.random.default_rng([seed, 1]))
    capture_s = np.arange(0.05, DURATION_S - 0.05, 1.0 / CAMERA_HZ)
    at_capture = interpolate_poses(traj_s, truth, capture_s)
    c2w = np.concatenate([at_capture @ FRONT, at_capture @ RIGHT])
    stamps = np.tile(traj_ns[0] + np.round((capture_s + faults.clock_offset_s) * 1e9).astype(np.int64), 2)
    s2b = np.concatenate([np.broadcast_to(m, at_capture.shape) for m in (FRONT, RIGHT)])
    K = len(c2w)
    c2w[:, :3, 3] += rng.normal(0.0, noise_m, (K, 3))
    c2w[:, :3, :3] = c2w[:, :3, :3] @ Rotation.from_rotvec(rng.normal(0.0, math.radians(noise_deg), (K, 3))).as_matrix()
    bad = rng.random(K) < outliers
    c2w[bad, :3, 3] += rng.uniform(0.3, 2.0, (bad.sum(), 1)) * Rotation.random(bad.sum(), rng).apply([1.0, 0, 0])
    c2w[bad, :3, :3] = Rotation.random(bad.sum(), rng).as_matrix() @ c2w[bad, :3, :3]
    return c2w, stamps, s2b, body_to_odom, traj_ns, bad, truth, odom_to_world(faults), faults.clock_offset_s


def _ate_m(body_to_world: np.ndarray, truth: np.ndarray) -> float:
    """RMS distance of the body positions from the truth, in the world (no alignment)."""
    return float(np.sqrt(np.mean(np.sum((body_to_world[:, :3, 3] - truth[:, :3, 3]) ** 2, axis=-1))))


def test_drift_refinement_recovers_the_odom_frame_that_a_rigid_fit_cannot():
    c2w, stamps, s2b, body, traj, bad, truth, odom_to_world, clock = drifted_log(1)
    # a rigid motion cannot absorb the drift: its residual exceeds the limits (3.9 cm / 1.07 deg median)
    with pytest.raises(InputError, match="registration residual median .* exceeds"):
        register_trajectory(c2w, stamps, s2b, body, traj)
    reg = register_trajectory(c2w, stamps, s2b, body, traj, drift=DriftModel())
    ref = reg.refined
    assert reg.ok and ref is not None
    # the rigid fit (kept in the registration) is off by the drift at the first pose
    rigid_m, rigid_deg = _errors(reg.odom_to_world, odom_to_world)
    assert rigid_m > 0.03 and rigid_deg > 1.0, (rigid_m, rigid_deg)  # measured 5.6 cm, 2.09 deg
    # the refined odometry frame: the acceptance bound (2 cm, 0.5 deg); measured 0.5 cm, 0.06 deg
    pos_err, rot_err = _errors(ref.odom_to_world, odom_to_world)
    assert pos_err < 0.02 and rot_err < 0.5, (pos_err, rot_err)
    np.testing.assert_allclose(ref.odom_to_world, ref.body_to_world[0] @ np.linalg.inv(body[0]), atol=1e-12)
    # its standard error is of the size of the error (measured 0.9 cm, 0.17 deg)
    assert pos_err < 3 * ref.odom_to_world_std_m < 0.06 and rot_err < 3 * ref.odom_to_world_std_deg < 1.0
    # the whole trajectory: ATE 3.5 mm refined against 4.3 cm rigid
    rigid_ate, refined_ate = _ate_m(reg.to_world(body), truth), _ate_m(ref.body_to_world, truth)
    assert refined_ate < 0.2 * rigid_ate and refined_ate < 0.01, (refined_ate, rigid_ate)
    rot = rotation_angle_deg(ref.body_to_world[:, :3, :3], truth[:, :3, :3])
    assert np.sqrt(np.mean(rot ** 2)) < 0.2
    # the systematic drift it found (the generator's: 1 % scale, 0.2 deg/m) and the clock (rigid: 26 ms)
    assert ref.scale_error == pytest.approx(0.01, abs=0.003) and ref.yaw_bias_deg_per_m == pytest.approx(0.2, abs=0.1)
    assert ref.clock_offset_s == pytest.approx(clock, abs=0.002) and 0.0 < ref.clock_offset_std_s < 0.005
    assert abs(reg.clock_offset_s - clock) > 0.003  # the rigid fit's offset, biased by the drift
    # outliers stay out, the residuals are the localisation noise (1 cm, 0.2 deg per axis)
    assert not (ref.inliers & bad).any() and ref.inliers[ref.used & ~bad].mean() > 0.97
    assert ref.median_m < 0.025 and ref.median_deg < 0.4 and ref.drift_m.max() > 0.03
    assert "drift up to" in ref.summary()


def test_drift_refinement_of_exact_data_is_exact():
    from nsim.synth.faulty_robot_log import RobotLogFaults

    faults = dataclasses.replace(RobotLogFaults.none(), odom_frame_yaw_deg=35.0, odom_frame_xyz_m=(1.2, -0.6, 0.5))
    c2w, stamps, s2b, body, traj, _, truth, odom_to_world, _ = drifted_log(2, faults, 0.0, 0.0, 0.0)
    reg = register_trajectory(c2w, stamps, s2b, body, traj, RegisterOptions(clock_offset_s=0.0), drift=DriftModel())
    ref = reg.refined
    pos_err, rot_err = _errors(ref.odom_to_world, odom_to_world)
    assert pos_err < 1e-4 and rot_err < 1e-3  # interpolation of 50 Hz odometry only
    assert _ate_m(ref.body_to_world, truth) < 1e-4 and ref.drift_m.max() < 1e-4
    assert abs(ref.scale_error) < 1e-4 and ref.clock_offset_s == 0.0 and math.isnan(ref.clock_offset_std_s)
    assert ref.inliers.all()


def test_drift_nodes_follow_distance_and_turning():
    # 1 m straight at 1 cm steps, then a turn on the spot of 30 deg in 1 deg steps
    line = make_se3(np.broadcast_to(np.eye(3), (101, 3, 3)), np.stack([np.linspace(0, 1, 101), 0 * np.ones(101),
                                                                       np.zeros(101)], -1))
    turn = make_se3(_yaw(np.arange(1.0, 31.0)[:, None]), np.broadcast_to([1.0, 0.0, 0.0], (30, 3)))
    poses = np.concatenate([line, turn])
    nodes, path_m, turn_rad = drift_nodes(poses, 1.0, 0.1, math.radians(5.0))
    assert path_m[-1] == pytest.approx(1.0) and turn_rad[-1] == pytest.approx(math.radians(30.0))
    # every 10 steps along the line (0.1 m, allowing rounding), then every 5 deg, and the last pose
    assert nodes[0] == 0 and nodes[-1] == len(poses) - 1
    assert np.all(np.diff(path_m[nodes[nodes <= 100]]) >= 0.1 - 1e-9) and 9 <= (nodes <= 100).sum() <= 11
    assert len(nodes[nodes > 100]) == 6
    # a scaled odometry counts metres after the scale
    assert len(drift_nodes(poses[:101], 2.0, 0.1, math.radians(5.0))[0]) > 15
    with pytest.raises(ValueError, match="node_spacing_m"):
        DriftModel(node_spacing_m=0.0)
