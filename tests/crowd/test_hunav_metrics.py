"""HuNavSim's evaluator metrics (robotics-upo/hunav_sim, hunav_evaluator/hunav_metrics.py and sfm.py)
on small cases whose values are worked out by hand here."""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from nsim.config import configs_dir
from nsim.crowd import CrowdTrajectory, ForceParams
from nsim.crowd.metrics import (
    CrowdMetrics,
    collisions,
    crowd_metrics,
    hunav_obstacle_force_modulus,
    hunav_pair_force,
    nearest_wall_distance_m,
    record_ticks,
)
from nsim.crowd.run_output import robot_goal_m, run_metrics, sweep_table_markdown

SPOT_RUN = configs_dir() / "scenarios" / "spot_run.json"


def make_traj(
    time_s,
    robot_xy,
    humans_xy,
    *,
    robot_vel=None,
    robot_heading=None,
    human_vel=None,
    human_heading=None,
    group_id=None,
    behaviour=None,
    robot_radius=0.3,
    half_length=0.0,
):
    """A trajectory from arrays: robot_xy (T, 2), humans_xy (T, N, 2); human radius 0.25."""
    time_s = np.asarray(time_s, dtype=np.float64)
    humans_xy = np.asarray(humans_xy, dtype=np.float64)
    robot_xy = np.asarray(robot_xy, dtype=np.float64)
    t, n = humans_xy.shape[:2]
    return CrowdTrajectory(
        time_s=time_s,
        position_m=humans_xy,
        velocity_mps=np.zeros((t, n, 2)) if human_vel is None else np.asarray(human_vel, dtype=np.float64),
        heading_rad=np.zeros((t, n))
        if human_heading is None
        else np.asarray(human_heading, dtype=np.float64),
        behaviour_state=np.zeros((t, n), np.int8),
        gait_phase=np.zeros((t, n)),
        goal_index=np.zeros((t, n), np.int64),
        radius_m=np.full(n, 0.25),
        behaviour=np.ones(n, np.int8) if behaviour is None else np.asarray(behaviour, np.int8),
        group_id=np.full(n, -1) if group_id is None else np.asarray(group_id),
        has_robot=True,
        robot_position_m=robot_xy,
        robot_velocity_mps=np.zeros((t, 2)) if robot_vel is None else np.asarray(robot_vel, dtype=np.float64),
        robot_heading_rad=np.zeros(t)
        if robot_heading is None
        else np.asarray(robot_heading, dtype=np.float64),
        robot_radius_m=robot_radius,
        robot_half_length_m=half_length,
    )


def passing_robot(behaviour=None):
    """The robot (radius 0.3) drives x = -2 .. 2 in 1 m steps every 0.5 s past ana, standing at
    (0, 0.9) and shuffling at 0.5 m/s, while ben walks at 1.5 m/s 6 m away (radius 0.25 each).
    Its speeds are 0, 1, 2, 2, 1 m/s, its heading 0, 0, 0.5, 1, 1 rad."""
    x = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    return make_traj(
        [0.0, 0.5, 1.0, 1.5, 2.0],
        np.column_stack([x, np.zeros(5)]),
        np.broadcast_to([[0.0, 0.9], [0.0, -6.0]], (5, 2, 2)),
        robot_vel=[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.0], [1.0, 0.0]],
        robot_heading=[0.0, 0.0, 0.5, 1.0, 1.0],
        human_vel=np.broadcast_to([[0.5, 0.0], [0.0, 1.5]], (5, 2, 2)),
        behaviour=behaviour,
    )


def test_a_robot_passing_a_person():
    m = crowd_metrics(passing_robot(), robot_goal_m=[2.0, 0.0])
    # gaps to ana (centre distance - 0.3 - 0.25), the closest at every tick
    gap = [math.hypot(2, 0.9) - 0.55, math.hypot(1, 0.9) - 0.55, 0.35, math.hypot(1, 0.9) - 0.55]
    gap.append(gap[0])
    assert m.minimum_distance_to_people_m == pytest.approx(0.35)
    assert m.avg_distance_to_closest_person_m == pytest.approx(sum(gap) / 5)
    # the farthest: ben at the ends, minus the robot's radius only (as the code has it)
    assert m.maximum_distance_to_people_m == pytest.approx(math.hypot(2.0, 6.0) - 0.3)
    # gaps 1.64, 0.80, 0.35, 0.80, 1.64: intimate once, personal twice, social twice
    assert m.intimate_space_intrusions_pct == pytest.approx(20.0)
    assert m.personal_space_intrusions_pct == pytest.approx(40.0)
    assert m.social_space_intrusions_pct == pytest.approx(40.0)
    assert m.group_intimate_space_intrusions_pct == m.group_social_space_intrusions_pct == 0.0  # no groups
    assert m.path_length_m == pytest.approx(4.0)
    assert m.cumulative_heading_changes_rad == pytest.approx(1.0)
    # the goal (2, 0) is reached at the last tick, within HuNavSim's 0.2 m
    assert m.time_to_reach_goal_s == pytest.approx(2.0) and m.completed is True
    assert m.minimum_distance_to_target_m == 0.0 and m.final_distance_to_target_m == 0.0
    # speeds 0, 1, 2, 2, 1: mean 6/5; accelerations |dv/dt| = 2, 2, 0, 2 over 5 samples;
    # HuNavSim's overacceleration divides each by dt once more
    assert m.avg_robot_linear_speed_mps == pytest.approx(1.2)
    assert m.avg_acceleration_mps2 == pytest.approx(6.0 / 5)
    assert m.avg_overacceleration_mps3 == pytest.approx(12.0 / 5)
    # yaw rate by central differences of 0, 0, 0.5, 1, 1 at 0.5 s: 0, 0.5, 1, 0.5, 0 rad/s
    assert m.avg_robot_angular_speed_radps == pytest.approx(2.0 / 5)
    # stopped (v < 0.01, omega < 0.02) only at tick 0: one sample of 2 s / 5 samples
    assert m.time_not_moving_s == pytest.approx(0.4)
    assert m.avg_pedestrian_velocity_mps == pytest.approx(1.0)  # (0.5 + 1.5) / 2
    assert m.avg_closest_pedestrian_velocity_mps == pytest.approx(0.5)  # always ana
    assert m.robot_on_person_collision == m.person_on_robot_collision == 0


def test_an_unfinished_run():
    tr = passing_robot()
    m = crowd_metrics(tr, robot_goal_m=[10.0, 0.0])
    # never within 0.2 m of (10, 0): not completed, and the time is the whole run, as HuNavSim reports it
    assert m.completed is False and m.time_to_reach_goal_s == pytest.approx(2.0)
    assert m.minimum_distance_to_target_m == pytest.approx(8.0)
    assert m.final_distance_to_target_m == pytest.approx(8.0)
    # passing through the goal does not complete the run: HuNavSim looks at the last pose
    m = crowd_metrics(tr, robot_goal_m=[0.0, 0.0])
    assert m.completed is False and m.time_to_reach_goal_s == pytest.approx(1.0)
    assert m.minimum_distance_to_target_m == 0.0 and m.final_distance_to_target_m == pytest.approx(2.0)
    # no goal (a looping robot): undefined
    m = crowd_metrics(tr)
    assert (
        m.completed is None
        and math.isnan(m.time_to_reach_goal_s)
        and math.isnan(m.final_distance_to_target_m)
    )


def test_collisions_are_blamed_as_hunavsim_does():
    """One person per tick, 0.54 m from the robot's centre (gap -0.01 < 0.02), the robot at the origin facing +x."""
    people = np.array([[[0.54, 0.0]], [[-0.54, 0.0]], [[0.0, 0.54]], [[0.0, 0.54]], [[0.0, 0.58]]])
    tr = make_traj(
        np.arange(5.0),
        np.zeros((5, 2)),
        people,
        robot_vel=[[1.0, 0.0], [0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 0.0]],
        human_vel=[[[-0.5, 0.0]], [[1.0, 0.0]], [[1.0, 0.0]], [[1.0, 0.0]], [[1.0, 0.0]]],
        human_heading=[[math.pi], [0.0], [0.0], [0.0], [0.0]],
    )
    robot_hits, person_hits = collisions(tr)
    # 0: the robot drives at 1 m/s into a person facing it (0.5 m/s): the robot is dead ahead of the
    #    person (alpha 0), the person at atan2(x=0.54, y=0) = pi/2 for the robot: the robot's fault.
    # 1: a person walks into the back of the standing robot: alpha 0, alpha2 = atan2(-0.54, 0) = -pi/2,
    #    |alpha| < |alpha2| and the speeds differ: HuNavSim blames the robot here too.
    # 2: a person brushes past the robot's left side: alpha = atan2(-0.54, 0) = -pi/2 (the robot on its
    #    right), alpha2 = atan2(0, 0.54) = 0: the person's fault.
    # 3: the same at equal speeds (1 m/s): no rule applies, nobody is blamed.
    # 4: 0.03 m apart (>= 0.02): no contact.
    np.testing.assert_array_equal(robot_hits[:, 0], [True, True, False, False, False])
    np.testing.assert_array_equal(person_hits[:, 0], [False, False, True, False, False])
    m = crowd_metrics(tr)
    assert m.robot_on_person_collision == 2 and m.person_on_robot_collision == 1
    assert m.minimum_distance_to_people_m == 0.0  # overlaps clamp at 0
    assert m.intimate_space_intrusions_pct == 100.0


def test_equal_angles_and_speeds_blame_both():
    # the person behind the robot's left, at (-0.38, 0.38) (gap 0.38 sqrt(2) - 0.55 = -0.013), both
    # facing +x: the robot seen from the person is at (0.38, -0.38), alpha = atan2(-0.38, 0.38); the
    # person in the robot's frame is (x, y) = (-0.38, 0.38), alpha2 = atan2(x, y) = atan2(-0.38, 0.38)
    people = np.broadcast_to([[-0.38, 0.38]], (3, 1, 2))
    tr = make_traj(
        np.arange(3.0),
        np.zeros((3, 2)),
        people,
        robot_vel=[[0.0, 0.0], [1.0, 0.0], [1.0, 0.0]],
        human_vel=[[[0.0, 0.0]], [[1.0, 0.0]], [[0.5, 0.0]]],
    )
    robot_hits, person_hits = collisions(tr)
    # equal angles and equal speeds (0 and 0, 1 and 1): both; equal angles, 1 vs 0.5 m/s: neither
    np.testing.assert_array_equal(robot_hits[:, 0], [True, True, False])
    np.testing.assert_array_equal(person_hits[:, 0], [True, True, False])


def test_group_space_intrusions():
    # group 0: two people at (2, +-1) facing -x, so their interaction centre is 1.5 m ahead of them,
    # at (0.5, 0); a loner next to the robot does not count; group 7 has one member far away
    people = [[2.0, 1.0], [2.0, -1.0], [0.0, 0.6], [30.0, 30.0]]
    robot_x = [0.5, 0.0, -0.5, -2.0, -5.0]
    tr = make_traj(
        np.arange(5.0),
        np.column_stack([robot_x, np.zeros(5)]),
        np.broadcast_to(people, (5, 4, 2)),
        human_heading=np.broadcast_to([math.pi, math.pi, 0.0, 0.0], (5, 4)),
        group_id=[0, 0, -1, 7],
    )
    m = crowd_metrics(tr)
    # robot surface to the centre: -0.3 (inside: intimate), 0.2, 0.7, 2.2, 5.2
    assert m.group_intimate_space_intrusions_pct == pytest.approx(40.0)
    assert m.group_personal_space_intrusions_pct == pytest.approx(20.0)
    assert m.group_social_space_intrusions_pct == pytest.approx(20.0)


def _pair_modulus(distance_m: float, interaction_length: float, theta: float) -> float:
    """|force| of sfm.py's computeSocialForceTwoAgents, written out: 2.1 |(exp_v i, exp_a i_left)|."""
    b = 0.35 * interaction_length
    along = math.exp(-distance_m / b - (3.0 * b * theta) ** 2)
    across = math.exp(-distance_m / b - (2.0 * b * theta) ** 2)
    return 2.1 * math.hypot(along, across)


def test_social_and_obstacle_forces():
    """The robot at the origin (still, then at 1 m/s along +x), a still person at (2, 0), a wall along y = -1."""
    tr = make_traj(
        [0.0, 1.0],
        np.zeros((2, 2)),
        np.broadcast_to([[2.0, 0.0]], (2, 1, 2)),
        robot_vel=[[0.0, 0.0], [1.0, 0.0]],
    )
    wall = np.array([[[-5.0, -1.0], [5.0, -1.0]]])
    # on the person: e = (-1, 0) (towards the robot), interaction i = lambda (0 - v_robot) + e:
    # (-1, 0) then (-3, 0), so L = 1 then 3; theta = atan2(0, -1) - atan2(-1, 0) = 3 pi / 2 -> -pi/2.
    # On the robot: e = (1, 0), i = lambda (v_robot - 0) + e: (1, 0) then (3, 0); theta = 0 - pi/2.
    still = _pair_modulus(2.0, 1.0, -math.pi / 2)
    moving = _pair_modulus(2.0, 3.0, -math.pi / 2)
    # obstacle forces: 10 exp(-(d - r) / 0.2) from the nearest wall point, 1 m away
    obstacle_robot = 10.0 * math.exp(-(1.0 - 0.3) / 0.2)
    obstacle_person = 10.0 * math.exp(-(1.0 - 0.25) / 0.2)
    m = crowd_metrics(tr, walls_m=wall)
    assert m.social_force_on_agents == pytest.approx(still + moving, rel=1e-12)
    assert m.social_force_on_robot == pytest.approx(still + moving, rel=1e-12)
    assert m.social_work == pytest.approx(2 * (still + moving) + 2 * obstacle_robot, rel=1e-12)
    assert m.obstacle_force_on_robot == pytest.approx(2 * obstacle_robot, rel=1e-12)
    assert m.obstacle_force_on_agents == pytest.approx(2 * obstacle_person, rel=1e-12)
    # the vector: along = -exp(..) times i = (-1, 0) pushes the person away (+x); the angle term
    # -sign(theta) exp(..) = +exp(..) along i's left normal (0, -1)
    f = hunav_pair_force(np.zeros(2), np.zeros(2), np.array([2.0, 0.0]), np.zeros(2))
    b = 0.35
    expected = 2.1 * np.array(
        [math.exp(-2.0 / b - (3 * b * math.pi / 2) ** 2), -math.exp(-2.0 / b - (2 * b * math.pi / 2) ** 2)]
    )
    np.testing.assert_allclose(f, expected, rtol=1e-12)


def test_obstacles_farther_than_10_m_do_not_count():
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    d = nearest_wall_distance_m(np.array([[0.0, 3.0], [8.0, 4.0], [0.0, 11.0], [0.0, -9.99]]), wall)
    np.testing.assert_allclose(d, [3.0, 5.0, np.inf, 9.99])
    np.testing.assert_allclose(
        hunav_obstacle_force_modulus(d, 0.25),
        [10 * math.exp(-2.75 / 0.2), 10 * math.exp(-4.75 / 0.2), 0.0, 10 * math.exp(-9.74 / 0.2)],
    )


def test_a_capsule_robot_is_measured_from_its_body_axis():
    # Spot-like: half length 0.4, radius 0.3, facing +x; a person 1.2 m ahead of its centre is
    # 1.2 - 0.4 - 0.3 - 0.25 = 0.25 m from its body
    tr = make_traj([0.0], np.zeros((1, 2)), [[[1.2, 0.0], [0.0, 1.5]]], half_length=0.4)
    m = crowd_metrics(tr)
    assert m.minimum_distance_to_people_m == pytest.approx(0.25)
    assert m.maximum_distance_to_people_m == pytest.approx(1.5 - 0.3)
    assert m.intimate_space_intrusions_pct == 100.0


def test_recording_frequency():
    time_s = np.arange(13) * 0.25  # 0 .. 3 s
    np.testing.assert_array_equal(record_ticks(time_s, 0.0), np.arange(13))
    np.testing.assert_array_equal(record_ticks(time_s, 1.0), [0, 4, 8, 12])
    np.testing.assert_array_equal(record_ticks(time_s, 0.4), [0, 10])  # every 2.5 s
    np.testing.assert_array_equal(record_ticks(np.arange(7) * 0.3, 1.0), [0, 3])  # latest tick at 1 s: 0.9 s
    with pytest.raises(ValueError, match="frequency_hz"):
        record_ticks(time_s, -1.0)
    # the robot at 1 m/s along x passes a person at (1.5, 0.8): every tick sees the closest gap,
    # 0.8 - 0.55; at 1 Hz the robot is only seen at x = 0, 1, 2, 3
    tr = make_traj(
        time_s,
        np.column_stack([time_s, np.zeros(13)]),
        np.broadcast_to([[1.5, 0.8]], (13, 1, 2)),
        robot_vel=np.broadcast_to([1.0, 0.0], (13, 2)),
    )
    assert crowd_metrics(tr).minimum_distance_to_people_m == pytest.approx(0.25)
    m = crowd_metrics(tr, frequency_hz=1.0)
    assert m.minimum_distance_to_people_m == pytest.approx(math.hypot(0.5, 0.8) - 0.55)
    assert m.path_length_m == pytest.approx(3.0)
    assert m.intimate_space_intrusions_pct == pytest.approx(50.0)  # x = 1, 2 of 0, 1, 2, 3


def test_robot_goal_from_the_scenario():
    from nsim.stages.simulate import load_scenario

    assert robot_goal_m(load_scenario(SPOT_RUN)) is None  # the walk loop has no goal
    sc = SimpleNamespace(
        data={
            "robot": {
                "trajectory": {"waypoints_m": [[0, 0], [3, 1], [4, 2]], "speed_mps": 1.0, "loop": False}
            }
        }
    )
    np.testing.assert_array_equal(robot_goal_m(sc), [4.0, 2.0])
    poses = [
        {"t_s": 0.0, "position_m": [0.0, 0.0, 0.5], "orientation_quat_wxyz": [1, 0, 0, 0]},
        {"t_s": 2.0, "position_m": [3.0, -1.0, 0.5], "orientation_quat_wxyz": [1, 0, 0, 0]},
    ]
    np.testing.assert_array_equal(
        robot_goal_m(SimpleNamespace(data={"robot": {"trajectory": {"poses": poses}}})), [3.0, -1.0]
    )


def test_metrics_json_per_behaviour_and_sweep_table():
    # ana is regular (code 1), ben scared (4); the robot goes nowhere in particular (a loop: no goal)
    loop = {"waypoints_m": [[-2, 0], [2, 0]], "speed_mps": 2.0, "loop": True}
    sc = SimpleNamespace(name="pass", humans=[1, 2], data={"robot": {"trajectory": loop}})
    crowd = passing_robot(behaviour=[1, 4])
    sim = SimpleNamespace(time_s=crowd.time_s, dt_s=0.5, crowd=crowd, walls_m=np.zeros((0, 2, 2)),
                          robot_command_body=None, robot_executed_body=None)
    record = json.loads(json.dumps(run_metrics(sc, sim, ForceParams()), allow_nan=False))
    hunav = record["hunav"]
    assert list(hunav) == [f.name for f in dataclasses.fields(CrowdMetrics)]
    assert hunav["completed"] is None and hunav["time_to_reach_goal_s"] is None
    assert hunav["robot_on_person_collision"] == 0 and isinstance(hunav["robot_on_person_collision"], int)
    assert hunav["intimate_space_intrusions_pct"] == pytest.approx(20.0)
    assert hunav["avg_pedestrian_velocity_mps"] == pytest.approx(1.0)
    # as HuNavSim's evaluator, each behaviour's people alone: ana (regular), ben (scared)
    regular, scared = record["hunav_by_behaviour"]["regular"], record["hunav_by_behaviour"]["scared"]
    assert set(record["hunav_by_behaviour"]) == {"regular", "scared"}
    assert regular["avg_pedestrian_velocity_mps"] == pytest.approx(0.5)
    assert regular["maximum_distance_to_people_m"] == pytest.approx(math.hypot(2.0, 0.9) - 0.3)
    assert scared["avg_pedestrian_velocity_mps"] == pytest.approx(1.5)
    assert scared["minimum_distance_to_people_m"] == pytest.approx(6.0 - 0.55)
    assert scared["intimate_space_intrusions_pct"] == 0.0 and scared["social_space_intrusions_pct"] == 0.0
    assert regular["path_length_m"] == scared["path_length_m"] == pytest.approx(4.0)  # the robot's own
    assert record["run"]["humans"] == 2 and record["run"]["ticks"] == 5
    row = {
        "grid": {"seed": 3, "extra_people": 0, "behaviours": ["regular"]},
        "humans": 2,
        "trajectory": "a" * 64,
        "metrics": hunav,
    }
    done = dict(hunav, completed=True)
    table = sweep_table_markdown([row, dict(row, metrics=done)]).splitlines()
    head = [c.strip() for c in table[0].strip("|").split("|")]
    assert head == ["seed", "extra", "behaviours", "controller", "humans", "trajectory", *hunav]
    cells = [
        dict(zip(head, (c.strip() for c in line.strip("|").split("|")), strict=True)) for line in table[2:]
    ]
    assert [c["completed"] for c in cells] == ["n/a", "yes"]
    assert [c["controller"] for c in cells] == ["replay", "replay"]  # no controller axis: replay
    assert cells[0]["intimate_space_intrusions_pct"] == "20" and cells[0]["trajectory"] == "a" * 12
    assert cells[0]["avg_acceleration_mps2"] == "1.2"


def test_simulate_stage_reports_an_unfinished_run(run_cli, tmp_path):
    """End to end: a robot sent 1 m along its path, cut at 0.5 s and at 2 s."""
    from nsim.stages.simulate import load_scenario
    from nsim.workspace.store import Store

    data = load_scenario(SPOT_RUN).data
    start = np.array(data["robot"]["trajectory"]["waypoints_m"][0])
    data["robot"]["trajectory"] = {
        "waypoints_m": [start.tolist(), (start + [0.0, 1.0]).tolist()],
        "speed_mps": 1.0,
        "loop": False,
    }
    data["humans"] = []
    path = tmp_path / "goal.json"
    path.write_text(json.dumps(data))
    results = {}
    for cut in ("0.5", "2"):
        code, out, err = run_cli(
            "simulate",
            "--scenario",
            str(path),
            "--preset",
            "tiny",
            "--set",
            "video=false",
            "--set",
            f"max_duration_s={cut}",
        )
        assert code == 0, err
        art = Store(tmp_path / "ws").get(out.strip())
        results[cut] = json.loads(art.file("metrics.json").read_text())["hunav"]
    short, long = results["0.5"], results["2"]
    assert short["completed"] is False and short["time_to_reach_goal_s"] == pytest.approx(0.5)
    assert short["final_distance_to_target_m"] == pytest.approx(0.5, abs=0.05)
    # 1 m at 1 m/s: within 0.2 m of the goal after 0.8 s (the first tick after it)
    assert long["completed"] is True and long["time_to_reach_goal_s"] == pytest.approx(0.85, abs=0.06)
    assert long["final_distance_to_target_m"] == pytest.approx(0.0, abs=1e-6)


def test_fast_paths_match_plain_loops():
    from nsim.crowd.metrics import group_centres_m
    from nsim.crowd.neighbours import closest_points_on_segments

    rng = np.random.default_rng(1)
    pos, heading = rng.normal(size=(7, 40, 2)), rng.uniform(-3, 3, (7, 40))
    gid = rng.integers(-1, 9, 40)
    ahead = pos + 1.5 * np.stack([np.cos(heading), np.sin(heading)], -1)
    loop = np.stack([ahead[:, gid == g].mean(axis=1) for g in np.unique(gid[gid != -1])], axis=1)
    np.testing.assert_allclose(group_centres_m(pos, heading, gid), loop, atol=1e-12)
    points, walls = rng.uniform(0, 20, (500, 2)), rng.uniform(0, 20, (30, 2, 2))
    loop = [
        np.linalg.norm(p - closest_points_on_segments(np.tile(p, (30, 1)), walls), axis=1).min()
        for p in points
    ]
    np.testing.assert_allclose(nearest_wall_distance_m(points, walls, 100.0), loop, atol=1e-12)
