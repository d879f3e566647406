"""Scenarios: a robot trajectory, the people around it and their scene, read from a JSON or YAML file.

A scenario file is an *input* (not an artifact). Reading it takes two steps:

1. ``parse_scenario`` / ``read_scenario`` validate it against ``nsim/configs/schemas/scenario.schema.json``
   (JSON Schema draft 2020-12, the single source of its structure, ranges and defaults; checked by
   ``jsonschema`` through ``nsim.crowd.schema``), inline a TUM trajectory and check what a schema
   cannot express: unique ids, increasing pose times, unit quaternions. The result is a
   :class:`ScenarioSpec`, whose ``scene`` is still the *reference* the file gives.
2. Whoever can resolve that reference (the simulate stage: the workspace for a scene checkpoint,
   ``nsim.synth`` for the test room, ``nsim.io.nav2`` for a nav2 map) turns it into a
   :class:`SceneMap` (arrays), and ``resolve_scenario(spec, scene_map)`` builds the
   :class:`Scenario`, checking every human's start and waypoints against the free space.

Every error is one :class:`~nsim.errors.InputError` line naming the file and the field path::

    spot_run.json: humans[2].behaviour: 'angry' is not one of regular, impassive, surprised, ...

A :class:`Scenario` holds typed views (``HumanSpec``, ``RobotSpec``), the obstacle map and the
*canonical resolved* content (``Scenario.data``): defaults filled in, numbers normalised, a TUM
trajectory inlined as poses, the walk loop expanded to waypoints, a scene checkpoint ref replaced by
its artifact id, a nav2 map replaced by its obstacle polygons. Its SHA-256 (``Scenario.digest``)
identifies the scenario in the run cache; loading the canonical content again gives the same content.

Scene (the 2D obstacle map, world x/y metres on the floor z = 0)
    ``{"room": "robot-lab", "room_seed": 0}``: the test room's walls and furniture footprints.
    ``{"checkpoint": REF}``: a ``scene-checkpoint`` artifact's ``occupancy.json``, laid out as the
    capture's (``{"polygons": [[[x, y], ...], ...]}``) plus, optionally, ``"holes"``: one list per
    polygon of rings of free space inside it (a ring of walls around a walkable room is a polygon
    whose hole is the room). Hole boundaries are walls too; a point inside a hole is not inside
    the obstacle. ``{"polygons": [...], "holes": [...]}``: the scenario's own map in the same
    layout, each ring closed (its last point repeats its first). ``{"nav2_map": "map.yaml"}``: a
    ROS 2 nav2 map (path relative to the scenario file): occupied cells, unknown ones too unless
    ``"unknown": "free"``, and everything beyond the raster are obstacles.
Robot (body frame: x forward, y left, z up; ``RobotSpec``)
    ``poses`` (timed body-to-world poses), ``waypoints_m`` + ``speed_mps`` (+ ``loop``), ``tum``
    (a TUM file, path relative to the scenario file), ``walk_loop`` (the test room's ellipse), or a
    real robot's path: ``recording`` (an ``nsim import-log`` artifact, e.g. a trajectory-only bag;
    its odometry frame is taken as the world, which is logged) or ``registration`` (an ``nsim
    register-log`` artifact: the path placed in the scene's world). The simulate stage, which holds
    the workspace, inlines those as ``poses`` with a ``source`` naming the artifact
    (:func:`with_recorded_trajectory`).
    Waypoint paths face along the path (``nsim.crowd.paths.waypoint_poses``). The body sits
    ``body_height_m`` above the floor. The humans see the robot as a capsule: the segment
    ``+- half_length_m`` along its heading grown by ``radius_m`` (Spot: 0.3 and 0.28, 1.16 m x 0.56 m).
    ``controller`` (left out: ``replay``, the trajectory as given) hands the robot to ``social_force``,
    ``orca`` or a user's class ``{"python": "module:Class" | "file.py:Class", "params": {...}}``,
    which head for the trajectory's waypoints (or poses' positions) in turn within ``limits``
    (``max_speed_mps``, ``max_yaw_rate_radps``; Spot's by default) and see the people within
    ``sensor_range_m`` (``nsim.crowd.controllers``). A user's class is imported when the scenario is
    read (errors name ``robot.controller.python``); a file's path is stored absolute with its SHA-256.
    ``sensors`` (scene checkpoints and controllers only) gives the controller rendered frames of a
    rig's named sensors at ``rate_hz``; its rig is stored resolved (``nsim.crowd.sensors``).
Humans (``HumanSpec``)
    Start, waypoints walked in straight lines (``loop``: a waypoint loop, else a goal list ending at
    the last), behaviour, walking-group id, body height and radius, desired speed, motion and
    appearance (a human-checkpoint ref for the renderer; only checked as a name here). The motion
    (``nsim.human.person_motion``) is one of nsim's clips by name, a BVH file ``{bvh: FILE, unit, axes,
    joint_map}`` or a human checkpoint's fitted motion ``{from: REF}``; the simulate stage reads the last
    two (``nsim.crowd.motion_source``) and stores the clip itself in the scenario (``motion_clips``,
    named by its SHA-256; the person's motion becomes ``{clip: SHA256, source}``, see
    :func:`with_motion_clips`), so the canonical scenario does not depend on where the file was. The
    desired speed left out is the motion's own (``person_motion.person_gait``: walk 1.3 m/s, idle 0, a
    recorded clip its travel speed).

Time: ``duration_s``, and ``dt_s`` (null: the simulate config's). Randomness: ``seed`` (combined with
the run's ``--seed`` by the simulate stage).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import logging
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import canonical_json, configs_dir, read_text_file
from nsim.crowd.controllers import SENSOR_RANGE_M, RobotLimits, resolve_python_spec
from nsim.crowd.neighbours import points_in_polygons, segments_from_polygons
from nsim.crowd.paths import clearance_m, enclosed, leg_crossings, ring_problem, waypoint_poses, yaw_of_poses
from nsim.crowd.schema import SchemaValidator, SchemaViolation, describe, format_path
from nsim.crowd.sensors import SensorsSpec
from nsim.errors import InputError, NsimError
from nsim.geometry.transforms import interpolate_poses
from nsim.human.motion import MotionClip
from nsim.human.person_motion import clip_data, clip_digest, clip_from_data, person_gait
from nsim.human.skeleton import REFERENCE_HEIGHT_M

log = logging.getLogger(__name__)

SCHEMA_FILE = "schemas/scenario.schema.json"
WALK_LOOP_POINTS = 72
"""The walk-loop ellipse becomes this many waypoints (every 5 degrees)."""
QUAT_NORM_TOLERANCE = 1e-3
SUFFIXES = (".json", ".yaml", ".yml")
CROSSING_EXAMPLES = 3
"""How many of the humans whose legs cross an obstacle the (single) warning names."""
POLYGON_DECIMALS = 6
"""Map polygons a scenario stores (e.g. traced from a nav2 map) are rounded to a micrometre."""

Fail = Callable[[Sequence[str | int] | str, str], InputError]
"""``fail(field path, message)``: the one-line error naming the scenario and the field."""


_VALIDATOR: SchemaValidator | None = None


def scenario_schema_path() -> Path:
    return configs_dir() / SCHEMA_FILE


def scenario_validator() -> SchemaValidator:
    """The validator of ``nsim/configs/schemas/scenario.schema.json`` (read once)."""
    global _VALIDATOR
    if _VALIDATOR is None:
        path = scenario_schema_path()
        try:
            schema = json.loads(path.read_text())
        except FileNotFoundError:
            raise NsimError(f"{path}: the scenario schema is missing (is $NSIM_CONFIGS right?)") from None
        _VALIDATOR = SchemaValidator(schema)
    return _VALIDATOR


def scenario_error(source: str, path: Sequence[str | int] | str, message: str) -> InputError:
    """``{source}: {field path}: {message}`` as one :class:`InputError`."""
    where = path if isinstance(path, str) else format_path(path)
    return InputError(f"{source}: {where}: {message}")


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
    text = read_text_file(path, "scenario", error=InputError)
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
    clip: MotionClip | None = None
    """The recorded clip (on the reference body) of a ``{clip: SHA256}`` motion, else None (``motion``: nsim's clip)."""
    clip_id: str | None = None
    """The recorded clip's SHA-256 (its entry in the scenario's ``motion_clips``)."""
    gait_stride_m: float = 0.0
    """The crowd's gait phase: the clip's own stride at this height, or 0 (``nsim.human.person_motion.Gait``)."""
    gait_period_s: float = 0.0
    """The crowd's gait phase by time for a clip that does not travel (> 0), else 0."""


@dataclasses.dataclass(frozen=True, eq=False)
class RobotSpec:
    """The robot: its capsule for the humans and its timed body-to-world poses.

    sample_times_s: (S,) strictly increasing; sample_poses_se3: (S, 4, 4) body-to-world, body axes
    x forward, y left, z up. ``poses_at`` interpolates them (positions linearly, rotations by
    slerp) and holds the first / last pose outside their span.

    controller: ``"replay"`` (follow the poses), ``"social_force"``, ``"orca"`` or a resolved
    ``{"python", "params", ...}`` entry (``nsim.crowd.controllers``); limits, sensor_range_m: for a
    controller. sensors: rendered frames for the controller (``nsim.crowd.sensors``), or None. goals_m: (G, 2) the goals a controller heads for in turn (the trajectory's waypoints,
    or its poses' positions), cycled when goals_loop; speed_mps: its cruising speed (the waypoint
    trajectory's, else 1 m/s).
    """

    name: str
    radius_m: float
    half_length_m: float
    body_height_m: float
    sample_times_s: np.ndarray
    sample_poses_se3: np.ndarray
    controller: str | Mapping[str, Any] = "replay"
    limits: RobotLimits = RobotLimits()
    sensor_range_m: float = SENSOR_RANGE_M
    sensors: SensorsSpec | None = None
    goals_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    goals_loop: bool = False
    speed_mps: float = 1.0

    def poses_at(self, times_s: np.ndarray) -> np.ndarray:
        """Body-to-world poses ``(T, 4, 4)`` at ``times_s (T,)``."""
        return interpolate_poses(self.sample_times_s, self.sample_poses_se3, times_s)


@dataclasses.dataclass(frozen=True, eq=False)
class SceneMap:
    """The floor plan a scenario's people walk in: its scene entry resolved to arrays.

    scene: the canonical entry the scenario stores (``{"room", "room_seed"}``, ``{"checkpoint":
    artifact id}`` or ``{"polygons", "holes"}``); obstacles_m: polygons ``(K, 2)``, implicitly closed;
    holes_m: for each polygon, its holes (rings of free space inside it); walk_loop_xy_m: the test
    room's walk-loop ellipse ``(cx, cy, rx, ry)``, None for any other scene.
    """

    scene: Mapping[str, Any]
    obstacles_m: tuple[np.ndarray, ...]
    holes_m: tuple[tuple[np.ndarray, ...], ...] = ()
    walk_loop_xy_m: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        polygons = tuple(np.asarray(p, dtype=np.float64) for p in self.obstacles_m)
        holes = tuple(tuple(np.asarray(h, dtype=np.float64) for h in hs) for hs in self.holes_m)
        if not holes:
            holes = tuple(() for _ in polygons)
        if len(holes) != len(polygons):
            raise ValueError(f"holes_m: expected one tuple per polygon ({len(polygons)}), got {len(holes)}")
        object.__setattr__(self, "scene", copy.deepcopy(dict(self.scene)))
        object.__setattr__(self, "obstacles_m", polygons)
        object.__setattr__(self, "holes_m", holes)

    @property
    def scene_id(self) -> str | None:
        """The scene checkpoint's artifact id, or None."""
        return self.scene.get("checkpoint")

    @property
    def label(self) -> str:
        """The map's name in messages (and in a trajectory's ``occupancy.json``)."""
        if "checkpoint" in self.scene:
            return f"scene-checkpoint {self.scene['checkpoint'][:12]}"
        if "room" in self.scene:
            return f"{self.scene['room']} (room_seed {self.scene['room_seed']})"
        return "the scenario's polygon map"


@dataclasses.dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario on its resolved map (see the module docstring). ``data`` returns a fresh copy each time."""

    source: str
    canonical: bytes
    digest: str
    name: str
    duration_s: float
    dt_s: float | None
    seed: int
    scene_map: SceneMap
    robot: RobotSpec
    humans: tuple[HumanSpec, ...]

    @property
    def data(self) -> dict[str, Any]:
        return json.loads(self.canonical)

    @property
    def scene(self) -> dict[str, Any]:
        return dict(self.scene_map.scene)

    @property
    def scene_id(self) -> str | None:
        return self.scene_map.scene_id

    @property
    def obstacles_m(self) -> tuple[np.ndarray, ...]:
        return self.scene_map.obstacles_m

    @property
    def obstacle_holes_m(self) -> tuple[tuple[np.ndarray, ...], ...]:
        return self.scene_map.holes_m

    @property
    def walls_m(self) -> np.ndarray:
        """Obstacle boundary segments ``(M, 2, 2)``: the outlines, then the holes' outlines."""
        return segments_from_polygons(self.obstacles_m + tuple(h for holes in self.obstacle_holes_m for h in holes))

    def in_obstacle(self, points_m: np.ndarray) -> np.ndarray:
        """Which points ``(P, 2)`` lie inside an obstacle (not in one of its holes): ``(P,)`` bool."""
        return points_in_polygons(points_m, self.obstacles_m, self.obstacle_holes_m)

    def scene_label(self) -> str:
        return self.scene_map.label

    def robot_distance_at_start_m(self, points_m: np.ndarray) -> np.ndarray:
        """Distance from points ``(P, 2)`` to the robot's body surface at t = 0: ``(P,)`` (negative inside)."""
        from nsim.crowd.social_force import robot_view
        from nsim.crowd.state import RobotState

        pose0 = self.robot.poses_at(np.zeros(1))[0]
        body = RobotState(
            pose0[:2, 3], np.zeros(2), float(yaw_of_poses(pose0[None])[0]), self.robot.radius_m, self.robot.half_length_m
        )
        return robot_view(np.asarray(points_m, dtype=np.float64).reshape(-1, 2), body).surface_distance_m


@dataclasses.dataclass(frozen=True, eq=False)
class ScenarioSpec:
    """A scenario validated on its own (schema, ids, poses; a TUM file inlined), its scene not yet resolved.

    data: the resolved content so far (never mutated: ``resolve_scenario`` copies it); ``scene``
    is the entry as the file gives it. base_dir: the folder files named in the scenario are
    relative to (None: no files allowed, e.g. for canonical content).
    """

    source: str
    data: Mapping[str, Any]
    base_dir: Path | None = None

    @property
    def scene(self) -> dict[str, Any]:
        return copy.deepcopy(self.data["scene"])

    def error(self, path: Sequence[str | int] | str, message: str) -> InputError:
        """The one-line error naming this scenario and the field ``path``."""
        return scenario_error(self.source, path, message)

    def artifact(self, path: Sequence[str | int], ref: str, kind: str, store, what: str) -> str:
        """The id of the ``kind`` artifact ``ref`` a field names, in the workspace ``store``; errors name the field
        (``what``: what needs the workspace, for the error when there is none)."""
        if store is None:
            raise self.error(path, f"{what} needs a workspace to resolve it")
        try:
            return store.resolve(ref, kind=kind)
        except NsimError as exc:
            raise self.error(path, str(exc)) from None

    def file(self, path: Sequence[str | int], name: str, what: str) -> Path:
        """The file ``name`` a field names, relative to the scenario file; errors name the field."""
        if self.base_dir is None:
            raise self.error(path, f"{what} is only allowed in a scenario file")
        out = Path(name) if Path(name).is_absolute() else self.base_dir / name
        if not out.is_file():
            raise self.error(path, f"no such file {out}")
        return out


# ----------------------------------------------------------------------------------------------
# Step 1: the file on its own


def read_scenario(path: str | Path) -> ScenarioSpec:
    """Read and validate a scenario file (step 1; see the module docstring)."""
    path = Path(path)
    return parse_scenario(read_scenario_file(path), source=str(path), base_dir=path.parent)


def parse_scenario(data: Any, *, source: str, base_dir: Path | None = None) -> ScenarioSpec:
    """Validate plain scenario data (step 1); errors name ``source`` and the field.

    base_dir: where a TUM or nav2 map path is relative to (None: such files are not allowed, e.g.
    for the canonical content, which never has one).
    """
    try:
        d = scenario_validator().validate(data)
    except SchemaViolation as exc:
        raise scenario_error(source, exc.path, _motion_message(exc, data)) from None
    d.pop("$schema", None)
    spec = ScenarioSpec(source, d, base_dir)
    _inline_tum(spec, d)
    _check_controller(spec, d)
    _check_sensors(spec, d)
    _check_humans(spec, d)
    _check_motions(spec, d)
    _check_poses(spec, d)
    return spec


def _motion_message(exc: SchemaViolation, data: Any) -> str:
    """The schema's message, or for a ``humans[k].motion`` that none of its forms fits, one naming the clips
    and the other forms (the schema's generic one-of message would list keys only)."""
    path = exc.path
    if not (len(path) == 3 and path[0] == "humans" and path[2] == "motion"
            and exc.message.startswith(("expected an object with exactly one of", "matches more than one"))):
        return exc.message
    value = data["humans"][path[1]]["motion"]
    names = ", ".join(scenario_validator().schema["$defs"]["motion"]["oneOf"][0]["enum"])
    forms = "a BVH file {bvh: FILE} or a human checkpoint's motion {from: REF}"
    if isinstance(value, str):
        return f"{describe(value)} is not one of {names} (nor {forms})"
    return f"expected one of {names}, {forms}; got {describe(value)}"


def _inline_tum(spec: ScenarioSpec, d: dict) -> None:
    """Replace a TUM trajectory by its poses (in place)."""
    traj = d["robot"]["trajectory"]
    if "tum" not in traj:
        return
    from nsim.io.tum import read_tum

    where = ("robot", "trajectory", "tum")
    path = spec.file(where, traj["tum"], "a TUM file")
    try:
        tum = read_tum(path)
    except InputError as exc:
        raise spec.error(where, str(exc)) from None
    t = tum.timestamps_s - (tum.timestamps_s[0] if traj["rebase_time"] else 0.0)
    if t[0] < 0:
        raise spec.error(where, f"{path}: negative timestamps (set rebase_time: true)")
    d["robot"]["trajectory"] = _poses_entry(t, tum.positions_xyz, tum.orientations_quat_wxyz)


def _poses_entry(t_s: np.ndarray, positions_m: np.ndarray, quats_wxyz: np.ndarray, source: str | None = None) -> dict:
    """A ``poses`` trajectory entry from arrays (``source``: where nsim took them from, kept in the scenario)."""
    entry: dict[str, Any] = {"poses": [
        {"t_s": float(ti), "position_m": p.tolist(), "orientation_quat_wxyz": q.tolist()}
        for ti, p, q in zip(t_s, np.asarray(positions_m, np.float64), np.asarray(quats_wxyz, np.float64), strict=True)
    ]}
    if source is not None:
        entry["source"] = source
    return entry


def with_recorded_trajectory(spec: ScenarioSpec, stamps_ns: np.ndarray, positions_m: np.ndarray,
                             quats_wxyz: np.ndarray, source: str) -> ScenarioSpec:
    """``spec`` with its ``robot.trajectory`` (a ``recording`` or ``registration`` entry, or any other when a
    command line replaces it) replaced by timed poses: ``stamps_ns (N,)`` int64 on the recording's clock (made to
    start at 0 unless the entry says ``rebase_time: false``), body poses ``positions_m (N, 3)`` and
    ``quats_wxyz (N, 4)`` in the scene's world; ``source`` says where they came from and is kept in the
    scenario (``robot.trajectory.source``). The poses are checked as a file's are."""
    d = copy.deepcopy(dict(spec.data))
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    where = ("robot", "trajectory")
    if len(stamps_ns) < 2 or np.any(np.diff(stamps_ns) <= 0):
        raise spec.error(where, f"{source}: {len(stamps_ns)} poses with increasing stamps; a path needs at least 2")
    rebase = d["robot"]["trajectory"].get("rebase_time", True)
    t = (stamps_ns - (stamps_ns[0] if rebase else 0)) / 1e9
    d["robot"]["trajectory"] = _poses_entry(t, positions_m, quats_wxyz, source)
    if t[-1] < float(d["duration_s"]):
        log.warning("%s: robot.trajectory: %s ends at t = %.3f s, before the scenario's duration_s %.3g: the robot "
                    "stands at its last pose for the rest", spec.source, source, t[-1], d["duration_s"])
    out = dataclasses.replace(spec, data=d)
    _check_poses(out, d)
    return out


def _check_controller(spec: ScenarioSpec, d: dict) -> None:
    """A user's controller class imported and checked (``nsim.crowd.controllers``); a file's path made
    absolute and its SHA-256 recorded (in place); a recorded SHA-256 must match the file."""
    entry = d["robot"].get("controller")
    if not isinstance(entry, dict):
        return
    where = ("robot", "controller", "python")
    resolved = resolve_python_spec(entry["python"], spec.base_dir, lambda m: spec.error(where, m))
    if "code_sha256" in entry and entry["code_sha256"] != resolved.get("code_sha256"):
        raise spec.error(("robot", "controller", "code_sha256"), "does not match the controller file's content")
    entry.update(resolved)


def _check_sensors(spec: ScenarioSpec, d: dict) -> None:
    """``robot.sensors`` (``nsim.crowd.sensors``): a scene checkpoint and a controller to use the frames;
    its rig resolved (in place) and its names the rig's."""
    entry = d["robot"].get("sensors")
    if entry is None:
        return
    from nsim.crowd.sensors import resolve_rig

    if "checkpoint" not in d["scene"]:
        raise spec.error(("robot", "sensors"), "rendered sensor frames need a scene checkpoint (scene: {checkpoint: "
                         f"REF}}); this scene is {', '.join(sorted(d['scene']))}")
    if d["robot"].get("controller", "replay") == "replay":
        raise spec.error(("robot", "sensors"), "rendered sensor frames are for a controller (robot.controller); "
                         "the replayed robot would not use them")
    entry["rig"] = resolve_rig(entry["rig"], spec.base_dir, lambda m: spec.error(("robot", "sensors", "rig"), m))
    has = [s["name"] for s in entry["rig"]["sensors"]]
    for k, name in enumerate(entry["names"]):
        if name not in has:
            raise spec.error(("robot", "sensors", "names", k), f"the rig {entry['rig']['name']!r} has no sensor "
                             f"{describe(name)} (has {', '.join(has)})")


def _check_humans(spec: ScenarioSpec, d: dict) -> None:
    """Default ids (``human<k>``, in place), unique and well formed; a warning for one-member groups."""
    seen: dict[str, int] = {}
    groups: dict[int, int] = {}
    for k, h in enumerate(d["humans"]):
        h.setdefault("id", f"human{k}")
        h_id = h["id"]
        if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}", h_id):
            raise spec.error(("humans", k, "id"), f"{describe(h_id)} is not a valid id (letters, digits, '_', '.', '-')")
        if h_id in seen:
            raise spec.error(("humans", k, "id"), f"{describe(h_id)} is already the id of humans[{seen[h_id]}]")
        seen[h_id] = k
        if h["group_id"] is not None:
            groups[h["group_id"]] = groups.get(h["group_id"], 0) + 1
    for g, count in sorted(groups.items()):
        if count == 1:
            log.warning("group_id %d has a single member: group forces do nothing for it", g)


def _check_motions(spec: ScenarioSpec, d: dict) -> None:
    """Recorded clips (``motion_clips``): each one's SHA-256 checked, only those a human names kept (in the order
    of their first use); every human's ``speed_mps`` left out filled in with its motion's own, except for a
    motion the simulate stage has yet to read (``nsim.crowd.motion_source``). In place."""
    table: dict[str, dict] = {}
    for j, entry in enumerate(d.get("motion_clips", [])):
        body = {key: entry[key] for key in ("fps", "root_positions_m", "local_rotations_wxyz")}
        if clip_digest(body) != entry["sha256"]:
            raise spec.error(("motion_clips", j, "sha256"), "does not match the clip's content")
        try:
            clip_from_data(body)
        except ValueError as exc:
            raise spec.error(("motion_clips", j), str(exc)) from None
        table[entry["sha256"]] = entry
    used: list[str] = []
    for k, h in enumerate(d["humans"]):
        motion = h["motion"]
        if isinstance(motion, dict) and "clip" in motion:
            if motion["clip"] not in table:
                raise spec.error(("humans", k, "motion", "clip"), f"{motion['clip'][:12]}... is not in motion_clips")
            used.append(motion["clip"])
    d.pop("motion_clips", None)
    if used:
        d["motion_clips"] = [table[sha] for sha in dict.fromkeys(used)]
    for h in d["humans"]:
        motion = h["motion"]
        if "speed_mps" in h or (isinstance(motion, dict) and "clip" not in motion):
            continue
        clip = None if isinstance(motion, str) else clip_from_data(table[motion["clip"]])
        h["speed_mps"] = round(person_gait(motion if isinstance(motion, str) else "", clip,
                                           REFERENCE_HEIGHT_M).speed_mps, 6)


def with_motion_clips(spec: ScenarioSpec, clips: Mapping[int, tuple[MotionClip, str]]) -> ScenarioSpec:
    """``spec`` with the motions of humans ``k`` replaced by recorded clips: ``clips[k] = (clip on the reference
    body, source)``, ``source`` saying where it came from (kept in the scenario, with no path in it). The clip goes
    to ``motion_clips`` in its plain form (``nsim.human.person_motion.clip_data``), the human's motion becomes
    ``{clip: SHA256, source}``; a speed left out is the clip's."""
    d = copy.deepcopy(dict(spec.data))
    table = list(d.get("motion_clips", []))
    for k, (clip, source) in clips.items():
        body = clip_data(clip)
        sha = clip_digest(body)
        if sha not in {entry["sha256"] for entry in table}:
            table.append({"sha256": sha, **body})
        d["humans"][k]["motion"] = {"clip": sha, "source": source}
    d["motion_clips"] = table
    out = dataclasses.replace(spec, data=d)
    _check_motions(out, d)
    return out


def _check_poses(spec: ScenarioSpec, d: dict) -> None:
    """Timed poses: strictly increasing times, unit quaternions."""
    traj = d["robot"]["trajectory"]
    if "poses" not in traj:
        return
    times = np.array([p["t_s"] for p in traj["poses"]], dtype=np.float64)
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        k = int(bad[0]) + 1
        raise spec.error(
            ("robot", "trajectory", "poses", k, "t_s"), f"{times[k]:g} is not after the previous pose's {times[k - 1]:g}"
        )
    norms = np.linalg.norm(np.array([p["orientation_quat_wxyz"] for p in traj["poses"]], dtype=np.float64), axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE)
    if len(bad):
        k = int(bad[0])
        raise spec.error(
            ("robot", "trajectory", "poses", k, "orientation_quat_wxyz"),
            f"not a unit quaternion (norm {norms[k]:.6g}, tolerance {QUAT_NORM_TOLERANCE:g})",
        )


# ----------------------------------------------------------------------------------------------
# Maps: a scene checkpoint's occupancy.json, the scenario's own polygons


def read_occupancy(path: Path, where: str, fail: Fail) -> tuple[list[np.ndarray], list[list[np.ndarray]]]:
    """Polygons and, per polygon, its holes from an ``occupancy.json`` (errors: ``fail(where, ...)``).

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


def polygon_scene(polygons_m: Sequence[np.ndarray], holes_m: Sequence[Sequence[np.ndarray]]) -> dict[str, Any]:
    """The scene entry ``{"polygons", "holes"}`` for obstacle rings (implicitly closed, e.g. traced from
    a raster): each ring rounded to ``POLYGON_DECIMALS`` and closed (its first point repeated)."""

    def ring(r: np.ndarray) -> list[list[float]]:
        pts = (np.round(np.asarray(r, dtype=np.float64), POLYGON_DECIMALS) + 0.0).tolist()
        return pts + pts[:1]

    return {"polygons": [ring(p) for p in polygons_m], "holes": [[ring(h) for h in hs] for hs in holes_m]}


def polygon_map(scene: Mapping[str, Any], fail: Fail) -> SceneMap:
    """The map of a ``{"polygons", "holes"}`` scene entry (already schema-valid); every ring closed.

    Errors name the ring (``scene.polygons[2]``, ``scene.holes[0][1]``).
    """
    polygons = [np.asarray(p, dtype=np.float64) for p in scene["polygons"]]
    raw_holes = scene.get("holes")
    if raw_holes is not None and len(raw_holes) != len(polygons):
        raise fail(("scene", "holes"), f"expected one list per polygon ({len(polygons)}), got {len(raw_holes)}")
    holes = [[np.asarray(h, dtype=np.float64) for h in hs] for hs in (raw_holes or [[] for _ in polygons])]
    for k, p in enumerate(polygons):
        if (problem := ring_problem(p)) is not None:
            raise fail(("scene", "polygons", k), problem)
        for j, h in enumerate(holes[k]):
            if (problem := ring_problem(h)) is not None:
                raise fail(("scene", "holes", k, j), problem)
    return SceneMap(
        {"polygons": scene["polygons"], **({"holes": raw_holes} if raw_holes is not None else {})},
        tuple(p[:-1] for p in polygons),
        tuple(tuple(h[:-1] for h in hs) for hs in holes),
    )


# ----------------------------------------------------------------------------------------------
# Step 2: on the resolved map


def nav2_scene(spec: ScenarioSpec) -> dict[str, Any]:
    """A ``{"nav2_map": PATH}`` scene as the ``{"polygons", "holes"}`` entry the scenario stores.

    The map (``nsim.io.nav2.read_nav2_map``) is traced as nsim traces its own obstacle maps
    (``nsim.rendering.occupancy.regions_from_mask``): occupied cells, unknown ones unless
    ``unknown: free``, and a one-cell border around the raster (nobody walks off the map) are obstacles.
    """
    from nsim.io.nav2 import CELL_OCCUPIED, CELL_UNKNOWN, read_nav2_map
    from nsim.rendering.occupancy import regions_from_mask

    scene, where = spec.scene, ("scene", "nav2_map")
    path = spec.file(where, scene["nav2_map"], "a nav2 map")
    try:
        grid = read_nav2_map(path)
    except InputError as exc:
        raise spec.error(where, str(exc)) from None
    blocked = grid.cells == CELL_OCCUPIED
    if scene["unknown"] == "obstacle":
        blocked |= grid.cells == CELL_UNKNOWN
    res = grid.resolution_m
    origin = (grid.origin_xy_m[0] - res, grid.origin_xy_m[1] - res)
    regions = regions_from_mask(np.pad(blocked, 1, constant_values=True), origin, res)
    return polygon_scene([r.outer_m for r in regions], [r.holes_m for r in regions])


def resolve_scenario(spec: ScenarioSpec, scene_map: SceneMap) -> Scenario:
    """The scenario on its map (step 2): the walk loop expanded, the canonical content, the free-space checks."""
    d = copy.deepcopy(dict(spec.data))
    d["scene"] = copy.deepcopy(dict(scene_map.scene))
    traj = d["robot"]["trajectory"]
    if "walk_loop" in traj:
        if scene_map.walk_loop_xy_m is None:
            raise spec.error("robot.trajectory.walk_loop", "the walk loop needs a test-room scene ({room: ...})")
        cx, cy, rx, ry = scene_map.walk_loop_xy_m
        wl = traj["walk_loop"]
        sign = -1.0 if wl["clockwise"] else 1.0
        a = np.deg2rad(wl["start_angle_deg"]) + sign * 2.0 * np.pi * np.arange(WALK_LOOP_POINTS) / WALK_LOOP_POINTS
        pts = np.round(np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], axis=-1), 6) + 0.0
        d["robot"]["trajectory"] = {"waypoints_m": pts.tolist(), "speed_mps": wl["speed_mps"], "loop": True}
    canonical = canonical_json(d)
    sc = Scenario(
        source=spec.source,
        canonical=canonical,
        digest=hashlib.sha256(canonical).hexdigest(),
        name=d["name"],
        duration_s=float(d["duration_s"]),
        dt_s=d["dt_s"],
        seed=int(d["seed"]),
        scene_map=scene_map,
        robot=_robot_spec(d),
        humans=_human_specs(spec, d),
    )
    _check_free_space(sc, spec.error)
    return sc


def _human_specs(spec: ScenarioSpec, d: dict) -> tuple[HumanSpec, ...]:
    """The humans of the resolved content ``d``; a motion not yet read (a BVH file, a human checkpoint) is refused."""
    clips = {entry["sha256"]: clip_from_data(entry, name=f"clip {entry['sha256'][:12]}")
             for entry in d.get("motion_clips", [])}
    gaits: dict[tuple[str, float], Any] = {}  # (motion, height) -> Gait: one per clip and body
    out = []
    for k, h in enumerate(d["humans"]):
        motion = h["motion"]
        if isinstance(motion, dict) and "clip" not in motion:
            what = "a BVH file" if "bvh" in motion else "a human checkpoint's motion"
            raise spec.error(("humans", k, "motion"), f"{what} is read by the simulate stage "
                             "(nsim.stages.simulate.load_scenario), which needs the scenario file and its workspace")
        name = motion if isinstance(motion, str) else f"clip {motion['clip'][:12]}"
        clip = clips[motion["clip"]] if isinstance(motion, dict) else None
        key = (name, float(h["height_m"]))
        if key not in gaits:
            gaits[key] = person_gait(name, clip, float(h["height_m"]))
        out.append(_human_spec(h, name, clip, gaits[key]))
    return tuple(out)


def _human_spec(h: dict, motion: str, clip: MotionClip | None, gait) -> HumanSpec:
    return HumanSpec(
        id=h["id"],
        start_m=np.array(h["start_m"], dtype=np.float64),
        waypoints_m=np.array(h["waypoints_m"], dtype=np.float64).reshape(-1, 2),
        loop=bool(h["loop"]),
        behaviour=h["behaviour"],
        group_id=-1 if h["group_id"] is None else int(h["group_id"]),
        height_m=float(h["height_m"]),
        radius_m=float(h["radius_m"]),
        speed_mps=float(h["speed_mps"]),
        motion=motion,
        appearance=h["appearance"],
        clip=clip,
        clip_id=None if clip is None else h["motion"]["clip"],
        gait_stride_m=gait.stride_m,
        gait_period_s=gait.period_s,
    )


def _robot_spec(d: dict) -> RobotSpec:
    r = d["robot"]
    traj = r["trajectory"]
    if "poses" in traj:
        from scipy.spatial.transform import Rotation

        times = np.array([p["t_s"] for p in traj["poses"]], dtype=np.float64)
        quat = np.array([p["orientation_quat_wxyz"] for p in traj["poses"]], dtype=np.float64)
        norms = np.linalg.norm(quat, axis=1)
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
    if "waypoints_m" in traj:
        goals = np.array(traj["waypoints_m"], dtype=np.float64).reshape(-1, 2)
        goals_loop, speed = bool(traj["loop"]), float(traj["speed_mps"])
    else:
        goals, goals_loop, speed = poses[:, :2, 3].copy(), False, 1.0
    return RobotSpec(
        name=r["name"],
        radius_m=float(r["radius_m"]),
        half_length_m=float(r["half_length_m"]),
        body_height_m=float(r["body_height_m"]),
        sample_times_s=times,
        sample_poses_se3=poses,
        controller=copy.deepcopy(r.get("controller", "replay")),
        limits=RobotLimits(**r.get("limits", {})),
        sensor_range_m=float(r.get("sensor_range_m", SENSOR_RANGE_M)),
        sensors=SensorsSpec.from_data(copy.deepcopy(r["sensors"])) if "sensors" in r else None,
        goals_m=goals,
        goals_loop=goals_loop,
        speed_mps=speed,
    )


def _check_free_space(sc: Scenario, fail: Fail) -> None:
    """Every start and waypoint in free space, starts apart and off the robot; one warning for legs across walls."""
    walls = sc.walls_m
    if not sc.humans:
        return
    starts = np.array([h.start_m for h in sc.humans])
    radius = np.array([h.radius_m for h in sc.humans])
    inside = sc.in_obstacle(starts)
    outside = ~enclosed(starts, walls)
    clear = clearance_m(starts, walls)
    crossing: list[tuple[int, str, int]] = []
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
                raise fail(("humans", k, "waypoints_m", j), f"({p[0]:g}, {p[1]:g}) is {what} of {sc.scene_label()}")
        legs = leg_crossings(h.start_m, h.waypoints_m, h.loop, walls)
        if legs:
            crossing.append((k, h.id, legs[0]))
    if crossing:
        examples = ", ".join(f"humans[{k}] ({h_id}) leg {leg}" for k, h_id, leg in crossing[:CROSSING_EXAMPLES])
        more = f" and {len(crossing) - CROSSING_EXAMPLES} more" if len(crossing) > CROSSING_EXAMPLES else ""
        log.warning(
            "%s: %d of %d humans walk a leg that crosses an obstacle (people walk straight between waypoints): %s%s",
            sc.source,
            len(crossing),
            len(sc.humans),
            examples,
            more,
        )
    if len(starts) > 1:
        from scipy.spatial import cKDTree

        pairs = cKDTree(starts).query_pairs(2.0 * float(radius.max()), output_type="ndarray")
        for i, j in sorted(map(tuple, pairs)):
            if np.linalg.norm(starts[i] - starts[j]) < radius[i] + radius[j]:
                raise fail(("humans", int(j), "start_m"), f"overlaps humans[{i}] ({sc.humans[i].id}) at the start")
    d = sc.robot_distance_at_start_m(starts)
    for k in np.flatnonzero(d < radius):
        raise fail(("humans", int(k), "start_m"), "overlaps the robot's body at t = 0")
