"""A scenario rolled out: the crowd's initial state, the simulation loop's driver, extra people for sweeps.

``simulate(sc, forces, behaviours, dt_s, duration_s, seed)`` turns a resolved
:class:`~nsim.crowd.scenario.Scenario` into arrays (the humans' ``CrowdState``, the robot's track,
the walls) and runs ``nsim.crowd.social_force.rollout`` over them. ``spawn_extra_humans`` adds random
people in the scenario's free space (the sweeps' crowd sizes), on the same map.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from nsim.crowd.behaviours import BEHAVIOUR_NAMES, behaviour_codes
from nsim.crowd.neighbours import segments_intersect
from nsim.crowd.paths import clearance_m, enclosed, yaw_of_poses
from nsim.crowd.scenario import Scenario, parse_scenario, resolve_scenario
from nsim.crowd.schema import describe
from nsim.crowd.social_force import CrowdState, CrowdTrajectory, RobotTrack, rollout
from nsim.errors import InputError, NsimError

MAX_TICKS = 2_000_000


@dataclasses.dataclass(frozen=True, eq=False)
class Simulation:
    """A scenario rolled out: ``T`` ticks at ``t_k = k dt``.

    time_s: (T,); robot_pose_se3: (T, 4, 4) body-to-world (x forward, z up); crowd: the humans and
    the robot as the crowd saw it; dt_s; walls_m: (M, 2, 2).
    """

    time_s: np.ndarray
    robot_pose_se3: np.ndarray
    crowd: CrowdTrajectory
    dt_s: float
    walls_m: np.ndarray


def crowd_state(sc: Scenario) -> CrowdState:
    """The humans' initial ``CrowdState`` (waypoints padded with the last one)."""
    n = len(sc.humans)
    k = max((len(h.waypoints_m) for h in sc.humans), default=1)
    goals = np.zeros((n, k, 2))
    for i, h in enumerate(sc.humans):
        goals[i, : len(h.waypoints_m)] = h.waypoints_m
        goals[i, len(h.waypoints_m) :] = h.waypoints_m[-1]

    def per(attr, dtype=np.float64):
        return np.array([getattr(h, attr) for h in sc.humans], dtype=dtype)

    return CrowdState.create(
        np.array([h.start_m for h in sc.humans], dtype=np.float64).reshape(n, 2),
        goals,
        n_goals=np.array([len(h.waypoints_m) for h in sc.humans], dtype=np.int64),
        loop_goals=per("loop", bool),
        desired_speed_mps=per("speed_mps"),
        radius_m=per("radius_m"),
        height_m=per("height_m"),
        group_id=per("group_id", np.int64),
        behaviour=behaviour_codes([h.behaviour for h in sc.humans]),
    )


def simulate(sc: Scenario, forces, behaviours, dt_s: float, duration_s: float, seed: int) -> Simulation:
    """Roll the scenario out for ``duration_s`` at ``dt_s`` (``rollout`` seeded with ``seed``)."""
    ticks = duration_s / dt_s
    if ticks > MAX_TICKS:
        raise InputError(f"{sc.source}: duration_s / dt_s = {ticks:.0f} ticks, more than {MAX_TICKS}")
    n_steps = max(1, int(round(ticks)))
    time_s = np.arange(n_steps + 1) * dt_s
    poses = sc.robot.poses_at(time_s)
    track = RobotTrack(
        poses[:, :2, 3], yaw_of_poses(poses), radius_m=sc.robot.radius_m, half_length_m=sc.robot.half_length_m
    )
    walls = sc.walls_m
    traj = rollout(
        crowd_state(sc),
        n_steps,
        dt_s,
        walls_m=walls,
        robot=track,
        forces=forces,
        behaviours=behaviours,
        seed=seed,
    )
    return Simulation(time_s=time_s, robot_pose_se3=poses, crowd=traj, dt_s=dt_s, walls_m=walls)


# ----------------------------------------------------------------------------------------------
# Sweeps: extra people in free space


def spawn_extra_humans(sc: Scenario, count: int, behaviours: Sequence[str], rng: np.random.Generator) -> Scenario:
    """The scenario plus ``count`` random people walking loops between two free points, on the same map.

    Starts and waypoints are drawn uniformly in the map's free space (not in an obstacle, enclosed,
    ``radius + 0.15`` m clear of walls); starts keep clear of every other human and 1 m clear of
    the robot at t = 0; every leg is a straight line ``radius + 0.05`` m clear of the walls.
    Behaviours are drawn uniformly from ``behaviours``, heights and speeds from normal
    distributions about 1.72 m and 1.3 m/s. Raises :class:`NsimError` when the space is too full.
    """
    bad = [b for b in behaviours if b not in BEHAVIOUR_NAMES]
    if bad or not behaviours:
        raise NsimError(
            f"behaviours: {describe(bad[0]) if bad else '[]'} is not one of {', '.join(BEHAVIOUR_NAMES)}"
        )
    data = sc.data
    if count == 0:
        return sc
    walls = sc.walls_m
    if len(walls) == 0:
        raise NsimError(f"{sc.source}: the scene has no obstacles to bound the space for extra people")
    radius = 0.25
    lo, hi = walls.reshape(-1, 2).min(axis=0), walls.reshape(-1, 2).max(axis=0)
    cand = rng.uniform(lo, hi, size=(max(4096, 40 * count), 2))
    ok = ~sc.in_obstacle(cand) & enclosed(cand, walls)
    cand = cand[ok]
    cand = cand[clearance_m(cand, walls) >= radius + 0.15]
    if len(cand) < 2:
        raise NsimError(f"{sc.source}: no free space found for extra people in {sc.scene_label()}")
    robot_d = sc.robot_distance_at_start_m(cand)
    starts = [h.start_m for h in sc.humans]
    radii = [h.radius_m for h in sc.humans]
    extra = []
    tries = 0
    while len(extra) < count:
        tries += 1
        if tries > 30 * count + 300:
            raise NsimError(
                f"{sc.source}: could place only {len(extra)} of {count} extra people in the free space of "
                f"{sc.scene_label()}: use fewer"
            )
        i, a, b = rng.integers(len(cand), size=3)
        s = cand[i]
        if robot_d[i] < 1.0:
            continue
        if starts and np.min(np.linalg.norm(np.array(starts) - s, axis=1) - np.array(radii)) < radius + 0.1:
            continue
        g = np.stack([cand[a], cand[b]])
        if np.linalg.norm(g[0] - g[1]) < 2.0:
            continue
        legs = np.stack([np.stack([s, g[0]]), np.stack([g[0], g[1]])])
        if segments_intersect(legs[:, 0], legs[:, 1], walls).any():
            continue
        samples = np.concatenate(
            [np.linspace(p, q, max(2, int(np.linalg.norm(q - p) / 0.1) + 1)) for p, q in legs]
        )
        if clearance_m(samples, walls).min() < radius + 0.05:
            continue
        starts.append(s)
        radii.append(radius)
        extra.append(
            {
                "id": f"extra{len(extra):03d}",
                "start_m": np.round(s, 3).tolist(),
                "waypoints_m": np.round(g, 3).tolist(),
                "loop": True,
                "behaviour": str(behaviours[int(rng.integers(len(behaviours)))]),
                "height_m": round(float(np.clip(rng.normal(1.72, 0.09), 1.5, 1.95)), 3),
                "speed_mps": round(float(np.clip(rng.normal(1.3, 0.15), 0.9, 1.7)), 3),
            }
        )
    data["humans"] = data["humans"] + extra
    return resolve_scenario(parse_scenario(data, source=sc.source), sc.scene_map)
