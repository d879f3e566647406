"""Running the crowd over time: ``rollout`` steps ``nsim.crowd.social_force.step`` over a replayed robot.

``RobotTrack`` is the robot's trajectory sampled at every tick; ``crowd_record`` the per-tick
arrays a rollout fills; ``CrowdTrajectory`` what it returns (the state layout is ``CrowdState``'s,
in ``nsim.crowd.social_force``). Same inputs and seed, same output.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields

import numpy as np

from nsim.crowd import behaviours as beh
from nsim.crowd.behaviours import BehaviourParams
from nsim.crowd.social_force import CrowdState, ForceParams, make_walls, step
from nsim.crowd.state import RobotState

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RobotTrack:
    """The robot's replayed trajectory, one sample per tick (``T`` ticks, ``t_k = k dt``).

    position_m: (T, 2); heading_rad: (T,); body: see ``RobotState``. Velocities are central
    differences of the positions (one-sided at the ends).
    """

    position_m: np.ndarray
    heading_rad: np.ndarray
    radius_m: float
    half_length_m: float = 0.0

    def __post_init__(self) -> None:
        p = np.array(self.position_m, dtype=np.float64)
        h = np.array(self.heading_rad, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 1:
            raise ValueError(f"position_m: expected shape (T >= 1, 2), got {p.shape}")
        if h.shape != (len(p),):
            raise ValueError(f"heading_rad: expected shape ({len(p)},), got {h.shape}")
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(h))):
            raise ValueError("robot track: expected finite positions and headings")
        if not (self.radius_m > 0 and self.half_length_m >= 0):
            raise ValueError("robot track: expected radius_m > 0 and half_length_m >= 0")
        object.__setattr__(self, "position_m", p)
        object.__setattr__(self, "heading_rad", h)

    def __len__(self) -> int:
        return len(self.position_m)

    def velocity_mps(self, dt_s: float) -> np.ndarray:
        if len(self.position_m) < 2:
            return np.zeros_like(self.position_m)
        return np.gradient(self.position_m, dt_s, axis=0)

    @staticmethod
    def resample(
        times_s: np.ndarray,
        position_m: np.ndarray,
        heading_rad: np.ndarray,
        dt_s: float,
        n_ticks: int,
        **body,
    ) -> RobotTrack:
        """Sample a timed trajectory (increasing ``times_s (S,)``) at ``t_k = k dt``, ``k < n_ticks``.

        Linear interpolation (headings unwrapped first); before the first / after the last sample
        the robot holds that pose.
        """
        t = np.asarray(times_s, dtype=np.float64)
        if t.ndim != 1 or len(t) < 1 or np.any(np.diff(t) <= 0):
            raise ValueError("times_s: expected a strictly increasing 1D array")
        p = np.asarray(position_m, dtype=np.float64)
        h = np.unwrap(np.asarray(heading_rad, dtype=np.float64))
        tick = np.arange(n_ticks) * dt_s
        xy = np.stack([np.interp(tick, t, p[:, 0]), np.interp(tick, t, p[:, 1])], axis=-1)
        yaw = (np.interp(tick, t, h) + np.pi) % (2.0 * np.pi) - np.pi
        return RobotTrack(xy, yaw, **body)


@dataclass(frozen=True)
class CrowdTrajectory:
    """Per-tick output of ``rollout``: ``T = n_steps + 1`` ticks (the initial state included).

    time_s: (T,). Humans: position_m (T, N, 2), velocity_mps (T, N, 2), heading_rad (T, N),
    behaviour_state (T, N) int8, gait_phase (T, N), goal_index (T, N) int64, plus the constant
    radius_m (N,), behaviour (N,) int8, group_id (N,). Robot (zeros and NaN-free even without a
    robot; ``has_robot`` says): robot_position_m (T, 2), robot_velocity_mps (T, 2),
    robot_heading_rad (T,), robot_radius_m, robot_half_length_m.
    The humans at tick k+1 are the result of stepping tick k against the robot at tick k (they
    react to it), kept out of the robot's body at tick k+1 (``step``'s ``robot_next``).
    """

    time_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    heading_rad: np.ndarray
    behaviour_state: np.ndarray
    gait_phase: np.ndarray
    goal_index: np.ndarray
    radius_m: np.ndarray
    behaviour: np.ndarray
    group_id: np.ndarray
    has_robot: bool
    robot_position_m: np.ndarray
    robot_velocity_mps: np.ndarray
    robot_heading_rad: np.ndarray
    robot_radius_m: float
    robot_half_length_m: float

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays by field name (scalars as 0-d arrays), e.g. for ``np.savez``."""
        return {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}

    @staticmethod
    def from_arrays(arrays) -> CrowdTrajectory:
        """Inverse of ``as_arrays`` (accepts an ``np.load`` result); ``KeyError`` names a missing field."""
        kw = {}
        for f in fields(CrowdTrajectory):
            a = np.asarray(arrays[f.name])
            kw[f.name] = a.item() if a.ndim == 0 else a.copy()
        kw["has_robot"] = bool(kw["has_robot"])
        kw["robot_radius_m"] = float(kw["robot_radius_m"])
        kw["robot_half_length_m"] = float(kw["robot_half_length_m"])
        return CrowdTrajectory(**kw)


def crowd_record(t_count: int, n: int) -> dict[str, np.ndarray]:
    """Empty per-tick arrays of a rollout's crowd, ``(T, N, ...)`` each, keyed by ``CrowdState`` field
    (what a rollout records at every tick: ``arr[k] = getattr(state, name)``)."""
    return {
        "position_m": np.empty((t_count, n, 2)),
        "velocity_mps": np.empty((t_count, n, 2)),
        "heading_rad": np.empty((t_count, n)),
        "behaviour_state": np.empty((t_count, n), np.int8),
        "gait_phase": np.empty((t_count, n)),
        "goal_index": np.empty((t_count, n), np.int64),
    }


def rollout(
    state: CrowdState,
    n_steps: int,
    dt_s: float,
    *,
    walls_m: np.ndarray | None = None,
    robot: RobotTrack | None = None,
    forces: ForceParams | None = None,
    behaviours: BehaviourParams | None = None,
    seed: int = 0,
) -> CrowdTrajectory:
    """Run ``n_steps`` fixed steps from ``state``; same inputs and seed -> identical output.

    walls_m: wall segments (M, 2, 2) (``neighbours.segments_from_polygons``). robot: sampled at
    every tick, ``len(robot) >= n_steps + 1``; the humans at tick k react to the robot at tick k,
    and the humans at tick k + 1 are kept out of the robot's body at tick k + 1.
    forces / behaviours: defaults when None.
    """
    forces = forces if forces is not None else ForceParams()
    behaviours = (behaviours if behaviours is not None else BehaviourParams()).resolved()
    if n_steps < 0:
        raise ValueError(f"n_steps: expected >= 0, got {n_steps}")
    if robot is not None and len(robot) < n_steps + 1:
        raise ValueError(f"robot: {len(robot)} ticks for {n_steps} steps (need n_steps + 1)")
    walls = make_walls(np.zeros((0, 2, 2)) if walls_m is None else walls_m, forces, state.radius_m)
    # only the behaviours someone has: a crowd without curious humans never walks at their speed
    fastest = forces.max_speed_factor * beh.fastest_speed_mps(state.behaviour, state.desired_speed_mps, behaviours)
    if state.n and fastest * dt_s > 0.5 * float(state.radius_m.min()):
        log.warning(
            "dt_s=%g lets humans move %.2f m per tick, more than half their radius: the displacement "
            "clamp will slow them down (use a smaller dt_s)",
            dt_s,
            fastest * dt_s,
        )
    rng = np.random.default_rng(seed)
    t_count = n_steps + 1
    out = crowd_record(t_count, state.n)
    robot_vel = robot.velocity_mps(dt_s) if robot is not None else None
    for k in range(t_count):
        for name, arr in out.items():
            arr[k] = getattr(state, name)
        if k == n_steps:
            break
        robot_k = robot_next = None
        if robot is not None:
            robot_k, robot_next = (
                RobotState(
                    robot.position_m[t],
                    robot_vel[t],
                    float(robot.heading_rad[t]),
                    robot.radius_m,
                    robot.half_length_m,
                )
                for t in (k, k + 1)
            )
        # the humans react to the robot at tick k and end the step clear of it at tick k + 1
        state = step(state, robot_k, walls, forces, behaviours, dt_s, rng, robot_next=robot_next)
    if robot is not None:
        r_pos, r_vel, r_yaw = robot.position_m[:t_count], robot_vel[:t_count], robot.heading_rad[:t_count]
        r_radius, r_half = robot.radius_m, robot.half_length_m
    else:
        r_pos, r_vel, r_yaw, r_radius, r_half = (
            np.zeros((t_count, 2)),
            np.zeros((t_count, 2)),
            np.zeros(t_count),
            0.0,
            0.0,
        )
    return CrowdTrajectory(
        time_s=np.arange(t_count) * dt_s,
        radius_m=state.radius_m.copy(),
        behaviour=state.behaviour.copy(),
        group_id=state.group_id.copy(),
        has_robot=robot is not None,
        robot_position_m=r_pos.copy(),
        robot_velocity_mps=r_vel.copy(),
        robot_heading_rad=r_yaw.copy(),
        robot_radius_m=float(r_radius),
        robot_half_length_m=float(r_half),
        **out,
    )
