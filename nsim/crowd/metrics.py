"""Social-navigation metrics as HuNavSim's evaluator reports them, from per-tick arrays.

Distances follow ``hunav_evaluator/hunav_metrics.py``: "distance to people" is from the human's
centre to the robot's *surface* (HuNavSim: centre distance minus the robot's radius; here the
robot is a capsule, see ``state.RobotState``); the closest-person average also subtracts
the human's radius. Space intrusions are the percentage of ticks whose closest person is in the
band: intimate ``[0, 0.45)`` (and anything closer), personal ``[0.45, 1.2)``, social
``[1.2, 3.6)`` metres. Forces use this package's own force model (``social_force``), as HuNavSim
uses its SFM: per tick, the social force on the robot (sum of the moduli of the humans' forces on
it), on the humans (sum of the moduli of the robot's forces on them), and the social work
``|sum of the humans' forces on the robot| + |wall force on the robot| + sum of the moduli of the
robot's forces on the humans``. Where HuNavSim adds these per message (so totals depend on the
message rate), ``*_integral`` here is the time integral (per-tick value times ``dt``).

Path irregularity (Kirby 2010; Guzzi et al. 2013): total turning of the robot's heading minus the
turn it needed at the start to face its goal, per metre of path, rad/m.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from nsim.crowd.neighbours import closest_points_on_segments
from nsim.crowd.social_force import CrowdTrajectory, ForceParams, pair_repulsion

INTIMATE_M = 0.45
PERSONAL_M = 1.2
SOCIAL_M = 3.6


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _robot_axis(position_m: np.ndarray, heading_rad: np.ndarray, half_length_m: float) -> np.ndarray:
    """Body axis end points ``(T, 2, 2)`` of the robot at every tick."""
    u = np.stack([np.cos(heading_rad), np.sin(heading_rad)], axis=-1) * half_length_m
    return np.stack([position_m - u, position_m + u], axis=1)


def robot_closest_points_m(
    human_position_m: np.ndarray,
    robot_position_m: np.ndarray,
    robot_heading_rad: np.ndarray,
    robot_half_length_m: float,
) -> np.ndarray:
    """Nearest point of the robot's body axis to each human at each tick: ``(T, N, 2)``.

    human_position_m: (T, N, 2); robot_position_m: (T, 2); robot_heading_rad: (T,).
    """
    t, n = human_position_m.shape[:2]
    axis = _robot_axis(robot_position_m, robot_heading_rad, robot_half_length_m)
    q = closest_points_on_segments(human_position_m.reshape(-1, 2), np.repeat(axis, n, axis=0))
    return q.reshape(t, n, 2)


def robot_distance_m(traj: CrowdTrajectory) -> np.ndarray:
    """Distance from each human's centre to the robot's surface at each tick: ``(T, N)``."""
    q = robot_closest_points_m(
        traj.position_m, traj.robot_position_m, traj.robot_heading_rad, traj.robot_half_length_m
    )
    return np.linalg.norm(traj.position_m - q, axis=-1) - traj.robot_radius_m


def closest_person_distance_m(distance_m: np.ndarray) -> np.ndarray:
    """Per tick, the distance of the closest person ``(T,)`` (``inf`` with no humans)."""
    return distance_m.min(axis=1, initial=np.inf)


def space_intrusions_pct(closest_m: np.ndarray, lower_m: float, upper_m: float) -> float:
    """Percentage of ticks whose closest person is in ``[lower_m, upper_m)``.

    With ``lower_m <= 0`` anything closer than ``upper_m`` counts (overlaps included).
    """
    if len(closest_m) == 0:
        return 0.0
    inside = (closest_m < upper_m) & ((closest_m >= lower_m) | (lower_m <= 0.0))
    return 100.0 * float(np.mean(inside))


def path_length_m(position_m: np.ndarray) -> float:
    """Length of a polyline ``(T, 2)``."""
    return float(np.linalg.norm(np.diff(position_m, axis=0), axis=1).sum())


def time_to_goal_s(
    time_s: np.ndarray, position_m: np.ndarray, goal_m: np.ndarray, goal_radius_m: float
) -> float:
    """First time ``position_m (T, 2)`` comes within ``goal_radius_m`` of ``goal_m``; NaN if never."""
    hit = np.flatnonzero(np.linalg.norm(position_m - np.asarray(goal_m), axis=1) <= goal_radius_m)
    return float(time_s[hit[0]] - time_s[0]) if len(hit) else float("nan")


def cumulative_heading_change_rad(heading_rad: np.ndarray) -> float:
    """Sum of the absolute heading changes between ticks (HuNavSim's ``cumulative_heading_changes``)."""
    return float(np.abs(_wrap(np.diff(heading_rad))).sum())


def path_irregularity_rad_per_m(position_m: np.ndarray, heading_rad: np.ndarray, goal_m: np.ndarray) -> float:
    """(Total turning - initial turn needed to face the goal) / path length, rad/m; NaN if it never moved."""
    length = path_length_m(position_m)
    if length <= 0.0:
        return float("nan")
    to_goal = np.asarray(goal_m) - position_m[0]
    needed = abs(float(_wrap(np.arctan2(to_goal[1], to_goal[0]) - heading_rad[0])))
    return max(cumulative_heading_change_rad(heading_rad) - needed, 0.0) / length


def robot_social_forces(
    traj: CrowdTrajectory, walls_m: np.ndarray, forces: ForceParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per tick ``(T,)``: social force on the robot, on the humans, and the social work (m/s²).

    See the module docstring; humans farther than ``agent_cutoff_m`` from the robot's body axis
    do not count, as in the simulation. The wall force on the robot uses the wall law at the
    nearest points between its body axis and each wall segment within ``obstacle_cutoff_m``.
    """
    t, n = traj.position_m.shape[:2]
    q = robot_closest_points_m(
        traj.position_m, traj.robot_position_m, traj.robot_heading_rad, traj.robot_half_length_m
    )
    offset = traj.position_m - q  # robot -> human
    near = np.linalg.norm(offset, axis=-1) < forces.agent_cutoff_m
    robot_vel = np.broadcast_to(traj.robot_velocity_mps[:, None, :], (t, n, 2))
    radius_sum = np.broadcast_to(traj.radius_m[None, :] + traj.robot_radius_m, (t, n))
    robot_dir = np.stack([np.cos(traj.robot_heading_rad), np.sin(traj.robot_heading_rad)], -1)
    human_dir = np.stack([np.cos(traj.heading_rad), np.sin(traj.heading_rad)], -1)

    def forces_on(offset_m, step_m, heading_unit):
        f = pair_repulsion(
            offset_m.reshape(-1, 2),
            step_m.reshape(-1, 2),
            radius_sum.reshape(-1),
            heading_unit.reshape(-1, 2),
            forces,
        ).reshape(t, n, 2)
        return np.where(near[..., None], f, 0.0)

    on_robot = forces_on(
        -offset,
        (traj.velocity_mps - robot_vel) * forces.agent_lookahead_s,
        np.broadcast_to(robot_dir[:, None, :], (t, n, 2)),
    )
    on_humans = forces_on(offset, (robot_vel - traj.velocity_mps) * forces.agent_lookahead_s, human_dir)
    on_robot_mod = np.linalg.norm(on_robot, axis=-1).sum(axis=1)
    on_humans_mod = np.linalg.norm(on_humans, axis=-1).sum(axis=1)
    wall = _wall_force_on_robot(traj, np.asarray(walls_m, dtype=np.float64).reshape(-1, 2, 2), forces)
    work = np.linalg.norm(on_robot.sum(axis=1), axis=-1) + np.linalg.norm(wall, axis=-1) + on_humans_mod
    return on_robot_mod, on_humans_mod, work


def _wall_force_on_robot(traj: CrowdTrajectory, walls_m: np.ndarray, forces: ForceParams) -> np.ndarray:
    """Wall-law force on the robot's body at each tick: ``(T, 2)``."""
    t = len(traj.time_s)
    if len(walls_m) == 0:
        return np.zeros((t, 2))
    axis = _robot_axis(traj.robot_position_m, traj.robot_heading_rad, traj.robot_half_length_m)  # (T, 2, 2)
    m = len(walls_m)
    # 2D segments that do not cross are closest at an end point of one of them: try all four
    best_d = np.full((t, m), np.inf)
    best_n = np.zeros((t, m, 2))
    walls = np.broadcast_to(walls_m[None], (t, m, 2, 2)).reshape(-1, 2, 2)
    for e in range(2):
        p = np.repeat(axis[:, e], m, axis=0)  # robot end point vs wall segment
        qw = closest_points_on_segments(p, walls)
        cand = [(p - qw)]
        wp = walls_m[:, e]  # wall end point vs robot axis
        qa = closest_points_on_segments(np.tile(wp, (t, 1)), np.repeat(axis, m, axis=0))
        cand.append(qa - np.tile(wp, (t, 1)))
        for diff in cand:
            diff = diff.reshape(t, m, 2)
            d = np.linalg.norm(diff, axis=-1)
            better = d < best_d
            best_d = np.where(better, d, best_d)
            best_n = np.where(better[..., None], diff / np.maximum(d, 1e-12)[..., None], best_n)
    mag = forces.obstacle_strength_mps2 * np.exp((traj.robot_radius_m - best_d) / forces.obstacle_range_m)
    mag = np.where(best_d < forces.obstacle_cutoff_m + traj.robot_radius_m, mag, 0.0)
    return (mag[..., None] * best_n).sum(axis=1)


@dataclass(frozen=True)
class CrowdMetrics:
    """HuNavSim-style metrics of one rollout (see the module docstring for definitions)."""

    time_to_goal_s: float
    path_length_m: float
    cumulative_heading_change_rad: float
    path_irregularity_rad_per_m: float
    minimum_distance_to_people_m: float
    maximum_distance_to_people_m: float
    avg_distance_to_closest_person_m: float
    intimate_space_intrusions_pct: float
    personal_space_intrusions_pct: float
    social_space_intrusions_pct: float
    social_force_on_robot_integral: float
    social_force_on_agents_integral: float
    social_work_integral: float
    avg_pedestrian_speed_mps: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def crowd_metrics(
    traj: CrowdTrajectory,
    *,
    walls_m: np.ndarray | None = None,
    forces: ForceParams | None = None,
    robot_goal_m: np.ndarray | None = None,
    goal_radius_m: float = 0.3,
) -> CrowdMetrics:
    """All metrics of a rollout with a robot. robot_goal_m defaults to the robot's last position."""
    if not traj.has_robot:
        raise ValueError("crowd_metrics: the trajectory has no robot")
    forces = forces if forces is not None else ForceParams()
    walls = np.zeros((0, 2, 2)) if walls_m is None else walls_m
    goal = traj.robot_position_m[-1] if robot_goal_m is None else np.asarray(robot_goal_m, dtype=np.float64)
    dist = robot_distance_m(traj)
    closest = closest_person_distance_m(dist)
    surface = closest_person_distance_m(dist - traj.radius_m[None, :])
    dt = float(traj.time_s[1] - traj.time_s[0]) if len(traj.time_s) > 1 else 0.0
    on_robot, on_humans, work = robot_social_forces(traj, walls, forces)
    n = dist.shape[1]
    return CrowdMetrics(
        time_to_goal_s=time_to_goal_s(traj.time_s, traj.robot_position_m, goal, goal_radius_m),
        path_length_m=path_length_m(traj.robot_position_m),
        cumulative_heading_change_rad=cumulative_heading_change_rad(traj.robot_heading_rad),
        path_irregularity_rad_per_m=path_irregularity_rad_per_m(
            traj.robot_position_m, traj.robot_heading_rad, goal
        ),
        minimum_distance_to_people_m=float(dist.min()) if n else float("inf"),
        maximum_distance_to_people_m=float(dist.max()) if n else float("inf"),
        avg_distance_to_closest_person_m=float(surface.mean()) if n else float("inf"),
        intimate_space_intrusions_pct=space_intrusions_pct(closest, 0.0, INTIMATE_M),
        personal_space_intrusions_pct=space_intrusions_pct(closest, INTIMATE_M, PERSONAL_M),
        social_space_intrusions_pct=space_intrusions_pct(closest, PERSONAL_M, SOCIAL_M),
        social_force_on_robot_integral=float(on_robot.sum() * dt),
        social_force_on_agents_integral=float(on_humans.sum() * dt),
        social_work_integral=float(work.sum() * dt),
        avg_pedestrian_speed_mps=float(np.linalg.norm(traj.velocity_mps, axis=-1).mean()) if n else 0.0,
    )
