"""Scenarios: a robot trajectory, the people around it and their scene, read from a JSON or YAML file.

A scenario file is an *input* (not an artifact). ``load_scenario`` reads it, validates it against
``configs/schemas/scenario.schema.json`` (JSON Schema draft 2020-12, the single source of its
structure, ranges and defaults; ``SchemaValidator`` interprets the subset of keywords it uses) and
then checks what a schema cannot express: unique ids, increasing pose times, unit quaternions, a
readable TUM file, and every human's start and waypoints in the free space of the scene. Every
error is one :class:`~nsim.errors.InputError` line naming the file and the field path::

    spot_run.json: humans[2].behaviour: 'angry' is not one of regular, impassive, surprised, ...

The result is a :class:`Scenario`: typed views (``HumanSpec``, ``RobotSpec``), the obstacle
polygons, and the *canonical resolved* content (``Scenario.data``): defaults filled in, numbers
normalised, a TUM trajectory inlined as poses, the walk loop expanded to waypoints, a scene
checkpoint ref replaced by its artifact id. Its SHA-256 (``Scenario.digest``) identifies the
scenario in the run cache; loading the canonical content again gives the same content.

Scene (the 2D obstacle map, world x/y metres on the floor z = 0)
    ``{"room": "robot-lab", "room_seed": 0}``: the test room's walls and furniture footprints
    (``nsim.synth.room.occupancy_polygons``). ``{"checkpoint": REF}``: a ``scene-checkpoint``
    artifact's ``occupancy.json``, laid out as the capture's (``{"polygons": [[[x, y], ...], ...]}``)
    plus, optionally, ``"holes"``: one list per polygon of rings of free space inside it (a ring of
    walls around a walkable room is a polygon whose hole is the room). Hole boundaries are walls
    too; a point inside a hole is not inside the obstacle.
Robot (body frame: x forward, y left, z up; ``RobotSpec``)
    ``poses`` (timed body-to-world poses), ``waypoints_m`` + ``speed_mps`` (+ ``loop``), ``tum``
    (a TUM file, path relative to the scenario file) or ``walk_loop`` (the test room's ellipse).
    Waypoint paths face along the path; at a corner the heading turns, centred on the corner, at up
    to ``ROBOT_TURN_RATE_DPS``, while the position stays on the polyline. The body sits
    ``body_height_m`` above the floor. The humans see the robot as a capsule: the segment
    ``+- half_length_m`` along its heading grown by ``radius_m`` (Spot: 0.3 and 0.28, 1.16 m x 0.56 m).
Humans (``HumanSpec``)
    Start, waypoints walked in straight lines (``loop``: a waypoint loop, else a goal list ending at
    the last), behaviour, walking-group id, body height and radius, desired speed, motion clip name
    and appearance (a human-checkpoint ref for the renderer; only checked as a name here).

Time: ``duration_s``, and ``dt_s`` (null: the simulate config's). Randomness: ``seed`` (combined with
the run's ``--seed`` by the simulate stage).
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import hashlib
import json
import logging
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import canonical_json, configs_dir
from nsim.crowd.behaviours import BEHAVIOUR_NAMES, behaviour_codes
from nsim.crowd.neighbours import (
    closest_points_on_segments,
    points_in_polygons,
    segments_from_polygons,
    segments_intersect,
)
from nsim.errors import InputError, NsimError
from nsim.geometry.transforms import interpolate_poses

log = logging.getLogger(__name__)

SCHEMA_FILE = "schemas/scenario.schema.json"
ROBOT_TURN_RATE_DPS = 90.0
"""Heading turn rate of a waypoint robot at a corner (the turn is centred on the corner)."""
WALK_LOOP_POINTS = 72
"""The walk-loop ellipse becomes this many waypoints (every 5 degrees)."""
QUAT_NORM_TOLERANCE = 1e-3
MAX_TICKS = 2_000_000
SUFFIXES = (".json", ".yaml", ".yml")


# ----------------------------------------------------------------------------------------------
# A JSON Schema interpreter for the subset of draft 2020-12 the scenario schema uses, with
# one-line messages that name the field path. Keywords outside the subset raise at load time,
# so the schema cannot silently use something this validator ignores.

_ANNOTATIONS = {"$schema", "$id", "title", "description", "default", "$comment", "examples"}
_KEYWORDS = _ANNOTATIONS | {
    "$ref",
    "$defs",
    "type",
    "enum",
    "const",
    "properties",
    "required",
    "additionalProperties",
    "items",
    "prefixItems",
    "minItems",
    "maxItems",
    "minimum",
    "maximum",
    "exclusiveMinimum",
    "exclusiveMaximum",
    "minLength",
    "pattern",
    "oneOf",
}
_TYPE_NAMES = {
    "object": "an object",
    "array": "a list",
    "string": "a string",
    "number": "a number",
    "integer": "an integer",
    "boolean": "true or false",
    "null": "null",
}


class SchemaViolation(Exception):
    """One schema error: ``path`` (keys and indices) and a message."""

    def __init__(self, path: Sequence[str | int], message: str):
        super().__init__(message)
        self.path = tuple(path)
        self.message = message

    def where(self) -> str:
        return format_path(self.path)


def format_path(path: Sequence[str | int]) -> str:
    """``("humans", 2, "behaviour")`` -> ``humans[2].behaviour``; ``()`` -> ``(top level)``."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "(top level)"


def describe(value: Any) -> str:
    """A short rendering of a value for messages."""
    if isinstance(value, str):
        return repr(value) if len(value) <= 40 else repr(value[:37] + "...")
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "null"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (dict, list, tuple)):
        text = json.dumps(value, default=str)
        return text if len(text) <= 40 else text[:37] + "..."
    return repr(value)


def _json_type(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "object"
    return type(value).__name__


class SchemaValidator:
    """Validate plain data against a JSON Schema (the subset above) and fill in its defaults.

    ``validate(data)`` returns a new, resolved copy: missing properties that have a ``default``
    are added, integers in ``number`` fields become floats and integral floats in ``integer``
    fields become ints. Numbers must be finite (the JSON data model has no NaN or infinity).
    Raises :class:`SchemaViolation` for the first error in document order.
    """

    def __init__(self, schema: Mapping[str, Any]):
        self.schema = schema
        self._check_keywords(schema, "#")

    def _check_keywords(self, node: Any, where: str) -> None:
        if not isinstance(node, Mapping):
            if node is not False and node is not True:
                raise ValueError(f"schema {where}: expected an object or a boolean")
            return
        unknown = set(node) - _KEYWORDS
        if unknown:
            raise ValueError(
                f"schema {where}: keywords {sorted(unknown)} are not supported by SchemaValidator"
            )
        for key in ("properties", "$defs"):
            for name, sub in node.get(key, {}).items():
                self._check_keywords(sub, f"{where}/{key}/{name}")
        for key in ("items", "additionalProperties"):
            if key in node:
                self._check_keywords(node[key], f"{where}/{key}")
        for key in ("prefixItems", "oneOf"):
            for k, sub in enumerate(node.get(key, [])):
                self._check_keywords(sub, f"{where}/{key}/{k}")

    def _resolve(self, node: Mapping[str, Any]) -> Mapping[str, Any]:
        while "$ref" in node:
            ref = node["$ref"]
            if not ref.startswith("#/"):
                raise ValueError(f"schema: only local $ref are supported, got {ref!r}")
            target: Any = self.schema
            for part in ref[2:].split("/"):
                target = target[part]
            node = target
        return node

    def validate(self, data: Any) -> Any:
        return self._validate(self.schema, data, ())

    def _validate(self, node: Any, value: Any, path: tuple) -> Any:
        if node is True:
            return copy.deepcopy(value)
        if node is False:
            raise SchemaViolation(path, "no value is allowed here")
        node = self._resolve(node)
        if "oneOf" in node:
            value = self._one_of(node["oneOf"], value, path)
        value = self._check_type(node, value, path)
        if "const" in node and not _json_equal(value, node["const"]):
            raise SchemaViolation(path, f"expected {describe(node['const'])}, got {describe(value)}")
        if "enum" in node and not any(_json_equal(value, e) for e in node["enum"]):
            raise SchemaViolation(
                path, f"{describe(value)} is not one of {', '.join(map(str, node['enum']))}"
            )
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            self._check_bounds(node, value, path)
        if isinstance(value, str):
            if "minLength" in node and len(value) < node["minLength"]:
                raise SchemaViolation(
                    path,
                    f"expected a string of at least {node['minLength']} characters, got {describe(value)}",
                )
            if "pattern" in node and re.search(node["pattern"], value) is None:
                raise SchemaViolation(path, f"{describe(value)} does not match {node['pattern']}")
        if isinstance(value, list):
            return self._array(node, value, path)
        if isinstance(value, dict):
            return self._object(node, value, path)
        return value

    def _check_type(self, node: Mapping[str, Any], value: Any, path: tuple) -> Any:
        kind = _json_type(value)
        if kind in ("integer", "number") and not math.isfinite(value):
            raise SchemaViolation(path, f"expected a finite number, got {describe(value)}")
        if "type" not in node:
            return copy.deepcopy(value) if kind in ("array", "object") else value
        allowed = node["type"] if isinstance(node["type"], list) else [node["type"]]
        if kind == "integer" and "integer" not in allowed and "number" in allowed:
            return float(value)  # canonical: a number field holds floats
        if kind == "number" and "integer" in allowed and float(value).is_integer():
            return int(value)  # JSON Schema: 2.0 is an integer
        if kind in allowed or (kind == "integer" and "number" in allowed):
            return value
        want = " or ".join(_TYPE_NAMES[t] for t in allowed)
        raise SchemaViolation(path, f"expected {want}, got {describe(value)}")

    @staticmethod
    def _check_bounds(node: Mapping[str, Any], value: float, path: tuple) -> None:
        bounds, ok = [], True
        for key, sym, good in (
            ("exclusiveMinimum", ">", lambda v, b: v > b),
            ("minimum", ">=", lambda v, b: v >= b),
            ("exclusiveMaximum", "<", lambda v, b: v < b),
            ("maximum", "<=", lambda v, b: v <= b),
        ):
            if key in node:
                bounds.append(f"{sym} {node[key]:g}")
                ok = ok and good(value, node[key])
        if not ok:
            types = node.get("type", [])
            tname = (
                "an integer" if "integer" in (types if isinstance(types, list) else [types]) else "a number"
            )
            raise SchemaViolation(path, f"expected {tname} {' and '.join(bounds)}, got {describe(value)}")

    def _array(self, node: Mapping[str, Any], value: list, path: tuple) -> list:
        if "minItems" in node and len(value) < node["minItems"]:
            n = node["minItems"]
            raise SchemaViolation(path, f"expected at least {n} item{'s' * (n != 1)}, got {len(value)}")
        if "maxItems" in node and len(value) > node["maxItems"]:
            n = node["maxItems"]
            raise SchemaViolation(path, f"expected at most {n} item{'s' * (n != 1)}, got {len(value)}")
        prefix = node.get("prefixItems", [])
        out = []
        for k, item in enumerate(value):
            if k < len(prefix):
                out.append(self._validate(prefix[k], item, (*path, k)))
            elif "items" in node:
                out.append(self._validate(node["items"], item, (*path, k)))
            else:
                out.append(copy.deepcopy(item))
        return out

    def _object(self, node: Mapping[str, Any], value: dict, path: tuple) -> dict:
        props = node.get("properties", {})
        for key in value:
            if not isinstance(key, str):
                raise SchemaViolation(path, f"keys must be strings, got {describe(key)}")
            if key not in props and node.get("additionalProperties", True) is False:
                near = difflib.get_close_matches(key, list(props), n=1, cutoff=0.7)
                hint = f" (did you mean '{near[0]}'?)" if near else ""
                raise SchemaViolation((*path, key), f"unknown key{hint}; valid keys: {', '.join(props)}")
        for key in node.get("required", []):
            if key not in value:
                raise SchemaViolation((*path, key), "required key is missing")
        out = {}
        for key, sub in props.items():
            if key in value:
                out[key] = self._validate(sub, value[key], (*path, key))
            else:
                resolved = self._resolve(sub) if isinstance(sub, Mapping) else {}
                if "default" in resolved:
                    out[key] = copy.deepcopy(resolved["default"])
        for key in value:
            if key not in props:  # additionalProperties allowed (not used by the scenario schema)
                out[key] = copy.deepcopy(value[key])
        return out

    def _one_of(self, branches: list, value: Any, path: tuple) -> Any:
        passed, errors = [], []
        for branch in branches:
            try:
                passed.append(self._validate(branch, value, path))
            except SchemaViolation as exc:
                errors.append(exc)
        if len(passed) == 1:
            return passed[0]
        keys = [self._resolve(b).get("required", []) for b in branches]
        options = ", ".join("/".join(k) for k in keys)
        if passed:
            raise SchemaViolation(path, f"matches more than one of the forms with {options}")
        if isinstance(value, dict):
            candidates = [k for k, req in enumerate(keys) if req and all(r in value for r in req)]
            if len(candidates) == 1:
                raise errors[candidates[0]]
        raise SchemaViolation(
            path, f"expected an object with exactly one of the keys {options}, got {describe(value)}"
        )


def _json_equal(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    return a == b


_VALIDATOR: SchemaValidator | None = None


def scenario_schema_path() -> Path:
    return configs_dir() / SCHEMA_FILE


def scenario_validator() -> SchemaValidator:
    """The validator of ``configs/schemas/scenario.schema.json`` (read once)."""
    global _VALIDATOR
    if _VALIDATOR is None:
        path = scenario_schema_path()
        try:
            schema = json.loads(path.read_text())
        except FileNotFoundError:
            raise NsimError(f"{path}: the scenario schema is missing (is $NSIM_CONFIGS right?)") from None
        _VALIDATOR = SchemaValidator(schema)
    return _VALIDATOR


# ----------------------------------------------------------------------------------------------
# Reading files


def _reject_duplicates(pairs: list[tuple[str, Any]]) -> dict:
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"duplicate key {k!r}")
        out[k] = v
    return out


def read_scenario_file(path: str | Path) -> Any:
    """Plain data from a ``.json``, ``.yaml`` or ``.yml`` file; :class:`InputError` naming the file.

    JSON's non-standard ``NaN`` / ``Infinity`` are read as numbers so that validation can name
    the field that holds them.
    """
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise InputError(f"{path}: expected a scenario file ending in .json, .yaml or .yml")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"{path}: scenario file not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the scenario file ({exc.__class__.__name__})") from None
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text, object_pairs_hook=_reject_duplicates, parse_constant=float)
        except json.JSONDecodeError as exc:
            raise InputError(
                f"{path}: line {exc.lineno} column {exc.colno}: malformed JSON: {exc.msg}"
            ) from None
        except ValueError as exc:
            raise InputError(f"{path}: malformed JSON: {exc}") from None
    from nsim.config import parse_yaml

    return parse_yaml(text, path, InputError)


# ----------------------------------------------------------------------------------------------
# Typed views


@dataclasses.dataclass(frozen=True, eq=False)
class HumanSpec:
    """One human. start_m: (2,); waypoints_m: (K, 2); group_id -1 = walks alone."""

    id: str
    start_m: np.ndarray
    waypoints_m: np.ndarray
    loop: bool
    behaviour: str
    group_id: int
    height_m: float
    radius_m: float
    speed_mps: float
    motion: str
    appearance: str | None


@dataclasses.dataclass(frozen=True, eq=False)
class RobotSpec:
    """The robot: its capsule for the humans and its timed body-to-world poses.

    sample_times_s: (S,) strictly increasing; sample_poses_se3: (S, 4, 4) body-to-world, body axes
    x forward, y left, z up. ``poses_at`` interpolates them (positions linearly, rotations by
    slerp) and holds the first / last pose outside their span.
    """

    name: str
    radius_m: float
    half_length_m: float
    body_height_m: float
    sample_times_s: np.ndarray
    sample_poses_se3: np.ndarray

    def poses_at(self, times_s: np.ndarray) -> np.ndarray:
        """Body-to-world poses ``(T, 4, 4)`` at ``times_s (T,)``."""
        return interpolate_poses(self.sample_times_s, self.sample_poses_se3, times_s)


@dataclasses.dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario (see the module docstring). ``data`` returns a fresh copy each time."""

    source: str
    canonical: bytes
    digest: str
    name: str
    duration_s: float
    dt_s: float | None
    seed: int
    scene: Mapping[str, Any]
    scene_id: str | None
    obstacles_m: tuple[np.ndarray, ...]
    obstacle_holes_m: tuple[tuple[np.ndarray, ...], ...]
    robot: RobotSpec
    humans: tuple[HumanSpec, ...]

    @property
    def data(self) -> dict[str, Any]:
        return json.loads(self.canonical)

    @property
    def walls_m(self) -> np.ndarray:
        """Obstacle boundary segments ``(M, 2, 2)``: the outlines, then the holes' outlines."""
        return segments_from_polygons(self.obstacles_m + tuple(h for holes in self.obstacle_holes_m for h in holes))

    def in_obstacle(self, points_m: np.ndarray) -> np.ndarray:
        """Which points ``(P, 2)`` lie inside an obstacle (not in one of its holes): ``(P,)`` bool."""
        return points_in_polygons(points_m, self.obstacles_m, self.obstacle_holes_m)

    def scene_label(self) -> str:
        if self.scene_id is not None:
            return f"scene-checkpoint {self.scene_id[:12]}"
        return f"{self.scene['room']} (room_seed {self.scene['room_seed']})"


# ----------------------------------------------------------------------------------------------
# Loading


def load_scenario(path: str | Path, store=None) -> Scenario:
    """Read, validate and resolve a scenario file (see the module docstring).

    store: the workspace (``nsim.workspace.store.Store``), needed only for a scene checkpoint.
    """
    path = Path(path)
    data = read_scenario_file(path)
    return scenario_from_data(data, source=str(path), base_dir=path.parent, store=store)


def scenario_from_data(data: Any, *, source: str, base_dir: Path | None = None, store=None) -> Scenario:
    """Validate and resolve plain scenario data; errors name ``source`` and the field.

    base_dir: where a TUM path is relative to (None: TUM files are not allowed, e.g. for the
    canonical content, which never has one).
    """

    def fail(path: Sequence[str | int] | str, message: str) -> InputError:
        where = path if isinstance(path, str) else format_path(path)
        return InputError(f"{source}: {where}: {message}")

    try:
        d = scenario_validator().validate(data)
    except SchemaViolation as exc:
        raise fail(exc.path, exc.message) from None
    d.pop("$schema", None)

    scene, scene_id, polygons, holes = _resolve_scene(d["scene"], store, fail)
    d["scene"] = scene
    _resolve_robot(d, base_dir, fail)
    humans = _resolve_humans(d, fail)
    robot = _robot_spec(d, fail)
    canonical = canonical_json(d)
    sc = Scenario(
        source=source,
        canonical=canonical,
        digest=hashlib.sha256(canonical).hexdigest(),
        name=d["name"],
        duration_s=float(d["duration_s"]),
        dt_s=d["dt_s"],
        seed=int(d["seed"]),
        scene=scene,
        scene_id=scene_id,
        obstacles_m=tuple(polygons),
        obstacle_holes_m=tuple(tuple(h) for h in holes),
        robot=robot,
        humans=humans,
    )
    _check_free_space(sc, fail)
    return sc


def _resolve_scene(scene: dict, store, fail) -> tuple[dict, str | None, list[np.ndarray], list[list[np.ndarray]]]:
    if "room" in scene:
        from nsim.synth.room import make_room, occupancy_polygons

        spec = make_room(scene["room"], scene["room_seed"])
        polygons = occupancy_polygons(spec)
        return scene, None, polygons, [[] for _ in polygons]
    ref = scene["checkpoint"]
    if store is None:
        raise fail("scene.checkpoint", "a scene checkpoint needs a workspace to resolve it")
    try:
        art_id = store.resolve(ref, kind="scene-checkpoint")
    except NsimError as exc:
        raise fail("scene.checkpoint", str(exc)) from None
    art = store.get(art_id).path
    occ = art / "occupancy.json"
    if not occ.is_file() and (art / "scene.json").is_file():
        why = json.loads((art / "scene.json").read_text()).get("walkable_map_why_not")
        if why:
            raise fail("scene.checkpoint", f"scene-checkpoint {art_id[:12]} has no walkable map: {why}")
    return {"checkpoint": art_id}, art_id, *read_occupancy(occ, f"scene.checkpoint {ref!r}", fail)


def read_occupancy(path: Path, where: str, fail) -> tuple[list[np.ndarray], list[list[np.ndarray]]]:
    """Polygons and, per polygon, its holes from an ``occupancy.json``.

    The capture's layout ``{"polygons": [[[x, y], ...], ...]}``, optionally with ``"holes": [[ring,
    ...], ...]`` (one list per polygon; ``nsim.rendering.occupancy.ObstacleMap.occupancy_doc``).
    """
    if not path.is_file():
        raise fail(where, f"the artifact has no occupancy.json ({path}): it cannot give an obstacle map")
    try:
        occ = json.loads(path.read_text())
        polygons = [np.asarray(p, dtype=np.float64) for p in occ["polygons"]]
        raw_holes = occ.get("holes", [[] for _ in polygons])
        holes = [[np.asarray(h, dtype=np.float64) for h in hs] for hs in raw_holes]
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise fail(where, f"{path}: malformed occupancy.json ({exc.__class__.__name__}: {exc})") from None
    for k, p in enumerate(polygons):
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2 or not np.all(np.isfinite(p)):
            raise fail(where, f"{path}: polygons[{k}]: expected finite [[x, y], ...] with at least 2 points")
    if len(holes) != len(polygons):
        raise fail(where, f"{path}: holes: expected one list per polygon ({len(polygons)}), got {len(holes)}")
    for k, hs in enumerate(holes):
        for j, h in enumerate(hs):
            if h.ndim != 2 or h.shape[1] != 2 or len(h) < 3 or not np.all(np.isfinite(h)):
                raise fail(where, f"{path}: holes[{k}][{j}]: expected finite [[x, y], ...] with at least 3 points")
    return polygons, holes


def _resolve_robot(d: dict, base_dir: Path | None, fail) -> None:
    """Inline a TUM file as poses and expand the walk loop into waypoints (in place)."""
    traj = d["robot"]["trajectory"]
    if "tum" in traj:
        from nsim.io.tum import read_tum

        if base_dir is None:
            raise fail("robot.trajectory.tum", "a TUM file is only allowed in a scenario file")
        path = (base_dir / traj["tum"]) if not Path(traj["tum"]).is_absolute() else Path(traj["tum"])
        if not path.is_file():
            raise fail("robot.trajectory.tum", f"no such file {path}")
        try:
            tum = read_tum(path)
        except InputError as exc:
            raise fail("robot.trajectory.tum", str(exc)) from None
        t = tum.timestamps_s - (tum.timestamps_s[0] if traj["rebase_time"] else 0.0)
        if t[0] < 0:
            raise fail("robot.trajectory.tum", f"{path}: negative timestamps (set rebase_time: true)")
        d["robot"]["trajectory"] = {
            "poses": [
                {"t_s": float(ti), "position_m": p.tolist(), "orientation_quat_wxyz": q.tolist()}
                for ti, p, q in zip(t, tum.positions_xyz, tum.orientations_quat_wxyz, strict=True)
            ]
        }
    elif "walk_loop" in traj:
        if "room" not in d["scene"]:
            raise fail("robot.trajectory.walk_loop", "the walk loop needs a test-room scene ({room: ...})")
        from nsim.synth.room import make_room

        cx, cy, rx, ry = make_room(d["scene"]["room"], d["scene"]["room_seed"]).walk_loop_xy_m
        wl = traj["walk_loop"]
        sign = -1.0 if wl["clockwise"] else 1.0
        a = (
            np.deg2rad(wl["start_angle_deg"])
            + sign * 2.0 * np.pi * np.arange(WALK_LOOP_POINTS) / WALK_LOOP_POINTS
        )
        pts = np.round(np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], axis=-1), 6) + 0.0
        d["robot"]["trajectory"] = {"waypoints_m": pts.tolist(), "speed_mps": wl["speed_mps"], "loop": True}


def _resolve_humans(d: dict, fail) -> tuple[HumanSpec, ...]:
    seen: dict[str, int] = {}
    out = []
    groups: dict[int, int] = {}
    for k, h in enumerate(d["humans"]):
        h.setdefault("id", f"human{k}")
        h_id = h["id"]
        if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}", h_id):
            raise fail(
                ("humans", k, "id"), f"{describe(h_id)} is not a valid id (letters, digits, '_', '.', '-')"
            )
        if h_id in seen:
            raise fail(("humans", k, "id"), f"{describe(h_id)} is already the id of humans[{seen[h_id]}]")
        seen[h_id] = k
        if h["group_id"] is not None:
            groups[h["group_id"]] = groups.get(h["group_id"], 0) + 1
        out.append(
            HumanSpec(
                id=h_id,
                start_m=np.array(h["start_m"], dtype=np.float64),
                waypoints_m=np.array(h["waypoints_m"], dtype=np.float64).reshape(-1, 2),
                loop=bool(h["loop"]),
                behaviour=h["behaviour"],
                group_id=-1 if h["group_id"] is None else int(h["group_id"]),
                height_m=float(h["height_m"]),
                radius_m=float(h["radius_m"]),
                speed_mps=float(h["speed_mps"]),
                motion=h["motion"],
                appearance=h["appearance"],
            )
        )
    for g, count in sorted(groups.items()):
        if count == 1:
            log.warning("group_id %d has a single member: group forces do nothing for it", g)
    return tuple(out)


def _robot_spec(d: dict, fail) -> RobotSpec:
    r = d["robot"]
    traj = r["trajectory"]
    if "poses" in traj:
        times = np.array([p["t_s"] for p in traj["poses"]], dtype=np.float64)
        bad = np.flatnonzero(np.diff(times) <= 0)
        if len(bad):
            k = int(bad[0]) + 1
            raise fail(
                ("robot", "trajectory", "poses", k, "t_s"),
                f"{times[k]:g} is not after the previous pose's {times[k - 1]:g}",
            )
        quat = np.array([p["orientation_quat_wxyz"] for p in traj["poses"]], dtype=np.float64)
        norms = np.linalg.norm(quat, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE)
        if len(bad):
            k = int(bad[0])
            raise fail(
                ("robot", "trajectory", "poses", k, "orientation_quat_wxyz"),
                f"not a unit quaternion (norm {norms[k]:.6g}, tolerance {QUAT_NORM_TOLERANCE:g})",
            )
        from scipy.spatial.transform import Rotation

        poses = np.tile(np.eye(4), (len(times), 1, 1))
        poses[:, :3, :3] = Rotation.from_quat(quat / norms[:, None], scalar_first=True).as_matrix()
        poses[:, :3, 3] = [p["position_m"] for p in traj["poses"]]
    else:
        times, poses = waypoint_poses(
            np.array(traj["waypoints_m"], dtype=np.float64).reshape(-1, 2),
            traj["speed_mps"],
            traj["loop"],
            d["duration_s"],
            r["body_height_m"],
        )
    return RobotSpec(
        name=r["name"],
        radius_m=float(r["radius_m"]),
        half_length_m=float(r["half_length_m"]),
        body_height_m=float(r["body_height_m"]),
        sample_times_s=times,
        sample_poses_se3=poses,
    )


# ----------------------------------------------------------------------------------------------
# Robot poses


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def yaw_poses_se3(xy_m: np.ndarray, yaw_rad: np.ndarray, z_m: float) -> np.ndarray:
    """Body-to-world poses ``(S, 4, 4)``: rotation about +z by ``yaw_rad (S,)``, at ``(x, y, z_m)``."""
    n = len(xy_m)
    poses = np.tile(np.eye(4), (n, 1, 1))
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s, s, c
    poses[:, :2, 3] = xy_m
    poses[:, 2, 3] = z_m
    return poses


def waypoint_poses(
    waypoints_m: np.ndarray, speed_mps: float, loop: bool, duration_s: float, body_height_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Timed poses ``(S,)``, ``(S, 4, 4)`` of a robot driving ``waypoints_m (K, 2)`` at ``speed_mps``.

    The robot faces along each leg; at a corner its heading turns from one leg's direction to the
    next over a window centred on the corner (at most ``ROBOT_TURN_RATE_DPS``, at most half of each
    adjacent leg), while its position stays on the polyline. A loop closes back to the first
    waypoint and repeats until ``duration_s``; otherwise the robot stops at the last waypoint.
    """
    pts = np.asarray(waypoints_m, dtype=np.float64)
    keep = np.r_[True, np.any(np.diff(pts, axis=0) != 0.0, axis=1)]  # drop repeated waypoints
    pts = pts[keep]
    if loop and len(pts) > 1 and np.array_equal(pts[0], pts[-1]):
        pts = pts[:-1]
    if len(pts) == 1 or (loop and len(pts) < 2):
        return np.zeros(1), yaw_poses_se3(pts[:1], np.zeros(1), body_height_m)
    if loop:
        lap = np.vstack([pts, pts[:1]])
        lap_len = float(np.linalg.norm(np.diff(lap, axis=0), axis=1).sum())
        laps = int(math.ceil(duration_s * speed_mps / lap_len)) + 1
        path = np.vstack([pts] * laps + [pts[:1]])
    else:
        path = pts
    seg = np.diff(path, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    seg_yaw = np.arctan2(seg[:, 1], seg[:, 0])
    t_corner = np.r_[0.0, np.cumsum(seg_len / speed_mps)]
    n_seg = len(seg)
    half = np.zeros(n_seg + 1)  # turn half-window at each waypoint
    turn = _wrap(seg_yaw[1:] - seg_yaw[:-1])  # at interior waypoints 1..n_seg-1
    durations = seg_len / speed_mps
    half[1:-1] = np.minimum(
        np.abs(turn) / (2.0 * np.deg2rad(ROBOT_TURN_RATE_DPS)),
        0.5 * np.minimum(durations[:-1], durations[1:]),
    )
    yaw_unwrapped = seg_yaw[0] + np.r_[0.0, np.cumsum(turn)]
    times, xy, yaw = [], [], []
    for k in range(n_seg + 1):
        times.append(t_corner[k])  # the corner: half-way through the turn
        xy.append(path[k])
        yaw.append(
            yaw_unwrapped[0] if k == 0 else yaw_unwrapped[k - 1] + 0.5 * (turn[k - 1] if k < n_seg else 0.0)
        )
        if k < n_seg:  # leg k -> k+1: constant heading between the two turn windows
            for t in (t_corner[k] + half[k], t_corner[k + 1] - half[k + 1]):
                times.append(t)
                xy.append(path[k] + seg[k] * ((t - t_corner[k]) / durations[k]))
                yaw.append(yaw_unwrapped[k])
    times_a = np.array(times)
    keep = np.r_[True, np.diff(times_a) > 1e-9]  # coinciding samples (no turn) are identical
    times_a, xy_a, yaw_a = times_a[keep], np.array(xy)[keep], _wrap(np.array(yaw)[keep])
    return times_a, yaw_poses_se3(xy_a, yaw_a, body_height_m)


def yaw_of_poses(poses_se3: np.ndarray) -> np.ndarray:
    """Heading ``(T,)``: the body x axis projected on the floor, angle from world +x about +z."""
    return np.arctan2(poses_se3[:, 1, 0], poses_se3[:, 0, 0])


# ----------------------------------------------------------------------------------------------
# Free space


def clearance_m(points_m: np.ndarray, walls_m: np.ndarray) -> np.ndarray:
    """Distance from each point ``(P, 2)`` to the nearest wall segment ``(M, 2, 2)``: ``(P,)`` (inf if none)."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if len(walls_m) == 0 or len(p) == 0:
        return np.full(len(p), np.inf)
    out = np.empty(len(p))
    chunk = max(1, 200_000 // len(walls_m))
    for s in range(0, len(p), chunk):
        q = p[s : s + chunk]
        rep = np.repeat(q, len(walls_m), axis=0)
        c = closest_points_on_segments(rep, np.tile(walls_m, (len(q), 1, 1)))
        out[s : s + chunk] = np.linalg.norm(rep - c, axis=1).reshape(len(q), -1).min(axis=1)
    return out


def enclosed(points_m: np.ndarray, walls_m: np.ndarray) -> np.ndarray:
    """Whether rays from each point along +x, -x, +y and -y all hit a wall: ``(P,)`` bool.

    A point outside the map (beyond its outer walls) has a ray that escapes.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if len(walls_m) == 0:
        return np.zeros(len(p), bool)
    lo, hi = walls_m.reshape(-1, 2).min(axis=0), walls_m.reshape(-1, 2).max(axis=0)
    reach = float(np.linalg.norm(hi - lo)) + 1.0 + float(np.abs(p).max(initial=0.0))
    ok = np.ones(len(p), bool)
    for d in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
        ok &= segments_intersect(p, p + reach * np.asarray(d), walls_m).any(axis=1)
    return ok


def leg_crossings(start_m: np.ndarray, waypoints_m: np.ndarray, loop: bool, walls_m: np.ndarray) -> list[int]:
    """Legs (0 = start -> waypoint 0, k = waypoint k-1 -> k, and the closing leg of a loop) that cross a wall."""
    pts = np.vstack([start_m[None], waypoints_m])
    if loop and len(waypoints_m) > 1:
        pts = np.vstack([pts, waypoints_m[:1]])
    if len(walls_m) == 0 or len(pts) < 2:
        return []
    hit = segments_intersect(pts[:-1], pts[1:], walls_m).any(axis=1)
    return [int(k) for k in np.flatnonzero(hit)]


def _check_free_space(sc: Scenario, fail) -> None:
    walls = sc.walls_m
    if not sc.humans:
        return
    starts = np.array([h.start_m for h in sc.humans])
    radius = np.array([h.radius_m for h in sc.humans])
    inside = sc.in_obstacle(starts)
    outside = ~enclosed(starts, walls)
    clear = clearance_m(starts, walls)
    for k, h in enumerate(sc.humans):
        xy = f"({h.start_m[0]:g}, {h.start_m[1]:g})"
        if inside[k]:
            raise fail(("humans", k, "start_m"), f"{xy} is inside an obstacle of {sc.scene_label()}")
        if outside[k]:
            raise fail(("humans", k, "start_m"), f"{xy} is outside the map of {sc.scene_label()}")
        if clear[k] < h.radius_m:
            raise fail(
                ("humans", k, "start_m"),
                f"{xy} is {clear[k]:.2f} m from an obstacle, less than the body radius {h.radius_m:g} m",
            )
        w_inside = sc.in_obstacle(h.waypoints_m)
        w_outside = ~enclosed(h.waypoints_m, walls)
        for j in range(len(h.waypoints_m)):
            if w_inside[j] or w_outside[j]:
                what = "inside an obstacle" if w_inside[j] else "outside the map"
                p = h.waypoints_m[j]
                raise fail(
                    ("humans", k, "waypoints_m", j), f"({p[0]:g}, {p[1]:g}) is {what} of {sc.scene_label()}"
                )
        crossing = leg_crossings(h.start_m, h.waypoints_m, h.loop, walls)
        if crossing:
            log.warning(
                "%s: humans[%d] (%s): leg %s crosses an obstacle (people walk straight between waypoints)",
                sc.source,
                k,
                h.id,
                crossing[0],
            )
    if len(starts) > 1:
        from scipy.spatial import cKDTree

        pairs = cKDTree(starts).query_pairs(2.0 * float(radius.max()), output_type="ndarray")
        for i, j in sorted(map(tuple, pairs)):
            if np.linalg.norm(starts[i] - starts[j]) < radius[i] + radius[j]:
                raise fail(
                    ("humans", int(j), "start_m"), f"overlaps humans[{i}] ({sc.humans[i].id}) at the start"
                )
    pose0 = sc.robot.poses_at(np.zeros(1))[0]
    d = robot_surface_distance_m(starts, pose0[:2, 3], float(yaw_of_poses(pose0[None])[0]), sc.robot)
    for k in np.flatnonzero(d < radius):
        raise fail(("humans", int(k), "start_m"), "overlaps the robot's body at t = 0")


def robot_surface_distance_m(
    points_m: np.ndarray, robot_xy_m: np.ndarray, yaw_rad: float, robot: RobotSpec
) -> np.ndarray:
    """Distance from points ``(P, 2)`` to the robot capsule's surface: ``(P,)`` (negative inside)."""
    u = np.array([math.cos(yaw_rad), math.sin(yaw_rad)]) * robot.half_length_m
    axis = np.stack([robot_xy_m - u, robot_xy_m + u])
    q = closest_points_on_segments(points_m, np.broadcast_to(axis, (len(points_m), 2, 2)))
    return np.linalg.norm(points_m - q, axis=1) - robot.radius_m


# ----------------------------------------------------------------------------------------------
# Simulation


@dataclasses.dataclass(frozen=True, eq=False)
class Simulation:
    """A scenario rolled out: ``T`` ticks at ``t_k = k dt``.

    time_s: (T,); robot_pose_se3: (T, 4, 4) body-to-world (x forward, z up); crowd: the humans and
    the robot as the crowd saw it (``social_force.CrowdTrajectory``); dt_s; walls_m: (M, 2, 2).
    """

    time_s: np.ndarray
    robot_pose_se3: np.ndarray
    crowd: Any
    dt_s: float
    walls_m: np.ndarray


def crowd_state(sc: Scenario):
    """The humans' initial ``CrowdState`` (waypoints padded with the last one)."""
    from nsim.crowd.social_force import CrowdState

    n = len(sc.humans)
    k = max((len(h.waypoints_m) for h in sc.humans), default=1)
    goals = np.zeros((n, k, 2))
    for i, h in enumerate(sc.humans):
        goals[i, : len(h.waypoints_m)] = h.waypoints_m
        goals[i, len(h.waypoints_m) :] = h.waypoints_m[-1]

    def per(attr, dtype=np.float64):
        return np.array([getattr(h, attr) for h in sc.humans], dtype=dtype)

    return CrowdState.create(
        np.array([h.start_m for h in sc.humans], dtype=np.float64).reshape(n, 2),
        goals,
        n_goals=np.array([len(h.waypoints_m) for h in sc.humans], dtype=np.int64),
        loop_goals=per("loop", bool),
        desired_speed_mps=per("speed_mps"),
        radius_m=per("radius_m"),
        height_m=per("height_m"),
        group_id=per("group_id", np.int64),
        behaviour=behaviour_codes([h.behaviour for h in sc.humans]),
    )


def simulate(sc: Scenario, forces, behaviours, dt_s: float, duration_s: float, seed: int) -> Simulation:
    """Roll the scenario out for ``duration_s`` at ``dt_s`` (``rollout`` seeded with ``seed``)."""
    from nsim.crowd.social_force import RobotTrack, rollout

    ticks = duration_s / dt_s
    if ticks > MAX_TICKS:
        raise InputError(f"{sc.source}: duration_s / dt_s = {ticks:.0f} ticks, more than {MAX_TICKS}")
    n_steps = max(1, int(round(ticks)))
    time_s = np.arange(n_steps + 1) * dt_s
    poses = sc.robot.poses_at(time_s)
    track = RobotTrack(
        poses[:, :2, 3], yaw_of_poses(poses), radius_m=sc.robot.radius_m, half_length_m=sc.robot.half_length_m
    )
    walls = sc.walls_m
    traj = rollout(
        crowd_state(sc),
        n_steps,
        dt_s,
        walls_m=walls,
        robot=track,
        forces=forces,
        behaviours=behaviours,
        seed=seed,
    )
    return Simulation(time_s=time_s, robot_pose_se3=poses, crowd=traj, dt_s=dt_s, walls_m=walls)


# ----------------------------------------------------------------------------------------------
# Sweeps: extra people in free space


def spawn_extra_humans(
    sc: Scenario, count: int, behaviours: Sequence[str], rng: np.random.Generator, *, store=None
) -> Scenario:
    """The scenario plus ``count`` random people walking loops between two free points.

    Starts and waypoints are drawn uniformly in the map's free space (not in an obstacle, enclosed,
    ``radius + 0.15`` m clear of walls); starts keep clear of every other human and 1 m clear of
    the robot at t = 0; every leg is a straight line ``radius + 0.05`` m clear of the walls.
    Behaviours are drawn uniformly from ``behaviours``, heights and speeds from normal
    distributions about 1.72 m and 1.3 m/s. Raises :class:`NsimError` when the space is too full.
    """
    bad = [b for b in behaviours if b not in BEHAVIOUR_NAMES]
    if bad or not behaviours:
        raise NsimError(
            f"behaviours: {describe(bad[0]) if bad else '[]'} is not one of {', '.join(BEHAVIOUR_NAMES)}"
        )
    data = sc.data
    if count == 0:
        return sc
    walls = sc.walls_m
    if len(walls) == 0:
        raise NsimError(f"{sc.source}: the scene has no obstacles to bound the space for extra people")
    radius = 0.25
    lo, hi = walls.reshape(-1, 2).min(axis=0), walls.reshape(-1, 2).max(axis=0)
    cand = rng.uniform(lo, hi, size=(max(4096, 40 * count), 2))
    ok = ~sc.in_obstacle(cand) & enclosed(cand, walls)
    cand = cand[ok]
    cand = cand[clearance_m(cand, walls) >= radius + 0.15]
    if len(cand) < 2:
        raise NsimError(f"{sc.source}: no free space found for extra people in {sc.scene_label()}")
    pose0 = sc.robot.poses_at(np.zeros(1))[0]
    robot_d = robot_surface_distance_m(cand, pose0[:2, 3], float(yaw_of_poses(pose0[None])[0]), sc.robot)
    starts = [h.start_m for h in sc.humans]
    radii = [h.radius_m for h in sc.humans]
    extra = []
    tries = 0
    while len(extra) < count:
        tries += 1
        if tries > 30 * count + 300:
            raise NsimError(
                f"{sc.source}: could place only {len(extra)} of {count} extra people in the free space of "
                f"{sc.scene_label()}: use fewer"
            )
        i, a, b = rng.integers(len(cand), size=3)
        s = cand[i]
        if robot_d[i] < 1.0:
            continue
        if starts and np.min(np.linalg.norm(np.array(starts) - s, axis=1) - np.array(radii)) < radius + 0.1:
            continue
        g = np.stack([cand[a], cand[b]])
        if np.linalg.norm(g[0] - g[1]) < 2.0:
            continue
        legs = np.stack([np.stack([s, g[0]]), np.stack([g[0], g[1]])])
        if segments_intersect(legs[:, 0], legs[:, 1], walls).any():
            continue
        samples = np.concatenate(
            [np.linspace(p, q, max(2, int(np.linalg.norm(q - p) / 0.1) + 1)) for p, q in legs]
        )
        if clearance_m(samples, walls).min() < radius + 0.05:
            continue
        starts.append(s)
        radii.append(radius)
        extra.append(
            {
                "id": f"extra{len(extra):03d}",
                "start_m": np.round(s, 3).tolist(),
                "waypoints_m": np.round(g, 3).tolist(),
                "loop": True,
                "behaviour": str(behaviours[int(rng.integers(len(behaviours)))]),
                "height_m": round(float(np.clip(rng.normal(1.72, 0.09), 1.5, 1.95)), 3),
                "speed_mps": round(float(np.clip(rng.normal(1.3, 0.15), 0.9, 1.7)), 3),
            }
        )
    data["humans"] = data["humans"] + extra
    return scenario_from_data(data, source=sc.source, store=store)
