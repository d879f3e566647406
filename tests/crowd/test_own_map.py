"""Scenario maps of their own, no scene checkpoint: polygons in the scenario, or a nav2 map.yaml."""

from __future__ import annotations

import ast
import logging
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from nsim.config import configs_dir
from nsim.crowd.behaviours import BehaviourParams
from nsim.crowd.driver import simulate
from nsim.crowd.neighbours import segments_intersect
from nsim.crowd.paths import clearance_m, enclosed
from nsim.crowd.social_force import ForceParams
from nsim.errors import InputError
from nsim.io.nav2 import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN, write_nav2_map
from nsim.stages.simulate import load_scenario, scenario_from_data

POLYGON_ROOM = configs_dir() / "scenarios" / "polygon_room.yaml"
NSIM = Path(__file__).resolve().parents[2] / "nsim"


# ----------------------------------------------------------------------------------------- polygons


def test_polygon_room_people_stay_out_of_the_polygons():
    sc = load_scenario(POLYGON_ROOM)
    assert sc.scene_id is None and sc.scene_label() == "the scenario's polygon map"
    assert [len(p) for p in sc.obstacles_m] == [4, 4, 4]  # the repeated closing point is dropped
    assert [len(h) for h in sc.obstacle_holes_m] == [1, 0, 0]
    assert len(sc.walls_m) == 16  # the walls' two faces, the table, the pillar
    # in the walls, the table, the pillar: obstacles; in the room: free; beyond the walls: off the map
    probes = np.array([[-0.1, 4.0], [6.0, 4.0], [3.1, 4.0], [1.0, 1.0], [11.0, 7.0], [4.2, 4.0], [13.0, 4.0]])
    assert sc.in_obstacle(probes).tolist() == [True, True, True, False, False, False, False]
    assert enclosed(probes[3:6], sc.walls_m).all() and not enclosed(probes[6:], sc.walls_m).any()

    sim = simulate(sc, ForceParams(), BehaviourParams(), 0.05, 20.0, seed=0)
    pos = sim.crowd.position_m  # (T, N, 2)
    t_count, n = pos.shape[:2]
    assert t_count == 401 and n == 5 and np.isfinite(pos).all()
    assert not sc.in_obstacle(pos.reshape(-1, 2)).any()
    assert enclosed(pos.reshape(-1, 2), sc.walls_m).all()
    assert clearance_m(pos.reshape(-1, 2), sc.walls_m).min() > 0.0
    for i in range(n):
        assert not segments_intersect(pos[:-1, i], pos[1:, i], sc.walls_m).any(), sc.humans[i].id
        walked = np.linalg.norm(np.diff(pos[:, i], axis=0), axis=1).sum()
        assert walked > 1.0, (sc.humans[i].id, walked)  # they walked, not stood still


def test_polygon_map_round_trips_through_the_canonical_content():
    sc = load_scenario(POLYGON_ROOM)
    scene = sc.data["scene"]
    assert set(scene) == {"polygons", "holes"} and scene["polygons"][1][0] == scene["polygons"][1][-1]
    again = scenario_from_data(sc.data, source="canonical")
    assert again.digest == sc.digest and again.canonical == sc.canonical
    for a, b in zip(again.obstacles_m, sc.obstacles_m, strict=True):
        np.testing.assert_array_equal(a, b)


def test_legs_across_obstacles_are_one_warning(caplog):
    d = yaml.safe_load(POLYGON_ROOM.read_text())
    # nine people walking straight through the table (and one past it): one summary line, not nine
    starts = [(x, y) for x in (3.7, 4.2, 4.7) for y in (3.4, 4.0, 4.6)] + [(4.2, 5.6)]
    d["humans"] = [{"id": f"p{k}", "start_m": list(s), "waypoints_m": [[8.0, s[1]]]} for k, s in enumerate(starts)]
    with caplog.at_level(logging.WARNING, logger="nsim.crowd.scenario"):
        scenario_from_data(d, source="crossing.yaml")
    lines = [r.getMessage() for r in caplog.records if "crosses an obstacle" in r.getMessage()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("crossing.yaml: ")
    assert "9 of 10 humans walk a leg that crosses an obstacle" in lines[0]
    assert lines[0].endswith("humans[0] (p0) leg 0, humans[1] (p1) leg 0, humans[2] (p2) leg 0 and 6 more")


# ----------------------------------------------------------------------------------------- nav2 maps


def _raster() -> tuple[np.ndarray, tuple[float, float], float]:
    """A map at 0.1 m over [-1, 7] x [-0.5, 4.5]: a free 6 x 4 m room inside 0.2 m occupied walls, a
    1 m occupied block in it, unknown cells beyond the walls."""
    res, origin, nx, ny = 0.1, (-1.0, -0.5), 80, 50
    x = origin[0] + (np.arange(nx) + 0.5) * res
    y = origin[1] + (np.arange(ny) + 0.5) * res
    xx, yy = np.meshgrid(x, y, indexing="ij")
    cells = np.full((nx, ny), CELL_UNKNOWN, dtype=np.int8)
    cells[(xx > -0.2) & (xx < 6.2) & (yy > -0.2) & (yy < 4.2)] = CELL_OCCUPIED
    cells[(xx > 0.0) & (xx < 6.0) & (yy > 0.0) & (yy < 4.0)] = CELL_FREE
    cells[(xx > 2.5) & (xx < 3.5) & (yy > 1.5) & (yy < 2.5)] = CELL_OCCUPIED
    return cells, origin, res


def _cell_centres(cells: np.ndarray, origin, res) -> np.ndarray:
    nx, ny = cells.shape
    x = origin[0] + (np.arange(nx) + 0.5) * res
    y = origin[1] + (np.arange(ny) + 0.5) * res
    return np.stack(np.meshgrid(x, y, indexing="ij"), axis=-1).reshape(-1, 2)


def _nav2_scenario(folder: Path, unknown: str = "obstacle") -> Path:
    """A scenario in ``folder`` whose map is ``maps/lab.yaml``, written by ``nsim.io.nav2``."""
    cells, origin, res = _raster()
    (folder / "maps").mkdir(parents=True)
    write_nav2_map(folder / "maps" / "lab.yaml", cells, origin, res)
    d = {
        "name": "nav2_room",
        "duration_s": 3.0,
        "scene": {"nav2_map": "maps/lab.yaml", "unknown": unknown},
        "robot": {"trajectory": {"waypoints_m": [[1.0, 1.0], [5.0, 1.0]], "speed_mps": 1.0}},
        "humans": [{"id": "ana", "start_m": [1.0, 3.0], "waypoints_m": [[5.0, 3.0], [5.0, 3.5]]}],
    }
    path = folder / "s.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def test_a_nav2_map_written_by_nsim_loads_back_as_its_raster(tmp_path):
    cells, origin, res = _raster()
    centres = _cell_centres(cells, origin, res)
    sc = load_scenario(_nav2_scenario(tmp_path))
    # every cell centre: an obstacle exactly where the raster is occupied or unknown
    np.testing.assert_array_equal(sc.in_obstacle(centres), (cells != CELL_FREE).reshape(-1))
    # beyond the raster nobody walks either
    assert sc.in_obstacle(np.array([[-1.05, 2.0], [7.05, 2.0], [3.0, 4.55], [3.0, -0.55]])).all()
    # stored as the polygons traced around it: the canonical content needs no file and gives the same map
    assert set(sc.data["scene"]) == {"polygons", "holes"} and sc.scene_label() == "the scenario's polygon map"
    again = scenario_from_data(sc.data, source="canonical")
    assert again.digest == sc.digest
    np.testing.assert_array_equal(again.in_obstacle(centres), (cells != CELL_FREE).reshape(-1))
    # unknown: free -> only the occupied cells (and the border beyond the raster) are obstacles
    free = load_scenario(_nav2_scenario(tmp_path / "free", unknown="free"))
    np.testing.assert_array_equal(free.in_obstacle(centres), (cells == CELL_OCCUPIED).reshape(-1))
    assert free.digest != sc.digest
    # and the crowd walks it
    sim = simulate(sc, ForceParams(), BehaviourParams(), 0.05, 3.0, seed=0)
    path = sim.crowd.position_m[:, 0]
    assert not sc.in_obstacle(path).any() and np.linalg.norm(path[-1] - path[0]) > 2.0


@pytest.mark.parametrize(
    "map_yaml, message",
    [
        ("image: none.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n", r"lab.yaml: image: 'none.pgm' not found"),
        ("image: lab.pgm\nresolution: -0.1\norigin: [0.0, 0.0, 0.0]\n", r"lab.yaml: resolution: expected > 0 .*got -0.1$"),
        ("image: lab.pgm\nresolution: fine\norigin: [0.0, 0.0, 0.0]\n", r"lab.yaml: resolution: expected a number, got 'fine'$"),
        ("image: lab.pgm\nresolution: 0.1\n", r"lab.yaml: origin: missing$"),
        ("resolution: 0.1\norigin: [0.0, 0.0, 0.0]\n", r"lab.yaml: image: missing$"),
        ("image: lab.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\nnegate: 2\n", r"lab.yaml: negate: expected 0 or 1, got 2$"),
        ("image: [lab.pgm\n", r"lab.yaml: line \d+: malformed YAML"),
    ],
    ids=["missing-image", "negative-resolution", "text-resolution", "no-origin", "no-image", "negate", "malformed"],
)
def test_bad_nav2_maps_are_one_line_naming_file_and_field(tmp_path, map_yaml, message):
    path = _nav2_scenario(tmp_path)
    (tmp_path / "maps" / "lab.yaml").write_text(map_yaml)
    with pytest.raises(InputError) as err:
        load_scenario(path)
    text = str(err.value)
    assert text.startswith(f"{path}: scene.nav2_map: ") and "\n" not in text, text
    assert re.search(message, text), text


def test_a_nav2_map_needs_a_scenario_file(tmp_path):
    d = yaml.safe_load(_nav2_scenario(tmp_path).read_text())
    with pytest.raises(InputError, match=r"^data: scene.nav2_map: a nav2 map is only allowed in a scenario file$"):
        scenario_from_data(d, source="data")
    (tmp_path / "maps" / "lab.pgm").unlink()
    with pytest.raises(InputError, match=r"s.yaml: scene.nav2_map: .*lab.yaml: image: 'lab.pgm' not found"):
        load_scenario(tmp_path / "s.yaml")


# ----------------------------------------------------------------------------------------- layering


def test_crowd_resolves_no_scene_itself():
    """``nsim.crowd`` gets arrays: it imports neither the test room, the workspace nor a stage (lazily or not)."""
    for path in sorted((NSIM / "crowd").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names] if isinstance(node, ast.Import)
                else [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            )
            for name in names:
                assert not name.startswith(("nsim.synth", "nsim.workspace", "nsim.stages")), (path.name, name)
