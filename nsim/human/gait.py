"""Procedural gait: walking at any speed, standing idle and turning, as ``MotionClip``s of the nsim body.

Speed relations (one place, shared with the crowd simulator): the stride (two steps) at speed
``v`` is ``nsim.human.gait_phase.stride_length_m(v, height)`` (``2 * 0.63 m * sqrt(v / 1 m/s)`` at
1.75 m, scaled by height), so the cadence is ``v / stride`` strides per second: 85, 109 and
128 steps/min at 0.8, 1.3 and 1.8 m/s for a 1.75 m adult, within the measured ranges (Grieve
& Gear 1966). A generated walk therefore has exactly the stride length the crowd simulator
uses for its gait phase, and a phase from ``nsim.human.gait_phase.gait_phase`` plays it without foot
sliding. The stance phase lasts ``duty_factor(v)`` of the cycle (about 62 % at 1.3 m/s).

The walk is built from its feet, so planted feet never slide:

* Phase 0 is the left heel strike, 0.5 the right one. Each stance has a heel rocker (the foot
  rotates down about the heel), a flat phase (ankle fixed) and a toe rocker (the heel rises,
  the foot rotating about the ball, whose joint stays fixed and whose toes stay flat). In swing
  the ankle follows a minimum-jerk path to the next heel strike, lifted by a sine bump that
  peaks a third into the swing.
* The pelvis moves at constant speed with a sway over the stance foot, a forward lean and hip
  rotation/list. Its height is a smooth envelope of what the legs need to reach the feet (at
  most ``MAX_LEG_EXTENSION`` of their length): the vertical bob this gives is lowest in double
  support and highest in mid-stance, as in the inverted-pendulum walk.
* Legs are solved by analytic two-bone IK with the knee in the plane of the leg and the
  pelvis' forward axis; arms swing opposite to the legs; the thorax counter-rotates; the head
  keeps looking along the walking direction.

Clips are cycles with the closing frame included (``MotionClip.loop``): ``N + 1`` frames
spanning exactly one period, at about ``fps``. ``write_default_clips`` writes the shipped
``nsim/configs/motions/*.bvh`` (regenerate with ``python -m nsim.human.gait nsim/configs/motions``).
"""

from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import numpy as np

from nsim.human import skeleton
from nsim.human.gait_phase import stride_length_m
from nsim.human.motion import LocomotionLoop, MotionClip

log = logging.getLogger(__name__)

MAX_LEG_EXTENSION = 0.985
"""Largest hip-to-ankle distance as a fraction of thigh + shin: legs never lock straight."""

DEFAULT_CLIPS: dict[str, float | None] = {"walk_slow": 0.8, "walk": 1.3, "walk_fast": 1.8, "idle": None}
"""Shipped clips (``nsim/configs/motions/NAME.bvh``): walking speed in m/s, None for standing idle."""

DEFAULT_FPS = 30.0

IDLE_PERIOD_S = 4.0
"""One cycle of the standing idle (``idle_cycle``), whatever the body's height: the crowd advances an
idle person's gait phase by time over this (``nsim.human.person_motion``)."""


def duty_factor(speed_mps: float) -> float:
    """Fraction of the gait cycle a foot is on the ground: ``0.66 - 0.035 v``, clipped to [0.55, 0.65]."""
    return float(np.clip(0.66 - 0.035 * speed_mps, 0.55, 0.65))


def cadence_steps_per_min(speed_mps: float, height_m: float = skeleton.REFERENCE_HEIGHT_M) -> float:
    """Steps per minute at ``speed_mps``: ``120 * v / stride_length_m(v, height)``."""
    return float(120.0 * speed_mps / stride_length_m(speed_mps, height_m))


def _rx(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = 1.0, c, -s, s, c
    return R


def _ry(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 2], R[..., 1, 1], R[..., 2, 0], R[..., 2, 2] = c, s, 1.0, -s, c
    return R


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _minimum_jerk(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _bone_frame(bone_dir: np.ndarray, hinge_axis: np.ndarray) -> np.ndarray:
    """Rotation ``(..., 3, 3)`` with columns (x, y = hinge, z = -bone): the frame of a downward bone."""
    z = -_unit(bone_dir)
    y = hinge_axis - np.sum(hinge_axis * z, axis=-1, keepdims=True) * z
    y = _unit(y)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


class _Foot:
    """Planted-foot geometry of one side in the walking frame (x forward, y left, z up)."""

    def __init__(self, sk: skeleton.Skeleton, side: str, toe_out_rad: float) -> None:
        rest = sk.rest_positions_m()
        self.ankle_rest = rest[sk.index(f"{side}_ankle")]
        ball = rest[sk.index(f"{side}_foot")]
        s = sk.height_m() / 1.72
        self.ball_rel0 = ball - self.ankle_rest  # (3,)
        self.heel_rel0 = np.array([-0.06 * s, 0.0, ball[2] - self.ankle_rest[2]])  # heel on the sole
        self.yaw = skeleton.rot_z(toe_out_rad)

    def rel(self, rel0: np.ndarray, pitch: np.ndarray) -> np.ndarray:
        return np.einsum("ij,njk,k->ni", self.yaw, _ry(pitch), rel0)

    def rotation(self, pitch: np.ndarray) -> np.ndarray:
        return self.yaw @ _ry(pitch)


def _foot_track(foot: _Foot, phase: np.ndarray, stride: float, duty: float, flat_x: float,
                pitch_hs: float, pitch_to: float, lift: float) -> tuple[np.ndarray, np.ndarray]:
    """World ankle positions ``(N, 3)`` and foot pitch ``(N,)`` of one foot at cycle ``phase (N,)``
    (which may exceed 1: cycles count strides). Heel strike at integer phases; ``flat_x`` is the
    flat-phase ankle x of cycle 0."""
    u_heel, u_toe = 0.12, 0.55  # end of the heel rocker, start of the toe rocker (fractions of stance)
    k = np.floor(phase)
    f = phase - k
    A = np.stack([flat_x + k * stride, np.full_like(k, foot.ankle_rest[1]), np.full_like(k, foot.ankle_rest[2])], -1)
    heel_pt = A + foot.heel_rel0 @ foot.yaw.T
    ball_pt = A + foot.ball_rel0 @ foot.yaw.T
    stance = f < duty
    u = np.where(stance, f / duty, (f - duty) / (1.0 - duty))
    # stance
    pitch_st = np.where(u < u_heel, -pitch_hs * (1.0 - _smoothstep(u / u_heel)),
                        np.where(u < u_toe, 0.0, pitch_to * _smoothstep((u - u_toe) / (1.0 - u_toe))))
    ankle_heel = heel_pt - foot.rel(foot.heel_rel0, pitch_st)
    ankle_toe = ball_pt - foot.rel(foot.ball_rel0, pitch_st)
    ankle_st = np.where((u < u_heel)[:, None], ankle_heel, np.where((u < u_toe)[:, None], A, ankle_toe))
    # swing: from toe-off of this cycle to heel strike of the next
    p0 = ball_pt - foot.rel(foot.ball_rel0, np.full_like(u, pitch_to))
    heel_next = heel_pt + np.array([stride, 0.0, 0.0])
    p1 = heel_next - foot.rel(foot.heel_rel0, np.full_like(u, -pitch_hs))
    m = _minimum_jerk(1.0 - (1.0 - u) ** 1.4)  # the foot leaves quickly, then settles
    ankle_sw = p0 + (p1 - p0) * m[:, None]
    ankle_sw[:, 2] += lift * np.sin(np.pi * u**0.6) ** 2  # highest a third into the swing
    pitch_sw = pitch_to + (-pitch_hs - pitch_to) * m
    return np.where(stance[:, None], ankle_st, ankle_sw), np.where(stance, pitch_st, pitch_sw)


def _leg_ik(hip: np.ndarray, ankle: np.ndarray, forward: np.ndarray, l1: float, l2: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Thigh and shin world rotations ``(N, 3, 3)`` placing the ankle at ``ankle`` (two-bone IK)."""
    d = ankle - hip
    D = np.linalg.norm(d, axis=-1)
    dn = d / D[:, None]
    D = np.clip(D, abs(l1 - l2) + 1e-6, (l1 + l2) * (1.0 - 1e-9))
    a = _unit(np.cross(forward, dn))  # knee hinge: positive rotation flexes (shin goes back)
    cos_alpha = np.clip((l1 * l1 + D * D - l2 * l2) / (2.0 * l1 * D), -1.0, 1.0)
    alpha = np.arccos(cos_alpha)
    # thigh direction: dn rotated about a by -alpha (knee forward); Rodrigues with a _|_ dn
    thigh = dn * np.cos(alpha)[:, None] - np.cross(a, dn) * np.sin(alpha)[:, None]
    knee = hip + l1 * thigh
    shin = _unit(hip + D[:, None] * dn - knee)
    return _bone_frame(thigh, a), _bone_frame(shin, a)


def _pelvis_drop(pelvis: np.ndarray, R_pelvis: np.ndarray, legs: list[tuple[np.ndarray, np.ndarray]],
                 reach: float, s: float) -> np.ndarray:
    """How far to lower the pelvis per frame ``(F,)`` (the last frame closes the cycle) so that every
    ankle is within ``reach`` of its hip: a smooth periodic envelope (Gaussian, sigma 3.5 % of
    the cycle) of what each frame needs, at least ``0.005 * s`` (knees never locked), plus
    the largest shortfall of the smoothed curve."""
    need = np.full(pelvis.shape[0], 0.005 * s)
    for hip_offset, ankle in legs:
        hip = pelvis + np.einsum("nij,j->ni", R_pelvis, hip_offset)
        d = ankle - hip
        horiz2 = d[:, 0] ** 2 + d[:, 1] ** 2
        need = np.maximum(need, -d[:, 2] - np.sqrt(np.maximum(reach**2 - horiz2, 0.0)))
    cyc = need[:-1]
    n = cyc.shape[0]
    k = np.arange(n)
    dist = np.minimum(k, n - k) / n
    kernel = np.exp(-0.5 * (dist / 0.035) ** 2)
    kernel /= kernel.sum()
    smooth = np.real(np.fft.ifft(np.fft.fft(cyc) * np.fft.fft(kernel)))
    smooth += max(0.0, float((cyc - smooth).max()))
    return np.r_[smooth, smooth[:1]]


def walk_cycle(speed_mps: float = 1.3, height_m: float = skeleton.REFERENCE_HEIGHT_M, fps: float = DEFAULT_FPS) -> MotionClip:
    """One walking cycle (stride) of ``nsim_skeleton(height_m)`` at ``speed_mps`` (0.3 to 2.5 m/s).

    Walks along +x from the origin; ``N + 1`` frames with ``N = round(period * fps)`` (the clip's
    fps is ``N / period``, close to ``fps``); the last frame closes the loop.
    """
    if not (math.isfinite(speed_mps) and 0.3 <= speed_mps <= 2.5):
        raise ValueError(f"walk_cycle: speed_mps must be in [0.3, 2.5], got {speed_mps!r}")
    sk = skeleton.nsim_skeleton(height_m)
    s = height_m / skeleton.REFERENCE_HEIGHT_M
    v = float(speed_mps)
    stride = float(stride_length_m(v, height_m))
    period = stride / v
    n = max(8, int(round(period * fps)))
    phase = np.arange(n + 1) / n  # (F,)
    F = phase.shape[0]
    duty = duty_factor(v)
    deg = np.radians

    # pelvis
    mid = 0.5 * (0.12 + 0.55) * duty  # mid flat-foot phase of the left foot
    yaw = -deg(3.0 + 2.0 * v) * np.cos(2 * np.pi * phase)  # left hip forward at left heel strike
    roll = deg(2.5 + 1.0 * v) * np.cos(2 * np.pi * (phase - mid))  # swing side drops
    lean = deg(2.0 + 2.0 * v)
    R_pelvis = skeleton.rot_z(yaw) @ _ry(np.full(F, lean)) @ _rx(roll)
    sway = 0.025 * s * np.cos(2 * np.pi * (phase - mid)) / (0.5 + 0.5 * v)
    pelvis = np.stack([v * period * phase, sway, np.full(F, sk.offsets_m[0, 2])], axis=-1)

    # feet
    toe_out = deg(5.0)
    feet = {"left": _Foot(sk, "left", toe_out), "right": _Foot(sk, "right", -toe_out)}
    pitch_hs, pitch_to = deg(12.0 + 6.0 * v), deg(35.0 + 15.0 * v)
    lift = 0.05 * s * (0.8 + 0.2 * v)
    tracks = {}
    for side, offset in (("left", 0.0), ("right", 0.5)):
        flat_x = stride * (offset + mid)
        tracks[side] = _foot_track(feet[side], phase - offset, stride, duty, flat_x, pitch_hs, pitch_to, lift)

    # pelvis height: lowered where the legs need it (double support), as a smooth envelope
    idx = {n_: sk.index(n_) for n_ in sk.joint_names}
    l1 = float(np.linalg.norm(sk.offsets_m[idx["left_knee"]]))
    l2 = float(np.linalg.norm(sk.offsets_m[idx["left_ankle"]]))
    drop = _pelvis_drop(pelvis, R_pelvis, [(sk.offsets_m[idx[f"{side}_hip"]], tracks[side][0])
                                           for side in ("left", "right")], MAX_LEG_EXTENSION * (l1 + l2), s)
    pelvis[:, 2] -= drop
    log.debug("walk %.2f m/s: pelvis lowered by %.3f to %.3f m", v, drop.min(), drop.max())

    # global rotations of every joint
    G = np.broadcast_to(np.eye(3), (F, sk.num_joints, 3, 3)).copy()
    G[:, 0] = R_pelvis
    spine_yaw = skeleton.rot_z(-0.45 * yaw) @ _rx(-roll / 3.0)
    G[:, idx["spine1"]] = R_pelvis @ spine_yaw
    G[:, idx["spine2"]] = G[:, idx["spine1"]] @ spine_yaw
    G[:, idx["spine3"]] = G[:, idx["spine2"]] @ spine_yaw @ _ry(np.full(F, -0.5 * lean))
    thorax = G[:, idx["spine3"]]
    G[:, idx["left_collar"]] = thorax
    G[:, idx["right_collar"]] = thorax
    head = _ry(np.full(F, deg(4.0)))  # looks along the path, slightly down
    G[:, idx["neck"]] = head
    G[:, idx["head"]] = head
    forward = R_pelvis[:, :, 0]
    pre = skeleton.forward_kinematics(sk, skeleton.local_rotations_from_global(sk, G), pelvis)
    for side in ("left", "right"):
        hip = pre[:, idx[f"{side}_hip"], :3, 3]
        ankle, pitch = tracks[side]
        thigh, shin = _leg_ik(hip, ankle, forward, l1, l2)
        G[:, idx[f"{side}_hip"]] = thigh
        G[:, idx[f"{side}_knee"]] = shin
        foot_rot = feet[side].rotation(pitch)
        G[:, idx[f"{side}_ankle"]] = foot_rot
        G[:, idx[f"{side}_foot"]] = np.where((pitch > 0)[:, None, None], feet[side].rotation(np.zeros(F)), foot_rot)
    # arms: hang down, swing opposite to the legs, elbows bent a little more when swung forward
    swing_amp = deg(6.0 + 12.0 * v)
    abduct = deg(82.0)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        swing = -sign * swing_amp * np.cos(2 * np.pi * phase)  # left arm forward at right heel strike
        upper = skeleton.rot_z(-0.35 * yaw) @ _ry(-swing) @ _rx(-sign * np.full(F, abduct))
        G[:, idx[f"{side}_shoulder"]] = upper
        elbow = deg(12.0 + 8.0 * v) + 0.5 * np.maximum(swing, 0.0)
        G[:, idx[f"{side}_elbow"]] = upper @ skeleton.rot_z(-sign * elbow)
        G[:, idx[f"{side}_wrist"]] = G[:, idx[f"{side}_elbow"]]
        G[:, idx[f"{side}_hand"]] = G[:, idx[f"{side}_elbow"]] @ skeleton.rot_z(-sign * np.full(F, deg(10.0)))
    L = skeleton.local_rotations_from_global(sk, G)
    return MotionClip(sk, n / period, pelvis, skeleton.quats_from_matrices(L), name=f"walk {v:g} m/s", loop=True)


def idle_cycle(height_m: float = skeleton.REFERENCE_HEIGHT_M, period_s: float = IDLE_PERIOD_S, fps: float = DEFAULT_FPS) -> MotionClip:
    """Standing idle of ``nsim_skeleton(height_m)``: breathing, a slow weight shift and head motion.

    Feet stay planted (legs solved by IK); ``N + 1`` frames over ``period_s``, the last closing the loop.
    """
    if not (math.isfinite(period_s) and period_s > 0.5):
        raise ValueError(f"idle_cycle: period_s must be > 0.5, got {period_s!r}")
    sk = skeleton.nsim_skeleton(height_m)
    s = height_m / skeleton.REFERENCE_HEIGHT_M
    n = max(8, int(round(period_s * fps)))
    phase = np.arange(n + 1) / n
    F = phase.shape[0]
    w = 2 * np.pi * phase
    deg = np.radians
    idx = {n_: sk.index(n_) for n_ in sk.joint_names}
    R_pelvis = skeleton.rot_z(deg(2.0) * np.sin(w)) @ _rx(deg(1.5) * np.sin(w + 0.7))
    pelvis = np.stack([0.01 * s * np.sin(w + 1.3), 0.02 * s * np.sin(w), np.full(F, sk.offsets_m[0, 2])], -1)
    l1 = float(np.linalg.norm(sk.offsets_m[idx["left_knee"]]))
    l2 = float(np.linalg.norm(sk.offsets_m[idx["left_ankle"]]))
    rest = sk.rest_positions_m()
    ankles = {side: np.broadcast_to(rest[idx[f"{side}_ankle"]], (F, 3)) for side in ("left", "right")}
    drop = 0.0
    for side in ("left", "right"):
        hip = pelvis + np.einsum("nij,j->ni", R_pelvis, sk.offsets_m[idx[f"{side}_hip"]])
        d = ankles[side] - hip
        need = -d[:, 2] - np.sqrt(np.maximum((0.97 * (l1 + l2)) ** 2 - d[:, 0] ** 2 - d[:, 1] ** 2, 0.0))
        drop = max(drop, float(need.max()))
    pelvis[:, 2] -= drop + 0.004 * s * (1 - np.cos(2 * w))
    G = np.broadcast_to(np.eye(3), (F, sk.num_joints, 3, 3)).copy()
    G[:, 0] = R_pelvis
    breath = deg(1.2) * np.sin(4 * w)
    G[:, idx["spine1"]] = R_pelvis @ _rx(-deg(0.7) * np.sin(w + 0.7))
    G[:, idx["spine2"]] = G[:, idx["spine1"]] @ _ry(-0.5 * breath)
    G[:, idx["spine3"]] = G[:, idx["spine2"]] @ _ry(-0.5 * breath)
    G[:, idx["left_collar"]] = G[:, idx["spine3"]]
    G[:, idx["right_collar"]] = G[:, idx["spine3"]]
    head = skeleton.rot_z(deg(8.0) * np.sin(w + 2.0)) @ _ry(deg(3.0) + deg(2.0) * np.sin(2 * w))
    G[:, idx["neck"]] = head
    G[:, idx["head"]] = head
    pre = skeleton.forward_kinematics(sk, skeleton.local_rotations_from_global(sk, G), pelvis)
    for side in ("left", "right"):
        thigh, shin = _leg_ik(pre[:, idx[f"{side}_hip"], :3, 3], ankles[side], np.tile([1.0, 0.0, 0.0], (F, 1)), l1, l2)
        G[:, idx[f"{side}_hip"]] = thigh
        G[:, idx[f"{side}_knee"]] = shin
    for side, sign in (("left", 1.0), ("right", -1.0)):
        upper = G[:, idx["spine3"]] @ _ry(np.full(F, deg(-4.0)) + deg(1.5) * np.sin(w + sign)) @ _rx(
            -sign * np.full(F, deg(84.0)))
        G[:, idx[f"{side}_shoulder"]] = upper
        G[:, idx[f"{side}_elbow"]] = upper @ skeleton.rot_z(-sign * np.full(F, deg(14.0)))
        G[:, idx[f"{side}_wrist"]] = G[:, idx[f"{side}_elbow"]]
        G[:, idx[f"{side}_hand"]] = G[:, idx[f"{side}_elbow"]] @ skeleton.rot_z(-sign * np.full(F, deg(12.0)))
    L = skeleton.local_rotations_from_global(sk, G)
    return MotionClip(sk, n / period_s, pelvis, skeleton.quats_from_matrices(L), name="idle", loop=True)


def turn(speed_mps: float = 1.0, turn_rate_deg_s: float = 45.0, duration_s: float = 4.0,
         height_m: float = skeleton.REFERENCE_HEIGHT_M, fps: float = DEFAULT_FPS) -> MotionClip:
    """Walk at ``speed_mps`` on a circular arc turning at ``turn_rate_deg_s`` (positive: left) for ``duration_s``."""
    if not (math.isfinite(turn_rate_deg_s) and turn_rate_deg_s != 0.0):
        raise ValueError(f"turn: turn_rate_deg_s must be nonzero, got {turn_rate_deg_s!r}")
    loop = LocomotionLoop.from_clip(walk_cycle(speed_mps, height_m, fps))
    radius = speed_mps / math.radians(abs(turn_rate_deg_s))
    angle = math.radians(abs(turn_rate_deg_s)) * duration_s
    a = np.linspace(0.0, angle, max(16, int(math.ceil(angle / math.radians(2.0)))) + 1)
    side = math.copysign(1.0, turn_rate_deg_s)
    path = np.stack([radius * np.sin(a), side * radius * (1.0 - np.cos(a))], axis=1)
    clip = loop.pose_along_path(path, speed_mps, fps=fps, turn_window_m=min(0.3, 0.25 * radius))
    return clip.with_name(f"turn {turn_rate_deg_s:g} deg/s at {speed_mps:g} m/s")


def default_clip(name: str, height_m: float = skeleton.REFERENCE_HEIGHT_M) -> MotionClip:
    """One of ``DEFAULT_CLIPS`` generated for a body ``height_m`` tall."""
    if name not in DEFAULT_CLIPS:
        raise ValueError(f"unknown default clip {name!r}; valid: {', '.join(DEFAULT_CLIPS)}")
    speed = DEFAULT_CLIPS[name]
    clip = idle_cycle(height_m) if speed is None else walk_cycle(speed, height_m)
    return clip.with_name(name)


def write_default_clips(out_dir: str | Path) -> list[Path]:
    """Write every ``DEFAULT_CLIPS`` entry as ``out_dir/NAME.bvh`` (1.75 m body, centimetres). Deterministic."""
    from nsim.human.bvh import write_bvh

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [write_bvh(out_dir / f"{name}.bvh", default_clip(name)) for name in DEFAULT_CLIPS]


if __name__ == "__main__":
    for p in write_default_clips(sys.argv[1] if len(sys.argv) > 1 else "nsim/configs/motions"):
        print(p)
