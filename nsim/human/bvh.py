"""BVH (Biovision hierarchy) motion files: reader and writer.

A BVH file has a ``HIERARCHY`` (one ``ROOT`` joint with nested ``JOINT``s and ``End Site``s,
each with an ``OFFSET`` from its parent and a ``CHANNELS`` list) and a ``MOTION`` section
(``Frames: N``, ``Frame Time: dt`` and ``N`` lines of channel values, in hierarchy order).

How nsim reads it:

* Rotation channels are intrinsic Euler angles in degrees, in the order listed per joint
  (``Zrotation Xrotation Yrotation`` is ``R = Rz @ Rx @ Ry``); every joint may have its own order.
* The root position is its ``OFFSET`` plus its position channels. Position channels on other
  joints (an exporter habit that repeats the offset) are read but the ``OFFSET`` is used (one
  warning per file where they differ from it).
* Axes: BVH files are y-up with the body facing +z (its left is +x), as CMU's and Mixamo's
  are; ``axes="y_up"`` converts that to nsim's z-up, +x-forward world
  (``nsim = BVH_Y_UP_TO_NSIM @ bvh``). ``axes="z_up"`` reads the axes as they are.
* Units: ``unit`` is a name in ``UNITS_M`` or a number of metres per file unit. ``unit="auto"``
  measures the rest skeleton (``infer_unit_m``): first metres, centimetres or millimetres,
  the one that puts its height within ``AUTO_UNIT_RANGE_M``; otherwise, if its proportions
  are a standing body's (legs, the root above the lowest joint, ``LEG_FRACTION_RANGE`` of its
  height), the scale that gives it the nsim body's leg length, or ``inch`` or ``cmu`` (the
  CMU database's 1/0.45 inch, about 7 units per leg bone) where one is within
  ``UNIT_SNAP_FACTOR`` of that scale. Only a skeleton whose proportions are not a body's
  "cannot tell" (InputError: give the unit).

The result is a ``MotionClip`` on the file's own skeleton (joints in file order, metres, nsim
axes); ``nsim.human.retarget`` maps it onto the nsim body. Malformed files raise
``InputError("<file>:<line>: <what is wrong>")``.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.human.motion import MotionClip
from nsim.human.skeleton import Skeleton, nsim_skeleton, quats_from_matrices
from nsim.io import atomic_write_text

log = logging.getLogger(__name__)

BVH_Y_UP_TO_NSIM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""``nsim_xyz = BVH_Y_UP_TO_NSIM @ bvh_xyz``: BVH +z (forward) -> +x, +x (left) -> +y, +y (up) -> +z."""
BVH_Y_UP_TO_NSIM.setflags(write=False)

UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "cmu": 0.0254 / 0.45}
"""Metres per file unit. ``cmu``: the CMU motion capture database's ASF unit (``length 0.45``:
1/0.45 inch), which its BVH conversions (cgspeed's) keep."""
METRIC_UNITS = ("m", "cm", "mm")
"""Tried first by ``unit="auto"``, on the skeleton's height."""
OTHER_UNITS = ("inch", "cmu")
"""Tried by ``unit="auto"`` when no metric unit fits, on the skeleton's leg length."""
AUTO_UNIT_RANGE_M = (0.4, 3.0)
"""Heights (m) a metric unit must give the rest skeleton for ``unit="auto"`` to take it."""
LEG_FRACTION_RANGE = (0.3, 0.8)
"""Leg length (root above the lowest joint) over height of a standing rest skeleton, for
``unit="auto"``: nsim's body 0.55, CMU's 0.64; outside it the proportions are not a body's."""
UNIT_SNAP_FACTOR = 1.25
"""``unit="auto"`` takes a named unit within this factor of the scale the leg length gives."""
_AXES = ("y_up", "z_up")
_CHANNELS = {"xposition": "Xposition", "yposition": "Yposition", "zposition": "Zposition",
             "xrotation": "Xrotation", "yrotation": "Yrotation", "zrotation": "Zrotation"}


def _axes_matrix(axes: str) -> np.ndarray:
    if axes == "y_up":
        return BVH_Y_UP_TO_NSIM
    if axes == "z_up":
        return np.eye(3)
    raise ValueError(f"axes must be one of {', '.join(_AXES)}, got {axes!r}")


@dataclass
class _Joint:
    name: str
    parent: int
    line: int
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    channels: list[str] = field(default_factory=list)
    end_site: np.ndarray | None = None


class _Tokens:
    """Whitespace tokens with their 1-based line numbers."""

    def __init__(self, lines: list[str], first_line: int, path: str) -> None:
        self.items = [(tok, first_line + i) for i, line in enumerate(lines) for tok in line.split()]
        self.pos = 0
        self.path = path
        self.last_line = first_line + max(len(lines) - 1, 0)

    def error(self, line: int, message: str) -> InputError:
        return InputError(f"{self.path}:{line}: {message}")

    def peek(self) -> tuple[str, int] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(self.last_line, f"unexpected end of the HIERARCHY section, expected {what}")
        item = self.items[self.pos]
        self.pos += 1
        return item

    def expect(self, word: str, context: str) -> int:
        tok, line = self.next(f"'{word}' {context}")
        if tok.upper() != word.upper():
            raise self.error(line, f"expected '{word}' {context}, got {tok!r}")
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(line, f"{what}: {tok!r} is not a number") from None
        if not math.isfinite(value):
            raise self.error(line, f"{what}: {tok!r} is not finite")
        return value


def _parse_joint(tokens: _Tokens, joints: list[_Joint], parent: int, name: str, line: int) -> None:
    if any(j.name == name for j in joints):
        raise tokens.error(line, f"duplicate joint name {name!r}")
    index = len(joints)
    joint = _Joint(name, parent, line)
    joints.append(joint)
    tokens.expect("{", f"after joint {name!r}")
    tokens.expect("OFFSET", f"in joint {name!r}")
    joint.offset = np.array([tokens.number(f"OFFSET of joint {name!r}") for _ in range(3)])
    has_children = False
    while True:
        tok, tline = tokens.next(f"'}}' closing joint {name!r}")
        key = tok.upper()
        if key == "}":
            break
        if key == "CHANNELS":
            if joint.channels:
                raise tokens.error(tline, f"joint {name!r} has a second CHANNELS line")
            count_tok, cline = tokens.next("the channel count")
            try:
                count = int(count_tok)
            except ValueError:
                raise tokens.error(cline, f"CHANNELS of joint {name!r}: count {count_tok!r} is not an integer") from None
            if not 0 <= count <= 6:
                raise tokens.error(cline, f"CHANNELS of joint {name!r}: count {count} is not in 0..6")
            for k in range(count):
                ch, chline = tokens.next(f"channel name {k + 1} of {count}")
                canonical = _CHANNELS.get(ch.lower())
                if canonical is None:
                    raise tokens.error(chline, f"CHANNELS of joint {name!r} declares {count} channels but lists {k} "
                                       f"(got {ch!r}, expected one of Xposition ... Zrotation)")
                if canonical in joint.channels:
                    raise tokens.error(chline, f"CHANNELS of joint {name!r}: {canonical} appears twice")
                joint.channels.append(canonical)
        elif key == "JOINT":
            child_name, cline = tokens.next("a joint name after JOINT")
            if child_name in ("{", "}"):
                raise tokens.error(cline, f"JOINT without a name in joint {name!r}")
            has_children = True
            _parse_joint(tokens, joints, index, child_name, cline)
        elif key == "END":
            tokens.expect("Site", "after 'End'")
            tokens.expect("{", "after 'End Site'")
            tokens.expect("OFFSET", "in End Site")
            site = np.array([tokens.number(f"End Site OFFSET of joint {name!r}") for _ in range(3)])
            tokens.expect("}", "closing End Site")
            if joint.end_site is not None:
                raise tokens.error(tline, f"joint {name!r} has two End Sites")
            joint.end_site = site
        elif key == "OFFSET":
            raise tokens.error(tline, f"joint {name!r} has a second OFFSET")
        elif key == "ROOT":
            raise tokens.error(tline, f"ROOT inside joint {name!r} (missing '}}'?)")
        else:
            raise tokens.error(tline, f"unexpected {tok!r} in joint {name!r} (expected CHANNELS, JOINT, End Site or '}}')")
    if joint.end_site is not None and has_children:
        raise tokens.error(line, f"joint {name!r} has both children and an End Site")


def infer_unit_m(skeleton: Skeleton) -> tuple[float, str] | None:
    """Metres per file unit of a rest ``skeleton`` given in file units (z up), as ``unit="auto"`` finds it.

    Returns ``(metres per unit, how it was found)``, or None when the skeleton's proportions are
    not a standing body's (see the module docstring). The leg length is ``Skeleton.leg_length_m``
    (the root above the lowest joint), the one retargeting scales root motion by.
    """
    height, leg = skeleton.height_m(), skeleton.leg_length_m()
    if not height > 0:
        return None
    lo, hi = AUTO_UNIT_RANGE_M
    for name in METRIC_UNITS:  # at most one fits: the range spans less than a factor of 10
        if lo <= height * UNITS_M[name] <= hi:
            return UNITS_M[name], f"unit {name} (rest height {height:.4g} units)"
    if not LEG_FRACTION_RANGE[0] <= leg / height <= LEG_FRACTION_RANGE[1]:
        return None
    scale = nsim_skeleton().leg_length_m() / leg
    name = min(OTHER_UNITS, key=lambda u: abs(math.log(UNITS_M[u] / scale)))
    if abs(math.log(UNITS_M[name] / scale)) <= math.log(UNIT_SNAP_FACTOR):
        return UNITS_M[name], f"unit {name} (legs {leg:.4g} units)"
    return scale, f"{scale:.4g} m per unit: no named unit fits; the nsim body's leg length over this one's ({leg:.4g} units)"


def _pick_unit(skeleton: Skeleton, path: str, unit: str | float) -> tuple[float, str | None]:
    """Metres per file unit, and how ``unit="auto"`` found it (None when ``unit`` gives it): ``unit`` as given,
    or ``infer_unit_m`` of the rest ``skeleton`` (file units, z up)."""
    if not isinstance(unit, str):
        scale = float(unit)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"unit: expected a name ({', '.join(UNITS_M)}, auto) or metres per unit > 0, got {unit!r}")
        return scale, None
    if unit != "auto":
        if unit not in UNITS_M:
            raise ValueError(f"unit: expected one of {', '.join(UNITS_M)}, auto; got {unit!r}")
        return UNITS_M[unit], None
    found = infer_unit_m(skeleton)
    if found is None:
        names = ", ".join(repr(u) for u in UNITS_M)
        raise InputError(f"{path}: cannot tell the length unit: the rest skeleton is {skeleton.height_m():.4g} file units "
                         f"tall with legs of {skeleton.leg_length_m():.4g}, not a standing body's proportions; "
                         f"give it explicitly (unit={names} or metres per unit)")
    return found


@dataclass(frozen=True)
class BvhFile:
    """A BVH file read (``load_bvh``): its clip and the length unit it was read in.

    clip: on the file's own skeleton (metres, nsim axes); unit_m: metres per file unit;
    unit_found: how ``unit="auto"`` measured it from the rest skeleton (``infer_unit_m``), None when
    the caller gave the unit.
    """

    clip: MotionClip
    unit_m: float
    unit_found: str | None


def _log_unit(path: str, found: BvhFile) -> None:
    """The unit ``auto`` took: a debug line for a metric one (the skeleton's height decides), else an info line."""
    if found.unit_found is None:
        return
    if found.unit_found.startswith("unit ") and found.unit_found.split()[1] in METRIC_UNITS:
        log.debug("%s: %s", path, found.unit_found)
    else:
        log.info("%s: %s", path, found.unit_found)


def parse_bvh(text: str, path: str | os.PathLike[str] = "<bvh>", unit: str | float = "auto",
              axes: str = "y_up") -> MotionClip:
    """Parse BVH text (see the module docstring). ``path`` names the source in error messages.

    The unit ``auto`` takes is logged (``load_bvh`` returns it instead)."""
    found = _parse_bvh(text, str(path), unit, axes)
    _log_unit(str(path), found)
    return found.clip


def _parse_bvh(text: str, path: str, unit: str | float, axes: str) -> BvhFile:
    A = _axes_matrix(axes)
    lines = text.splitlines()
    motion_idx = next((i for i, ln in enumerate(lines) if ln.split()[:1] == ["MOTION"]), None)
    tokens = _Tokens(lines if motion_idx is None else lines[:motion_idx], 1, path)
    first = tokens.peek()
    if first is None:
        raise InputError(f"{path}:1: empty file, expected 'HIERARCHY'")
    tokens.expect("HIERARCHY", "at the start of the file")
    tokens.expect("ROOT", "after HIERARCHY")
    root_name, root_line = tokens.next("the root joint's name")
    joints: list[_Joint] = []
    _parse_joint(tokens, joints, -1, root_name, root_line)
    extra = tokens.peek()
    if extra is not None:
        what = "second ROOT (only one skeleton per file is supported)" if extra[0].upper() == "ROOT" else repr(extra[0])
        raise tokens.error(extra[1], f"unexpected {what} after the root joint's closing '}}'")
    if motion_idx is None:
        raise InputError(f"{path}:{len(lines)}: no MOTION section")

    # MOTION header
    def header(idx: int, label: str) -> tuple[str, int]:
        while idx < len(lines) and not lines[idx].strip():
            idx += 1
        if idx >= len(lines):
            raise InputError(f"{path}:{len(lines)}: missing '{label}' in the MOTION section")
        ln = lines[idx].strip()
        if not ln.lower().startswith(label.lower()):
            raise InputError(f"{path}:{idx + 1}: expected '{label} ...', got {ln[:40]!r}")
        return ln[len(label):].strip(), idx

    value, idx = header(motion_idx + 1, "Frames:")
    try:
        n_frames = int(value)
    except ValueError:
        raise InputError(f"{path}:{idx + 1}: Frames: {value!r} is not an integer") from None
    if n_frames < 1:
        raise InputError(f"{path}:{idx + 1}: Frames: expected at least 1 frame, got {n_frames}")
    value, idx = header(idx + 1, "Frame Time:")
    try:
        frame_time = float(value)
    except ValueError:
        raise InputError(f"{path}:{idx + 1}: Frame Time: {value!r} is not a number") from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise InputError(f"{path}:{idx + 1}: Frame Time: expected a duration > 0 s, got {value}")

    n_channels = sum(len(j.channels) for j in joints)
    frame_lines = [(i + 1, ln) for i, ln in enumerate(lines[idx + 1:], start=idx + 1) if ln.strip()]
    if len(frame_lines) != n_frames:
        where = frame_lines[-1][0] if frame_lines else idx + 1
        raise InputError(f"{path}:{where}: Frames: declares {n_frames} frames but {len(frame_lines)} frame lines follow")
    data = np.empty((n_frames, n_channels))
    for k, (lineno, ln) in enumerate(frame_lines):
        toks = ln.split()
        if len(toks) != n_channels:
            raise InputError(f"{path}:{lineno}: frame {k} has {len(toks)} values, expected {n_channels} "
                             "(the sum of the CHANNELS counts)")
        try:
            data[k] = np.array(toks, dtype=np.float64)
        except ValueError:
            bad = next(t for t in toks if not _is_float(t))
            raise InputError(f"{path}:{lineno}: frame {k}: value {bad!r} is not a number") from None
        if not np.all(np.isfinite(data[k])):
            raise InputError(f"{path}:{lineno}: frame {k}: values must be finite")

    # rest skeleton in nsim axes and file units, to pick the unit
    parents = np.array([j.parent for j in joints])
    offsets = np.array([j.offset for j in joints])
    ends = np.array([j.end_site if j.end_site is not None else np.full(3, np.nan) for j in joints])
    file_skeleton = Skeleton(tuple(j.name for j in joints), parents, offsets @ A.T, ends @ A.T)
    scale, unit_found = _pick_unit(file_skeleton, path, unit)

    # channels -> root positions and local rotations (file axes)
    F, J = n_frames, len(joints)
    R_local = np.broadcast_to(np.eye(3), (F, J, 3, 3)).copy()
    root_pos = np.broadcast_to(joints[0].offset, (F, 3)).copy()
    ignored: list[str] = []  # joints whose position channels differ from their OFFSET
    col = 0
    for j, joint in enumerate(joints):
        rot_axes, rot_cols = "", []
        for c, ch in enumerate(joint.channels):
            if ch.endswith("rotation"):
                rot_axes += ch[0]
                rot_cols.append(col + c)
            elif j == 0:
                root_pos[:, "XYZ".index(ch[0])] += data[:, col + c]
            elif (np.abs(data[:, col + c] - joint.offset["XYZ".index(ch[0])]).max()
                  > 1e-4 * max(1.0, np.abs(joint.offset).max())) and joint.name not in ignored:
                ignored.append(joint.name)
        if rot_axes:
            from scipy.spatial.transform import Rotation  # on use: the CLI starts without scipy

            R_local[:, j] = Rotation.from_euler(rot_axes, data[:, rot_cols], degrees=True).as_matrix()
        col += len(joint.channels)
    if ignored:
        shown = ", ".join(ignored[:5]) + (f" and {len(ignored) - 5} more" if len(ignored) > 5 else "")
        log.warning("%s: position channels differ from the OFFSET on %d joint(s) (%s); using the OFFSETs "
                    "(only the root's position channels move it)", path, len(ignored), shown)

    # to nsim axes and metres
    skeleton = file_skeleton.scaled(scale)
    R_nsim = A @ R_local @ A.T
    clip = MotionClip(skeleton, 1.0 / frame_time, (root_pos @ A.T) * scale, quats_from_matrices(R_nsim),
                      name=path, loop=False)
    return BvhFile(clip, scale, unit_found)


def _is_float(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def load_bvh(path: str | os.PathLike[str], unit: str | float = "auto", axes: str = "y_up") -> BvhFile:
    """Read a BVH file: its clip on the file's skeleton (metres, nsim axes) and the unit it was read in.

    Nothing is logged: a caller that let ``unit="auto"`` measure the unit says so (``BvhFile.unit_found``)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except FileNotFoundError:
        raise InputError(f"{path}: BVH file not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read BVH file ({exc.__class__.__name__})") from None
    return _parse_bvh(text, str(path), unit, axes)


def read_bvh(path: str | os.PathLike[str], unit: str | float = "auto", axes: str = "y_up") -> MotionClip:
    """Read a BVH file into a ``MotionClip`` on the file's skeleton (metres, nsim axes); the unit ``auto``
    takes is logged."""
    found = load_bvh(path, unit, axes)
    _log_unit(str(path), found)
    return found.clip


def _fmt(values, decimals: int = 6) -> str:
    """Fixed-point text of ``values``; a value that rounds to zero is written ``0.000000``, never ``-0.000000``
    (a last-bit difference between CPUs must not flip the sign in the text)."""
    return " ".join(f"{round(float(v), decimals) + 0.0:.{decimals}f}" for v in values)


def format_bvh(clip: MotionClip, unit: str = "cm", euler_order: str = "ZXY", axes: str = "y_up") -> str:
    """BVH text of ``clip``: joints in depth-first order, ``ROOT OFFSET 0 0 0`` with 6 channels
    (absolute root position), 3 rotation channels per joint in ``euler_order`` (intrinsic), an
    End Site on every leaf (zero offset where the skeleton has none). Angles have 6 decimals
    (degrees), lengths enough for 1e-8 m (6 decimals in cm, 8 in m)."""
    if unit not in UNITS_M:
        raise ValueError(f"format_bvh: unit must be one of {', '.join(UNITS_M)}, got {unit!r}")
    order = euler_order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"format_bvh: euler_order must be a permutation of XYZ, got {euler_order!r}")
    A = _axes_matrix(axes)
    inv_scale = 1.0 / UNITS_M[unit]
    dec = max(6, int(math.ceil(8 + math.log10(UNITS_M[unit]))))  # lengths to 1e-8 m
    sk = clip.skeleton
    for name in sk.joint_names:
        if not name or any(c.isspace() for c in name) or name in ("{", "}"):
            raise ValueError(f"format_bvh: joint name {name!r} cannot be written to BVH")
    offsets = (sk.offsets_m @ A) * inv_scale  # A^T @ offset, row-wise
    ends = (np.nan_to_num(sk.end_sites_m) @ A) * inv_scale
    rot_channels = " ".join(f"{a}rotation" for a in order)

    order_dfs: list[int] = []
    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        order_dfs.append(j)
        pad = "\t" * depth
        kind = "ROOT" if j == 0 else "JOINT"
        out.append(f"{pad}{kind} {sk.joint_names[j]}")
        out.append(f"{pad}{{")
        off = np.zeros(3) if j == 0 else offsets[j]
        out.append(f"{pad}\tOFFSET {_fmt(off, dec)}")
        if j == 0:
            out.append(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition {rot_channels}")
        else:
            out.append(f"{pad}\tCHANNELS 3 {rot_channels}")
        kids = sk.children(j)
        for c in kids:
            emit(c, depth + 1)
        if not kids:
            out.append(f"{pad}\tEnd Site")
            out.append(f"{pad}\t{{")
            out.append(f"{pad}\t\tOFFSET {_fmt(ends[j], dec)}")
            out.append(f"{pad}\t}}")
        out.append(f"{pad}}}")

    emit(0, 0)
    F = clip.num_frames
    R = clip.rotation_matrices()[:, order_dfs]  # (F, J, 3, 3), nsim axes
    R_file = A.T @ R @ A
    from scipy.spatial.transform import Rotation

    euler = Rotation.from_matrix(R_file.reshape(-1, 3, 3)).as_euler(order, degrees=True).reshape(F, -1)
    root = (clip.root_positions_m @ A) * inv_scale
    out += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / clip.fps:.9f}"]
    out += [_fmt(root[k], dec) + " " + _fmt(euler[k]) for k in range(F)]
    return "\n".join(out) + "\n"


def write_bvh(path: str | os.PathLike[str], clip: MotionClip, unit: str = "cm", euler_order: str = "ZXY",
              axes: str = "y_up") -> Path:
    """Write ``clip`` as BVH (``format_bvh``) to ``path``, atomically. Returns the path."""
    return atomic_write_text(path, format_bvh(clip, unit=unit, euler_order=euler_order, axes=axes))
