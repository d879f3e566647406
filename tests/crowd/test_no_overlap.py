"""No overlapping bodies: people apart and out of the robot at every saved tick; walls win."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from nsim.crowd import (
    Behaviour,
    BehaviourParams,
    CrowdState,
    ForceParams,
    RobotState,
    RobotTrack,
    make_walls,
    rollout,
    segments_from_polygons,
    step,
)
from nsim.crowd.social_force import SEPARATION_OVERRELAXATION, SEPARATION_TOLERANCE_M, separate_bodies
from tests.crowd.reference import closest_point

DT = 0.05
MM = 1e-3


def pair_gap_m(position_m, radius_m):
    """Per tick, the smallest ``|x_i - x_j| - (r_i + r_j)`` over all pairs: ``(T,)`` (KD-tree, not nsim's search)."""
    reach = 2.0 * float(radius_m.max()) + 0.01
    out = []
    for x in position_m:
        p = cKDTree(x).query_pairs(reach, output_type="ndarray")
        gap = np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=-1) - radius_m[p[:, 0]] - radius_m[p[:, 1]]
        out.append(gap.min(initial=np.inf))
    return np.array(out)


def robot_gap_m(traj):
    """Per tick and human, the distance between the human's body and the robot's (negative: overlap)."""
    t, n = traj.position_m.shape[:2]
    out = np.empty((t, n))
    for k in range(t):
        u = np.array([np.cos(traj.robot_heading_rad[k]), np.sin(traj.robot_heading_rad[k])])
        a = traj.robot_position_m[k] - traj.robot_half_length_m * u
        b = traj.robot_position_m[k] + traj.robot_half_length_m * u
        for i in range(n):
            q = closest_point(traj.position_m[k, i], a, b)
            out[k, i] = np.linalg.norm(traj.position_m[k, i] - q) - traj.robot_radius_m - traj.radius_m[i]
    return out


def box(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


# --------------------------------------------------------------------------------------------
# Head-on in a corridor, a dense crowd


def corridor_run(seed, forces=None):
    rng = np.random.default_rng(seed)
    walls = np.array([[[-1.0, -1.0], [11.0, -1.0]], [[-1.0, 1.0], [11.0, 1.0]]])  # 2 m wide
    ya, yb = rng.uniform(-0.1, 0.1, 2)
    s = CrowdState.create([[0.0, ya], [10.0, yb]], [[10.0, ya], [0.0, yb]], desired_speed_mps=rng.uniform(1.1, 1.5, 2))
    return rollout(s, 300, DT, walls_m=walls, forces=forces, seed=seed)


def test_head_on_in_a_2_m_corridor_never_overlaps():
    for seed in range(10):
        tr = corridor_run(seed)
        assert pair_gap_m(tr.position_m, tr.radius_m).min() >= -MM, f"seed {seed}"
        assert np.abs(tr.position_m[..., 1]).max() <= 1.0 - 0.25 + MM  # and never in a wall
        assert tr.position_m[-1, 0, 0] > 9.0 and tr.position_m[-1, 1, 0] < 1.0  # both got through


def test_without_the_constraint_the_corridor_does_overlap():
    # the test above can fail: the forces alone let these bodies overlap
    worst = min(
        pair_gap_m(tr.position_m, tr.radius_m).min()
        for tr in (corridor_run(seed, ForceParams(separation_passes=0)) for seed in range(10))
    )
    assert worst < -MM


def dense_crowd(n=1000, seed=0):
    """n people on a jittered 0.8 m grid (1.6 per m², bodies 0.4-0.6 m wide, apart at the start),
    each walking to a random point of the room."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2)[:n] * 0.8
    pos = grid + rng.uniform(-0.05, 0.05, grid.shape)
    lo, hi = np.array([-4.0, -1.0]), np.array([side * 0.8 + 0.5, side * 0.8 + 0.5])
    goals = rng.uniform(lo + 0.5, hi - 0.5, (n, 2))
    s = CrowdState.create(pos, goals, radius_m=rng.uniform(0.2, 0.3, n), desired_speed_mps=rng.uniform(1.0, 1.5, n))
    return s, segments_from_polygons([box(*lo, *hi)]), (lo, hi)


def test_dense_crowd_of_1000_never_overlaps_people_robot_or_walls():
    s, walls, (lo, hi) = dense_crowd()
    ticks = 80
    # the robot drives into the crowd from the left at 1.2 m/s
    robot = RobotTrack(
        np.column_stack([-3.0 + 1.2 * DT * np.arange(ticks + 1), np.full(ticks + 1, 11.5)]),
        np.zeros(ticks + 1), 0.28, 0.3,
    )
    tr = rollout(s, ticks, DT, walls_m=walls, robot=robot, seed=0)
    gaps = pair_gap_m(tr.position_m, tr.radius_m)
    assert gaps.min() >= -MM, f"closest bodies overlap by {-gaps.min():.4f} m"
    assert robot_gap_m(tr).min() >= -MM
    clearance = np.minimum(tr.position_m - lo, hi - tr.position_m).min(axis=-1) - tr.radius_m
    assert clearance.min() >= -MM
    moved = np.linalg.norm(tr.position_m[-1] - tr.position_m[0], axis=-1)
    assert np.median(moved) > 0.5  # they did walk (4 s in a jam)


# --------------------------------------------------------------------------------------------
# The robot at the saved tick; walls win


def test_people_in_the_robots_path_are_never_inside_it_at_a_saved_tick():
    ticks = 120
    # Spot drives at 1.6 m/s through a row of people who ignore it (hunavsim surprised humans
    # facing away do not see it, and leave it out of their forces)
    robot = RobotTrack(np.column_stack([1.6 * DT * np.arange(ticks + 1), np.zeros(ticks + 1)]), np.zeros(ticks + 1), 0.28, 0.3)
    xs = np.array([2.0, 3.0, 4.0, 5.0, 6.0])
    pos = np.column_stack([xs, [0.0, 0.1, -0.1, 0.2, -0.05]])
    s = CrowdState.create(pos, pos, heading_rad=0.0, behaviour=Behaviour.SURPRISED)
    tr = rollout(s, ticks, DT, robot=robot, behaviours=BehaviourParams())
    gap = robot_gap_m(tr)
    assert gap.min() >= -MM
    assert (gap.min(axis=0) < 0.01).sum() >= 3  # the robot did reach them: bodies touching, not overlapping


def test_step_keeps_people_out_of_the_robot_where_it_ends_the_step():
    robot = RobotState(np.zeros(2), np.array([1.6, 0.0]), 0.0, 0.28, 0.3)
    s = CrowdState.create([[0.85, 0.0]], [[0.85, 0.0]], behaviour=Behaviour.SURPRISED)  # 0.02 m clear now
    rng = np.random.default_rng(0)
    default = step(s, robot, np.zeros((0, 2, 2)), ForceParams(), BehaviourParams(), DT, rng)
    assert default.position_m[0, 0] >= 0.08 + 0.3 + 0.28 + 0.25 - 1e-9  # clear of the robot moved on
    stale = step(s, robot, np.zeros((0, 2, 2)), ForceParams(), BehaviourParams(), DT, rng, robot_next=robot)
    assert stale.position_m[0, 0] < 0.08 + 0.3 + 0.28 + 0.25 - 0.05  # only clear of where it was: 0.06 m inside


def test_walls_win_over_the_robot():
    wall = make_walls(np.array([[[1.0, -2.0], [1.0, 2.0]]]), ForceParams())
    robot = RobotState(np.array([0.3, 0.0]), np.zeros(2), 0.0, 0.28)
    start = np.array([[0.7, 0.0]])
    out = separate_bodies(start, start, np.array([0.25]), wall, robot=robot)
    assert out[0, 0] <= 1.0 - 0.25 + 1e-9  # pressed against the wall, still overlapping the robot


# --------------------------------------------------------------------------------------------
# The loop twin


def separate_bodies_loop(start_m, position_m, radius_m, robot, passes=16):
    """Plain loops over pairs and humans: the projection of ``separate_bodies`` without walls."""
    x = np.array(position_m, dtype=float)
    n = len(x)
    seg = robot.body_segment_m() if robot is not None else None
    for _ in range(passes):
        moved = False
        push = np.zeros_like(x)
        for i in range(n):
            for j in range(i + 1, n):
                d = x[i] - x[j]
                dist = float(np.linalg.norm(d))
                depth = radius_m[i] + radius_m[j] - dist
                if depth > SEPARATION_TOLERANCE_M:
                    u = d / dist if dist >= 1e-12 else np.array([1.0, 0.0])
                    push[i] += 0.5 * SEPARATION_OVERRELAXATION * depth * u
                    push[j] -= 0.5 * SEPARATION_OVERRELAXATION * depth * u
                    moved = True
        x = x + push
        if seg is not None:
            for i in range(n):
                q = closest_point(x[i], seg[0], seg[1])
                dist = float(np.linalg.norm(x[i] - q))
                depth = radius_m[i] + robot.radius_m - dist
                if depth > SEPARATION_TOLERANCE_M:
                    x[i] = x[i] + depth * (x[i] - q) / dist
                    moved = True
        if not moved:
            break
        for i in range(n):
            m = x[i] - start_m[i]
            length = float(np.linalg.norm(m))
            if length > 0.9 * radius_m[i]:
                x[i] = start_m[i] + m / length * 0.9 * radius_m[i]
    return x


@pytest.mark.parametrize("seed", range(3))
def test_separate_bodies_matches_loop_twin(seed):
    rng = np.random.default_rng(seed)
    n = 50
    start = rng.uniform(0.0, 5.0, (n, 2))  # 2 per m²: many overlaps, some deeper than the cap allows
    radius = rng.uniform(0.2, 0.3, n)
    target = start + rng.normal(0.0, 0.05, (n, 2))
    robot = RobotState(np.array([2.5, 2.5]), np.zeros(2), 0.7, 0.28, 0.3)
    fast = separate_bodies(start, target, radius, make_walls(np.zeros((0, 2, 2)), ForceParams()), robot=robot)
    np.testing.assert_allclose(fast, separate_bodies_loop(start, target, radius, robot), atol=1e-12)


def test_separate_bodies_leaves_clear_crowds_alone_and_does_not_mutate():
    rng = np.random.default_rng(0)
    start = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2)  # 1 m apart
    target = start + rng.normal(0, 0.02, start.shape)
    before = target.copy()
    out = separate_bodies(start, target, np.full(25, 0.25), make_walls(np.zeros((0, 2, 2)), ForceParams()))
    np.testing.assert_array_equal(out, target)
    np.testing.assert_array_equal(target, before)
