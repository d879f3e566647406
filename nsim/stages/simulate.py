"""``nsim simulate``: a scenario's crowd reacting to the robot, as a ``trajectory`` artifact.

Input: a scenario (``nsim.crowd.scenario``; a file, not an artifact: its canonical resolved
content is stored in the artifact and its digest enters the action key), plus the scene
checkpoint it names, if any (an input artifact, so lineage reaches it). ``load_scenario`` reads
the file and resolves its scene here (``resolve_scene``: a checkpoint through the workspace, the
test room through ``nsim.synth``, a nav2 map through ``nsim.io.nav2``); ``nsim.crowd`` gets arrays.
The run's random stream is seeded from both the scenario's ``seed`` and the run's ``--seed``.

Artifact layout (``T`` ticks at ``t_k = k dt_s``, ``N`` humans)::

    trajectory.npz    per-tick arrays (below); deterministic bytes (fixed zip timestamps)
    robot.tum         the robot's body-to-world pose at every tick (body: x forward, y left, z up;
                      z = the body frame's height above the floor)
    humans/<id>.tum   each human's root at every tick: (x, y, 0) on the floor, rotated about +z by
                      its heading (x forward). The root is on the floor, not at the pelvis: the
                      human model places the pelvis at its own height above it.
    metrics.json      HuNavSim's evaluator metrics and nsim's (``nsim.crowd.run_output.run_metrics``),
                      for everyone and per behaviour; null where undefined, e.g. time to goal for
                      a looping robot; and the run's size
    scenario.json     the canonical resolved scenario (``load_scenario`` reads it back unchanged)
    occupancy.json    the 2D obstacle map used (the capture's layout)
    topdown.png       the run from above: obstacles, the robot's path, each human's path
    run.mp4           (video: true) the run from above, H.264 (``nsim.io.video``), ``fps`` frames per
                      second, each frame labelled with the scenario and the time

``trajectory.npz`` holds ``nsim.crowd.CrowdTrajectory.as_arrays()`` (so
``CrowdTrajectory.from_arrays(np.load(path))`` restores it: ``time_s (T,)``, ``position_m (T, N, 2)``,
``velocity_mps (T, N, 2)``, ``heading_rad (T, N)``, ``behaviour_state (T, N)`` int8 (0 navigating,
1 reacting, 2 done), ``gait_phase (T, N)`` in [0, 1), ``goal_index (T, N)``, ``radius_m (N,)``,
``behaviour (N,)`` int8 codes, ``group_id (N,)``, the robot as the crowd saw it) plus
``robot_pose_se3 (T, 4, 4)``, ``human_ids (N,)``, ``height_m (N,)``, ``motion (N,)``, ``appearance (N,)`` (``""``:
default look), ``behaviour_names (6,)`` (code k at index k - 1), recorded clips (``person_motion.person_clip_arrays``).
When a controller drives the robot (the scenario's ``robot.controller``, ``nsim.crowd.controllers``)
it also holds ``robot_command_body (T - 1, 3)``, the command issued at tick k as the controller
returned it, and ``robot_executed_body (T - 1, 3)``, the motion from tick k to k + 1 (clamped to the
robot's limits, stopped by walls), both ``(vx_mps, vy_mps, yaw_rate_radps)`` in the body frame at
tick k; metrics.json's ``run`` names the controller and counts the ticks whose command was not
executed as given. A replayed robot's artifact has neither (its bytes are those of earlier versions).
With ``robot.sensors`` the controller also gets frames of the scene checkpoint rendered on ``--device``
(``nsim.crowd.sensors``); they are not kept: ``run.sensor_frames`` counts them per sensor.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from nsim.config import from_dict, param, to_dict
from nsim.context import RunContext
from nsim.crowd.behaviours import BehaviourParams
from nsim.crowd.driver import simulate, spawn_extra_humans
from nsim.crowd.motion_source import resolve_motions
from nsim.crowd.recorded_path import resolve_trajectory
from nsim.crowd.run_output import SUMMARY_METRICS, run_metrics, write_trajectory
from nsim.crowd.scenario import (
    Scenario,
    ScenarioSpec,
    SceneMap,
    nav2_scene,
    parse_scenario,
    polygon_map,
    read_occupancy,
    read_scenario,
    resolve_scenario,
)
from nsim.crowd.sensors import scene_sensors
from nsim.crowd.social_force import ForceParams
from nsim.crowd.sweep import SweepSpec
from nsim.stages.runner import cached, device_kind, rerun

STAGE = "simulate"
VERSION = 5  # 2: H.264, labelled frames; 3: HuNavSim metrics; 4: numbers rounded; 5: gait phase by each clip; run.mp4 the same
#   bytes on any CPU (nsim.io.video.SWS_FLAGS)

@dataclasses.dataclass(frozen=True)
class Config:
    dt_s: float = param(0.05, gt=0, le=0.5, help="simulation step (a scenario's own dt_s wins)")
    max_duration_s: float | None = param(None, gt=0, help="cut the scenario's duration to this (tests)")
    forces: ForceParams = ForceParams()
    behaviours: BehaviourParams = BehaviourParams()
    video: bool = param(True, help="write run.mp4")
    fps: float = param(
        10.0, gt=0, le=60, help="video frame rate (frames are every round(1 / (fps dt)) ticks)"
    )
    px_per_m: float = param(60.0, ge=10, le=400, help="video and top-down scale")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """A validated scenario on its resolved map (``load_scenario``)."""

    scenario: Scenario

    def ids(self) -> dict[str, str]:
        return {"scene": self.scenario.scene_id} if self.scenario.scene_id is not None else {}


@dataclasses.dataclass(frozen=True)
class Outputs:
    trajectory: str
    cache_hit: bool = False


# ----------------------------------------------------------------------------------------------
# Reading the scenario: its scene reference resolved to arrays, a recorded robot path inlined


def resolve_scene(spec: ScenarioSpec, store=None) -> SceneMap:
    """The map of the scenario's ``scene`` entry: the test room, a scene checkpoint's ``occupancy.json``
    (``store``: the workspace that resolves its ref), the scenario's own polygons or a nav2 map."""
    scene = spec.scene
    if "room" in scene:
        from nsim.synth.room import make_room, occupancy_polygons

        room = make_room(scene["room"], scene["room_seed"])
        return SceneMap(scene, tuple(occupancy_polygons(room)), walk_loop_xy_m=room.walk_loop_xy_m)
    if "polygons" in scene:
        return polygon_map(scene, spec.error)
    if "nav2_map" in scene:
        return polygon_map(nav2_scene(spec), spec.error)
    where, ref = ("scene", "checkpoint"), scene["checkpoint"]
    art_id = spec.artifact(where, ref, "scene-checkpoint", store, "a scene checkpoint")
    art = store.get(art_id).path
    occ = art / "occupancy.json"
    if not occ.is_file() and (art / "scene.json").is_file():
        why = json.loads((art / "scene.json").read_text()).get("walkable_map_why_not")
        if why:
            raise spec.error(where, f"scene-checkpoint {art_id[:12]} has no walkable map: {why}")
    return SceneMap({"checkpoint": art_id}, *read_occupancy(occ, f"scene.checkpoint {ref!r}", spec.error))


def _person_bvh_file() -> str:  # imported on use: the CLI answers without scipy or OpenCV
    from nsim.train.human_data_video import PERSON_BVH_FILE

    return PERSON_BVH_FILE


def load_scenario(path: str | Path, store=None, robot_trajectory: str | None = None) -> Scenario:
    """Read, validate and resolve a scenario file (``store``: the workspace, for a scene checkpoint, a recording,
    a registration or a human checkpoint's motion; ``robot_trajectory``: ``--robot-trajectory``, see
    :func:`resolve_trajectory`; the people's BVH files and checkpoints' motions: :func:`resolve_motions`)."""
    spec = resolve_motions(resolve_trajectory(read_scenario(path), store, robot_trajectory), store, _person_bvh_file)
    return resolve_scenario(spec, resolve_scene(spec, store))


def scenario_from_data(data: Any, *, source: str, base_dir: Path | None = None, store=None) -> Scenario:
    """Validate and resolve plain scenario data (e.g. an artifact's ``scenario.json``); errors name ``source``."""
    spec = parse_scenario(data, source=source, base_dir=base_dir)
    return resolve_scenario(spec, resolve_scene(spec, store))


# ----------------------------------------------------------------------------------------------
# Running


def effective_times(sc, cfg: Config) -> tuple[float, float]:
    """``(dt_s, duration_s)`` of a run: the scenario's dt_s or else the config's; the duration capped."""
    dt = sc.dt_s if sc.dt_s is not None else cfg.dt_s
    duration = sc.duration_s if cfg.max_duration_s is None else min(sc.duration_s, cfg.max_duration_s)
    return float(dt), float(duration)


def rollout_seed(ctx: RunContext, sc) -> int:
    """The crowd's seed from the run's ``--seed`` and the scenario's ``seed``."""
    return int(ctx.rng(f"simulate.crowd.{sc.seed}").integers(2**63))


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    extra = {"scenario": inputs.scenario.digest}  # it covers robot.sensors (the resolved rig, names, rate)
    if inputs.scenario.robot.sensors is not None:  # rendered frames also depend on the device
        extra["device"] = device_kind(ctx.device)
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    store = ctx.store
    sc = inputs.scenario
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(trajectory=hit, cache_hit=True)

    dt_s, duration_s = effective_times(sc, cfg)
    cam = scene_sensors(sc, store, ctx.device)  # robot.sensors: the scene rendered without people
    sim = simulate(sc, cfg.forces, cfg.behaviours, dt_s, duration_s, rollout_seed(ctx, sc), cam and cam.hook())
    metrics = run_metrics(sc, sim, cfg.forces)
    if cam is not None:  # the frames are not kept: how many of each sensor the controller asked for
        metrics["run"]["sensor_frames"] = dict(cam.frames_rendered)
    with store.publish(kind="trajectory", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(),
                       seed=ctx.seed) as out:
        write_trajectory(out.dir, sc, sim, metrics, cfg)
        out.summary.update({"scenario": sc.name, "scenario_digest": sc.digest, "humans": len(sc.humans),
                            "ticks": len(sim.time_s), "dt_s": dt_s, "duration_s": float(sim.time_s[-1]),
                            **{k: metrics["hunav"][k] for k in SUMMARY_METRICS}})
    return Outputs(trajectory=out.ref)


# ----------------------------------------------------------------------------------------------
# Sweeps (the file and its table: ``nsim.crowd.sweep``)


def sweep_items(spec: SweepSpec, scenario_path: Path, cfg: Config, ctx: RunContext) -> list[dict[str, Any]]:
    """One task per grid cell: plain, picklable data (``run_sweep_item`` runs one).

    The scenarios are built and validated here, in the driver, so a bad sweep fails before any
    work is sent out; workers only re-read the canonical content.
    """
    from nsim.crowd.controllers import controller_label

    base = load_scenario(scenario_path, store=ctx.store)
    items = []
    for seed in spec.seeds:
        for size in spec.crowd_sizes:
            for b_idx, b in enumerate(spec.behaviours):
                names = (b,) if isinstance(b, str) else tuple(b)
                for c_idx, controller in enumerate(spec.controllers):
                    data = base.data
                    data["seed"] = int(seed)
                    if not spec.keep_scenario_humans:
                        data["humans"] = []
                    if controller != "replay":  # replay cells keep the scenario as it is (same ids)
                        data["robot"]["controller"] = controller
                    # with no extra people the behaviour set plays no part: those cells share one scenario
                    data["name"] = (
                        f"{base.name[:40]}.s{seed}.n{size}"
                        + (f".b{b_idx}" if size else "")
                        + (f".c{c_idx}" if controller != "replay" else "")
                    )
                    source = f"{scenario_path} (seed {seed}, controllers[{c_idx}])"
                    cell = parse_scenario(data, source=source)
                    sc = resolve_scenario(cell, base.scene_map)
                    # the same extra people for every controller
                    rng = ctx.rng(f"simulate.sweep.spawn.{seed}.{size}.{'+'.join(names)}")
                    sc = spawn_extra_humans(sc, size, names, rng)
                    items.append(
                        {
                            "workspace": str(ctx.store.root),
                            "seed": ctx.seed,
                            "force": ctx.force,
                            "config": to_dict(cfg),
                            "scenario": sc.data,
                            "source": sc.source,
                            "grid": {
                                "seed": int(seed),
                                "extra_people": int(size),
                                "behaviours": list(names),
                                "controller": controller_label(controller),
                            },
                        }
                    )
    return items


def run_sweep_item(item: dict[str, Any]) -> dict[str, Any]:
    """Run one sweep cell in this process (any worker): returns the artifact id, its metrics and the grid cell."""
    from nsim.workspace.store import Store

    store = Store(item["workspace"])
    ctx = RunContext(store=store, device_spec="cpu", seed=item["seed"], force=item["force"], progress=False)
    cfg = from_dict(Config, item["config"])
    sc = scenario_from_data(item["scenario"], source=item["source"], store=store)
    out = run(Inputs(sc), cfg, ctx)
    metrics = json.loads(store.get(out.trajectory).file("metrics.json").read_text())
    return {
        "grid": item["grid"],
        "scenario": sc.name,
        "humans": len(sc.humans),
        "trajectory": out.trajectory,
        "cache_hit": out.cache_hit,
        "metrics": metrics["hunav"],
    }


def run_sweep(
    spec: SweepSpec,
    scenario_path: Path,
    cfg: Config,
    ctx: RunContext,
    *,
    engine: str = "local",
    address: str | None = None,
    workers: int = 1,
) -> list[dict[str, Any]]:
    """Every grid cell as its own artifact, through ``nsim.distributed.map_tasks``; rows in grid order."""
    from nsim.distributed import map_tasks

    items = sweep_items(spec, scenario_path, cfg, ctx)
    return map_tasks(run_sweep_item, items, engine=engine, address=address, workers=workers)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    art = ctx.store.get(manifest["id"])
    sc = scenario_from_data(
        json.loads(art.file("scenario.json").read_text()),
        source=f"artifact {art.short} scenario.json",
        store=ctx.store,
    )
    return rerun(run, Inputs(sc), Config, manifest, ctx).trajectory
