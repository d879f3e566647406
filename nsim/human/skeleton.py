"""The nsim body: a 24-joint humanoid kinematic tree, forward kinematics and pose bounding boxes.

Conventions (``nsim.geometry.conventions``): metres, world z up, quaternions wxyz. The body
faces **+x** (heading yaw 0), its left is +y. Every joint has a frame; in the rest pose every
joint frame is aligned with the world axes, so a local rotation of identity everywhere gives
the rest pose (a T-pose: arms horizontal, legs straight, feet flat on the floor ``z = 0``).

A ``Skeleton`` holds, for ``J`` joints in an order where every parent comes before its
children (``parents[j] < j``):

* ``offsets_m (J, 3)``: the rest offset of joint ``j`` from its parent, in the parent's frame;
  ``offsets_m[0]`` is the root's rest position in the world.
* ``end_sites_m (J, 3)``: the tip of the bone that ends at a leaf joint (top of the head,
  toe tip, finger tip), in that joint's frame; NaN where a joint has none (like a BVH End Site).

Forward kinematics takes local rotations ``(..., J, 3, 3)`` (or wxyz quaternions
``(..., J, 4)``) and the root's world position ``(..., 3)``; the root's local rotation is its
world orientation. It returns joint-to-world transforms ``(..., J, 4, 4)``: column 3 is the
joint position, the 3x3 block the joint frame's orientation.

``nsim_skeleton(height_m)`` is the nsim body: SMPL's joint names and tree (no SMPL data) with
rest offsets of an adult of 1.75 m scaled to ``height_m`` (floor to the top of the head).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nsim.geometry.transforms import matrix_from_quat_wxyz, quat_wxyz_from_matrix

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)
"""SMPL's 24 joint names; ``left_foot`` is the ball of the foot (toe joint), ``left_hand`` the knuckles."""

PARENTS: tuple[int, ...] = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)

REFERENCE_HEIGHT_M = 1.75
"""Height (floor to top of head) of the rest offsets below; ``nsim_skeleton`` scales them."""

# Rest offsets (x forward, y left, z up) of a 1.75 m adult, each from its parent.
_REST_OFFSETS_M = {
    "pelvis": (0.0, 0.0, 0.98),
    "left_hip": (0.0, 0.09, -0.07),
    "right_hip": (0.0, -0.09, -0.07),
    "spine1": (0.0, 0.0, 0.11),
    "left_knee": (0.0, 0.0, -0.41),
    "right_knee": (0.0, 0.0, -0.41),
    "spine2": (0.0, 0.0, 0.12),
    "left_ankle": (0.0, 0.0, -0.42),
    "right_ankle": (0.0, 0.0, -0.42),
    "spine3": (0.0, 0.0, 0.12),
    "left_foot": (0.13, 0.0, -0.05),
    "right_foot": (0.13, 0.0, -0.05),
    "neck": (-0.01, 0.0, 0.19),
    "left_collar": (-0.01, 0.07, 0.12),
    "right_collar": (-0.01, -0.07, 0.12),
    "head": (0.01, 0.0, 0.08),
    "left_shoulder": (0.0, 0.11, -0.01),
    "right_shoulder": (0.0, -0.11, -0.01),
    "left_elbow": (0.0, 0.26, 0.0),
    "right_elbow": (0.0, -0.26, 0.0),
    "left_wrist": (0.0, 0.25, 0.0),
    "right_wrist": (0.0, -0.25, 0.0),
    "left_hand": (0.0, 0.08, 0.0),
    "right_hand": (0.0, -0.08, 0.0),
}
# End sites of the leaves: top of the head, toe tips, finger tips.
_END_SITES_M = {
    "head": (0.0, 0.0, 0.15),
    "left_foot": (0.05, 0.0, 0.0),
    "right_foot": (0.05, 0.0, 0.0),
    "left_hand": (0.0, 0.09, 0.0),
    "right_hand": (0.0, -0.09, 0.0),
}
SOLE_HEIGHT_M = 0.03
"""Height of the ball-of-foot and toe joints above the floor in the rest pose (at 1.75 m): the sole's thickness."""

BODY_RADIUS_FRACTION = 0.1
"""Default box padding as a fraction of body height: covers the flesh around the bones (0.175 m at 1.75 m)."""


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree (see the module docstring for the conventions).

    joint_names: (J,) unique names.
    parents: (J,) int64, ``-1`` for joint 0 (the root) only, ``parents[j] < j`` otherwise.
    offsets_m: (J, 3) float64 rest offsets from the parent, in the parent's frame.
    end_sites_m: (J, 3) float64 end-site offsets in the joint's frame, NaN rows where none.
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray
    offsets_m: np.ndarray
    end_sites_m: np.ndarray

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.joint_names)
        parents = np.array(self.parents, dtype=np.int64).reshape(-1)
        offsets = np.array(self.offsets_m, dtype=np.float64)
        ends = np.array(self.end_sites_m, dtype=np.float64)
        J = len(names)
        if J == 0 or len(set(names)) != J:
            raise ValueError(f"Skeleton: expected unique, non-empty joint names, got {names!r}")
        if parents.shape != (J,) or offsets.shape != (J, 3) or ends.shape != (J, 3):
            raise ValueError(f"Skeleton: expected parents (J,), offsets_m (J, 3), end_sites_m (J, 3) for J={J}, "
                             f"got {parents.shape}, {offsets.shape}, {ends.shape}")
        if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, J)):
            raise ValueError("Skeleton: parents must be -1 for joint 0 and satisfy 0 <= parents[j] < j")
        if not np.all(np.isfinite(offsets)):
            raise ValueError("Skeleton: offsets_m must be finite")
        for name, value in (("joint_names", names), ("parents", parents), ("offsets_m", offsets),
                            ("end_sites_m", ends)):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def index(self, name: str) -> int:
        """Index of joint ``name``; KeyError naming the valid joints otherwise."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"no joint {name!r}; joints: {', '.join(self.joint_names)}") from None

    def children(self, j: int) -> list[int]:
        """Indices of the children of joint ``j``, ascending (the first is the *primary* child)."""
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    def rest_transforms(self) -> np.ndarray:
        """Joint-to-world transforms ``(J, 4, 4)`` of the rest pose."""
        return forward_kinematics(self, np.broadcast_to(np.eye(3), (self.num_joints, 3, 3)), self.offsets_m[0])

    def rest_positions_m(self) -> np.ndarray:
        """Rest joint positions ``(J, 3)`` in the world."""
        return self.rest_transforms()[:, :3, 3]

    def height_m(self, up_axis: int = 2) -> float:
        """Extent of the rest pose (joints and end sites) along ``up_axis``.

        For nsim bodies that is the height minus the soles' thickness (1.72 m for a 1.75 m body).
        """
        T = self.rest_transforms()
        pts = np.concatenate([T[:, :3, 3], end_site_positions(self, T)])
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        return float(pts[:, up_axis].max() - pts[:, up_axis].min())

    def leg_length_m(self) -> float:
        """Rest height of the root above the lowest joint (the scale used to retarget root motion)."""
        p = self.rest_positions_m()
        return float(p[0, 2] - p[:, 2].min())

    def scaled(self, factor: float) -> Skeleton:
        """The same tree with every offset multiplied by ``factor``."""
        return Skeleton(self.joint_names, self.parents, self.offsets_m * factor, self.end_sites_m * factor)


def nsim_skeleton(height_m: float = REFERENCE_HEIGHT_M) -> Skeleton:
    """The nsim body (``JOINT_NAMES``, ``PARENTS``) for a person ``height_m`` tall (0.5 to 2.5 m).

    The rest pose is a T-pose standing on ``z = 0`` with the pelvis at ``(0, 0, 0.98 * height_m / 1.75)``.
    """
    if not (np.isfinite(height_m) and 0.5 <= height_m <= 2.5):
        raise ValueError(f"nsim_skeleton: height_m must be in [0.5, 2.5], got {height_m!r}")
    s = float(height_m) / REFERENCE_HEIGHT_M
    offsets = np.array([_REST_OFFSETS_M[n] for n in JOINT_NAMES]) * s
    ends = np.full((len(JOINT_NAMES), 3), np.nan)
    for name, off in _END_SITES_M.items():
        ends[JOINT_NAMES.index(name)] = np.asarray(off) * s
    return Skeleton(JOINT_NAMES, np.array(PARENTS), offsets, ends)


# ----------------------------------------------------------------------------------------------
# Rotations


def as_rotation_matrices(rotations: np.ndarray) -> np.ndarray:
    """Rotations given as ``(..., 3, 3)`` matrices or ``(..., 4)`` wxyz quaternions -> ``(..., 3, 3)``."""
    r = np.asarray(rotations, dtype=np.float64)
    if r.ndim >= 2 and r.shape[-2:] == (3, 3):
        return r
    if r.ndim >= 1 and r.shape[-1] == 4:
        return matrix_from_quat_wxyz(r)
    raise ValueError(f"rotations: expected (..., 3, 3) matrices or (..., 4) wxyz quaternions, got {r.shape}")


def quat_mul_wxyz(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of wxyz quaternions ``(..., 4)`` (broadcast): rotation ``a`` after ``b``."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_conj_wxyz(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion) ``(..., 4)``."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_slerp_wxyz(q0: np.ndarray, q1: np.ndarray, w: np.ndarray | float) -> np.ndarray:
    """Spherical interpolation from ``q0`` (w = 0) to ``q1`` (w = 1) along the shorter arc.

    q0, q1: (..., 4) unit wxyz; w: (...) or scalar (broadcast). Returns (..., 4) unit, ``w >= 0``.
    """
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-6
    safe = np.where(small, 1.0, sin_theta)
    c0 = np.where(small, 1.0 - w, np.sin((1.0 - w) * theta) / safe)
    c1 = np.where(small, w, np.sin(w * theta) / safe)
    q = c0 * q0 + c1 * q1
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_about_z_wxyz(yaw_rad: np.ndarray | float) -> np.ndarray:
    """Rotations about +z by ``yaw_rad (...)``: ``(..., 4)`` wxyz."""
    half = 0.5 * np.asarray(yaw_rad, dtype=np.float64)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], axis=-1)


def rot_z(yaw_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` about +z by ``yaw_rad (...)``."""
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(yaw.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def heading_yaw(root_rotation: np.ndarray) -> np.ndarray:
    """Heading (rad, about +z, 0 = facing +x) of root orientations ``(..., 3, 3)``: the yaw of the
    body's forward axis (joint-frame +x) projected on the floor. Returns ``(...)``."""
    R = np.asarray(root_rotation, dtype=np.float64)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


# ----------------------------------------------------------------------------------------------
# Forward kinematics and boxes


def forward_kinematics(skeleton: Skeleton, local_rotations: np.ndarray, root_position_m: np.ndarray,
                       root_to_world: np.ndarray | None = None) -> np.ndarray:
    """Joint-to-world transforms of posed skeletons.

    local_rotations: (..., J, 3, 3) rotation matrices or (..., J, 4) wxyz quaternions, each joint's
        rotation relative to its parent's frame (the root's: its orientation in the world).
    root_position_m: (..., 3) position of the root joint (batch dimensions broadcast).
    root_to_world: optional (..., 4, 4) rigid transform applied on top (e.g. to place a clip
        that was posed in its own frame); None is the identity.
    Returns (..., J, 4, 4) float64. Vectorised over the batch; one matrix product per joint.
    """
    R = as_rotation_matrices(local_rotations)
    J = skeleton.num_joints
    if R.ndim < 3 or R.shape[-3] != J:
        raise ValueError(f"forward_kinematics: expected local rotations for {J} joints, got shape {R.shape}")
    root = np.asarray(root_position_m, dtype=np.float64)
    if root.shape[-1:] != (3,):
        raise ValueError(f"forward_kinematics: root_position_m: expected (..., 3), got {root.shape}")
    batch = np.broadcast_shapes(R.shape[:-3], root.shape[:-1])
    R = np.broadcast_to(R, batch + (J, 3, 3))
    T = np.zeros(batch + (J, 4, 4))
    T[..., 3, 3] = 1.0
    T[..., 0, :3, :3] = R[..., 0, :, :]
    T[..., 0, :3, 3] = root
    offsets = skeleton.offsets_m
    for j in range(1, J):
        p = skeleton.parents[j]
        Rp = T[..., p, :3, :3]
        T[..., j, :3, :3] = Rp @ R[..., j, :, :]
        T[..., j, :3, 3] = T[..., p, :3, 3] + Rp @ offsets[j]
    if root_to_world is not None:
        W = np.asarray(root_to_world, dtype=np.float64)
        if W.shape[-2:] != (4, 4):
            raise ValueError(f"forward_kinematics: root_to_world: expected (..., 4, 4), got {W.shape}")
        T = W[..., None, :, :] @ T
    return T


def joint_positions(skeleton: Skeleton, local_rotations: np.ndarray, root_position_m: np.ndarray) -> np.ndarray:
    """World joint positions ``(..., J, 3)``: the translation part of ``forward_kinematics``."""
    return forward_kinematics(skeleton, local_rotations, root_position_m)[..., :3, 3]


def end_site_positions(skeleton: Skeleton, joint_transforms: np.ndarray) -> np.ndarray:
    """World end-site positions ``(..., J, 3)`` from ``joint_transforms (..., J, 4, 4)``; NaN rows where none."""
    T = np.asarray(joint_transforms, dtype=np.float64)
    ends = np.nan_to_num(skeleton.end_sites_m)
    pts = T[..., :3, 3] + np.einsum("...ij,...j->...i", T[..., :3, :3], ends)
    return np.where(np.isnan(skeleton.end_sites_m[:, :1]), np.nan, pts)


def _pose_points(skeleton: Skeleton, joint_transforms: np.ndarray) -> np.ndarray:
    """Joints and end sites ``(..., J + E, 3)`` (E: joints that have an end site)."""
    T = np.asarray(joint_transforms, dtype=np.float64)
    if T.ndim < 3 or T.shape[-3:] != (skeleton.num_joints, 4, 4):
        raise ValueError(f"joint_transforms: expected (..., {skeleton.num_joints}, 4, 4), got {T.shape}")
    has_end = ~np.isnan(skeleton.end_sites_m[:, 0])
    ends = end_site_positions(skeleton, T)[..., has_end, :]
    return np.concatenate([T[..., :3, 3], ends], axis=-2)


def default_padding_m(skeleton: Skeleton) -> float:
    """Box padding that covers the body's flesh: ``BODY_RADIUS_FRACTION`` of the body height."""
    return BODY_RADIUS_FRACTION * skeleton.height_m()


def pose_aabb(skeleton: Skeleton, joint_transforms: np.ndarray,
              padding_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World axis-aligned box of posed bodies: joints and end sites, grown by ``padding_m``.

    joint_transforms: (..., J, 4, 4) from ``forward_kinematics``. padding_m: None uses
    ``default_padding_m(skeleton)``. Returns ``lo, hi``: (..., 3) each.
    """
    pad = default_padding_m(skeleton) if padding_m is None else float(padding_m)
    pts = _pose_points(skeleton, joint_transforms)
    return pts.min(axis=-2) - pad, pts.max(axis=-2) + pad


def pose_obb(skeleton: Skeleton, joint_transforms: np.ndarray,
             padding_m: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Oriented box of posed bodies in their *heading frame*.

    The heading frame has its origin at the root joint, +z up (world), +x along the root's
    heading (``heading_yaw``). The box is axis-aligned in that frame: the tightest box around
    the joints and end sites, grown by ``padding_m`` (None: ``default_padding_m``).
    Returns ``box_to_world (..., 4, 4)``, ``lo (..., 3)``, ``hi (..., 3)`` (box-frame corners).
    """
    pad = default_padding_m(skeleton) if padding_m is None else float(padding_m)
    T = np.asarray(joint_transforms, dtype=np.float64)
    pts = _pose_points(skeleton, T)
    yaw = heading_yaw(T[..., 0, :3, :3])
    Rz = rot_z(yaw)
    origin = T[..., 0, :3, 3]
    local = np.einsum("...ji,...nj->...ni", Rz, pts - origin[..., None, :])  # Rz^T (p - o)
    box_to_world = np.zeros(yaw.shape + (4, 4))
    box_to_world[..., :3, :3] = Rz
    box_to_world[..., :3, 3] = origin
    box_to_world[..., 3, 3] = 1.0
    return box_to_world, local.min(axis=-2) - pad, local.max(axis=-2) + pad


def local_rotations_from_global(skeleton: Skeleton, global_rotations: np.ndarray) -> np.ndarray:
    """Local rotations ``(..., J, 3, 3)`` from joint-to-world orientations ``(..., J, 3, 3)``: ``G_parent^T G_j``."""
    G = np.asarray(global_rotations, dtype=np.float64)
    L = np.empty_like(G)
    L[..., 0, :, :] = G[..., 0, :, :]
    p = skeleton.parents[1:]
    L[..., 1:, :, :] = np.swapaxes(G[..., p, :, :], -1, -2) @ G[..., 1:, :, :]
    return L


def quats_from_matrices(R: np.ndarray) -> np.ndarray:
    """wxyz quaternions ``(..., 4)`` (``w >= 0``) of rotation matrices ``(..., 3, 3)``."""
    return quat_wxyz_from_matrix(R)
