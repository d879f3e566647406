"""Motion clips, looping with root-motion extraction, and replay along any 2D path.

A ``MotionClip`` is a skeleton plus ``F`` frames at ``fps``: the root joint's world position
``root_positions_m (F, 3)`` and every joint's local rotation ``local_rotations_wxyz (F, J, 4)``
(see ``nsim.human.skeleton`` for the frame conventions). Frame ``k`` is at ``t = k / fps``; the
clip lasts ``duration_s = (F - 1) / fps``.

A *looping* clip (``loop=True``) closes on itself: its last frame has the pose of frame 0,
displaced by one cycle of root motion (the DeepMimic "wrap" convention, and what
``nsim.human.gait`` writes). ``LocomotionLoop.from_clip`` turns any clip into an endless cycle:

1. Root motion is split off: the *travel frame* moves at the clip's mean planar velocity
   (``speed_mps`` along heading ``travel_yaw``); what is left of the root position and the
   root's orientation, relative to that frame, is periodic body motion (sway, bob, hip yaw).
2. The seam is blended: the mismatch between the last frame and frame 0 (zero for a clip that
   truly loops) is spread over the last ``blend_s`` seconds, so the cycle is continuous.
3. The cycle is indexed by its *phase* in ``[0, 1)`` (one cycle; for walks a stride, two steps).
   A body at planar position ``xy``, heading ``yaw`` and phase ``phase`` is ``pose_at``; the
   phase advances by the distance walked over ``stride_m`` (so feet do not slide at any speed),
   or by time over ``period_s`` for clips that do not travel (idle).

``pose_along_path(path_xy, speed_mps)`` walks a polyline at constant speed and returns a clip.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from nsim.human.skeleton import (
    Skeleton,
    as_rotation_matrices,
    forward_kinematics,
    heading_yaw,
    quat_about_z_wxyz,
    quat_conj_wxyz,
    quat_mul_wxyz,
    quat_slerp_wxyz,
    rot_z,
)

log = logging.getLogger(__name__)

MIN_TRAVEL_SPEED_MPS = 0.05
"""Below this mean speed a clip counts as not travelling (idle): its phase advances with time."""


def _normalise_quats(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


@dataclass(frozen=True, eq=False)
class MotionClip:
    """Frames of a skeleton's motion (see the module docstring).

    skeleton: the body the rotations apply to.
    fps: frames per second (> 0).
    root_positions_m: (F, 3) world position of the root joint per frame.
    local_rotations_wxyz: (F, J, 4) unit quaternions, normalised and canonicalised (w >= 0) on construction.
    name: label used in messages (a file path for clips read from files).
    loop: whether the last frame closes a cycle (same pose as frame 0 after one cycle of root motion).
    """

    skeleton: Skeleton
    fps: float
    root_positions_m: np.ndarray
    local_rotations_wxyz: np.ndarray
    name: str = ""
    loop: bool = False

    def __post_init__(self) -> None:
        root = np.array(self.root_positions_m, dtype=np.float64)
        q = np.array(self.local_rotations_wxyz, dtype=np.float64)
        J = self.skeleton.num_joints
        if root.ndim != 2 or root.shape[1] != 3 or root.shape[0] < 1:
            raise ValueError(f"MotionClip {self.name!r}: root_positions_m: expected (F, 3), got {root.shape}")
        if q.shape != (root.shape[0], J, 4):
            raise ValueError(f"MotionClip {self.name!r}: local_rotations_wxyz: expected {(root.shape[0], J, 4)}, "
                             f"got {q.shape}")
        if not (np.all(np.isfinite(root)) and np.all(np.isfinite(q))):
            raise ValueError(f"MotionClip {self.name!r}: positions and rotations must be finite")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"MotionClip {self.name!r}: fps must be > 0, got {self.fps!r}")
        q = _normalise_quats(q)
        root.setflags(write=False)
        q.setflags(write=False)
        object.__setattr__(self, "root_positions_m", root)
        object.__setattr__(self, "local_rotations_wxyz", q)
        object.__setattr__(self, "fps", float(self.fps))

    @property
    def num_frames(self) -> int:
        return self.root_positions_m.shape[0]

    @property
    def duration_s(self) -> float:
        return (self.num_frames - 1) / self.fps

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.skeleton.joint_names

    @property
    def times_s(self) -> np.ndarray:
        """Frame times ``(F,)``."""
        return np.arange(self.num_frames) / self.fps

    def rotation_matrices(self) -> np.ndarray:
        """Local rotations as matrices ``(F, J, 3, 3)``."""
        return as_rotation_matrices(self.local_rotations_wxyz)

    def joint_transforms(self) -> np.ndarray:
        """Joint-to-world transforms ``(F, J, 4, 4)`` of every frame."""
        return forward_kinematics(self.skeleton, self.rotation_matrices(), self.root_positions_m)

    def joint_positions(self) -> np.ndarray:
        """World joint positions ``(F, J, 3)``."""
        return self.joint_transforms()[..., :3, 3]

    def sample(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated pose at ``times_s (N,)`` (clamped to ``[0, duration_s]``): linear root, slerped rotations.

        Returns ``root_positions_m (N, 3)``, ``local_rotations_wxyz (N, J, 4)``. For endless
        playback use ``LocomotionLoop``.
        """
        t = np.clip(np.asarray(times_s, dtype=np.float64).reshape(-1), 0.0, self.duration_s)
        return _interp_frames(self.root_positions_m, self.local_rotations_wxyz, t * self.fps)

    def with_name(self, name: str) -> MotionClip:
        return MotionClip(self.skeleton, self.fps, self.root_positions_m, self.local_rotations_wxyz, name, self.loop)


def _interp_frames(root: np.ndarray, quats: np.ndarray, frame_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear/slerp interpolation at fractional frame indices ``frame_pos (N,)`` in ``[0, F - 1]``."""
    F = root.shape[0]
    if F == 1:
        n = frame_pos.shape[0]
        return np.repeat(root, n, axis=0), np.repeat(quats, n, axis=0)
    i0 = np.clip(np.floor(frame_pos).astype(np.int64), 0, F - 2)
    w = np.clip(frame_pos - i0, 0.0, 1.0)
    r = root[i0] * (1.0 - w)[:, None] + root[i0 + 1] * w[:, None]
    q = quat_slerp_wxyz(quats[i0], quats[i0 + 1], np.broadcast_to(w[:, None], quats[i0].shape[:-1]))
    return r, q


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True, eq=False)
class LocomotionLoop:
    """An endless motion cycle with its root motion split off (see the module docstring).

    skeleton: the body.
    period_s: duration of one cycle.
    speed_mps: the clip's natural mean planar speed (0 for clips that do not travel).
    residual_root_m: (K, 3) root position in the travel frame (x forward, y left, z up; origin on
        the floor under the body's mean planar position) at phases ``k / (K - 1)``; row K-1 equals row 0.
    residual_rotations_wxyz: (K, J, 4) local rotations, the root's relative to the travel frame.
    name: label of the source clip.
    """

    skeleton: Skeleton
    period_s: float
    speed_mps: float
    residual_root_m: np.ndarray
    residual_rotations_wxyz: np.ndarray
    name: str = ""

    @property
    def stride_m(self) -> float:
        """Distance travelled per cycle at the natural speed (0 for idle clips)."""
        return self.speed_mps * self.period_s

    @property
    def travels(self) -> bool:
        return self.speed_mps >= MIN_TRAVEL_SPEED_MPS

    @classmethod
    def from_clip(cls, clip: MotionClip, blend_s: float = 0.25) -> LocomotionLoop:
        """Extract the root motion of ``clip`` (its frames ``0 .. F-1`` are one cycle) and blend its seam.

        The travel direction is that of the root's net planar displacement; for clips that do
        not travel (mean speed below ``MIN_TRAVEL_SPEED_MPS``) it is the root's mean heading.
        A clip that turns is straightened: its net turn is spread over the cycle like the seam.
        """
        if clip.num_frames < 3:
            raise ValueError(f"LocomotionLoop: clip {clip.name!r} needs at least 3 frames, got {clip.num_frames}")
        root = clip.root_positions_m
        q = clip.local_rotations_wxyz
        F = clip.num_frames
        T = clip.duration_s
        t = clip.times_s
        delta = root[-1, :2] - root[0, :2]
        velocity = delta / T
        speed = float(np.linalg.norm(velocity))
        if speed >= MIN_TRAVEL_SPEED_MPS:
            travel_yaw = float(np.arctan2(delta[1], delta[0]))
        else:
            yaws = heading_yaw(as_rotation_matrices(q[:, 0]))
            travel_yaw = float(np.arctan2(np.sin(yaws).mean(), np.cos(yaws).mean()))
            velocity = np.zeros(2)
            speed = 0.0
        Rz_inv = rot_z(-travel_yaw)[:2, :2]
        planar = (root[:, :2] - root[0, :2] - velocity * t[:, None]) @ Rz_inv.T
        planar -= planar[:-1].mean(axis=0)  # centre the sway on the travel line
        res_root = np.concatenate([planar, root[:, 2:3]], axis=1)
        res_q = q.copy()
        res_q[:, 0] = quat_mul_wxyz(quat_about_z_wxyz(-travel_yaw), q[:, 0])
        # blend the seam: spread the mismatch (frame 0 vs last frame) over the last blend_s seconds
        blend = min(max(float(blend_s), 1e-9), T)
        w = _smoothstep((t - (T - blend)) / blend)
        w[-1] = 1.0
        d_root = res_root[0] - res_root[-1]
        res_root = res_root + w[:, None] * d_root
        d_q = quat_mul_wxyz(res_q[0], quat_conj_wxyz(res_q[-1]))  # (J, 4): last -> first
        identity = np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0]), d_q.shape)
        corr = quat_slerp_wxyz(identity[None], d_q[None], np.broadcast_to(w[:, None], (F, q.shape[1])))
        res_q = _normalise_quats(quat_mul_wxyz(corr, res_q))
        res_q[-1] = res_q[0]
        res_root[-1] = res_root[0]
        res_root.setflags(write=False)
        res_q.setflags(write=False)
        return cls(clip.skeleton, T, speed, res_root, res_q, clip.name)

    def sample_phase(self, phase: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body motion at ``phase (N,)`` (wrapped to [0, 1)) in the travel frame.

        Returns ``root_m (N, 3)`` (travel frame) and ``local_rotations_wxyz (N, J, 4)``.
        """
        ph = np.mod(np.asarray(phase, dtype=np.float64).reshape(-1), 1.0)
        K = self.residual_root_m.shape[0]
        return _interp_frames(self.residual_root_m, self.residual_rotations_wxyz, ph * (K - 1))

    def pose_at(self, phase: np.ndarray, position_xy_m: np.ndarray,
                heading_yaw_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bodies at planar positions ``(N, 2)``, headings ``(N,)`` (rad, 0 = +x) and cycle phases ``(N,)``.

        Returns ``root_positions_m (N, 3)`` and ``local_rotations_wxyz (N, J, 4)`` in the world,
        ready for ``forward_kinematics``.
        """
        xy = np.asarray(position_xy_m, dtype=np.float64).reshape(-1, 2)
        yaw = np.broadcast_to(np.asarray(heading_yaw_rad, dtype=np.float64).reshape(-1), (xy.shape[0],))
        ph = np.broadcast_to(np.asarray(phase, dtype=np.float64).reshape(-1), (xy.shape[0],))
        res_root, q = self.sample_phase(ph)
        Rz = rot_z(yaw)
        root = np.concatenate([xy + np.einsum("nij,nj->ni", Rz[:, :2, :2], res_root[:, :2]), res_root[:, 2:3]], axis=1)
        q = q.copy()
        q[:, 0] = quat_mul_wxyz(quat_about_z_wxyz(yaw), q[:, 0])
        return root, _normalise_quats(q)

    def phase_at_distance(self, distance_m: np.ndarray, start_phase: float = 0.0) -> np.ndarray:
        """Phase after walking ``distance_m (...)`` from ``start_phase`` (no foot sliding)."""
        if not self.travels:
            raise ValueError(f"LocomotionLoop {self.name!r} does not travel: advance its phase with time")
        return np.mod(start_phase + np.asarray(distance_m, dtype=np.float64) / self.stride_m, 1.0)

    def sample(self, times_s: np.ndarray, speed_mps: float | None = None,
               start_phase: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Endless playback along +x from the origin at ``speed_mps`` (None: the natural speed).

        The phase advances by distance over ``stride_m`` (idle clips: by time over ``period_s``).
        Returns ``root_positions_m (N, 3)``, ``local_rotations_wxyz (N, J, 4)``.
        """
        t = np.asarray(times_s, dtype=np.float64).reshape(-1)
        v = self.speed_mps if speed_mps is None else float(speed_mps)
        if self.travels:
            phase = self.phase_at_distance(v * t, start_phase)
        else:
            phase = np.mod(start_phase + t / self.period_s, 1.0)
        xy = np.stack([v * t, np.zeros_like(t)], axis=1)
        return self.pose_at(phase, xy, np.zeros_like(t))

    def pose_along_path(self, path_xy_m: np.ndarray, speed_mps: float | None = None, fps: float = 30.0,
                        start_phase: float = 0.0, turn_window_m: float = 0.3) -> MotionClip:
        """Walk the polyline ``path_xy_m (P, 2)`` at constant ``speed_mps`` (None: natural) from its start to its end.

        The heading at arc length ``s`` is the direction from the path point at ``s - turn_window_m``
        to the one at ``s + turn_window_m`` (clamped to the ends), so corners are rounded
        smoothly. Returns a clip sampled at ``fps`` (last frame at the path's end).
        """
        v = self.speed_mps if speed_mps is None else float(speed_mps)
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"pose_along_path: speed_mps must be > 0, got {v!r}")
        pts = np.asarray(path_xy_m, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2 or not np.all(np.isfinite(pts)):
            raise ValueError(f"pose_along_path: expected a finite path (P >= 2, 2), got {pts.shape}")
        keep = np.r_[True, np.any(np.diff(pts, axis=0) != 0.0, axis=1)]
        pts = pts[keep]
        if pts.shape[0] < 2:
            raise ValueError("pose_along_path: the path has zero length")
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        arc = np.r_[0.0, np.cumsum(seg)]
        length = float(arc[-1])
        n = int(np.floor(length / v * fps + 1e-9)) + 1
        t = np.arange(n) / fps
        s = np.minimum(v * t, length)

        def at(s_query: np.ndarray) -> np.ndarray:
            s_query = np.clip(s_query, 0.0, length)
            return np.stack([np.interp(s_query, arc, pts[:, 0]), np.interp(s_query, arc, pts[:, 1])], axis=1)

        xy = at(s)
        ahead, behind = at(s + turn_window_m), at(s - turn_window_m)
        d = ahead - behind
        yaw = np.arctan2(d[:, 1], d[:, 0])
        yaw = np.unwrap(yaw)
        if self.travels:
            phase = self.phase_at_distance(s, start_phase)
        else:
            phase = np.mod(start_phase + t / self.period_s, 1.0)
        root, q = self.pose_at(phase, xy, yaw)
        return MotionClip(self.skeleton, fps, root, q, name=f"{self.name} along path", loop=False)

