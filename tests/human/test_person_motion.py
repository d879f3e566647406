"""A person's motion (nsim.human.person_motion): recorded clips on the reference body, played at any height by
nsim's rule (the speed kept, stride and cycle with the body), their gait for the crowd, their arrays in a run."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.human.bvh import write_bvh
from nsim.human.gait import IDLE_PERIOD_S, default_clip, walk_cycle
from nsim.human.motion import LocomotionLoop, MotionClip
from nsim.human.person_motion import (
    MAX_CLIP_FPS,
    STEADY_TOLERANCE_M,
    clip_at_height,
    clip_data,
    clip_digest,
    clip_from_data,
    load_recorded_clip,
    person_clip_arrays,
    person_clips,
    person_gait,
    unsteadiness_m,
)


def test_a_recorded_walk_plays_at_any_height_as_nsim_s_own_walk(tmp_path):
    """nsim's walk written as a BVH and read back: the crowd gets the speed, stride and cycle nsim's walk has at
    each height (the rule of gait.default_clip), and the render's loop agrees with it."""
    clip = load_recorded_clip(write_bvh(tmp_path / "walk.bvh", default_clip("walk"))).clip
    for height in (1.5, 1.75, 1.95):
        own = LocomotionLoop.from_clip(default_clip("walk", height))
        gait = person_gait("", clip, height)
        assert gait.speed_mps == pytest.approx(1.3, rel=1e-6) and gait.period_s == 0.0
        assert gait.stride_m == pytest.approx(own.stride_m, rel=1e-5)
        played = LocomotionLoop.from_clip(clip_at_height(clip, height))
        assert played.period_s == pytest.approx(own.period_s, rel=1e-5)
        assert clip_at_height(clip, height).skeleton.height_m() == pytest.approx(own.skeleton.height_m(), rel=1e-12)
    # nsim's own clips by name: the walks' stride by the crowd's formula (0), the idle by time
    assert person_gait("walk_slow", None, 1.6) == person_gait("walk_slow", None, 1.9)
    assert person_gait("walk_slow", None, 1.6).speed_mps == 0.8 and person_gait("walk", None, 1.6).stride_m == 0.0
    idle = person_gait("idle", None, 1.6)
    assert idle.speed_mps == 0.0 and idle.period_s == IDLE_PERIOD_S
    assert LocomotionLoop.from_clip(default_clip("idle", 1.6)).period_s == pytest.approx(IDLE_PERIOD_S, rel=1e-12)


def test_a_fast_clip_is_kept_at_about_30_fps_with_its_speed(tmp_path):
    walk = walk_cycle(1.1, fps=120.0)
    read = load_recorded_clip(write_bvh(tmp_path / "fast.bvh", walk))
    assert read.clip.fps == pytest.approx(MAX_CLIP_FPS, rel=0.02) and "resampled from" in read.description
    assert read.clip.duration_s == pytest.approx(walk.duration_s, rel=1e-6)
    assert person_gait("", read.clip, 1.75).speed_mps == pytest.approx(1.1, rel=1e-5)
    assert "resampled" not in load_recorded_clip(write_bvh(tmp_path / "w30.bvh", walk_cycle(1.1))).description


def test_the_plain_form_and_the_run_arrays_give_the_clip_back(tmp_path):
    clip = load_recorded_clip(write_bvh(tmp_path / "walk.bvh", default_clip("walk_fast"))).clip
    data = clip_data(clip)
    again = clip_from_data(data)
    np.testing.assert_array_equal(again.root_positions_m, clip.root_positions_m)
    assert clip_digest(clip_data(again)) == clip_digest(data)  # stored rounded: reading it back changes nothing
    other = load_recorded_clip(write_bvh(tmp_path / "slow.bvh", default_clip("walk_slow"))).clip
    arrays = person_clip_arrays([("a", clip), None, ("b", other), ("a", clip)])
    assert list(arrays["motion_clip"]) == [0, -1, 1, 0] and list(arrays["motion_clip_frames"]) == [
        clip.num_frames, other.num_frames]
    back = person_clips(arrays, 4)
    assert back[1] is None and back[0] is back[3]
    np.testing.assert_allclose(back[2].local_rotations_wxyz, other.local_rotations_wxyz, atol=1e-12)
    assert person_clip_arrays([None, None]) == {} and person_clips({}, 2) == [None, None]
    with pytest.raises(ValueError, match="root_positions_m"):
        clip_from_data({**data, "root_positions_m": data["root_positions_m"][:2]})


def test_a_start_walk_stop_clip_is_unsteady():
    walk = walk_cycle(1.0)
    stand = 30  # a second standing in the first pose, then the walk
    root = np.concatenate([np.repeat(walk.root_positions_m[:1], stand, 0), walk.root_positions_m])
    quats = np.concatenate([np.repeat(walk.local_rotations_wxyz[:1], stand, 0), walk.local_rotations_wxyz])
    start_walk = MotionClip(walk.skeleton, walk.fps, root, quats)
    assert unsteadiness_m(walk) < 0.05 < STEADY_TOLERANCE_M < unsteadiness_m(start_walk)
