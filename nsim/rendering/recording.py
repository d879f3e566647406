"""A registered recording's sensors, frame by frame: which frames, each one's world pose, its rays.

The core of ``nsim render --recording`` (arrays in, arrays out; the stage reads the artifacts).
A ``recording`` (``nsim import-log``) holds streams of kind ``camera``, ``depth`` or ``lidar``,
each with its ``sensor_to_body (4, 4)`` and its frames' header stamps (int64 ns); a
``registration`` (``nsim register-log``) holds ``body_to_world (T, 4, 4)`` at odometry stamps
``traj_ns (T,)`` and the cameras' ``clock_offset_s``.

Clocks (the convention of ``nsim.sfm.register``): ``clock_offset_s`` is the cameras' clock minus
the odometry's, so a frame stamped ``s`` on the cameras' clock was captured at odometry time
``s - clock_offset_s``. Which streams run on the cameras' clock is the caller's choice (by kind):
in nsim's robot log (``nsim.synth.faulty_robot_log``) only the colour frames do; depth and LiDAR are
stamped on the odometry's clock. Odometry times stay int64 nanoseconds; poses are interpolated
(``nsim.geometry.transforms.interpolate_poses``: positions linearly, rotations slerped) in seconds
from the trajectory's first stamp, so the epoch's magnitude costs no precision. A frame whose
odometry time lies outside ``[traj_ns[0], traj_ns[-1]]`` has no pose: it is not extrapolated.

LiDAR: one simulated ray per recorded point, from the sensor's origin along the point's direction
(``point_directions``); the simulated return lies on that ray (``points_from_ranges``), so sim and
real ranges pair point for point.

People (a ``trajectory`` of ``nsim simulate``: ``time_s (T,)``, per tick and person ``position_m
(T, P, 2)``, ``heading_rad (T, P)``, ``gait_phase (T, P)`` in [0, 1), NaN positions for a person no
longer in the run): a frame at odometry time ``o`` (int64 ns) sees the people of simulation time
``people_time_s = time_s[0] + (o - first_odometry_ns) / 1e9 + offset_s``, where
``first_odometry_ns`` is the recording's first odometry stamp. ``offset_s = 0`` is the mapping
``nsim capture robot-log`` writes (its odometry clock reads ``start_time_s`` at the run's first
tick and advances with the simulation's). Between two ticks ``people_states_at`` interpolates
(positions linearly, headings along the shorter arc, gait phases forward modulo 1); on a tick it
returns that tick's state exactly; outside ``[time_s[0], time_s[-1]]`` nobody is present.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

KINDS = ("camera", "depth", "lidar")


def odometry_time_ns(stamps_ns: np.ndarray, clock_offset_s: float, on_camera_clock: bool) -> np.ndarray:
    """Odometry times ``(N,)`` int64 ns of frames stamped ``stamps_ns (N,)``: ``stamps - round(clock_offset_s
    * 1e9)`` for a stream on the cameras' clock, the stamps themselves otherwise."""
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    if not on_camera_clock:
        return stamps.copy()
    return stamps - np.int64(int(round(float(clock_offset_s) * 1e9)))


def sensor_poses(odom_ns: np.ndarray, traj_ns: np.ndarray, body_to_world: np.ndarray,
                 sensor_to_body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sensor's world poses at odometry times ``odom_ns (N,)`` int64.

    traj_ns: ``(T,)`` int64 increasing, ``T >= 1``; body_to_world: ``(T, 4, 4)``; sensor_to_body:
    ``(4, 4)``. Returns ``inside (N,)`` bool (the time lies within the trajectory's span),
    ``body_to_world (N, 4, 4)`` and ``sensor_to_world (N, 4, 4) = body_to_world @ sensor_to_body``,
    both NaN where not ``inside``.
    """
    from nsim.geometry.transforms import interpolate_poses

    odom = np.asarray(odom_ns, dtype=np.int64).reshape(-1)
    traj = np.asarray(traj_ns, dtype=np.int64).reshape(-1)
    poses = np.asarray(body_to_world, dtype=np.float64)
    if poses.shape != (len(traj), 4, 4) or len(traj) == 0:
        raise ValueError(f"body_to_world: expected shape ({len(traj)}, 4, 4) with a pose per stamp, got {poses.shape}")
    if np.any(np.diff(traj) <= 0):
        raise ValueError("traj_ns: expected strictly increasing stamps")
    inside = (odom >= traj[0]) & (odom <= traj[-1])
    body = np.full((len(odom), 4, 4), np.nan)
    if inside.any():
        t0 = traj[0]
        body[inside] = interpolate_poses((traj - t0) / 1e9, poses, (odom[inside] - t0) / 1e9)
    sensor = body @ np.asarray(sensor_to_body, dtype=np.float64)
    return inside, body, sensor


def select_frames(indices: np.ndarray, start: int, stride: int) -> np.ndarray:
    """Positions ``(M,)`` into a stream's kept frame ``indices (N,)``: those with index ``>= start``, then
    every ``stride``-th of them."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    return np.flatnonzero(idx >= start)[::stride]


def select_streams(available: list[str], wanted: tuple[str, ...] | list[str]) -> list[str]:
    """The streams ``<kind>/<name>`` of ``available`` that ``wanted`` names (empty: all), in ``available``'s
    order. A wanted entry is a ``<kind>/<name>`` key or a bare ``<name>`` (every kind of that name).
    Raises ValueError naming the entries that match nothing."""
    if not wanted:
        return list(available)
    names = {k.split("/", 1)[1] for k in available}
    unknown = [w for w in wanted if w not in available and w not in names]
    if unknown:
        raise ValueError(", ".join(map(repr, unknown)))
    return [k for k in available if k in wanted or k.split("/", 1)[1] in wanted]


def point_directions(xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions ``(N, 3)`` from the sensor's origin to points ``xyz_m (N, 3)`` (sensor frame) and
    ``valid (N,)``: the point is finite and not at the origin. Invalid rows get ``(1, 0, 0)``."""
    xyz = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    norm = np.linalg.norm(xyz, axis=-1)
    valid = np.isfinite(norm) & (norm > 1e-9)
    dirs = np.where(valid[:, None], xyz / np.where(valid, norm, 1.0)[:, None], [1.0, 0.0, 0.0])
    return dirs, valid


def points_from_ranges(dirs: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """Points ``(N, 3)`` at ``range_m (N,)`` along unit ``dirs (N, 3)``; NaN where the range is not finite
    (inf: no return, NaN: no valid ray)."""
    r = np.asarray(range_m, dtype=np.float64).reshape(-1)
    hit = np.isfinite(r)
    return np.where(hit[:, None], np.asarray(dirs, dtype=np.float64) * np.where(hit, r, 0.0)[:, None], np.nan)


def people_time_s(odom_ns: np.ndarray, first_odometry_ns: int, run_start_s: float, offset_s: float) -> np.ndarray:
    """Simulation times ``(N,)`` float64 of the people seen at odometry times ``odom_ns (N,)`` int64:
    ``run_start_s + (odom_ns - first_odometry_ns) / 1e9 + offset_s`` (the difference taken in integer
    nanoseconds, so an epoch-sized clock costs no precision)."""
    d = np.asarray(odom_ns, dtype=np.int64).reshape(-1) - np.int64(first_odometry_ns)
    return float(run_start_s) + d / 1e9 + float(offset_s)


def people_states_at(time_s: np.ndarray, position_m: np.ndarray, heading_rad: np.ndarray, gait_phase: np.ndarray,
                     query_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The people's state at simulation time ``query_s``.

    time_s: ``(T,)`` increasing; position_m: ``(T, P, 2)`` (NaN: not in the run); heading_rad,
    gait_phase: ``(T, P)``. Returns ``present (P,)`` bool, ``position_m (P, 2)``, ``heading_rad (P,)``,
    ``gait_phase (P,)`` in [0, 1) (NaN where not present). On a tick: that tick's values, bit for bit.
    Between ticks i and i + 1 (weight ``w``): present where both ticks are; positions linear, heading
    ``h_i + w * wrap(h_{i+1} - h_i)`` (the shorter arc), phase ``(g_i + w * ((g_{i+1} - g_i) mod 1)) mod 1``
    (gait only advances). Outside ``[time_s[0], time_s[-1]]``: nobody present.
    """
    t = np.asarray(time_s, dtype=np.float64).reshape(-1)
    pos = np.asarray(position_m, dtype=np.float64)
    head = np.asarray(heading_rad, dtype=np.float64)
    phase = np.asarray(gait_phase, dtype=np.float64)
    n = pos.shape[1] if pos.ndim == 3 else 0
    if pos.shape != (len(t), n, 2) or head.shape != (len(t), n) or phase.shape != (len(t), n) or len(t) == 0:
        raise ValueError(f"expected time_s (T,), position_m (T, P, 2), heading_rad and gait_phase (T, P); got "
                         f"{t.shape}, {pos.shape}, {head.shape}, {phase.shape}")
    if np.any(np.diff(t) <= 0):
        raise ValueError("time_s: expected strictly increasing times")
    q = float(query_s)
    nobody = (np.zeros(n, dtype=bool), np.full((n, 2), np.nan), np.full(n, np.nan), np.full(n, np.nan))
    if not (t[0] <= q <= t[-1]):
        return nobody
    hit = np.flatnonzero(t == q)
    if len(hit):
        i = int(hit[0])
        present = np.isfinite(pos[i]).all(-1)
        return (present, np.where(present[:, None], pos[i], np.nan), np.where(present, head[i], np.nan),
                np.where(present, phase[i], np.nan))
    i = int(np.searchsorted(t, q, side="right")) - 1
    w = (q - t[i]) / (t[i + 1] - t[i])
    present = np.isfinite(pos[i]).all(-1) & np.isfinite(pos[i + 1]).all(-1)
    p = pos[i] + w * (pos[i + 1] - pos[i])
    dh = np.mod(head[i + 1] - head[i] + np.pi, 2.0 * np.pi) - np.pi
    h = np.mod(head[i] + w * dh + np.pi, 2.0 * np.pi) - np.pi
    g = np.mod(phase[i] + w * np.mod(phase[i + 1] - phase[i], 1.0), 1.0)
    return present, np.where(present[:, None], p, np.nan), np.where(present, h, np.nan), np.where(present, g, np.nan)


@dataclass(frozen=True)
class RegisteredTrajectory:
    """A ``registration`` artifact (``nsim register-log``) as its readers use it: ``body_to_world (T, 4, 4)``
    at ``stamps_ns (T,)`` int64 on the odometry clock (increasing, ``T >= 1``), the cameras'
    ``clock_offset_s`` and ``registration.json`` itself (``doc``); ``id`` names it in errors."""

    id: str
    stamps_ns: np.ndarray
    body_to_world: np.ndarray
    clock_offset_s: float
    doc: dict[str, Any]

    def sensor_poses(self, odom_ns: np.ndarray, sensor_to_body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`sensor_poses` on this trajectory."""
        return sensor_poses(odom_ns, self.stamps_ns, self.body_to_world, sensor_to_body)


def read_registration(directory: str | Path, ident: str) -> RegisteredTrajectory:
    """The registration artifact in ``directory`` (``registration.json``, ``trajectory_world.tum`` and
    ``trajectory_world_ns.npy``), checked: a finite clock offset, one stamp per pose, increasing.
    ``ident`` names it in the one-line ``InputError``."""
    from nsim.errors import InputError
    from nsim.io.tum import read_tum

    d = Path(directory)
    for name in ("registration.json", "trajectory_world.tum", "trajectory_world_ns.npy"):
        if not (d / name).is_file():
            raise InputError(f"registration {ident}: has no {name}")
    try:
        doc = json.loads((d / "registration.json").read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"registration {ident}: registration.json is not readable JSON ({e})") from None
    offset_s = doc.get("clock_offset_s") if isinstance(doc, dict) else None
    if isinstance(offset_s, bool) or not isinstance(offset_s, int | float) or not math.isfinite(offset_s):
        raise InputError(f"registration {ident}: registration.json has no finite clock_offset_s")
    stamps = np.load(d / "trajectory_world_ns.npy", allow_pickle=False)
    body_to_world = read_tum(d / "trajectory_world.tum").poses_se3()
    if stamps.ndim != 1 or len(stamps) != len(body_to_world) or len(stamps) < 1 or np.any(np.diff(stamps) <= 0):
        raise InputError(f"registration {ident}: trajectory_world_ns.npy and trajectory_world.tum disagree, are "
                         "empty or are not increasing")
    return RegisteredTrajectory(ident, stamps.astype(np.int64), body_to_world, float(offset_s), doc)
