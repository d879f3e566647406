"""Pose refinement's kinematics, regulariser and report (``nsim.human.refine``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nsim.human.data import poses_from_joint_transforms
from nsim.human.refine import BodyPoseRefinement, axis_angle_to_matrix, pose_change
from nsim.human.skeleton import forward_kinematics, nsim_skeleton

SKELETON = nsim_skeleton(1.75)


def random_poses(n: int = 4, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rot = Rotation.from_rotvec(rng.normal(scale=0.4, size=(n * 24, 3))).as_quat()[:, [3, 0, 1, 2]]
    return forward_kinematics(SKELETON, rot.reshape(n, 24, 4), rng.normal(size=(n, 3)))


def test_axis_angle_matches_scipy():
    v = np.random.default_rng(1).normal(size=(5, 3))
    R = axis_angle_to_matrix(torch.tensor(v)).numpy()
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    assert torch.equal(axis_angle_to_matrix(torch.zeros(3)), torch.eye(3))


def test_zero_corrections_give_the_poses_back():
    T = random_poses()
    with torch.no_grad():
        out = BodyPoseRefinement(torch.tensor(T), SKELETON.parents)().double().numpy()
    np.testing.assert_allclose(out, T, atol=2e-6)


def test_a_joint_correction_moves_its_descendants_and_keeps_bone_lengths():
    T = random_poses(2)
    m = BodyPoseRefinement(torch.tensor(T), SKELETON.parents)
    elbow = SKELETON.index("left_elbow")
    with torch.no_grad():  # frame 1 turned by 0.3 rad, frame 0 by nothing: about their mean, +-0.15
        m.rotation[1, elbow] = torch.tensor([0.0, 0.0, 0.3])  # about the vertical: the forearm swings
        out = m().double().numpy()
    moved = np.linalg.norm(out[..., :3, 3] - T[..., :3, 3], axis=-1) > 1e-5
    below = {j for j in range(24) if elbow in _ancestors(j)}
    for f in range(2):
        assert set(np.nonzero(moved[f])[0]) == below and below  # the wrist and hand, not the elbow itself
        # the elbow's own frame turned by exactly 0.15 rad
        rel = T[f, elbow, :3, :3].T @ out[f, elbow, :3, :3]
        assert np.degrees(Rotation.from_matrix(rel).magnitude()) == pytest.approx(np.degrees(0.15), abs=1e-3)
    for f in range(2):  # bone lengths unchanged
        p = SKELETON.parents[1:]
        np.testing.assert_allclose(np.linalg.norm(out[f, 1:, :3, 3] - out[f, p, :3, 3], axis=-1),
                                   np.linalg.norm(T[f, 1:, :3, 3] - T[f, p, :3, 3], axis=-1), atol=1e-5)


def _ancestors(j: int) -> list[int]:
    out = []
    while SKELETON.parents[j] >= 0:
        j = int(SKELETON.parents[j])
        out.append(j)
    return out


def test_the_root_translation_shifts_the_whole_body():
    T = random_poses(2)
    m = BodyPoseRefinement(torch.tensor(T), SKELETON.parents)
    with torch.no_grad():
        m.translation[0] = torch.tensor([0.0, 0.04, -0.02])  # against frame 1's zero: +-half of it each
        out = m().double().numpy()
    np.testing.assert_allclose(out[0, :, :3, 3] - T[0, :, :3, 3], np.broadcast_to([0.0, 0.02, -0.01], (24, 3)),
                               atol=1e-5)
    change = pose_change(T, out)
    assert change["joint_shift_cm_mean"] == pytest.approx(100 * np.hypot(0.02, 0.01), abs=1e-3)
    assert change["rotation_deg_max"] < 0.05 and change["frames"] == 2  # float32 rounding only


def test_smoothness_carries_the_neighbours_correction_to_a_frame_without_data():
    """Frames 0 and 2 are pulled to a correction by a data term, 3 and 5 to its opposite; frames 1 and 4
    have none (held-out frames): with the smoothness term they follow their neighbours, without it the
    prior keeps them at zero."""
    T = random_poses(6)
    target = torch.tensor([0.2, -0.1, 0.05])
    ends = {}
    for smooth in (0.0, 1.0):
        m = BodyPoseRefinement(torch.tensor(T), SKELETON.parents)
        opt = torch.optim.Adam(m.parameters(), lr=0.01)
        for _ in range(400):
            r = m.corrections()[0][:, 3]
            data = ((r[[0, 2]] - target) ** 2).sum() + ((r[[3, 5]] + target) ** 2).sum()
            loss = data + m.regulariser(1e-3, 1e-3, smooth)
            opt.zero_grad()
            loss.backward()
            opt.step()
        ends[smooth] = m.corrections()[0].detach()[:, 3]
    assert torch.allclose(ends[1.0][1], target, atol=0.05) and torch.allclose(ends[1.0][4], -target, atol=0.05), ends
    assert ends[0.0][[1, 4]].abs().max() < 0.01, ends


def test_a_correction_every_frame_shares_is_no_correction():
    """The canonical body can absorb a correction common to all frames, so only departures from the mean count."""
    T = random_poses(3)
    m = BodyPoseRefinement(torch.tensor(T), SKELETON.parents)
    with torch.no_grad():
        m.rotation[:, 5] = torch.tensor([0.3, 0.1, -0.2])
        m.translation[:] = torch.tensor([0.1, 0.0, 0.2])
        out = m().double().numpy()
    np.testing.assert_allclose(out, T, atol=2e-6)
    # without the mean taken (a per-frame fit against a frozen body) each frame's own correction applies
    own = BodyPoseRefinement(torch.tensor(T), SKELETON.parents, subtract_mean=False)
    own.load_state_dict(m.state_dict())
    with torch.no_grad():
        moved = own().double().numpy()
        r, t = own.corrections()
    assert torch.equal(r, own.rotation) and torch.equal(t, own.translation)
    np.testing.assert_allclose(moved[:, 0, :3, 3], T[:, 0, :3, 3] + [0.1, 0.0, 0.2], atol=2e-6)
    assert pose_change(T, moved)["rotation_deg_max"] > 10.0


def test_bad_shapes_and_orders_are_refused():
    T = torch.tensor(random_poses(1))
    with pytest.raises(ValueError, match="parents"):
        BodyPoseRefinement(T, SKELETON.parents[:5])
    bad = SKELETON.parents.copy()
    bad[3] = 7
    with pytest.raises(ValueError, match="before its child"):
        BodyPoseRefinement(T, bad)
    with pytest.raises(ValueError, match="two"):
        pose_change(T.numpy(), T.numpy()[:, :3])


def test_refined_poses_round_trip_as_a_poses_file():
    T = random_poses(3)
    poses = poses_from_joint_transforms(SKELETON, 1.75, T, file_paths=("a", "b", "c"))
    np.testing.assert_allclose(poses.joint_transforms(), T, atol=1e-12)
    assert poses.height_m == 1.75 and poses.file_paths == ("a", "b", "c")
