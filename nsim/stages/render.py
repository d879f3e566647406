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
    (``HumanSet.joint_transforms_at``: interpolated between the run's ticks) on every stream, the
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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import from_dict, param, to_dict
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.rendering.renderer import MarchConfig

STAGE = "render"
VERSION = 4  # 2: people culled by the sensor range; no person on invalid (outside the fisheye circle) rays
# 3: ``fill`` (no-return pixels over the training images' mean colour) and ``background``
# 4: preview/preview.mp4 in H.264 (was MPEG-4 Part 2); contact sheet tiles labelled (nsim.io.labels)
log = logging.getLogger(__name__)

DEPTH_ATTRIBUTE = {
    "z": "z-depth: metres along the camera's optical (+z) axis; inf = no return; NaN = no valid measurement",
    "range": "range: metres along the pixel's ray; inf = no return; NaN = no valid measurement",
}


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
    if not _scene_is_metric(ctx, scene):
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

    rig = Rig.load(inputs.rig)
    return adapt_rig(rig, cfg)


def adapt_rig(rig, cfg: Config):
    from nsim.sensors.rig import CameraSensor, LidarSensor

    names = list(cfg.sensors) or list(rig.names)
    unknown = [n for n in names if n not in rig.names]
    if unknown:
        raise InputError(f"sensors: the rig {rig.name!r} has no sensor {', '.join(unknown)} (has {', '.join(rig.names)})")
    sensors = []
    for s in rig.sensors:
        if s.name not in names:
            continue
        if isinstance(s, CameraSensor) and cfg.image_scale != 1.0:
            s = dataclasses.replace(s, camera=s.camera.scaled(cfg.image_scale))
        if isinstance(s, LidarSensor) and cfg.lidar_azimuth_scale != 1.0:
            a = max(1, round(s.config.azimuth_samples * cfg.lidar_azimuth_scale))
            s = dataclasses.replace(s, config=dataclasses.replace(s.config, azimuth_samples=a))
        sensors.append(s)
    return dataclasses.replace(rig, sensors=tuple(sensors))


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext, rig) -> str:
    extra = {"device": "cuda" if str(ctx.device).startswith("cuda") else "cpu"}
    if rig is not None:
        extra["rig"] = hashlib.sha256(json.dumps(rig.to_dict(), sort_keys=True, default=str).encode()).hexdigest()
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


# ---------------------------------------------------------------------------------- the frames
def plan_frames(inputs: Inputs, cfg: Config, ctx: RunContext) -> list[dict[str, Any]]:
    """The frames to render: ``{index, time_s, body_to_world | cam_to_world (+ camera), name}``."""
    store = ctx.store
    if inputs.trajectory is not None:
        from nsim.io.npz import read_npz

        arrays = read_npz(store.get(inputs.trajectory).file("trajectory.npz"), required=("robot_pose_se3", "time_s"))
        poses = arrays["robot_pose_se3"]
        times = arrays["time_s"]
        if not np.isfinite(poses).all():
            raise InputError(f"trajectory {inputs.trajectory[:12]}: robot poses contain NaN/inf")
        idx = list(range(cfg.start, len(times), cfg.tick_stride))
        frames = [{"index": int(i), "time_s": float(times[i]), "body_to_world": poses[i].tolist()} for i in idx]
    else:
        from nsim.io.transforms_json import read_transforms

        art = store.get(inputs.poses)
        data = read_transforms(art.file("transforms.json"))
        ids = range(len(data.frames))
        if cfg.frames == "heldout":
            scene_json = json.loads(store.get(inputs.scene).file("scene.json").read_text())
            held = scene_json.get("extra", scene_json).get("eval_images")
            if held is None:
                raise InputError(f"scene {inputs.scene[:12]}: scene.json lists no held-out images")
            ids = held
        idx = [i for i in ids if i >= cfg.start][:: cfg.tick_stride]
        frames = []
        for i in idx:
            f = data.frames[i]
            cam = f.camera.scaled(cfg.image_scale) if cfg.image_scale != 1.0 else f.camera
            frames.append({"index": int(i), "time_s": f.timestamp_s, "name": Path(f.file_path).name,
                           "cam_to_world": np.asarray(f.cam_to_world).tolist(), "camera": cam.to_dict()})
    if cfg.max_frames is not None:
        frames = frames[: cfg.max_frames]
    if not frames:
        raise InputError("render: no frames selected (check start / tick_stride / max_frames)")
    return frames


def plan_recording(inputs: Inputs, cfg: Config, ctx: RunContext) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Recording mode: the frames to render (``{stream, index, stamp_ns, odom_time_ns, body_to_world,
    sensor_to_world}``, with people also ``people_time_s``, stream by stream) and the streams (``{key, kind,
    name, sensor_to_body, camera, color, skipped_outside_trajectory}``, with people also
    ``people_outside_run``). Every check before any rendering."""
    import cv2

    from nsim.rendering import recording as core
    from nsim.workspace.store import safe_relpath

    if cfg.image_scale != 1.0 or cfg.lidar_azimuth_scale != 1.0:
        raise InputError(f"render --recording: image_scale {cfg.image_scale:g}, lidar_azimuth_scale "
                         f"{cfg.lidar_azimuth_scale:g}: a recording renders at its recorded sizes and points, so "
                         "that sim and real frames pair one to one; set both to 1")
    if bad := [k for k in cfg.camera_clock_kinds if k not in core.KINDS]:
        raise InputError(f"camera_clock_kinds: {', '.join(map(repr, bad))} is not a stream kind "
                         f"({', '.join(core.KINDS)})")
    store = ctx.store
    reg = store.get(inputs.registration)
    registered = core.read_registration(reg.path, reg.id[:12])
    reg_doc, offset_s = registered.doc, registered.clock_offset_s
    if abs(float(reg_doc.get("scale", 1.0)) - 1.0) > 0.01:
        log.warning("render --recording: registration %s has scale %g: the sensors' mounts stay in metres",
                    reg.id[:12], reg_doc["scale"])
    rec = store.get(reg.manifest["inputs"]["recording"])
    doc = json.loads(rec.file("recording.json").read_text())
    try:
        keys = core.select_streams(list(doc["streams"]), cfg.sensors)
    except ValueError as e:
        raise InputError(f"sensors: recording {rec.id[:12]} has no stream {e} (it has: "
                         f"{', '.join(doc['streams'])})") from None
    people = _people_clock(inputs, ctx, rec) if inputs.trajectory is not None else None
    frames, streams = [], []
    for key in keys:
        entry = doc["streams"][key]
        kind, name = key.split("/", 1)
        if kind not in core.KINDS or entry.get("dir") != key or not safe_relpath(key) or "/" in name:
            raise InputError(f"recording {rec.id[:12]}: recording.json: stream {key!r} is not <kind>/<name> "
                             f"(kinds: {', '.join(core.KINDS)}) kept in its own folder")
        stamps = np.load(rec.file(f"{entry['dir']}/stamps_ns.npy"), allow_pickle=False)
        indices = np.asarray(entry["frames"], dtype=np.int64)
        if stamps.shape != indices.shape:
            raise InputError(f"recording {rec.id[:12]}: {key}: {len(stamps)} stamps for {len(indices)} frames")
        pick = core.select_frames(indices, cfg.start, cfg.tick_stride)
        mount = np.asarray(entry["sensor_to_body"], dtype=np.float64)
        odom = core.odometry_time_ns(stamps[pick], offset_s, kind in cfg.camera_clock_kinds)
        inside, body, sensor = registered.sensor_poses(odom, mount)
        rows = [{"stream": key, "index": int(indices[p]), "stamp_ns": int(stamps[p]), "odom_time_ns": int(t),
                 "body_to_world": b.tolist(), "sensor_to_world": w.tolist()}
                for p, t, b, w, ok in zip(pick, odom, body, sensor, inside, strict=True) if ok]
        rows = rows[: cfg.max_frames]
        frames += rows
        info = {"key": key, "kind": kind, "name": name, "sensor_to_body": mount.tolist(), "dir": entry["dir"],
                "skipped_outside_trajectory": int((~inside).sum()), "camera": entry.get("camera"), "color": "rgb"}
        if people is not None:
            t = core.people_time_s(np.array([r["odom_time_ns"] for r in rows], dtype=np.int64),
                                   people["first_odometry_ns"], people["run_start_s"], cfg.people_time_offset_s)
            for r, ti in zip(rows, t, strict=True):
                r["people_time_s"] = float(ti)
            info["people_outside_run"] = int(((t < people["run_start_s"]) | (t > people["run_end_s"])).sum())
        if kind == "camera" and len(indices):
            first = cv2.imread(str(rec.file(f"{entry['dir']}/{indices[0]:06d}.png")), cv2.IMREAD_UNCHANGED)
            if first is None:
                raise InputError(f"recording {rec.id[:12]}: {entry['dir']}/{indices[0]:06d}.png is not a readable image")
            info["color"] = "gray" if first.ndim == 2 else "rgb"
        if kind != "lidar" and info["camera"] is None:
            raise InputError(f"recording {rec.id[:12]}: {key} has no camera model")
        streams.append(info)
        if info["skipped_outside_trajectory"]:
            log.warning("render --recording: %s: %d of %d frames lie outside the registered trajectory; skipped",
                        key, info["skipped_outside_trajectory"], len(pick))
    if not frames:
        raise InputError(f"render --recording: no frames selected in {', '.join(keys)} (check start / tick_stride / "
                         "max_frames, and that the frames lie inside the registered trajectory)")
    if people is not None:
        outside = sum(st["people_outside_run"] for st in streams)
        if outside == len(frames):
            seen = [f["people_time_s"] for f in frames]
            raise InputError(f"--trajectory {inputs.trajectory[:12]}: its run spans simulation time "
                             f"[{people['run_start_s']:g}, {people['run_end_s']:g}] s, the recording's frames see "
                             f"[{min(seen):g}, {max(seen):g}] s (people_time_offset_s {cfg.people_time_offset_s:g}): "
                             "no frame overlaps the run, nobody would be drawn")
        if outside:
            log.warning("render --recording: %d of %d frames lie outside the run's time span; drawn without people",
                        outside, len(frames))
    return frames, streams


def _people_clock(inputs: Inputs, ctx: RunContext, rec) -> dict[str, Any]:
    """Recording mode with people: the run's time span and the recording's first odometry stamp, the two ends
    of ``nsim.rendering.recording.people_time_s``; the trajectory's people arrays checked."""
    from nsim.io.npz import read_npz

    path = ctx.store.get(inputs.trajectory).file("trajectory.npz")
    a = read_npz(path, required=("time_s", "position_m", "heading_rad", "gait_phase", "height_m"))
    t, pos = a["time_s"], a["position_m"]
    n = pos.shape[1] if pos.ndim == 3 else -1
    if (t.ndim != 1 or len(t) < 1 or not np.isfinite(t).all() or np.any(np.diff(t) <= 0) or pos.shape != (len(t), n, 2)
            or a["heading_rad"].shape != (len(t), n) or a["gait_phase"].shape != (len(t), n)
            or a["height_m"].shape != (n,)):
        raise InputError(f"{path}: time_s (T,) increasing, position_m (T, P, 2), heading_rad and gait_phase (T, P), "
                         "height_m (P,) expected")
    if n == 0:
        raise InputError(f"--trajectory {inputs.trajectory[:12]}: its run has no people to draw")
    odom_ns = np.load(rec.file("trajectory_ns.npy"), allow_pickle=False)
    if odom_ns.ndim != 1 or len(odom_ns) < 1:
        raise InputError(f"recording {rec.id[:12]}: trajectory_ns.npy holds no odometry stamp")
    return {"run_start_s": float(t[0]), "run_end_s": float(t[-1]), "first_odometry_ns": int(odom_ns[0])}


def shards_of(frames: list[dict], cfg: Config) -> list[list[dict]]:
    return [frames[a : a + cfg.shard_frames] for a in range(0, len(frames), cfg.shard_frames)]


def shard_key(key: str, shard: list[dict]) -> str:
    first, last = shard[0]["index"], shard[-1]["index"]
    ids = [f["index"] if "stream" not in f else (f["stream"], f["index"]) for f in shard]  # recording: per stream
    digest = hashlib.sha256(f"{key}:{ids}".encode()).hexdigest()[:16]
    return f"shard_{first:06d}_{last:06d}_{digest}"


# ---------------------------------------------------------------------------------- the stage
def run(inputs: Inputs, cfg: Config, ctx: RunContext, engine=None) -> Outputs:
    """Render (or find in the run cache). ``engine``: an ``nsim.rendering.engine.EngineConfig``
    (default: local, in-process); it never changes the result."""
    from nsim.rendering.engine import EngineConfig, run_shards

    store = ctx.store
    inputs = resolve_inputs(inputs, ctx)
    rig = load_rig_for(inputs, cfg)
    key = action_key(inputs, cfg, ctx, rig)
    if not ctx.force and (hit := store.lookup(key)) is not None:
        return Outputs(render=hit.id, cache_hit=True)

    streams = None
    if inputs.registration is not None:
        frames, streams = plan_recording(inputs, cfg, ctx)
    else:
        frames = plan_frames(inputs, cfg, ctx)
    shards = shards_of(frames, cfg)
    shard_root = store.root / "tmp" / f"{STAGE}.{key[:24]}.shards"
    shard_root.mkdir(parents=True, exist_ok=True)
    keys = [shard_key(key, s) for s in shards]
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
        "config": to_dict(cfg),
        "seed": ctx.seed,
        "device": str(ctx.device),
        "shards": shards,
    }
    from functools import partial

    factory = partial(ShardRenderer, job)
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


# ---------------------------------------------------------------------------------- per-shard rendering
class ShardRenderer:
    """Holds the loaded models; renders one shard of frames into a directory (a Ray actor keeps one)."""

    def __init__(self, job: dict[str, Any]) -> None:
        import torch

        from nsim.rendering.model import load_model
        from nsim.rendering.occupancy import OccupancyGrid

        self.job = job
        self.cfg = from_dict(Config, job["config"])
        self.device = torch.device(job["device"])
        scene_dir = Path(job["scene_dir"])
        self.model = load_model(scene_dir, device=self.device).eval()
        if self.cfg.background != "scene":
            self.model.sampler_cfg = dataclasses.replace(self.model.sampler_cfg, background=self.cfg.background)
        self.fill_rgb = None  # (3,) colour of no-return pixels (``fill``)
        if self.cfg.fill == "image_mean":
            mean = self.model.image_mean_rgb  # set by load_model; None for checkpoints written before it existed
            if mean is None:
                log.warning("%s: the scene checkpoint has no image_mean_rgb (written before nsim kept it); "
                            "no-return pixels are not filled", scene_dir)
            else:
                self.fill_rgb = torch.tensor(mean, dtype=torch.float32, device=self.device)
        self.grid = OccupancyGrid.load(scene_dir / "occupancy_grid.npy", device=self.device)
        self.rig = None
        if job["rig"] is not None:
            from nsim.sensors.rig import Rig

            self.rig = Rig.from_resolved(job["rig"])
        self.humans = HumanSet.load(job["human_dirs"], job["trajectory_file"], self.device) if job["human_dirs"] else None
        self.streams = {}  # recording mode: stream key -> its CameraSensor (camera, depth) or None (LiDAR)
        for st in job.get("streams") or ():
            self.streams[st["key"]] = _stream_sensor(st)

    # -- rays -> samples -> outputs
    def _render_rays(self, origins: np.ndarray, dirs: np.ndarray, valid: np.ndarray, near: float, far: float,
                     posed: list, camera=None, cam_to_world=None) -> dict[str, np.ndarray]:
        """Render world rays ``(N, 3)`` among the ``posed`` people (``HumanSet.joint_transforms``; [] for
        nobody): rgb (N, 3), range (N,), accumulation (N,), instance (N,)."""
        import torch

        from nsim.rendering.rays import make_rays
        from nsim.rendering.renderer import render_rays

        cfg = self.cfg
        o = torch.as_tensor(np.array(origins, dtype=np.float32), device=self.device)
        d = torch.as_tensor(np.where(valid[:, None], dirs, [0.0, 0.0, 1.0]), dtype=torch.float32, device=self.device)
        sc = self.model.sampler_cfg
        rays = make_rays(o, d, max(near, sc.near_m), min(far, sc.far_m),
                         self.model.aabb if sc.clip_rays_to_box else None)
        people = (self.humans.visible(posed, o, d, camera, cam_to_world, cfg.culling, t_min=near, t_max=far,
                                      valid=valid) if self.humans and posed else [])
        if not people:
            out = render_rays(self.model, rays, cfg.method, self.grid, cfg.march, cfg.chunk_rays)
            instance = np.zeros(len(o), dtype=np.uint16)
        else:
            out, instance = self.humans.composite(self.model, self.grid, rays, people, cfg)
        r = out.depth_median if cfg.depth_estimate == "median" else out.depth
        acc = out.accumulation
        surface = acc >= cfg.min_accumulation
        r = torch.where(surface, r, torch.tensor(float("inf"), device=r.device))
        v = torch.as_tensor(valid, device=r.device)
        rgb = out.rgb
        if self.fill_rgb is not None:  # no return: the remaining light over the training images' mean colour
            rgb = torch.where(surface[:, None], rgb, rgb + (1.0 - acc)[:, None] * (self.fill_rgb - out.background))
        rgb = torch.where(v[:, None], rgb.clamp(0.0, 1.0), 0.0)
        return {"rgb": rgb.cpu().numpy(), "range": torch.where(v, r, float("nan")).cpu().numpy(),
                "acc": acc.cpu().numpy(), "instance": np.where(valid, instance, 0).astype(np.uint16)}

    def _rng(self, frame_index: int, sensor: str) -> np.random.Generator:
        digest = hashlib.sha256(f"nsim.render:{self.job['seed']}:{frame_index}:{sensor}".encode()).digest()
        return np.random.default_rng(int.from_bytes(digest[:8], "little"))

    def render_shard(self, shard: int, out_dir: Path) -> dict:
        out_dir = Path(out_dir)
        stats = []
        for frame in self.job["shards"][shard]:
            if "stream" in frame:
                stats.append(self._render_recording_frame(frame, out_dir))
            elif self.rig is not None:
                stats.append(self._render_tick(frame, out_dir))
            else:
                stats.append(self._render_pose_frame(frame, out_dir))
        (out_dir / "frames.json").write_text(json.dumps(stats, indent=1, sort_keys=True) + "\n")
        return {"frames": len(stats)}

    def _render_tick(self, frame: dict, out_dir: Path) -> dict:
        from nsim.sensors.rig import CameraSensor, LidarSensor

        body = np.asarray(frame["body_to_world"], dtype=np.float64)
        i = frame["index"]
        row: dict[str, Any] = {"index": i}
        posed = self.humans.joint_transforms(i) if self.humans else []
        for s in self.rig.sensors:
            o, d = s.rays(body)
            valid = np.isfinite(d).all(-1)
            if isinstance(s, CameraSensor):
                res = self._render_rays(o, d, valid, 0.0, float("inf"), posed, s.camera, s.world_pose(body))
                row[s.name] = self._write_camera(out_dir, s.name, i, s, res)
            elif isinstance(s, LidarSensor):
                c = s.config
                res = self._render_rays(o, d, valid, c.min_range_m, c.max_range_m, posed)
                row[s.name] = self._write_lidar(out_dir, s, i, res)
        return row

    def _render_pose_frame(self, frame: dict, out_dir: Path) -> dict:
        from nsim.geometry import Camera

        cam = Camera.from_dict(frame["camera"])
        c2w = np.asarray(frame["cam_to_world"], dtype=np.float64)
        dirs_cam = cam.pixel_dirs_cam().reshape(-1, 3)
        valid = np.isfinite(dirs_cam).all(-1)
        d = np.where(valid[:, None], dirs_cam, [0.0, 0.0, 1.0]) @ c2w[:3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(c2w[:3, 3], d.shape)
        res = self._render_rays(o, d, valid, 0.0, float("inf"), [], cam, c2w)
        h, w = cam.height, cam.width
        i = frame["index"]
        from nsim.io.exr import write_depth_exr
        from nsim.io.images import to_uint8, write_image

        (out_dir / "frames" / "rgb").mkdir(parents=True, exist_ok=True)
        (out_dir / "frames" / "depth").mkdir(parents=True, exist_ok=True)
        write_image(out_dir / "frames" / "rgb" / f"{i:06d}.png", to_uint8(res["rgb"].reshape(h, w, 3)))
        z = np.where(dirs_cam[:, 2] > 1e-9, res["range"] * dirs_cam[:, 2], np.nan).reshape(h, w)
        write_depth_exr(out_dir / "frames" / "depth" / f"{i:06d}.exr", z, attributes={"nsim_depth": DEPTH_ATTRIBUTE["z"]})
        return {"index": i, "frames": {"mean_accumulation": float(np.mean(res["acc"]))}}

    def _render_recording_frame(self, frame: dict, out_dir: Path) -> dict:
        """One frame of one recorded stream, written where the recording keeps it (module docstring)."""
        from nsim.io.exr import write_depth_exr, write_points_exr
        from nsim.io.images import to_uint8, write_image

        key, i = frame["stream"], frame["index"]
        kind, name = key.split("/", 1)
        path = out_dir / kind / name / f"{i:06d}"
        path.parent.mkdir(parents=True, exist_ok=True)
        s = self.streams[key]
        posed = self.humans.joint_transforms_at(frame["people_time_s"]) if self.humans else []
        if kind == "lidar":
            from nsim.io.exr import read_points_exr
            from nsim.rendering.recording import point_directions, points_from_ranges

            rec = read_points_exr(Path(self.job["recording_dir"]) / kind / name / f"{i:06d}.exr")
            xyz_rec = np.stack([rec[c].reshape(-1) for c in "XYZ"], axis=-1)
            dirs, valid = point_directions(xyz_rec)
            pose = np.asarray(frame["sensor_to_world"], dtype=np.float64)
            o = np.broadcast_to(pose[:3, 3], dirs.shape)
            res = self._render_rays(o, dirs @ pose[:3, :3].T, valid, 0.0, float("inf"), posed)
            xyz = points_from_ranges(dirs, res["range"]).astype(np.float32)
            write_points_exr(path.with_suffix(".exr"), {"X": xyz[None, :, 0], "Y": xyz[None, :, 1], "Z": xyz[None, :, 2],
                                                         "range": res["range"].astype(np.float32)[None, :]})
            return {"stream": key, "index": i, "points": len(xyz), "returns": int(np.isfinite(res["range"]).sum())}
        body = np.asarray(frame["body_to_world"], dtype=np.float64)
        o, d = s.rays(body)
        valid = np.isfinite(d).all(-1)
        res = self._render_rays(o, d, valid, 0.0, float("inf"), posed, s.camera, s.world_pose(body))
        h, w = s.ray_shape
        if kind == "camera":
            write_image(path.with_suffix(".png"), to_uint8(s.expose(res["rgb"].reshape(h, w, 3))))
            row = {"stream": key, "index": i, "mean_accumulation": float(np.mean(res["acc"]))}
            if self.humans is not None:
                from nsim.io.coco import write_instance_mask

                (out_dir / "mask" / name).mkdir(parents=True, exist_ok=True)
                write_instance_mask(out_dir / "mask" / name / f"{i:06d}.png", res["instance"].reshape(h, w))
                row["people_px"] = int((res["instance"] > 0).sum())
            return row
        depth = s.depth_from_range(res["range"].reshape(h, w)).astype(np.float32)  # inf stays inf, NaN stays NaN
        write_depth_exr(path.with_suffix(".exr"), depth, attributes={"nsim_depth": DEPTH_ATTRIBUTE["z"],
                                                                     "nsim_sensor": name})
        return {"stream": key, "index": i, "valid_depth_fraction": float(np.isfinite(depth).mean())}

    def _write_camera(self, out_dir: Path, name: str, i: int, s, res: dict) -> dict:
        from nsim.io.exr import write_depth_exr, write_rgb_exr
        from nsim.io.images import to_uint8, write_image

        h, w = s.ray_shape
        info: dict[str, Any] = {}
        if s.emits_image:
            rgb = s.expose(res["rgb"].reshape(h, w, 3))
            (out_dir / name / "rgb").mkdir(parents=True, exist_ok=True)
            write_image(out_dir / name / "rgb" / f"{i:06d}.png", to_uint8(rgb))
            if self.cfg.rgb_exr:
                (out_dir / name / "rgb_linear").mkdir(parents=True, exist_ok=True)
                lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
                if lin.ndim == 2:
                    lin = np.repeat(lin[..., None], 3, axis=-1)
                write_rgb_exr(out_dir / name / "rgb_linear" / f"{i:06d}.exr", lin)
        if s.emits_depth:
            rng = self._rng(i, name) if self.cfg.noise else None
            depth_cfg = s.depth
            if not self.cfg.noise:
                depth_cfg = dataclasses.replace(depth_cfg, noise_abs_std_m=0.0, noise_rel_std=0.0)
            from nsim.sensors.depth import apply_depth_model

            depth = apply_depth_model(s.depth_from_range(np.nan_to_num(res["range"].reshape(h, w), nan=np.inf)),
                                      depth_cfg, rng)
            depth = np.where(np.isfinite(res["range"].reshape(h, w)) | np.isinf(res["range"].reshape(h, w)), depth, np.nan)
            (out_dir / name / "depth").mkdir(parents=True, exist_ok=True)
            write_depth_exr(out_dir / name / "depth" / f"{i:06d}.exr", depth.astype(np.float32),
                            attributes={"nsim_depth": DEPTH_ATTRIBUTE[s.depth.kind], "nsim_sensor": name})
            info["valid_depth_fraction"] = float(np.isfinite(depth).mean())
        if self.humans is not None:
            from nsim.io.coco import write_instance_mask

            (out_dir / name / "mask").mkdir(parents=True, exist_ok=True)
            write_instance_mask(out_dir / name / "mask" / f"{i:06d}.png", res["instance"].reshape(h, w))
            info["people_px"] = int((res["instance"] > 0).sum())
        return info

    def _write_lidar(self, out_dir: Path, s, i: int, res: dict) -> dict:
        from nsim.io.lidar_exr import write_lidar_exr, write_lidar_ply

        c, a = s.ray_shape
        exact = np.nan_to_num(res["range"].reshape(c, a), nan=np.inf)
        if self.cfg.noise:
            ranges = s.measure(exact, self._rng(i, s.name))
        else:
            ok = np.isfinite(exact) & (exact >= s.config.min_range_m) & (exact <= s.config.max_range_m)
            ranges = np.where(ok, exact, np.inf).astype(np.float32)
        intensity = np.where(np.isfinite(ranges), res["acc"].reshape(c, a), 0.0).astype(np.float32)
        scan = s.scan(ranges, intensity)
        (out_dir / s.name / "scan").mkdir(parents=True, exist_ok=True)
        write_lidar_exr(out_dir / s.name / "scan" / f"{i:06d}.exr", scan, sensor=s.name, elevations_deg=s.elevations_deg)
        write_lidar_ply(out_dir / s.name / "scan" / f"{i:06d}.ply", scan)
        return {"returns": int(np.isfinite(ranges).sum())}


def _stream_sensor(stream: dict[str, Any]):
    """A recorded camera or depth stream as the rig's ``CameraSensor`` (its rays, grey conversion and
    z-depth are the rig's); None for a LiDAR stream (its rays are its recorded points)."""
    from nsim.geometry import Camera
    from nsim.sensors.depth import DepthConfig
    from nsim.sensors.rig import CameraSensor

    if stream["kind"] == "lidar":
        return None
    return CameraSensor(name=stream["name"], sensor_to_body=np.asarray(stream["sensor_to_body"], dtype=np.float64),
                        camera=Camera.from_dict(stream["camera"]), kind=stream["kind"], color=stream["color"],
                        depth=DepthConfig(kind="z") if stream["kind"] == "depth" else None)


# ---------------------------------------------------------------------------------- humans
class HumanSet:
    """The trajectory's people, each drawn by a human checkpoint (person k uses checkpoint k mod M)."""

    def __init__(self, models: list, arrays: dict[str, np.ndarray], device) -> None:
        self.models = models
        self.arrays = arrays
        self.device = device
        self._loops: dict[tuple[str, float], Any] = {}

    @classmethod
    def load(cls, human_dirs: list[str], trajectory_file: str | None, device) -> HumanSet:
        from nsim.human.nerf import load_human_model

        if trajectory_file is None:
            raise InputError("render: human checkpoints need a trajectory (people come from nsim simulate)")
        from nsim.io.npz import read_npz

        arrays = read_npz(Path(trajectory_file))
        return cls([load_human_model(d, device=device).eval() for d in human_dirs], arrays, device)

    def _loop(self, motion: str, height: float):
        from nsim.human.gait import DEFAULT_CLIPS, default_clip
        from nsim.human.motion import LocomotionLoop

        key = (motion, round(height, 3))
        if key not in self._loops:
            name = motion if motion in DEFAULT_CLIPS else "walk"
            self._loops[key] = LocomotionLoop.from_clip(default_clip(name, height))
        return self._loops[key]

    def joint_transforms(self, tick: int) -> list[tuple[int, np.ndarray]]:
        """``[(person k, joint_transforms (J, 4, 4))]`` at a tick, for people still in the run."""
        a = self.arrays
        return self._posed(a["position_m"][tick], a["heading_rad"][tick], a["gait_phase"][tick])

    def joint_transforms_at(self, time_s: float) -> list[tuple[int, np.ndarray]]:
        """``[(person k, joint_transforms (J, 4, 4))]`` at simulation time ``time_s``, between ticks too
        (``nsim.rendering.recording.people_states_at``; on a tick: ``joint_transforms(tick)``); nobody
        outside the run's span."""
        from nsim.rendering.recording import people_states_at

        a = self.arrays
        present, pos, head, phase = people_states_at(a["time_s"], a["position_m"], a["heading_rad"], a["gait_phase"],
                                                     time_s)
        return self._posed(pos, head, phase)

    def _posed(self, position_m: np.ndarray, heading_rad: np.ndarray, gait_phase: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Every person with a finite ``position_m (P, 2)`` posed by its gait loop at ``heading_rad (P,)`` and
        ``gait_phase (P,)``: ``[(person k, joint_transforms (J, 4, 4))]``."""
        from nsim.human.skeleton import forward_kinematics

        a = self.arrays
        out = []
        for k in range(len(position_m)):
            pos = position_m[k]
            if not np.isfinite(pos).all():
                continue
            height = float(a["height_m"][k])
            motion = str(a["motion"][k]) if "motion" in a else "walk"
            loop = self._loop(motion, height)
            root, quats = loop.pose_at(np.array([gait_phase[k]]), pos[None], np.array([heading_rad[k]]))
            T = forward_kinematics(loop.skeleton, quats[0], root[0])
            out.append((k, T))
        return out

    def visible(self, posed: list[tuple[int, np.ndarray]], origins, dirs, camera, cam_to_world, culling: bool,
                t_min: float = 0.0, t_max: float = math.inf, valid=None) -> list[dict]:
        """Of the ``posed`` people (``joint_transforms``), those whose posed box the rays can see, with the
        ray mask to cast their samples on.

        With ``culling`` a person is dropped when the box's image rectangle misses a camera's frame
        (the cheap test, first), then when no ray meets the box within ``[t_min, t_max]`` m (the
        sensor's range) among the ``valid (N,)`` rays; the mask keeps the rays that meet it."""
        import torch

        from nsim.rendering.culling import OrientedBox, camera_box_bounds, lidar_ray_box_mask

        people = []
        o = d = None
        for k, T in posed:
            model = self.models[k % len(self.models)]
            with torch.no_grad():
                lo, hi = model.posed_box(torch.as_tensor(T, dtype=torch.float32)).reshape(2, 3).cpu().numpy()
            box = OrientedBox.from_min_max(lo.astype(np.float64), hi.astype(np.float64), np.eye(4))
            inside = None
            if culling and camera is not None and cam_to_world is not None:
                bounds = camera_box_bounds(camera, np.linalg.inv(cam_to_world), box)
                if bounds is None:
                    continue
                u0, v0, u1, v1 = bounds
                h, w = camera.height, camera.width
                uu, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
                inside = ((uu >= u0) & (uu <= u1) & (vv >= v0) & (vv <= v1)).reshape(-1)
            if o is None:
                o = origins.cpu().numpy().astype(np.float64)
                d = dirs.cpu().numpy().astype(np.float64)
            mask = lidar_ray_box_mask(o, d, box, t_min, t_max)  # exact ray-box test within the sensor's range
            if valid is not None:
                mask &= np.asarray(valid, dtype=bool)
            if inside is not None:
                mask &= inside
            if culling and not mask.any():
                continue
            people.append({"k": k, "T": T, "model": model, "mask": torch.as_tensor(mask if culling else np.ones_like(mask))})
        return people

    def composite(self, scene_model, grid, rays, people: list[dict], cfg: Config):
        """Scene samples + every person's samples on its rays, merged in depth order; one volume
        rendering over both. Returns (RenderOutput, instance ids (N,) uint16)."""
        import torch

        from nsim.rendering.model import RaySamples, composite
        from nsim.rendering.renderer import render_rays

        n = len(rays)
        scene_out = render_rays(scene_model, rays, cfg.method, grid, cfg.march, cfg.chunk_rays, return_samples=True)
        any_mask = torch.zeros(n, dtype=torch.bool)
        for p in people:
            any_mask |= p["mask"]
        idx = torch.nonzero(any_mask, as_tuple=True)[0]
        out = scene_out
        instance = np.zeros(n, dtype=np.uint16)
        if len(idx):
            sub = rays[idx]
            parts = [RaySamples(*(getattr(scene_out.samples, f)[idx] for f in ("t_starts", "t_ends", "sigma", "rgb")))]
            owners = [torch.zeros_like(parts[0].sigma, dtype=torch.long)]
            live = torch.zeros(len(idx), dtype=torch.bool)  # rays where some person has a sample of non-zero length
            for p in people:
                m = p["mask"][idx]
                with torch.no_grad():  # the model's parameters require grad; rendering needs none
                    hs = p["model"].render_samples(sub.origins, sub.dirs, torch.as_tensor(p["T"], dtype=torch.float32),
                                                   sub.near, sub.far, box_test=cfg.culling)
                sig = torch.where(m[:, None], hs.sigma, 0.0)
                live |= m & (hs.t_ends > hs.t_starts).any(-1)
                parts.append(RaySamples(hs.t_starts, hs.t_ends, sig, hs.rgb))
                owners.append(torch.full_like(sig, p["k"] + 1, dtype=torch.long))
            # a ray that no person's samples reach keeps the scene's own rendering, bit for bit (re-compositing
            # the same samples after a merge can round differently): culling on or off, the same image
            parts = [RaySamples(*(getattr(q, f)[live] for f in ("t_starts", "t_ends", "sigma", "rgb"))) for q in parts]
            owners = [o[live] for o in owners]
            idx = idx[live]
        if len(idx):
            merged = RaySamples(*(torch.cat([getattr(q, f) for q in parts], dim=1)
                                  for f in ("t_starts", "t_ends", "sigma", "rgb")))
            comp = composite(merged, scene_out.background[idx])  # the scene's per-ray background
            owner = torch.cat(owners, dim=1)
            order = torch.argsort(merged.t_starts, dim=-1, stable=True)
            owner = torch.gather(owner, -1, order)
            # instance: the person holding the most weight on the ray, if they hold more than half
            per = torch.zeros(len(idx), len(people) + 1)
            for j, p in enumerate(people):
                per[:, j + 1] = (comp.weights * (owner == p["k"] + 1)).sum(-1)
            best = per.argmax(-1)
            strong = per.max(-1).values > 0.5
            ids = torch.tensor([0] + [p["k"] + 1 for p in people])[best]
            instance[idx.numpy()] = torch.where(strong, ids, 0).numpy().astype(np.uint16)
            for f in ("rgb", "depth", "depth_median", "accumulation"):
                getattr(out, f)[idx] = getattr(comp, f)
        return out, instance


# ---------------------------------------------------------------------------------- assembling the artifact
def _scene_is_metric(ctx: RunContext, scene: str) -> bool:
    """False when the scene was trained on poses of arbitrary scale (its scene.json says ``metric: false``)."""
    doc = json.loads(ctx.store.get(scene).file("scene.json").read_text())
    return doc.get("extra", doc).get("metric", True) is not False


def _world_units(ctx: RunContext, scene: str | None) -> str:
    """What the world's lengths are: metres, unless the scene was trained on poses of arbitrary scale."""
    if scene is not None and not _scene_is_metric(ctx, scene):
        return "arbitrary units (the poses had no metric scale; see scene.json units_per_m), z up"
    return "metres, z up"


def assemble(out_dir: Path, inputs: Inputs, cfg: Config, rig, frames: list[dict], shard_dirs: list[Path],
             ctx: RunContext, streams: list[dict] | None = None, recording_dir: str | None = None) -> dict[str, Any]:
    """Hard-link every shard's files into the artifact, then write the frame-level files."""
    rows: list[dict] = []
    for sd in shard_dirs:
        for src in sorted(Path(sd).rglob("*")):
            if src.is_file() and src.name != "frames.json":
                dst = out_dir / src.relative_to(sd)
                dst.parent.mkdir(parents=True, exist_ok=True)
                try:
                    os.link(src, dst)
                except OSError:
                    shutil.copyfile(src, dst)
        rows += json.loads((Path(sd) / "frames.json").read_text())
    if streams is not None:
        return _assemble_recording(out_dir, inputs, cfg, frames, streams, rows, Path(recording_dir), ctx)
    meta: dict[str, Any] = {
        "mode": "trajectory" if inputs.trajectory else "poses",
        "scene": inputs.scene,
        "frames": [{k: f[k] for k in ("index", "time_s", "name") if k in f} for f in frames],
        "conventions": {
            "world": _world_units(ctx, inputs.scene),
            "camera": "OpenCV axes (x right, y down, z forward)",
            "lidar": "x forward, y left, z up; rows = beams (ring 0 lowest), columns = azimuth",
            "body": "x forward, y left, z up",
            "rgb": "8-bit sRGB PNG",
            "depth": "float32 EXR channel Z, metres; see the nsim_depth header attribute",
        },
        "per_frame": rows,
    }
    summary: dict[str, Any] = {"mode": meta["mode"], "frames": len(frames), "humans": len(inputs.humans)}
    if rig is not None:
        from nsim.io.transforms_json import Frame, TransformsData, write_transforms
        from nsim.io.tum import Trajectory, write_tum
        from nsim.sensors.rig import CameraSensor

        (out_dir / "rig.json").write_text(json.dumps(rig.to_dict(), indent=1, sort_keys=True, default=str) + "\n")
        body = np.stack([np.asarray(f["body_to_world"]) for f in frames])
        times = np.array([f["time_s"] for f in frames])
        write_tum(out_dir / "robot.tum", Trajectory.from_poses(times, body))
        (out_dir / "cameras").mkdir()
        for s in rig.sensors:
            if isinstance(s, CameraSensor):
                tf = [Frame(file_path=f"{s.name}/rgb/{f['index']:06d}.png", cam_to_world=s.world_pose(b), camera=s.camera,
                            timestamp_s=f["time_s"]) for f, b in zip(frames, body, strict=True)]
                write_transforms(out_dir / "cameras" / f"{s.name}.json", TransformsData(frames=tf))
        meta["sensors"] = [{"name": s.name, "type": s.type} for s in rig.sensors]
        summary["sensors"] = [s.name for s in rig.sensors]
        summary["rig"] = rig.name
        summary["rig_file"] = str(inputs.rig)
        if inputs.humans:
            from nsim.io.coco import coco_from_mask_files, write_coco_json

            for s in rig.sensors:
                if isinstance(s, CameraSensor):
                    masks = sorted((out_dir / s.name / "mask").glob("*.png"))
                    write_coco_json(out_dir / s.name / "boxes.json",
                                    coco_from_mask_files(masks, [f"{s.name}/rgb/{m.name}" for m in masks]))
    (out_dir / "render.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    write_previews(out_dir, rig, frames, cfg)
    return summary


def _assemble_recording(out_dir: Path, inputs: Inputs, cfg: Config, frames: list[dict], streams: list[dict],
                        rows: list[dict], recording_dir: Path, ctx: RunContext) -> dict[str, Any]:
    """Recording mode's render.json (the contract in the module docstring) and previews."""
    recording = ctx.store.get(inputs.registration).manifest["inputs"]["recording"]
    per_stream = []
    fields = ("index", "stamp_ns", "odom_time_ns", "sensor_to_world", "people_time_s")
    for st in streams:
        mine = [f for f in frames if f["stream"] == st["key"]]
        per_stream.append({"name": st["name"], "kind": st["kind"], "color": st["color"],
                           "skipped_outside_trajectory": st["skipped_outside_trajectory"],
                           **({"people_outside_run": st["people_outside_run"]} if inputs.humans else {}),
                           "frames": [{k: f[k] for k in fields if k in f} for f in mine]})
    meta: dict[str, Any] = {
        "mode": "recording",
        "recording": recording,
        "registration": inputs.registration,
        "scene": inputs.scene,
        "streams": per_stream,
        "conventions": {
            "world": _world_units(ctx, inputs.scene),
            "time": "stamp_ns: the recorded header stamp; odom_time_ns: the same instant on the odometry clock "
                    "(stamp - clock_offset_s for the kinds in camera_clock_kinds), where the registration's "
                    "trajectory was interpolated",
            "sensor_to_world": "4 x 4, the sensor's frame (cameras: OpenCV axes; LiDAR: the recording's) in the world",
            "camera": "camera/<name>/NNNNNN.png, 8-bit sRGB, grey where the recording's stream is grey",
            "depth": "depth/<name>/NNNNNN.exr, float32 channel Z: z-depth in metres; inf = no return, NaN = invalid",
            "lidar": "lidar/<name>/NNNNNN.exr, one row of the recorded file's points in its order: X Y Z (sensor "
                     "frame, metres, NaN without a return), range (metres along the recorded point's direction; "
                     "inf = no return, NaN = the recorded point gives no direction)",
            "index": "NNNNNN and index: the recording's own frame index",
        },
        "per_frame": rows,
    }
    if inputs.humans:
        meta["people"] = _recording_people(out_dir, inputs, cfg, streams, ctx)
        meta["conventions"].update({
            "people_time_s": "the run's simulation time whose people a frame shows: run_start_s + (odom_time_ns - "
                             "first_odometry_ns) / 1e9 + people_time_offset_s (see people); outside the run: nobody",
            "mask": "mask/<name>/NNNNNN.png per camera stream, 16-bit instance mask: 0 background, k + 1 = the "
                    "trajectory's person k (its order in position_m)",
            "boxes": "boxes/<name>.json per camera stream, COCO person boxes of the masks (file_name: the rendered "
                     "camera/<name>/NNNNNN.png)"})
    (out_dir / "render.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    by_stream = {st["key"]: [f["index"] for f in frames if f["stream"] == st["key"]] for st in streams}
    n = max(len(v) for v in by_stream.values())
    picked = [{"row": r} for r in range(n)]
    write_previews(out_dir, None, picked, cfg,
                   strip=lambda row: _recording_strip(out_dir, recording_dir, streams, by_stream, row["row"]))
    summary = {"mode": "recording", "frames": len(frames), "humans": len(inputs.humans),
               "streams": {st["key"]: len(by_stream[st["key"]]) for st in streams},
               "skipped_outside_trajectory": sum(st["skipped_outside_trajectory"] for st in streams)}
    if inputs.humans:
        summary["people_outside_run"] = sum(st["people_outside_run"] for st in streams)
    return summary


def _recording_people(out_dir: Path, inputs: Inputs, cfg: Config, streams: list[dict], ctx: RunContext) -> dict[str, Any]:
    """Recording mode with people: each camera stream's COCO boxes (``boxes/<name>.json``, from its masks)
    and render.json's ``people`` entry (the trajectory, the humans, the time origin)."""
    from nsim.io.coco import coco_from_mask_files, write_coco_json

    (out_dir / "boxes").mkdir()
    for st in streams:
        if st["kind"] == "camera":
            masks = sorted((out_dir / "mask" / st["name"]).glob("*.png"))
            write_coco_json(out_dir / "boxes" / f"{st['name']}.json",
                            coco_from_mask_files(masks, [f"camera/{st['name']}/{m.name}" for m in masks]))
    clock = _people_clock(inputs, ctx, ctx.store.get(ctx.store.get(inputs.registration).manifest["inputs"]["recording"]))
    return {"trajectory": inputs.trajectory, "humans": list(inputs.humans),
            "people_time_offset_s": cfg.people_time_offset_s, **clock,
            "people_outside_run": sum(st["people_outside_run"] for st in streams),
            "rule": "people_time_s = run_start_s + (odom_time_ns - first_odometry_ns) / 1e9 + people_time_offset_s: "
                    "people_time_offset_s 0 puts the run's first tick at the recording's first odometry stamp, as "
                    "nsim capture robot-log records a run"}


def _recording_strip(out_dir: Path, recording_dir: Path, streams: list[dict], by_stream: dict[str, list[int]],
                     row: int, height: int = 160) -> np.ndarray:
    """Row ``row`` of the contact sheet: per camera stream its ``row``-th frame, recorded beside rendered;
    per LiDAR stream a view from above, the recorded points grey under the rendered ones; each labelled."""
    import cv2

    from nsim.io.exr import read_points_exr
    from nsim.io.images import read_image
    from nsim.io.labels import add_label

    def tile(path: Path) -> np.ndarray:
        im = read_image(path)
        if im.dtype == np.uint16:
            im = (im >> 8).astype(np.uint8)
        if im.ndim == 2:
            im = np.repeat(im[..., None], 3, -1)
        return cv2.resize(im, (max(1, round(im.shape[1] * height / im.shape[0])), height), interpolation=cv2.INTER_AREA)

    tiles = []
    for st in streams:
        if row >= len(by_stream[st["key"]]) or st["kind"] == "depth":
            continue
        index = by_stream[st["key"]][row]
        rel = f"{st['kind']}/{st['name']}/{index:06d}"
        if st["kind"] == "camera":
            pair = np.concatenate([tile(recording_dir / f"{rel}.png"), tile(out_dir / f"{rel}.png")], axis=1)
            tiles.append(add_label(pair, [f"{st['name']} #{index} recorded", "rendered"]))
        else:
            def xyz(path: Path) -> np.ndarray:
                p = read_points_exr(path)
                return np.stack([p[c].reshape(-1) for c in "XYZ"], -1)

            img = _bev_points(xyz(recording_dir / f"{rel}.exr"), colour=(110, 110, 110))
            img = _bev_points(xyz(out_dir / f"{rel}.exr"), img=img)
            tiles.append(add_label(cv2.resize(img, (height, height), interpolation=cv2.INTER_NEAREST),
                                   f"{st['name']} #{index} (recorded grey)"))
    return np.concatenate(tiles, axis=1) if tiles else add_label(np.zeros((height, height, 3), np.uint8), "no frame")


def _bev(scan_path: Path, size: int = 240, extent_m: float = 10.0) -> np.ndarray:
    from nsim.io.lidar_exr import read_lidar_exr

    scan = read_lidar_exr(scan_path)
    return _bev_points(scan.xyz_m[scan.hit], size=size, extent_m=extent_m)


def _bev_points(xyz: np.ndarray, img: np.ndarray | None = None, colour=None, size: int = 240,
                extent_m: float = 10.0) -> np.ndarray:
    """LiDAR points ``(N, 3)`` (sensor frame; non-finite rows dropped) from above, x up: coloured by height,
    or in one ``colour``, drawn over ``img`` (default: a dark square)."""
    if img is None:
        img = np.full((size, size, 3), 16, np.uint8)
    xyz = np.asarray(xyz)[np.isfinite(xyz).all(-1)]
    u = (size / 2 - xyz[:, 1] / extent_m * size / 2).astype(int)
    v = (size / 2 - xyz[:, 0] / extent_m * size / 2).astype(int)
    ok = (u >= 0) & (u < size) & (v >= 0) & (v < size)
    z = np.clip((xyz[ok, 2] + 1.0) / 3.0, 0, 1)
    img[v[ok], u[ok]] = (np.stack([255 * z, 255 * (1 - abs(z - 0.5) * 2), 255 * (1 - z)], -1).astype(np.uint8)
                         if colour is None else colour)
    img[size // 2 - 2 : size // 2 + 2, size // 2 - 2 : size // 2 + 2] = (255, 255, 255)
    return img


def _frame_strip(out_dir: Path, rig, index: int, time_s: float | None = None, height: int = 160) -> np.ndarray:
    """One row of the contact sheet: frame ``index``'s camera images and LiDAR views from above, each
    labelled with its sensor, the frame and (when known) its time."""
    import cv2

    from nsim.io.images import read_image
    from nsim.io.labels import add_label

    when = f" #{index}" + (f"  t {time_s:.2f} s" if time_s is not None else "")
    tiles = []
    names = [s.name for s in rig.sensors if s.type == "camera"] if rig is not None else ["frames"]
    for name in names:
        p = out_dir / name / "rgb" / f"{index:06d}.png"
        if p.is_file():
            im = read_image(p)
            if im.ndim == 2:
                im = np.repeat(im[..., None], 3, -1)
            tiles.append(add_label(cv2.resize(im, (max(1, round(im.shape[1] * height / im.shape[0])), height),
                                              interpolation=cv2.INTER_AREA), name + when))
    if rig is not None:
        for s in rig.sensors:
            p = out_dir / s.name / "scan" / f"{index:06d}.exr"
            if s.type == "lidar" and p.is_file():
                tiles.append(add_label(cv2.resize(_bev(p), (height, height), interpolation=cv2.INTER_NEAREST),
                                       s.name + when))
    return np.concatenate(tiles, axis=1) if tiles else add_label(np.zeros((height, height, 3), np.uint8), when)


def write_previews(out_dir: Path, rig, frames: list[dict], cfg: Config, strip=None) -> None:
    """The contact sheet (and video) of ``frames``; ``strip(frame) -> (H, W, 3) uint8`` draws one row
    (default: the rig's cameras and LiDAR BEVs at the frame's index)."""
    from nsim.io.images import write_image

    if strip is None:
        def strip(f: dict) -> np.ndarray:
            return _frame_strip(out_dir, rig, f["index"], f.get("time_s"))
    (out_dir / "preview").mkdir()
    picked = frames[:: cfg.preview_every][: cfg.preview_max_rows]
    strips = [strip(f) for f in picked]
    width = max(s.shape[1] for s in strips)
    sheet = np.concatenate([np.pad(s, ((0, 2), (0, width - s.shape[1]), (0, 0))) for s in strips], axis=0)
    write_image(out_dir / "preview" / "contact_sheet.png", sheet)
    if cfg.video and len(frames) > 1:
        import cv2

        from nsim.io.video import open_mp4

        first = strip(frames[0])
        h, w = first.shape[:2]
        with open_mp4(out_dir / "preview" / "preview.mp4", cfg.video_fps) as video:
            for f in frames:
                row = first if f is frames[0] else strip(f)
                if row.shape[:2] != (h, w):
                    row = cv2.resize(row, (w, h))
                video.write(row)


# ---------------------------------------------------------------------------------- ROS 2 bag export
def export_rosbag(art_dir: Path, bag_path: Path, storage: str = "sqlite3") -> Path:
    """Write a trajectory-mode render artifact as a ROS 2 bag (images, depth, camera info, point
    clouds, tf / tf_static, odometry) with ``rosbags``; the bag is written whole or not at all."""
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_image
    from nsim.io.lidar_exr import read_lidar_exr
    from nsim.io.rosbag import BagWriter
    from nsim.io.tum import read_tum
    from nsim.sensors.rig import Rig

    art_dir = Path(art_dir)
    meta = json.loads((art_dir / "render.json").read_text())
    if meta["mode"] != "trajectory":
        raise InputError(f"render {art_dir.name[:12]}: only trajectory renders (a robot's run) export to a ROS bag")
    rig = Rig.from_resolved(json.loads((art_dir / "rig.json").read_text()))
    robot = read_tum(art_dir / "robot.tum")
    poses = robot.poses_se3()
    with BagWriter(bag_path, rig, storage=storage) as bag:
        for f, pose in zip(meta["frames"], poses, strict=True):
            i = f["index"]
            images, depths, clouds = {}, {}, {}
            for s in rig.sensors:
                if s.type == "lidar":
                    clouds[s.name] = read_lidar_exr(art_dir / s.name / "scan" / f"{i:06d}.exr")
                    continue
                if (p := art_dir / s.name / "rgb" / f"{i:06d}.png").is_file():
                    images[s.name] = read_image(p)
                if (p := art_dir / s.name / "depth" / f"{i:06d}.exr").is_file():
                    depths[s.name] = read_depth_exr(p)
            bag.write_tick(float(f["time_s"]), pose, images=images, depths=depths, clouds=clouds)
    return Path(bag_path)
