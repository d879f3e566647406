"""``nsim capture synth``: a handheld capture of the test room with exact ground truth.

The capture artifact holds what a user's phone video would give, plus everything a real
capture cannot: exact poses, depth and the room itself (so evaluation can render the
ground truth for any sensor at any pose through :class:`nsim.synth.oracle.RoomOracle`).

Artifact layout::

    transforms.json          nerfstudio convention (OpenGL camera axes), metric GT poses,
                             intrinsics, per-frame depth_file_path and timestamp
    images/frame_00000.png   RGB, 8-bit sRGB-ish (the room's baked shading, no tone curve);
                             .jpg with ``phone.jpeg_quality``
    depth/frame_00000.exr    float32 channel Z: z-depth in metres along the camera's +z axis
                             (NaN where undefined: fisheye pixels beyond 90 degrees)
    video.mp4                the frames as a video (H.264, ``nsim.io.video``), what `nsim reconstruct` reads
    gt_trajectory.tum        camera-to-world poses, TUM format (a metric `--reference`)
    room.json                the room specification (rebuilds the oracle)
    occupancy.json           2D obstacle polygons (walls + furniture footprints), metres
    preview.png              contact sheet (frames labelled with index and time) beside a top-down
                             view of the path over the room

With ``actor: true`` (``nsim capture synth --actor``) a person walks through the room and the
handheld camera follows it instead (``nsim.synth.actor_capture``; ``low_pass_height_m`` unused);
the artifact also holds ``masks/`` (person mask, 0/255), ``background/`` (the views without the
person) and ``poses.json`` (per-frame skeleton poses, docs/human_data.md); its depth includes the person.

``phone`` (``nsim.synth.phone.PhoneConfig``; ``--preset phone`` turns it all on) makes the images
look like a phone's: auto-exposure and white-balance drift, shot and read noise, motion blur,
rolling shutter, vignetting, JPEG. Poses, trajectory and depth stay the exact ground truth of the
camera at each frame's timestamp (mid-exposure of row 0), byte for byte those of the same capture
without ``phone``; each frame in transforms.json also records its ``exposure_gain`` and
``wb_gains_rgb``, and the top level the model (``nsim_phone``). While every phone setting is at its
default, ``phone`` is left out of the action key and the manifest, so such captures keep the ids
they had before the phone model existed.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import param, to_dict
from nsim.context import RunContext
from nsim.io.canonical import round_decimals
from nsim.stages.runner import cached, rerun
from nsim.synth.faulty_robot_log import RobotLogFaults
from nsim.synth.phone import PhoneConfig
from nsim.synth.room import ROOM_PRESETS

STAGE = "capture"
VERSION = 4  # 2: video.mp4 in H.264 (was MPEG-4 Part 2); preview.png with labelled frames
# 3: poses, trajectories and metrics written rounded (nsim.io.canonical: the same bytes on any CPU)
# 4: video.mp4's YUV conversion bit-exact (nsim.io.video.SWS_FLAGS: the same bytes on any CPU)
CAMERAS = ("pinhole", "fisheye")


@dataclasses.dataclass(frozen=True)
class Config:
    room: str = param("robot-lab", choices=ROOM_PRESETS, help="room preset")
    room_seed: int = param(0, ge=0, help="seed of the room layout (the path uses the run's --seed)")
    camera: str = param("pinhole", choices=CAMERAS)
    width: int = param(320, ge=16, le=4096)
    height: int = param(240, ge=16, le=4096)
    hfov_deg: float = param(75.0, gt=10.0, lt=170.0, help="pinhole horizontal field of view")
    n_frames: int = param(150, ge=3, le=100_000)
    fps: float = param(10.0, gt=0.0, le=240.0)
    supersample: int = param(2, ge=1, le=8, help="sub-pixel rays per axis for anti-aliasing")
    video: bool = True
    low_pass_height_m: float | None = param(
        0.6, ge=0.55, le=1.5,
        help="camera height of the second, low loop (Spot's body cameras: 0.5-0.7 m); null: both loops at eye height")
    actor: bool = param(False, help="a person walks through the room, filmed by a camera that follows it "
                                    "(adds masks/ and poses.json: training data for train-human)")
    actor_height_m: float = param(1.75, ge=0.5, le=2.5, help="the person's height (actor: true)")
    actor_speed_mps: float = param(1.2, ge=0.3, le=2.5, help="the person's walking speed (actor: true)")
    actor_view_deg: float | None = param(
        None, ge=-360.0, le=360.0,
        help="actor: true: the camera keeps this side of the person, an angle about it from its heading (0: in "
             "front, the person walks towards the camera; 90: its left; 180: behind, a camera that follows the "
             "walker); null: the camera orbits the person (front, sides and back all filmed)")
    phone: PhoneConfig = PhoneConfig()

    def __post_init__(self) -> None:
        frame_s = 1.0 / self.fps
        for name in ("exposure_time_s", "readout_time_s"):
            if getattr(self.phone, name) > frame_s:
                raise ValueError(f"phone.{name}: expected <= 1 / fps = {frame_s:g} s, got {getattr(self.phone, name)}")
        if self.actor_view_deg is not None and not self.actor:
            raise ValueError("actor_view_deg: needs actor: true (it places the camera about the person)")
        if self.actor and self.phone != PhoneConfig():
            raise ValueError("phone: not supported with actor: true (leave every phone setting at its default)")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """The test room has no input artifacts."""

    def ids(self) -> dict[str, str]:
        return {}


@dataclasses.dataclass(frozen=True)
class Outputs:
    capture: str
    cache_hit: bool = False


def make_camera(cfg: Config):
    from nsim.geometry.cameras import Camera

    if cfg.camera == "pinhole":
        return Camera.pinhole_from_fov(cfg.width, cfg.height, cfg.hfov_deg)
    return Camera.fisheye_spot_like(cfg.width, cfg.height)


def path_config(cfg: Config):
    """The handheld path: eye-height loop, then a low loop at ``cfg.low_pass_height_m`` (or a second eye-height one)."""
    from nsim.synth.path import DEFAULT_PATH

    if cfg.low_pass_height_m is None:
        return dataclasses.replace(DEFAULT_PATH, low_height_m=DEFAULT_PATH.eye_height_m,
                                   low_pitch_down_deg=DEFAULT_PATH.eye_pitch_down_deg)
    return dataclasses.replace(DEFAULT_PATH, low_height_m=cfg.low_pass_height_m)


def actor_config(cfg: Config):
    """The ``ActorCaptureConfig`` of a capture with a person (``cfg.actor``)."""
    from nsim.synth.actor_capture import ActorCaptureConfig

    return ActorCaptureConfig(
        room=cfg.room, room_seed=cfg.room_seed, camera=cfg.camera, width=cfg.width, height=cfg.height,
        hfov_deg=cfg.hfov_deg, n_frames=cfg.n_frames, fps=cfg.fps, supersample=cfg.supersample, video=cfg.video,
        actor_height_m=cfg.actor_height_m, actor_speed_mps=cfg.actor_speed_mps,
        **({} if cfg.actor_view_deg is None else {"view_deg": cfg.actor_view_deg, "orbit_deg_s": 0.0}),
    )


def recorded_config(cfg: Config) -> dict[str, Any]:
    """``cfg`` as the action key and the manifest record it: without ``phone`` while it is all defaults."""
    data = to_dict(cfg)
    if cfg.phone == PhoneConfig():
        del data["phone"]
    if cfg.actor_view_deg is None:  # a field added later: at its default the key is what it was
        del data["actor_view_deg"]
    return data


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    store = ctx.store
    record = recorded_config(cfg)
    key = store.action_key(STAGE, VERSION, record, inputs.ids(), seed=ctx.seed)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(capture=hit, cache_hit=True)
    if cfg.actor:
        from nsim.synth.actor_capture import render_actor_capture

        with store.publish(kind="capture", stage=STAGE, version=VERSION, key=key, config=record, seed=ctx.seed) as out:
            result = render_actor_capture(out.dir, actor_config(cfg), seed=ctx.seed, show_progress=ctx.show_progress)
            out.summary.update({"room": cfg.room, "camera": cfg.camera, "frames": cfg.n_frames,
                                "resolution": [cfg.width, cfg.height], "actor": True,
                                "frames_with_person": int((result.mask_fraction > 0).sum())})
        return Outputs(capture=out.ref)

    from nsim.synth.oracle import RoomOracle
    from nsim.synth.path import handheld_path, handheld_path_at, timestamps_s
    from nsim.synth.room import make_room

    spec = make_room(cfg.room, cfg.room_seed)
    camera = make_camera(cfg)
    # (N, 4, 4) OpenCV axes, rounded to 1e-9 before anything is rendered from them: the frames, depth and the
    # transforms.json written (nsim.io.canonical) all hold the same poses, whatever the CPU's last bits
    cam_to_world = round_decimals(handheld_path(spec, cfg.n_frames, seed=ctx.seed, cfg=path_config(cfg)))
    times_s = timestamps_s(cfg.n_frames, cfg.fps)
    oracle = RoomOracle(spec)
    plan = None
    if cfg.phone.any_effect:
        from nsim.synth.phone import plan_frames

        def pose_at(t_s: np.ndarray) -> np.ndarray:  # the path between frames: frame k at fraction k / n
            return handheld_path_at(spec, t_s * cfg.fps / cfg.n_frames, seed=ctx.seed, cfg=path_config(cfg))

        plan = plan_frames(cfg.phone, camera, times_s, cfg.fps, ctx.seed, pose_at)

    with store.publish(kind="capture", stage=STAGE, version=VERSION, key=key, config=record, seed=ctx.seed) as out:
        from nsim.synth.capture_output import write_capture

        write_capture(out.dir, cfg, spec, camera, cam_to_world, times_s, oracle, ctx.show_progress, plan, ctx.seed,
                      STAGE)
        out.summary.update(
            {
                "room": cfg.room,
                "camera": cfg.camera,
                "frames": cfg.n_frames,
                "resolution": [cfg.width, cfg.height],
            }
        )
    return Outputs(capture=out.ref)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    return rerun(run, Inputs(), Config, manifest, ctx).capture


# ---------------------------------------------------------------------------------- a robot's log
@dataclasses.dataclass(frozen=True)
class RobotLogConfig:
    """``nsim capture robot-log``: the rig's sensors along a simulated run, with real-world faults."""

    faults: RobotLogFaults = RobotLogFaults()
    storage: str = param("sqlite3", choices=("sqlite3", "mcap", "ros1"), help="ROS 2 sqlite3 / mcap, or a ROS 1 .bag")
    sensors: tuple[str, ...] = param((), help="the rig's sensors to record (empty: all)")
    image_scale: float = param(1.0, gt=0.0, le=4.0, help="scale every camera's resolution (intrinsics follow)")
    lidar_azimuth_scale: float = param(1.0, gt=0.0, le=4.0, help="scale every LiDAR's azimuth samples")
    tick_stride: int = param(1, ge=1, help="record every k-th tick of the run")
    max_ticks: int = param(0, ge=0, help="then at most this many ticks (0: all)")
    supersample: int = param(1, ge=1, le=4, help="oracle supersampling per pixel side")
    start_time_s: float = param(1.7e9, ge=1.0, help="the log's clock at the run's first tick (seconds since the "
                                                    "epoch, as a robot's clock reads; ROS treats stamp 0 as unset)")


def robot_log(trajectory: str, rig_path: Path, out: Path, cfg: RobotLogConfig, ctx: RunContext) -> dict[str, Any]:
    """Write the realistic robot log of a simulated run (``nsim.synth.faulty_robot_log.write_robot_log``).

    trajectory: a trajectory artifact (``nsim simulate``) whose scenario's scene is a test room
    (``scene: {room, room_seed}``); the robot's true path is its ``robot.tum``. The bag (and its
    ``<bag>.truth.json``) goes to ``out``, outside the workspace, which must not exist yet. Returns the
    truth. Checked before any rendering: the trajectory, the room, the rig, the destination.
    """
    from nsim.errors import InputError
    from nsim.io.rosbag import check_bag_destination
    from nsim.io.tum import read_tum
    from nsim.rendering.render_plan import adapt_rig
    from nsim.sensors.rig import Rig
    from nsim.synth.faulty_robot_log import write_robot_log
    from nsim.synth.room import make_room

    store = ctx.store
    art = store.get(store.resolve(trajectory, kind="trajectory"))
    scene = json.loads(art.file("scenario.json").read_text()).get("scene", {})
    if "room" not in scene:
        raise InputError(f"trajectory {art.id[:12]}: its scenario's scene is not a test room ({sorted(scene)}); a "
                         "robot log needs the room's oracle")
    if cfg.storage == "ros1" and out.suffix != ".bag":
        raise InputError(f"--out {out}: a ROS 1 bag is one file named *.bag")
    check_bag_destination(out, "--out")
    rig = adapt_rig(Rig.load(rig_path), cfg)
    robot = read_tum(art.file("robot.tum"))
    idx = np.arange(0, len(robot), cfg.tick_stride)
    if cfg.max_ticks:
        idx = idx[: cfg.max_ticks]
    body = robot.poses_se3()[idx]
    stamps = robot.timestamps_s[idx] - robot.timestamps_s[0] + cfg.start_time_s
    spec = make_room(scene["room"], int(scene.get("room_seed", 0)))
    return write_robot_log(out, spec, rig, body, stamps, cfg.faults.validated(), seed=ctx.seed, storage=cfg.storage,
                           supersample=cfg.supersample)
