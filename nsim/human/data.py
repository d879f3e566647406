"""Training data for a human model: frames, per-frame skeleton poses and person masks.

The format (documented for users in ``docs/human_data.md``) is what ``nsim capture synth
--actor`` writes and what a lab brings from its own video and pose estimator::

    <root>/
      transforms.json        frames: images, camera poses, intrinsics (nerfstudio convention)
      images/...             the frames
      poses.json             per-frame skeleton poses (format below); or
      poses.bvh              a BVH with one motion frame per image (retargeted to the nsim body),
      root_transforms.json     optionally with a per-frame root transform for it
      masks/<image stem>.png person masks, same size as the images
      background/...         optional: the same views without the person (synthetic captures)

Poses are aligned to ``transforms.json`` frames by index. A pose is the nsim body
(``nsim.human.skeleton``: 24 joints, SMPL names, z up, metres, quaternions wxyz) posed by

    joint_to_world (J, 4, 4) = root_to_world (4, 4) @ forward_kinematics(skeleton, local_rotations_wxyz, 0)

i.e. ``root_to_world`` places the root joint (pelvis) and ``local_rotations_wxyz (J, 4)`` are
each joint's rotation relative to its parent, row 0 the root's rotation relative to
``root_to_world`` (identity when ``root_to_world`` carries the full root orientation, as in
files nsim writes; a pose estimator with a separate global orientation puts it there).

``poses.json``::

    {"format": "nsim-human-poses", "version": 1,
     "height_m": 1.75,                       body height, floor to top of head
     "skeleton": {"joint_names": [24 names], "parents": [24 ints], "offsets_m": [[x, y, z] * 24],
                  "end_sites_m": [[x, y, z] or [null, null, null] * 24]},   optional (default: nsim_skeleton(height_m))
     "frames": [{"file_path": "images/frame_00000.png",          optional, checked against transforms.json
                 "timestamp": 0.0,                                optional, seconds
                 "root_to_world": [[4 x 4]],
                 "local_rotations_wxyz": [[w, x, y, z] * 24],
                 "joint_positions_m": [[x, y, z] * 24]}, ...],   optional, checked against the kinematics
     "meta": {...}}                                               optional, free-form

Every problem is an ``InputError`` naming the file and the field (``poses.json:
frames[7].local_rotations_wxyz: contains NaN``).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.geometry.transforms import is_rotation
from nsim.human.skeleton import (
    JOINT_NAMES,
    PARENTS,
    REFERENCE_HEIGHT_M,
    Skeleton,
    forward_kinematics,
    local_rotations_from_global,
    nsim_skeleton,
    quats_from_matrices,
)
from nsim.io import atomic_path

POSES_FORMAT = "nsim-human-poses"
POSES_VERSION = 1
POSES_FILE = "poses.json"
POSES_REFINED_FILE = "poses_refined.json"  # a human checkpoint's refined poses (nsim.train.human.export_human)
BVH_POSES_FILE = "poses.bvh"
ROOT_TRANSFORMS_FILE = "root_transforms.json"
MASKS_DIR = "masks"
MASK_PATH_KEY = "person_mask_path"
"""Optional per-frame key in ``transforms.json`` naming the frame's mask (default ``masks/<image stem>.png``)."""
BACKGROUND_PATH_KEY = "background_path"
"""Optional per-frame key in ``transforms.json`` naming an image of the same view without the person."""

JOINT_POSITION_TOLERANCE_M = 0.01
"""``joint_positions_m`` in a poses file may differ from the kinematics by at most this."""

_TOP_KEYS = ("format", "version", "height_m", "skeleton", "frames", "meta")
_FRAME_KEYS = ("file_path", "timestamp", "root_to_world", "local_rotations_wxyz", "joint_positions_m")
_SKELETON_KEYS = ("joint_names", "parents", "offsets_m", "end_sites_m")


# ---------------------------------------------------------------------------------------------- poses


@dataclass(frozen=True, eq=False)
class HumanPoses:
    """Per-frame poses of one person (``F`` frames; see the module docstring for the convention).

    skeleton: the nsim body (``JOINT_NAMES`` order and tree) with this person's bone lengths.
    height_m: body height, floor to top of head.
    root_to_world: (F, 4, 4) float64 rigid transforms.
    local_rotations_wxyz: (F, J, 4) float64 unit quaternions (normalised, ``w >= 0``).
    timestamps_s: (F,) float64 seconds; NaN where not given.
    file_paths: (F,) the image each pose belongs to, as in ``transforms.json``; None where not given.
    meta: free-form extra information (``poses.json``'s ``meta``).
    """

    skeleton: Skeleton
    height_m: float
    root_to_world: np.ndarray
    local_rotations_wxyz: np.ndarray
    timestamps_s: np.ndarray
    file_paths: tuple[str | None, ...]
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        J = self.skeleton.num_joints
        R = np.array(self.root_to_world, dtype=np.float64)
        q = np.array(self.local_rotations_wxyz, dtype=np.float64)
        t = np.array(self.timestamps_s, dtype=np.float64).reshape(-1)
        F = R.shape[0] if R.ndim == 3 else -1
        if R.shape != (F, 4, 4) or q.shape != (F, J, 4) or t.shape != (F,) or len(self.file_paths) != F:
            raise ValueError(f"HumanPoses: expected root_to_world (F, 4, 4), local_rotations_wxyz (F, {J}, 4), "
                             f"timestamps_s (F,), F file paths; got {R.shape}, {q.shape}, {t.shape}, "
                             f"{len(self.file_paths)}")
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(q))):
            raise ValueError("HumanPoses: root_to_world and local_rotations_wxyz must be finite")
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
        if np.any(norm < 1e-6):
            raise ValueError("HumanPoses: local_rotations_wxyz contains a zero quaternion")
        q = q / norm
        q = np.where(q[..., :1] < 0.0, -q, q)
        for name, value in (("root_to_world", R), ("local_rotations_wxyz", q), ("timestamps_s", t)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "file_paths", tuple(self.file_paths))
        object.__setattr__(self, "height_m", float(self.height_m))

    @property
    def num_frames(self) -> int:
        return self.root_to_world.shape[0]

    def joint_transforms(self) -> np.ndarray:
        """Joint-to-world transforms ``(F, J, 4, 4)``."""
        zero = np.zeros((self.num_frames, 3))
        return forward_kinematics(self.skeleton, self.local_rotations_wxyz, zero, self.root_to_world)

    def joint_positions_m(self) -> np.ndarray:
        """World joint positions ``(F, J, 3)``."""
        return self.joint_transforms()[..., :3, 3]


def poses_from_joint_transforms(skeleton: Skeleton, height_m: float, joint_transforms: np.ndarray,
                                timestamps_s: np.ndarray | None = None,
                                file_paths: tuple[str | None, ...] | None = None,
                                meta: dict[str, Any] | None = None) -> HumanPoses:
    """``HumanPoses`` of joint-to-world transforms ``(F, J, 4, 4)`` of ``skeleton`` (bone lengths as the
    skeleton's): the root joint's transform as ``root_to_world``, each other joint's rotation relative to
    its parent's. ``forward_kinematics`` of the result gives the transforms back."""
    T = np.asarray(joint_transforms, dtype=np.float64)
    F = T.shape[0]
    local = local_rotations_from_global(skeleton, T[..., :3, :3])
    local[:, 0] = np.eye(3)
    times = np.full(F, np.nan) if timestamps_s is None else timestamps_s
    paths = (None,) * F if file_paths is None else tuple(file_paths)
    return HumanPoses(skeleton, height_m, T[:, 0], quats_from_matrices(local), times, paths, meta or {})


def skeleton_to_dict(skeleton: Skeleton) -> dict[str, Any]:
    """The ``skeleton`` block of ``poses.json`` (NaN end sites as null)."""
    return {"joint_names": list(skeleton.joint_names), "parents": [int(p) for p in skeleton.parents],
            "offsets_m": skeleton.offsets_m.tolist(),
            "end_sites_m": [[None if math.isnan(v) else float(v) for v in row] for row in skeleton.end_sites_m]}


def poses_to_dict(poses: HumanPoses) -> dict[str, Any]:
    """``poses.json`` content of ``poses`` (joint positions included, for readers without kinematics)."""
    positions = poses.joint_positions_m()
    frames = []
    for i in range(poses.num_frames):
        frame: dict[str, Any] = {}
        if poses.file_paths[i] is not None:
            frame["file_path"] = poses.file_paths[i]
        if math.isfinite(poses.timestamps_s[i]):
            frame["timestamp"] = float(poses.timestamps_s[i])
        frame["root_to_world"] = poses.root_to_world[i].tolist()
        frame["local_rotations_wxyz"] = poses.local_rotations_wxyz[i].tolist()
        frame["joint_positions_m"] = positions[i].tolist()
        frames.append(frame)
    out: dict[str, Any] = {"format": POSES_FORMAT, "version": POSES_VERSION, "height_m": poses.height_m,
                           "skeleton": skeleton_to_dict(poses.skeleton), "frames": frames}
    if poses.meta:
        out["meta"] = poses.meta
    return out


def write_poses(path: str | os.PathLike, poses: HumanPoses) -> Path:
    """Write ``poses`` as ``poses.json`` (atomically; floats rounded to 1e-9, ``nsim.io.canonical``: the same
    bytes on every CPU). Returns the path."""
    from nsim.io.canonical import POSE_DECIMALS, canonical_floats

    path = Path(path)
    doc = canonical_floats(poses_to_dict(poses), decimals=POSE_DECIMALS)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return path


class _Fields:
    """Field checks for one file: every failure is ``InputError("<file>: <field>: <problem>")``."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> InputError:
        return InputError(f"{self.path}: {where}: {problem}")

    def array(self, value: Any, where: str, shape: tuple[int, ...]) -> np.ndarray:
        try:
            a = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.fail(where, f"expected numbers of shape {shape}") from None
        if a.shape != shape:
            raise self.fail(where, f"expected shape {shape}, got {a.shape}")
        if np.isnan(a).any():
            raise self.fail(where, "contains NaN")
        if not np.all(np.isfinite(a)):
            raise self.fail(where, "contains inf")
        return a

    def number(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        return float(value)

    def keys(self, data: Any, where: str, known: tuple[str, ...], required: tuple[str, ...]) -> dict:
        if not isinstance(data, dict):
            raise self.fail(where, f"expected an object, got {type(data).__name__}")
        if unknown := sorted(set(data) - set(known)):
            raise self.fail(where, f"unknown key(s) {', '.join(map(repr, unknown))} (known: {', '.join(known)})")
        if missing := [k for k in required if k not in data]:
            raise self.fail(where, f"missing key(s) {', '.join(map(repr, missing))}")
        return data

    def rigid(self, value: Any, where: str) -> np.ndarray:
        T = self.array(value, where, (4, 4))
        if not is_rotation(T[:3, :3], tol=1e-4) or np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
            raise self.fail(where, "not a rigid transform (rotation block not orthonormal, or last row not 0 0 0 1)")
        return T


def _nsim_order(f: _Fields, names: list[str], where: str) -> np.ndarray:
    """Index into the file's joints of each nsim joint (``(J,)``); InputError for unknown or missing names."""
    for n in names:
        if n not in JOINT_NAMES:
            raise f.fail(where, f"unknown joint {n!r} (the nsim body's joints: {', '.join(JOINT_NAMES)})")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise f.fail(where, f"duplicate joint(s) {', '.join(dup)}")
    if missing := [n for n in JOINT_NAMES if n not in names]:
        raise f.fail(where, f"missing joint(s) {', '.join(missing)}")
    return np.array([names.index(n) for n in JOINT_NAMES])


def _read_skeleton(f: _Fields, raw: Any, height_m: float) -> tuple[Skeleton, np.ndarray | None]:
    """The file's skeleton in nsim joint order, and the file-to-nsim order of the joints (None: no skeleton block)."""
    if raw is None:
        return nsim_skeleton(height_m), None
    raw = f.keys(raw, "skeleton", _SKELETON_KEYS, ("joint_names",))
    names = raw["joint_names"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise f.fail("skeleton.joint_names", "expected a list of strings")
    order = _nsim_order(f, names, "skeleton.joint_names")
    J = len(names)
    rest = nsim_skeleton(height_m)
    if "parents" in raw:
        parents = raw["parents"]
        if not isinstance(parents, list) or len(parents) != J or not all(
                isinstance(p, int) and not isinstance(p, bool) and -1 <= p < J for p in parents):
            raise f.fail("skeleton.parents", f"expected {J} joint indices (-1 for the root)")
        for j, name in enumerate(JOINT_NAMES):
            p = parents[order[j]]
            parent_name = names[p] if p >= 0 else None
            expected = JOINT_NAMES[PARENTS[j]] if PARENTS[j] >= 0 else None
            if parent_name != expected:
                raise f.fail("skeleton.parents", f"joint {name!r} has parent {parent_name!r}, the nsim body has "
                                                 f"{expected!r}")
    offsets = rest.offsets_m
    if "offsets_m" in raw:
        offsets = f.array(raw["offsets_m"], "skeleton.offsets_m", (J, 3))[order]
    ends = rest.end_sites_m
    if "end_sites_m" in raw:
        e = raw["end_sites_m"]
        if not isinstance(e, list) or len(e) != J:
            raise f.fail("skeleton.end_sites_m", f"expected {J} rows of [x, y, z] or [null, null, null]")
        try:
            ends = np.array([[np.nan if v is None else v for v in row] for row in e], dtype=np.float64)
        except (TypeError, ValueError):
            raise f.fail("skeleton.end_sites_m", "expected numbers or nulls") from None
        if ends.shape != (J, 3):
            raise f.fail("skeleton.end_sites_m", f"expected shape ({J}, 3), got {ends.shape}")
        ends = ends[order]
    return Skeleton(JOINT_NAMES, np.array(PARENTS), offsets, ends), order


def read_poses(path: str | os.PathLike) -> HumanPoses:
    """Read a ``poses.json`` (see the module docstring). Joints may come in any order; they are
    returned in the nsim body's order. InputError naming the file and field for every problem."""
    path = Path(path)
    f = _Fields(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: poses file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    data = f.keys(data, "top level", _TOP_KEYS, ("format", "version", "height_m", "frames"))
    if data["format"] != POSES_FORMAT:
        raise f.fail("format", f"expected {POSES_FORMAT!r}, got {data['format']!r}")
    if data["version"] != POSES_VERSION:
        raise f.fail("version", f"expected {POSES_VERSION}, got {data['version']!r}")
    height = f.number(data["height_m"], "height_m")
    if not 0.5 <= height <= 2.5:
        raise f.fail("height_m", f"expected a body height in [0.5, 2.5] m, got {height}")
    skeleton, order = _read_skeleton(f, data.get("skeleton"), height)
    J = skeleton.num_joints
    frames = data["frames"]
    if not isinstance(frames, list) or not frames:
        raise f.fail("frames", "expected a non-empty list")
    meta = data.get("meta", {})
    if not isinstance(meta, dict):
        raise f.fail("meta", f"expected an object, got {type(meta).__name__}")
    F = len(frames)
    root = np.empty((F, 4, 4))
    quats = np.empty((F, J, 4))
    times = np.full(F, np.nan)
    files: list[str | None] = []
    given_positions: dict[int, np.ndarray] = {}
    take = slice(None) if order is None else order
    for i, raw in enumerate(frames):
        where = f"frames[{i}]"
        raw = f.keys(raw, where, _FRAME_KEYS, ("root_to_world", "local_rotations_wxyz"))
        root[i] = f.rigid(raw["root_to_world"], f"{where}.root_to_world")
        q = f.array(raw["local_rotations_wxyz"], f"{where}.local_rotations_wxyz", (J, 4))
        if np.any(np.linalg.norm(q, axis=-1) < 1e-6):
            raise f.fail(f"{where}.local_rotations_wxyz", "contains a zero quaternion")
        quats[i] = q[take]
        if "timestamp" in raw:
            times[i] = f.number(raw["timestamp"], f"{where}.timestamp")
        fp = raw.get("file_path")
        if fp is not None and not isinstance(fp, str):
            raise f.fail(f"{where}.file_path", f"expected a string, got {type(fp).__name__}")
        files.append(fp)
        if "joint_positions_m" in raw:
            given_positions[i] = f.array(raw["joint_positions_m"], f"{where}.joint_positions_m", (J, 3))[take]
    poses = HumanPoses(skeleton, height, root, quats, times, tuple(files), meta)
    if given_positions:
        idx = np.array(sorted(given_positions))
        fk = forward_kinematics(skeleton, poses.local_rotations_wxyz[idx], np.zeros((idx.size, 3)),
                                poses.root_to_world[idx])[..., :3, 3]
        err = np.linalg.norm(fk - np.stack([given_positions[i] for i in idx]), axis=-1)  # (n, J)
        if err.max() > JOINT_POSITION_TOLERANCE_M:
            k, j = np.unravel_index(int(err.argmax()), err.shape)
            raise f.fail(f"frames[{idx[k]}].joint_positions_m",
                         f"joint {JOINT_NAMES[j]!r} is {err[k, j]:.3f} m from where the skeleton's kinematics put "
                         f"it (tolerance {JOINT_POSITION_TOLERANCE_M} m): offsets_m and rotations disagree")
    return poses


def read_root_transforms(path: str | os.PathLike) -> np.ndarray:
    """Read ``root_transforms.json`` (``{"root_to_world": [[4 x 4], ...]}``, one per frame): ``(F, 4, 4)``."""
    path = Path(path)
    f = _Fields(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: root transforms file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    data = f.keys(data, "top level", ("root_to_world",), ("root_to_world",))
    mats = data["root_to_world"]
    if not isinstance(mats, list) or not mats:
        raise f.fail("root_to_world", "expected a non-empty list of 4x4 matrices")
    return np.stack([f.rigid(m, f"root_to_world[{i}]") for i, m in enumerate(mats)])


def read_bvh_poses(path: str | os.PathLike, height_m: float | None = None,
                   root_transforms: np.ndarray | None = None, joint_map=None) -> HumanPoses:
    """Poses from a BVH, one motion frame per image, retargeted to the nsim body.

    height_m: body height; None derives it from the BVH's rest skeleton. root_transforms:
    optional ``(F, 4, 4)`` placed on top of each frame (the BVH world to the scene's world);
    without them the clip's feet are put on the floor (``retarget``'s ``ground_feet``).
    joint_map: see ``nsim.human.retarget.retarget``. Bad files raise InputError.
    """
    from nsim.human.bvh import read_bvh

    path = Path(path)
    return _poses_from_bvh_clip(read_bvh(path), path, height_m, root_transforms, joint_map)


def _poses_from_bvh_clip(clip, path: Path, height_m: float | None, root_transforms: np.ndarray | None,
                         joint_map) -> HumanPoses:
    from nsim.human.retarget import retarget

    if height_m is None:
        ratio = REFERENCE_HEIGHT_M / nsim_skeleton(REFERENCE_HEIGHT_M).height_m()
        height_m = float(np.clip(clip.skeleton.height_m() * ratio, 0.5, 2.5))
    target = retarget(clip, nsim_skeleton(height_m), joint_map, ground_feet=root_transforms is None)
    F = target.num_frames
    root = np.tile(np.eye(4), (F, 1, 1))
    root[:, :3, 3] = target.root_positions_m
    if root_transforms is not None:
        extra = np.asarray(root_transforms, dtype=np.float64)
        if extra.shape != (F, 4, 4):
            raise InputError(f"{path}: {F} BVH frames but {extra.shape[0]} root transforms")
        root = extra @ root
    return HumanPoses(target.skeleton, height_m, root, target.local_rotations_wxyz, target.times_s,
                      (None,) * F, {"source": str(path)})


# ---------------------------------------------------------------------------------------------- data set


def _image_size(path: Path, what: str) -> tuple[int, int]:
    """``(width, height)`` of an image file from its header; InputError if missing or unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"{path}: {what} is not a readable image ({exc.__class__.__name__})") from None


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """A person mask PNG as ``(H, W)`` bool.

    8- or 16-bit grey (or RGB with equal channels): person where the value is at least half the
    type's maximum (128 / 32768); a mask whose values are only 0 and 1 is read as 0/1.
    """
    import cv2

    path = Path(path)
    try:
        data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    except FileNotFoundError:
        raise InputError(f"{path}: mask not found") from None
    m = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if m is None:
        raise InputError(f"{path}: not a readable mask image")
    if m.ndim == 3:
        if not all(np.array_equal(m[..., 0], m[..., c]) for c in range(1, min(m.shape[2], 3))):
            raise InputError(f"{path}: expected a grey mask, got {m.shape[2]} different channels")
        m = m[..., 0]
    if m.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{path}: expected an 8- or 16-bit mask, got {m.dtype}")
    if m.max(initial=0) <= 1:
        return m == 1
    return m >= (np.iinfo(m.dtype).max + 1) // 2


@dataclass(frozen=True, eq=False)
class HumanData:
    """A validated human training set (see the module docstring); ``HumanData.load(root)``.

    frames: the ``transforms.json`` frames (cameras, cam_to_world in OpenCV axes).
    poses: per-frame poses, aligned with ``frames``.
    image_paths, mask_paths: paths, one per frame.
    background_paths: per frame, the image of the view without the person, or None.
    """

    root: Path
    frames: tuple
    poses: HumanPoses
    image_paths: tuple[Path, ...]
    mask_paths: tuple[Path, ...]
    background_paths: tuple[Path | None, ...]

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    @property
    def skeleton(self) -> Skeleton:
        return self.poses.skeleton

    def cam_to_world(self) -> np.ndarray:
        """Camera poses ``(F, 4, 4)``, OpenCV axes."""
        return np.stack([fr.cam_to_world for fr in self.frames])

    def joint_transforms(self) -> np.ndarray:
        """Joint-to-world transforms ``(F, J, 4, 4)``."""
        return self.poses.joint_transforms()

    def image(self, i: int) -> np.ndarray:
        """Frame ``i`` as ``(H, W, 3)`` float32 RGB in [0, 1]."""
        from nsim.io.images import read_image, to_float

        return to_float(read_image(self.image_paths[i]))

    def mask(self, i: int) -> np.ndarray:
        """Person mask of frame ``i``: ``(H, W)`` bool."""
        return read_mask(self.mask_paths[i])

    def background(self, i: int) -> np.ndarray | None:
        """The view of frame ``i`` without the person, ``(H, W, 3)`` float32 in [0, 1]; None if not given."""
        from nsim.io.images import read_image, to_float

        path = self.background_paths[i]
        return None if path is None else to_float(read_image(path))

    def camera(self):
        """The camera all frames share (``nsim.geometry.cameras.Camera``); InputError if intrinsics differ."""
        first = self.frames[0].camera
        for i, fr in enumerate(self.frames):
            if fr.camera != first:
                raise InputError(f"{self.root / 'transforms.json'}: frames[{i}]: intrinsics differ from frames[0] "
                                 "(one camera per human data set)")
        return first

    def read_all(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Every frame in memory: images ``(F, H, W, 3)`` uint8, masks ``(F, H, W)`` bool and, when every
        frame has one, backgrounds ``(F, H, W, 3)`` uint8 (else None). Images must share one size."""
        from nsim.io.images import read_image

        images = [read_image(p) for p in self.image_paths]
        sizes = {im.shape for im in images}
        if len(sizes) != 1:
            raise InputError(f"{self.root}: images differ in size ({', '.join(sorted(map(str, sizes)))})")
        backgrounds = None
        if all(p is not None for p in self.background_paths):
            backgrounds = np.stack([read_image(p) for p in self.background_paths])
        return np.stack(images), np.stack([self.mask(i) for i in range(self.num_frames)]), backgrounds

    @classmethod
    def load(cls, root: str | os.PathLike, poses: str | os.PathLike | None = None,
             height_m: float | None = None, joint_map=None) -> HumanData:
        """Read and validate the data set at ``root``.

        poses: the poses file (``.json`` or ``.bvh``); None looks for ``poses.json``, then
        ``poses.bvh`` (with ``root_transforms.json`` beside it if present) in ``root``.
        height_m, joint_map: for BVH poses (see ``read_bvh_poses``).
        Checks: pose frame count = frame count, pose ``file_path`` = frame ``file_path``, images
        and masks exist, mask size = image size. InputError (one line: what and where) otherwise.
        """
        from nsim.io.transforms_json import read_transforms

        root = Path(root)
        transforms = read_transforms(root / "transforms.json")
        frames = tuple(transforms.frames)
        if not frames:
            raise InputError(f"{root / 'transforms.json'}: frames: empty (no images)")
        if poses is None:
            if (root / POSES_FILE).exists():
                poses_path = root / POSES_FILE
            elif (root / BVH_POSES_FILE).exists():
                poses_path = root / BVH_POSES_FILE
            else:
                raise InputError(f"{root}: no per-frame poses: expected {POSES_FILE} or {BVH_POSES_FILE}")
        else:
            poses_path = Path(poses)
        if poses_path.suffix.lower() == ".bvh":
            extra_path = poses_path.with_name(ROOT_TRANSFORMS_FILE)
            extra = read_root_transforms(extra_path) if extra_path.exists() else None
            if extra is not None and extra.shape[0] != len(frames):
                raise InputError(f"{extra_path}: {extra.shape[0]} root transforms but transforms.json has "
                                 f"{len(frames)} frames")
            clip_poses = _bvh_poses_for_frames(poses_path, len(frames), height_m, extra, joint_map)
        else:
            clip_poses = read_poses(poses_path)
        if clip_poses.num_frames != len(frames):
            raise InputError(f"{poses_path}: {clip_poses.num_frames} pose frames but transforms.json has "
                             f"{len(frames)} frames (poses are aligned to frames by index)")
        image_paths, mask_paths, background_paths = [], [], []
        for i, fr in enumerate(frames):
            fp = clip_poses.file_paths[i]
            if fp is not None and Path(fp) != Path(fr.file_path):
                raise InputError(f"{poses_path}: frames[{i}].file_path: {fp!r} does not match transforms.json "
                                 f"frames[{i}] ({fr.file_path!r})")
            image_path = root / fr.file_path
            mask_rel = fr.extra.get(MASK_PATH_KEY, f"{MASKS_DIR}/{Path(fr.file_path).stem}.png")
            if not isinstance(mask_rel, str):
                raise InputError(f"{root / 'transforms.json'}: frames[{i}].{MASK_PATH_KEY}: expected a string")
            mask_path = root / mask_rel
            if not mask_path.exists():
                raise InputError(f"{mask_path}: person mask of frame {i} ({fr.file_path}) not found")
            w, h = _image_size(image_path, f"image of frame {i}")
            mw, mh = _image_size(mask_path, f"person mask of frame {i}")
            if (mw, mh) != (w, h):
                raise InputError(f"{mask_path}: mask is {mw}x{mh} but image {fr.file_path} is {w}x{h}")
            background = fr.extra.get(BACKGROUND_PATH_KEY)
            if background is not None:
                if not isinstance(background, str):
                    raise InputError(f"{root / 'transforms.json'}: frames[{i}].{BACKGROUND_PATH_KEY}: expected a string")
                bw, bh = _image_size(root / background, f"background of frame {i}")
                if (bw, bh) != (w, h):
                    raise InputError(f"{root / background}: background is {bw}x{bh} but image {fr.file_path} is {w}x{h}")
                background = root / background
            image_paths.append(image_path)
            mask_paths.append(mask_path)
            background_paths.append(background)
        return cls(root, frames, clip_poses, tuple(image_paths), tuple(mask_paths), tuple(background_paths))


def _bvh_poses_for_frames(path: Path, n_frames: int, height_m: float | None, extra: np.ndarray | None,
                          joint_map) -> HumanPoses:
    """``read_bvh_poses`` with the frame-count check first (a clearer message than a shape error)."""
    from nsim.human.bvh import read_bvh

    clip = read_bvh(path)
    if clip.num_frames != n_frames:
        raise InputError(f"{path}: {clip.num_frames} BVH frames but transforms.json has {n_frames} frames "
                         "(poses are aligned to frames by index)")
    return _poses_from_bvh_clip(clip, path, height_m, extra, joint_map)


__all__ = ["HumanData", "HumanPoses", "poses_to_dict", "read_bvh_poses", "read_mask", "read_poses",
           "read_root_transforms", "skeleton_to_dict", "write_poses"]
