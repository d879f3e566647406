"""A simulated person's motion: one of nsim's procedural clips or a recorded clip, and what follows from it.

Motions
    A name in ``nsim.human.gait.DEFAULT_CLIPS`` (``walk``, ``walk_slow``, ``walk_fast``: nsim's procedural
    walks at 1.3, 0.8 and 1.8 m/s; ``idle``: standing), or a *recorded clip*: a BVH file (any unit, any
    naming ``nsim/configs/motions/joint_map.yaml`` knows, or the caller's joint map) or a human
    checkpoint's ``person.bvh`` (the motion ``train-human --video`` fitted), read by ``load_recorded_clip``:
    retargeted onto the reference body ``nsim_skeleton(REFERENCE_HEIGHT_M)`` (``nsim.human.retarget``:
    the root's motion scaled by leg length, the feet on the floor), kept at ``MAX_CLIP_FPS`` frames per
    second at most (resampled over the same duration, so its travel speed is kept) and rounded to
    ``CLIP_DECIMALS`` decimals (a micrometre; a millionth of a quaternion component) so that it is the
    same clip on every CPU. ``clip_data`` / ``clip_from_data`` is its plain form (what a scenario stores),
    ``clip_digest`` the SHA-256 that names it.

Heights (the rule of ``nsim.human.gait.default_clip``)
    A person ``h`` tall plays a clip on ``nsim_skeleton(h)`` (``clip_at_height``): positions scale by
    ``s = h / REFERENCE_HEIGHT_M``, and the time of a clip that travels too, so that its speed is the
    clip's at every height while its stride and cycle grow with the body (as nsim's walks do:
    ``stride_length_m(v, h)``); a clip that does not travel keeps its timing (the idle's 4 s cycle).

What follows (``person_gait``)
    The speed the clip travels at (``LocomotionLoop.speed_mps``; 0 for a clip that does not travel,
    whose person stands): a scenario person's desired speed unless the scenario gives one. How the
    crowd advances the person's gait phase (``nsim.human.gait_phase.advance_person_phase``): a
    procedural walk by the stride formula it is built with, a recorded clip by its own stride at the
    person's height (its feet do not slide at any speed), a clip that does not travel by time over
    its cycle. ``person_loop`` is the loop the renderer poses the body with: the same clip at the same
    height, so its stride and cycle are the ones ``person_gait`` gives the crowd.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from nsim.config import canonical_json
from nsim.errors import InputError
from nsim.human.bvh import load_bvh
from nsim.human.gait import DEFAULT_CLIPS, IDLE_PERIOD_S, default_clip
from nsim.human.motion import LocomotionLoop, MotionClip
from nsim.human.retarget import JointMap, default_joint_map, retarget
from nsim.human.skeleton import REFERENCE_HEIGHT_M, nsim_skeleton

MAX_CLIP_FPS = 30.0
"""A recorded clip more than 1 % faster than this is resampled to about this rate (over its own duration)
when read (a BVH file's ``Frame Time: 0.033333`` is 30.00003 fps, kept as it is)."""
CLIP_DECIMALS = 6
"""Decimals of a stored clip's root positions (metres) and rotations (quaternion components)."""
MIN_CLIP_FRAMES = 3
"""Frames a recorded clip needs (``LocomotionLoop.from_clip``)."""


@dataclass(frozen=True)
class Gait:
    """What a person's motion means for the crowd (see the module docstring).

    speed_mps: the clip's travel speed (0: it does not travel). stride_m: the clip's own stride at the
    person's height (> 0), or 0 for nsim's procedural walks (the stride formula). period_s: > 0 for a clip
    that does not travel (the phase advances with time over it), else 0.
    """

    speed_mps: float
    stride_m: float
    period_s: float


@dataclass(frozen=True)
class RecordedClip:
    """A recorded clip read by ``load_recorded_clip``.

    clip: on the reference body, as it is stored (rounded). description: how it was read (unit, axes,
    joint names, joints mapped, frames), with no path in it. unit_m: the file's metres per unit;
    unit_found: how ``unit="auto"`` measured it (None when given).
    """

    clip: MotionClip
    description: str
    unit_m: float
    unit_found: str | None


def clip_data(clip: MotionClip) -> dict[str, Any]:
    """The plain form of a clip on the reference body: ``fps``, ``root_positions_m`` (F, 3) and
    ``local_rotations_wxyz`` (F, 24, 4) as lists, rounded to ``CLIP_DECIMALS`` (``-0`` written ``0``)."""

    def rounded(a: np.ndarray) -> list:
        return (np.round(np.asarray(a, dtype=np.float64), CLIP_DECIMALS) + 0.0).tolist()

    return {"fps": float(round(clip.fps, 9)), "root_positions_m": rounded(clip.root_positions_m),
            "local_rotations_wxyz": rounded(clip.local_rotations_wxyz)}


def clip_from_data(data: Mapping[str, Any], name: str = "") -> MotionClip:
    """The clip of ``clip_data``'s plain form on the reference body; ``ValueError`` saying what is wrong."""
    try:
        fps = float(data["fps"])
        root = np.asarray(data["root_positions_m"], dtype=np.float64)
        quats = np.asarray(data["local_rotations_wxyz"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"expected fps, root_positions_m (F, 3) and local_rotations_wxyz (F, 24, 4) "
                         f"({exc.__class__.__name__}: {exc})") from None
    if root.ndim != 2 or root.shape[0] < MIN_CLIP_FRAMES:
        raise ValueError(f"root_positions_m: expected at least {MIN_CLIP_FRAMES} frames of (x, y, z), "
                         f"got shape {root.shape}")
    return MotionClip(nsim_skeleton(), fps, root, quats, name=name)


def clip_digest(data: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of a clip's plain form (``clip_data``), as canonical JSON."""
    return hashlib.sha256(canonical_json(dict(data))).hexdigest()


def _resampled(clip: MotionClip, max_fps: float) -> MotionClip:
    """``clip`` at about ``max_fps`` when it is faster: ``n = round(duration * max_fps)`` intervals over the
    same duration (the first and last frames kept, so the travel and its speed are the same)."""
    if clip.fps <= 1.01 * max_fps:
        return clip
    n = max(MIN_CLIP_FRAMES - 1, int(round(clip.duration_s * max_fps)))
    root, quats = clip.sample(np.linspace(0.0, clip.duration_s, n + 1))
    return MotionClip(clip.skeleton, n / clip.duration_s, root, quats, name=clip.name, loop=clip.loop)


def load_recorded_clip(path: str | os.PathLike[str], unit: str | float = "auto", axes: str = "y_up",
                       joint_map: JointMap | Mapping | None = None) -> RecordedClip:
    """A BVH file as a recorded clip on the reference body (the module docstring).

    unit, axes: as ``nsim.human.bvh.load_bvh``; joint_map: as ``nsim.human.retarget.retarget`` (None: the
    shipped profiles). A malformed file, fewer than ``MIN_CLIP_FRAMES`` frames or a skeleton too few of
    whose joints map raise ``InputError`` naming the file.
    """
    found = load_bvh(path, unit=unit, axes=axes)
    source = found.clip
    if source.num_frames < MIN_CLIP_FRAMES:
        raise InputError(f"{path}: {source.num_frames} frame(s); a motion needs at least {MIN_CLIP_FRAMES}")
    body = nsim_skeleton()
    jm = default_joint_map() if joint_map is None else (
        joint_map if isinstance(joint_map, JointMap) else JointMap.from_mapping(joint_map))
    profile, mapping = jm.resolve_profile(source.skeleton, body)
    retargeted = retarget(source, body, jm)
    played = _resampled(retargeted, MAX_CLIP_FPS)
    clip = clip_from_data(clip_data(played), name=str(path))
    if found.unit_found is None:
        unit_text = f"unit {unit if isinstance(unit, str) else format(float(unit), 'g') + ' m'}"
    else:
        unit_text = f"unit measured: {found.unit_found}"
    rate = f"{clip.num_frames} frames at {clip.fps:.6g} fps"
    if played is not retargeted:
        rate += f" (resampled from {source.num_frames} at {source.fps:.6g} fps)"
    names = f"{profile} joint names" if len(jm.profiles) > 1 else "the given joint map"
    description = (f"{unit_text}, {found.unit_m:.6g} m per unit; axes {axes}; {names}, {len(mapping)} of "
                   f"{body.num_joints} body joints mapped; {rate}")
    return RecordedClip(clip, description, found.unit_m, found.unit_found)


STEADY_TOLERANCE_M = 0.25
"""A recorded clip whose root strays further than this from a steady walk along its travel is warned about:
played as one cycle, its body drifts about the person's position (a start and a stop, a turn)."""


def unsteadiness_m(clip: MotionClip) -> float:
    """How far (m) the clip's root strays on the floor from moving at its mean velocity (its loop's
    ``residual_root_m``): a few centimetres of sway for a steady walk, metres for a start-walk-stop."""
    return float(np.linalg.norm(LocomotionLoop.from_clip(clip).residual_root_m[:, :2], axis=1).max())


def clip_at_height(clip: MotionClip, height_m: float) -> MotionClip:
    """``clip`` (on the reference body) played by a person ``height_m`` tall (the module docstring's rule)."""
    s = float(height_m) / REFERENCE_HEIGHT_M
    fps = clip.fps / s if LocomotionLoop.from_clip(clip).travels else clip.fps
    return MotionClip(nsim_skeleton(height_m), fps, clip.root_positions_m * s, clip.local_rotations_wxyz,
                      name=clip.name, loop=clip.loop)


def person_loop(motion: str, clip: MotionClip | None, height_m: float) -> LocomotionLoop:
    """The loop that poses a person ``height_m`` tall: the recorded ``clip`` (reference body) when given,
    else nsim's clip named ``motion`` (``nsim.human.gait.default_clip``)."""
    if clip is None:
        return LocomotionLoop.from_clip(default_clip(motion, height_m))
    return LocomotionLoop.from_clip(clip_at_height(clip, height_m))


def person_gait(motion: str, clip: MotionClip | None, height_m: float) -> Gait:
    """The speed, stride and cycle the crowd gives a person ``height_m`` tall (the module docstring)."""
    if clip is None:
        if motion not in DEFAULT_CLIPS:
            raise ValueError(f"unknown motion {motion!r}; valid: {', '.join(DEFAULT_CLIPS)}")
        speed = DEFAULT_CLIPS[motion]
        return Gait(0.0, 0.0, IDLE_PERIOD_S) if speed is None else Gait(float(speed), 0.0, 0.0)
    loop = person_loop(motion, clip, height_m)
    if loop.travels:
        return Gait(float(loop.speed_mps), float(loop.stride_m), 0.0)
    return Gait(0.0, 0.0, float(loop.period_s))


def person_clip_arrays(clips: Sequence[tuple[str, MotionClip] | None]) -> dict[str, np.ndarray]:
    """A run's recorded clips as arrays (for ``trajectory.npz``; ``person_clips`` reads them back).

    clips: per person, ``(clip id, clip on the reference body)`` or None (nsim's clip, named by the run's
    ``motion``). Nothing when no person has a recorded clip. Else ``motion_clip (P,)`` int64: the
    person's clip (-1: none), and per clip (each once, in the order of first use) ``motion_clip_fps (C,)``,
    ``motion_clip_frames (C,)`` int64 and its frames after those of the clips before it:
    ``motion_clip_root_m (sum F, 3)``, ``motion_clip_rotations_wxyz (sum F, 24, 4)``.
    """
    if all(c is None for c in clips):
        return {}
    ids: dict[str, int] = {}
    kept: list[MotionClip] = []
    index = []
    for c in clips:
        if c is None:
            index.append(-1)
            continue
        if c[0] not in ids:
            ids[c[0]] = len(kept)
            kept.append(c[1])
        index.append(ids[c[0]])
    return {
        "motion_clip": np.array(index, dtype=np.int64),
        "motion_clip_fps": np.array([c.fps for c in kept], dtype=np.float64),
        "motion_clip_frames": np.array([c.num_frames for c in kept], dtype=np.int64),
        "motion_clip_root_m": np.concatenate([c.root_positions_m for c in kept]),
        "motion_clip_rotations_wxyz": np.concatenate([c.local_rotations_wxyz for c in kept]),
    }


def person_clips(arrays: Mapping[str, np.ndarray], people: int) -> list[MotionClip | None]:
    """Per person, its recorded clip (reference body) from ``person_clip_arrays``' arrays, or None (nsim's clip;
    also every person of a run with no recorded clip)."""
    if "motion_clip" not in arrays:
        return [None] * people
    frames = np.asarray(arrays["motion_clip_frames"], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(frames)])
    root, quats = np.asarray(arrays["motion_clip_root_m"]), np.asarray(arrays["motion_clip_rotations_wxyz"])
    fps = np.asarray(arrays["motion_clip_fps"], dtype=np.float64)
    body = nsim_skeleton()
    clips = [MotionClip(body, float(fps[c]), root[start[c]:start[c + 1]], quats[start[c]:start[c + 1]],
                        name=f"clip {c}") for c in range(len(frames))]
    return [None if i < 0 else clips[i] for i in np.asarray(arrays["motion_clip"], dtype=np.int64)]
