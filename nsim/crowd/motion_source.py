"""A scenario person's recorded motion -- ``humans[k].motion: {bvh: FILE, unit, axes, joint_map}`` or
``{from: HUMAN_CHECKPOINT}`` -- read before any simulation work and stored in the scenario itself
(:func:`nsim.crowd.scenario.with_motion_clips`): the clip on the nsim body in ``motion_clips``, named by its
SHA-256, and the person's motion ``{clip: SHA256, source}``, ``source`` saying what was read and how (the
file's SHA-256, or the checkpoint's artifact id; the unit, measured or given; the joint names; the frames),
never where the file was. ``store`` is the workspace (its ``resolve`` and ``get``) for a human checkpoint, whose
motion is its file ``person_bvh`` (the simulate stage passes the name ``train-human`` writes); nothing here
writes to the workspace. A file that is missing or malformed, a checkpoint without ``person.bvh`` or a
skeleton too few of whose joints map is one ``InputError`` line naming ``humans[k].motion`` and the file.

A unit that ``auto`` measured is one log line with its number; a clip that does not move steadily (a start
and a stop: it plays as one cycle, ``person_motion.unsteadiness_m``) one warning; a person whose scenario gives
a speed other than its clip's own is named in one log line (the clip is played at that speed, its feet do not slide: the
crowd advances its phase by the clip's stride, ``nsim.human.gait_phase.advance_person_phase``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from nsim.crowd.scenario import ScenarioSpec, with_motion_clips
from nsim.errors import InputError
from nsim.human.motion import MotionClip
from nsim.human.person_motion import STEADY_TOLERANCE_M, load_recorded_clip, person_gait, unsteadiness_m
from nsim.human.skeleton import REFERENCE_HEIGHT_M

log = logging.getLogger("nsim.stages.simulate")

CHECKPOINT_BVH_UNIT = "cm"
"""The unit ``train-human --video`` writes ``person.bvh`` in (``nsim.human.bvh.write_bvh``'s default)."""


def resolve_motions(spec: ScenarioSpec, store, person_bvh: Callable[[], str]) -> ScenarioSpec:
    """``spec`` with every ``{bvh: ...}`` and ``{from: ...}`` motion read and stored as a clip (the module docstring);
    ``person_bvh()``: the name of a human checkpoint's file holding its fitted motion
    (``nsim.train.human_data_video.PERSON_BVH_FILE``), asked only for a ``{from: ...}`` motion."""
    clips: dict[int, tuple[MotionClip, str]] = {}
    read: dict[str, tuple[MotionClip, str]] = {}  # the same entry (file and settings, or checkpoint) read once
    for k, h in enumerate(spec.data["humans"]):
        motion = h["motion"]
        if not (isinstance(motion, dict) and ("bvh" in motion or "from" in motion)):
            continue
        key = json.dumps(motion, sort_keys=True)
        if key not in read:
            read[key] = (_bvh_clip(spec, k, motion) if "bvh" in motion
                         else _checkpoint_clip(spec, k, motion["from"], store, person_bvh()))
        clips[k] = read[key]
    for clip, _ in read.values():
        if (stray := unsteadiness_m(clip)) > STEADY_TOLERANCE_M:
            who = ", ".join(f"humans[{k}]" for k, (c, _) in clips.items() if c is clip)
            log.warning("%s: %s: the clip's root strays up to %.2f m from a steady walk along its travel (a start or "
                        "a stop, a turn?); it plays as one cycle of %.2f s, %.2f m, so the body drifts about the "
                        "person's position: cut the clip to a steady stretch", spec.source, who, stray,
                        clip.duration_s, person_gait("", clip, REFERENCE_HEIGHT_M).stride_m)
    _log_other_speeds(spec, clips)
    return with_motion_clips(spec, clips) if clips else spec


def _file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _bvh_clip(spec: ScenarioSpec, k: int, motion: dict[str, Any]) -> tuple[MotionClip, str]:
    """A ``{bvh: FILE, ...}`` motion read (paths relative to the scenario file)."""
    from nsim.human.retarget import JointMap, load_joint_map

    where = ("humans", k, "motion")
    path = spec.file((*where, "bvh"), motion["bvh"], "a BVH file")
    joint_map = motion.get("joint_map")
    if isinstance(joint_map, str):
        map_path = spec.file((*where, "joint_map"), joint_map, "a joint map file")
        try:
            joint_map = load_joint_map(map_path)
        except InputError as exc:
            raise spec.error((*where, "joint_map"), str(exc)) from None
    elif joint_map is not None:
        joint_map = JointMap.from_mapping(joint_map, f"{spec.source}: humans[{k}].motion.joint_map")
    try:
        read = load_recorded_clip(path, unit=motion["unit"], axes=motion["axes"], joint_map=joint_map)
    except InputError as exc:
        raise spec.error(where, str(exc)) from None
    if read.unit_found is not None:
        log.info("%s: humans[%d].motion: %s: %s, taken as %.6g m per unit (unit: auto; give unit to set it)",
                 spec.source, k, path, read.unit_found, read.unit_m)
    return read.clip, f"bvh file sha256 {_file_sha256(path)} ({read.description})"


def _checkpoint_clip(spec: ScenarioSpec, k: int, ref: str, store, person_bvh: str) -> tuple[MotionClip, str]:
    """A ``{from: REF}`` motion: the human checkpoint's ``person_bvh`` (nsim's own names and unit)."""
    where = ("humans", k, "motion", "from")
    art_id = spec.artifact(where, ref, "human-checkpoint", store, "a human checkpoint's motion")
    path = store.get(art_id).path / person_bvh
    if not path.is_file():
        raise spec.error(where, f"human checkpoint {art_id[:12]} ({ref}) has no {person_bvh}: only one "
                         "trained from a video (nsim train-human --video) holds the person's fitted motion")
    try:
        read = load_recorded_clip(path, unit=CHECKPOINT_BVH_UNIT)
    except InputError as exc:
        raise spec.error(where, str(exc)) from None
    return read.clip, f"human-checkpoint {art_id} {person_bvh} ({read.description})"


def _log_other_speeds(spec: ScenarioSpec, clips: dict[int, tuple[MotionClip, str]]) -> None:
    """One line naming the people whose scenario gives a speed other than their clip's own (recorded clips, and
    the idle, which stands): they walk at the given speed, the clip played at it."""
    other = []
    for k, h in enumerate(spec.data["humans"]):
        if k in clips:
            own, what = person_gait("", clips[k][0], REFERENCE_HEIGHT_M).speed_mps, "its clip's"
        elif h["motion"] == "idle":
            own, what = 0.0, "the idle's"
        else:
            continue
        given = h.get("speed_mps")
        if given is not None and not math.isclose(given, own, rel_tol=1e-3, abs_tol=1e-3):
            other.append(f"humans[{k}] ({h['id']}) {given:g} m/s, {what} {own:.3g} m/s")
    if other:
        log.info("%s: %d %s a speed_mps other than the motion's own, so the clip is played at another speed than "
                 "its own (its cadence follows; its feet do not slide): %s", spec.source, len(other),
                 "person has" if len(other) == 1 else "people have", "; ".join(other))
