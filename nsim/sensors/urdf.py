"""Link frames from a URDF robot description, so a rig can mount sensors on named links.

Parsed with the standard library's ``xml.etree`` (a URDF library such as yourdfpy pulls in trimesh
with a dozen mesh and geometry packages; link frames need none of that). What is read: ``<robot
name>``, every ``<link name>``, and every ``<joint>``'s ``type``, ``<parent link>``, ``<child
link>``, ``<origin xyz rpy>`` and ``<axis xyz>``. Visuals, collisions, inertials, limits and
mimic tags are ignored; xacro macros must be expanded first (``xacro robot.urdf.xacro``).

Conventions (URDF / ROS REP 103): metres and radians; link frames are x forward, y left, z up;
``rpy`` is a fixed-axis roll-pitch-yaw, ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. A joint's origin
is the child link's frame in the parent link's frame at joint position 0; a revolute or
continuous joint then rotates the child about ``axis`` (in the joint frame) by its position in
radians, a prismatic joint translates it along ``axis`` by its position in metres. Fixed,
floating and planar joints do not move here (floating/planar take no position).

Poses are ``(4, 4)`` float64 ``a_to_b`` matrices mapping frame-``a`` coordinates to frame ``b``.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.geometry.transforms import make_se3

JOINT_TYPES = ("fixed", "revolute", "continuous", "prismatic", "floating", "planar")
_MOVING = ("revolute", "continuous", "prismatic")


def rpy_to_matrix(rpy_rad) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw ``(3,)`` radians -> rotation ``(3, 3)``: ``Rz(y) Ry(p) Rx(r)``."""
    r, p, y = (float(v) for v in rpy_rad)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation ``(3, 3)`` by ``angle`` radians about the unit ``axis (3,)`` (Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


@dataclass(frozen=True, eq=False)
class UrdfJoint:
    """One joint. origin: ``(4, 4)`` child frame in the parent frame at position 0; axis: ``(3,)`` unit."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray

    def child_to_parent(self, position: float = 0.0) -> np.ndarray:
        """The child link's frame in the parent link's frame at joint ``position``: ``(4, 4)``."""
        if position == 0.0:
            return self.origin.copy()
        if self.type in ("revolute", "continuous"):
            motion = make_se3(_axis_angle(self.axis, position), np.zeros(3))
        else:  # prismatic
            motion = make_se3(np.eye(3), self.axis * position)
        return self.origin @ motion


@dataclass(frozen=True, eq=False)
class Urdf:
    """A parsed URDF: its links and joints (a tree). ``joints`` maps a *child* link to its joint."""

    path: Path
    robot_name: str
    root_link: str
    links: tuple[str, ...]
    joints: Mapping[str, UrdfJoint]

    def _check_link(self, link: str) -> None:
        if link not in self.links:
            known = ", ".join(self.links)
            raise InputError(f"{self.path}: no link named {link!r} (links: {known})")

    def link_to_root(self, link: str, joint_positions: Mapping[str, float] | None = None) -> np.ndarray:
        """Pose ``(4, 4)`` of ``link``'s frame in the root link's frame.

        joint_positions: joint name -> position (radians or metres) for moving joints; joints not
        named are at 0. Naming an unknown or non-moving joint is an InputError.
        """
        self._check_link(link)
        positions = dict(joint_positions or {})
        by_name = {j.name: j for j in self.joints.values()}
        for name in positions:
            if name not in by_name:
                raise InputError(f"{self.path}: no joint named {name!r}")
            if by_name[name].type not in _MOVING:
                raise InputError(f"{self.path}: joint {name!r} is {by_name[name].type} and takes no position")
        pose = np.eye(4)
        node = link
        while node != self.root_link:
            joint = self.joints[node]
            pose = joint.child_to_parent(float(positions.get(joint.name, 0.0))) @ pose
            node = joint.parent
        return pose

    def link_to_link(
        self, link: str, reference: str, joint_positions: Mapping[str, float] | None = None
    ) -> np.ndarray:
        """Pose ``(4, 4)`` of ``link``'s frame in ``reference``'s frame (``reference_T_link``)."""
        self._check_link(reference)
        ref_to_root = self.link_to_root(reference, joint_positions)
        R, t = ref_to_root[:3, :3], ref_to_root[:3, 3]
        root_to_ref = make_se3(R.T, -R.T @ t)
        return root_to_ref @ self.link_to_root(link, joint_positions)


def _floats(path: Path, text: str | None, n: int, where: str, default: tuple[float, ...]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=np.float64)
    parts = text.split()
    try:
        values = np.array([float(p) for p in parts], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: {where}: expected {n} numbers, got {text!r}") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise InputError(f"{path}: {where}: expected {n} finite numbers, got {text!r}")
    return values


def _parse_joint(path: Path, el: ET.Element) -> UrdfJoint:
    name = el.get("name")
    if not name:
        raise InputError(f"{path}: a <joint> has no name")
    where = f"joint {name!r}"
    jtype = el.get("type")
    if jtype not in JOINT_TYPES:
        raise InputError(f"{path}: {where}: type {jtype!r} is not one of {', '.join(JOINT_TYPES)}")
    links = {}
    for tag in ("parent", "child"):
        sub = el.find(tag)
        if sub is None or not sub.get("link"):
            raise InputError(f"{path}: {where}: missing <{tag} link=...>")
        links[tag] = sub.get("link")
    origin_el = el.find("origin")
    xyz = _floats(path, None if origin_el is None else origin_el.get("xyz"), 3, f"{where}.origin.xyz", (0, 0, 0))
    rpy = _floats(path, None if origin_el is None else origin_el.get("rpy"), 3, f"{where}.origin.rpy", (0, 0, 0))
    axis_el = el.find("axis")
    axis = _floats(path, None if axis_el is None else axis_el.get("xyz"), 3, f"{where}.axis.xyz", (1, 0, 0))
    norm = float(np.linalg.norm(axis))
    if jtype in _MOVING and norm < 1e-9:
        raise InputError(f"{path}: {where}.axis.xyz: must be nonzero")
    axis = axis / norm if norm > 0 else axis
    return UrdfJoint(name, jtype, links["parent"], links["child"], make_se3(rpy_to_matrix(rpy), xyz), axis)


def load_urdf(path: str | os.PathLike) -> Urdf:
    """Parse a URDF file; errors (unreadable file, malformed XML, a joint naming an unknown link,
    a link with two parents, no single root, a cycle) are one InputError naming the file."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        raise InputError(f"{path}: URDF file not found") from None
    except ET.ParseError as exc:
        raise InputError(f"{path}: malformed URDF XML: {exc}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read URDF file ({exc.__class__.__name__})") from None
    if root.tag != "robot":
        raise InputError(f"{path}: expected a <robot> root element, got <{root.tag}>")
    links: list[str] = []
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            raise InputError(f"{path}: a <link> has no name")
        if name in links:
            raise InputError(f"{path}: link {name!r} is defined twice")
        links.append(name)
    if not links:
        raise InputError(f"{path}: the URDF has no <link>")
    joints: dict[str, UrdfJoint] = {}
    names: set[str] = set()
    for el in root.findall("joint"):
        joint = _parse_joint(path, el)
        if joint.name in names:
            raise InputError(f"{path}: joint {joint.name!r} is defined twice")
        names.add(joint.name)
        for link in (joint.parent, joint.child):
            if link not in links:
                raise InputError(f"{path}: joint {joint.name!r} names an undefined link {link!r}")
        if joint.child in joints:
            raise InputError(f"{path}: link {joint.child!r} is the child of two joints")
        joints[joint.child] = joint
    roots = [link for link in links if link not in joints]
    if len(roots) != 1:
        raise InputError(f"{path}: expected exactly one root link, got {roots or 'none (a cycle)'}")
    for link in links:  # every chain must reach the root (no cycle hanging off the tree)
        seen, node = set(), link
        while node != roots[0]:
            if node in seen:
                raise InputError(f"{path}: the joints form a cycle through link {node!r}")
            seen.add(node)
            node = joints[node].parent
    return Urdf(path, root.get("name", ""), roots[0], tuple(links), joints)
