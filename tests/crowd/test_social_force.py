"""Crowd dynamics: a lone walker, head-on passing, walls, groups, determinism, purity, scaling."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from nsim.crowd import (
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
from nsim.crowd.neighbours import points_in_polygons
from tests.crowd.reference import distance_to_segments

DT = 0.05


def _box(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def room_with_furniture():
    """A 12 x 8 m room (walls 0.1 m thick) with five pieces of furniture."""
    walls = [
        _box(-0.1, -0.1, 12.1, 0.0),
        _box(-0.1, 8.0, 12.1, 8.1),
        _box(-0.1, -0.1, 0.0, 8.1),
        _box(12.0, -0.1, 12.1, 8.1),
    ]
    furniture = [
        _box(3, 2, 4, 6),
        _box(6, 0, 7, 3),
        _box(6, 5, 7, 8),
        _box(9, 3.5, 10.5, 4.5),
        _box(1, 6.5, 2, 7),
    ]
    return walls + furniture


def test_lone_agent_reaches_goal_at_desired_speed():
    s = CrowdState.create([[0.0, 0.0]], [[10.0, 0.0]], desired_speed_mps=1.3)
    tr = rollout(s, 240, DT)
    speed = np.linalg.norm(tr.velocity_mps[:, 0], axis=-1)
    cruising = (tr.position_m[:, 0, 0] > 3.0) & (tr.position_m[:, 0, 0] < 7.0)
    np.testing.assert_allclose(speed[cruising], 1.3, rtol=0.03)
    assert np.linalg.norm(tr.position_m[-1, 0] - [10.0, 0.0]) < ForceParams().goal_radius_m
    assert abs(tr.position_m[:, 0, 1]).max() < 0.1  # straight, noise notwithstanding
    arrive = tr.time_s[np.argmax(np.linalg.norm(tr.position_m[:, 0] - [10, 0], axis=-1) < 0.3)]
    assert 10.0 / 1.3 < arrive < 10.0 / 1.3 + 1.5  # start-up and the final slow-down cost < 1.5 s
    assert np.all(speed <= 1.3 * ForceParams().max_speed_factor + 1e-9)


@pytest.mark.parametrize("offset_m", [0.0, 0.05, 0.3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_head_on_pass_without_collision(offset_m, seed):
    s = CrowdState.create(
        [[0.0, 0.0], [10.0, offset_m]], [[10.0, 0.0], [0.0, offset_m]], desired_speed_mps=1.3
    )
    tr = rollout(s, 300, DT, seed=seed)
    gap = np.linalg.norm(tr.position_m[:, 0] - tr.position_m[:, 1], axis=-1)
    assert gap.min() > s.radius_m.sum()  # bodies never touch
    np.testing.assert_allclose(tr.position_m[-1], [[10.0, 0.0], [0.0, offset_m]], atol=0.35)  # both got there
    assert np.abs(tr.position_m[:, :, 1]).max() < 1.5  # a side-step, not a detour


def _free_points(rng, k, polys, segs, clearance_m=0.35, spacing_m=0.0):
    """k random points in the room, clear of the furniture (and of each other by spacing_m)."""
    out = []
    while len(out) < k:
        p = rng.uniform([0.5, 0.5], [11.5, 7.5])
        if points_in_polygons(p[None], polys)[0] or distance_to_segments(p[None], segs)[0] < clearance_m:
            continue
        if spacing_m and out and np.min(np.linalg.norm(np.array(out) - p, axis=1)) < spacing_m:
            continue
        out.append(p)
    return np.array(out)


def _crowd_in_room(n, seed):
    rng = np.random.default_rng(seed)
    polys = room_with_furniture()
    segs = segments_from_polygons(polys)
    pos = _free_points(rng, n, polys, segs, spacing_m=0.6)
    goals = np.stack([_free_points(rng, n, polys, segs), _free_points(rng, n, polys, segs), pos], axis=1)
    return CrowdState.create(pos, goals, loop_goals=True), segs, polys


def test_agents_never_enter_obstacles():
    s, segs, polys = _crowd_in_room(60, seed=5)
    robot = RobotTrack(
        np.column_stack([np.linspace(1, 11, 301), np.full(301, 4.8)]), np.zeros(301), 0.28, 0.3
    )
    tr = rollout(s, 300, DT, walls_m=segs, robot=robot, seed=5)
    flat = tr.position_m.reshape(-1, 2)
    assert not points_in_polygons(flat, polys).any()
    clearance = distance_to_segments(flat[::7], segs)  # every 7th sample: the loop twin is slow
    assert clearance.min() > 0.25 * 0.98
    moved = np.linalg.norm(tr.position_m[-1] - tr.position_m[0], axis=-1)
    assert np.median(moved) > 1.0  # they did walk around


def test_agent_pushed_into_a_wall_stays_out():
    # goal behind a wall: the desired force pushes straight into it for the whole run
    segs = segments_from_polygons([_box(2.0, -2.0, 2.2, 2.0)])
    s = CrowdState.create([[0.0, 0.1]], [[5.0, 0.1]], desired_speed_mps=1.8)
    tr = rollout(s, 200, DT, walls_m=segs, forces=ForceParams(obstacle_strength_mps2=0.0))
    assert tr.position_m[:, 0, 0].max() <= 2.0 - 0.25 + 1e-9


def test_group_members_walk_together():
    pos = np.array([[0.0, 0.0], [0.0, 2.5], [0.0, 5.0], [0.0, 7.5]])
    goals = pos + [20.0, 0.0]
    together = CrowdState.create(pos, goals, group_id=[0, 0, -1, -1], desired_speed_mps=[1.3, 1.3, 1.3, 1.3])
    tr = rollout(together, 200, DT, seed=0)
    gap = np.linalg.norm(tr.position_m[:, 0] - tr.position_m[:, 1], axis=-1)
    alone = np.linalg.norm(tr.position_m[:, 2] - tr.position_m[:, 3], axis=-1)
    assert gap[-50:].max() < 1.5 < alone[-50:].min()
    assert gap.min() > 0.5  # and do not bump into each other


def test_waypoints_loop_in_order():
    square = np.array([[2.0, 0.0], [2.0, 2.0], [0.0, 2.0], [0.0, 0.0]])
    s = CrowdState.create([[0.0, 0.0]], square[None], loop_goals=True, desired_speed_mps=1.0)
    tr = rollout(s, 400, DT)
    visits = tr.goal_index[:, 0]
    changes = visits[1:][np.diff(visits) != 0]
    assert list(changes[:6]) == [1, 2, 3, 0, 1, 2]


def test_stops_at_last_goal():
    s = CrowdState.create([[0.0, 0.0]], [[[1.0, 0.0], [2.0, 0.0]]], desired_speed_mps=1.0)
    tr = rollout(s, 200, DT)
    assert tr.goal_index[-1, 0] == 1
    assert np.linalg.norm(tr.velocity_mps[-1, 0]) < 0.05


def _snapshot(obj):
    return {f.name: np.array(getattr(obj, f.name), copy=True) for f in dataclasses.fields(obj)}


def test_step_does_not_mutate_inputs():
    s, segs, _ = _crowd_in_room(30, seed=1)
    s = dataclasses.replace(s, behaviour=np.arange(30, dtype=np.int8) % 6 + 1)
    robot = RobotState(np.array([6.0, 4.8]), np.array([0.8, 0.0]), 0.0, 0.28, 0.3)
    before, robot_before, segs_before = _snapshot(s), _snapshot(robot), segs.copy()
    rng = np.random.default_rng(0)
    new = step(s, robot, segs, ForceParams(), BehaviourParams(), DT, rng)
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(s, name), value, err_msg=name)
    for name, value in robot_before.items():
        np.testing.assert_array_equal(getattr(robot, name), value, err_msg=name)
    np.testing.assert_array_equal(segs, segs_before)
    assert not np.shares_memory(new.position_m, s.position_m)
    assert new.time_s == pytest.approx(DT)


def test_create_copies_and_validates():
    pos = np.zeros((2, 2))
    s = CrowdState.create(pos, [[1.0, 0.0], [2.0, 0.0]])
    pos[0, 0] = 5.0
    assert s.position_m[0, 0] == 0.0
    with pytest.raises(ValueError, match="goals_m"):
        CrowdState.create(np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="behaviour"):
        CrowdState.create(np.zeros((1, 2)), np.ones((1, 2)), behaviour=9)
    with pytest.raises(ValueError, match="radius_m"):
        CrowdState.create(np.zeros((1, 2)), np.ones((1, 2)), radius_m=0.0)
    with pytest.raises(ValueError, match="n_goals"):
        CrowdState.create(np.zeros((1, 2)), np.ones((1, 3, 2)), n_goals=[4])


def _scenario_run(seed):
    s, segs, _ = _crowd_in_room(40, seed=2)
    s = dataclasses.replace(
        s, behaviour=np.arange(40, dtype=np.int8) % 6 + 1, group_id=np.arange(40) // 2 % 3 - 1
    )
    robot = RobotTrack(
        np.column_stack([np.linspace(1, 11, 201), np.full(201, 4.8)]), np.zeros(201), 0.28, 0.3
    )
    return rollout(s, 200, DT, walls_m=segs, robot=robot, seed=seed)


def test_same_scenario_and_seed_give_identical_output():
    a, b, c = _scenario_run(7), _scenario_run(7), _scenario_run(8)
    for name, value in a.as_arrays().items():
        np.testing.assert_array_equal(value, b.as_arrays()[name], err_msg=name)
    assert not np.array_equal(a.position_m, c.position_m)  # the seed matters (fluctuations)


def test_trajectory_array_round_trip(tmp_path):
    tr = _scenario_run(0)
    np.savez(tmp_path / "t.npz", **tr.as_arrays())
    with np.load(tmp_path / "t.npz") as z:
        back = type(tr).from_arrays(z)
    for name, value in tr.as_arrays().items():
        np.testing.assert_array_equal(value, back.as_arrays()[name], err_msg=name)


def _steps_time(n, steps=15):
    rng = np.random.default_rng(0)
    side = float(np.sqrt(n / 0.5))  # constant density: 0.5 humans per m²
    s = CrowdState.create(rng.uniform(0.5, side - 0.5, (n, 2)), rng.uniform(0.5, side - 0.5, (n, 2)))
    forces, behaviours = ForceParams(), BehaviourParams()
    walls = make_walls(segments_from_polygons([_box(0, 0, side, side)]), forces)
    robot = RobotState(np.array([side / 2, side / 2]), np.array([1.0, 0.0]), 0.0, 0.28, 0.3)
    rng = np.random.default_rng(0)
    s = step(s, robot, walls, forces, behaviours, DT, rng)
    best = np.inf
    for _ in range(3):
        t0 = time.process_time()  # CPU time: another process on the machine does not count
        for _ in range(steps):
            s = step(s, robot, walls, forces, behaviours, DT, rng)
        best = min(best, time.process_time() - t0)
    return best


def test_cost_grows_near_linearly():
    ratio = _steps_time(2000) / _steps_time(500)
    assert ratio < 6.0, f"2000 agents took {ratio:.1f}x the time of 500"


def test_empty_crowd_and_no_walls():
    s = CrowdState.create(np.zeros((0, 2)), np.zeros((0, 2)))
    robot = RobotTrack(np.zeros((11, 2)), np.zeros(11), 0.28, 0.3)
    tr = rollout(s, 10, DT, robot=robot)
    assert tr.position_m.shape == (11, 0, 2) and tr.robot_position_m.shape == (11, 2)


def test_step_rejects_a_wall_index_too_small_for_the_forces():
    from nsim.crowd.neighbours import SegmentGrid

    s = CrowdState.create([[0.0, 0.0]], [[1.0, 0.0]])
    grid = SegmentGrid.build(np.array([[[0.0, 1.0], [1.0, 1.0]]]), reach_m=0.1)
    with pytest.raises(ValueError, match="make_walls"):
        step(s, None, grid, ForceParams(), BehaviourParams(), DT, np.random.default_rng(0))


def test_robot_track_resample_and_velocity():
    times = np.array([0.0, 1.0, 2.0])
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    yaw = np.array([0.0, 0.0, np.pi / 2])
    track = RobotTrack.resample(times, xy, yaw, dt_s=0.5, n_ticks=6, radius_m=0.3)
    np.testing.assert_allclose(track.position_m, [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [1, 1]])
    np.testing.assert_allclose(track.heading_rad, [0, 0, 0, np.pi / 4, np.pi / 2, np.pi / 2])
    np.testing.assert_allclose(track.velocity_mps(0.5)[1], [1.0, 0.0])
    with pytest.raises(ValueError, match="increasing"):
        RobotTrack.resample(times[::-1], xy, yaw, dt_s=0.5, n_ticks=3, radius_m=0.3)
    with pytest.raises(ValueError, match="need n_steps"):
        rollout(CrowdState.create([[0.0, 0.0]], [[1.0, 0.0]]), 10, DT, robot=track)


def test_params_load_strictly_from_plain_data():
    from nsim.config import ConfigError, from_dict, to_dict

    assert from_dict(ForceParams, {}) == ForceParams()
    assert from_dict(BehaviourParams, to_dict(BehaviourParams())) == BehaviourParams()
    assert from_dict(ForceParams, {"agent_strength_mps2": 3}).agent_strength_mps2 == 3.0
    with pytest.raises(ConfigError, match="anisotropy: expected float >= 0 and <= 1, got 1.5"):
        from_dict(ForceParams, {"anisotropy": 1.5})
    with pytest.raises(ConfigError, match="did you mean 'scared_detection_distance_m'"):
        from_dict(BehaviourParams, {"scared_detection_distance": 3.0})
    assert from_dict(ForceParams, {"separation_passes": 0}).separation_passes == 0
    with pytest.raises(ConfigError, match="separation_passes: expected int"):
        from_dict(ForceParams, {"separation_passes": 1.5})


def test_simulate_config_takes_a_behaviour_profile():
    from nsim.config import ConfigError, from_dict
    from nsim.stages.simulate import Config

    assert Config().behaviours.resolved().profile == "hunavsim"
    cfg = from_dict(Config, {"behaviours": {"profile": "nsim", "curious_speed_mps": 0.8}})
    assert cfg.behaviours.resolved().curious_speed_mps == 0.8
    assert cfg.behaviours.resolved().curious_stop_distance_m == 1.0  # the rest: nsim's
    with pytest.raises(ConfigError, match="behaviours.profile: 'x' is not one of hunavsim, nsim"):
        from_dict(Config, {"behaviours": {"profile": "x"}})
