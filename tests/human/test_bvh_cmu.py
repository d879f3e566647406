"""CMU motion capture BVH (the cgspeed conversion): its units, its joint names onto the nsim body,
skeletons too few of whose joints map, and exporters' position channels.

The test writes CMU's skeleton (its joint names, tree and offsets, in CMU's unit of 1/0.45 inch:
about 7 units per leg bone, 24.6 units tall) with a walk-like motion generated here.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.human.bvh import BVH_Y_UP_TO_NSIM, UNITS_M, read_bvh
from nsim.human.motion import LocomotionLoop
from nsim.human.motion_io import load_motion
from nsim.human.skeleton import JOINT_NAMES, end_site_positions, forward_kinematics, nsim_skeleton
from nsim.synth.actor import Actor

A = BVH_Y_UP_TO_NSIM
CMU_UNIT_M = 0.0254 / 0.45
FPS, FRAMES, SPEED_MPS = 30.0, 31, 1.2
KNEE_DEG = 50.0

# (name, parent, OFFSET, End Site or None) in the file's units and axes (y up, facing +z, left +x), as
# in CMU's BVH: a T-pose with the legs splayed 20 degrees, Neck and shoulders at the chest's origin.
CMU_SKELETON = (
    ("Hips", None, (0.0, 0.0, 0.0), None),
    ("LHipJoint", "Hips", (0.0, 0.0, 0.0), None),
    ("LeftUpLeg", "LHipJoint", (1.85590, -1.73949, 0.84976), None),
    ("LeftLeg", "LeftUpLeg", (2.36836, -6.50702, 0.0), None),
    ("LeftFoot", "LeftLeg", (2.53268, -6.95849, 0.0), None),
    ("LeftToeBase", "LeftFoot", (0.15935, -0.43781, 1.94506), (0.0, 0.0, 1.00661)),
    ("RHipJoint", "Hips", (0.0, 0.0, 0.0), None),
    ("RightUpLeg", "RHipJoint", (-1.68297, -1.73949, 0.84976), None),
    ("RightLeg", "RightUpLeg", (-2.44709, -6.72334, 0.0), None),
    ("RightFoot", "RightLeg", (-2.43843, -6.69953, 0.0), None),
    ("RightToeBase", "RightFoot", (-0.20854, -0.57295, 2.02172), (0.0, 0.0, 1.05594)),
    ("LowerBack", "Hips", (0.0, 0.0, 0.0), None),
    ("Spine", "LowerBack", (-0.01560, 2.23971, -0.03712), None),
    ("Spine1", "Spine", (0.05490, 2.19225, -0.19086), None),
    ("Neck", "Spine1", (0.0, 0.0, 0.0), None),
    ("Neck1", "Neck", (-0.12403, 1.43168, 0.27585), None),
    ("Head", "Neck1", (0.17855, 1.46173, -0.32578), (0.07217, 1.51590, -0.14537)),
    ("LeftShoulder", "Spine1", (0.0, 0.0, 0.0), None),
    ("LeftArm", "LeftShoulder", (3.27650, 0.85634, 0.05396), None),
    ("LeftForeArm", "LeftArm", (4.96755, 0.0, 0.0), None),
    ("LeftHand", "LeftForeArm", (3.35751, 0.0, 0.0), None),
    ("LeftFingerBase", "LeftHand", (0.0, 0.0, 0.0), None),
    ("LeftHandIndex1", "LeftFingerBase", (0.79697, 0.0, 0.0), (0.64254, 0.0, 0.0)),
    ("LThumb", "LeftHand", (0.0, 0.0, 0.0), (0.65235, 0.0, 0.65235)),
    ("RightShoulder", "Spine1", (0.0, 0.0, 0.0), None),
    ("RightArm", "RightShoulder", (-3.24434, 1.02034, 0.34688), None),
    ("RightForeArm", "RightArm", (-5.21859, 0.0, 0.0), None),
    ("RightHand", "RightForeArm", (-3.36504, 0.0, 0.0), None),
    ("RightFingerBase", "RightHand", (0.0, 0.0, 0.0), None),
    ("RightHandIndex1", "RightFingerBase", (-0.62044, 0.0, 0.0), (-0.50022, 0.0, 0.0)),
    ("RThumb", "RightHand", (0.0, 0.0, 0.0), (-0.50786, 0.0, 0.50786)),
)


def _phase() -> np.ndarray:
    return 2.0 * np.pi * np.arange(FRAMES) / (FRAMES - 1)  # one stride


def _walk_angles() -> dict[str, np.ndarray]:
    """Channel values (F, 3) in CMU's order Zrotation Yrotation Xrotation, degrees.

    The thighs turn 20 degrees about z to stand under the body and swing about x (negative: forward);
    a knee's positive x rotation bends it (the foot goes back): the left knee is straight at
    frame 0 and bent ``KNEE_DEG`` half a stride later, the right knee the other way round.
    """
    ph = _phase()
    zero = np.zeros_like(ph)
    a = {name: np.zeros((FRAMES, 3)) for name, *_ in CMU_SKELETON}
    a["Hips"] = np.stack([zero, 4.0 * np.sin(ph), zero], axis=1)
    a["LeftUpLeg"] = np.stack([zero - 20.0, zero, -25.0 * np.sin(ph)], axis=1)
    a["RightUpLeg"] = np.stack([zero + 20.0, zero, 25.0 * np.sin(ph)], axis=1)
    a["LeftLeg"] = np.stack([zero, zero, KNEE_DEG * (1.0 - np.cos(ph)) / 2.0], axis=1)
    a["RightLeg"] = np.stack([zero, zero, KNEE_DEG * (1.0 + np.cos(ph)) / 2.0], axis=1)
    a["LeftArm"] = np.stack([zero - 75.0, -15.0 * np.sin(ph), zero], axis=1)  # arms down, swinging
    a["RightArm"] = np.stack([zero + 75.0, -15.0 * np.sin(ph), zero], axis=1)
    return a


def _write_bvh(path, joints=CMU_SKELETON, scale: float = 1.0, position_channels: bool = False,
               angles: dict[str, np.ndarray] | None = None):
    """Write ``joints`` (offsets times ``scale``) walking along +z at ``SPEED_MPS`` (in CMU units times ``scale``).

    position_channels: every joint gets ``Xposition Yposition Zposition`` (as some exporters
    write), with values that differ from its OFFSET.
    """
    angles = _walk_angles() if angles is None else angles
    children: dict[str | None, list[int]] = {}
    for i, (_, parent, _, _) in enumerate(joints):
        children.setdefault(parent, []).append(i)
    lines, order = ["HIERARCHY"], []

    def fmt(v) -> str:
        return " ".join(f"{x:.6f}" for x in v)

    def emit(i: int, depth: int) -> None:
        name, parent, off, end = joints[i]
        order.append(i)
        pad = "\t" * depth
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(f"{pad}\tOFFSET {fmt(np.asarray(off) * scale)}")
        six = parent is None or position_channels
        lines.append(f"{pad}\tCHANNELS {6 if six else 3} {'Xposition Yposition Zposition ' if six else ''}"
                     "Zrotation Yrotation Xrotation")
        for c in children.get(name, []):
            emit(c, depth + 1)
        if not children.get(name):
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {fmt(np.asarray(end or (0, 0, 0)) * scale)}",
                          f"{pad}\t}}"])
        lines.append(pad + "}")

    emit(0, 0)
    t = np.arange(FRAMES) / FPS
    root = np.stack([np.zeros(FRAMES), 16.0 + 0.2 * np.cos(2.0 * _phase()), SPEED_MPS / CMU_UNIT_M * t], axis=1) * scale
    lines += ["MOTION", f"Frames: {FRAMES}", f"Frame Time: {1.0 / FPS:.8f}"]
    for f in range(FRAMES):
        vals: list[float] = []
        for i in order:
            name, parent, off, _ = joints[i]
            if parent is None:
                vals += list(root[f])
            elif position_channels:
                vals += list(np.asarray(off) * scale + 0.25)
            vals += list(angles.get(name, np.zeros((FRAMES, 3)))[f])
        lines.append(fmt(vals))
    path.write_text("\n".join(lines) + "\n")
    return path


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (F,) between directions a and b (F, 3)."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_cmu_unit_is_measured_from_the_skeleton(tmp_path):
    path = _write_bvh(tmp_path / "cmu_walk.bvh")
    clip = read_bvh(path)  # "auto": no metric unit gives a body 24.6 units tall; the legs give CMU's unit
    sk = clip.skeleton
    assert UNITS_M["cmu"] == pytest.approx(CMU_UNIT_M)
    np.testing.assert_allclose(sk.offsets_m[sk.index("LeftLeg")], A @ np.array([2.36836, -6.50702, 0.0]) * CMU_UNIT_M,
                               atol=1e-12)
    assert sk.height_m() == pytest.approx(1.387, abs=0.005)  # CMU's joints, floor to the head's end site
    np.testing.assert_allclose(np.diff(clip.root_positions_m[:, 0]) * FPS, SPEED_MPS, rtol=1e-5)  # +z -> +x
    # an explicit unit or scale is taken as given
    assert read_bvh(path, unit="inch").skeleton.height_m() == pytest.approx(sk.height_m() * 0.45)
    assert read_bvh(path, unit=0.1).skeleton.height_m() == pytest.approx(sk.height_m() / CMU_UNIT_M * 0.1)


def test_an_odd_unit_is_derived_from_the_legs_and_absurd_proportions_cannot_tell(tmp_path):
    # CMU's skeleton times 0.6, a unit no name fits: the nsim body's leg length sets the scale
    clip = read_bvh(_write_bvh(tmp_path / "odd.bvh", scale=0.6))
    assert clip.skeleton.leg_length_m() == pytest.approx(nsim_skeleton().leg_length_m(), rel=1e-9)
    # legs a twentieth of the trunk: not a body, so the unit cannot be told
    stumpy = tuple((n, p, np.asarray(o) / (20.0 if n.endswith(("Leg", "Foot", "ToeBase")) else 1.0), e)
                   for n, p, o, e in CMU_SKELETON)
    path = _write_bvh(tmp_path / "stumpy.bvh", joints=stumpy)
    with pytest.raises(InputError) as info:
        read_bvh(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: cannot tell the length unit") and "\n" not in msg
    assert read_bvh(path, unit="cmu").num_frames == FRAMES  # given explicitly, it reads


def test_cmu_walk_loads_onto_the_nsim_body_and_drives_a_person(tmp_path):
    path = _write_bvh(tmp_path / "cmu_walk.bvh")
    clip = load_motion(path, height_m=1.75)
    sk = clip.skeleton
    assert sk.joint_names == JOINT_NAMES and clip.num_frames == FRAMES and clip.fps == pytest.approx(FPS)
    # retargeting scales root motion by leg length, so the file's unit does not change the clip
    for unit in ("cmu", "inch", 0.05):
        np.testing.assert_allclose(load_motion(path, height_m=1.75, unit=unit).joint_positions(),
                                   clip.joint_positions(), atol=1e-9)

    T = clip.joint_transforms()
    P = T[..., :3, 3]
    z = {n: P[:, sk.index(n), 2] for n in JOINT_NAMES}
    # feet on the ground: the lowest joint of the clip is at the soles' height, and every frame stands on a foot
    assert P[..., 2].min() == pytest.approx(nsim_skeleton(1.75).rest_positions_m()[:, 2].min(), abs=1e-9)
    feet = np.minimum.reduce([z["left_foot"], z["right_foot"], z["left_ankle"], z["right_ankle"]])
    assert feet.max() < 0.10, feet
    # a 1.75 m person: the top of the head at about 1.7 m, upright, the pelvis at hip height
    head_top = end_site_positions(sk, T)[:, sk.index("head"), 2]
    assert np.all((head_top > 1.6) & (head_top < 1.8)), head_top
    assert np.all((z["pelvis"] > 0.85) & (z["pelvis"] < 1.02)), z["pelvis"]
    for side in ("left", "right"):  # arms hang down (CMU's rest is a T-pose, these frames lower the arms)
        assert np.all(z[f"{side}_wrist"] < z[f"{side}_shoulder"] - 0.3)

    # knees bend as the source's do, by the same angle
    src = read_bvh(path)
    Q = src.joint_positions()
    for side, cmu in (("left", "Left"), ("right", "Right")):
        hip, knee, ankle = (P[:, sk.index(f"{side}_{n}")] for n in ("hip", "knee", "ankle"))
        bend = _angle_deg(knee - hip, ankle - knee)
        s_hip, s_knee, s_ankle = (Q[:, src.skeleton.index(f"{cmu}{n}")] for n in ("UpLeg", "Leg", "Foot"))
        np.testing.assert_allclose(bend, _angle_deg(s_knee - s_hip, s_ankle - s_knee), atol=0.5)
    left = _angle_deg(P[:, sk.index("left_knee")] - P[:, sk.index("left_hip")],
                      P[:, sk.index("left_ankle")] - P[:, sk.index("left_knee")])
    right = _angle_deg(P[:, sk.index("right_knee")] - P[:, sk.index("right_hip")],
                       P[:, sk.index("right_ankle")] - P[:, sk.index("right_knee")])
    half = FRAMES // 2
    assert left[0] < 5.0 and right[0] > 35.0  # left straight, right bent
    assert left[half] > 35.0 and right[half] < 5.0  # half a stride later, the other way round
    assert P[0, sk.index("right_ankle"), 0] < P[0, sk.index("right_knee"), 0] - 0.15  # the foot goes back

    # drive a person with it: endless walking at any place and heading
    loop = LocomotionLoop.from_clip(clip)
    assert loop.travels and 1.0 < loop.speed_mps < 1.6
    root, q = loop.pose_at(np.array([0.0, 0.5]), np.array([[2.0, 3.0], [2.0, 3.0]]), np.full(2, np.pi / 2))
    posed = forward_kinematics(sk, q, root)
    actor = Actor(1.75, seed=0)
    for Tk in posed:
        lo, hi = actor.bounding_box(Tk)
        assert -0.2 < lo[2] < 0.05 and 1.7 < hi[2] < 1.95, (lo, hi)
        assert np.linalg.norm((lo[:2] + hi[:2]) / 2 - (2.0, 3.0)) < 0.4
        # a ray straight down onto the head meets its top at about 1.75 m
        head = Tk[sk.index("head"), :3, 3]
        hits = actor.intersect(np.array([[head[0], head[1], 3.0]]), np.array([[0.0, 0.0, -1.0]]), Tk)
        assert hits.hit[0] and actor.part_names[hits.part_id[0]] == "head"
        assert 1.65 < 3.0 - hits.t[0] < 1.85, 3.0 - hits.t[0]
        # heading +y: the body's left is -x
        assert Tk[sk.index("left_hip"), 0, 3] < Tk[sk.index("right_hip"), 0, 3]


def test_a_skeleton_with_few_mapped_joints_is_refused(tmp_path):
    few = (  # 8 joints with CMU names (centimetres): legs and a head, no spine or arms
        ("Hips", None, (0.0, 0.0, 0.0), None),
        ("LeftUpLeg", "Hips", (9.0, -7.0, 0.0), None),
        ("LeftLeg", "LeftUpLeg", (0.0, -41.0, 0.0), None),
        ("LeftFoot", "LeftLeg", (0.0, -42.0, 0.0), (0.0, -5.0, 13.0)),
        ("RightUpLeg", "Hips", (-9.0, -7.0, 0.0), None),
        ("RightLeg", "RightUpLeg", (0.0, -41.0, 0.0), None),
        ("RightFoot", "RightLeg", (0.0, -42.0, 0.0), (0.0, -5.0, 13.0)),
        ("Head", "Hips", (0.0, 62.0, 0.0), (0.0, 18.0, 0.0)),
    )
    path = _write_bvh(tmp_path / "few.bvh", joints=few)
    with pytest.raises(InputError) as info:
        load_motion(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: only 8 of 24 body joints map"), msg
    assert "\n" not in msg
    missing = msg.split("missing: ")[1].split(" (")[0].split(", ")
    assert sorted(missing) == sorted(set(JOINT_NAMES) - {"pelvis", "left_hip", "left_knee", "left_ankle",
                                                          "right_hip", "right_knee", "right_ankle", "head"})


def test_position_channels_on_every_joint_log_one_warning(tmp_path, caplog):
    plain = load_motion(_write_bvh(tmp_path / "plain.bvh"))
    caplog.clear()
    with caplog.at_level(logging.INFO):
        clip = load_motion(_write_bvh(tmp_path / "positions.bvh", position_channels=True))
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1, [r.getMessage() for r in warnings]
    msg = warnings[0].getMessage()
    assert "position channels" in msg and f"on {len(CMU_SKELETON) - 1} joint(s)" in msg and "\n" not in msg
    np.testing.assert_allclose(clip.joint_positions(), plain.joint_positions(), atol=1e-9)  # the OFFSETs are used


def test_joints_the_map_names_but_the_file_lacks_are_one_warning(tmp_path, caplog):
    no_fingers = tuple(j for j in CMU_SKELETON if j[0] not in ("LeftFingerBase", "LeftHandIndex1", "LThumb"))
    with caplog.at_level(logging.WARNING):
        clip = load_motion(_write_bvh(tmp_path / "no_fingers.bvh", joints=no_fingers))
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "22 of 24 body joints" in warnings[0] and "left_hand" in warnings[0], warnings
    P = clip.joint_positions()
    sk = clip.skeleton
    # the unmapped hand follows the wrist, which (with no hand rotation in the file) continues the forearm
    elbow, wrist, hand = (P[:, sk.index(f"left_{n}")] for n in ("elbow", "wrist", "hand"))
    assert _angle_deg(wrist - elbow, hand - wrist).max() < 1.0
