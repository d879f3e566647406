"""DeepMimic motion clips (the format of ``pybullet_data/data/motions/humanoid3d_*.txt``).

Real motion capture that installs offline: the ``pybullet`` wheel ships DeepMimic's clips,
retargeted from mocap to its 3D humanoid. nsim reads the files; pybullet itself stays an
optional extra (``deepmimic_motion_path`` finds the files when it is installed).

File format: JSON ``{"Loop": "wrap" | "none", "Frames": [[...44 numbers...], ...]}``, one row
per frame, y-up world, metres, quaternions wxyz, the humanoid facing +x with its right on +z:

    ====  ========================================
    col   meaning
    ====  ========================================
    0     dt: duration of this frame (s; the last frame of a "wrap" clip has 0)
    1-3   root (pelvis) position
    4-7   root orientation
    8-11  chest      12-15 neck
    16-19 right hip  20    right knee (angle, rad, about the joint's z axis)
    21-24 right ankle  25-28 right shoulder  29 right elbow (angle)
    30-33 left hip   34    left knee   35-38 left ankle  39-42 left shoulder  43 left elbow
    ====  ========================================

Joint rotations are local (relative to the parent); in the humanoid's rest pose every joint
frame is aligned with the world and the arms hang down. ``read_deepmimic`` returns a
``MotionClip`` on ``deepmimic_skeleton()`` (the humanoid's joint offsets from its URDF, scaled
by 0.25 as pybullet loads it), converted to nsim's z-up world (``DEEPMIMIC_TO_NSIM``; the
humanoid then faces +x with its left on +y). A "wrap" clip's last frame closes its loop, which
is nsim's ``MotionClip.loop`` convention. ``read_deepmimic_nsim`` retargets onto the nsim body.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.human.motion import MotionClip
from nsim.human.retarget import retarget
from nsim.human.skeleton import Skeleton, nsim_skeleton

FRAME_COLUMNS = 44
DEEPMIMIC_TO_NSIM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""``nsim_xyz = DEEPMIMIC_TO_NSIM @ deepmimic_xyz``: +x forward stays, +y up -> +z, +z (right) -> -y."""
DEEPMIMIC_TO_NSIM.setflags(write=False)

URDF_SCALE = 0.25
"""pybullet loads DeepMimic's humanoid URDF with ``globalScaling=0.25``; the clips are in that scale."""

# joint name, parent, URDF offset (DeepMimic axes, unscaled), first column, kind ("quat" | "angle")
_JOINTS = (
    ("root", -1, (0.0, 0.0, 0.0), 4, "quat"),
    ("chest", 0, (0.0, 0.944604, 0.0), 8, "quat"),
    ("neck", 1, (0.0, 0.895576, 0.0), 12, "quat"),
    ("right_hip", 0, (0.0, 0.0, 0.339548), 16, "quat"),
    ("right_knee", 3, (0.0, -1.686184, 0.0), 20, "angle"),
    ("right_ankle", 4, (0.0, -1.639480, 0.0), 21, "quat"),
    ("right_shoulder", 1, (-0.0962, 0.974, 0.73244), 25, "quat"),
    ("right_elbow", 6, (0.0, -1.099152, 0.0), 29, "angle"),
    ("right_wrist", 7, (0.0, -1.035788, 0.0), -1, "fixed"),
    ("left_hip", 0, (0.0, 0.0, -0.339548), 30, "quat"),
    ("left_knee", 9, (0.0, -1.686184, 0.0), 34, "angle"),
    ("left_ankle", 10, (0.0, -1.639480, 0.0), 35, "quat"),
    ("left_shoulder", 1, (-0.0962, 0.974, -0.73244), 39, "quat"),
    ("left_elbow", 12, (0.0, -1.099152, 0.0), 43, "angle"),
    ("left_wrist", 13, (0.0, -1.035788, 0.0), -1, "fixed"),
)
# End sites (DeepMimic axes, unscaled): top of the head, toe tips on the sole, finger tips.
_END_SITES = {
    "neck": (0.0, 1.0, 0.0),
    "right_ankle": (0.534, -0.2, 0.0),
    "left_ankle": (0.534, -0.2, 0.0),
    "right_wrist": (0.0, -0.3, 0.0),
    "left_wrist": (0.0, -0.3, 0.0),
}
_ANKLE_ABOVE_SOLE = 0.2  # unscaled: the foot box's bottom is 0.2 below the ankle
_LEG = 1.686184 + 1.639480

DEEPMIMIC_TO_NSIM_JOINTS = {
    "pelvis": "root", "spine2": "chest", "neck": "neck",
    "right_hip": "right_hip", "right_knee": "right_knee", "right_ankle": "right_ankle",
    "right_shoulder": "right_shoulder", "right_elbow": "right_elbow", "right_wrist": "right_wrist",
    "left_hip": "left_hip", "left_knee": "left_knee", "left_ankle": "left_ankle",
    "left_shoulder": "left_shoulder", "left_elbow": "left_elbow", "left_wrist": "left_wrist",
}
"""nsim joint -> DeepMimic joint (the chest drives spine2; collars, toes, hands and head follow their parents)."""


def deepmimic_skeleton() -> Skeleton:
    """DeepMimic's humanoid in nsim axes and metres, standing with its soles on ``z = 0``."""
    A = DEEPMIMIC_TO_NSIM
    offsets = np.array([j[2] for j in _JOINTS]) * URDF_SCALE
    offsets[0] = (0.0, (_LEG + _ANKLE_ABOVE_SOLE) * URDF_SCALE, 0.0)
    ends = np.full((len(_JOINTS), 3), np.nan)
    for i, j in enumerate(_JOINTS):
        if j[0] in _END_SITES:
            ends[i] = np.asarray(_END_SITES[j[0]]) * URDF_SCALE
    return Skeleton(tuple(j[0] for j in _JOINTS), np.array([j[1] for j in _JOINTS]), offsets @ A.T, ends @ A.T)


def _num(value, path: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{path}: {where}: expected a finite number, got {value!r}")
    return float(value)


def parse_deepmimic(data, path: str = "<deepmimic>") -> MotionClip:
    """A DeepMimic clip from its parsed JSON ``data`` (see the module docstring)."""
    if not isinstance(data, dict) or "Frames" not in data:
        raise InputError(f"{path}: expected a JSON object with 'Frames' (DeepMimic motion)")
    loop = data.get("Loop", "none")
    if loop not in ("wrap", "none"):
        raise InputError(f"{path}: Loop: expected 'wrap' or 'none', got {loop!r}")
    frames = data["Frames"]
    if not isinstance(frames, list) or len(frames) < 2:
        raise InputError(f"{path}: Frames: expected a list of at least 2 frames")
    rows = np.empty((len(frames), FRAME_COLUMNS))
    for i, fr in enumerate(frames):
        if not isinstance(fr, list) or len(fr) != FRAME_COLUMNS:
            n = len(fr) if isinstance(fr, list) else type(fr).__name__
            raise InputError(f"{path}: Frames[{i}]: expected {FRAME_COLUMNS} values (humanoid3d), got {n}")
        rows[i] = [_num(v, path, f"Frames[{i}][{c}]") for c, v in enumerate(fr)]
    dt = rows[:, 0]
    body = dt[:-1]
    if np.any(body <= 0):
        i = int(np.argmax(body <= 0))
        raise InputError(f"{path}: Frames[{i}][0]: frame duration must be > 0, got {body[i]}")
    if np.ptp(body) > 1e-3 * body.mean():
        raise InputError(f"{path}: Frames[*][0]: frame durations vary ({body.min():.6g} to {body.max():.6g} s); "
                         "only clips at a constant frame rate are supported")
    fps = 1.0 / float(body.mean())

    A = DEEPMIMIC_TO_NSIM
    F = rows.shape[0]
    q = np.zeros((F, len(_JOINTS), 4))
    q[..., 0] = 1.0
    for i, (name, _, _, col, kind) in enumerate(_JOINTS):
        if kind == "quat":
            qq = rows[:, col:col + 4]
            norm = np.linalg.norm(qq, axis=1)
            if np.any(norm < 1e-6):
                k = int(np.argmax(norm < 1e-6))
                raise InputError(f"{path}: Frames[{k}][{col}:{col + 4}]: {name} quaternion is zero")
            q[:, i, 0] = qq[:, 0]
            q[:, i, 1:] = qq[:, 1:] @ A.T  # a proper rotation maps the vector part
        elif kind == "angle":  # revolute about the joint's z axis
            half = 0.5 * rows[:, col]
            q[:, i, 0] = np.cos(half)
            q[:, i, 1:] = np.sin(half)[:, None] * (A @ np.array([0.0, 0.0, 1.0]))
    root = rows[:, 1:4] @ A.T
    return MotionClip(deepmimic_skeleton(), fps, root, q, name=path, loop=loop == "wrap")


def read_deepmimic(path: str | os.PathLike[str]) -> MotionClip:
    """Read a DeepMimic motion file into a ``MotionClip`` on ``deepmimic_skeleton()``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: DeepMimic motion file not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read DeepMimic motion file ({exc.__class__.__name__})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: malformed JSON: {exc.msg}") from None
    return parse_deepmimic(data, str(path))


def read_deepmimic_nsim(path: str | os.PathLike[str], height_m: float = 1.75) -> MotionClip:
    """Read a DeepMimic clip and retarget it onto ``nsim_skeleton(height_m)`` (``DEEPMIMIC_TO_NSIM_JOINTS``)."""
    return retarget(read_deepmimic(path), nsim_skeleton(height_m), DEEPMIMIC_TO_NSIM_JOINTS)


def deepmimic_motion_path(name: str = "humanoid3d_walk.txt") -> Path:
    """Path of a motion shipped by the optional ``pybullet`` wheel (``pybullet_data/data/motions/NAME``).

    InputError when pybullet is not installed or the file is not there.
    """
    try:
        import pybullet_data
    except ImportError:
        raise InputError(f"{name}: DeepMimic motions come with the optional pybullet package "
                         "(pip install pybullet); it is not installed") from None
    path = Path(pybullet_data.getDataPath()) / "data" / "motions" / name
    if not path.is_file():
        raise InputError(f"{path}: no such DeepMimic motion in pybullet_data")
    return path
