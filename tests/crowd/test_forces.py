"""Force terms: hand-computed values for two agents, and the fast paths against loop twins."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nsim.crowd import behaviours as beh
from nsim.crowd.behaviours import BehaviourParams
from nsim.crowd.neighbours import neighbour_pairs, segments_from_polygons
from nsim.crowd.social_force import (
    ForceParams,
    agent_repulsion,
    desired_force,
    desired_velocity,
    group_coherence,
    group_gaze,
    group_repulsion,
    make_walls,
    obstacle_repulsion,
    pair_repulsion,
    robot_repulsion,
    robot_view,
)
from nsim.crowd.state import RobotState
from tests.crowd.reference import agent_repulsion_loop, obstacle_repulsion_loop, pair_force_numeric

P = ForceParams(agent_strength_mps2=2.0, agent_range_m=0.5, anisotropy=0.3, agent_lookahead_s=1.0)
R = np.array([0.25, 0.25])


def test_desired_force_and_velocity():
    np.testing.assert_allclose(desired_force(np.zeros((1, 2)), np.array([[1.3, 0.0]]), 0.5), [[2.6, 0.0]])
    pos = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    target = np.array([[10.0, 0.0], [0.0, 0.5], [0.0, 0.2]])  # 10, 0.5, 0.2 m away
    slow = np.array([False, True, True])
    params = ForceParams(arrival_deceleration_mps2=1.0, relaxation_time_s=0.5)
    v = desired_velocity(pos, np.zeros((3, 2)), target, np.full(3, 1.2), np.zeros(3), slow, params)
    np.testing.assert_allclose(v, [[1.2, 0.0], [0.0, 1.0], [0.0, math.sqrt(0.4)]])  # sqrt(2 a s)
    # braking looks tau ahead: moving at 0.4 m/s towards a target 0.5 m away -> 0.3 m left
    v = desired_velocity(
        pos[1:2], np.array([[0.0, 0.4]]), target[1:2], np.array([1.2]), np.zeros(1), slow[1:2], params
    )
    np.testing.assert_allclose(v, [[0.0, math.sqrt(0.6)]])


def test_two_agents_at_rest_hand_computed():
    # both face +x: agent 0 sees agent 1 ahead (w = 1), agent 1 has agent 0 behind (w = lambda)
    pos = np.array([[0.0, 0.0], [1.0, 0.0]])
    f = agent_repulsion(pos, np.zeros((2, 2)), np.zeros(2), R, np.array([[0, 1]]), P)
    mag = 2.0 * math.exp((0.5 - 1.0) / 0.5)  # A exp((r_i + r_j - d) / B) = 2 / e
    np.testing.assert_allclose(f, [[-mag, 0.0], [0.3 * mag, 0.0]], atol=1e-12)


def test_two_agents_side_by_side_hand_computed():
    # perpendicular: cos(phi) = 0 -> w = lambda + (1 - lambda) / 2 = 0.65
    pos = np.array([[0.0, 0.0], [0.0, 0.8]])
    f = agent_repulsion(pos, np.zeros((2, 2)), np.zeros(2), R, np.array([[0, 1]]), P)
    mag = 2.0 * math.exp((0.5 - 0.8) / 0.5) * 0.65
    np.testing.assert_allclose(f, [[0.0, -mag], [0.0, mag]], atol=1e-12)


def test_approaching_agents_push_harder_than_receding_ones():
    pos = np.array([[0.0, 0.0], [2.0, 0.3]])
    heading = np.array([0.0, math.pi])
    approaching = agent_repulsion(pos, np.array([[1.0, 0], [-1.0, 0]]), heading, R, np.array([[0, 1]]), P)
    receding = agent_repulsion(pos, np.array([[-1.0, 0], [1.0, 0]]), heading, R, np.array([[0, 1]]), P)
    assert np.linalg.norm(approaching[0]) > 3 * np.linalg.norm(receding[0])
    assert approaching[0, 1] < 0 < approaching[1, 1]  # they step aside from each other


@pytest.mark.parametrize("seed", range(5))
def test_pair_repulsion_is_minus_gradient_of_the_potential(seed):
    rng = np.random.default_rng(seed)
    d, y = rng.normal(0, 1.5, 2), rng.normal(0, 1.5, 2)
    heading = rng.normal(size=2)
    heading /= np.linalg.norm(heading)
    f = pair_repulsion(d[None], y[None], np.array([0.5]), heading[None], P)[0]
    np.testing.assert_allclose(f, pair_force_numeric(d, y, 0.5, heading, P), rtol=1e-5, atol=1e-8)


def test_agent_repulsion_matches_loop_twin():
    rng = np.random.default_rng(3)
    n = 60
    pos = rng.uniform(0, 8, (n, 2))
    vel = rng.normal(0, 0.8, (n, 2))
    heading = rng.uniform(-math.pi, math.pi, n)
    radius = rng.uniform(0.2, 0.3, n)
    fast = agent_repulsion(pos, vel, heading, radius, neighbour_pairs(pos, P.agent_cutoff_m), P)
    np.testing.assert_allclose(fast, agent_repulsion_loop(pos, vel, heading, radius, P), rtol=1e-5, atol=1e-7)


def test_obstacle_repulsion_hand_computed():
    walls = make_walls(np.array([[[-1.0, 0.0], [1.0, 0.0]]]), ForceParams())
    f = obstacle_repulsion(np.array([[0.0, 0.5]]), np.array([0.25]), walls, ForceParams())
    np.testing.assert_allclose(f, [[0.0, 10.0 * math.exp((0.25 - 0.5) / 0.2)]], atol=1e-12)


def test_corner_counts_once():
    # two segments meeting at (0, 0); the agent's nearest point on both is the corner
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]], [[0.0, 0.0], [0.0, 1.0]]])
    f = obstacle_repulsion(
        np.array([[-0.3, -0.3]]), np.array([0.25]), make_walls(segs, ForceParams()), ForceParams()
    )
    d = math.hypot(0.3, 0.3)
    mag = 10.0 * math.exp((0.25 - d) / 0.2)
    np.testing.assert_allclose(f, [[-mag / math.sqrt(2), -mag / math.sqrt(2)]], atol=1e-12)


def test_obstacle_repulsion_matches_loop_twin():
    rng = np.random.default_rng(4)
    boxes = []
    for _ in range(12):
        x, y = rng.uniform(0, 10, 2)
        w, h = rng.uniform(0.3, 2, 2)
        boxes.append(np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]]))
    segs = segments_from_polygons(boxes)
    pos = rng.uniform(-1, 11, (300, 2))
    radius = np.full(300, 0.25)
    fast = obstacle_repulsion(pos, radius, make_walls(segs, ForceParams()), ForceParams())
    np.testing.assert_allclose(fast, obstacle_repulsion_loop(pos, radius, segs, ForceParams()), atol=1e-10)


def test_robot_repulsion_by_law():
    robot = RobotState(np.array([0.0, 0.0]), np.zeros(2), 0.0, radius_m=0.3, half_length_m=0.4)
    pos = np.array([[1.5, 0.0], [0.0, 1.5], [0.0, 1.5]])  # ahead of the robot's nose, beside its flank
    heading = np.array([math.pi, -math.pi / 2, -math.pi / 2])  # all facing the robot
    view = robot_view(pos, robot)
    np.testing.assert_allclose(view.closest_m, [[0.4, 0.0], [0.0, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(view.surface_distance_m, [1.1 - 0.3, 1.5 - 0.3, 1.5 - 0.3])
    np.testing.assert_allclose(view.centre_m, [0.0, 0.0])
    np.testing.assert_allclose(view.centre_distance_m, [1.5, 1.5, 1.5])
    radius = np.full(3, 0.25)
    law = np.array([beh.ROBOT_AS_AGENT, beh.ROBOT_AS_OBSTACLE, beh.ROBOT_IGNORED])
    f = robot_repulsion(pos, np.zeros((3, 2)), heading, radius, robot, view, law, P)
    agent_mag = 2.0 * math.exp((0.55 - 1.1) / 0.5)  # facing it: w = 1
    wall_mag = P.obstacle_strength_mps2 * math.exp((0.55 - 1.5) / P.obstacle_range_m)
    np.testing.assert_allclose(f, [[agent_mag, 0.0], [0.0, wall_mag], [0.0, 0.0]], atol=1e-12)


def test_scared_repulsion_hand_computed():
    robot = RobotState(np.array([0.0, 0.0]), np.zeros(2), 0.0, radius_m=0.3)
    pos = np.array([[2.0, 0.0], [0.0, 2.0]])
    radius = np.full(2, 0.25)
    # nsim: A exp(-d / B), d to the robot's surface (A, B not the profile's)
    params = BehaviourParams(profile="nsim", scared_strength_mps2=4.0, scared_range_m=1.0)
    f = beh.scared_repulsion(pos, radius, robot_view(pos, robot), np.array([True, False]), params)
    np.testing.assert_allclose(f, [[4.0 * math.exp(-1.7), 0.0], [0.0, 0.0]], atol=1e-12)
    # hunavsim: A B / d, d from the robot's centre less the human's radius
    params = BehaviourParams(scared_strength_mps2=4.0, scared_range_m=1.0)
    f = beh.scared_repulsion(pos, radius, robot_view(pos, robot), np.array([True, False]), params)
    np.testing.assert_allclose(f, [[4.0 / 1.75, 0.0], [0.0, 0.0]], atol=1e-12)


def test_group_coherence_hand_computed():
    pos = np.array([[0.0, 0.0], [4.0, 0.0], [2.0, 0.0], [9.0, 9.0]])
    f = group_coherence(pos, np.array([7, 7, 7, -1]), P)
    # centre (2, 0); threshold (n - 1) / 2 = 1 m: the outer two are pulled with beta_2 = 2
    np.testing.assert_allclose(f, [[2.0, 0.0], [-2.0, 0.0], [0.0, 0.0], [0.0, 0.0]])


def test_group_repulsion_hand_computed():
    pos = np.array([[0.0, 0.0], [0.6, 0.0], [0.0, 0.65]])  # 0-1 and 0-2 closer than 0.25 + 0.25 + 0.2
    gid = np.array([1, 1, 2])
    f = group_repulsion(pos, np.full(3, 0.25), gid, neighbour_pairs(pos, 3.0), P)
    np.testing.assert_allclose(f, [[-1.0, 0.0], [1.0, 0.0], [0.0, 0.0]])  # 2 is in another group


def test_group_gaze_hand_computed():
    pos = np.array([[0.0, 0.0], [-2.0, 0.0]])
    vel = np.array([[1.0, 0.0], [1.0, 0.0]])
    f = group_gaze(pos, vel, np.zeros(2), np.array([0, 0]), P)
    # agent 0 must turn 180 deg to see the centre behind it: alpha = 180 - 90 deg = pi / 2
    np.testing.assert_allclose(f, [[-3.0 * math.pi / 2, 0.0], [0.0, 0.0]], atol=1e-12)
