"""Behaviours: HuNavSim's distances, timers and speeds (the default profile), and nsim's tuning.

HuNavSim's numbers are written here as its source gives them (robotics-upo/hunav_sim,
``hunav_agent_manager/behavior_trees/BT*Nav.xml`` and ``src/agent_manager.cpp``), not read from
``PROFILES``, so a change of the table fails these tests.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from nsim.config import ConfigError, from_dict
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
from nsim.crowd.neighbours import closest_points_on_segments
from nsim.crowd.social_force import robot_view

DT = 0.05
T = 300
SEEDS = range(8)
NSIM = BehaviourParams(profile="nsim")
# the robot drives along the x axis from x = -8 at 0.8 m/s (to x = 4)
ROBOT = RobotTrack(
    np.column_stack([-8.0 + 0.8 * DT * np.arange(T + 1), np.zeros(T + 1)]), np.zeros(T + 1), 0.28, 0.3
)
B = Behaviour


def parked(ticks):
    """Spot parked at the origin, facing +x."""
    return RobotTrack(np.zeros((ticks + 1, 2)), np.zeros(ticks + 1), 0.28, 0.3)


def surface_distance_m(traj):
    """Each human's centre to the robot's surface at each tick: ``(T, N)``."""
    u = np.stack([np.cos(traj.robot_heading_rad), np.sin(traj.robot_heading_rad)], axis=-1)
    seg = np.stack([traj.robot_position_m - traj.robot_half_length_m * u, traj.robot_position_m + traj.robot_half_length_m * u], axis=1)
    t, n = traj.position_m.shape[:2]
    q = closest_points_on_segments(traj.position_m.reshape(-1, 2), np.repeat(seg, n, axis=0)).reshape(t, n, 2)
    return np.linalg.norm(traj.position_m - q, axis=-1) - traj.robot_radius_m


def centre_distance_m(traj):
    """Each human's centre to the robot's centre at each tick: ``(T, N)``."""
    return np.linalg.norm(traj.position_m - traj.robot_position_m[:, None, :], axis=-1)


def speed_mps(traj):
    return np.linalg.norm(traj.velocity_mps[:, 0], axis=-1)


def reacting_s(traj):
    return (traj.behaviour_state[:, 0] == beh.REACTING).sum() * DT


# --------------------------------------------------------------------------------------------
# The profiles


def test_default_profile_is_hunavsim_with_its_numbers():
    p = BehaviourParams().resolved()
    assert p.profile == "hunavsim"
    # IsRobotVisible distances (BT*Nav.xml), centre to centre
    assert (p.surprised_detection_distance_m, p.scared_detection_distance_m) == (4.0, 3.0)
    assert (p.curious_detection_distance_m, p.threatening_detection_distance_m) == (10.0, 4.0)
    assert p.regular_detection_distance_m == 0.0  # regular and impassive trees have no condition
    # lineOfSight: |angle| <= pi / 2 + 0.17
    assert p.field_of_view_deg == pytest.approx(2 * math.degrees(math.pi / 2 + 0.17))
    # TimeExpiredCondition seconds: surprised 30, scared 40, curious 30, threatening 40
    assert (p.surprised_duration_s, p.scared_duration_s, p.curious_duration_s, p.threatening_duration_s) == (
        30.0, 40.0, 30.0, 40.0,
    )
    # avoidRobot: desiredVelocity = 0.6, force 20 * forceSigmaObstacle (0.2) / d
    assert (p.scared_max_speed_mps, p.scared_speed_factor) == (0.6, 1.0)
    assert p.scared_strength_mps2 * p.scared_range_m == pytest.approx(4.0)
    # approximateRobot: 1.8 * dist / 10, stops within 1.5 m; blockRobot: 2 m/s, 1.1 m, looks within 1.2 m
    assert (p.curious_speed_mps, p.curious_stop_distance_m) == (1.8, 1.5)
    assert (p.threatening_speed_mps, p.threatening_front_distance_m, p.threatening_look_distance_m) == (
        2.0, 1.1, 1.2,
    )


def test_nsim_profile_keeps_the_earlier_tuning():
    p = NSIM.resolved()
    # the values BehaviourParams had before profiles existed
    assert p.field_of_view_deg == 200.0 and p.line_of_sight
    assert {
        p.regular_detection_distance_m,
        p.surprised_detection_distance_m,
        p.scared_detection_distance_m,
        p.curious_detection_distance_m,
        p.threatening_detection_distance_m,
    } == {4.0}
    assert (p.surprised_duration_s, p.curious_duration_s, p.threatening_duration_s) == (3.0, 10.0, 10.0)
    assert p.scared_duration_s == math.inf
    assert (p.scared_strength_mps2, p.scared_range_m, p.scared_speed_factor) == (6.0, 1.5, 0.6)
    assert p.scared_max_speed_mps == math.inf
    assert (p.curious_speed_mps, p.curious_stop_distance_m) == (0.6, 1.0)
    assert (p.threatening_speed_mps, p.threatening_front_distance_m) == (1.6, 0.8)


def test_a_number_set_overrides_its_profile_and_configs_load_strictly():
    p = BehaviourParams(curious_speed_mps=1.0).resolved()
    assert p.curious_speed_mps == 1.0 and p.curious_stop_distance_m == 1.5
    assert from_dict(BehaviourParams, {"profile": "nsim"}).resolved() == NSIM.resolved()
    assert BehaviourParams().resolved().resolved() == BehaviourParams().resolved()
    with pytest.raises(ConfigError, match="profile: 'helbing' is not one of hunavsim, nsim"):
        from_dict(BehaviourParams, {"profile": "helbing"})
    with pytest.raises(ConfigError, match="scared_detection_distance_m: expected float > 0"):
        from_dict(BehaviourParams, {"scared_detection_distance_m": -1})
    with pytest.raises(ValueError, match="curious_speed_mps"):
        BehaviourParams(curious_speed_mps=0.0)


# --------------------------------------------------------------------------------------------
# hunavsim: perception and the clock


@pytest.mark.parametrize(
    ("behaviour", "limit_m"),
    [(B.SURPRISED, 4.0), (B.SCARED, 3.0), (B.CURIOUS, 10.0), (B.THREATENING, 4.0)],
)
def test_hunavsim_detection_distance_is_centre_to_centre(behaviour, limit_m):
    robot = RobotState(np.zeros(2), np.zeros(2), 0.0, 0.28, 0.3)  # capsule: its nose at x = 0.58
    pos = np.array([[limit_m - 0.01, 0.0], [limit_m + 0.01, 0.0]])  # on its axis, ahead, facing it
    seen = beh.robot_detected(
        np.full(2, behaviour, np.int8), pos, np.full(2, math.pi), robot_view(pos, robot), np.zeros((0, 2, 2)),
        BehaviourParams(),
    )
    np.testing.assert_array_equal(seen, [True, False])  # to the surface the second is 0.57 m nearer


def test_hunavsim_regular_and_impassive_never_react():
    robot = RobotState(np.zeros(2), np.zeros(2), 0.0, 0.28, 0.3)
    pos = np.array([[1.0, 0.0], [1.0, 0.0]])
    codes = np.array([B.REGULAR, B.IMPASSIVE], np.int8)
    seen = beh.robot_detected(codes, pos, np.full(2, math.pi), robot_view(pos, robot), np.zeros((0, 2, 2)), BehaviourParams())
    assert not seen.any()
    marked = beh.robot_detected(codes, pos, np.full(2, math.pi), robot_view(pos, robot), np.zeros((0, 2, 2)), NSIM)
    assert marked.all()  # nsim: they mark it (behaviour_state 1, no change of motion)


def test_hunavsim_field_of_view():
    robot = RobotState(np.zeros(2), np.zeros(2), 0.0, 0.28, 0.3)
    pos = np.array([[2.0, 0.0], [2.0, 0.0]])
    half = math.pi / 2 + 0.17  # HuNavSim: the robot is visible within this of the heading
    heading = np.array([math.pi + half - 0.01, math.pi + half + 0.01])
    seen = beh.robot_detected(
        np.full(2, B.SURPRISED, np.int8), pos, heading, robot_view(pos, robot), np.zeros((0, 2, 2)), BehaviourParams()
    )
    np.testing.assert_array_equal(seen, [True, False])


def _clock_run(params, seen_pattern, codes):
    state, timer = np.zeros(len(codes), np.int8), np.zeros(len(codes))
    states = []
    for seen in seen_pattern:
        state, timer = beh.update_behaviour_states(codes, state, timer, np.full(len(codes), seen), None, params, DT)
        states.append(state)
    return np.array(states)


def test_hunavsim_clock_counts_seen_time_once_per_run_and_scared_rearms():
    codes = np.array([B.SURPRISED, B.SCARED, B.CURIOUS, B.THREATENING], np.int8)
    # seen for 10 s, out of sight for 5 s, seen again for 50 s
    pattern = [True] * 200 + [False] * 100 + [True] * 1000
    states = _clock_run(BehaviourParams(), pattern, codes)
    seen = np.array(pattern)
    for k, limit_s in enumerate([30.0, 40.0, 30.0, 40.0]):
        reacting = states[:, k] == beh.REACTING
        assert not reacting[~seen].any()  # only on ticks it sees the robot
        first_stop = int(np.argmax(states[:, k] == beh.DONE))
        assert abs(reacting[:first_stop].sum() * DT - limit_s) <= DT + 1e-9  # seen time, pause excluded
        assert first_stop * DT == pytest.approx(limit_s + 5.0, abs=2 * DT)
    # one-shot: done for good, though the robot is still in sight
    for k in (0, 2, 3):
        first_stop = int(np.argmax(states[:, k] == beh.DONE))
        assert (states[first_stop:, k] == beh.DONE).all()
    # scared re-arms: one tick off, then reacting again for another 40 s
    stops = np.flatnonzero(states[:, 1] == beh.DONE)
    assert len(stops) == 1 and states[stops[0] + 1, 1] == beh.REACTING
    assert (states[stops[0] + 1 :, 1] == beh.REACTING).all()


def test_hunavsim_clock_without_a_robot_keeps_its_time():
    codes = np.array([B.SURPRISED], np.int8)
    p = BehaviourParams()
    state, timer = beh.update_behaviour_states(codes, np.array([1], np.int8), np.array([12.0]), np.array([False]), None, p, DT)
    assert state[0] == beh.NAVIGATING and timer[0] == 12.0


# --------------------------------------------------------------------------------------------
# hunavsim: reactions


def _reactions(codes, pos, states=None, params=None):
    robot = RobotState(np.zeros(2), np.zeros(2), 0.0, 0.28, 0.3)
    states = np.full(len(codes), beh.REACTING, np.int8) if states is None else states
    return beh.behaviour_reactions(
        np.array(codes, np.int8), states, np.array(pos, float), robot,
        robot_view(np.array(pos, float), robot), params or BehaviourParams(),
    )


def test_hunavsim_reactions_hand_computed():
    codes = [B.REGULAR, B.IMPASSIVE, B.SURPRISED, B.SCARED, B.CURIOUS, B.CURIOUS, B.THREATENING]
    pos = [[0, 3], [0, 3], [0, 3], [0, 3], [0, 5], [0, 1.4], [0, 3.5]]
    r = _reactions(codes, pos)
    np.testing.assert_array_equal(r.robot_law, [beh.ROBOT_AS_AGENT, beh.ROBOT_AS_OBSTACLE] + [beh.ROBOT_IGNORED] * 5)
    np.testing.assert_array_equal(r.hold, [False, False, True, False, False, True, False])  # freeze in place
    np.testing.assert_array_equal(r.look_at_robot, [False, False, True, False, False, True, False])
    np.testing.assert_allclose(r.look_at_m[2], [0.0, 0.0])  # its centre
    # scared: desired speed and speed at most 0.6 m/s (absolute), no multiplier
    assert r.speed_limit_mps[3] == 0.6 and r.speed_factor[3] == 1.0 and r.scared[3]
    # curious 5 m away: to the robot's centre at 1.8 * 5 / 10 m/s, stopping 1.5 m from it
    np.testing.assert_allclose(r.target_m[4], [0.0, 0.0])
    assert r.target_speed_mps[4] == pytest.approx(0.9) and r.stop_distance_m[4] == 1.5
    # threatening: 2 m/s to 1.1 m *ahead* of the robot's centre (HuNavSim's (sin h, cos h) is beside it)
    np.testing.assert_allclose(r.target_m[6], [1.1, 0.0])
    assert r.target_speed_mps[6] == 2.0 and r.override[6]


def test_hunavsim_non_regular_humans_ignore_the_robot_also_when_not_reacting():
    codes = [B.REGULAR, B.IMPASSIVE, B.SURPRISED, B.SCARED, B.CURIOUS, B.THREATENING]
    r = _reactions(codes, [[0, 3]] * 6, states=np.zeros(6, np.int8))
    np.testing.assert_array_equal(r.robot_law, [beh.ROBOT_AS_AGENT, beh.ROBOT_AS_OBSTACLE] + [beh.ROBOT_IGNORED] * 4)
    n = _reactions(codes, [[0, 3]] * 6, states=np.zeros(6, np.int8), params=NSIM)
    np.testing.assert_array_equal(n.robot_law, [beh.ROBOT_AS_AGENT, beh.ROBOT_AS_OBSTACLE] + [beh.ROBOT_AS_AGENT] * 4)


def test_hunavsim_surprised_walker_freezes_for_30_s_and_resumes():
    # walking across the parked robot's path, 3 m ahead of it
    s = CrowdState.create([[3.0, -5.0]], [[3.0, 5.0]], behaviour=B.SURPRISED)
    tr = rollout(s, 800, DT, robot=parked(800))
    reacting = tr.behaviour_state[:, 0] == beh.REACTING
    start = int(np.argmax(reacting))
    d = centre_distance_m(tr)[:, 0]
    assert d[start - 1] <= 4.0 < d[start - 2]  # seen from 4 m, centre to centre
    assert abs(reacting_s(tr) - 30.0) < 2 * DT
    assert (speed_mps(tr)[reacting] == 0.0).all()  # stands still (HuNavSim skips the update)
    to_robot = -tr.position_m[start + 100, 0]
    assert abs(math.remainder(tr.heading_rad[start + 100, 0] - math.atan2(to_robot[1], to_robot[0]), math.tau)) < 0.05
    assert tr.behaviour_state[-1, 0] == beh.DONE  # once per run, though the robot is still there
    assert tr.position_m[-1, 0, 1] > 4.5  # then carried on to its goal


def test_hunavsim_curious_approaches_at_its_distance_law_and_stops_at_1_5_m():
    # standing 8 m from the parked robot, looking at it
    s = CrowdState.create([[0.0, 8.0]], [[0.0, 8.0]], heading_rad=-math.pi / 2, behaviour=B.CURIOUS)
    tr = rollout(s, 800, DT, robot=parked(800))
    d = centre_distance_m(tr)[:, 0]
    v = speed_mps(tr)
    assert tr.behaviour_state[1, 0] == beh.REACTING  # seen at 8 m (curious see 10 m)
    approach = (tr.behaviour_state[1:, 0] == beh.REACTING) & (d[:-1] > 3.0) & (d[:-1] < 6.0)
    mid = np.flatnonzero(approach) + 1  # tick k moved at the speed chosen at k - 1
    assert len(mid) > 10
    np.testing.assert_allclose(v[mid], 1.8 * d[mid - 1] / 10.0, rtol=0.15)
    assert v.max() <= 1.8 * 8.0 / 10.0 + 0.05
    assert abs(d[300] - 1.5) < 0.1  # stopped at 1.5 m, centre to centre
    assert v[250:550].max() < 0.02
    assert abs(math.remainder(tr.heading_rad[300, 0] + math.pi / 2, math.tau)) < 0.05  # facing it
    assert abs(reacting_s(tr) - 30.0) < 2 * DT
    assert np.linalg.norm(tr.position_m[-1, 0] - [0.0, 8.0]) < 1.0  # then back to where it stood


def test_hunavsim_threatening_runs_to_the_point_ahead_of_the_robot():
    s = CrowdState.create([[0.0, 3.5]], [[0.0, 3.5]], heading_rad=-math.pi / 2, behaviour=B.THREATENING)
    tr = rollout(s, 200, DT, robot=parked(200))
    assert tr.behaviour_state[1, 0] == beh.REACTING  # seen at 3.5 m
    np.testing.assert_allclose(tr.position_m[-1, 0], [1.1, 0.0], atol=0.1)  # ahead, not beside
    assert abs(math.remainder(tr.heading_rad[-1, 0] - math.pi, math.tau)) < 0.05  # within 1.2 m: faces it
    assert 1.4 < speed_mps(tr).max() <= 2.0 * 1.3 + 1e-9


def test_hunavsim_scared_walker_never_exceeds_0_6_mps_while_reacting():
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        y0 = rng.uniform(-0.5, 0.5)
        s = CrowdState.create([[6.0, y0]], [[-6.0, y0]], behaviour=B.SCARED)
        tr = rollout(s, T, DT, robot=parked(T), seed=seed)
        reacting = tr.behaviour_state[:, 0] == beh.REACTING
        assert reacting.any()
        assert speed_mps(tr)[reacting].max() <= 0.6 + 1e-9
        first = int(np.argmax(reacting))
        assert centre_distance_m(tr)[first - 1, 0] <= 3.0  # seen from 3 m


def test_hunavsim_scared_repulsion_hand_computed():
    robot = RobotState(np.zeros(2), np.zeros(2), 0.0, 0.28, 0.3)
    pos = np.array([[2.0, 0.0], [0.0, 2.0], [0.2, 0.0], [3.0, 0.0]])
    radius = np.full(4, 0.25)
    f = beh.scared_repulsion(pos, radius, robot_view(pos, robot), np.array([True, True, True, False]), BehaviourParams())
    # 20 * 0.2 / d from the robot's centre, d = centre distance - the human's radius
    np.testing.assert_allclose(
        f, [[4.0 / 1.75, 0.0], [0.0, 4.0 / 1.75], [4.0 / beh.SCARED_MIN_DISTANCE_M, 0.0], [0.0, 0.0]], atol=1e-12
    )


# --------------------------------------------------------------------------------------------
# nsim: the earlier tuning, unchanged


def oncoming_walker(behaviour, seed, params=NSIM):
    """A human walking towards the robot, slightly off its path; returns the rollout."""
    rng = np.random.default_rng(seed)
    y0, x0 = rng.uniform(-0.8, 0.8), rng.uniform(6.0, 9.0)
    s = CrowdState.create([[x0, y0]], [[-10.0, y0]], behaviour=behaviour)
    return rollout(s, T, DT, robot=ROBOT, behaviours=params, seed=seed)


def bystander(behaviour, seed, params=NSIM):
    """A human standing 2.5-3.5 m beside the robot's path, looking at where it comes from."""
    rng = np.random.default_rng(seed)
    x0, y0 = rng.uniform(-2.0, 2.0), rng.choice([-1.0, 1.0]) * rng.uniform(2.5, 3.5)
    s = CrowdState.create([[x0, y0]], [[x0, y0]], heading_rad=math.atan2(-y0, -4.0 - x0), behaviour=behaviour)
    return rollout(s, T, DT, robot=ROBOT, behaviours=params, seed=seed)


def min_distance(traj):
    return float(surface_distance_m(traj)[:, 0].min())


@pytest.mark.parametrize("scenario", [oncoming_walker, bystander])
def test_nsim_scared_keeps_more_distance_than_regular(scenario):
    regular = np.array([min_distance(scenario(Behaviour.REGULAR, s)) for s in SEEDS])
    scared = np.array([min_distance(scenario(Behaviour.SCARED, s)) for s in SEEDS])
    assert scared.mean() > regular.mean() + 0.15
    assert np.count_nonzero(scared > regular) >= len(SEEDS) - 1  # paired runs: same start, same seed


def test_nsim_curious_approaches_the_robot():
    params = NSIM.resolved()
    for seed in SEEDS:
        regular, curious = bystander(Behaviour.REGULAR, seed), bystander(Behaviour.CURIOUS, seed)
        d_regular, d_curious = surface_distance_m(regular)[:, 0], surface_distance_m(curious)[:, 0]
        assert d_curious.min() < d_regular.min() - 0.7
        assert d_curious.min() < params.curious_stop_distance_m + 0.6
        assert d_curious.min() > params.curious_stop_distance_m - 0.3  # stops short of it
        assert (curious.behaviour_state[:, 0] == beh.REACTING).any()


def test_nsim_curious_human_looks_at_a_parked_robot():
    s = CrowdState.create([[0.0, 3.5]], [[0.0, 3.5]], heading_rad=-math.pi / 2, behaviour=Behaviour.CURIOUS)
    tr = rollout(s, 240, DT, robot=parked(240), behaviours=NSIM)
    d = surface_distance_m(tr)[:, 0]
    assert abs(d[150] - NSIM.resolved().curious_stop_distance_m) < 0.3  # the robot's repulsion keeps it a bit off
    assert np.linalg.norm(tr.velocity_mps[150, 0]) < 0.05
    assert abs(tr.heading_rad[150, 0] + math.pi / 2) < 0.05  # facing the robot
    assert abs(reacting_s(tr) - NSIM.resolved().curious_duration_s) < 2 * DT
    assert tr.behaviour_state[-1, 0] == beh.DONE


def test_nsim_surprised_walker_stops_looks_and_resumes():
    # walking across the robot's path, 3 m ahead of it; the robot is parked
    s = CrowdState.create([[3.0, -5.0]], [[3.0, 5.0]], behaviour=Behaviour.SURPRISED)
    tr = rollout(s, 300, DT, robot=parked(300), behaviours=NSIM)
    reacting = tr.behaviour_state[:, 0] == beh.REACTING
    assert reacting.any()
    start = int(np.argmax(reacting))
    assert abs(reacting_s(tr) - NSIM.resolved().surprised_duration_s) < 2 * DT
    speed = speed_mps(tr)
    assert speed[start + 30 : start + 55].max() < 0.1  # stood (nearly) still 1.5 s after noticing
    to_robot = -tr.position_m[start + 40, 0]
    assert (
        abs(math.remainder(tr.heading_rad[start + 40, 0] - math.atan2(to_robot[1], to_robot[0]), math.tau))
        < 0.1
    )
    assert tr.position_m[-1, 0, 1] > 4.5  # then carried on to its goal


def test_nsim_threatening_human_blocks_the_robot():
    params = NSIM.resolved()
    for seed in SEEDS:
        tr = bystander(Behaviour.THREATENING, seed)
        rel = tr.position_m[:, 0] - tr.robot_position_m  # the robot heads +x
        ahead = (rel[:, 0] > 0.3 + 0.28) & (np.abs(rel[:, 1]) < 0.35)
        assert ahead.any(), f"seed {seed}: never got in front of the robot"
        assert min_distance(tr) < params.threatening_front_distance_m


@pytest.mark.parametrize("params", [BehaviourParams(), NSIM], ids=["hunavsim", "nsim"])
def test_regular_and_impassive_do_not_change_goals(params):
    for b in (Behaviour.REGULAR, Behaviour.IMPASSIVE):
        tr = bystander(b, 0, params)
        assert np.linalg.norm(tr.position_m[-1, 0] - tr.position_m[0, 0]) < 0.3


def test_nsim_detection_needs_range_field_of_view_and_line_of_sight():
    robot = RobotState(np.array([0.0, 0.0]), np.zeros(2), 0.0, 0.3)
    pos = np.array([[3.0, 0.0], [3.0, 0.0], [0.0, 3.0], [-6.0, 0.0]])
    heading = np.array([math.pi, 0.0, -math.pi / 2, 0.0])  # facing it, facing away, facing it, facing it
    codes = np.full(4, B.SURPRISED, np.int8)
    view = robot_view(pos, robot)
    wall = np.array([[[-1.0, 1.5], [1.0, 1.5]]])  # between the robot and human 2
    seen = beh.robot_detected(codes, pos, heading, view, wall, NSIM)
    np.testing.assert_array_equal(seen, [True, False, False, False])
    unblocked = beh.robot_detected(codes, pos, heading, view, wall, BehaviourParams(profile="nsim", line_of_sight=False))
    np.testing.assert_array_equal(unblocked, [True, False, True, False])
    # nsim measures to the surface: 4.29 m from the centre of a 0.3 m robot is 3.99 m from its body
    far = np.array([[4.29, 0.0], [4.31, 0.0]])
    seen = beh.robot_detected(codes[:2], far, np.full(2, math.pi), robot_view(far, robot), np.zeros((0, 2, 2)), NSIM)
    np.testing.assert_array_equal(seen, [True, False])


def test_nsim_state_machine_transitions():
    params = BehaviourParams(profile="nsim", surprised_duration_s=0.1)
    b = np.array([Behaviour.SURPRISED, Behaviour.SCARED], dtype=np.int8)

    def view(d):
        return beh.RobotView(np.zeros((2, 2)), np.array([d, d]), np.zeros(2), np.array([d, d]) + 0.3)

    near, far = view(2.0), view(5.0)
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


def test_time_step_warning_counts_only_behaviours_someone_has(caplog):
    # 1.3 x 1.0 m/s x 0.08 s < half a radius; a threatening human (2 m/s) would not be
    calm = CrowdState.create([[0.0, 0.0], [0.0, 2.0]], [[5.0, 0.0], [5.0, 2.0]], desired_speed_mps=1.0)
    with caplog.at_level("WARNING", logger="nsim.crowd.rollout"):
        rollout(calm, 2, 0.08)
    assert not [r for r in caplog.records if "half their radius" in r.getMessage()]
    threat = CrowdState.create(
        [[0.0, 0.0], [0.0, 2.0]], [[5.0, 0.0], [5.0, 2.0]], desired_speed_mps=1.0, behaviour=[1, 6]
    )
    with caplog.at_level("WARNING", logger="nsim.crowd.rollout"):
        rollout(threat, 2, 0.08)
    assert [r for r in caplog.records if "half their radius" in r.getMessage()]


def test_behaviour_codes():
    np.testing.assert_array_equal(behaviour_codes(["regular", "Scared", "threatening"]), [1, 4, 6])
    with pytest.raises(ValueError, match="'angry' is not one of regular, impassive"):
        behaviour_codes(["angry"])
