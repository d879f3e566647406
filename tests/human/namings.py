"""The common BVH joint namings, as renamings of the nsim body's 24 joints (for tests that write BVH files).

``NAMINGS[name][nsim joint]`` is that naming's joint; a release without a joint nsim has gets a name no
profile knows (so it stays unmapped, as it would be in a file of that release). The profiles of
``nsim/configs/motions/joint_map.yaml`` are expected to read them.
"""

from __future__ import annotations

from nsim.human.motion import MotionClip
from nsim.human.skeleton import JOINT_NAMES, Skeleton


def _sided(left: dict[str, str], right_of) -> dict[str, str]:
    out = dict(left)
    for joint, name in left.items():
        if joint.startswith("left_"):
            out["right_" + joint[5:]] = right_of(name)
    return out


def _lr(name: str) -> str:
    return name.replace("Left", "Right", 1)


NAMINGS: dict[str, dict[str, str]] = {
    # cgspeed's MotionBuilder-friendly CMU release: LHipJoint etc. left out here; one spine joint fewer than nsim
    "cmu": _sided({"pelvis": "Hips", "spine1": "Spine", "spine2": "SpineMid", "spine3": "Spine1", "neck": "Neck",
                   "head": "Head", "left_hip": "LeftUpLeg", "left_knee": "LeftLeg", "left_ankle": "LeftFoot",
                   "left_foot": "LeftToeBase", "left_collar": "LeftShoulder", "left_shoulder": "LeftArm",
                   "left_elbow": "LeftForeArm", "left_wrist": "LeftHand", "left_hand": "LeftFingerBase"}, _lr),
    # cgspeed's 3dsMax-friendly CMU release and Character Studio Biped files
    "biped": _sided({"pelvis": "Hips", "spine1": "Chest", "spine2": "Chest2", "spine3": "Chest3", "neck": "Neck",
                     "head": "Head", "left_hip": "LeftHip", "left_knee": "LeftKnee", "left_ankle": "LeftAnkle",
                     "left_foot": "LeftToe", "left_collar": "LeftCollar", "left_shoulder": "LeftShoulder",
                     "left_elbow": "LeftElbow", "left_wrist": "LeftWrist", "left_hand": "LeftFinger2"}, _lr),
    # cgspeed's Daz-friendly CMU release: no toes, one spine joint between abdomen and neck
    "daz": _sided({"pelvis": "hip", "spine1": "abdomen", "spine2": "abdomenMid", "spine3": "chest", "neck": "neck",
                   "head": "head", "left_hip": "lThigh", "left_knee": "lShin", "left_ankle": "lFoot",
                   "left_foot": "lFootEnd", "left_collar": "lCollar", "left_shoulder": "lShldr",
                   "left_elbow": "lForeArm", "left_wrist": "lHand", "left_hand": "lMid1"},
                  lambda n: "r" + n[1:] if n.startswith("l") else n),
    # Mixamo, with its "mixamorig:" prefix
    "mixamo": _sided({j: f"mixamorig:{n}" for j, n in {
        "pelvis": "Hips", "spine1": "Spine", "spine2": "Spine1", "spine3": "Spine2", "neck": "Neck", "head": "Head",
        "left_hip": "LeftUpLeg", "left_knee": "LeftLeg", "left_ankle": "LeftFoot", "left_foot": "LeftToeBase",
        "left_collar": "LeftShoulder", "left_shoulder": "LeftArm", "left_elbow": "LeftForeArm",
        "left_wrist": "LeftHand", "left_hand": "LeftHandMiddle1"}.items()}, _lr),
}
assert all(set(n) == set(JOINT_NAMES) for n in NAMINGS.values())


def renamed(clip: MotionClip, naming: str) -> MotionClip:
    """``clip`` (on an nsim body) with its joints named as ``naming`` names them."""
    sk = clip.skeleton
    names = tuple(NAMINGS[naming][n] for n in sk.joint_names)
    body = Skeleton(names, sk.parents, sk.offsets_m, sk.end_sites_m)
    return MotionClip(body, clip.fps, clip.root_positions_m, clip.local_rotations_wxyz, name=clip.name, loop=clip.loop)
