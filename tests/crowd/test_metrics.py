"""Crowd metrics on trajectories with known answers: distances, bands, path and nsim's force sums
(HuNavSim's hand cases: ``test_hunav_metrics.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nsim.crowd import CrowdTrajectory, ForceParams
from nsim.crowd.metrics import (
    crowd_metrics,
    cumulative_heading_changes_rad,
    path_irregularity_rad_per_m,
    people_gap_m,
    robot_distance_m,
    robot_social_forces,
    space_intrusions_pct,
    time_to_reach_goal_s,
)
from nsim.crowd.social_force import pair_repulsion

DT = 0.05


def make_traj(robot_xy, humans_xy, robot_heading=None, human_vel=None, robot_radius=0.3, half_length=0.0):
    """A trajectory from arrays: robot_xy (T, 2), humans_xy (T, N, 2)."""
    t, n = humans_xy.shape[:2]
    heading = np.zeros(t) if robot_heading is None else robot_heading
    return CrowdTrajectory(
        time_s=np.arange(t) * DT,
        position_m=humans_xy,
        velocity_mps=np.zeros((t, n, 2)) if human_vel is None else human_vel,
        heading_rad=np.zeros((t, n)),
        behaviour_state=np.zeros((t, n), np.int8),
        gait_phase=np.zeros((t, n)),
        goal_index=np.zeros((t, n), np.int64),
        radius_m=np.full(n, 0.25),
        behaviour=np.ones(n, np.int8),
        group_id=np.full(n, -1),
        has_robot=True,
        robot_position_m=robot_xy,
        robot_velocity_mps=np.gradient(robot_xy, DT, axis=0),
        robot_heading_rad=heading,
        robot_radius_m=robot_radius,
        robot_half_length_m=half_length,
    )


def straight_pass(lateral_m=2.0):
    """The robot drives x = -10 -> 10 at 1 m/s; one human stands at (0, lateral_m)."""
    x = np.arange(-10.0, 10.0 + 1e-9, DT)
    robot = np.column_stack([x, np.zeros_like(x)])
    human = np.broadcast_to([[0.0, lateral_m]], (len(x), 1, 2)).copy()
    return make_traj(robot, human)


def test_distances_and_intrusions_of_a_straight_pass():
    tr = straight_pass(2.0)
    m = crowd_metrics(tr, robot_goal_m=[10.0, 0.0])
    # HuNavSim: the gap between the bodies, centre distance - 0.3 (robot) - 0.25 (human)
    assert m.minimum_distance_to_people_m == pytest.approx(2.0 - 0.3 - 0.25)
    assert m.maximum_distance_to_people_m == pytest.approx(math.hypot(10.0, 2.0) - 0.3)  # robot radius only
    x = tr.robot_position_m[:, 0]
    d = np.hypot(x, 2.0) - 0.3
    assert m.avg_distance_to_closest_person_m == pytest.approx(np.mean(d - 0.25))
    # social band [1.2, 3.6) of the gap: |x| < sqrt(4.15^2 - 4); never personal (gap >= 1.45 m)
    expected = 100.0 * np.mean(np.abs(x) < math.sqrt(4.15**2 - 4.0))
    assert m.social_space_intrusions_pct == pytest.approx(expected)
    assert abs(expected - 100.0 * 2 * math.sqrt(4.15**2 - 4.0) / 20.0) < 1.0
    assert m.intimate_space_intrusions_pct == 0.0 and m.personal_space_intrusions_pct == 0.0
    assert m.path_length_m == pytest.approx(20.0)
    # HuNavSim's goal radius, 0.2 m: first inside at x > 9.8
    assert m.time_to_reach_goal_s == pytest.approx(20.0 - 0.2, abs=DT)
    assert m.completed is True and m.final_distance_to_target_m == pytest.approx(0.0, abs=1e-9)
    assert m.path_irregularity_rad_per_m == 0.0 and m.cumulative_heading_changes_rad == 0.0


def test_close_pass_counts_intimate_and_personal_ticks():
    tr = straight_pass(0.7)  # closest: 0.7 - 0.3 - 0.25 = 0.15 m between the bodies
    gap = np.maximum(people_gap_m(tr)[:, 0], 0.0)
    np.testing.assert_allclose(gap.min(), 0.15, atol=1e-12)
    m = crowd_metrics(tr)
    assert m.intimate_space_intrusions_pct == pytest.approx(100.0 * np.mean(gap < 0.45))
    assert m.personal_space_intrusions_pct == pytest.approx(100.0 * np.mean((gap >= 0.45) & (gap < 1.2)))
    # the gap is < 0.45 while the centres are < 1.0 m apart: |x| < sqrt(1 - 0.49)
    x = tr.robot_position_m[:, 0]
    assert m.intimate_space_intrusions_pct == pytest.approx(100.0 * np.mean(np.abs(x) < math.sqrt(0.51)))
    assert m.intimate_space_intrusions_pct > 0


def test_capsule_robot_distance_is_to_its_surface():
    tr = make_traj(np.zeros((2, 2)), np.array([[[1.5, 0.0], [0.0, 1.5]]] * 2), half_length=0.4)
    np.testing.assert_allclose(robot_distance_m(tr)[0], [1.5 - 0.4 - 0.3, 1.5 - 0.3])


def test_space_intrusions_bands():
    closest = np.array([-0.1, 0.2, 0.45, 1.0, 1.2, 3.0, 3.6, 5.0])
    assert space_intrusions_pct(closest, 0.0, 0.45) == pytest.approx(100 * 2 / 8)
    assert space_intrusions_pct(closest, 0.45, 1.2) == pytest.approx(100 * 2 / 8)
    assert space_intrusions_pct(closest, 1.2, 3.6) == pytest.approx(100 * 2 / 8)


def test_time_to_goal_never_reached_is_the_whole_run():
    # HuNavSim reports the whole recording for a robot that does not get there
    assert time_to_reach_goal_s(np.arange(3.0), np.zeros((3, 2)), np.array([5.0, 0.0]), 0.3) == 2.0
    path = np.array([[0.0, 0.0], [4.5, 0.0], [4.9, 0.0]])
    assert time_to_reach_goal_s(np.arange(3.0), path, np.array([5.0, 0.0]), 0.3) == 2.0
    assert time_to_reach_goal_s(np.arange(3.0), path, np.array([5.0, 0.0]), 0.6) == 1.0


def test_path_irregularity():
    # a zigzag: turning +-45 degrees every metre towards a goal straight ahead
    heading = np.tile([math.pi / 4, -math.pi / 4], 5)
    steps = np.stack([np.cos(heading), np.sin(heading)], -1) * math.sqrt(2)
    pos = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    heading = np.concatenate([[math.pi / 4], heading])
    turning = cumulative_heading_changes_rad(heading)
    assert turning == pytest.approx(9 * math.pi / 2)
    goal = pos[-1]
    needed = math.pi / 4  # from the first heading to the goal direction (+x)
    length = 10 * math.sqrt(2)
    assert path_irregularity_rad_per_m(pos, heading, goal) == pytest.approx((turning - needed) / length)


def test_social_forces_on_robot_and_humans():
    # one human 1.5 m ahead of the robot, both at rest, the robot facing it
    tr = make_traj(np.zeros((2, 2)), np.array([[[1.5, 0.0]], [[1.5, 0.0]]]))
    forces = ForceParams()
    on_robot, on_humans, work = robot_social_forces(tr, np.zeros((0, 2, 2)), forces)
    r_sum = np.array([0.55])
    expected_robot = pair_repulsion(
        np.array([[-1.5, 0.0]]), np.zeros((1, 2)), r_sum, np.array([[1.0, 0.0]]), forces
    )
    expected_human = pair_repulsion(
        np.array([[1.5, 0.0]]), np.zeros((1, 2)), r_sum, np.array([[1.0, 0.0]]), forces
    )
    np.testing.assert_allclose(on_robot, np.linalg.norm(expected_robot))  # facing it: w = 1
    np.testing.assert_allclose(
        on_humans, np.linalg.norm(expected_human)
    )  # the robot is behind it: w = lambda
    np.testing.assert_allclose(work, on_robot + on_humans)  # no walls: |sum| = sum for one human
    assert on_humans[0] == pytest.approx(forces.anisotropy * on_robot[0])


def test_wall_force_adds_to_social_work():
    tr = straight_pass(2.0)
    wall = np.array([[[-20.0, -0.8], [20.0, -0.8]]])  # 0.5 m from the robot's surface
    _, _, no_wall = robot_social_forces(tr, np.zeros((0, 2, 2)), ForceParams())
    _, _, with_wall = robot_social_forces(tr, wall, ForceParams())
    np.testing.assert_allclose(with_wall - no_wall, 10.0 * math.exp((0.3 - 0.8) / 0.2), rtol=1e-9)
    m = crowd_metrics(tr, walls_m=wall)
    assert m.social_work_integral == pytest.approx(with_wall.sum() * DT)


def test_metrics_without_humans():
    tr = make_traj(np.column_stack([np.linspace(0, 1, 11), np.zeros(11)]), np.zeros((11, 0, 2)))
    m = crowd_metrics(tr)
    assert m.minimum_distance_to_people_m == math.inf == m.avg_distance_to_closest_person_m
    assert m.intimate_space_intrusions_pct == m.social_space_intrusions_pct == 0.0
    assert m.group_intimate_space_intrusions_pct == 0.0
    assert m.robot_on_person_collision == m.person_on_robot_collision == 0
    assert math.isnan(m.avg_pedestrian_velocity_mps) and math.isnan(m.avg_closest_pedestrian_velocity_mps)
    assert m.social_work_integral == 0.0 and m.path_length_m == pytest.approx(1.0)
    assert m.social_force_on_robot == m.social_work == 0.0
    # no goal: the goal metrics are undefined
    assert m.completed is None and math.isnan(m.time_to_reach_goal_s)
    assert math.isnan(m.minimum_distance_to_target_m) and math.isnan(m.final_distance_to_target_m)
