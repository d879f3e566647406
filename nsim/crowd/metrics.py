"""Social-navigation metrics of a rollout with a robot: HuNavSim's evaluator, plus nsim's extras.

HuNavSim's metrics follow ``hunav_evaluator/hunav_evaluator/hunav_metrics.py`` and ``sfm.py``
(robotics-upo/hunav_sim, MIT), as that code computes them (where its README says otherwise, the
code wins, and the difference is noted below), over the recorded samples ``k = 0 .. T-1``: every
tick (HuNavSim's ``frequency: 0``, the node's default) or, with ``frequency_hz > 0``, the latest
tick every ``1 / frequency_hz`` seconds from the start (``metrics.yaml`` ships ``frequency: 1.0``;
sums such as the forces and the collision counts grow with the sampling rate). Keys carry the
unit; where the value is a count or a sum over samples the key is HuNavSim's bare name.

The robot is nsim's capsule (``state.RobotState``): where HuNavSim uses the robot's centre and
radius, the robot's "position" towards a person is the nearest point of its body axis to that
person, so a capsule of half length 0 is HuNavSim's disc exactly. A person's "gap" is the distance
between the two bodies: centre distance minus the robot's and the person's radii.

Teaching Robot Navigation Behaviors to Optimal RRT Planners (Pérez-Higueras et al. 2018)
    ``time_to_reach_goal_s``: the time of the first sample within the goal (distance below the
    goal radius, HuNavSim's 0.2 m); a run that never gets there reports its whole duration, as
    HuNavSim's evaluator reports the whole recording. ``path_length_m``;
    ``cumulative_heading_changes_rad``: sum of ``|wrap(h_k - h_k+1)|``.
    ``avg_distance_to_closest_person_m``: mean over samples of the closest person's gap, clamped
    at 0. ``minimum_distance_to_people_m``: the smallest gap of anyone at any sample, clamped at 0.
    ``maximum_distance_to_people_m``: the largest centre-to-robot-surface distance (the code
    subtracts only the robot's radius, the README both).
    ``intimate/personal/social_space_intrusions_pct``: percentage of samples whose closest gap is
    in ``[0, 0.45)``, ``[0.45, 1.2)``, ``[1.2, 3.6)`` m. Without people the distances are inf
    (HuNavSim's code divides by zero or returns its 10000 sentinel) and the intrusions 0.
    ``group_intimate/personal/social_space_intrusions_pct``: the same bands for the distance from
    the robot's surface to the nearest group's interaction centre (no clamp: inside the robot is
    intimate): a group is the people sharing a ``group_id`` other than -1 (nsim's walking groups),
    its centre the mean of the points 1.5 m ahead of each member along its heading. 0 without groups.
SEAN 2.0 (Tsoi et al. 2022)
    ``completed``: the last sample is within the goal radius (None without a goal).
    ``minimum_distance_to_target_m``, ``final_distance_to_target_m``: robot centre to goal.
    ``robot_on_person_collision``, ``person_on_robot_collision``: counts of (sample, person)
    contacts, gap below 0.02 m (the README says 0.01), each blamed by HuNavSim's rule: ``alpha`` is
    the robot's bearing in the person's frame, ``atan2(y, x)``; ``alpha2`` the person's in the
    robot's frame taken as ``atan2(x, y)`` (the code's argument order: the angle from the robot's
    left axis); ``|alpha| < |alpha2|`` blames the robot, ``>`` the person, whichever moves faster,
    and equal angles with equal speeds blame both; equal angles or equal speeds alone blame no one.
    ``time_not_moving_s``: samples with linear speed below 0.01 m/s and angular velocity below
    0.02 rad/s (signed, as the code compares it), times ``duration / T``.
SocNavBench (Biswas et al. 2022)
    ``avg_robot_linear_speed_mps``: mean ``|v|``; ``avg_robot_angular_speed_radps``: mean
    ``|omega|`` (yaw rate, central differences of the heading, like the velocity);
    ``avg_acceleration_mps2``: ``sum_k |dv_k / dt_k| / T`` of the linear speed;
    ``avg_overacceleration_mps3``: ``sum_k |dv_k / dt_k| / dt_k / T`` (HuNavSim's "jerk" is the
    acceleration over the sample period, not the change of acceleration).
Learning a Group-Aware Policy for Robot Navigation (Katyal et al. 2022)
    ``avg_pedestrian_velocity_mps``: mean speed of everyone at every sample;
    ``avg_closest_pedestrian_velocity_mps``: mean speed of the person nearest the robot (by centre
    distance to its body axis, no radii, as the code). NaN without people.
Social force model (``sfm.py``: lightsfm's pair force with its constants: social factor 2.1,
lambda 2, gamma 0.35, n 2, n' 3; obstacle factor 10, sigma 0.2 m)
    ``social_force_on_robot``: sum over samples and people of the modulus of each person's force
    on the robot; ``social_force_on_agents``: of the robot's force on each person;
    ``social_work``: per sample ``|sum of the people's forces on the robot| + |obstacle force on
    the robot| + sum of the moduli of the robot's forces on the people``, summed;
    ``obstacle_force_on_robot``: sum of the modulus of the obstacle force on the robot;
    ``obstacle_force_on_agents``: sum over samples of its mean modulus over the people (NaN
    without people). The obstacle force comes from the closest obstacle point within 10 m (as
    HuNavSim's Gazebo plugin reports one per agent, robotics-upo/hunav_gazebo_wrapper
    ``src/HuNavPlugin.cpp``; here the nearest point of the walls), ``10 exp(-(d - r) / 0.2)``.
    As ``sfm.py`` has it, the pair force's angle is ``atan2(e_y, e_x) - atan2(i_x, i_y)``
    (robotics-upo/lightsfm ``include/sfm.hpp``: ``- atan2(i_y, i_x)``); nsim keeps the evaluator's
    so the numbers match it. A pair at the same point (the evaluator's NaN) contributes nothing.

``crowd_metrics`` gives them for everyone; ``crowd_metrics_breakdown`` also for the people of each
behaviour alone, as HuNavSim's evaluator writes them (``*_beh_<k>.txt``).

nsim's own metrics (not HuNavSim's), under their own names:
    ``path_irregularity_rad_per_m`` (Kirby 2010; Guzzi et al. 2013): total turning of the robot's
    heading minus the turn it needed at the start to face its goal (without a goal: its last
    position), per metre of path. ``social_force_on_robot_integral``,
    ``social_force_on_agents_integral``, ``social_work_integral``: HuNavSim's three force sums
    with this package's own force model (``social_force``; people farther than ``agent_cutoff_m``
    ignored, the wall law for the robot), integrated over time (per-tick value times ``dt``) at
    every tick, so they do not depend on a sampling rate.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from nsim.crowd.behaviours import BEHAVIOUR_NAMES
from nsim.crowd.neighbours import closest_points_on_segments
from nsim.crowd.rollout import CrowdTrajectory
from nsim.crowd.social_force import ForceParams, pair_repulsion

# Thresholds of hunav_evaluator/hunav_metrics.py (indicator_function, get_group_center, collisions,
# time_not_moving) and the goal radius its node gives the robot's goal (hunav_evaluator_node.py).
INTIMATE_M = 0.45
PERSONAL_M = 1.2
SOCIAL_M = 3.6
GROUP_CENTRE_AHEAD_M = 1.5
COLLISION_GAP_M = 0.02
NOT_MOVING_LINEAR_MPS = 0.01
NOT_MOVING_ANGULAR_RADPS = 0.02
GOAL_RADIUS_M = 0.2
OBSTACLE_SEARCH_M = 10.0
"""hunav_gazebo_wrapper's HuNavPlugin reports an agent's closest obstacle only within 10 m."""


@dataclass(frozen=True)
class HunavSfm:
    """The social force constants of ``hunav_evaluator/hunav_evaluator/sfm.py`` (``SFM.__init__``)."""

    social_factor: float = 2.1
    lambda_: float = 2.0
    gamma: float = 0.35
    n: float = 2.0
    n_prime: float = 3.0
    obstacle_factor_mps2: float = 10.0
    obstacle_sigma_m: float = 0.2


HUNAV_SFM = HunavSfm()


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


# ----------------------------------------------------------------------------------------------
# Geometry


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
    """Nearest point of the robot's body axis to each point at each tick: ``(T, N, 2)``.

    human_position_m: (T, N, 2); robot_position_m: (T, 2); robot_heading_rad: (T,).
    """
    t, n = human_position_m.shape[:2]
    axis = _robot_axis(robot_position_m, robot_heading_rad, robot_half_length_m)
    q = closest_points_on_segments(human_position_m.reshape(-1, 2), np.repeat(axis, n, axis=0))
    return q.reshape(t, n, 2)


def _closest_points(traj: CrowdTrajectory) -> np.ndarray:
    return robot_closest_points_m(
        traj.position_m, traj.robot_position_m, traj.robot_heading_rad, traj.robot_half_length_m
    )


def robot_distance_m(traj: CrowdTrajectory) -> np.ndarray:
    """Distance from each human's centre to the robot's surface at each tick: ``(T, N)``."""
    return np.linalg.norm(traj.position_m - _closest_points(traj), axis=-1) - traj.robot_radius_m


def people_gap_m(traj: CrowdTrajectory) -> np.ndarray:
    """Gap between the robot's body and each human's at each tick (negative: overlap): ``(T, N)``.

    HuNavSim's distance to a person: centre distance minus both radii.
    """
    return robot_distance_m(traj) - traj.radius_m[None, :]


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


def group_centres_m(
    position_m: np.ndarray,
    heading_rad: np.ndarray,
    group_id: np.ndarray,
    ahead_m: float = GROUP_CENTRE_AHEAD_M,
) -> np.ndarray:
    """Each group's interaction centre at each tick: ``(T, G, 2)``, groups in increasing id.

    position_m: (T, N, 2); heading_rad: (T, N); group_id: (N,), -1 = alone. The centre is the mean
    of the points ``ahead_m`` in front of each member (HuNavSim's ``get_group_center``).
    """
    ids = np.unique(group_id[group_id != -1])
    ahead = position_m + ahead_m * np.stack([np.cos(heading_rad), np.sin(heading_rad)], axis=-1)
    if len(ids) == 0:
        return np.zeros((len(position_m), 0, 2))
    members = np.flatnonzero(group_id != -1)
    members = members[np.argsort(group_id[members], kind="stable")]  # grouped by id, ids increasing
    starts = np.searchsorted(group_id[members], ids)
    counts = np.diff(np.append(starts, len(members)))
    return np.add.reduceat(ahead[:, members], starts, axis=1) / counts[None, :, None]


def group_distance_m(traj: CrowdTrajectory) -> np.ndarray:
    """Per tick, the distance from the robot's surface to the nearest group centre ``(T,)`` (inf: no group)."""
    centres = group_centres_m(traj.position_m, traj.heading_rad, traj.group_id)
    if centres.shape[1] == 0:
        return np.full(len(traj.time_s), np.inf)
    q = robot_closest_points_m(
        centres, traj.robot_position_m, traj.robot_heading_rad, traj.robot_half_length_m
    )
    return (np.linalg.norm(centres - q, axis=-1) - traj.robot_radius_m).min(axis=1)


def path_length_m(position_m: np.ndarray) -> float:
    """Length of a polyline ``(T, 2)``."""
    return float(np.linalg.norm(np.diff(position_m, axis=0), axis=1).sum())


def time_to_reach_goal_s(
    time_s: np.ndarray, position_m: np.ndarray, goal_m: np.ndarray, goal_radius_m: float = GOAL_RADIUS_M
) -> float:
    """First time ``position_m (T, 2)`` is closer than ``goal_radius_m`` to ``goal_m``; the whole
    duration if never (what HuNavSim reports for a run that does not get there)."""
    hit = np.flatnonzero(np.linalg.norm(position_m - np.asarray(goal_m), axis=1) - goal_radius_m < 0.0)
    return float(time_s[hit[0] if len(hit) else -1] - time_s[0])


def cumulative_heading_changes_rad(heading_rad: np.ndarray) -> float:
    """Sum of the absolute heading changes between ticks (HuNavSim's ``cumulative_heading_changes``)."""
    return float(np.abs(_wrap(np.diff(heading_rad))).sum())


def path_irregularity_rad_per_m(position_m: np.ndarray, heading_rad: np.ndarray, goal_m: np.ndarray) -> float:
    """(Total turning - initial turn needed to face the goal) / path length, rad/m; NaN if it never moved."""
    length = path_length_m(position_m)
    if length <= 0.0:
        return float("nan")
    to_goal = np.asarray(goal_m) - position_m[0]
    needed = abs(float(_wrap(np.arctan2(to_goal[1], to_goal[0]) - heading_rad[0])))
    return max(cumulative_heading_changes_rad(heading_rad) - needed, 0.0) / length


# ----------------------------------------------------------------------------------------------
# Motion


def robot_angular_velocity_radps(time_s: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
    """Yaw rate ``(T,)``: central differences of the unwrapped heading (one-sided at the ends)."""
    if len(time_s) < 2:
        return np.zeros(len(time_s))
    return np.gradient(np.unwrap(heading_rad), time_s)


def avg_acceleration(time_s: np.ndarray, speed_mps: np.ndarray) -> tuple[float, float]:
    """HuNavSim's ``avg_acceleration`` (m/s²) and ``avg_overacceleration`` (m/s³) of a speed ``(T,)``.

    ``sum_k |dv_k / dt_k| / T`` and ``sum_k |dv_k / dt_k / dt_k| / T`` (steps with ``dt = 0`` add 0).
    """
    if len(time_s) == 0:
        return 0.0, 0.0
    dt = np.diff(time_s)
    ok = dt != 0.0
    acc = np.diff(speed_mps)[ok] / dt[ok]
    return float(np.abs(acc).sum() / len(time_s)), float(np.abs(acc / dt[ok]).sum() / len(time_s))


def collisions(
    traj: CrowdTrajectory, axis_points_m: np.ndarray | None = None, gap_m: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """HuNavSim's blame of each contact: ``robot_on_person (T, N)``, ``person_on_robot (T, N)`` bool.

    axis_points_m: the robot axis points nearest the humans ``(T, N, 2)``; gap_m: ``people_gap_m``
    (both computed when None). See the module docstring for the rule.
    """
    q = _closest_points(traj) if axis_points_m is None else axis_points_m
    gap = people_gap_m(traj) if gap_m is None else gap_m
    contact = gap < COLLISION_GAP_M
    h = traj.heading_rad
    rel = q - traj.position_m  # the robot seen from the person, world axes
    x = rel[..., 0] * np.cos(h) + rel[..., 1] * np.sin(h)  # ... in the person's frame
    y = -rel[..., 0] * np.sin(h) + rel[..., 1] * np.cos(h)
    alpha = np.arctan2(y, x)
    c, s = np.cos(traj.robot_heading_rad)[:, None], np.sin(traj.robot_heading_rad)[:, None]
    x2 = -rel[..., 0] * c - rel[..., 1] * s  # the person in the robot's frame
    y2 = rel[..., 0] * s - rel[..., 1] * c
    alpha2 = np.arctan2(x2, y2)  # sic: hunav_metrics.collisions takes atan2(x, y) here
    a, a2 = np.abs(alpha), np.abs(alpha2)
    v_robot = np.linalg.norm(traj.robot_velocity_mps, axis=-1)[:, None]
    v_person = np.linalg.norm(traj.velocity_mps, axis=-1)
    differ = v_robot != v_person
    both = (a == a2) & ~differ
    return contact & (((a < a2) & differ) | both), contact & (((a > a2) & differ) | both)


# ----------------------------------------------------------------------------------------------
# HuNavSim's social force model (hunav_evaluator/hunav_evaluator/sfm.py)


def hunav_pair_force(
    source_m: np.ndarray,
    source_velocity_mps: np.ndarray,
    target_m: np.ndarray,
    target_velocity_mps: np.ndarray,
    sfm: HunavSfm = HUNAV_SFM,
) -> np.ndarray:
    """The social force that an agent at ``source_m`` exerts on one at ``target_m``: ``(..., 2)``.

    All inputs ``(..., 2)``. ``SFM.computeSocialForceTwoAgents``: with ``e`` the unit vector from
    the target to the source, ``i`` the unit interaction vector ``lambda (v_target - v_source) + e``
    of length ``L``, ``theta = atan2(e_y, e_x) - atan2(i_x, i_y)`` brought into ``[-pi, pi]`` and
    ``B = gamma L``: ``F (-exp(-d/B - (n' B theta)^2) i - sign(theta) exp(-d/B - (n B theta)^2) i_left)``.
    Zero where the two agents are at the same point or ``L`` is 0 (undefined there).
    """
    diff = np.asarray(source_m, dtype=np.float64) - np.asarray(target_m, dtype=np.float64)
    dist = np.linalg.norm(diff, axis=-1)
    ok = dist > 0.0
    e = diff / np.where(ok, dist, 1.0)[..., None]
    inter = sfm.lambda_ * (np.asarray(target_velocity_mps) - np.asarray(source_velocity_mps)) + e
    length = np.linalg.norm(inter, axis=-1)
    ok &= length > 0.0
    i = inter / np.where(ok, length, 1.0)[..., None]
    theta = np.arctan2(e[..., 1], e[..., 0]) - np.arctan2(i[..., 0], i[..., 1])
    theta = np.where(theta > np.pi, theta - 2.0 * np.pi, np.where(theta < -np.pi, theta + 2.0 * np.pi, theta))
    b = np.where(ok, sfm.gamma * length, 1.0)
    along = -np.exp(-dist / b - (sfm.n_prime * b * theta) ** 2)
    across = -np.sign(theta) * np.exp(-dist / b - (sfm.n * b * theta) ** 2)
    left = np.stack([-i[..., 1], i[..., 0]], axis=-1)
    force = sfm.social_factor * (along[..., None] * i + across[..., None] * left)
    return np.where(ok[..., None], force, 0.0)


def hunav_obstacle_force_modulus(distance_m: np.ndarray, radius_m, sfm: HunavSfm = HUNAV_SFM) -> np.ndarray:
    """``|SFM.computeObstacleForce|`` for one closest obstacle at ``distance_m`` (inf: none): ``factor exp(-(d - r) / sigma)``."""
    d = np.asarray(distance_m, dtype=np.float64)
    with np.errstate(over="ignore"):
        f = sfm.obstacle_factor_mps2 * np.exp(-(d - radius_m) / sfm.obstacle_sigma_m)
    return np.where(d <= OBSTACLE_SEARCH_M, f, 0.0)


def nearest_wall_distance_m(
    points_m: np.ndarray, walls_m: np.ndarray, reach_m: float = OBSTACLE_SEARCH_M
) -> np.ndarray:
    """Distance from each point ``(P, 2)`` to the nearest wall segment ``(M, 2, 2)``; inf beyond ``reach_m``.

    Every point against every segment (``P x M``, in blocks): with a 10 m reach a room's segment
    grid lists nearly every segment for every point, and its candidate lists cost more than this.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    walls = np.asarray(walls_m, dtype=np.float64).reshape(-1, 2, 2)
    out = np.full(len(p), np.inf)
    if len(p) == 0 or len(walls) == 0:
        return out
    ax, ay = walls[:, 0, 0], walls[:, 0, 1]
    abx, aby = walls[:, 1, 0] - ax, walls[:, 1, 1] - ay
    inv_len2 = 1.0 / np.maximum(abx * abx + aby * aby, 1e-300)
    block = max(1, (1 << 19) // len(walls))
    for s in range(0, len(p), block):
        dx = p[s : s + block, 0:1] - ax  # (B, M): from each segment's start to each point
        dy = p[s : s + block, 1:2] - ay
        t = dx * abx
        t += dy * aby
        t *= inv_len2
        np.clip(t, 0.0, 1.0, out=t)
        dx -= t * abx
        dy -= t * aby
        dx *= dx
        dy *= dy
        dx += dy
        out[s : s + block] = np.sqrt(dx.min(axis=1))
    out[out > reach_m] = np.inf
    return out


def _robot_wall_contacts(traj: CrowdTrajectory, walls_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per tick and wall, the distance between the robot's body axis and the wall ``(T, M)`` and the
    unit vector from the wall to the axis ``(T, M, 2)``."""
    t, m = len(traj.time_s), len(walls_m)
    if m == 0:
        return np.full((t, 0), np.inf), np.zeros((t, 0, 2))
    axis = _robot_axis(traj.robot_position_m, traj.robot_heading_rad, traj.robot_half_length_m)  # (T, 2, 2)
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
    return best_d, best_n


# ----------------------------------------------------------------------------------------------
# nsim's force-model sums


def robot_pair_forces(traj: CrowdTrajectory, forces: ForceParams) -> tuple[np.ndarray, np.ndarray]:
    """nsim's force model between the robot and each human: on the robot ``(T, N, 2)``, on the
    humans ``(T, N, 2)``; zero for humans farther than ``agent_cutoff_m`` from the robot's body
    axis, as in the simulation."""
    t, n = traj.position_m.shape[:2]
    q = _closest_points(traj)
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
    return on_robot, on_humans


def _force_sums(on_robot: np.ndarray, on_humans: np.ndarray, wall: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per tick: sum of the moduli on the robot, on the humans, and the social work (see the module docstring)."""
    on_humans_mod = np.linalg.norm(on_humans, axis=-1).sum(axis=1)
    work = np.linalg.norm(on_robot.sum(axis=1), axis=-1) + np.linalg.norm(wall, axis=-1) + on_humans_mod
    return np.linalg.norm(on_robot, axis=-1).sum(axis=1), on_humans_mod, work


def robot_social_forces(
    traj: CrowdTrajectory, walls_m: np.ndarray, forces: ForceParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per tick ``(T,)``, with nsim's force model: social force on the robot, on the humans, and
    the social work (m/s²).

    See the module docstring and ``robot_pair_forces``. The wall force on the robot uses the wall
    law at the nearest points between its body axis and each wall segment within ``obstacle_cutoff_m``.
    """
    wall = _wall_force_on_robot(traj, np.asarray(walls_m, dtype=np.float64).reshape(-1, 2, 2), forces)
    return _force_sums(*robot_pair_forces(traj, forces), wall)


def _wall_force_on_robot(traj: CrowdTrajectory, walls_m: np.ndarray, forces: ForceParams) -> np.ndarray:
    """Wall-law force on the robot's body at each tick: ``(T, 2)``."""
    if len(walls_m) == 0:
        return np.zeros((len(traj.time_s), 2))
    best_d, best_n = _robot_wall_contacts(traj, walls_m)
    mag = forces.obstacle_strength_mps2 * np.exp((traj.robot_radius_m - best_d) / forces.obstacle_range_m)
    mag = np.where(best_d < forces.obstacle_cutoff_m + traj.robot_radius_m, mag, 0.0)
    return (mag[..., None] * best_n).sum(axis=1)


# ----------------------------------------------------------------------------------------------
# All of them


@dataclass(frozen=True)
class CrowdMetrics:
    """The metrics of one rollout (definitions in the module docstring): HuNavSim's, then nsim's."""

    time_to_reach_goal_s: float
    path_length_m: float
    cumulative_heading_changes_rad: float
    avg_distance_to_closest_person_m: float
    minimum_distance_to_people_m: float
    maximum_distance_to_people_m: float
    intimate_space_intrusions_pct: float
    personal_space_intrusions_pct: float
    social_space_intrusions_pct: float
    group_intimate_space_intrusions_pct: float
    group_personal_space_intrusions_pct: float
    group_social_space_intrusions_pct: float
    completed: bool | None
    minimum_distance_to_target_m: float
    final_distance_to_target_m: float
    robot_on_person_collision: int
    person_on_robot_collision: int
    time_not_moving_s: float
    avg_robot_linear_speed_mps: float
    avg_robot_angular_speed_radps: float
    avg_acceleration_mps2: float
    avg_overacceleration_mps3: float
    avg_pedestrian_velocity_mps: float
    avg_closest_pedestrian_velocity_mps: float
    social_force_on_agents: float
    social_force_on_robot: float
    social_work: float
    obstacle_force_on_robot: float
    obstacle_force_on_agents: float
    # nsim's own
    path_irregularity_rad_per_m: float
    social_force_on_robot_integral: float
    social_force_on_agents_integral: float
    social_work_integral: float

    def as_dict(self) -> dict[str, float | int | bool | None]:
        return asdict(self)


def record_ticks(time_s: np.ndarray, frequency_hz: float) -> np.ndarray:
    """The ticks HuNavSim's evaluator would record: all (``frequency_hz == 0``) or, every
    ``1 / frequency_hz`` seconds from the first tick, the latest tick at that time."""
    if frequency_hz == 0.0:
        return np.arange(len(time_s))
    if not (frequency_hz > 0.0 and math.isfinite(frequency_hz)):
        raise ValueError(f"frequency_hz: expected a finite value >= 0, got {frequency_hz!r}")
    period = 1.0 / frequency_hz
    samples = time_s[0] + period * np.arange(int(math.floor((time_s[-1] - time_s[0]) / period + 1e-9)) + 1)
    return np.unique(np.searchsorted(time_s, samples + 1e-9 * period, side="right") - 1)


def _take_ticks(traj: CrowdTrajectory, ticks: np.ndarray) -> CrowdTrajectory:
    per_tick = (
        "time_s", "position_m", "velocity_mps", "heading_rad", "behaviour_state", "gait_phase",
        "goal_index", "robot_position_m", "robot_velocity_mps", "robot_heading_rad",
    )  # fmt: skip
    return replace(traj, **{name: getattr(traj, name)[ticks] for name in per_tick})


@dataclass(frozen=True)
class _Terms:
    """What the metrics add up, computed once for everyone: per recorded sample ``(T,)`` for the
    robot, per sample and person ``(T, N)`` for the people; ``full_*``: nsim's sums at every tick."""

    traj: CrowdTrajectory  # the recorded samples
    goal_m: np.ndarray | None
    goal_radius_m: float
    omega_radps: np.ndarray
    obstacle_robot: np.ndarray
    to_axis_m: np.ndarray
    robot_hits: np.ndarray
    person_hits: np.ndarray
    on_robot: np.ndarray  # (T, N, 2) HuNavSim's SFM, each person on the robot
    on_people_mod: np.ndarray  # (T, N) |HuNavSim's SFM, the robot on each person|
    obstacle_people: np.ndarray
    dt_s: float
    full_on_robot: np.ndarray  # (T_full, N, 2) nsim's force model
    full_on_humans: np.ndarray
    full_wall: np.ndarray  # (T_full, 2)
    path_irregularity_rad_per_m: float


def _terms(
    traj: CrowdTrajectory,
    *,
    walls_m: np.ndarray | None = None,
    forces: ForceParams | None = None,
    robot_goal_m: np.ndarray | None = None,
    goal_radius_m: float = GOAL_RADIUS_M,
    frequency_hz: float = 0.0,
) -> _Terms:
    if not traj.has_robot:
        raise ValueError("crowd_metrics: the trajectory has no robot")
    if len(traj.time_s) == 0:
        raise ValueError("crowd_metrics: the trajectory has no ticks")
    forces = forces if forces is not None else ForceParams()
    walls = (
        np.zeros((0, 2, 2)) if walls_m is None else np.asarray(walls_m, dtype=np.float64).reshape(-1, 2, 2)
    )
    goal = None if robot_goal_m is None else np.asarray(robot_goal_m, dtype=np.float64).reshape(2)
    ticks = record_ticks(traj.time_s, frequency_hz)
    rec = _take_ticks(traj, ticks)
    t_count, n = rec.position_m.shape[:2]
    q = _closest_points(rec)
    to_axis = np.linalg.norm(rec.position_m - q, axis=-1)
    robot_hits, person_hits = collisions(rec, q, to_axis - rec.robot_radius_m - rec.radius_m[None, :])
    robot_vel = np.broadcast_to(rec.robot_velocity_mps[:, None, :], (t_count, n, 2))
    robot_wall = _robot_wall_contacts(rec, walls)[0].min(axis=1, initial=np.inf)
    people_wall = nearest_wall_distance_m(rec.position_m.reshape(-1, 2), walls).reshape(t_count, n)
    full_on_robot, full_on_humans = robot_pair_forces(traj, forces)
    return _Terms(
        traj=rec,
        goal_m=goal,
        goal_radius_m=goal_radius_m,
        omega_radps=robot_angular_velocity_radps(traj.time_s, traj.robot_heading_rad)[ticks],
        obstacle_robot=hunav_obstacle_force_modulus(robot_wall, rec.robot_radius_m),
        to_axis_m=to_axis,
        robot_hits=robot_hits,
        person_hits=person_hits,
        on_robot=hunav_pair_force(rec.position_m, rec.velocity_mps, q, robot_vel),
        on_people_mod=np.linalg.norm(
            hunav_pair_force(q, robot_vel, rec.position_m, rec.velocity_mps), axis=-1
        ),
        obstacle_people=hunav_obstacle_force_modulus(people_wall, rec.radius_m[None, :]),
        dt_s=float(traj.time_s[1] - traj.time_s[0]) if len(traj.time_s) > 1 else 0.0,
        full_on_robot=full_on_robot,
        full_on_humans=full_on_humans,
        full_wall=_wall_force_on_robot(traj, walls, forces),
        path_irregularity_rad_per_m=path_irregularity_rad_per_m(
            traj.robot_position_m, traj.robot_heading_rad, traj.robot_position_m[-1] if goal is None else goal
        ),
    )


def _metrics(terms: _Terms, keep: np.ndarray) -> CrowdMetrics:
    """Add the terms up over the people ``keep (N,)`` (bool)."""
    tr = terms.traj
    people = _take_humans(tr, keep)
    t_count, n = people.position_m.shape[:2]
    duration = float(tr.time_s[-1] - tr.time_s[0])
    to_axis = terms.to_axis_m[:, keep]
    closest = np.maximum(
        closest_person_distance_m(to_axis - tr.robot_radius_m - people.radius_m[None, :]), 0.0
    )
    group = group_distance_m(people)
    speed = np.linalg.norm(tr.robot_velocity_mps, axis=-1)
    acc, over_acc = avg_acceleration(tr.time_s, speed)
    still = (speed < NOT_MOVING_LINEAR_MPS) & (terms.omega_radps < NOT_MOVING_ANGULAR_RADPS)
    ped_speed = np.linalg.norm(people.velocity_mps, axis=-1)  # (T, N)
    on_robot, on_people_mod = terms.on_robot[:, keep], terms.on_people_mod[:, keep].sum(axis=1)
    goal = terms.goal_m
    if goal is not None:
        to_goal = np.linalg.norm(tr.robot_position_m - goal, axis=1)
        reached_goal = time_to_reach_goal_s(tr.time_s, tr.robot_position_m, goal, terms.goal_radius_m)
        completed = bool(to_goal[-1] - terms.goal_radius_m < 0.0)
        min_goal, final_goal = float(to_goal.min()), float(to_goal[-1])
    else:
        reached_goal, completed, min_goal, final_goal = math.nan, None, math.nan, math.nan
    nsim_on_robot, nsim_on_humans, nsim_work = _force_sums(
        terms.full_on_robot[:, keep], terms.full_on_humans[:, keep], terms.full_wall
    )
    return CrowdMetrics(
        time_to_reach_goal_s=reached_goal,
        path_length_m=path_length_m(tr.robot_position_m),
        cumulative_heading_changes_rad=cumulative_heading_changes_rad(tr.robot_heading_rad),
        avg_distance_to_closest_person_m=float(closest.mean()) if n else math.inf,
        minimum_distance_to_people_m=float(closest.min()) if n else math.inf,
        maximum_distance_to_people_m=float((to_axis - tr.robot_radius_m).max()) if n else math.inf,
        intimate_space_intrusions_pct=space_intrusions_pct(closest, 0.0, INTIMATE_M),
        personal_space_intrusions_pct=space_intrusions_pct(closest, INTIMATE_M, PERSONAL_M),
        social_space_intrusions_pct=space_intrusions_pct(closest, PERSONAL_M, SOCIAL_M),
        group_intimate_space_intrusions_pct=space_intrusions_pct(group, -math.inf, INTIMATE_M),
        group_personal_space_intrusions_pct=space_intrusions_pct(group, INTIMATE_M, PERSONAL_M),
        group_social_space_intrusions_pct=space_intrusions_pct(group, PERSONAL_M, SOCIAL_M),
        completed=completed,
        minimum_distance_to_target_m=min_goal,
        final_distance_to_target_m=final_goal,
        robot_on_person_collision=int(terms.robot_hits[:, keep].sum()),
        person_on_robot_collision=int(terms.person_hits[:, keep].sum()),
        time_not_moving_s=duration / t_count * int(still.sum()),
        avg_robot_linear_speed_mps=float(speed.mean()),
        avg_robot_angular_speed_radps=float(np.abs(terms.omega_radps).mean()),
        avg_acceleration_mps2=acc,
        avg_overacceleration_mps3=over_acc,
        avg_pedestrian_velocity_mps=float(ped_speed.mean()) if n else math.nan,
        avg_closest_pedestrian_velocity_mps=(
            float(np.take_along_axis(ped_speed, to_axis.argmin(axis=1)[:, None], axis=1).mean())
            if n
            else math.nan
        ),
        social_force_on_agents=float(on_people_mod.sum()),
        social_force_on_robot=float(np.linalg.norm(on_robot, axis=-1).sum()),
        social_work=float(
            (np.linalg.norm(on_robot.sum(axis=1), axis=-1) + terms.obstacle_robot + on_people_mod).sum()
        ),
        obstacle_force_on_robot=float(terms.obstacle_robot.sum()),
        obstacle_force_on_agents=float(terms.obstacle_people[:, keep].mean(axis=1).sum()) if n else math.nan,
        path_irregularity_rad_per_m=terms.path_irregularity_rad_per_m,
        social_force_on_robot_integral=float(nsim_on_robot.sum() * terms.dt_s),
        social_force_on_agents_integral=float(nsim_on_humans.sum() * terms.dt_s),
        social_work_integral=float(nsim_work.sum() * terms.dt_s),
    )


def _take_humans(traj: CrowdTrajectory, keep: np.ndarray) -> CrowdTrajectory:
    per_tick = ("position_m", "velocity_mps", "heading_rad", "behaviour_state", "gait_phase", "goal_index")
    per_human = ("radius_m", "behaviour", "group_id")
    return replace(
        traj,
        **{name: getattr(traj, name)[:, keep] for name in per_tick},
        **{name: getattr(traj, name)[keep] for name in per_human},
    )


def crowd_metrics(
    traj: CrowdTrajectory,
    *,
    walls_m: np.ndarray | None = None,
    forces: ForceParams | None = None,
    robot_goal_m: np.ndarray | None = None,
    goal_radius_m: float = GOAL_RADIUS_M,
    frequency_hz: float = 0.0,
) -> CrowdMetrics:
    """All metrics of a rollout with a robot.

    robot_goal_m: (2,) where the robot was sent (the scenario's last waypoint); None: it has no
    goal (a looping robot), and the goal metrics are NaN / None. goal_radius_m: HuNavSim's 0.2 m.
    frequency_hz: HuNavSim's recording rate (0: every tick). forces: nsim's force model, for its
    ``*_integral`` sums.
    """
    terms = _terms(
        traj,
        walls_m=walls_m,
        forces=forces,
        robot_goal_m=robot_goal_m,
        goal_radius_m=goal_radius_m,
        frequency_hz=frequency_hz,
    )
    return _metrics(terms, np.ones(traj.position_m.shape[1], dtype=bool))


def crowd_metrics_breakdown(traj: CrowdTrajectory, **kwargs) -> tuple[CrowdMetrics, dict[str, CrowdMetrics]]:
    """The metrics of everyone and, as HuNavSim's evaluator also writes them, those with only the
    people of one behaviour, for each behaviour someone has (behaviour name -> ``CrowdMetrics``, in
    code order), from one pass over the trajectory. kwargs: as ``crowd_metrics``. A behaviour's
    groups are formed by its own people only, as there; the robot's own metrics are the same in all.
    """
    terms = _terms(traj, **kwargs)
    everyone = _metrics(terms, np.ones(traj.position_m.shape[1], dtype=bool))
    return everyone, {
        name: _metrics(terms, traj.behaviour == code)
        for code, name in enumerate(BEHAVIOUR_NAMES, start=1)
        if np.any(traj.behaviour == code)
    }
