"""Scenario files: the schema (validated by jsonschema), one-line errors, resolution, free space, robot poses."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import yaml

from nsim.config import configs_dir
from nsim.crowd.behaviours import BEHAVIOUR_NAMES
from nsim.crowd.driver import crowd_state, spawn_extra_humans
from nsim.crowd.neighbours import points_in_polygons, segments_intersect
from nsim.crowd.paths import clearance_m, leg_crossings, waypoint_poses, yaw_of_poses
from nsim.crowd.scenario import scenario_schema_path
from nsim.crowd.schema import SchemaValidator, SchemaViolation
from nsim.crowd.sweep import load_sweep
from nsim.errors import InputError, NsimError
from nsim.geometry.transforms import interpolate_poses
from nsim.stages.simulate import load_scenario, scenario_from_data
from nsim.synth.room import ROOM_PRESETS

SCENARIOS = sorted((configs_dir() / "scenarios").glob("*.json")) + sorted(
    (configs_dir() / "scenarios").glob("*.yaml")
)
SPOT_RUN = configs_dir() / "scenarios" / "spot_run.json"


def base() -> dict:
    return json.loads(SPOT_RUN.read_text())


def mutated(fn) -> dict:
    d = base()
    fn(d)
    return d


def _set(path, value):
    def fn(d):
        node = d
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = value

    return fn


def _delete(path):
    def fn(d):
        node = d
        for p in path[:-1]:
            node = node[p]
        del node[path[-1]]

    return fn


# Bad content the schema itself rejects: (case id, mutation, text our one-line message must contain).
SCHEMA_BAD = [
    (
        "unknown-behaviour",
        _set(("humans", 2, "behaviour"), "angry"),
        "humans[2].behaviour: 'angry' is not one of regular, impassive, surprised, scared, curious, threatening",
    ),
    ("negative-dt", _set(("dt_s",), -0.05), "dt_s: expected a number > 0 and <= 0.5, got -0.05"),
    ("zero-duration", _set(("duration_s",), 0), "duration_s: expected a number > 0"),
    ("unknown-top-key", _set(("durations",), 3), "durations: unknown key (did you mean 'duration_s'?)"),
    (
        "unknown-human-key",
        _set(("humans", 0, "behavior"), "regular"),
        "humans[0].behavior: unknown key (did you mean 'behaviour'?)",
    ),
    ("missing-start", _delete(("humans", 1, "start_m")), "humans[1].start_m: required key is missing"),
    ("missing-robot", _delete(("robot",)), "robot: required key is missing"),
    (
        "xy-three-numbers",
        _set(("humans", 0, "start_m"), [1.0, 1.0, 0.0]),
        "humans[0].start_m: expected at most 2 items, got 3",
    ),
    (
        "xy-string",
        _set(("humans", 0, "start_m"), [1.0, "a"]),
        "humans[0].start_m[1]: expected a number, got 'a'",
    ),
    (
        "bool-as-number",
        _set(("humans", 0, "height_m"), True),
        "humans[0].height_m: expected a number, got true",
    ),
    (
        "height-range",
        _set(("humans", 3, "height_m"), 3.2),
        "humans[3].height_m: expected a number >= 0.5 and <= 2.5, got 3.2",
    ),
    ("group-negative", _set(("humans", 1, "group_id"), -1), "humans[1].group_id: expected an integer >= 0"),
    (
        "group-float",
        _set(("humans", 1, "group_id"), 0.5),
        "humans[1].group_id: expected an integer or null, got 0.5",
    ),
    (
        "no-waypoints",
        _set(("humans", 4, "waypoints_m"), []),
        "humans[4].waypoints_m: expected at least 1 item, got 0",
    ),
    ("bad-id", _set(("humans", 0, "id"), "a b"), "humans[0].id: 'a b' does not match"),
    ("room", _set(("scene",), {"room": "garage"}), "scene.room: 'garage' is not one of robot-lab"),
    ("motion", _set(("humans", 2, "motion"), "cmu_131_01"),
     "humans[2].motion: 'cmu_131_01' is not one of walk, walk_slow, walk_fast, idle"),
    (
        "scene-both",
        _set(("scene",), {"room": "robot-lab", "checkpoint": "scene/x"}),
        "scene: expected an object with exactly one of the keys room, checkpoint",
    ),
    (
        "trajectory-two-forms",
        _set(("robot", "trajectory"), {"tum": "a.tum", "waypoints_m": [[1, 1]]}),
        "robot.trajectory: expected an object with exactly one of the keys poses, recording, registration, waypoints_m, tum, walk_loop",
    ),
    (
        "speed",
        _set(("robot", "trajectory", "walk_loop", "speed_mps"), 0),
        "robot.trajectory.walk_loop.speed_mps: expected a number > 0",
    ),
    (
        "pose-quat-length",
        _set(
            ("robot", "trajectory"),
            {"poses": [{"t_s": 0, "position_m": [1, 1, 0.5], "orientation_quat_wxyz": [1, 0, 0]}]},
        ),
        "robot.trajectory.poses[0].orientation_quat_wxyz: expected at least 4 items, got 3",
    ),
    ("format", _set(("format",), 2), "format: expected 1, got 2"),
    ("humans-not-list", _set(("humans",), {"a": 1}), "humans: expected a list"),
    ("top-level-list", lambda d: d.clear(), "scene: required key is missing"),
    (
        "appearance-type",
        _set(("humans", 0, "appearance"), 3),
        "humans[0].appearance: expected a string or null, got 3",
    ),
    # the scenario's own map
    (
        "scene-empty",
        _set(("scene",), {}),
        "scene: expected an object with exactly one of the keys room, checkpoint, polygons, nav2_map, got {}",
    ),
    (
        "ring-too-short",
        _set(("scene",), {"polygons": [[[0, 0], [1, 0], [0, 0]]]}),
        "scene.polygons[0]: expected at least 4 items, got 3",
    ),
    (
        "ring-point",
        _set(("scene",), {"polygons": [[[0, 0], [1, 0], [1, 1], [0, "a"]]]}),
        "scene.polygons[0][3][1]: expected a number, got 'a'",
    ),
    (
        "polygons-unknown-key",
        _set(("scene",), {"polygons": [[[0, 0], [1, 0], [1, 1], [0, 0]]], "hole": []}),
        "scene.hole: unknown key (did you mean 'holes'?)",
    ),
    (
        "nav2-unknown",
        _set(("scene",), {"nav2_map": "map.yaml", "unknown": "maybe"}),
        "scene.unknown: 'maybe' is not one of obstacle, free",
    ),
]

# Bad content only nsim's own checks can see (a schema cannot express them).
BEYOND_SCHEMA = [
    (
        "start-inside-obstacle",
        _set(("humans", 1, "start_m"), [0.3, 4.0]),
        "humans[1].start_m: (0.3, 4) is inside an obstacle of robot-lab",
    ),
    (
        "start-outside-map",
        _set(("humans", 1, "start_m"), [9.0, 4.0]),
        "humans[1].start_m: (9, 4) is outside the map",
    ),
    (
        "start-touching-wall",
        _set(("humans", 0, "start_m"), [0.1, 1.0]),
        "humans[0].start_m: (0.1, 1) is 0.10 m from an obstacle",
    ),
    (
        "waypoint-inside",
        _set(("humans", 2, "waypoints_m"), [[6.3, 4.9], [7.3, 5.0]]),
        "humans[2].waypoints_m[1]: (7.3, 5) is inside an obstacle",
    ),
    (
        "starts-overlap",
        _set(("humans", 1, "start_m"), [1.0, 1.2]),
        "humans[1].start_m: overlaps humans[0] (ana)",
    ),
    (
        "start-on-robot",
        _set(("humans", 0, "start_m"), [6.11, 3.31]),
        "humans[0].start_m: overlaps the robot's body at t = 0",
    ),
    ("duplicate-id", _set(("humans", 3, "id"), "ana"), "humans[3].id: 'ana' is already the id of humans[0]"),
    (
        "missing-tum",
        _set(("robot", "trajectory"), {"tum": "no_such.tum"}),
        "robot.trajectory.tum: no such file",
    ),
    (
        "pose-times",
        _set(
            ("robot", "trajectory"),
            {
                "poses": [
                    {"t_s": 1.0, "position_m": [3, 3, 0.5], "orientation_quat_wxyz": [1, 0, 0, 0]},
                    {"t_s": 1.0, "position_m": [3, 4, 0.5], "orientation_quat_wxyz": [1, 0, 0, 0]},
                ]
            },
        ),
        "robot.trajectory.poses[1].t_s: 1 is not after the previous pose's 1",
    ),
    (
        "pose-quat-norm",
        _set(
            ("robot", "trajectory"),
            {"poses": [{"t_s": 0.0, "position_m": [3, 3, 0.5], "orientation_quat_wxyz": [0.5, 0, 0, 0]}]},
        ),
        "robot.trajectory.poses[0].orientation_quat_wxyz: not a unit quaternion (norm 0.5",
    ),
    (
        "walk-loop-needs-room",
        _set(("scene",), {"checkpoint": "scene/none"}),
        "scene.checkpoint: a scene checkpoint needs a workspace",
    ),
    # the scenario's own map: rings closed and enclosing an area, one holes list per polygon
    (
        "polygon-not-closed",
        _set(("scene",), {"polygons": [[[-1, -1], [9, -1], [9, 8], [-1, 8]]]}),
        "scene.polygons[0]: not closed: a ring ends with its first point (-1, -1) again, got (-1, 8)",
    ),
    (
        "polygon-no-area",
        _set(("scene",), {"polygons": [[[0, 0], [1, 1], [2, 2], [0, 0]]]}),
        "scene.polygons[0]: encloses no area",
    ),
    (
        "holes-count",
        _set(("scene",), {"polygons": [[[0, 0], [1, 0], [1, 1], [0, 0]]], "holes": []}),
        "scene.holes: expected one list per polygon (1), got 0",
    ),
    (
        "hole-not-closed",
        _set(("scene",), {"polygons": [[[0, 0], [9, 0], [9, 9], [0, 0]]], "holes": [[[[1, 1], [2, 1], [2, 2], [1, 2]]]]}),
        "scene.holes[0][0]: not closed",
    ),
    (
        "walk-loop-on-polygons",
        _set(("scene",), {"polygons": [[[-1, -1], [9, -1], [9, 8], [-1, 8], [-1, -1]]]}),
        "robot.trajectory.walk_loop: the walk loop needs a test-room scene",
    ),
    ("nav2-missing", _set(("scene",), {"nav2_map": "maps/none.yaml"}), "scene.nav2_map: no such file"),
]


def write(tmp_path: Path, data, name="s.json") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if name.endswith((".yaml", ".yml")) else json.dumps(data))
    return p


# ----------------------------------------------------------------------------------------- schema


def test_schema_is_valid_draft_2020_12_and_its_enums_match_the_code():
    schema = json.loads(scenario_schema_path().read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    defs = schema["$defs"]
    assert tuple(defs["human"]["properties"]["behaviour"]["enum"]) == BEHAVIOUR_NAMES
    assert tuple(defs["scene"]["oneOf"][0]["properties"]["room"]["enum"]) == ROOM_PRESETS


def _strict_json_data(data):
    """What a JSON Schema validator sees: the JSON data model (no NaN / infinity)."""
    text = json.dumps(data, allow_nan=True)
    return json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_shipped_scenarios_pass_the_schema_and_load(path):
    schema = json.loads(scenario_schema_path().read_text())
    data = json.loads(path.read_text()) if path.suffix == ".json" else yaml.safe_load(path.read_text())
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(data)) == []
    load_scenario(path)


@pytest.mark.parametrize("case,mutate,message", SCHEMA_BAD, ids=[c[0] for c in SCHEMA_BAD])
def test_schema_errors_are_one_line_naming_the_field(case, mutate, message, tmp_path):
    schema = json.loads(scenario_schema_path().read_text())
    data = mutated(mutate)
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(_strict_json_data(data))), case
    path = write(tmp_path, data)
    with pytest.raises(InputError) as err:
        load_scenario(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    assert message in text, text


@pytest.mark.parametrize("case,mutate,message", BEYOND_SCHEMA, ids=[c[0] for c in BEYOND_SCHEMA])
def test_checks_beyond_the_schema(case, mutate, message, tmp_path):
    schema = json.loads(scenario_schema_path().read_text())
    data = mutated(mutate)
    # the schema accepts these: only nsim's own checks can see the problem
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(data)) == [], case
    path = write(tmp_path, data)
    with pytest.raises(InputError) as err:
        load_scenario(path)
    assert message in str(err.value) and str(err.value).startswith(str(path)), str(err.value)


def test_non_finite_numbers_are_named(tmp_path):
    p = tmp_path / "nan.json"
    p.write_text(SPOT_RUN.read_text().replace('"start_m": [1.0, 1.0]', '"start_m": [NaN, 1.0]', 1))
    with pytest.raises(
        InputError, match=r"nan.json: humans\[0\].start_m\[0\]: expected a finite number, got nan"
    ):
        load_scenario(p)
    with pytest.raises(ValueError):  # and a JSON Schema validator never sees it: it is not JSON
        json.loads(p.read_text(), parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    y = tmp_path / "inf.yaml"
    y.write_text(yaml.safe_dump(base()).replace("duration_s: 30.0", "duration_s: .inf"))
    with pytest.raises(InputError, match=r"inf.yaml: duration_s: expected a finite number, got inf"):
        load_scenario(y)


def test_malformed_files(tmp_path):
    cases = {
        "a.json": ('{"name": [1,\n', r"a.json: line 2 column 1: malformed JSON"),
        "b.yaml": ("a: [1,\n", r"b.yaml: line 2: malformed YAML"),
        "c.json": ('{"seed": 1, "seed": 2}', r"c.json: malformed JSON: duplicate key 'seed'"),
        "d.txt": ("{}", r"d.txt: expected a scenario file ending in .json, .yaml or .yml"),
    }
    for name, (text, pattern) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError, match=pattern):
            load_scenario(tmp_path / name)
    with pytest.raises(InputError, match="scenario file not found"):
        load_scenario(tmp_path / "missing.json")


def test_validator_fills_defaults_and_normalises_numbers():
    v = SchemaValidator(json.loads(scenario_schema_path().read_text()))
    d = base()
    del d["humans"][0]["height_m"]
    d["humans"][0]["speed_mps"] = 1  # an int in a number field
    d["seed"] = 3.0  # an integral float in an integer field
    out = v.validate(d)
    h = out["humans"][0]
    assert h["height_m"] == 1.75 and h["radius_m"] == 0.25 and h["group_id"] is None
    assert isinstance(h["speed_mps"], float) and isinstance(out["seed"], int)
    assert out["robot"]["trajectory"]["walk_loop"]["clockwise"] is False
    assert d["humans"][0]["speed_mps"] == 1 and "radius_m" not in d["humans"][0]  # input untouched
    with pytest.raises(ValueError, match="not supported"):
        SchemaValidator({"type": "object", "anyOf": []})
    with pytest.raises(SchemaViolation) as err:
        v.validate([])
    assert err.value.where() == "(top level)"


# ----------------------------------------------------------------------------------------- resolution


def test_canonical_content_is_stable(tmp_path):
    sc = load_scenario(SPOT_RUN)
    again = scenario_from_data(sc.data, source="canonical")
    assert again.digest == sc.digest and again.canonical == sc.canonical
    # the same scenario as YAML, reformatted, with defaults spelled out: the same digest
    y = write(tmp_path, yaml.safe_load(json.dumps(base())), "s.yaml")
    assert load_scenario(y).digest == sc.digest
    spelled = base()
    spelled["humans"][0]["radius_m"] = 0.25
    assert load_scenario(write(tmp_path, spelled)).digest == sc.digest
    changed = base()
    changed["humans"][0]["speed_mps"] = 1.25
    assert load_scenario(write(tmp_path, changed, "c.json")).digest != sc.digest
    data = sc.data
    assert "walk_loop" not in json.dumps(data) and data["robot"]["trajectory"]["loop"] is True
    assert len(data["robot"]["trajectory"]["waypoints_m"]) == 72


def test_tum_trajectory_is_inlined_and_hashed(tmp_path):
    from nsim.io.tum import Trajectory, write_tum

    t = np.arange(0.0, 6.0, 0.5) + 100.0
    xy = np.stack([1.5 + 0.8 * (t - 100.0), np.full_like(t, 3.3)], axis=-1)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    poses[:, :2, 3] = xy
    poses[:, 2, 3] = 0.52
    (tmp_path / "traj").mkdir()
    write_tum(tmp_path / "traj" / "spot.tum", Trajectory.from_poses(t, poses))
    d = base()
    d["robot"]["trajectory"] = {"tum": "traj/spot.tum"}
    d["humans"] = d["humans"][3:]
    sc = load_scenario(write(tmp_path, d))
    assert sc.robot.sample_times_s[0] == 0.0 and sc.robot.sample_times_s[-1] == pytest.approx(5.5)
    at = sc.robot.poses_at(np.array([0.25, 100.0]))
    np.testing.assert_allclose(at[0, :3, 3], [1.7, 3.3, 0.52])
    np.testing.assert_allclose(at[1, :3, 3], [1.5 + 0.8 * 5.5, 3.3, 0.52])  # holds the last pose
    assert "tum" not in sc.data["robot"]["trajectory"]
    poses[3, 0, 3] += 0.01
    write_tum(tmp_path / "traj" / "spot.tum", Trajectory.from_poses(t, poses))
    assert load_scenario(tmp_path / "s.json").digest != sc.digest  # the digest covers the TUM content
    (tmp_path / "traj" / "spot.tum").write_text("0 1 2\n")
    with pytest.raises(InputError, match=r"s.json: robot.trajectory.tum: .*spot.tum:1: expected 8 columns"):
        load_scenario(tmp_path / "s.json")


def _publish_scene(
    store, occupancy: dict | None, kind: str = "scene-checkpoint", ref: str = "scene/test", scene_json: dict | None = None
) -> str:
    key = store.action_key("fake-scene", 1, {"n": json.dumps(occupancy), "s": json.dumps(scene_json)})
    with store.publish(kind=kind, stage="fake-scene", version=1, key=key, config={}, ref=ref) as out:
        if occupancy is not None:
            (out.dir / "occupancy.json").write_text(json.dumps(occupancy))
        else:
            (out.dir / "weights.bin").write_bytes(b"\0")
        if scene_json is not None:
            (out.dir / "scene.json").write_text(json.dumps(scene_json))
    return out.ref


def test_scene_checkpoint_reads_its_occupancy(store, tmp_path):
    square = [[[0, 0], [8, 0], [8, 7], [0, 7], [0, 0]]]  # a 2-vertex-free outline: boundary segments only
    walls = [
        [[-0.1, -0.1], [0, -0.1], [0, 7.1], [-0.1, 7.1]],
        [[8, -0.1], [8.1, -0.1], [8.1, 7.1], [8, 7.1]],
        [[-0.1, -0.1], [8.1, -0.1], [8.1, 0], [-0.1, 0]],
        [[-0.1, 7], [8.1, 7], [8.1, 7.1], [-0.1, 7.1]],
    ]
    art = _publish_scene(store, {"units": "m", "polygons": walls + [[[3, 3], [4, 3], [4, 4], [3, 4]]]})
    d = base()
    d["scene"] = {"checkpoint": "scene/test"}
    d["robot"]["trajectory"] = {"waypoints_m": [[1.5, 1.5], [6.5, 1.5]], "speed_mps": 1.0}
    sc = load_scenario(write(tmp_path, d), store=store)
    assert sc.scene_id == art and sc.data["scene"] == {"checkpoint": art}
    assert len(sc.obstacles_m) == 5 and square
    d["humans"][0]["start_m"] = [3.5, 3.5]
    with pytest.raises(
        InputError, match=r"humans\[0\].start_m: \(3.5, 3.5\) is inside an obstacle of scene-checkpoint"
    ):
        load_scenario(write(tmp_path, d), store=store)
    _publish_scene(store, None, ref="scene/empty")
    d["scene"] = {"checkpoint": "scene/empty"}
    with pytest.raises(
        InputError, match=r"scene.checkpoint 'scene/empty': the artifact has no occupancy.json"
    ):
        load_scenario(write(tmp_path, d), store=store)
    # a scene of arbitrary scale has no walkable map: the one line says why and how to give a scale
    _publish_scene(store, None, ref="scene/unscaled", scene_json={
        "metric": False, "walkable_map": None, "walkable_map_why_not": "the poses' scale is arbitrary (test)"})
    d["scene"] = {"checkpoint": "scene/unscaled"}
    with pytest.raises(InputError, match=r"scene.checkpoint: scene-checkpoint \w{12} has no walkable map: the poses' "
                                         r"scale is arbitrary \(test\)$"):
        load_scenario(write(tmp_path, d), store=store)
    _publish_scene(store, {"polygons": []}, kind="capture", ref="capture/x")
    d["scene"] = {"checkpoint": "capture/x"}
    with pytest.raises(
        InputError, match=r"scene.checkpoint: 'capture/x' is a capture artifact, expected scene-checkpoint"
    ):
        load_scenario(write(tmp_path, d), store=store)
    d["scene"] = {"checkpoint": "scene/nothing"}
    with pytest.raises(InputError, match=r"scene.checkpoint: no artifact or ref named 'scene/nothing'"):
        load_scenario(write(tmp_path, d), store=store)


# ----------------------------------------------------------------------------------------- the shipped scenario


def test_spot_run_people_cross_the_robot_path_through_free_space():
    sc = load_scenario(SPOT_RUN)
    walls = sc.walls_m
    assert sc.name == "spot_run" and len(sc.humans) == 5 and sc.scene["room"] == "robot-lab"
    assert len({h.behaviour for h in sc.humans}) >= 4
    groups = [h.group_id for h in sc.humans if h.group_id >= 0]
    assert len(groups) == 2 and len(set(groups)) == 1
    robot = sc.robot
    assert robot.half_length_m * 2 == pytest.approx(0.6) and robot.radius_m == pytest.approx(0.28)
    t = np.arange(0, sc.duration_s, 0.05)
    poses = robot.poses_at(t)
    speed = np.linalg.norm(np.diff(poses[:, :2, 3], axis=0), axis=1) / 0.05
    assert np.allclose(speed, 1.0, atol=0.02)
    assert np.all(points_in_polygons(poses[:, :2, 3], sc.obstacles_m) == 0)
    assert clearance_m(poses[:, :2, 3], walls).min() > robot.radius_m + robot.half_length_m
    robot_path = np.stack([poses[:-1, :2, 3], poses[1:, :2, 3]], axis=1)
    for h in sc.humans:
        pts = np.vstack([h.start_m, h.waypoints_m])
        assert not points_in_polygons(pts, sc.obstacles_m).any()
        assert clearance_m(pts, walls).min() >= h.radius_m
        assert leg_crossings(h.start_m, h.waypoints_m, h.loop, walls) == []
        # every leg, sampled, keeps the body clear of the walls
        legs = np.vstack([pts, pts[1:2]]) if h.loop else pts
        samples = np.concatenate([np.linspace(a, b, 50) for a, b in zip(legs[:-1], legs[1:], strict=True)])
        assert clearance_m(samples, walls).min() >= h.radius_m
        # and crosses the robot's loop
        assert segments_intersect(legs[:-1], legs[1:], robot_path).any(), h.id


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_shipped_scenarios_route_people_through_free_space(path):
    sc = load_scenario(path)
    walls = sc.walls_m
    poses = sc.robot.poses_at(np.arange(0, sc.duration_s, 0.05))
    assert clearance_m(poses[:, :2, 3], walls).min() > sc.robot.radius_m + sc.robot.half_length_m
    for h in sc.humans:
        pts = np.vstack([h.start_m, h.waypoints_m])
        legs = np.vstack([pts, pts[1:2]]) if h.loop else pts
        assert leg_crossings(h.start_m, h.waypoints_m, h.loop, walls) == [], h.id
        samples = np.concatenate([np.linspace(a, b, 50) for a, b in zip(legs[:-1], legs[1:], strict=True)])
        assert clearance_m(samples, walls).min() >= h.radius_m, h.id


def test_shipped_sweep_files_parse():
    for path in sorted((configs_dir() / "scenarios" / "sweeps").glob("*.yaml")):
        spec, scenario = load_sweep(path)
        assert scenario.is_file() and spec.seeds


# ----------------------------------------------------------------------------------------- robot poses


def test_waypoint_poses_drive_the_polyline_at_speed_facing_along_it():
    wp = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])
    times, poses = waypoint_poses(wp, 2.0, False, 10.0, 0.5)
    assert np.all(np.diff(times) > 0)
    t = np.linspace(0, 5.0, 501)
    at = interpolate_poses(times, poses, t)
    xy = at[:, :2, 3]
    assert np.allclose(at[:, 2, 3], 0.5)
    # on the polyline, at constant speed, ending (and holding) at the last waypoint
    on_first = np.isclose(xy[:, 1], 0.0) & (xy[:, 0] <= 4.0 + 1e-9)
    on_second = np.isclose(xy[:, 0], 4.0)
    assert np.all(on_first | on_second)
    travelled = np.where(on_first & ~on_second, xy[:, 0], 4.0 + xy[:, 1])
    np.testing.assert_allclose(travelled, np.minimum(2.0 * t, 7.0), atol=1e-9)
    yaw = yaw_of_poses(at)
    # facing along each leg away from the corner; the turn (90 deg at 90 deg/s) is centred on it (t = 2 s)
    assert np.allclose(yaw[t < 1.49], 0.0) and np.allclose(yaw[(t > 2.51) & (t < 3.5)], math.pi / 2)
    assert yaw[np.argmin(abs(t - 2.0))] == pytest.approx(math.pi / 4)
    assert np.allclose(at[:, :3, :3] @ np.swapaxes(at[:, :3, :3], 1, 2), np.eye(3), atol=1e-9)
    assert np.allclose(at[:, 2, :3], [0, 0, 1])  # z stays up


def test_waypoint_loop_repeats_until_the_duration():
    wp = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    times, poses = waypoint_poses(wp, 1.0, True, 20.0, 0.5)
    assert times[-1] >= 20.0
    at = interpolate_poses(times, poses, np.array([0.0, 8.0, 16.0, 9.0]))
    np.testing.assert_allclose(at[:3, :2, 3], np.zeros((3, 2)), atol=1e-9)
    np.testing.assert_allclose(at[3, :2, 3], [1.0, 0.0], atol=1e-9)
    single_t, single = waypoint_poses(np.array([[1.0, 2.0]]), 1.0, True, 5.0, 0.4)
    assert len(single_t) == 1 and np.allclose(single[0, :3, 3], [1.0, 2.0, 0.4])


def test_interpolate_poses_slerps_and_holds():
    from scipy.spatial.transform import Rotation

    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    poses[1, :3, 3] = [2.0, 0.0, 1.0]
    out = interpolate_poses(np.array([1.0, 3.0]), poses, np.array([0.0, 2.0, 5.0]))
    assert np.allclose(out[0], poses[0]) and np.allclose(out[2], poses[1])
    assert yaw_of_poses(out[1:2])[0] == pytest.approx(math.pi / 4)
    np.testing.assert_allclose(out[1, :3, 3], [1.0, 0.0, 0.5])


# ----------------------------------------------------------------------------------------- extra people


def test_spawn_extra_humans_in_free_space_deterministically():
    sc = load_scenario(SPOT_RUN)
    a = spawn_extra_humans(sc, 12, ("scared", "curious"), np.random.default_rng(5))
    b = spawn_extra_humans(sc, 12, ("scared", "curious"), np.random.default_rng(5))
    c = spawn_extra_humans(sc, 12, ("scared", "curious"), np.random.default_rng(6))
    assert a.digest == b.digest != c.digest
    extra = a.humans[5:]
    assert len(extra) == 12 and [h.id for h in a.humans[:5]] == [h.id for h in sc.humans]
    assert {h.behaviour for h in extra} <= {"scared", "curious"}
    walls = a.walls_m
    for h in extra:
        legs = np.vstack([h.start_m, h.waypoints_m, h.waypoints_m[:1]])
        samples = np.concatenate([np.linspace(p, q, 40) for p, q in zip(legs[:-1], legs[1:], strict=True)])
        assert clearance_m(samples, walls).min() >= h.radius_m
    assert spawn_extra_humans(sc, 0, ("regular",), np.random.default_rng(0)) is sc
    with pytest.raises(NsimError, match="could place only"):
        spawn_extra_humans(sc, 400, ("regular",), np.random.default_rng(0))
    with pytest.raises(NsimError, match="'angry' is not one of"):
        spawn_extra_humans(sc, 1, ("angry",), np.random.default_rng(0))


def test_crowd_state_matches_the_scenario():
    sc = load_scenario(SPOT_RUN)
    st = crowd_state(sc)
    assert st.n == 5 and st.goals_m.shape == (5, 2, 2)
    np.testing.assert_array_equal(st.position_m, [h.start_m for h in sc.humans])
    assert list(st.loop_goals) == [h.loop for h in sc.humans]
    assert list(st.group_id) == [-1, 0, 0, -1, -1]
    empty = scenario_from_data({**sc.data, "humans": []}, source="x")
    assert crowd_state(empty).n == 0


def test_inputs_are_not_mutated(tmp_path):
    d = base()
    before = copy.deepcopy(d)
    scenario_from_data(d, source="x", base_dir=tmp_path)
    assert d == before


def test_the_schema_s_motions_are_the_clips_nsim_draws():
    """A motion the schema accepts is one nsim has (never silently the walk), and every clip can be named."""
    from nsim.crowd.scenario import scenario_validator
    from nsim.human.gait import DEFAULT_CLIPS

    schema = scenario_validator().schema
    assert schema["$defs"]["human"]["properties"]["motion"] == {"$ref": "#/$defs/motion"}
    motion = schema["$defs"]["motion"]
    names = motion["oneOf"][0]["enum"]  # the other forms are recorded clips: objects
    assert sorted(names) == sorted(DEFAULT_CLIPS) and motion["default"] in DEFAULT_CLIPS
    assert all(form["type"] == "object" for form in motion["oneOf"][1:])
