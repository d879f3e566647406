"""Retargeting a clip from any skeleton onto another (usually the nsim body) by a joint-name map.

Local Euler angles cannot simply be copied between skeletons: rest poses differ (a T-pose
against arms down), and so do the joints in between (CMU's ``LHipJoint``, ``LowerBack``).
What is transferred is each mapped joint's *world orientation relative to its rest*:

    G_target[j](t) = G_source[m(j)](t) @ C_j

with ``G`` the joint-to-world rotations (both skeletons have world-aligned rest frames, see
``nsim.human.skeleton``) and ``C_j`` the rest alignment: the smallest rotation that turns the
target's rest bone direction (joint ``j`` to the next mapped joint down its primary chain)
onto the source's (``m(j)`` to the source joint of that descendant). Joints whose bone has no
mapped descendant (feet, hands, the head) inherit the alignment of their parent; unmapped
target joints keep their rest orientation relative to their parent. When the two skeletons
share their rest pose every ``C_j`` is the identity and the world orientations are copied.

The target root takes the world position of its source joint, scaled by the ratio of leg
lengths (``Skeleton.leg_length_m``), so a shorter body takes proportionally shorter steps; by
default it is then shifted vertically so that the feet touch the floor (``ground_feet``).

A ``JointMap`` maps each nsim joint to one or more candidate source names (the first present
in the source is used; names match case-insensitively, ignoring a ``prefix:`` such as
Mixamo's ``mixamorig:``), in one or more naming profiles (the best-matching one is used).
``default_joint_map()`` reads ``nsim/configs/motions/joint_map.yaml``: profiles for nsim's own
names, CMU (cgspeed BVH conversion) and Mixamo.

A skeleton that mostly does not map would come out as a body with straight legs and a stiff
spine, so ``retarget`` refuses it (``check_coverage``): fewer than ``MIN_MAPPED_FRACTION`` of
the target's joints mapped, or one of ``REQUIRED_JOINTS`` (pelvis, hips, knees, ankles)
missing, is an InputError naming the clip, the count and the missing joints. Joints the
profile names but the source lacks are one warning.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from nsim.config import configs_dir, parse_yaml, read_text_file
from nsim.errors import InputError
from nsim.human.motion import MotionClip
from nsim.human.skeleton import Skeleton, local_rotations_from_global, quats_from_matrices

DEFAULT_JOINT_MAP_FILE = "motions/joint_map.yaml"
"""Path of the default joint map, relative to ``nsim.config.configs_dir()``."""

MIN_MAPPED_FRACTION = 0.5
"""``retarget`` refuses (InputError) when fewer than this fraction of the target's joints map to source joints."""
REQUIRED_JOINTS = ("pelvis", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle")
"""Target joints ``retarget`` refuses to do without (those the target has): unmapped, the legs would not bend."""

log = logging.getLogger(__name__)


def _key(name: str) -> str:
    return name.rsplit(":", 1)[-1].strip().lower()


@dataclass(frozen=True)
class JointMap:
    """Target joint name -> candidate source joint names, in one or more naming *profiles*.

    profiles: ``(profile name, {target: (source candidates, ...)})`` pairs. ``resolve`` uses the
    profile that matches the most target joints in the source skeleton (the first on ties).
    source: where the map came from (for messages).
    """

    profiles: tuple[tuple[str, Mapping[str, tuple[str, ...]]], ...]
    source: str = "<joint map>"

    @classmethod
    def from_mapping(cls, data: Mapping, source: str = "<joint map>") -> JointMap:
        """From ``{target: name | [names]}`` (one profile) or ``{profiles: {name: {target: ...}}}``.

        InputError naming ``source`` and the key for bad entries.
        """
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected a mapping of target joint -> source joint name(s), "
                             f"got {type(data).__name__}")
        if "profiles" in data:
            raw = data["profiles"]
            if not isinstance(raw, Mapping) or not raw or len(data) != 1:
                raise InputError(f"{source}: profiles: expected the only top-level key, a non-empty mapping "
                                 "of profile name -> joint map")
            items = [(str(k), v, f"profiles.{k}.") for k, v in raw.items()]
        else:
            items = [("default", data, "")]
        profiles = []
        for pname, mapping, prefix in items:
            if not isinstance(mapping, Mapping):
                raise InputError(f"{source}: {prefix.rstrip('.')}: expected a mapping, got {type(mapping).__name__}")
            out: dict[str, tuple[str, ...]] = {}
            for k, v in mapping.items():
                names = (v,) if isinstance(v, str) else v
                if not isinstance(k, str) or not isinstance(names, (list, tuple)) or not names or not all(
                        isinstance(n, str) and n for n in names):
                    raise InputError(f"{source}: {prefix}{k}: expected a joint name or a non-empty list of names, "
                                     f"got {v!r}")
                out[k] = tuple(names)
            profiles.append((pname, out))
        return cls(tuple(profiles), source)

    def resolve(self, source: Skeleton, target: Skeleton) -> dict[int, int]:
        """``{target joint index: source joint index}`` for every target joint with a candidate in ``source``.

        Uses the best-matching profile (``resolve_profile``).
        """
        return self.resolve_profile(source, target)[1]

    def resolve_profile(self, source: Skeleton, target: Skeleton) -> tuple[str, dict[int, int]]:
        """The best-matching profile's name and its ``{target joint index: source joint index}``.

        The best profile maps the most target joints, then has the fewest joints whose names the
        source lacks (the first on ties: CMU's names also match most of Mixamo's). InputError
        (naming the map) for target names that the target skeleton does not have.
        """
        by_key: dict[str, int] = {}
        for i, n in enumerate(source.joint_names):
            by_key.setdefault(_key(n), i)
        best_name, best, best_score = self.profiles[0][0], {}, (0, 0)
        for pname, table in self.profiles:
            out: dict[int, int] = {}
            for tname, candidates in table.items():
                if tname not in target.joint_names:
                    where = f"profiles.{pname}." if len(self.profiles) > 1 else ""
                    raise InputError(f"{self.source}: {where}{tname}: not a joint of the target skeleton "
                                     f"({', '.join(target.joint_names)})")
                for c in candidates:
                    if _key(c) in by_key:
                        out[target.index(tname)] = by_key[_key(c)]
                        break
            score = (len(out), len(out) - len(table))  # most joints mapped, then fewest named but absent
            if score > best_score:
                best_name, best, best_score = pname, out, score
        return best_name, best

    def profile(self, name: str) -> Mapping[str, tuple[str, ...]]:
        """The table of profile ``name``."""
        return dict(self.profiles)[name]

    def candidates(self, target_joint: str) -> tuple[str, ...]:
        """All source names tried for ``target_joint`` across the profiles (for messages)."""
        return tuple(dict.fromkeys(c for _, t in self.profiles for c in t.get(target_joint, ())))


def load_joint_map(path: str | os.PathLike[str]) -> JointMap:
    """Read a joint map YAML ``{nsim_joint: source_name | [source_names]}``."""
    text = read_text_file(path, "joint map", error=InputError)
    return JointMap.from_mapping(parse_yaml(text, path, error=InputError), str(path))


def default_joint_map() -> JointMap:
    """The shipped map (``nsim/configs/motions/joint_map.yaml``): nsim names, CMU and Mixamo names."""
    return load_joint_map(configs_dir() / DEFAULT_JOINT_MAP_FILE)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation ``(3, 3)`` turning direction ``a (3,)`` onto direction ``b (3,)`` (both nonzero)."""
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K * ((1.0 - c) / (s * s))


def rest_alignment(source: Skeleton, target: Skeleton, mapping: Mapping[int, int]) -> np.ndarray:
    """Per-target-joint rest alignment ``C (J_target, 3, 3)`` (see the module docstring)."""
    ps = source.rest_positions_m()
    pt = target.rest_positions_m()
    C = np.broadcast_to(np.eye(3), (target.num_joints, 3, 3)).copy()
    for j in range(1, target.num_joints):
        C[j] = C[target.parents[j]]
        if j not in mapping:
            continue
        m = j
        while True:  # first mapped joint down the primary chain
            kids = target.children(m)
            if not kids:
                m = -1
                break
            m = kids[0]
            if m in mapping:
                break
        if m < 0:
            continue
        dt = pt[m] - pt[j]
        ds = ps[mapping[m]] - ps[mapping[j]]
        if np.linalg.norm(dt) > 1e-9 and np.linalg.norm(ds) > 1e-9:
            C[j] = rotation_between(dt, ds)
    return C


def check_coverage(mapping: Mapping[int, int], source: Skeleton, target: Skeleton, profile: str = "",
                   expected: Mapping[str, object] | None = None, name: str = "<clip>") -> None:
    """Refuse a joint mapping that would leave the body mostly unposed; warn about partial ones.

    InputError (one line naming ``name``, how many of the target's joints map and which are
    missing) when fewer than ``MIN_MAPPED_FRACTION`` of them map, or one of ``REQUIRED_JOINTS``
    does not. Otherwise one warning if some target joints that ``expected`` (the profile's
    table) names a source joint for are not in ``source``: they follow their parents.
    """
    J = target.num_joints
    missing = [n for i, n in enumerate(target.joint_names) if i not in mapping]
    need = math.ceil(MIN_MAPPED_FRACTION * J)
    lacking = [n for n in REQUIRED_JOINTS if n in missing]
    names = f" ({profile} names)" if profile else ""
    if len(mapping) < need or lacking:
        why = f"need at least {need}" + (f", including {', '.join(lacking)}" if lacking else "")
        shown = ", ".join(source.joint_names[:12]) + (", ..." if source.num_joints > 12 else "")
        raise InputError(f"{name}: only {len(mapping)} of {J} body joints map to the source skeleton{names}; "
                         f"missing: {', '.join(missing)} ({why}); source joints: {shown}; "
                         f"give a joint map for this skeleton (see nsim/configs/{DEFAULT_JOINT_MAP_FILE})")
    absent = [n for n in missing if expected and expected.get(n)]
    if absent:
        log.warning("%s: %d of %d body joints map to the source skeleton%s; no source joint for %s, which "
                    "follow their parents", name, len(mapping), J, names, ", ".join(absent))


def retarget(clip: MotionClip, target: Skeleton, joint_map: JointMap | Mapping | None = None,
             root_scale: float | None = None, ground_feet: bool = True) -> MotionClip:
    """``clip`` on ``target`` (see the module docstring).

    joint_map: ``JointMap``, a mapping ``{target: name | [names]}``, or None for ``default_joint_map()``.
    root_scale: factor on the root position; None is the ratio of leg lengths (rest height of the
        root above the lowest joint, target over source).
    ground_feet: shift the root vertically so that the retargeted clip's lowest joint (over all
        frames) is as high above the floor as the target's lowest joint in its rest pose (soles on
        ``z = 0``); the source's floor height and foot geometry then do not matter. False: the root
        height is only scaled.
    The target's root joint must be mapped. Returns a clip with the same frames, fps and loop flag.
    """
    if joint_map is None:
        joint_map = default_joint_map()
    elif not isinstance(joint_map, JointMap):
        joint_map = JointMap.from_mapping(joint_map)
    source = clip.skeleton
    profile, mapping = joint_map.resolve_profile(source, target)
    if 0 not in mapping:
        tried = ", ".join(joint_map.candidates(target.joint_names[0])) or "no candidates"
        raise InputError(f"{clip.name or '<clip>'}: no source joint for the root {target.joint_names[0]!r} "
                         f"(tried {tried}; source joints: {', '.join(source.joint_names)})")
    check_coverage(mapping, source, target, profile if len(joint_map.profiles) > 1 else "",
                   joint_map.profile(profile), clip.name or "<clip>")
    if root_scale is None:
        ps = source.rest_positions_m()
        leg_s, leg_t = ps[mapping[0], 2] - ps[:, 2].min(), target.leg_length_m()
        root_scale = leg_t / leg_s if leg_s > 1e-6 else 1.0
    C = rest_alignment(source, target, mapping)
    T_src = clip.joint_transforms()  # (F, Js, 4, 4)
    G_src = T_src[..., :3, :3]
    F = clip.num_frames
    G = np.empty((F, target.num_joints, 3, 3))
    for j in range(target.num_joints):
        if j in mapping:
            G[:, j] = G_src[:, mapping[j]] @ C[j]
        else:
            G[:, j] = G[:, target.parents[j]] if j > 0 else np.eye(3)
    L = local_rotations_from_global(target, G)
    root = T_src[:, mapping[0], :3, 3] * float(root_scale)
    quats = quats_from_matrices(L)
    if ground_feet:
        posed = MotionClip(target, clip.fps, root, quats).joint_positions()
        root[:, 2] += float(target.rest_positions_m()[:, 2].min()) - float(posed[..., 2].min())
    return MotionClip(target, clip.fps, root, quats, name=clip.name, loop=clip.loop)
