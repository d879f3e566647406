"""The crowd on a scene checkpoint's map: polygons with holes (a ring of walls around the walkable room)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.crowd.behaviours import BehaviourParams
from nsim.crowd.driver import simulate, spawn_extra_humans
from nsim.crowd.neighbours import points_in_polygons, segments_intersect
from nsim.crowd.paths import enclosed
from nsim.crowd.social_force import ForceParams
from nsim.errors import InputError
from nsim.rendering.occupancy import ObstacleMap
from nsim.stages.simulate import scenario_from_data
from tests.crowd.test_scenario import _publish_scene, base


def test_points_in_polygons_with_holes():
    outer = np.array([[0, 0], [10, 0], [10, 8], [0, 8]], dtype=float)
    hole = np.array([[1, 1], [1, 7], [9, 7], [9, 1]], dtype=float)  # clockwise, as written
    pillar = np.array([[4, 4], [5, 4], [5, 5], [4, 5]], dtype=float)
    pts = np.array([[0.5, 4], [5, 2], [4.5, 4.5], [11, 4], [9.5, 7.5]])
    assert points_in_polygons(pts, [outer, pillar], [[hole], []]).tolist() == [True, False, True, False, True]
    assert points_in_polygons(pts, [outer, pillar]).tolist() == [True, True, True, False, True]  # solid: as before
    with pytest.raises(ValueError, match="one list per polygon"):
        points_in_polygons(pts, [outer, pillar], [[hole]])


def _room_map() -> ObstacleMap:
    """An 8 x 7 m room with 10 cm walls and a 1 m block, in a map 2 m larger on every side (0.1 m cells).

    Seen: the room and its walls; beyond them, unknown."""
    cell, origin = 0.1, (-2.0, -2.0)
    nx, ny = 120, 110
    x = origin[0] + (np.arange(nx) + 0.5) * cell
    y = origin[1] + (np.arange(ny) + 0.5) * cell
    X, Y = np.meshgrid(x, y, indexing="ij")
    room = (X > 0) & (X < 8) & (Y > 0) & (Y < 7)
    walls = (X > -0.1) & (X < 8.1) & (Y > -0.1) & (Y < 7.1) & ~room
    block = (X > 3) & (X < 4) & (Y > 3) & (Y < 4)
    observed = room | walls
    return ObstacleMap(origin, cell, walls | block, (0.1, 1.0), observed)


@pytest.fixture
def scene(store, tmp_path):
    d = tmp_path / "scene"
    d.mkdir()
    _room_map().save(d)
    return _publish_scene(store, json.loads((d / "occupancy.json").read_text()))


def _scenario(scene_ref: str, start=(1.0, 1.0)):
    d = base()
    d["scene"] = {"checkpoint": scene_ref}
    d["robot"]["trajectory"] = {"waypoints_m": [[1.5, 5.5], [6.5, 5.5]], "speed_mps": 1.0}
    d["humans"] = [{"id": "ana", "start_m": list(start), "waypoints_m": [[6.5, 1.0], [6.5, 2.5]], "loop": True}]
    d["duration_s"] = 2.0
    return d


def test_a_start_in_the_free_room_loads_and_simulates(store, scene):
    sc = scenario_from_data(_scenario(scene), source="s.json", store=store)
    assert sc.scene_id == scene and any(len(h) for h in sc.obstacle_holes_m)
    walls = sc.walls_m
    n_outline = sum(len(p) for p in sc.obstacles_m)
    assert len(walls) == n_outline + sum(len(h) for hs in sc.obstacle_holes_m for h in hs)  # hole rings are walls
    inside_room = np.array([[1.0, 1.0], [6.5, 2.5], [7.5, 6.5]])
    assert not sc.in_obstacle(inside_room).any() and enclosed(inside_room, walls).all()
    assert sc.in_obstacle(np.array([[3.5, 3.5], [-1.0, 3.0], [9.5, 3.0]])).all()  # the block; unknown beyond the walls
    sim = simulate(sc, ForceParams(), BehaviourParams(), 0.05, 2.0, seed=0)
    path = sim.crowd.position_m[:, 0]
    assert len(path) == 41 and np.isfinite(path).all()
    assert not sc.in_obstacle(path).any()
    assert np.linalg.norm(path[-1] - path[0]) > 1.0  # walked towards its waypoint
    assert not segments_intersect(path[:-1], path[1:], walls).any()


def test_a_start_beyond_the_walls_is_inside_an_obstacle(store, scene):
    with pytest.raises(InputError, match=r"humans\[0\].start_m: \(9.5, 3\) is inside an obstacle of scene-checkpoint"):
        scenario_from_data(_scenario(scene, start=(9.5, 3.0)), source="s.json", store=store)
    with pytest.raises(InputError, match=r"humans\[0\].start_m: \(3.5, 3.5\) is inside an obstacle"):
        scenario_from_data(_scenario(scene, start=(3.5, 3.5)), source="s.json", store=store)


def test_extra_people_are_placed_in_the_hole(store, scene):
    sc = scenario_from_data(_scenario(scene), source="s.json", store=store)
    more = spawn_extra_humans(sc, 6, ["regular"], np.random.default_rng(0))
    pts = np.array([h.start_m for h in more.humans[1:]] + [w for h in more.humans[1:] for w in h.waypoints_m])
    assert len(more.humans) == 7 and not more.in_obstacle(pts).any()
    assert ((pts > 0.0) & (pts < [8.0, 7.0])).all()


def test_old_files_without_holes_still_read(store, tmp_path):
    walls = [
        [[-0.1, -0.1], [0, -0.1], [0, 7.1], [-0.1, 7.1]],
        [[8, -0.1], [8.1, -0.1], [8.1, 7.1], [8, 7.1]],
        [[-0.1, -0.1], [8.1, -0.1], [8.1, 0], [-0.1, 0]],
        [[-0.1, 7], [8.1, 7], [8.1, 7.1], [-0.1, 7.1]],
    ]
    art = _publish_scene(store, {"units": "m", "polygons": walls})
    sc = scenario_from_data(_scenario(art), source="s.json", store=store)
    assert sc.obstacle_holes_m == ((), (), (), ()) and len(sc.walls_m) == 16


@pytest.mark.parametrize("holes, message", [
    ([[]], r"holes: expected one list per polygon \(2\), got 1"),
    ([[[[0, 0], [1, 0]]], []], r"holes\[0\]\[0\]: expected finite"),
    ("x", "malformed occupancy.json"),
])
def test_malformed_holes_are_named(store, holes, message):
    square = [[0, 0], [8, 0], [8, 7], [0, 7]]
    _publish_scene(store, {"polygons": [square, square], "holes": holes})
    with pytest.raises(InputError, match=message):
        scenario_from_data(_scenario("scene/test"), source="s.json", store=store)
