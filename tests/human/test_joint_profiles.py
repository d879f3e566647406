"""Each common BVH joint naming (CMU in cgspeed's three releases, Mixamo) maps nearly all of the nsim body's
joints through the shipped joint map, and a left knee bent in the file bends the nsim body's left knee."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.human.bvh import UNITS_M, load_bvh, read_bvh, write_bvh
from nsim.human.motion import MotionClip
from nsim.human.retarget import default_joint_map, retarget
from nsim.human.skeleton import nsim_skeleton, quat_about_z_wxyz
from tests.human.namings import NAMINGS, renamed

BODY = nsim_skeleton()
FRAMES = 5
KNEE_DEG = np.array([0.0, 20.0, 40.0, 60.0, 80.0])


def _knee_bend_clip() -> MotionClip:
    """The nsim body standing, its left knee bending from 0 to 80 degrees (about +y: the shin goes back)."""
    q = np.zeros((FRAMES, BODY.num_joints, 4))
    q[..., 0] = 1.0
    half = np.radians(KNEE_DEG) / 2.0
    q[:, BODY.index("left_knee")] = np.stack([np.cos(half), 0 * half, np.sin(half), 0 * half], axis=1)
    q[:, 0] = quat_about_z_wxyz(np.full(FRAMES, 0.3))  # turned a little: sides must not depend on the heading
    root = np.tile([0.0, 0.0, BODY.offsets_m[0, 2]], (FRAMES, 1))
    return MotionClip(BODY, 30.0, root, q)


def _bend_deg(P: np.ndarray, side: str) -> np.ndarray:
    hip, knee, ankle = (P[:, BODY.index(f"{side}_{n}")] for n in ("hip", "knee", "ankle"))
    a, b = knee - hip, ankle - knee
    cos = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize(("naming", "unit", "mapped"), [("cmu", "cmu", 23), ("biped", "cmu", 24), ("daz", "cm", 21),
                                                        ("mixamo", "cm", 24)])
def test_each_naming_maps_the_body_and_bends_the_left_knee(tmp_path, naming, unit, mapped):
    path = write_bvh(tmp_path / f"{naming}.bvh", renamed(_knee_bend_clip(), naming), unit=unit)
    found = load_bvh(path)  # the unit measured from the skeleton
    assert found.unit_found is not None and found.unit_m == UNITS_M[unit]
    source = found.clip
    assert source.skeleton.leg_length_m() == pytest.approx(BODY.leg_length_m(), rel=1e-6)
    profile, mapping = default_joint_map().resolve_profile(source.skeleton, BODY)
    assert profile == naming and len(mapping) == mapped >= 20
    for joint, index in mapping.items():  # every mapped joint is the one the naming gives it
        assert source.skeleton.joint_names[index] == NAMINGS[naming][BODY.joint_names[joint]]
    P = retarget(source, BODY, ground_feet=False).joint_positions()
    np.testing.assert_allclose(_bend_deg(P, "left"), KNEE_DEG, atol=0.01)
    np.testing.assert_allclose(_bend_deg(P, "right"), 0.0, atol=0.01)
    # the left shin goes back (the body faces +x turned 0.3 rad): the left ankle behind its knee, on the left
    forward = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    left = np.array([-np.sin(0.3), np.cos(0.3), 0.0])
    ankle, knee = P[-1, BODY.index("left_ankle")], P[-1, BODY.index("left_knee")]
    assert (ankle - knee) @ forward < -0.3 and P[-1, BODY.index("left_ankle")] @ left > 0.05


def test_a_biped_file_is_not_read_with_cmu_s_collar_for_an_arm(tmp_path):
    """The 3dsMax-friendly release's LeftShoulder is the upper arm (the MotionBuilder release's is the collar)."""
    path = write_bvh(tmp_path / "max.bvh", renamed(_knee_bend_clip(), "biped"), unit="cmu")
    source = read_bvh(path)
    profile, mapping = default_joint_map().resolve_profile(source.skeleton, BODY)
    assert profile == "biped"
    assert source.skeleton.joint_names[mapping[BODY.index("left_shoulder")]] == "LeftShoulder"
    assert source.skeleton.joint_names[mapping[BODY.index("left_collar")]] == "LeftCollar"
