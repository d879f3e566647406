"""A seeded "handheld" capture path through the test room.

The path is what a person filming the room for a ground robot would walk: one loop around
the room's walk loop (``RoomSpec.walk_loop_xy_m``) at eye height, then, after crouching
while walking, a second loop low down. The camera looks inwards, at the loop centre, so it
sees the far side of the room and consecutive frames overlap strongly while the walk gives
parallax (an orbit, which suits SfM). On top: head bob and sway tied to the distance
walked, and small smooth yaw / pitch / roll wobbles (sums of seeded sinusoids).

Poses are ``cam_to_world (N, 4, 4)`` in OpenCV camera axes (+x right, +y down, +z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from nsim.geometry.transforms import look_at
from nsim.synth.room import RoomSpec, clearance_xy_m

MIN_CLEARANCE_M = 0.5
"""The path never comes closer than this (2D, so also 3D) to a wall or furniture footprint."""


@dataclass(frozen=True)
class HandheldPathConfig:
    """Shape of the handheld capture (heights in metres above the floor).

    eye_height_m / low_height_m: camera height of the first and the second loop.
    crouch_fraction: fraction of the capture spent moving between the two heights.
    eye_pitch_down_deg / low_pitch_down_deg: how far below the horizon the camera looks on
        each loop (it faces the loop centre in yaw).
    bob_amplitude_m, sway_amplitude_m, step_length_m: gait (vertical bob once per step,
        sideways sway once per stride of two steps); halved on the low loop.
    yaw_wobble_deg, pitch_wobble_deg, roll_wobble_deg: peak amplitude of the rotation wobble.
    """

    eye_height_m: float = 1.5
    low_height_m: float = 0.6
    crouch_fraction: float = 0.12
    eye_pitch_down_deg: float = 10.0
    low_pitch_down_deg: float = 0.0
    bob_amplitude_m: float = 0.025
    sway_amplitude_m: float = 0.02
    step_length_m: float = 0.7
    yaw_wobble_deg: float = 5.0
    pitch_wobble_deg: float = 2.5
    roll_wobble_deg: float = 1.5

    def __post_init__(self) -> None:
        for name in ("eye_height_m", "low_height_m", "step_length_m"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"HandheldPathConfig.{name}: expected > 0, got {getattr(self, name)!r}")
        for name in ("eye_pitch_down_deg", "low_pitch_down_deg"):
            if not -60.0 <= getattr(self, name) <= 60.0:
                raise ValueError(f"HandheldPathConfig.{name}: expected in [-60, 60], got {getattr(self, name)!r}")
        if not 0.0 <= self.crouch_fraction < 1.0:
            raise ValueError(f"HandheldPathConfig.crouch_fraction: expected in [0, 1), got {self.crouch_fraction!r}")
        for name in ("bob_amplitude_m", "sway_amplitude_m", "yaw_wobble_deg", "pitch_wobble_deg", "roll_wobble_deg"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"HandheldPathConfig.{name}: expected >= 0, got {getattr(self, name)!r}")


DEFAULT_PATH = HandheldPathConfig()


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _wobble(rng: np.random.Generator, s: np.ndarray, amplitude: float) -> np.ndarray:
    """Smooth pseudo-random signal over ``s in [0, 1]`` peaking at about ``amplitude``: three sinusoids."""
    freqs = rng.uniform(1.5, 6.0, size=3)  # cycles over the whole capture
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    weights = np.array([0.5, 0.3, 0.2])
    return amplitude * np.sum(weights[:, None] * np.sin(2 * np.pi * freqs[:, None] * s[None] + phases[:, None]), axis=0)


def handheld_path(spec: RoomSpec, n_frames: int, seed: int = 0,
                  cfg: HandheldPathConfig = DEFAULT_PATH) -> np.ndarray:
    """``cam_to_world (n_frames, 4, 4)`` of a two-loop handheld capture of ``spec`` (see module doc).

    Frame k sits at capture fraction ``k / n_frames``; the loops run counter-clockwise from a
    seeded start angle. Deterministic in (spec, n_frames, seed, cfg). Raises ValueError when
    the heights do not fit the room, RuntimeError if the path would come within
    ``MIN_CLEARANCE_M`` of an obstacle (a spec whose walk loop is too tight).
    """
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 2:
        raise ValueError(f"handheld_path: n_frames must be an int >= 2, got {n_frames!r}")
    return handheld_path_at(spec, np.arange(n_frames) / n_frames, seed, cfg)


def handheld_path_at(spec: RoomSpec, capture_fraction: np.ndarray, seed: int = 0,
                     cfg: HandheldPathConfig = DEFAULT_PATH) -> np.ndarray:
    """``cam_to_world (M, 4, 4)`` of the handheld path at any capture fractions ``(M,)``.

    Frame k of an n-frame capture at ``fps`` sits at ``k / n``, so time ``t_s`` sits at
    ``t_s * fps / n``: this gives the camera between frames (motion blur, rolling shutter).
    The path is smooth in the fraction; outside ``[0, 1]`` it goes on (the loop continues,
    the height holds). ``handheld_path`` is this at ``arange(n) / n``. Errors as ``handheld_path``.
    """
    s = np.asarray(capture_fraction, dtype=np.float64)
    if s.ndim != 1 or not np.all(np.isfinite(s)):
        raise ValueError(f"handheld_path_at: capture_fraction must be a finite 1-D array, got shape {s.shape}")
    Z = spec.size_xyz_m[2]
    top = max(cfg.eye_height_m, cfg.low_height_m) + cfg.bob_amplitude_m
    bottom = min(cfg.eye_height_m, cfg.low_height_m) - cfg.bob_amplitude_m
    if top > Z - MIN_CLEARANCE_M or bottom < MIN_CLEARANCE_M:
        raise ValueError(
            f"handheld_path: heights {cfg.eye_height_m} / {cfg.low_height_m} m (+- bob) must stay "
            f"{MIN_CLEARANCE_M} m from the floor and the ceiling at {Z} m"
        )
    rng = np.random.default_rng([int(seed), 0x9A7])
    cx, cy, rx, ry = spec.walk_loop_xy_m
    angle = rng.uniform(0.0, 2.0 * np.pi) + 4.0 * np.pi * s  # two counter-clockwise loops
    on_loop = np.stack([cx + rx * np.cos(angle), cy + ry * np.sin(angle)], axis=-1)

    # distance walked along the ellipse (fine numerical integration, for the gait phase)
    fine = np.linspace(0.0, 4.0 * np.pi, 4097)
    seg = np.hypot(np.diff(rx * np.cos(fine)), np.diff(ry * np.sin(fine)))
    arc_fine = np.concatenate([[0.0], np.cumsum(seg)])
    walked_m = np.interp(4.0 * np.pi * s, fine, arc_fine)
    if (beyond := (s < 0.0) | (s > 1.0)).any():  # whole loops (of arc_fine[2048] m) plus the part of one
        turns = np.floor(2.0 * s[beyond])
        walked_m[beyond] = turns * arc_fine[2048] + np.interp(4.0 * np.pi * s[beyond] - 2.0 * np.pi * turns,
                                                              fine[:2049], arc_fine[:2049])
    step_phase = 2.0 * np.pi * walked_m / cfg.step_length_m

    crouch = _smoothstep((s - (0.5 - cfg.crouch_fraction / 2)) / max(cfg.crouch_fraction, 1e-9))
    height = (1.0 - crouch) * cfg.eye_height_m + crouch * cfg.low_height_m
    gait = 1.0 - 0.5 * crouch
    height = height + gait * cfg.bob_amplitude_m * np.sin(step_phase)

    # sway: sideways (radial) offset once per stride
    radial = on_loop - np.array([cx, cy])
    radial /= np.linalg.norm(radial, axis=-1, keepdims=True)
    xy = on_loop + (gait * cfg.sway_amplitude_m * np.sin(step_phase / 2.0))[:, None] * radial
    eye = np.concatenate([xy, height[:, None]], axis=-1)

    pitch_down = np.radians((1.0 - crouch) * cfg.eye_pitch_down_deg + crouch * cfg.low_pitch_down_deg)
    inward = -radial  # unit, horizontal, towards the loop centre
    target = eye + np.concatenate([inward, -np.tan(pitch_down)[:, None]], axis=-1)
    cam_to_world = look_at(eye, target)
    wobble_deg = np.stack([
        _wobble(rng, s, cfg.pitch_wobble_deg),  # about camera +x (pitch)
        _wobble(rng, s, cfg.yaw_wobble_deg),  # about camera +y (yaw, y points down)
        _wobble(rng, s, cfg.roll_wobble_deg),  # about camera +z (roll)
    ], axis=-1)
    R_wobble = Rotation.from_rotvec(np.radians(wobble_deg)).as_matrix()
    cam_to_world[:, :3, :3] = cam_to_world[:, :3, :3] @ R_wobble

    clearance = clearance_xy_m(spec, xy)
    if clearance.min() < MIN_CLEARANCE_M:
        raise RuntimeError(
            f"handheld_path: path passes {clearance.min():.3f} m from an obstacle in room {spec.name!r} "
            f"(walk loop {spec.walk_loop_xy_m}); needs >= {MIN_CLEARANCE_M} m"
        )
    return cam_to_world


def timestamps_s(n_frames: int, fps: float) -> np.ndarray:
    """Frame times ``(n_frames,)`` float64 in seconds: ``k / fps``, starting at 0."""
    if not (math.isfinite(fps) and fps > 0.0):
        raise ValueError(f"timestamps_s: fps must be > 0, got {fps!r}")
    if n_frames < 0:
        raise ValueError(f"timestamps_s: n_frames must be >= 0, got {n_frames!r}")
    return np.arange(n_frames, dtype=np.float64) / fps
