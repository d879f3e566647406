"""A scenario rolled out: the crowd's initial state, the simulation loop's driver, extra people for sweeps.

``simulate(sc, forces, behaviours, dt_s, duration_s, seed)`` turns a resolved
:class:`~nsim.crowd.scenario.Scenario` into arrays (the humans' ``CrowdState``, the robot's track,
the walls) and runs ``nsim.crowd.rollout.rollout`` over them when the robot replays its
trajectory, or ``closed_loop`` when a controller drives it (``nsim.crowd.controllers``): each tick
the controller observes, its command is checked and clamped, the robot moves, then the crowd
steps against the robot where it is and where it will be. ``spawn_extra_humans`` adds random
people in the scenario's free space (the sweeps' crowd sizes), on the same map.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from nsim.crowd import controllers as ctl
from nsim.crowd.behaviours import BEHAVIOUR_NAMES, behaviour_codes
from nsim.crowd.neighbours import segments_intersect
from nsim.crowd.paths import clearance_m, enclosed, yaw_of_poses, yaw_poses_se3
from nsim.crowd.rollout import CrowdTrajectory, RobotTrack, crowd_record, rollout
from nsim.crowd.scenario import Scenario, parse_scenario, resolve_scenario
from nsim.crowd.schema import describe
from nsim.crowd.social_force import CrowdState, keep_out_of_walls, make_walls, step
from nsim.crowd.state import RobotState
from nsim.errors import InputError, NsimError

MAX_TICKS = 2_000_000


@dataclasses.dataclass(frozen=True, eq=False)
class Simulation:
    """A scenario rolled out: ``T`` ticks at ``t_k = k dt``.

    time_s: (T,); robot_pose_se3: (T, 4, 4) body-to-world (x forward, z up); crowd: the humans and
    the robot as the crowd saw it; dt_s; walls_m: (M, 2, 2). With a controller (None for replay):
    robot_command_body (T - 1, 3): the command issued at tick k, ``(vx_mps, vy_mps, yaw_rate_radps)``
    in the body frame at tick k, as the controller returned it; robot_executed_body (T - 1, 3): the
    motion from tick k to k + 1 in the same frame (clamped to the limits, stopped by walls).
    """

    time_s: np.ndarray
    robot_pose_se3: np.ndarray
    crowd: CrowdTrajectory
    dt_s: float
    walls_m: np.ndarray
    robot_command_body: np.ndarray | None = None
    robot_executed_body: np.ndarray | None = None


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
        gait_stride_m=per("gait_stride_m"),
        gait_period_s=per("gait_period_s"),
    )


def simulate(sc: Scenario, forces, behaviours, dt_s: float, duration_s: float, seed: int,
             sensors: ctl.SensorHook | None = None) -> Simulation:
    """Roll the scenario out for ``duration_s`` at ``dt_s`` (``rollout`` seeded with ``seed``).

    sensors: rendered frames for the controller (``closed_loop``); only with a controller."""
    ticks = duration_s / dt_s
    if ticks > MAX_TICKS:
        raise InputError(f"{sc.source}: duration_s / dt_s = {ticks:.0f} ticks, more than {MAX_TICKS}")
    n_steps = max(1, int(round(ticks)))
    time_s = np.arange(n_steps + 1) * dt_s
    if sc.robot.controller != "replay":
        return closed_loop(sc, make_controller(sc, forces), forces, behaviours, dt_s, n_steps, seed, sensors)
    if sensors is not None:
        raise InputError(f"{sc.source}: robot.sensors: rendered sensor frames are for a controller (robot.controller)")
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
# A controller in the loop


def make_controller(sc: Scenario, forces):
    """The scenario's controller object (``robot.controller``): built-in, or the user's class with its params."""
    entry = sc.robot.controller
    if entry == "social_force":
        return ctl.SocialForceController(forces)
    if entry == "orca":
        return ctl.OrcaController()
    params = dict(entry.get("params", {}))
    try:
        return ctl.user_class(entry)(**params)
    except Exception as exc:  # the user's constructor refused its params
        raise InputError(
            f"{sc.source}: robot.controller.params: constructing {ctl.controller_label(entry)} failed: "
            f"{exc.__class__.__name__}: {exc}"
        ) from None


def _advance_goal(goal_index: int, position_m: np.ndarray, goals_m: np.ndarray, loop: bool) -> int:
    """The goal to head for: the next one once within ``GOAL_TOLERANCE_M`` (cycled on a loop, held at the last)."""
    for _ in range(len(goals_m)):
        if np.linalg.norm(goals_m[goal_index] - position_m) > ctl.GOAL_TOLERANCE_M:
            break
        if goal_index == len(goals_m) - 1:
            if not loop:
                break
            goal_index = 0
        else:
            goal_index += 1
    return goal_index


def observe(
    sc: Scenario,
    state: CrowdState,
    time_s: float,
    dt_s: float,
    position_m: np.ndarray,
    heading_rad: float,
    velocity_mps: np.ndarray,
    goal_index: int,
    walls_m: np.ndarray,
    render_sensor=None,
) -> ctl.Observation:
    """The controller's view at one tick (``controllers.Observation``): the people within its sensor range, nearest first."""
    robot = sc.robot
    d = np.linalg.norm(state.position_m - position_m, axis=1)
    seen = np.flatnonzero(d <= robot.sensor_range_m)
    seen = seen[np.argsort(d[seen], kind="stable")]

    def frozen(a: np.ndarray) -> np.ndarray:
        a = np.array(a, dtype=np.float64)
        a.flags.writeable = False
        return a

    return ctl.Observation(
        time_s=float(time_s),
        dt_s=float(dt_s),
        position_m=frozen(position_m),
        heading_rad=float(heading_rad),
        velocity_mps=frozen(velocity_mps),
        goal_m=frozen(robot.goals_m[goal_index]),
        goal_index=int(goal_index),
        goals_m=frozen(robot.goals_m),
        final_goal=bool(not robot.goals_loop and goal_index == len(robot.goals_m) - 1),
        people_position_m=frozen(state.position_m[seen]),
        people_velocity_mps=frozen(state.velocity_mps[seen]),
        people_radius_m=frozen(state.radius_m[seen]),
        people_index=seen.astype(np.int64),
        walls_m=frozen(walls_m),
        obstacles_m=tuple(frozen(p) for p in sc.obstacles_m),
        robot_radius_m=robot.radius_m,
        robot_half_length_m=robot.half_length_m,
        limits=robot.limits,
        desired_speed_mps=robot.speed_mps,
        sensor_range_m=robot.sensor_range_m,
        render_sensor=render_sensor,
    )


def _sensor_call(render, pose_se3: np.ndarray, time_s: float):
    """``render_sensor(name)`` for one tick: ``render(name, pose_se3, time_s)``."""

    def render_sensor(name: str):
        return render(name, pose_se3, time_s)

    return render_sensor


def closed_loop(
    sc: Scenario,
    controller,
    forces,
    behaviours,
    dt_s: float,
    n_steps: int,
    seed: int,
    sensors: ctl.SensorHook | None = None,
) -> Simulation:
    """Roll out ``n_steps`` with ``controller`` driving the robot (see the module docstring).

    Per step k: observe (``observe``), command (checked: 3 finite numbers, else an
    :class:`InputError` naming the scenario and ``robot.controller``), clamp to the limits
    (``controllers.clamp_command``), move the robot (world velocity from the body command at tick
    k's heading, its centre disc kept out of the walls), then ``social_force.step`` with the robot
    at tick k (its executed velocity) and at tick k + 1 (people are pushed out of it there).
    The robot starts at its trajectory's pose at t = 0, standing. sensors: on the ticks it is due,
    the observation's ``render_sensor(name)`` calls ``sensors.render(name, pose, t)`` with the robot's
    body-to-world pose then (z = ``body_height_m``).
    """
    from nsim.crowd.behaviours import BehaviourParams
    from nsim.crowd.social_force import ForceParams

    forces = forces if forces is not None else ForceParams()
    behaviours = (behaviours if behaviours is not None else BehaviourParams()).resolved()
    robot = sc.robot
    label = ctl.controller_label(robot.controller)
    walls_m = sc.walls_m
    state = crowd_state(sc)
    grid = make_walls(walls_m, forces, np.append(state.radius_m, robot.radius_m))
    rng = np.random.default_rng(seed)
    pose0 = robot.poses_at(np.zeros(1))[0]
    pos, yaw, vel = pose0[:2, 3].copy(), float(yaw_of_poses(pose0[None])[0]), np.zeros(2)
    goal_index = _advance_goal(0, pos, robot.goals_m, robot.goals_loop)
    t_count = n_steps + 1
    out = crowd_record(t_count, state.n)
    r_pos, r_vel, r_yaw = np.empty((t_count, 2)), np.zeros((t_count, 2)), np.empty(t_count)
    commands, executed = np.empty((n_steps, 3)), np.empty((n_steps, 3))
    sensor_every = sensors.every_ticks(dt_s) if sensors is not None else 0
    for k in range(t_count):
        for name, arr in out.items():
            arr[k] = getattr(state, name)
        r_pos[k], r_yaw[k] = pos, yaw
        if k == n_steps:
            r_vel[k] = vel
            break
        render = None
        if sensors is not None and k % sensor_every == 0:
            pose_k = yaw_poses_se3(pos[None], np.array([yaw]), robot.body_height_m)[0]
            pose_k.flags.writeable = False
            render = _sensor_call(sensors.render, pose_k, k * dt_s)
        obs = observe(sc, state, k * dt_s, dt_s, pos, yaw, vel, goal_index, walls_m, render)
        raw = controller.command(obs)
        where = f"{sc.source}: robot.controller ({label}) at t = {k * dt_s:g} s"
        cmd = ctl.check_command(raw, lambda m, where=where: InputError(f"{where}: {m}"))
        commands[k] = cmd
        cmd = ctl.clamp_command(cmd, robot.limits)
        new_pos = pos + ctl.body_to_world(cmd[:2], yaw) * dt_s
        if len(walls_m):
            new_pos = keep_out_of_walls(new_pos[None], np.array([robot.radius_m]), grid)[0]
        new_yaw = ctl._wrap(yaw + cmd[2] * dt_s)
        vel = (new_pos - pos) / dt_s
        r_vel[k] = vel
        executed[k] = [*ctl.world_to_body(vel, yaw), ctl._wrap(new_yaw - yaw) / dt_s]
        robot_k = RobotState(pos, vel, yaw, robot.radius_m, robot.half_length_m)
        robot_next = RobotState(new_pos, vel, new_yaw, robot.radius_m, robot.half_length_m)
        state = step(state, robot_k, grid, forces, behaviours, dt_s, rng, robot_next=robot_next)
        pos, yaw = new_pos, new_yaw
        goal_index = _advance_goal(goal_index, pos, robot.goals_m, robot.goals_loop)
    crowd = CrowdTrajectory(
        time_s=np.arange(t_count) * dt_s,
        radius_m=state.radius_m.copy(),
        behaviour=state.behaviour.copy(),
        group_id=state.group_id.copy(),
        has_robot=True,
        robot_position_m=r_pos,
        robot_velocity_mps=r_vel,
        robot_heading_rad=r_yaw,
        robot_radius_m=float(robot.radius_m),
        robot_half_length_m=float(robot.half_length_m),
        **out,
    )
    return Simulation(
        time_s=crowd.time_s,
        robot_pose_se3=yaw_poses_se3(r_pos, r_yaw, robot.body_height_m),
        crowd=crowd,
        dt_s=dt_s,
        walls_m=walls_m,
        robot_command_body=commands,
        robot_executed_body=executed,
    )


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
