"""BVH reader and writer: round trips, per-joint Euler orders, units, and malformed files."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.human.bvh import BVH_Y_UP_TO_NSIM, parse_bvh, read_bvh, write_bvh
from nsim.human.gait import walk_cycle
from nsim.human.motion import MotionClip
from nsim.human.skeleton import nsim_skeleton, quats_from_matrices

SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 50 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 50 0
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 10 -5 0
    CHANNELS 3 Yrotation Xrotation Zrotation
    End Site
    {
      OFFSET 0 -90 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 95 0 0 0 0 0 0 0 0 0 0
1 95 0 10 20 30 5 15 25 40 -30 60
"""


def _positions_by_name(clip: MotionClip) -> dict[str, np.ndarray]:
    P = clip.joint_positions()
    return {n: P[:, i] for i, n in enumerate(clip.joint_names)}


def _random_clip(frames: int = 6, seed: int = 0) -> MotionClip:
    sk = nsim_skeleton(1.8)
    R = Rotation.random(frames * sk.num_joints, random_state=seed).as_matrix().reshape(frames, sk.num_joints, 3, 3)
    root = np.random.default_rng(seed).normal(size=(frames, 3))
    return MotionClip(sk, 30.0, root, quats_from_matrices(R))


@pytest.mark.parametrize("order", ["ZXY", "XYZ", "YZX"])
@pytest.mark.parametrize("unit", ["cm", "m"])
def test_write_read_round_trip_gives_identical_joint_positions(tmp_path, order, unit):
    clip = _random_clip()
    path = write_bvh(tmp_path / "clip.bvh", clip, unit=unit, euler_order=order)
    back = read_bvh(path)
    assert back.num_frames == clip.num_frames and back.fps == pytest.approx(30.0, rel=1e-6)
    got = _positions_by_name(back)
    want = _positions_by_name(clip)
    assert set(got) == set(want)
    err = max(np.abs(got[n] - want[n]).max() for n in want)
    assert err <= 1e-6


def test_round_trip_of_a_generated_walk(tmp_path):
    clip = walk_cycle(1.3)
    back = read_bvh(write_bvh(tmp_path / "walk.bvh", clip))
    got, want = _positions_by_name(back), _positions_by_name(clip)
    assert max(np.abs(got[n] - want[n]).max() for n in want) <= 1e-6


def test_per_joint_euler_orders_and_centimetres():
    clip = parse_bvh(SMALL, "small.bvh")
    assert clip.joint_names == ("Hips", "Spine", "LeftUpLeg")
    assert clip.fps == pytest.approx(1 / 0.0333333)
    # reference FK in the file's axes (cm), then to nsim axes and metres
    r_hips = Rotation.from_euler("ZXY", [10, 20, 30], degrees=True).as_matrix()
    r_leg = Rotation.from_euler("YXZ", [40, -30, 60], degrees=True).as_matrix()
    root = np.array([1.0, 95.0, 0.0])
    leg = root + r_hips @ np.array([10.0, -5.0, 0.0])
    leg_end = leg + r_hips @ r_leg @ np.array([0.0, -90.0, 0.0])
    T = clip.joint_transforms()
    A = BVH_Y_UP_TO_NSIM
    np.testing.assert_allclose(T[1, 0, :3, 3], A @ root / 100, atol=1e-12)
    np.testing.assert_allclose(T[1, 2, :3, 3], A @ leg / 100, atol=1e-12)
    end = T[1, 2, :3, :3] @ clip.skeleton.end_sites_m[2] + T[1, 2, :3, 3]
    np.testing.assert_allclose(end, A @ leg_end / 100, atol=1e-12)


def test_unit_detection_metres_equals_centimetres():
    metres = re.sub(r"OFFSET .*", lambda m: "OFFSET " + " ".join(repr(float(v) / 100) for v in m.group().split()[1:]),
                    SMALL.split("MOTION")[0])
    frames = SMALL.split("MOTION")[1].splitlines()
    rows = [" ".join(repr(float(v) / 100) if i < 3 else v for i, v in enumerate(r.split())) for r in frames[3:]]
    text = metres + "MOTION" + "\n".join(frames[:3]) + "\n" + "\n".join(rows) + "\n"
    a, b = parse_bvh(SMALL, "cm.bvh"), parse_bvh(text, "m.bvh")
    np.testing.assert_allclose(a.joint_positions(), b.joint_positions(), atol=1e-12)
    np.testing.assert_allclose(parse_bvh(text, "explicit.bvh", unit="m").joint_positions(), b.joint_positions())
    with pytest.raises(InputError, match="cannot tell the length unit"):
        parse_bvh(SMALL.replace("OFFSET 0 -90 0", "OFFSET 0 -9000000 0"), "huge.bvh")


def _mutate(old: str, new: str) -> str:
    assert old in SMALL
    return SMALL.replace(old, new, 1)


MALFORMED = [
    ("missing brace", _mutate("  JOINT Spine\n  {\n", "  JOINT Spine\n"), 7, "expected '{' after joint 'Spine'"),
    ("channel count", _mutate("CHANNELS 3 Zrotation Xrotation Yrotation\n    End",
                              "CHANNELS 3 Zrotation Xrotation\n    End"), 10, "declares 3 channels but lists 2"),
    ("values per frame", _mutate("1 95 0 10 20 30 5 15 25 40 -30 60", "1 95 0 10 20 30 5 15 25 40 -30"), 29,
     "frame 1 has 11 values, expected 12"),
    ("non-numeric", _mutate("1 95 0 10 20 30", "1 95 0 ten 20 30"), 29, "value 'ten' is not a number"),
    ("frame count", _mutate("Frames: 2", "Frames: 3"), 29, "declares 3 frames but 2 frame lines follow"),
    ("unknown keyword", _mutate("    End Site\n    {\n      OFFSET 0 50 0", "    Ending Site\n    {\n      OFFSET 0 50 0"),
     10, "unexpected 'Ending' in joint 'Spine'"),
    ("second root", SMALL.replace("MOTION", "ROOT Other\n{\n}\nMOTION"), 25, "second ROOT"),
    ("bad offset", _mutate("OFFSET 10 -5 0", "OFFSET 10 x 0"), 17, "OFFSET of joint 'LeftUpLeg': 'x' is not a number"),
    ("no motion", SMALL.split("MOTION")[0], 24, "no MOTION section"),
    ("bad frame time", _mutate("Frame Time: 0.0333333", "Frame Time: -1"), 27, "Frame Time: expected a duration > 0"),
]


@pytest.mark.parametrize("text,line,message", [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED])
def test_malformed_bvh_raises_input_error_with_file_and_line(tmp_path, text, line, message):
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_bvh(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:{line}: "), msg
    assert message in msg
    assert "\n" not in msg


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_bvh(tmp_path / "nope.bvh")
