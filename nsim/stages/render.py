"""``nsim render``: the robot's sensors in the trained world, frame by frame, as a ``render`` artifact.

Three modes:

``trajectory``
    For each selected tick of a ``trajectory`` artifact (``nsim simulate``), for each sensor of a
    rig (``configs/robots/*.yaml``): world pose = robot pose x mount; rays from the camera model
    or the LiDAR pattern; the scene NeRF rendered along them (marching with the baked occupancy
    grid, early ray termination) and, with human checkpoints, every visible person's samples
    merged with the scene's in depth order (one volume rendering over both).
``poses``
    Every frame (or the held-out frames) of a ``poses`` / ``capture`` artifact with the frame's own
    camera: what ``nsim evaluate`` compares with the captured images.
``recording``
    Exactly the recorded sensors of a ``registration`` (``nsim register-log``) of a ``recording``
    (``nsim import-log``), so that sim and real frames pair one to one: per stream, per kept frame,
    its stamp moved onto the odometry clock (``nsim.rendering.recording``), the body pose
    interpolated in the registration's world trajectory, the stream's own camera model at its
    recorded size, or (LiDAR) one ray along each recorded point's direction. Frames outside the
    trajectory's span are skipped and counted. No sensor noise. With ``--trajectory`` and
    ``--humans`` the run's people are drawn as in trajectory mode, posed at the frame's instant
    (``nsim.rendering.people.HumanSet.joint_transforms_at``: interpolated between the run's ticks) on every stream, the
    run's clock tied to the recording's by ``people_time_offset_s`` (``nsim.rendering.recording``:
    0 = the run's first tick at the recording's first odometry stamp, as ``nsim capture robot-log``
    records a run); frames outside the run's span are drawn without people and counted; the
    robot's poses still come from the registration.

Artifact layout (``NNNNNN`` = tick index in the trajectory, or frame index in the poses)::

    render.json                  mode, sensors, frames (index, time, name), conventions, the scene id
    rig.json                     the resolved rig (mounts, intrinsics, LiDAR patterns)
    robot.tum                    trajectory mode: the robot body pose at each rendered tick
    cameras/<sensor>.json        per camera: transforms.json (intrinsics, cam_to_world per frame)
    <camera>/rgb/NNNNNN.png      8-bit sRGB (gray cameras: one channel)
    <camera>/rgb_linear/NNNNNN.exr   (rgb_exr: true) linear float16 R, G, B
    <camera>/depth/NNNNNN.exr    float32 channel Z: the rig's depth kind (z-depth along the optical
                                 axis unless the rig says range), metres; inf = no return, NaN =
                                 no valid measurement; stated in the header (nsim_depth)
    <camera>/mask/NNNNNN.png     (with humans) 16-bit instance mask: 0 background, k = human k
    <camera>/boxes.json          (with humans) COCO-style person boxes per frame
    <lidar>/scan/NNNNNN.exr      organised sweep (rows = beams, cols = azimuth): X Y Z (sensor
                                 frame), range, intensity (= opacity), ring; see nsim.io.lidar_exr
    <lidar>/scan/NNNNNN.ply      the returns as a point cloud (sensor frame)
    preview/contact_sheet.png    every ``preview_every``-th frame: the cameras side by side + LiDAR BEV
                                 (recording mode: each camera's recorded frame beside the rendered one,
                                 the LiDAR's recorded points grey under the rendered ones)
    preview/preview.mp4          (video: true) the same for every frame (H.264, ``nsim.io.video``)

Recording mode mirrors the recording's layout, file for file, for the frames rendered (``NNNNNN``
= the recording's own frame index, ``<name>`` the stream's)::

    render.json                  mode "recording", the recording, registration and scene ids, per
                                 stream: name, kind, frames (index, stamp_ns, odom_time_ns,
                                 sensor_to_world 4 x 4; with people people_time_s) and
                                 skipped_outside_trajectory (with people people_outside_run); with
                                 people ``people``: trajectory, humans, people_time_offset_s, the run's
                                 span, the first odometry stamp and the rule
    camera/<name>/NNNNNN.png     8-bit sRGB at the recorded size; grey where the recording's is grey
    depth/<name>/NNNNNN.exr      float32 channel Z: z-depth in metres; inf = no return, NaN = invalid
    lidar/<name>/NNNNNN.exr      one row of the recorded file's N points, in its order: X Y Z (sensor
                                 frame, metres; NaN without a return) and range (metres along the
                                 recorded point's direction; inf = no return, NaN = no direction)
    mask/<name>/NNNNNN.png       (with people; camera streams) 16-bit instance mask: 0 background,
                                 k + 1 = the trajectory's person k (a folder that no recording has)
    boxes/<name>.json            (with people; camera streams) COCO-style person boxes per frame

Sharding: frames are cut into fixed shards of ``shard_frames``; each shard is rendered into its
own directory under ``<workspace>/tmp/render.<key>.shards/`` and published there by an atomic
rename, so a rerun after a crash renders only the missing shards. The artifact (and its
manifest) is published last, from the complete set. Each shard draws its sensor noise from
generators seeded by (seed, frame, sensor), so the result does not depend on the shard size,
the engine or the number of workers.

This module reads the inputs, keys the run and publishes; the work is the core's:
``nsim.rendering.render_plan`` (the adapted rig, the frames of each mode, the shards),
``nsim.rendering.shard`` (rendering and measuring one shard), ``nsim.rendering.people`` (the run's
people: posing, culling, compositing) and ``nsim.rendering.render_output`` (render.json, previews,
the ROS 2 bag export).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import shutil
from pathlib import Path
from typing import Any

from nsim.config import from_dict, param
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.rendering import render_plan
from nsim.rendering.renderer import MarchConfig

STAGE = "render"
VERSION = 5  # 2: people culled by the sensor range; no person on invalid (outside the fisheye circle) rays
# 3: ``fill`` (no-return pixels over the training images' mean colour) and ``background``
# 4: preview/preview.mp4 in H.264 (was MPEG-4 Part 2); contact sheet tiles labelled (nsim.io.labels)
# 5: the culling tests a pixel by its centre in the bound's own coordinates (whole numbers; it took u + 0.5,
#    so a person could lose the column or row at the bound's right or bottom edge)

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Config:
    tick_stride: int = param(1, ge=1, help="render every k-th tick (trajectory) or frame (poses; recording: of "
                                           "each stream's kept frames)")
    start: int = param(0, ge=0, help="first tick / frame index")
    max_frames: int | None = param(None, ge=1, help="render at most this many ticks / frames (recording: per stream)")
    frames: str = param("all", choices=("all", "heldout"), help="poses mode: all frames or the scene's held-out ones")
    sensors: tuple[str, ...] = param((), help="rig sensors to render, or (recording mode) the recording's streams, "
                                              "each <kind>/<name> or a bare <name> for every kind (empty: all)")
    camera_clock_kinds: tuple[str, ...] = param(("camera",), help="recording mode: the stream kinds stamped on the "
                                                "cameras' clock (shifted by the registration's clock_offset_s); the "
                                                "others are stamped on the odometry's")
    people_time_offset_s: float = param(0.0, ge=-1e6, le=1e6,
                                        help="recording mode with --trajectory: a frame at odometry time o sees the "
                                             "run's people at simulation time time_s[0] + (o - the recording's first "
                                             "odometry stamp) + people_time_offset_s; 0 puts the run's first tick at "
                                             "the first odometry stamp, as nsim capture robot-log records a run")
    image_scale: float = param(1.0, gt=0.0, le=4.0, help="scale every camera's resolution (intrinsics follow; "
                                                       "recording mode renders the recorded sizes: 1 only)")
    lidar_azimuth_scale: float = param(1.0, gt=0.0, le=1.0, help="scale LiDAR azimuth samples per sweep (recording "
                                                                 "mode renders the recorded points: 1 only)")
    shard_frames: int = param(8, ge=1, help="frames per shard (the unit of resume and of distribution)")
    method: str = param("proposal", choices=("proposal", "march"),
                        help="march: constant steps with the occupancy grid and early termination; proposal: "
                             "the proposal sampler the model trained with (fewer samples, faster on CPU)")
    march: MarchConfig = MarchConfig(step_m=0.01)
    chunk_rays: int = param(16384, ge=256)
    depth_estimate: str = param("median", choices=("median", "expected"),
                                help="ray depth: the median of the weights or the normalised expected depth")
    min_accumulation: float = param(0.5, ge=0.0, le=1.0, help="opacity below which a ray has no return")
    fill: str = param("image_mean", choices=("image_mean", "none"),
                      help="camera pixels with no return (accumulation below min_accumulation, depth inf: no "
                           "surface, e.g. a ceiling the capture never looked at): image_mean composites the ray's "
                           "remaining light over the training images' mean colour (kept with the scene checkpoint) "
                           "instead of the model's background; none: as the model renders them")
    background: str = param("scene", choices=("scene", "last_sample"),
                            help="what a ray's remaining light is composited over: scene, the model's own "
                                 "background (sampler.background, as it was trained); last_sample, the scene "
                                 "field's colour at the ray's last sample (nerfacto's default)")
    rgb_exr: bool = param(False, help="also write linear RGB EXR")
    noise: bool = param(True, help="apply the rig's depth / LiDAR noise models (seeded; recording mode has no rig "
                                   "and renders noise-free)")
    culling: bool = param(True, help="query people's NeRFs only on rays that can see their posed box (2D bound for "
                                      "cameras, ray-box test); false: on every ray (the same images, slower)")
    preview_every: int = param(10, ge=1, help="contact sheet: every k-th rendered frame")
    preview_max_rows: int = param(8, ge=1)
    video: bool = param(True, help="write preview/preview.mp4")
    video_fps: float = param(10.0, gt=0.0, le=60.0)


@dataclasses.dataclass(frozen=True)
class Inputs:
    """trajectory, poses or registration (exactly one; registration: ``--recording``, a registered
    recording, with which a trajectory only supplies the people); scene: a scene-checkpoint (default:
    the one the trajectory names); rig: a rig file (trajectory mode); humans: human-checkpoint ids."""

    trajectory: str | None = None
    poses: str | None = None
    scene: str | None = None
    rig: Path | None = None
    humans: tuple[str, ...] = ()
    registration: str | None = None

    def ids(self) -> dict[str, str]:
        out = {}
        if self.trajectory:
            out["trajectory"] = self.trajectory
        if self.poses:
            out["poses"] = self.poses
        if self.registration:
            out["registration"] = self.registration
        if self.scene:
            out["scene"] = self.scene
        for k, h in enumerate(self.humans):
            out[f"human{k}"] = h
        return out


@dataclasses.dataclass(frozen=True)
class Outputs:
    render: str
    cache_hit: bool = False
    shards_rendered: int = 0
    shards_reused: int = 0


# ---------------------------------------------------------------------------------- resolving inputs
def resolve_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    """Artifact ids resolved and checked (kinds, the scene checkpoint's presence)."""
    store = ctx.store
    modes = (inputs.poses, inputs.registration, inputs.trajectory if inputs.registration is None else None)
    if sum(x is not None for x in modes) != 1:
        raise InputError("render: give exactly one of --trajectory, --poses or --recording (with --recording, "
                         "--trajectory only supplies the people)")
    if inputs.registration is not None:
        return resolve_recording_inputs(inputs, ctx)
    traj = poses = None
    if inputs.trajectory is not None:
        traj = store.resolve(inputs.trajectory, kind="trajectory")
        if inputs.rig is None:
            raise InputError("render --trajectory: a rig file is needed (--rig configs/robots/spot.yaml)")
    else:
        poses = store.resolve(inputs.poses)
        kind = store.get(poses).kind
        if kind not in ("poses", "capture"):
            raise InputError(f"--poses {inputs.poses}: a {kind} artifact; render needs a poses or capture artifact")
    scene = inputs.scene
    if scene is None and traj is not None:
        named = store.get(traj).manifest.get("inputs", {}).get("scene")
        if named is None:
            raise InputError(f"trajectory {traj[:12]} names no scene checkpoint: pass --scene")
        if not (store.root / "objects" / named[:2] / named).is_dir():
            raise InputError(f"trajectory {traj[:12]}: its scene checkpoint {named[:12]} is missing from the "
                             f"workspace {store.root} (train it with nsim train-scene, or pass --scene)")
        scene = named
    elif scene is None:
        raise InputError("render --poses: pass --scene (a scene-checkpoint artifact)")
    else:
        scene = store.resolve(scene, kind="scene-checkpoint")
    humans = tuple(store.resolve(h, kind="human-checkpoint") for h in inputs.humans)
    return Inputs(trajectory=traj, poses=poses, scene=scene, rig=inputs.rig, humans=humans)


def resolve_recording_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    """Recording mode: a registration (its recording present), a metric scene checkpoint, and people (human
    checkpoints and the trajectory whose people they draw) both or neither."""
    store = ctx.store
    reg = store.resolve(inputs.registration)
    kind = store.get(reg).kind
    if kind != "registration":
        raise InputError(f"--recording {inputs.registration}: a {kind} artifact; render --recording needs a "
                         "registration artifact (nsim register-log)")
    rec = store.get(reg).manifest.get("inputs", {}).get("recording")
    if rec is None or not (store.root / "objects" / rec[:2] / rec).is_dir():
        raise InputError(f"--recording {inputs.registration}: its recording {str(rec)[:12]} is missing from the "
                         f"workspace {store.root} (import it again with nsim import-log)")
    if inputs.humans and inputs.trajectory is None:
        raise InputError("render --recording: --humans needs --trajectory, the nsim simulate run whose people they "
                         "draw (a recording has no people of its own)")
    if inputs.trajectory is not None and not inputs.humans:
        raise InputError(f"render --recording: --trajectory {inputs.trajectory} only supplies the people; pass "
                         "--humans (the human checkpoints that draw them)")
    traj = store.resolve(inputs.trajectory, kind="trajectory") if inputs.trajectory is not None else None
    if inputs.rig is not None:
        raise InputError(f"render --recording: --rig {inputs.rig}: a recording renders its own recorded sensors")
    if inputs.scene is None:
        raise InputError("render --recording: pass --scene (a scene-checkpoint artifact of the registration's world)")
    scene = store.resolve(inputs.scene, kind="scene-checkpoint")
    if not render_plan.scene_is_metric(ctx, scene):
        raise InputError(f"--scene {inputs.scene}: the scene's scale is arbitrary (trained on poses without a metric "
                         "scale); a registered recording lives in a metric world")
    trained_on = store.get(scene).manifest.get("inputs", {}).get("poses")
    registered_to = store.get(reg).manifest.get("inputs", {}).get("poses")
    if trained_on and registered_to and trained_on != registered_to:
        log.warning("render --recording: scene %s was trained on poses %s, the recording registered to poses %s: "
                    "their worlds must agree", scene[:12], trained_on[:12], registered_to[:12])
    humans = tuple(store.resolve(h, kind="human-checkpoint") for h in inputs.humans)
    return Inputs(scene=scene, registration=reg, trajectory=traj, humans=humans)


def load_rig_for(inputs: Inputs, cfg: Config):
    """The rig (scaled and filtered by the config), or None in poses mode."""
    if inputs.rig is None or inputs.trajectory is None:
        return None
    from nsim.sensors.rig import Rig

    return render_plan.adapt_rig(Rig.load(inputs.rig), cfg)


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext, rig) -> str:
    extra = {"device": "cuda" if str(ctx.device).startswith("cuda") else "cpu"}
    if rig is not None:
        extra["rig"] = hashlib.sha256(json.dumps(rig.to_dict(), sort_keys=True, default=str).encode()).hexdigest()
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


# ---------------------------------------------------------------------------------- the stage
def run(inputs: Inputs, cfg: Config, ctx: RunContext, engine=None) -> Outputs:
    """Render (or find in the run cache). ``engine``: an ``nsim.rendering.engine.EngineConfig``
    (default: local, in-process); it never changes the result."""
    from functools import partial

    from nsim.rendering.engine import EngineConfig, run_shards
    from nsim.rendering.render_output import assemble
    from nsim.rendering.shard import ShardRenderer

    store = ctx.store
    inputs = resolve_inputs(inputs, ctx)
    rig = load_rig_for(inputs, cfg)
    key = action_key(inputs, cfg, ctx, rig)
    if not ctx.force and (hit := store.lookup(key)) is not None:
        return Outputs(render=hit.id, cache_hit=True)

    streams = None
    if inputs.registration is not None:
        frames, streams = render_plan.plan_recording(inputs, cfg, ctx)
    else:
        frames = render_plan.plan_frames(inputs, cfg, ctx)
    shards = render_plan.shards_of(frames, cfg)
    shard_root = store.root / "tmp" / f"{STAGE}.{key[:24]}.shards"
    shard_root.mkdir(parents=True, exist_ok=True)
    keys = [render_plan.shard_key(key, s) for s in shards]
    present = sum((shard_root / k).is_dir() for k in keys)
    job = {
        "workspace": str(store.root),
        "scene_dir": str(store.get(inputs.scene).path),
        "human_dirs": [str(store.get(h).path) for h in inputs.humans],
        "trajectory_file": str(store.get(inputs.trajectory).file("trajectory.npz")) if inputs.trajectory else None,
        "rig": rig.to_dict() if rig is not None else None,
        "recording_dir": (str(store.get(store.get(inputs.registration).manifest["inputs"]["recording"]).path)
                          if inputs.registration else None),
        "streams": streams,
        "seed": ctx.seed,
        "device": str(ctx.device),
        "shards": shards,
    }
    factory = partial(ShardRenderer, job, cfg)
    done = run_shards(factory, list(range(len(shards))), shard_root, lambda i: keys[i], engine or EngineConfig(),
                      progress=ctx.show_progress)
    with store.publish(kind="render", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(),
                       seed=ctx.seed) as out:
        summary = assemble(out.dir, inputs, cfg, rig, frames, [done[i] for i in range(len(shards))], ctx,
                           streams=streams, recording_dir=job["recording_dir"])
        out.summary.update(summary)
    shutil.rmtree(shard_root, ignore_errors=True)
    return Outputs(render=out.ref, shards_rendered=len(shards) - present, shards_reused=present)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    summary = manifest.get("summary", {})
    rig_file = summary.get("rig_file")
    ids = manifest["inputs"]
    cfg = from_dict(Config, manifest["config"])
    ctx = dataclasses.replace(ctx, force=True)
    inputs = Inputs(trajectory=ids.get("trajectory"), poses=ids.get("poses"), scene=ids.get("scene"),
                    rig=Path(rig_file) if rig_file else None,
                    humans=tuple(ids[k] for k in sorted(ids) if k.startswith("human")),
                    registration=ids.get("registration"))
    return run(inputs, cfg, ctx).render
