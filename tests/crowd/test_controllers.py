"""Robot controllers in the loop (``nsim.crowd.controllers``, ``nsim.crowd.driver.closed_loop``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nsim.crowd import controllers as ctl
from nsim.crowd.behaviours import BehaviourParams
from nsim.crowd.driver import simulate
from nsim.crowd.metrics import GOAL_RADIUS_M, people_gap_m
from nsim.crowd.scenario import parse_scenario, polygon_map, resolve_scenario
from nsim.crowd.social_force import ForceParams
from nsim.errors import InputError
from tests.crowd import user_controllers

# a 10 x 6 m room inside a ring of walls
ROOM = {
    "polygons": [[[-1, -4], [11, -4], [11, 4], [-1, 4], [-1, -4]]],
    "holes": [[[[0, -3], [10, -3], [10, 3], [0, 3], [0, -3]]]],
}
HEAD_ON = [{"start_m": [9.0, 0.0], "waypoints_m": [[1.0, 0.0]], "behaviour": "impassive"}]
USER = "tests.crowd.user_controllers"


def scenario(controller=None, humans=(), duration_s=12.0, **robot):
    d = {
        "duration_s": duration_s,
        "dt_s": 0.05,
        "scene": ROOM,
        "robot": {"trajectory": {"waypoints_m": [[1.0, 0.0], [9.0, 0.0]], "speed_mps": 1.0}, **robot},
        "humans": list(humans),
    }
    if controller is not None:
        d["robot"]["controller"] = controller
    spec = parse_scenario(d, source="room.json")
    return resolve_scenario(spec, polygon_map(spec.scene, spec.error))


def run(sc, seed=0):
    return simulate(sc, ForceParams(), BehaviourParams(), 0.05, sc.duration_s, seed)


@pytest.mark.parametrize(
    "controller", [None, "social_force", "orca", {"python": f"{USER}:GoalSeeker", "params": {"speed_mps": 1.2}}]
)
def test_each_controller_reaches_its_goal_in_an_empty_room(controller):
    sim = run(scenario(controller))
    end = sim.crowd.robot_position_m[-1]
    assert np.linalg.norm(end - [9.0, 0.0]) < GOAL_RADIUS_M  # HuNavSim's "completed"
    speed = np.linalg.norm(sim.crowd.robot_velocity_mps, axis=1)
    assert speed.max() <= ctl.RobotLimits().max_speed_mps + 1e-9
    if controller is not None:  # commands recorded, executed within the limits
        assert sim.robot_command_body.shape == sim.robot_executed_body.shape == (len(sim.time_s) - 1, 3)
        assert np.allclose(sim.robot_pose_se3[:, :2, 3], sim.crowd.robot_position_m)


def test_orca_avoids_a_person_walking_head_on_where_replay_collides():
    replay = run(scenario(None, HEAD_ON))
    orca = run(scenario("orca", HEAD_ON))
    assert people_gap_m(replay.crowd).min() < 1e-6  # the replayed robot runs into them (they are pushed)
    assert people_gap_m(orca.crowd).min() > 0.05
    assert np.linalg.norm(orca.crowd.robot_position_m[-1] - [9.0, 0.0]) < GOAL_RADIUS_M


def test_social_force_robot_keeps_a_gap_head_on():
    sim = run(scenario("social_force", HEAD_ON))
    assert people_gap_m(sim.crowd).min() > 0.0


def test_user_class_gets_the_documented_observation_and_its_command_is_clamped():
    user_controllers.RECORDERS.clear()
    humans = [
        {"start_m": [4.0, 1.0], "waypoints_m": [[4.0, 1.0]]},  # 3 m from the robot: seen
        {"start_m": [9.5, 2.5], "waypoints_m": [[9.5, 2.5]]},  # 8.9 m: beyond 8 m
    ]
    ctrl = {"python": f"{USER}:Recorder", "params": {"command": [5.0, 0.0, 9.0]}}
    sc = scenario(ctrl, humans, duration_s=0.5, limits={"max_speed_mps": 1.2, "max_yaw_rate_radps": 1.0})
    sim = run(sc)
    (rec,) = user_controllers.RECORDERS
    assert len(rec.seen) == 10
    obs = rec.seen[0]
    assert obs.time_s == 0.0 and obs.dt_s == 0.05 and rec.seen[3].time_s == pytest.approx(0.15)
    assert obs.position_m.shape == (2,) and np.allclose(obs.position_m, [1.0, 0.0])
    assert obs.heading_rad == pytest.approx(0.0) and np.allclose(obs.velocity_mps, 0.0)
    assert np.allclose(obs.goal_m, [9.0, 0.0]) and obs.final_goal  # the start waypoint is passed
    assert obs.people_position_m.shape == (1, 2) and np.allclose(obs.people_position_m, [[4.0, 1.0]])
    assert obs.people_velocity_mps.shape == (1, 2) and np.allclose(obs.people_radius_m, [0.25])
    assert list(obs.people_index) == [0] and obs.sensor_range_m == ctl.SENSOR_RANGE_M
    assert obs.walls_m.shape == (8, 2, 2) and len(obs.obstacles_m) == 1
    assert obs.limits == ctl.RobotLimits(1.2, 1.0)
    with pytest.raises(ValueError):
        obs.position_m[0] = 3.0  # read-only
    # the command is recorded as given and executed clamped
    assert np.allclose(sim.robot_command_body, [5.0, 0.0, 9.0])
    assert np.allclose(np.linalg.norm(sim.robot_executed_body[:, :2], axis=1), 1.2)
    assert np.allclose(sim.robot_executed_body[:, 2], 1.0)
    # the robot moved 1.2 m/s along its heading, turning at 1 rad/s
    yaw = sim.crowd.robot_heading_rad
    assert np.allclose(np.diff(yaw), 0.05)
    step = np.diff(sim.crowd.robot_position_m, axis=0)
    assert np.allclose(step, 0.06 * np.stack([np.cos(yaw[:-1]), np.sin(yaw[:-1])], -1))


def test_walls_stop_the_robot_not_the_controller():
    user_controllers.RECORDERS.clear()
    sc = scenario({"python": f"{USER}:Recorder", "params": {"command": [0.0, 1.5, 0.0]}}, duration_s=4.0)
    sim = run(sc)
    y = sim.crowd.robot_position_m[:, 1]
    assert y.max() <= 3.0 - sc.robot.radius_m + 1e-6  # the wall at y = 3 stops it
    assert np.allclose(sim.robot_command_body[-1], [0.0, 1.5, 0.0])
    assert abs(sim.robot_executed_body[-1, 1]) < 1e-6


@pytest.mark.parametrize(
    "entry, message",
    [
        ({"python": "nsim_no_such_module:X"}, "robot.controller.python: cannot import module 'nsim_no_such_module'"),
        ({"python": f"{USER}:Missing"}, f"robot.controller.python: '{USER}' has no class 'Missing'"),
        ({"python": f"{USER}:NoCommand"}, "robot.controller.python: class 'NoCommand' has no method command"),
        ({"python": "no_colon"}, "robot.controller.python: 'no_colon': expected 'module.path:Class'"),
        ("dwa", "robot.controller"),
        ({"python": f"{USER}:GoalSeeker", "param": {}}, "robot.controller"),
    ],
)
def test_bad_controller_specs_name_the_field(entry, message):
    with pytest.raises(InputError) as exc:
        scenario(entry)
    assert str(exc.value).startswith("room.json: ") and message in str(exc.value)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize(
    "cls, message",
    [("WrongShape", "command returned shape (2,), expected (3,)"), ("NotFinite", "command returned non-finite")],
)
def test_bad_commands_name_the_scenario_and_the_field(cls, message):
    sc = scenario({"python": f"{USER}:{cls}"}, duration_s=1.0)
    with pytest.raises(InputError) as exc:
        run(sc)
    assert str(exc.value).startswith(f"room.json: robot.controller ({cls}) at t = ") and message in str(exc.value)


def test_bad_constructor_params():
    sc = scenario({"python": f"{USER}:GoalSeeker", "params": {"speed": 1.0}}, duration_s=1.0)
    with pytest.raises(InputError, match=r"room.json: robot.controller.params: constructing GoalSeeker failed: TypeError"):
        run(sc)


def test_a_controller_file_next_to_the_scenario(tmp_path):
    import json

    from nsim.stages.simulate import load_scenario

    (tmp_path / "mine.py").write_text(
        "class Still:\n    def command(self, obs):\n        return (0.0, 0.0, 0.0)\n"
    )
    data = {
        "duration_s": 1.0,
        "scene": ROOM,
        "robot": {"trajectory": {"waypoints_m": [[1.0, 0.0], [9.0, 0.0]]}, "controller": {"python": "mine.py:Still"}},
        "humans": [],
    }
    (tmp_path / "s.json").write_text(json.dumps(data))
    sc = load_scenario(tmp_path / "s.json")
    entry = sc.data["robot"]["controller"]
    assert entry["python"] == f"{(tmp_path / 'mine.py').resolve()}:Still" and len(entry["code_sha256"]) == 64
    sim = run(sc)
    assert np.allclose(sim.crowd.robot_position_m, [1.0, 0.0])
    # the canonical content reads back anywhere; an edited file no longer matches it
    (tmp_path / "mine.py").write_text("class Still:\n    def command(self, obs):\n        return (1.0, 0.0, 0.0)\n")
    with pytest.raises(InputError, match="robot.controller.code_sha256: does not match"):
        parse_scenario(sc.data, source="artifact scenario.json")


def test_closed_loop_is_deterministic():
    humans = [{"start_m": [9.0, 0.5], "waypoints_m": [[1.0, 0.5]]}, {"start_m": [5.0, -2.0], "waypoints_m": [[5.0, 2.0]]}]
    a, b = (run(scenario("orca", humans, duration_s=4.0), seed=3) for _ in range(2))
    assert np.array_equal(a.crowd.position_m, b.crowd.position_m)
    assert np.array_equal(a.robot_command_body, b.robot_command_body)


# ---------------------------------------------------------------------------------------------- ORCA core


def test_orca_half_plane_matches_a_hand_case():
    # a neighbour 2 m ahead, combined radius 1, horizon 1: the cut-off disc is centred at (2, 0), radius 1;
    # relative velocity (1.5, 0) is inside it, 0.5 from its front arc at (1, 0): u = (-0.5, 0), n = (-1, 0)
    h = ctl.orca_half_plane(np.array([2.0, 0.0]), np.array([1.5, 0.0]), 1.0, 1.0, 0.05, np.array([1.5, 0.0]), 0.5)
    assert np.allclose(h.normal, [-1.0, 0.0]) and np.allclose(h.point, [1.25, 0.0])
    # relative velocity (2, 1.5): the nearest boundary is the left leg, at 30 deg
    h = ctl.orca_half_plane(np.array([2.0, 0.0]), np.array([2.0, 1.5]), 1.0, 1.0, 0.05, np.zeros(2), 1.0)
    leg = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    assert np.allclose(h.normal, [-leg[1], leg[0]])
    assert np.allclose(h.point, (np.array([2.0, 1.5]) @ leg) * leg - [2.0, 1.5])


def test_orca_velocities_are_collision_free_over_the_horizon():
    rng = np.random.default_rng(0)
    for _ in range(200):
        p = rng.uniform(-4, 4, 2)
        r = 0.6
        if np.linalg.norm(p) <= r + 0.05:
            continue
        v_other = rng.uniform(-1, 1, 2)
        pref = rng.uniform(-1.5, 1.5, 2)
        h = ctl.orca_half_plane(p, pref - v_other, r, 2.0, 0.05, pref, 1.0)
        v, ok = ctl.solve_velocity([h], 1.6, pref)
        assert ok and np.linalg.norm(v) <= 1.6 + 1e-9
        t = np.linspace(0, 2.0, 201)[:, None]
        assert np.min(np.linalg.norm(p - (v - v_other) * t, axis=1)) >= r - 1e-6


def test_solve_velocity_without_a_solution_least_violates():
    planes = [ctl.HalfPlane(np.array([1.0, 0.0]), np.array([1.0, 0.0])), ctl.HalfPlane(np.array([-1.0, 0.0]), np.array([-1.0, 0.0]))]
    v, ok = ctl.solve_velocity(planes, 2.0, np.array([0.5, 0.0]))
    assert not ok and abs(v[0]) < 0.3  # between the two, each violated by about 1


def test_clamp_command_keeps_the_direction():
    cmd = ctl.clamp_command(np.array([3.0, 4.0, -2.0]), ctl.RobotLimits())
    assert np.allclose(cmd, [0.96, 1.28, -1.5])


def test_sensor_frames_are_rendered_at_the_pose_and_rate_asked():
    from nsim.crowd.driver import closed_loop, make_controller

    user_controllers.RECORDERS.clear()
    calls = []

    def render(name, pose, t):
        calls.append((name, np.array(pose), t))
        return np.full((2, 3), t)

    sc = scenario({"python": f"{USER}:Looker"}, duration_s=2.0)
    ctrl = make_controller(sc, ForceParams())
    sim = closed_loop(sc, ctrl, ForceParams(), BehaviourParams(), 0.05, 40, 0, ctl.SensorHook(render, 2.0))
    ticks = [0, 10, 20, 30]
    assert [t for t, _ in ctrl.frames] == pytest.approx([0.05 * k for k in ticks])
    assert np.allclose(ctrl.frames[1][1], 0.5)
    for (name, pose, _), k in zip(calls, ticks, strict=True):
        assert name == "front"
        assert np.allclose(pose[:2, 3], sim.crowd.robot_position_m[k]) and pose[2, 3] == sc.robot.body_height_m
        assert np.allclose(pose, sim.robot_pose_se3[k])
