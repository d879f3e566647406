"""Retargeting: a CMU-style BVH (other names, extra joints, arms-down rest pose, centimetres)
written by the test lands on the nsim body with the same joint positions, in metres."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.human.bvh import BVH_Y_UP_TO_NSIM, read_bvh
from nsim.human.motion_io import load_motion
from nsim.human.retarget import JointMap, default_joint_map, load_joint_map, retarget, rotation_between
from nsim.human.skeleton import nsim_skeleton

A = BVH_Y_UP_TO_NSIM
NSIM = nsim_skeleton(1.75)
OFF = {n: NSIM.offsets_m[i] for i, n in enumerate(NSIM.joint_names)}
END = {n: NSIM.end_sites_m[i] for i, n in enumerate(NSIM.joint_names)}


def _cmu_joints() -> list[tuple[str, str | None, np.ndarray, np.ndarray | None, bool]]:
    """(name, parent, offset nsim axes m, end site or None, moves) of a CMU-style body with arms down."""
    # LowerBack turns but has Spine at its own origin, so it moves Spine's orientation, not its position
    j = [("Hips", None, np.zeros(3), None, True), ("LowerBack", "Hips", OFF["spine1"], None, True),
         ("Spine", "LowerBack", np.zeros(3), None, True),
         ("Spine1", "Spine", OFF["spine2"] + OFF["spine3"], None, True),
         ("Neck", "Spine1", OFF["neck"], None, True),
         ("Neck1", "Neck", 0.5 * OFF["head"], None, False),
         ("Head", "Neck1", 0.5 * OFF["head"], END["head"], True)]
    for side, s, cmu in (("left", 1.0, "L"), ("right", -1.0, "R")):
        Side = side.capitalize()
        j += [(f"{cmu}HipJoint", "Hips", 0.5 * OFF[f"{side}_hip"], None, False),
              (f"{Side}UpLeg", f"{cmu}HipJoint", 0.5 * OFF[f"{side}_hip"], None, True),
              (f"{Side}Leg", f"{Side}UpLeg", OFF[f"{side}_knee"], None, True),
              (f"{Side}Foot", f"{Side}Leg", OFF[f"{side}_ankle"], None, True),
              (f"{Side}ToeBase", f"{Side}Foot", OFF[f"{side}_foot"], END[f"{side}_foot"], True),
              (f"{Side}Shoulder", "Spine1", OFF[f"{side}_collar"], None, True),
              (f"{Side}Arm", f"{Side}Shoulder", OFF[f"{side}_shoulder"], None, True),
              # arms hang down in this rest pose (the nsim body's rest is a T-pose)
              (f"{Side}ForeArm", f"{Side}Arm", np.array([0.0, 0.0, -0.26]), None, True),
              (f"{Side}Hand", f"{Side}ForeArm", np.array([0.0, 0.0, -0.25]), None, True),
              (f"{Side}FingerBase", f"{Side}Hand", np.array([0.0, 0.0, -0.08]), np.array([0.0, 0.0, -0.09]), True),
              (f"{cmu}Thumb", f"{Side}Hand", np.array([0.02, s * 0.01, -0.03]), np.array([0.02, 0.0, -0.03]), True)]
    return j


CMU_TO_NSIM = {"Hips": "pelvis", "Spine": "spine1", "Spine1": "spine3", "Neck": "neck", "Head": "head",
               **{f"{S}{c}": f"{s}_{n}" for s, S in (("left", "Left"), ("right", "Right"))
                  for c, n in (("UpLeg", "hip"), ("Leg", "knee"), ("Foot", "ankle"), ("ToeBase", "foot"),
                               ("Shoulder", "collar"), ("Arm", "shoulder"), ("ForeArm", "elbow"), ("Hand", "wrist"),
                               ("FingerBase", "hand"))}}


def _write_cmu_bvh(path, frames: int = 5, seed: int = 0) -> dict[str, np.ndarray]:
    """Write the body in centimetres with random motion; returns expected world positions (F, 3) in metres (nsim axes)."""
    joints = _cmu_joints()
    rng = np.random.default_rng(seed)
    children: dict[str | None, list[int]] = {}
    for i, (_, parent, _, _, _) in enumerate(joints):
        children.setdefault(parent, []).append(i)
    angles = {name: (rng.uniform(-40, 40, size=(frames, 3)) if moves else np.zeros((frames, 3)))
              for name, _, _, _, moves in joints}
    root_cm = np.stack([rng.uniform(-50, 50, frames), rng.uniform(90, 100, frames), rng.uniform(-50, 50, frames)], 1)
    lines, order = ["HIERARCHY"], []

    def cm(v):
        return " ".join(f"{x:.6f}" for x in (A.T @ v) * 100)

    def emit(i: int, depth: int) -> None:
        name, parent, off, end, _ = joints[i]
        order.append(i)
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {cm(off)}")
        chans = "Xposition Yposition Zposition Zrotation Yrotation Xrotation" if parent is None else \
            "Zrotation Yrotation Xrotation"
        lines.append(f"{pad}  CHANNELS {6 if parent is None else 3} {chans}")
        for c in children.get(name, []):
            emit(c, depth + 1)
        if end is not None:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET {cm(end)}", pad + "  }"])
        lines.append(pad + "}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.033333"]
    for f in range(frames):
        vals = list(root_cm[f])
        for i in order:
            vals += list(angles[joints[i][0]][f])
        lines.append(" ".join(f"{v:.6f}" for v in vals))
    path.write_text("\n".join(lines) + "\n")

    # reference forward kinematics in the file's axes (cm), then nsim axes in metres
    expected: dict[str, np.ndarray] = {}
    G: dict[str, np.ndarray] = {}
    P: dict[str, np.ndarray] = {}
    for i in order:
        name, parent, off, _, _ = joints[i]
        R = Rotation.from_euler("ZYX", angles[name], degrees=True).as_matrix()
        if parent is None:
            G[name], P[name] = R, root_cm
        else:
            G[name] = G[parent] @ R
            P[name] = P[parent] + np.einsum("fij,j->fi", G[parent], (A.T @ off) * 100)
        expected[name] = (P[name] @ A.T) / 100
    return expected


def test_cmu_style_bvh_in_centimetres_retargets_to_the_same_joint_positions(tmp_path):
    path = tmp_path / "cmu_walk.bvh"
    expected = _write_cmu_bvh(path)
    source = read_bvh(path)
    clip = retarget(source, NSIM, ground_feet=False)  # the default map picks the CMU profile
    got = clip.joint_positions()
    assert clip.joint_names == NSIM.joint_names
    for cmu_name, nsim_name in CMU_TO_NSIM.items():
        np.testing.assert_allclose(got[:, NSIM.index(nsim_name)], expected[cmu_name], atol=1e-6,
                                   err_msg=f"{cmu_name} -> {nsim_name}")


def test_load_motion_grounds_the_feet(tmp_path):
    path = tmp_path / "cmu.bvh"
    _write_cmu_bvh(path, frames=8, seed=3)
    clip = load_motion(path, height_m=1.6)
    lowest = clip.joint_positions()[..., 2].min()
    assert lowest == pytest.approx(nsim_skeleton(1.6).rest_positions_m()[:, 2].min(), abs=1e-9)


def test_rest_alignment_turns_bones_exactly():
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = rng.normal(size=3), rng.normal(size=3)
        R = rotation_between(a, b)
        np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    R = rotation_between(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], atol=1e-12)


def test_joint_map_files_and_errors(tmp_path):
    assert {name for name, _ in default_joint_map().profiles} == {"nsim", "cmu", "mixamo", "biped", "daz"}
    good = tmp_path / "map.yaml"
    good.write_text("pelvis: [root, Hips]\nleft_knee: LKnee\n")
    jm = load_joint_map(good)
    assert jm.profiles[0][1]["pelvis"] == ("root", "Hips")
    bad = tmp_path / "bad.yaml"
    bad.write_text("pelvis: [root, 3]\n")
    with pytest.raises(InputError, match=r"bad\.yaml: pelvis: expected a joint name"):
        load_joint_map(bad)
    path = tmp_path / "cmu.bvh"
    _write_cmu_bvh(path, frames=2)
    with pytest.raises(InputError, match=r"cmu\.bvh: no source joint for the root 'pelvis'"):
        retarget(read_bvh(path), NSIM, JointMap.from_mapping({"pelvis": "Root"}))
    with pytest.raises(InputError, match="kneecap: not a joint of the target"):
        retarget(read_bvh(path), NSIM, {"pelvis": "Hips", "kneecap": "LeftLeg"})
