"""What ``nsim render`` renders: the rig adapted to the config, the frames of each mode, the shards.

Each function reads the input artifacts it needs from their folders (``RenderSources``, resolved from
the workspace by the stage, ``nsim.stages.render``) and checks them before any rendering (a bad input
is one ``InputError`` line). The frames, the recorded streams and the shard job are the dataclasses of
``nsim.rendering.render_job`` (plain, picklable data: they travel to the shard renderers,
``nsim.rendering.shard``):

trajectory mode
    a ``TickFrame`` per selected tick (``plan_frames``);
poses mode
    a ``PoseFrame`` per selected frame (``plan_frames``);
recording mode
    a ``RecordedFrame`` per kept frame of each stream, the ``RecordedStream``s and, with people, their
    ``PeopleClock`` (``plan_recording``; the clocks and poses are ``nsim.rendering.recording``'s).

``cfg`` is the render's ``RenderConfig`` (the stage's ``Config``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.config import param
from nsim.errors import InputError
from nsim.rendering.march_config import MarchConfig
from nsim.rendering.render_job import (
    ArtifactDir,
    Frame,
    PeopleClock,
    PoseFrame,
    RecordedFrame,
    RecordedStream,
    RecordingPlan,
    RenderSources,
    ShardJob,
    TickFrame,
)

if TYPE_CHECKING:
    from nsim.geometry.cameras import Camera
    from nsim.sensors.rig import Rig

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """``nsim render``'s settings (``nsim.stages.render.Config`` is this class; presets in ``nsim/configs/render/``)."""

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


def scaled_camera(camera: Camera, image_scale: float, what: str) -> Camera:
    """``camera.scaled(image_scale)``; InputError naming ``what`` when the scale leaves no pixel."""
    try:
        return camera.scaled(image_scale)
    except ValueError:
        raise InputError(f"image_scale: {image_scale:g} shrinks {what}'s {camera.width}x{camera.height} image to "
                         "nothing") from None


def adapt_rig(rig: Rig, cfg) -> Rig:
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
            s = dataclasses.replace(s, camera=scaled_camera(s.camera, cfg.image_scale, f"camera {s.name!r}"))
        if isinstance(s, LidarSensor) and cfg.lidar_azimuth_scale != 1.0:
            a = max(1, round(s.config.azimuth_samples * cfg.lidar_azimuth_scale))
            s = dataclasses.replace(s, config=dataclasses.replace(s.config, azimuth_samples=a))
        sensors.append(s)
    return dataclasses.replace(rig, sensors=tuple(sensors))


def plan_frames(sources: RenderSources, cfg: RenderConfig) -> list[TickFrame] | list[PoseFrame]:
    """The frames to render: a ``TickFrame`` per selected tick of ``sources.trajectory`` (trajectory mode),
    else a ``PoseFrame`` per selected frame of ``sources.poses`` (all, or the scene's held-out ones)."""
    frames: list
    if sources.trajectory is not None:
        from nsim.io.npz import read_npz

        traj = sources.trajectory
        arrays = read_npz(traj.file("trajectory.npz"), required=("robot_pose_se3", "time_s"))
        poses = arrays["robot_pose_se3"]
        times = arrays["time_s"]
        if not np.isfinite(poses).all():
            raise InputError(f"trajectory {traj.id[:12]}: robot poses contain NaN/inf")
        idx = range(cfg.start, len(times), cfg.tick_stride)
        frames = [TickFrame(index=int(i), time_s=float(times[i]), body_to_world=poses[i]) for i in idx]
    else:
        from nsim.io.transforms_json import read_transforms

        data = read_transforms(sources.poses.file("transforms.json"))
        ids = range(len(data.frames))
        if cfg.frames == "heldout":
            scene_json = json.loads(sources.scene.file("scene.json").read_text())
            held = scene_json.get("extra", scene_json).get("eval_images")
            if held is None:
                raise InputError(f"scene {sources.scene.id[:12]}: scene.json lists no held-out images")
            ids = held
        idx = [i for i in ids if i >= cfg.start][:: cfg.tick_stride]
        frames = []
        for i in idx:
            f = data.frames[i]
            cam = scaled_camera(f.camera, cfg.image_scale, f"frame {i}") if cfg.image_scale != 1.0 else f.camera
            frames.append(PoseFrame(index=int(i), time_s=f.timestamp_s, name=Path(f.file_path).name,
                                    cam_to_world=f.cam_to_world, camera=cam))
    if cfg.max_frames is not None:
        frames = frames[: cfg.max_frames]
    if not frames:
        raise InputError("render: no frames selected (check start / tick_stride / max_frames)")
    return frames


def plan_recording(sources: RenderSources, cfg: RenderConfig) -> RecordingPlan:
    """Recording mode: the frames to render of ``sources.recording`` (stream by stream, posed by
    ``sources.registration``), the streams and, with people (``sources.trajectory``), their clock.
    Every check before any rendering."""
    import cv2

    from nsim.rendering import recording as core

    if bad := [k for k in cfg.camera_clock_kinds if k not in core.KINDS]:
        raise InputError(f"camera_clock_kinds: {', '.join(map(repr, bad))} is not a stream kind "
                         f"({', '.join(core.KINDS)})")
    reg, rec = sources.registration, sources.recording
    registered = core.read_registration(reg.path, reg.id[:12])
    reg_doc, offset_s = registered.doc, registered.clock_offset_s
    if abs(float(reg_doc.get("scale", 1.0)) - 1.0) > 0.01:
        log.warning("render --recording: registration %s has scale %g: the sensors' mounts stay in metres",
                    reg.id[:12], reg_doc["scale"])
    doc = json.loads(rec.file("recording.json").read_text())
    try:
        keys = core.select_streams(list(doc["streams"]), cfg.sensors)
    except ValueError as e:
        raise InputError(f"sensors: recording {rec.id[:12]} has no stream {e} (it has: "
                         f"{', '.join(doc['streams'])})") from None
    # a recording renders at its recorded sizes and points, so that sim and real frames pair one to one; a scale
    # only matters for the streams it scales (a preset's LiDAR scale is no reason to refuse a camera-only recording)
    kinds = {k.split("/", 1)[0] for k in keys}
    scales = [(n, v) for n, v, kind in (("image_scale", cfg.image_scale, ("camera", "depth")),
                                        ("lidar_azimuth_scale", cfg.lidar_azimuth_scale, ("lidar",)))
              if v != 1.0 and kinds & set(kind)]
    if scales:
        raise InputError("render --recording: " + ", ".join(f"{n} {v:g}" for n, v in scales) + ": a recording renders "
                         "at its recorded sizes and points, so that sim and real frames pair one to one; set "
                         + (" and ".join(n for n, _ in scales)) + " to 1")
    people = people_clock(sources.trajectory, rec) if sources.trajectory is not None else None
    frames: list[RecordedFrame] = []
    streams: list[RecordedStream] = []
    for key in keys:
        entry = doc["streams"][key]
        kind, name = key.split("/", 1)
        if (kind not in core.KINDS or entry.get("dir") != key or name in ("", ".", "..")
                or any(c in name for c in "/\\\x00")):  # a plain folder name inside the recording
            raise InputError(f"recording {rec.id[:12]}: recording.json: stream {key!r} is not <kind>/<name> "
                             f"(kinds: {', '.join(core.KINDS)}) kept in its own folder")
        stamps = np.load(rec.file(f"{key}/stamps_ns.npy"), allow_pickle=False)
        indices = np.asarray(entry["frames"], dtype=np.int64)
        if stamps.shape != indices.shape:
            raise InputError(f"recording {rec.id[:12]}: {key}: {len(stamps)} stamps for {len(indices)} frames")
        pick = core.select_frames(indices, cfg.start, cfg.tick_stride)
        mount = np.asarray(entry["sensor_to_body"], dtype=np.float64)
        odom = core.odometry_time_ns(stamps[pick], offset_s, kind in cfg.camera_clock_kinds)
        inside, body, sensor = registered.sensor_poses(odom, mount)
        kept = [(p, int(t), b, w) for p, t, b, w, ok in zip(pick, odom, body, sensor, inside, strict=True) if ok]
        kept = kept[: cfg.max_frames]
        people_t: list[float | None] = [None] * len(kept)
        outside_run = None
        if people is not None:
            t = core.people_time_s(np.array([o for _, o, _, _ in kept], dtype=np.int64), people.first_odometry_ns,
                                   people.run_start_s, cfg.people_time_offset_s)
            people_t = [float(ti) for ti in t]
            outside_run = int(((t < people.run_start_s) | (t > people.run_end_s)).sum())
        frames += [RecordedFrame(stream=key, index=int(indices[p]), stamp_ns=int(stamps[p]), odom_time_ns=o,
                                 body_to_world=b, sensor_to_world=w, people_time_s=pt)
                   for (p, o, b, w), pt in zip(kept, people_t, strict=True)]
        color = "rgb"
        if kind == "camera" and len(indices):
            first = cv2.imread(str(rec.file(f"{key}/{indices[0]:06d}.png")), cv2.IMREAD_UNCHANGED)
            if first is None:
                raise InputError(f"recording {rec.id[:12]}: {key}/{indices[0]:06d}.png is not a readable image")
            color = "gray" if first.ndim == 2 else "rgb"
        if kind != "lidar" and entry.get("camera") is None:
            raise InputError(f"recording {rec.id[:12]}: {key} has no camera model")
        skipped = int((~inside).sum())
        streams.append(RecordedStream(key=key, kind=kind, name=name, sensor_to_body=mount,
                                      camera=None if kind == "lidar" else _recorded_camera(entry["camera"], rec, key),
                                      color=color, skipped_outside_trajectory=skipped, people_outside_run=outside_run))
        if skipped:
            log.warning("render --recording: %s: %d of %d frames lie outside the registered trajectory; skipped",
                        key, skipped, len(pick))
    if not frames:
        raise InputError(f"render --recording: no frames selected in {', '.join(keys)} (check start / tick_stride / "
                         "max_frames, and that the frames lie inside the registered trajectory)")
    if people is not None:
        outside = sum(st.people_outside_run for st in streams)
        if outside == len(frames):
            seen = [f.people_time_s for f in frames]
            raise InputError(f"--trajectory {sources.trajectory.id[:12]}: its run spans simulation time "
                             f"[{people.run_start_s:g}, {people.run_end_s:g}] s, the recording's frames see "
                             f"[{min(seen):g}, {max(seen):g}] s (people_time_offset_s {cfg.people_time_offset_s:g}): "
                             "no frame overlaps the run, nobody would be drawn")
        if outside:
            log.warning("render --recording: %d of %d frames lie outside the run's time span; drawn without people",
                        outside, len(frames))
    return RecordingPlan(frames=tuple(frames), streams=tuple(streams), people=people)


def _recorded_camera(camera: dict, rec: ArtifactDir, key: str) -> Camera:
    """A camera or depth stream's camera model as recording.json holds it, checked."""
    from nsim.geometry.cameras import Camera

    try:
        return Camera.from_dict(camera)
    except ValueError as e:
        raise InputError(f"recording {rec.id[:12]}: recording.json: {key}: {e}") from None


def people_clock(trajectory: ArtifactDir, recording: ArtifactDir) -> PeopleClock:
    """Recording mode with people: the run's time span and the recording's first odometry stamp, the two ends
    of ``nsim.rendering.recording.people_time_s``; the trajectory's people arrays checked."""
    from nsim.io.npz import read_npz

    path = trajectory.file("trajectory.npz")
    a = read_npz(path, required=("time_s", "position_m", "heading_rad", "gait_phase", "height_m"))
    t, pos = a["time_s"], a["position_m"]
    n = pos.shape[1] if pos.ndim == 3 else -1
    if (t.ndim != 1 or len(t) < 1 or not np.isfinite(t).all() or np.any(np.diff(t) <= 0) or pos.shape != (len(t), n, 2)
            or a["heading_rad"].shape != (len(t), n) or a["gait_phase"].shape != (len(t), n)
            or a["height_m"].shape != (n,)):
        raise InputError(f"{path}: time_s (T,) increasing, position_m (T, P, 2), heading_rad and gait_phase (T, P), "
                         "height_m (P,) expected")
    if n == 0:
        raise InputError(f"--trajectory {trajectory.id[:12]}: its run has no people to draw")
    odom_ns = np.load(recording.file("trajectory_ns.npy"), allow_pickle=False)
    if odom_ns.ndim != 1 or len(odom_ns) < 1:
        raise InputError(f"recording {recording.id[:12]}: trajectory_ns.npy holds no odometry stamp")
    return PeopleClock(run_start_s=float(t[0]), run_end_s=float(t[-1]), first_odometry_ns=int(odom_ns[0]))


def shards_of(frames: Sequence[Frame], cfg: RenderConfig) -> tuple[tuple[Frame, ...], ...]:
    """The frames cut into shards of ``cfg.shard_frames``."""
    return tuple(tuple(frames[a : a + cfg.shard_frames]) for a in range(0, len(frames), cfg.shard_frames))


def shard_key(key: str, shard: Sequence[Frame]) -> str:
    """The shard's folder name: its first and last index and a digest of the run's key and its frames."""
    first, last = shard[0].index, shard[-1].index
    ids = [(f.stream, f.index) if isinstance(f, RecordedFrame) else f.index for f in shard]  # recording: per stream
    digest = hashlib.sha256(f"{key}:{ids}".encode()).hexdigest()[:16]
    return f"shard_{first:06d}_{last:06d}_{digest}"


def scene_is_metric(scene_json: Path) -> bool:
    """False when the scene was trained on poses of arbitrary scale (its ``scene.json`` says ``metric: false``)."""
    doc = json.loads(scene_json.read_text())
    return doc.get("extra", doc).get("metric", True) is not False


def bake_here(scene: ArtifactDir, device: str, shard_root: Path) -> Path:
    """``method: baked`` without ``--baked``: the scene baked with ``BakeConfig()``'s settings into
    ``shard_root/baked`` (written to a temp folder and renamed: a rerun after a crash reuses it)."""
    import os
    import shutil
    import uuid

    from nsim.rendering import OccupancyGrid, load_model
    from nsim.rendering.bake_bricks import bake
    from nsim.rendering.bake_config import BakeConfig

    dest = shard_root / "baked"
    if not dest.is_dir():
        log.info("render: baking scene %s on demand (nsim bake + --baked to keep it)", scene.id[:12])
        model = load_model(scene.path, device)
        grid = OccupancyGrid.load(scene.file("occupancy_grid.npy"), device)
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
    return dest


def run_appearances(trajectory: ArtifactDir) -> list[str]:
    """Per person of the trajectory, the scenario's ``humans[k].appearance`` (``""``: none named)."""
    from nsim.io.npz import read_npz

    arrays = read_npz(trajectory.file("trajectory.npz"))
    n = int(np.asarray(arrays["height_m"]).shape[0])
    appearance = [str(a) for a in arrays["appearance"]] if "appearance" in arrays else [""] * n
    if len(appearance) != n:
        raise InputError(f"trajectory {trajectory.id[:12]}: trajectory.npz has {len(appearance)} appearance "
                         f"entries for {n} people")
    return appearance


def person_models(trajectory: ArtifactDir, human_ids: Sequence[str], find: Callable[[str], str | None]) -> list[int]:
    """Per person of the trajectory, the index (into ``human_ids``, the render's ``--humans``) of the human
    checkpoint that draws it (``nsim.rendering.people.person_checkpoints``: the scenario's
    ``humans[k].appearance``, else k mod M; ``find``: a name -> its human-checkpoint id or None, ``Store.find``).
    Checked before any work: a name that is unknown or not among ``human_ids`` is one line."""
    from nsim.rendering.people import person_checkpoints

    return person_checkpoints(run_appearances(trajectory), human_ids, find, source=f"trajectory {trajectory.id[:12]}")


def scenario_people(trajectory: ArtifactDir, find: Callable[[str], str | None]
                    ) -> tuple[tuple[str, ...], list[int], list[str]]:
    """Who draws each person of the trajectory when the render gives no ``--humans``: the human checkpoint its
    scenario's ``humans[k].appearance`` names (``find``: a name -> its human-checkpoint id or None,
    ``Store.find``), else the default look (``nsim.rendering.default_look``).

    Returns the checkpoints named (ids, in order of first use), per person an index into them or
    ``DEFAULT_LOOK``, and labels of the people drawn with the default look (``humans[k]``, with the name the
    workspace does not hold). An ambiguous or dangling name is one ``InputError`` line, before any work."""
    from nsim.errors import NsimError
    from nsim.rendering.default_look import DEFAULT_LOOK

    source = f"trajectory {trajectory.id[:12]}"
    ids: list[str] = []
    person_model, defaulted = [], []
    for k, name in enumerate(run_appearances(trajectory)):
        try:
            hid = find(name) if name else None
        except NsimError as err:  # ambiguous, a ref to a missing artifact, another kind
            raise InputError(f"{source}: humans[{k}].appearance {name!r}: {err}") from None
        if hid is None:
            person_model.append(DEFAULT_LOOK)
            defaulted.append(f"humans[{k}] {name!r} (not in this workspace)" if name else f"humans[{k}]")
            continue
        if hid not in ids:
            ids.append(hid)
        person_model.append(ids.index(hid))
    return tuple(ids), person_model, defaulted


def run_people(trajectory: ArtifactDir, humans: Sequence[str], find: Callable[[str], str | None]
               ) -> tuple[tuple[str, ...], list[int], list[str]]:
    """Who draws each person of the trajectory: ``humans`` (``--humans``, ``person_models``) when given, else the
    scenario's appearances and the default look (``scenario_people``, said in one warning line). Returns the
    human checkpoints (ids), per person an index into them or ``DEFAULT_LOOK``, the default-look labels."""
    if humans:
        return tuple(humans), person_models(trajectory, humans, find), []
    from nsim.rendering.default_look import DEFAULT_LOOK_SEED

    ids, people, defaulted = scenario_people(trajectory, find)
    if defaulted:
        log.warning("render: %d of %d people drawn with the default look (the test-room mannequin, seed %d): %s; "
                    "a scenario's humans[k].appearance or --humans names a human checkpoint",
                    len(defaulted), len(people), DEFAULT_LOOK_SEED, ", ".join(defaulted))
    return ids, people, defaulted


def people_differ_from_default(person_model: Sequence[int] | None, n_humans: int) -> bool:
    """Whether ``person_model`` (``run_people``) draws someone otherwise than checkpoint k mod M would (then the
    render's key records it: the scenario's names resolved, the default look)."""
    from nsim.rendering.people import default_checkpoint

    return person_model is not None and list(person_model) != [default_checkpoint(k, max(1, n_humans))
                                                               for k in range(len(person_model))]


def people_summary(humans: Sequence[str], people: Sequence[int] | None, defaulted: Sequence[str], source: str) -> dict:
    """What ``render.json``'s summary says of a trajectory's people: who drew each (``run_people``) and from where
    (``people_from``: ``humans``, the render's ``--humans``; ``scenario``, its appearances and the default look;
    ``none``, ``--no-people``): a rebuild draws them alike."""
    from nsim.rendering.default_look import DEFAULT_LOOK, DEFAULT_LOOK_NAME, DEFAULT_LOOK_SEED

    out: dict[str, Any] = {"people_from": source}
    if people is not None:
        out["people_checkpoints"] = [humans[m] if m != DEFAULT_LOOK else DEFAULT_LOOK_NAME for m in people]
    if defaulted:
        out["default_look"] = {"seed": DEFAULT_LOOK_SEED, "people": list(defaulted)}
    return out


def shard_job(sources: RenderSources, rig: Rig | None, recording: RecordingPlan | None, shards: tuple[tuple[Frame, ...], ...],
              seed: int, device: str, baked_dir: Path | None, person_model: Sequence[int] | None) -> ShardJob:
    """What every shard worker needs: the ``shards`` of frames, the inputs' folders, the adapted ``rig`` (or
    None) as its ``rig.json`` reads back (``Rig.from_resolved``: the workers render what the artifact records),
    the ``recording``'s streams (or None), the run's ``seed`` and torch ``device``, the baked scene's folder
    (``method: baked``) and which checkpoint draws each person (``person_models`` or ``scenario_people``, where
    ``DEFAULT_LOOK`` is the default look; None: k mod M)."""
    from nsim.sensors.rig import Rig

    return ShardJob(
        scene_dir=sources.scene.path,
        human_dirs=tuple(h.path for h in sources.humans),
        person_model=None if person_model is None else tuple(int(m) for m in person_model),
        trajectory_npz=sources.trajectory.file("trajectory.npz") if sources.trajectory is not None else None,
        rig=None if rig is None else Rig.from_resolved(rig.to_dict()),
        recording_dir=sources.recording.path if sources.recording is not None else None,
        streams=recording.streams if recording is not None else None,
        seed=seed,
        device=device,
        shards=shards,
        baked_dir=baked_dir,
    )
