"""HuNavSim behaviours: perception, the state machine, and each reaction over seeded runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nsim.crowd import (
    Behaviour,
    BehaviourParams,
    CrowdState,
    RobotState,
    RobotTrack,
    behaviour_codes,
    rollout,
)
from nsim.crowd import behaviours as beh
from nsim.crowd.metrics import robot_distance_m
from nsim.crowd.social_force import robot_view

DT = 0.05
T = 300
SEEDS = range(8)
# the robot drives along the x axis from x = -8 at 0.8 m/s (to x = 4)
ROBOT = RobotTrack(
    np.column_stack([-8.0 + 0.8 * DT * np.arange(T + 1), np.zeros(T + 1)]), np.zeros(T + 1), 0.28, 0.3
)


def oncoming_walker(behaviour, seed):
    """A human walking towards the robot, slightly off its path; returns the rollout."""
    rng = np.random.default_rng(seed)
    y0, x0 = rng.uniform(-0.8, 0.8), rng.uniform(6.0, 9.0)
    s = CrowdState.create([[x0, y0]], [[-10.0, y0]], behaviour=behaviour)
    return rollout(s, T, DT, robot=ROBOT, seed=seed)


def bystander(behaviour, seed):
    """A human standing 2.5-3.5 m beside the robot's path, looking at where it comes from."""
    rng = np.random.default_rng(seed)
    x0, y0 = rng.uniform(-2.0, 2.0), rng.choice([-1.0, 1.0]) * rng.uniform(2.5, 3.5)
    s = CrowdState.create([[x0, y0]], [[x0, y0]], heading_rad=math.atan2(-y0, -4.0 - x0), behaviour=behaviour)
    return rollout(s, T, DT, robot=ROBOT, seed=seed)


def min_distance(traj):
    return float(robot_distance_m(traj)[:, 0].min())


@pytest.mark.parametrize("scenario", [oncoming_walker, bystander])
def test_scared_keeps_more_distance_than_regular(scenario):
    regular = np.array([min_distance(scenario(Behaviour.REGULAR, s)) for s in SEEDS])
    scared = np.array([min_distance(scenario(Behaviour.SCARED, s)) for s in SEEDS])
    assert scared.mean() > regular.mean() + 0.15
    assert np.count_nonzero(scared > regular) >= len(SEEDS) - 1  # paired runs: same start, same seed


def test_curious_approaches_the_robot():
    params = BehaviourParams()
    for seed in SEEDS:
        regular, curious = bystander(Behaviour.REGULAR, seed), bystander(Behaviour.CURIOUS, seed)
        d_regular, d_curious = robot_distance_m(regular)[:, 0], robot_distance_m(curious)[:, 0]
        assert d_curious.min() < d_regular.min() - 0.7
        assert d_curious.min() < params.curious_stop_distance_m + 0.6
        assert d_curious.min() > params.curious_stop_distance_m - 0.3  # stops short of it
        assert (curious.behaviour_state[:, 0] == beh.REACTING).any()


def test_curious_human_looks_at_a_parked_robot():
    parked = RobotTrack(np.zeros((241, 2)), np.zeros(241), 0.28, 0.3)
    s = CrowdState.create([[0.0, 3.5]], [[0.0, 3.5]], heading_rad=-math.pi / 2, behaviour=Behaviour.CURIOUS)
    tr = rollout(s, 240, DT, robot=parked)
    d = robot_distance_m(tr)[:, 0]
    assert (
        abs(d[150] - BehaviourParams().curious_stop_distance_m) < 0.3
    )  # the robot's repulsion keeps it a bit off
    assert np.linalg.norm(tr.velocity_mps[150, 0]) < 0.05
    assert abs(tr.heading_rad[150, 0] + math.pi / 2) < 0.05  # facing the robot
    reacting_s = (tr.behaviour_state[:, 0] == beh.REACTING).sum() * DT
    assert abs(reacting_s - BehaviourParams().curious_duration_s) < 2 * DT
    assert tr.behaviour_state[-1, 0] == beh.DONE


def test_surprised_walker_stops_looks_and_resumes():
    # walking across the robot's path, 3 m ahead of it; the robot is parked
    parked = RobotTrack(np.zeros((301, 2)), np.zeros(301), 0.28, 0.3)
    s = CrowdState.create([[3.0, -5.0]], [[3.0, 5.0]], behaviour=Behaviour.SURPRISED)
    tr = rollout(s, 300, DT, robot=parked)
    reacting = tr.behaviour_state[:, 0] == beh.REACTING
    assert reacting.any()
    start = int(np.argmax(reacting))
    duration = reacting.sum() * DT
    assert abs(duration - BehaviourParams().surprised_duration_s) < 2 * DT
    speed = np.linalg.norm(tr.velocity_mps[:, 0], axis=-1)
    assert speed[start + 30 : start + 55].max() < 0.1  # stood (nearly) still 1.5 s after noticing
    to_robot = -tr.position_m[start + 40, 0]
    assert (
        abs(math.remainder(tr.heading_rad[start + 40, 0] - math.atan2(to_robot[1], to_robot[0]), math.tau))
        < 0.1
    )
    assert tr.position_m[-1, 0, 1] > 4.5  # then carried on to its goal


def test_threatening_human_blocks_the_robot():
    params = BehaviourParams()
    for seed in SEEDS:
        tr = bystander(Behaviour.THREATENING, seed)
        rel = tr.position_m[:, 0] - tr.robot_position_m  # the robot heads +x
        ahead = (rel[:, 0] > 0.3 + 0.28) & (np.abs(rel[:, 1]) < 0.35)
        assert ahead.any(), f"seed {seed}: never got in front of the robot"
        assert min_distance(tr) < params.threatening_front_distance_m


def test_regular_and_impassive_do_not_change_goals():
    for b in (Behaviour.REGULAR, Behaviour.IMPASSIVE):
        tr = bystander(b, 0)
        assert np.linalg.norm(tr.position_m[-1, 0] - tr.position_m[0, 0]) < 0.3


def test_detection_needs_range_field_of_view_and_line_of_sight():
    robot = RobotState(np.array([0.0, 0.0]), np.zeros(2), 0.0, 0.3)
    pos = np.array([[3.0, 0.0], [3.0, 0.0], [0.0, 3.0], [-6.0, 0.0]])
    heading = np.array([math.pi, 0.0, -math.pi / 2, 0.0])  # facing it, facing away, facing it, facing it
    params = BehaviourParams(detection_distance_m=4.0, field_of_view_deg=200.0)
    view = robot_view(pos, robot)
    wall = np.array([[[-1.0, 1.5], [1.0, 1.5]]])  # between the robot and human 2
    seen = beh.robot_detected(pos, heading, view, wall, params)
    np.testing.assert_array_equal(seen, [True, False, False, False])
    unblocked = beh.robot_detected(pos, heading, view, wall, BehaviourParams(line_of_sight=False))
    np.testing.assert_array_equal(unblocked, [True, False, True, False])


def test_state_machine_transitions():
    params = BehaviourParams(detection_distance_m=4.0, surprised_duration_s=0.1)
    b = np.array([Behaviour.SURPRISED, Behaviour.SCARED], dtype=np.int8)
    near = beh.RobotView(np.zeros((2, 2)), np.array([2.0, 2.0]))
    far = beh.RobotView(np.zeros((2, 2)), np.array([5.0, 5.0]))
    state, timer = np.zeros(2, np.int8), np.zeros(2)
    state, timer = beh.update_behaviour_states(b, state, timer, np.array([True, True]), near, params, DT)
    np.testing.assert_array_equal(state, [beh.REACTING, beh.REACTING])
    state, timer = beh.update_behaviour_states(b, state, timer, np.array([False, False]), near, params, DT)
    np.testing.assert_array_equal(state, [beh.REACTING, beh.REACTING])  # stays while in range
    state, timer = beh.update_behaviour_states(b, state, timer, np.array([False, False]), near, params, DT)
    np.testing.assert_array_equal(state, [beh.DONE, beh.REACTING])  # surprise over after 0.1 s
    state, timer = beh.update_behaviour_states(b, state, timer, np.array([True, True]), near, params, DT)
    np.testing.assert_array_equal(state, [beh.DONE, beh.REACTING])  # no re-trigger while in range
    state, timer = beh.update_behaviour_states(b, state, timer, np.array([False, False]), far, params, DT)
    np.testing.assert_array_equal(state, [beh.NAVIGATING, beh.NAVIGATING])  # re-armed
    np.testing.assert_array_equal(timer, [0.0, 0.0])


def test_behaviour_codes():
    np.testing.assert_array_equal(behaviour_codes(["regular", "Scared", "threatening"]), [1, 4, 6])
    with pytest.raises(ValueError, match="'angry' is not one of regular, impassive"):
        behaviour_codes(["angry"])
