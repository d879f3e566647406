"""Skeleton, forward kinematics and pose boxes: hand-computed positions and invariances."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.human.skeleton import (
    JOINT_NAMES,
    PARENTS,
    Skeleton,
    forward_kinematics,
    heading_yaw,
    joint_positions,
    nsim_skeleton,
    pose_aabb,
    pose_obb,
    quat_slerp_wxyz,
    quats_from_matrices,
    rot_z,
)


def _chain() -> Skeleton:
    return Skeleton(("root", "mid", "tip"), np.array([-1, 0, 1]),
                    np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), np.full((3, 3), np.nan))


def test_fk_matches_hand_computed_positions():
    sk = _chain()
    R = np.stack([Rotation.from_euler("z", 90, degrees=True).as_matrix(),
                  Rotation.from_euler("y", 90, degrees=True).as_matrix(), np.eye(3)])
    T = forward_kinematics(sk, R, np.array([1.0, 2.0, 3.0]))
    # root at (1,2,3); mid = root + Rz90 (0,0,1) = (1,2,4); tip = mid + Rz90 Ry90 (1,0,0) = mid + (0,0,-1)
    np.testing.assert_allclose(T[:, :3, 3], [[1, 2, 3], [1, 2, 4], [1, 2, 3]], atol=1e-12)
    np.testing.assert_allclose(T[2, :3, :3], R[0] @ R[1], atol=1e-12)


def test_fk_accepts_quaternions_and_batches():
    sk = nsim_skeleton(1.6)
    rng = np.random.default_rng(0)
    R = Rotation.random(5 * sk.num_joints, random_state=1).as_matrix().reshape(5, sk.num_joints, 3, 3)
    root = rng.normal(size=(5, 3))
    T_mat = forward_kinematics(sk, R, root)
    T_quat = forward_kinematics(sk, quats_from_matrices(R), root)
    assert T_mat.shape == (5, sk.num_joints, 4, 4)
    np.testing.assert_allclose(T_mat, T_quat, atol=1e-12)
    for f in range(5):  # the batch is independent frames
        np.testing.assert_allclose(forward_kinematics(sk, R[f], root[f]), T_mat[f], atol=1e-12)


def test_nsim_skeleton_tree_and_rest_pose():
    sk = nsim_skeleton(1.75)
    assert sk.joint_names == JOINT_NAMES and tuple(sk.parents) == PARENTS
    p = sk.rest_positions_m()
    np.testing.assert_allclose(p[sk.index("left_hip")], [0.0, 0.09, 0.91], atol=1e-12)
    np.testing.assert_allclose(p[sk.index("right_ankle")], [0.0, -0.09, 0.08], atol=1e-12)
    assert p[sk.index("left_wrist"), 1] > 0.5  # T-pose, left is +y
    assert sk.height_m() == pytest.approx(1.72)  # head top at 1.75, soles 3 cm below the toe joints
    short = nsim_skeleton(1.5)
    np.testing.assert_allclose(short.rest_positions_m(), p * (1.5 / 1.75), atol=1e-12)


def test_pose_boxes_contain_the_body_and_obb_follows_heading():
    sk = nsim_skeleton()
    rng = np.random.default_rng(2)
    R = Rotation.from_rotvec(rng.normal(scale=0.3, size=(sk.num_joints, 3))).as_matrix()
    R[0] = np.eye(3)
    T = forward_kinematics(sk, R, np.array([1.0, 2.0, 0.95]))
    lo, hi = pose_aabb(sk, T, padding_m=0.0)
    pts = T[:, :3, 3]
    assert np.all(pts >= lo - 1e-12) and np.all(pts <= hi + 1e-12)
    box0, blo0, bhi0 = pose_obb(sk, T)
    yaw = 0.7
    turned = R.copy()
    turned[0] = rot_z(yaw)
    T_turned = forward_kinematics(sk, turned, np.array([1.0, 2.0, 0.95]))
    box1, blo1, bhi1 = pose_obb(sk, T_turned)
    np.testing.assert_allclose(blo1, blo0, atol=1e-9)
    np.testing.assert_allclose(bhi1, bhi0, atol=1e-9)
    np.testing.assert_allclose(box1[:3, :3], rot_z(yaw), atol=1e-12)
    assert heading_yaw(T_turned[0, :3, :3]) == pytest.approx(yaw)


def test_slerp_endpoints_and_midpoint():
    q0 = quats_from_matrices(np.eye(3))
    q1 = quats_from_matrices(rot_z(1.0))
    np.testing.assert_allclose(quat_slerp_wxyz(q0, q1, 0.0), q0, atol=1e-12)
    np.testing.assert_allclose(quat_slerp_wxyz(q0, q1, 1.0), q1, atol=1e-12)
    np.testing.assert_allclose(quat_slerp_wxyz(q0, -q1, 0.5), quats_from_matrices(rot_z(0.5)), atol=1e-12)


def test_skeleton_rejects_bad_trees():
    with pytest.raises(ValueError, match="parents"):
        Skeleton(("a", "b"), np.array([-1, 1]), np.zeros((2, 3)), np.full((2, 3), np.nan))
    with pytest.raises(ValueError, match="unique"):
        Skeleton(("a", "a"), np.array([-1, 0]), np.zeros((2, 3)), np.full((2, 3), np.nan))


def test_joint_positions_is_fk_translation():
    sk = nsim_skeleton()
    R = np.broadcast_to(np.eye(3), (sk.num_joints, 3, 3))
    np.testing.assert_allclose(joint_positions(sk, R, sk.offsets_m[0]), sk.rest_positions_m())
