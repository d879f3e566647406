"""Procedural gait: requested speed, speed relations, closed loops, planted feet, shipped clips."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from nsim.human.bvh import format_bvh, parse_bvh
from nsim.human.gait import DEFAULT_CLIPS, cadence_steps_per_min, default_clip, idle_cycle, turn, walk_cycle
from nsim.human.gait_phase import stride_length_m
from nsim.human.motion import LocomotionLoop
from nsim.human.skeleton import heading_yaw

MOTIONS = Path(__file__).resolve().parents[2] / "nsim" / "configs" / "motions"


@pytest.mark.parametrize("speed", [0.8, 1.3, 1.8])
def test_walk_root_speed_matches_the_request(speed):
    clip = walk_cycle(speed)
    root = clip.root_positions_m
    measured = np.linalg.norm(root[-1, :2] - root[0, :2]) / clip.duration_s
    assert measured == pytest.approx(speed, rel=0.02)
    assert LocomotionLoop.from_clip(clip).speed_mps == pytest.approx(speed, rel=0.02)
    # the stride is the crowd simulator's, so its gait phase plays the clip without sliding
    assert np.linalg.norm(root[-1, :2] - root[0, :2]) == pytest.approx(stride_length_m(speed), rel=1e-9)


def test_cadence_grows_with_speed_in_the_measured_range():
    cadences = [cadence_steps_per_min(v) for v in (0.8, 1.3, 1.8)]
    assert cadences == sorted(cadences)
    assert 80 < cadences[0] < 95 and 100 < cadences[1] < 120 and 115 < cadences[2] < 140


def test_walk_cycle_closes_and_feet_stay_planted():
    clip = walk_cycle(1.3)
    q = clip.local_rotations_wxyz
    np.testing.assert_allclose(np.abs(np.sum(q[0] * q[-1], axis=-1)), 1.0, atol=1e-12)
    P = clip.joint_positions()
    names = clip.skeleton.joint_names
    assert P[..., 2].min() >= 0.03 - 1e-9  # nothing below the sole height
    ball = P[:, names.index("left_foot")]
    planted = ball[:, 2] < 0.03 + 1e-6
    assert planted.sum() >= 0.3 * len(ball)
    assert np.ptp(ball[planted, 0]) < 1e-6  # the stance foot does not slide
    # the left foot is ahead at phase 0 (left heel strike), the right one at 0.5
    half = clip.num_frames // 2
    assert P[0, names.index("left_ankle"), 0] > P[0, names.index("right_ankle"), 0]
    assert P[half, names.index("right_ankle"), 0] > P[half, names.index("left_ankle"), 0]


def test_idle_and_turn():
    idle = idle_cycle()
    assert np.abs(idle.root_positions_m[:, :2]).max() < 0.05
    assert LocomotionLoop.from_clip(idle).speed_mps == 0.0
    clip = turn(1.0, 45.0, 2.0)
    yaw = np.unwrap(heading_yaw(clip.rotation_matrices()[:, 0]))
    assert yaw[-1] - yaw[0] == pytest.approx(np.radians(90.0), abs=np.radians(15.0))


@pytest.mark.parametrize("name", list(DEFAULT_CLIPS))
def test_shipped_clips_equal_a_regeneration(name):
    """The shipped clip and one regenerated here agree as numbers (last bits differ between CPUs): the same
    hierarchy text, the same frames, joints within 1e-6 m and rotations within 1e-6 rad."""
    shipped_text = (MOTIONS / f"{name}.bvh").read_text()
    fresh_text = format_bvh(default_clip(name))
    hint = f"regenerate with: python -m nsim.human.gait {MOTIONS}"
    assert shipped_text.split("MOTION")[0] == fresh_text.split("MOTION")[0], hint
    shipped, fresh = parse_bvh(shipped_text, unit="cm"), parse_bvh(fresh_text, unit="cm")
    assert shipped.num_frames == fresh.num_frames and shipped.fps == pytest.approx(fresh.fps, rel=1e-9), hint
    np.testing.assert_allclose(shipped.joint_positions(), fresh.joint_positions(), atol=1e-6, err_msg=hint)
    np.testing.assert_allclose(shipped.rotation_matrices(), fresh.rotation_matrices(), atol=1e-6, err_msg=hint)
    assert not _negative_zeros(shipped_text), "a -0 in the shipped text"


def _negative_zeros(text: str) -> list[str]:
    return [t for t in text.split() if t.startswith("-") and t[1:].replace(".", "").isdigit() and float(t) == 0.0]


def test_bvh_text_has_no_negative_zero():
    clip = default_clip("walk")
    tiny = dataclasses.replace(clip, root_positions_m=clip.root_positions_m * 0.0 - 1e-12)
    text = format_bvh(tiny)
    assert not _negative_zeros(text) and " 0.000000" in text
    assert _negative_zeros("1 -0.000000 2") == ["-0.000000"]
