"""Robot controllers in the loop: what the robot sees each tick, and the velocity it asks for.

A scenario's ``robot.controller`` picks who drives the robot:

``replay`` (default)
    The robot follows its trajectory (poses, waypoints, TUM file, walk loop) whatever the people do
    (``nsim.crowd.driver.simulate`` samples it; no controller runs).
``social_force``
    The robot is a social-force agent (``SocialForceController``): it relaxes towards its goal at
    its speed, pushed by the people it sees and by the walls, with the crowd's force model and
    parameters (``nsim.crowd.social_force``).
``orca``
    Optimal reciprocal collision avoidance (``OrcaController``; van den Berg, Guy, Lin & Manocha,
    "Reciprocal n-body collision avoidance", ISRR 2009), written here: one velocity half-plane per
    person seen and per nearby wall point, the velocity closest to the preferred one inside them
    and the speed limit by an incremental 2D linear program, the least-violating velocity when
    they admit none.
``{"python": "module.path:Class", "params": {...}}``
    A user's class, imported by module path (``sys.path``: the working directory and installed
    packages) or from a file next to the scenario, ``"my_controller.py:Class"`` (relative to the
    scenario file; the resolved scenario stores the absolute path and the file's SHA-256, so an
    edit re-runs it). It is constructed once per run as ``Class(**params)`` and must have a method
    ``command(observation) -> (vx_mps, vy_mps, yaw_rate_radps)``. The file is *executed*: name only
    code you trust.

Each tick the controller gets an :class:`Observation` (world frame, metres, seconds) and returns a
body-frame command ``(vx, vy, yaw rate)`` (x forward, y left, yaw about +z). nsim clamps it to the
robot's :class:`RobotLimits` (holonomic: the linear speed to ``max_speed_mps``, the yaw rate to
``max_yaw_rate_radps``; Spot's by default, a scenario's ``robot.limits`` override them) and moves
the robot by it for one step (``integrate``). The robot does not yield to anyone: people are pushed
out of its body (``social_force.separate_bodies``), so a controller that drives into a person is
responsible for the collision, which HuNavSim's collision metrics count. Walls stop the robot:
its body is projected out of them (the executed velocity then differs from the command).

Sensor frames: ``closed_loop`` may be given a :class:`SensorHook` (a renderer and a rate); on the
ticks due at that rate the observation's ``render_sensor(name)`` renders the named sensor at the
robot's current body-to-world pose through it (lazily: only what the controller asks for). The
simulate stage passes one when the scenario has ``robot.sensors`` (a scene checkpoint rendered by
``nsim.crowd.sensors.SceneSensors``, without people); otherwise it is None.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.util
import math
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from nsim.crowd.neighbours import SegmentGrid, closest_points_on_segments
from nsim.crowd.social_force import (
    ForceParams,
    desired_force,
    desired_velocity,
    obstacle_repulsion,
    pair_repulsion,
)

BUILT_IN = ("replay", "social_force", "orca")
SENSOR_RANGE_M = 8.0
"""People farther than this from the robot's centre are not in the observation (``robot.sensor_range_m``)."""
GOAL_TOLERANCE_M = 0.3
"""The robot has reached a goal when its centre is this close; it then heads for the next one."""
YAW_TIME_CONSTANT_S = 0.5
"""The built-in controllers turn to face their velocity at ``heading error / this`` (clamped)."""


@dataclasses.dataclass(frozen=True)
class RobotLimits:
    """The robot's velocity limits (holonomic base). Defaults: Boston Dynamics Spot (1.6 m/s, 1.5 rad/s)."""

    max_speed_mps: float = 1.6
    max_yaw_rate_radps: float = 1.5


@dataclasses.dataclass(frozen=True)
class SensorHook:
    """Rendered sensor frames for controllers: ``render(sensor_name, body_to_world_se3 (4, 4), time_s)``
    returns that sensor's frame; ``rate_hz``: frames are offered every ``round(1 / (rate_hz dt))`` ticks
    (at least every tick), from tick 0."""

    render: Callable[[str, np.ndarray, float], Any]
    rate_hz: float

    def every_ticks(self, dt_s: float) -> int:
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz: expected > 0, got {self.rate_hz!r}")
        return max(1, int(round(1.0 / (self.rate_hz * dt_s))))


@dataclasses.dataclass(frozen=True, eq=False)
class Observation:
    """What a controller sees at one tick (world frame, z up; arrays are read-only copies).

    time_s, dt_s: the tick's time and the step. position_m: (2,) robot centre; heading_rad: yaw
    about +z from +x; velocity_mps: (2,) the robot's executed world velocity over the last step.
    goal_m: (2,) the current goal; goal_index: its index in goals_m (G, 2); final_goal: the goal is
    the last one of a non-looping path (stop there). people_position_m, people_velocity_mps: (P, 2)
    and people_radius_m (P,): the people whose centre is within sensor_range_m, nearest first;
    people_index (P,): their rows in the crowd. walls_m: (M, 2, 2) every obstacle boundary segment;
    obstacles_m: the obstacle polygons ``(K_i, 2)``. robot_radius_m, robot_half_length_m: its capsule;
    limits: its velocity limits; desired_speed_mps: the scenario's cruising speed for it.
    render_sensor: on the ticks a :class:`SensorHook` is due, ``render_sensor(name)`` renders that
    sensor at the robot's pose now; None on other ticks and when the run has no hook.
    """

    time_s: float
    dt_s: float
    position_m: np.ndarray
    heading_rad: float
    velocity_mps: np.ndarray
    goal_m: np.ndarray
    goal_index: int
    goals_m: np.ndarray
    final_goal: bool
    people_position_m: np.ndarray
    people_velocity_mps: np.ndarray
    people_radius_m: np.ndarray
    people_index: np.ndarray
    walls_m: np.ndarray
    obstacles_m: tuple[np.ndarray, ...]
    robot_radius_m: float
    robot_half_length_m: float
    limits: RobotLimits
    desired_speed_mps: float
    sensor_range_m: float
    render_sensor: Callable[[str], Any] | None = None


# ----------------------------------------------------------------------------------------------
# Commands: frames, clamping, integration


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def world_to_body(v_world: np.ndarray, heading_rad: float) -> np.ndarray:
    """A world-frame velocity ``(2,)`` in the body frame (x forward, y left)."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([c * v_world[0] + s * v_world[1], -s * v_world[0] + c * v_world[1]])


def body_to_world(v_body: np.ndarray, heading_rad: float) -> np.ndarray:
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([c * v_body[0] - s * v_body[1], s * v_body[0] + c * v_body[1]])


def clamp_command(command: np.ndarray, limits: RobotLimits) -> np.ndarray:
    """``(vx, vy, yaw rate)`` within the limits: the linear part scaled to ``max_speed_mps`` (its
    direction kept), the yaw rate clipped to ``+- max_yaw_rate_radps``."""
    cmd = np.asarray(command, dtype=np.float64).copy()
    speed = math.hypot(cmd[0], cmd[1])
    if speed > limits.max_speed_mps:
        cmd[:2] *= limits.max_speed_mps / speed
    cmd[2] = min(max(cmd[2], -limits.max_yaw_rate_radps), limits.max_yaw_rate_radps)
    return cmd


def face_velocity_yaw_rate(v_world: np.ndarray, heading_rad: float, toward_m: np.ndarray | None = None) -> float:
    """Yaw rate turning the body towards its velocity (or towards ``toward_m`` when nearly still)."""
    if math.hypot(v_world[0], v_world[1]) > 0.1:
        target = math.atan2(v_world[1], v_world[0])
    elif toward_m is not None and np.linalg.norm(toward_m) > 1e-6:
        target = math.atan2(toward_m[1], toward_m[0])
    else:
        return 0.0
    return _wrap(target - heading_rad) / YAW_TIME_CONSTANT_S


# ----------------------------------------------------------------------------------------------
# Built-in controllers


def preferred_velocity(obs: Observation, braking_mps2: float = 1.0) -> np.ndarray:
    """Straight to the goal at the desired speed (at most the limit), braking before a final goal."""
    to_goal = obs.goal_m - obs.position_m
    dist = float(np.linalg.norm(to_goal))
    if dist < 1e-9:
        return np.zeros(2)
    speed = min(obs.desired_speed_mps, obs.limits.max_speed_mps)
    if obs.final_goal:
        speed = min(speed, math.sqrt(2.0 * braking_mps2 * dist), dist / obs.dt_s)
    return to_goal / dist * speed


class SocialForceController:
    """The robot as a social-force agent (``nsim.crowd.social_force``'s model and parameters).

    Acceleration: relaxation to the desired velocity towards the goal (``desired_velocity``,
    braking before a final goal), the people's repulsion on it as on a human (``pair_repulsion``,
    the robot a disc of radius ``radius + half_length``: people are kept off its whole body) and the
    walls' (``obstacle_repulsion`` on its ``radius``: the driver keeps that disc out of the walls,
    and the wider disc would hold it off goals near a wall).
    The command is the velocity after one semi-implicit Euler step, in the body frame.
    """

    def __init__(self, forces: ForceParams):
        self.forces = forces
        self._walls: SegmentGrid | None = None

    def command(self, obs: Observation) -> np.ndarray:
        f = self.forces
        radius = obs.robot_radius_m + obs.robot_half_length_m
        if self._walls is None:
            self._walls = SegmentGrid.build(obs.walls_m, max(f.obstacle_cutoff_m, obs.robot_radius_m * 1.5))
        x, v = obs.position_m[None], obs.velocity_mps[None]
        speed = min(obs.desired_speed_mps, obs.limits.max_speed_mps)
        v_des = desired_velocity(
            x, v, obs.goal_m[None], np.array([speed]), np.array([0.05]), np.array([obs.final_goal]), f
        )
        acc = desired_force(v, v_des, f.relaxation_time_s)[0]
        if len(obs.people_position_m):
            p = len(obs.people_position_m)
            heading = np.tile([math.cos(obs.heading_rad), math.sin(obs.heading_rad)], (p, 1))
            acc = acc + pair_repulsion(
                obs.position_m - obs.people_position_m,
                (obs.people_velocity_mps - obs.velocity_mps) * f.agent_lookahead_s,
                radius + obs.people_radius_m,
                heading,
                f,
            ).sum(axis=0)
        if len(obs.walls_m):
            acc = acc + obstacle_repulsion(x, np.array([obs.robot_radius_m]), self._walls, f)[0]
        v_new = obs.velocity_mps + acc * obs.dt_s
        yaw_rate = face_velocity_yaw_rate(v_new, obs.heading_rad, obs.goal_m - obs.position_m)
        return np.array([*world_to_body(v_new, obs.heading_rad), yaw_rate])


@dataclasses.dataclass(frozen=True)
class HalfPlane:
    """Velocities ``v`` with ``(v - point) . normal >= 0``."""

    point: np.ndarray
    normal: np.ndarray


def orca_half_plane(
    rel_position_m: np.ndarray,
    rel_velocity_mps: np.ndarray,
    radius_sum_m: float,
    horizon_s: float,
    dt_s: float,
    own_velocity_mps: np.ndarray,
    responsibility: float,
) -> HalfPlane:
    """The ORCA half-plane for one neighbour (van den Berg et al. 2009, section 5).

    rel_position_m: the neighbour's centre minus ours; rel_velocity_mps: our velocity minus its.
    The velocity obstacle is the cone from the origin tangent to the disc of radius
    ``radius_sum / horizon`` about ``rel_position / horizon``, cut off by the disc's front arc. ``u``
    is the shortest vector from the relative velocity to its boundary and ``n`` the outward normal
    there; we take ``responsibility`` of ``u`` (1: all of it) and keep ``(v - (v_own + resp u)) . n >= 0``.
    Already overlapping: the disc is ``radius_sum / dt`` about ``rel_position / dt`` (get out within a step).
    """
    p, v = np.asarray(rel_position_m, float), np.asarray(rel_velocity_mps, float)
    d = float(np.linalg.norm(p))
    r = radius_sum_m
    if d <= r:  # overlapping: leave the disc within one step
        c, rad = p / dt_s, r / dt_s
        w = v - c
        wn = float(np.linalg.norm(w))
        n = w / wn if wn > 1e-12 else -p / max(d, 1e-12) if d > 1e-12 else np.array([1.0, 0.0])
        u = (rad - wn) * n
        return HalfPlane(own_velocity_mps + responsibility * u, n)
    c, rad = p / horizon_s, r / horizon_s
    axis = p / d
    sin_a = r / d
    cos_a = math.sqrt(max(1.0 - sin_a * sin_a, 0.0))
    legs = (  # left (counter-clockwise) and right tangent directions, with outward normals
        (np.array([axis[0] * cos_a - axis[1] * sin_a, axis[0] * sin_a + axis[1] * cos_a]), +1.0),
        (np.array([axis[0] * cos_a + axis[1] * sin_a, -axis[0] * sin_a + axis[1] * cos_a]), -1.0),
    )
    tangent_len = math.sqrt(d * d - r * r) / horizon_s
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for leg, side in legs:
        t = max(float(v @ leg), tangent_len)
        q = t * leg
        normal = side * np.array([-leg[1], leg[0]])
        dist = float(np.linalg.norm(v - q))
        if best is None or dist < best[0]:
            best = (dist, q, normal)
    w = v - c
    wn = float(np.linalg.norm(w))
    if wn > 1e-12:
        q = c + rad * w / wn
        on_front_arc = float((q - c) @ (-axis)) >= rad * sin_a - 1e-12
        if on_front_arc and abs(wn - rad) < best[0]:
            best = (abs(wn - rad), q, w / wn)
    _, q, n = best
    return HalfPlane(own_velocity_mps + responsibility * (q - v), n)


def _solve_on_line(planes: list[HalfPlane], i: int, max_speed: float, pref: np.ndarray) -> np.ndarray | None:
    """Closest point to ``pref`` on plane i's boundary within the speed disc and planes ``< i``; None if empty."""
    p, n = planes[i].point, planes[i].normal
    d = np.array([-n[1], n[0]])
    # |p + t d| <= max_speed
    b = float(p @ d)
    disc = b * b - (float(p @ p) - max_speed * max_speed)
    if disc < 0:
        return None
    t_lo, t_hi = -b - math.sqrt(disc), -b + math.sqrt(disc)
    for j in range(i):
        pj, nj = planes[j].point, planes[j].normal
        den = float(d @ nj)
        num = float((pj - p) @ nj)
        if abs(den) < 1e-12:
            if num > 1e-12:
                return None
            continue
        if den > 0:
            t_lo = max(t_lo, num / den)
        else:
            t_hi = min(t_hi, num / den)
        if t_lo > t_hi:
            return None
    t = min(max(float((pref - p) @ d), t_lo), t_hi)
    return p + t * d


def solve_velocity(planes: list[HalfPlane], max_speed: float, pref: np.ndarray) -> tuple[np.ndarray, bool]:
    """The velocity closest to ``pref`` within ``|v| <= max_speed`` and every half-plane, and whether
    one exists (incremental 2D linear program). None exists: the velocity on a polar grid of the
    speed disc that least violates the worst half-plane (ties: closest to ``pref``)."""
    v = pref.copy()
    s = float(np.linalg.norm(v))
    if s > max_speed:
        v *= max_speed / s
    for i, h in enumerate(planes):
        if float((v - h.point) @ h.normal) < 0.0:
            on = _solve_on_line(planes, i, max_speed, pref)
            if on is None:
                break
            v = on
    else:
        return v, True
    ang = np.linspace(0.0, 2.0 * math.pi, 48, endpoint=False)
    speeds = np.linspace(0.0, max_speed, 9)[1:]
    cand = np.concatenate([np.zeros((1, 2)), (speeds[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], -1)).reshape(-1, 2)])
    pts = np.array([h.point for h in planes])
    nrm = np.array([h.normal for h in planes])
    violation = np.maximum(-((cand[:, None, :] - pts[None]) * nrm[None]).sum(-1), 0.0).max(axis=1)
    score = violation * 1e3 + np.linalg.norm(cand - pref, axis=1)
    return cand[int(np.argmin(score))], False


class OrcaController:
    """ORCA among the people seen and the walls (see ``orca_half_plane``, ``solve_velocity``).

    Among people the robot is a disc of radius ``radius + half_length`` (its capsule's circumscribed
    disc) plus ``safety_margin_m``; against walls, of ``radius`` plus the margin (the disc the
    driver keeps out of the walls). People: ``time_horizon_s``, ``responsibility`` of the avoidance (1: the
    robot does it all; people also avoid it, which only adds margin). Walls: the nearest point of
    every segment within ``wall_range_m``, a static point, over ``obstacle_time_horizon_s``.
    Preferred velocity: ``preferred_velocity``.
    """

    def __init__(
        self,
        time_horizon_s: float = 2.0,
        obstacle_time_horizon_s: float = 0.5,
        responsibility: float = 1.0,
        safety_margin_m: float = 0.1,
        wall_range_m: float = 1.5,
    ):
        self.time_horizon_s = time_horizon_s
        self.obstacle_time_horizon_s = obstacle_time_horizon_s
        self.responsibility = responsibility
        self.safety_margin_m = safety_margin_m
        self.wall_range_m = wall_range_m
        self.feasible_ticks = 0
        self.infeasible_ticks = 0

    def command(self, obs: Observation) -> np.ndarray:
        radius = obs.robot_radius_m + obs.robot_half_length_m + self.safety_margin_m
        wall_radius = obs.robot_radius_m + self.safety_margin_m
        x, v = obs.position_m, obs.velocity_mps
        planes = []
        if len(obs.walls_m):
            q = closest_points_on_segments(np.broadcast_to(x, (len(obs.walls_m), 2)), obs.walls_m)
            dist = np.linalg.norm(q - x, axis=1)
            key = np.round(q * 1e6)
            _, first = np.unique(key, axis=0, return_index=True)
            for k in sorted(int(i) for i in first if dist[i] < self.wall_range_m):
                planes.append(
                    orca_half_plane(q[k] - x, v, wall_radius, self.obstacle_time_horizon_s, obs.dt_s, v, 1.0)
                )
        for p, vp, rp in zip(obs.people_position_m, obs.people_velocity_mps, obs.people_radius_m, strict=True):
            planes.append(
                orca_half_plane(p - x, v - vp, radius + rp, self.time_horizon_s, obs.dt_s, v, self.responsibility)
            )
        pref = preferred_velocity(obs)
        v_new, ok = solve_velocity(planes, obs.limits.max_speed_mps, pref)
        if ok:
            self.feasible_ticks += 1
        else:
            self.infeasible_ticks += 1
        yaw_rate = face_velocity_yaw_rate(v_new, obs.heading_rad, obs.goal_m - x)
        return np.array([*world_to_body(v_new, obs.heading_rad), yaw_rate])


# ----------------------------------------------------------------------------------------------
# User classes


def _file_module(path: Path) -> Any:
    """The module of a Python file, imported once per content (module name from its SHA-256)."""
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    name = f"nsim_user_controller_{digest[:16]}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def resolve_python_spec(value: str, base_dir: Path | None, fail: Callable[[str], Exception]) -> dict[str, str]:
    """Check ``"module.path:Class"`` / ``"file.py:Class"`` and import it; the canonical entries.

    A file is relative to ``base_dir`` (the scenario's folder) unless absolute; the result holds
    its absolute path and SHA-256. ``fail(message)`` builds the error (naming file and field).
    """
    module_part, _, cls_name = value.rpartition(":")
    if not module_part or not cls_name.isidentifier():
        raise fail(f"{value!r}: expected 'module.path:Class' or 'file.py:Class'")
    out: dict[str, str] = {}
    if module_part.endswith(".py"):
        path = Path(module_part)
        if not path.is_absolute():
            if base_dir is None:
                raise fail(f"{value!r}: a relative controller file is only allowed in a scenario file")
            path = base_dir / path
        path = path.resolve()
        if not path.is_file():
            raise fail(f"no such file {path}")
        out["python"] = f"{path}:{cls_name}"
        out["code_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
        load = lambda: _file_module(path)  # noqa: E731
    else:
        out["python"] = value
        load = lambda: importlib.import_module(module_part)  # noqa: E731
    try:
        module = load()
    except ModuleNotFoundError as exc:
        raise fail(f"cannot import module {module_part!r} ({exc})") from None
    except Exception as exc:  # the user's module failed while importing
        raise fail(f"importing {module_part!r} failed: {exc.__class__.__name__}: {exc}") from None
    cls = getattr(module, cls_name, None)
    if cls is None or not isinstance(cls, type):
        raise fail(f"{module_part!r} has no class {cls_name!r}")
    if not callable(getattr(cls, "command", None)):
        raise fail(f"class {cls_name!r} has no method command(observation)")
    return out


def user_class(entry: Mapping[str, Any]) -> type:
    """The class a resolved ``{"python": ...}`` entry names (already checked by ``resolve_python_spec``)."""
    module_part, _, cls_name = entry["python"].rpartition(":")
    module = _file_module(Path(module_part)) if module_part.endswith(".py") else importlib.import_module(module_part)
    return getattr(module, cls_name)


def controller_label(entry: str | Mapping[str, Any]) -> str:
    """A short name for tables: the built-in's name or the user's class name."""
    if isinstance(entry, str):
        return entry
    return str(entry["python"]).rpartition(":")[2]


def check_command(raw: Any, fail: Callable[[str], Exception]) -> np.ndarray:
    """A controller's return value as a ``(3,)`` float array; ``fail`` unless it is 3 finite numbers."""
    try:
        cmd = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise fail(f"command returned {type(raw).__name__}, expected 3 numbers (vx_mps, vy_mps, yaw_rate_radps)") from None
    if cmd.shape != (3,):
        raise fail(f"command returned shape {cmd.shape}, expected (3,) (vx_mps, vy_mps, yaw_rate_radps)")
    if not np.all(np.isfinite(cmd)):
        raise fail(f"command returned non-finite values {cmd.tolist()}")
    return cmd
