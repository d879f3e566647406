"""The canonical body's priors (nsim.human.shape_prior): cross-section frames and turns, the mirror, where a
point was seen from, and the points they are drawn on."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch.testing import assert_close

from nsim.geometry.transforms import look_at
from nsim.human.nerf import gait_cycle_poses
from nsim.human.shape_prior import (
    bone_frames,
    cameras_in_canonical,
    cross_section,
    mirror_left_right,
    nearest_bone,
    outward,
    sample_near_bones,
    seen_fraction,
    trunk_joints,
    turn_cross_section,
)
from nsim.human.skeleton import nsim_skeleton


@pytest.fixture(scope="module")
def skeleton():
    return nsim_skeleton(1.75)


def test_trunk_is_the_pelvis_and_spine(skeleton):
    names = {skeleton.joint_names[j] for j in np.nonzero(trunk_joints(skeleton))[0]}
    assert names == {"pelvis", "spine1", "spine2", "spine3"}


def test_frames_are_orthonormal_with_depth_forward(skeleton):
    f = bone_frames(skeleton, trunk_aspect=0.6)
    basis = torch.stack([f.axis, f.lateral, f.depth], dim=1)  # (B, 3, 3)
    assert_close(basis @ basis.transpose(1, 2), torch.eye(3).expand_as(basis), atol=1e-5, rtol=0)
    shin = skeleton.index("left_knee")
    b = int(torch.nonzero(f.joint == shin)[0, 0])
    assert_close(f.depth[b], torch.tensor([1.0, 0.0, 0.0]), atol=1e-6, rtol=0)  # a vertical bone: depth is +x
    assert f.aspect[b] == 1.0 and f.weight[b] == pytest.approx(1.0)
    toes = int(torch.nonzero(f.joint == skeleton.index("left_foot"))[0, 0])
    assert f.weight[toes] < 0.05  # along +x: nothing hidden in its cross-section
    spine = int(torch.nonzero(f.joint == skeleton.index("spine2"))[0, 0])
    assert f.aspect[spine] == pytest.approx(0.6)


def test_turns_keep_the_scaled_radius_and_come_back(skeleton):
    f = bone_frames(skeleton, trunk_aspect=0.65)
    g = torch.Generator().manual_seed(0)
    p, bone = sample_near_bones(f, 500, 0.2, g)
    angle = 2 * math.pi * torch.rand(500, generator=g)
    q = turn_cross_section(p, bone, f, angle)
    u0, l0, d0 = cross_section(p, bone, f)
    u1, l1, d1 = cross_section(q, bone, f)
    k = f.aspect[bone]
    assert_close(u1, u0, atol=1e-5, rtol=0)  # along the bone: unchanged
    assert_close(l1**2 + (d1 / k) ** 2, l0**2 + (d0 / k) ** 2, atol=1e-5, rtol=0)  # on the same ellipse
    assert_close(turn_cross_section(q, bone, f, -angle), p, atol=1e-5, rtol=0)
    # a quarter turn takes the width the camera sees in front (lateral) to the depth it does not
    quarter = turn_cross_section(p, bone, f, torch.full((500,), math.pi / 2))
    assert_close(cross_section(quarter, bone, f)[2], k * l0, atol=1e-5, rtol=0)


def test_points_lie_near_their_bones(skeleton):
    f = bone_frames(skeleton)
    p, bone = sample_near_bones(f, 2000, 0.15, torch.Generator().manual_seed(1))
    from nsim.human.nerf import point_segment_distance

    d = point_segment_distance(p, f.start, f.end)[torch.arange(2000), bone]
    assert float(d.max()) <= 0.15 + 1e-5
    near, dist = nearest_bone(p, f)
    assert torch.all(dist <= d + 1e-6)
    assert float((near == bone).float().mean()) > 0.5


def test_mirror_swaps_left_and_right(skeleton):
    rest = torch.as_tensor(skeleton.rest_transforms()[:, :3, 3], dtype=torch.float32)
    mirrored = mirror_left_right(rest, skeleton)
    for j, name in enumerate(skeleton.joint_names):
        twin = name.replace("left", "@").replace("right", "left").replace("@", "right")
        assert_close(mirrored[j], rest[skeleton.index(twin)], atol=1e-6, rtol=0)
    assert_close(mirror_left_right(mirrored, skeleton), rest)


def test_seen_fraction_front_and_back(skeleton):
    """A camera always in front of a walking body (3 m ahead of the pelvis, whatever the pose): the chest's front
    was seen in every frame, its back in none; the cameras carried into the canonical frame by the joints."""
    T = gait_cycle_poses(skeleton, 8)
    pelvis = T[:, 0, :3, 3]
    c2w = np.stack([look_at(p + np.array([3.0, 0.0, 0.3]), p) for p in pelvis])
    cams = cameras_in_canonical(torch.as_tensor(T, dtype=torch.float32),
                                torch.as_tensor(skeleton.rest_transforms(), dtype=torch.float32),
                                torch.as_tensor(c2w, dtype=torch.float32))
    assert cams.shape == (8, skeleton.num_joints, 3)
    f = bone_frames(skeleton)
    chest = int(torch.nonzero(f.joint == skeleton.index("spine2"))[0, 0])
    mid = f.start[chest] + 0.5 * f.length_m[chest] * f.axis[chest]
    pts = torch.stack([mid + torch.tensor([0.1, 0.0, 0.0]), mid - torch.tensor([0.1, 0.0, 0.0])])
    bone = torch.tensor([chest, chest])
    normals = outward(pts, bone, f)
    assert_close(normals, torch.tensor([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]), atol=1e-5, rtol=0)
    seen = seen_fraction(pts, normals, f.joint[bone], cams)
    assert seen.tolist() == [1.0, 0.0]
