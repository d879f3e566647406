"""What ``nsim render`` renders: the rig adapted to the config, the frames of each mode, the shards.

Each function reads the artifacts it needs through the workspace store and checks them before any
rendering (a bad input is one ``InputError`` line). Frames are plain dicts (JSON-able: they travel to
the shard renderers, ``nsim.rendering.shard``):

trajectory mode
    ``{index, time_s, body_to_world}`` per selected tick (``plan_frames``);
poses mode
    ``{index, time_s, name, cam_to_world, camera}`` per selected frame (``plan_frames``);
recording mode
    ``{stream, index, stamp_ns, odom_time_ns, body_to_world, sensor_to_world}`` (with people also
    ``people_time_s``) per kept frame of each stream, and the streams (``plan_recording``; the clocks
    and poses are ``nsim.rendering.recording``'s).

``inputs`` and ``cfg`` are the stage's resolved ``nsim.stages.render.Inputs`` and its ``Config``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import param
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.rendering.renderer import MarchConfig

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """``nsim render``'s settings (``nsim.stages.render.Config`` is this class; presets in ``configs/render/``)."""

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
    method: str = param("proposal", choices=("proposal", "march", "baked"),
                        help="march: constant steps with the occupancy grid and early termination; proposal: "
                             "the proposal sampler the model trained with (fewer samples, faster on CPU); baked: "
                             "the scene baked into a sparse voxel grid (nsim bake; --baked ID, else baked here)")
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


def adapt_rig(rig, cfg):
    """The rig's sensors named in ``cfg.sensors`` (empty: all), cameras scaled by ``cfg.image_scale``, LiDARs'
    azimuth samples by ``cfg.lidar_azimuth_scale``. ``cfg``: any config with these three fields (the
    render's, the robot log's)."""
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


def plan_frames(inputs, cfg, ctx: RunContext) -> list[dict[str, Any]]:
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


def plan_recording(inputs, cfg, ctx: RunContext) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
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
    people = people_clock(inputs, ctx, rec) if inputs.trajectory is not None else None
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


def people_clock(inputs, ctx: RunContext, rec) -> dict[str, Any]:
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


def shards_of(frames: list[dict], cfg) -> list[list[dict]]:
    return [frames[a : a + cfg.shard_frames] for a in range(0, len(frames), cfg.shard_frames)]


def shard_key(key: str, shard: list[dict]) -> str:
    first, last = shard[0]["index"], shard[-1]["index"]
    ids = [f["index"] if "stream" not in f else (f["stream"], f["index"]) for f in shard]  # recording: per stream
    digest = hashlib.sha256(f"{key}:{ids}".encode()).hexdigest()[:16]
    return f"shard_{first:06d}_{last:06d}_{digest}"


def scene_is_metric(ctx: RunContext, scene: str) -> bool:
    """False when the scene was trained on poses of arbitrary scale (its scene.json says ``metric: false``)."""
    doc = json.loads(ctx.store.get(scene).file("scene.json").read_text())
    return doc.get("extra", doc).get("metric", True) is not False


# ---------------------------------------------------------------------------------- the baked scene (method: baked)
def resolve_baked(ctx: RunContext, spec: str, scene: str) -> str:
    """The ``baked-scene`` artifact ``spec`` (``--baked``), checked: baked from the render's scene checkpoint."""
    store = ctx.store
    baked = store.resolve(spec)
    art = store.get(baked)
    if art.kind != "baked-scene":
        raise InputError(f"--baked {spec}: a {art.kind} artifact; render needs a baked-scene artifact (nsim bake)")
    made_from = art.manifest.get("inputs", {}).get("scene")
    if made_from != scene:
        raise InputError(f"--baked {spec}: baked from scene {str(made_from)[:12]}, the render's scene is {scene[:12]} "
                         f"(nsim bake {scene[:12]})")
    return baked


def check_method(inputs, cfg) -> None:
    """``--baked`` goes with ``method: baked`` only."""
    if inputs.baked is not None and cfg.method != "baked":
        raise InputError(f"--baked {inputs.baked[:12]}: renders from a baked scene need --set method=baked "
                         f"(method is {cfg.method})")


def baked_dir(inputs, cfg, ctx: RunContext, shard_root: Path) -> str | None:
    """Where the shards read the baked scene (``method: baked``; None otherwise): the ``--baked`` artifact,
    or one baked here with ``BakeConfig()``'s settings into ``shard_root/baked`` (written to a temp folder and
    renamed: a rerun after a crash reuses it)."""
    if cfg.method != "baked":
        return None
    if inputs.baked is not None:
        return str(ctx.store.get(inputs.baked).path)
    import os
    import shutil
    import uuid

    from nsim.rendering import OccupancyGrid, load_model
    from nsim.rendering.baked import BakeConfig, bake

    dest = shard_root / "baked"
    if not dest.is_dir():
        scene = ctx.store.get(inputs.scene)
        log.info("render: baking scene %s on demand (nsim bake + --baked to keep it)", scene.id[:12])
        model = load_model(scene.path, ctx.device)
        grid = OccupancyGrid.load(scene.file("occupancy_grid.npy"), ctx.device)
        tmp = shard_root / f".baked.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp"
        tmp.mkdir()
        try:
            bake(model, grid, BakeConfig()).save(tmp, extra={"scene_checkpoint": scene.id})
            os.rename(tmp, dest)
        except OSError:
            if not dest.is_dir():
                raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return str(dest)


def person_models(inputs, ctx) -> list[int] | None:
    """Per person of the trajectory, the index (into ``inputs.humans``) of the human checkpoint that draws it
    (``nsim.rendering.people.person_checkpoints``: the scenario's ``humans[k].appearance``, else k mod M); None
    without people. Checked before any work: a name that is unknown or not among ``--humans`` is one line."""
    if not inputs.humans or inputs.trajectory is None:
        return None
    from nsim.io.npz import read_npz
    from nsim.rendering.people import person_checkpoints

    store = ctx.store
    arrays = read_npz(store.get(inputs.trajectory).file("trajectory.npz"))
    n = int(np.asarray(arrays["height_m"]).shape[0])
    appearance = [str(a) for a in arrays["appearance"]] if "appearance" in arrays else [""] * n
    if len(appearance) != n:
        raise InputError(f"trajectory {inputs.trajectory[:12]}: trajectory.npz has {len(appearance)} appearance "
                         f"entries for {n} people")
    return person_checkpoints(appearance, inputs.humans, lambda name: store.find(name, kind="human-checkpoint"),
                              source=f"trajectory {inputs.trajectory[:12]}")


def shard_job(inputs, cfg, ctx, rig, streams, shards, shard_root, person_model=None) -> dict:
    """What every shard worker needs, as plain data (paths, the rig as a dict, the seed, the device):
    the render stage's resolved ``inputs`` and ``cfg``, the adapted ``rig`` (or None), the recording's
    ``streams`` (or None), the ``shards`` and the folder they are rendered into, and which checkpoint draws
    each person (``person_models``; None: k mod M)."""
    store = ctx.store
    recording_dir = None
    if inputs.registration:
        recording_dir = str(store.get(store.get(inputs.registration).manifest["inputs"]["recording"]).path)
    return {
        "workspace": str(store.root),
        "scene_dir": str(store.get(inputs.scene).path),
        "human_dirs": [str(store.get(h).path) for h in inputs.humans],
        "person_model": person_model,
        "trajectory_file": str(store.get(inputs.trajectory).file("trajectory.npz")) if inputs.trajectory else None,
        "rig": rig.to_dict() if rig is not None else None,
        "recording_dir": recording_dir,
        "streams": streams,
        "seed": ctx.seed,
        "device": str(ctx.device),
        "shards": shards,
        "baked_dir": baked_dir(inputs, cfg, ctx, shard_root),
    }


def load_rig(inputs, cfg):
    """The rig of trajectory mode (scaled and filtered by the config: ``adapt_rig``), or None in the other modes."""
    if inputs.rig is None or inputs.trajectory is None:
        return None
    from nsim.sensors.rig import Rig

    return adapt_rig(Rig.load(inputs.rig), cfg)
