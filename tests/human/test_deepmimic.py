"""DeepMimic clips: a file written by the test, errors, and (when pybullet is installed) the shipped walk."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.human.deepmimic import FRAME_COLUMNS, deepmimic_motion_path, read_deepmimic, read_deepmimic_nsim
from nsim.human.motion import LocomotionLoop
from nsim.human.motion_io import load_motion


def _frames(n: int = 4, speed: float = 1.0, knee: float = -0.6) -> list[list[float]]:
    rows = []
    for k in range(n):
        row = [1 / 30 if k < n - 1 else 0.0, speed * k / 30, 0.85, 0.0, 1.0, 0.0, 0.0, 0.0]
        row += [1.0, 0.0, 0.0, 0.0] * 2  # chest, neck
        for _ in range(2):  # right side, then left side
            row += [1.0, 0.0, 0.0, 0.0, knee, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.4]  # hip knee ankle shoulder elbow
        rows.append(row)
    assert all(len(r) == FRAME_COLUMNS for r in rows)
    return rows


def _write(path, frames, loop="wrap"):
    path.write_text(json.dumps({"Loop": loop, "Frames": frames}, indent=1))
    return path


def test_reads_a_deepmimic_file_in_z_up(tmp_path):
    clip = read_deepmimic(_write(tmp_path / "walk.txt", _frames()))
    assert clip.loop and clip.num_frames == 4 and clip.fps == pytest.approx(30.0)
    # y-up (x forward, z right) -> z-up (x forward, y left)
    np.testing.assert_allclose(clip.root_positions_m[:, 2], 0.85)
    np.testing.assert_allclose(clip.root_positions_m[:, 0], np.arange(4) / 30)
    P = clip.joint_positions()
    sk = clip.skeleton
    assert P[0, sk.index("left_hip"), 1] > 0 > P[0, sk.index("right_hip"), 1]  # left is +y
    knee, ankle = P[0, sk.index("right_knee")], P[0, sk.index("right_ankle")]
    assert ankle[0] < knee[0] - 0.1  # a negative DeepMimic knee angle flexes the shin backwards
    elbow, wrist = P[0, sk.index("left_elbow")], P[0, sk.index("left_wrist")]
    assert wrist[0] > elbow[0] + 0.05  # a positive elbow angle brings the forearm forward


def test_retargets_onto_the_nsim_body(tmp_path):
    path = _write(tmp_path / "walk.txt", _frames(6))
    clip = load_motion(path, height_m=1.75)
    assert clip.skeleton.num_joints == 24
    P = clip.joint_positions()
    names = clip.skeleton.joint_names
    # arms hang down (DeepMimic's rest) although the nsim rest pose is a T-pose
    assert P[0, names.index("left_wrist"), 2] < P[0, names.index("left_shoulder"), 2] - 0.3
    assert P[..., 2].min() == pytest.approx(0.03, abs=1e-9)  # feet on the floor
    np.testing.assert_allclose(read_deepmimic_nsim(path).joint_positions(), P)


@pytest.mark.parametrize("frames,message", [
    ([[0.1] * 43, [0.1] * 44], r"Frames\[0\]: expected 44 values \(humanoid3d\), got 43"),
    ([[0.1] * 44, [0.1] * 43 + ["x"]], r"Frames\[1\]\[43\]: expected a finite number, got 'x'"),
])
def test_bad_frames_are_input_errors(tmp_path, frames, message):
    with pytest.raises(InputError, match=message):
        read_deepmimic(_write(tmp_path / "bad.txt", frames))


def test_malformed_json_names_the_line(tmp_path):
    path = tmp_path / "broken.txt"
    path.write_text('{\n"Loop": "wrap",\n"Frames": [[1, 2,]\n}')
    with pytest.raises(InputError, match=r"broken\.txt:3: malformed JSON"):
        read_deepmimic(path)


def test_shipped_walk_clip_moves_at_about_one_metre_per_second():
    pytest.importorskip("pybullet_data")
    clip = read_deepmimic(deepmimic_motion_path("humanoid3d_walk.txt"))
    speed = LocomotionLoop.from_clip(clip).speed_mps
    assert speed == pytest.approx(1.0, abs=0.1)
