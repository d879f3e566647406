"""The ``render`` artifact from its rendered shards: assembly, previews, and the ROS 2 bag export.

``assemble`` hard-links every shard's files (``nsim.rendering.shard``) into the artifact and writes
the frame-level files: ``render.json`` (the mode's contract, in the layout below),
trajectory mode's ``rig.json``, ``robot.tum``, ``cameras/<sensor>.json`` and person boxes, recording
mode's per-stream frames and person boxes, and ``preview/`` (``write_previews``: the contact sheet
and the H.264 video, rows drawn by ``_frame_strip`` or, recording mode, ``_recording_strip``).
``export_rosbag`` writes a trajectory-mode artifact as a ROS 2 bag.

``sources`` are the render's input artifacts as folders and ``frames`` what was rendered
(``nsim.rendering.render_job``); ``cfg`` is the render's ``nsim.rendering.render_plan.RenderConfig``.

The render artifact (``nsim render``; its modes are described in :mod:`nsim.stages.render`).
Layout (``NNNNNN`` = tick index in the trajectory, or frame index in the poses)::

    render.json                  mode, sensors, frames (index, time, name), conventions, the scene id
    rig.json                     the resolved rig (mounts, intrinsics, LiDAR patterns)
    robot.tum                    trajectory mode: the robot body pose at each rendered tick
    cameras/<sensor>.json        per camera: transforms.json (intrinsics, cam_to_world per frame)
    <camera>/rgb/NNNNNN.png      8-bit sRGB (gray cameras: one channel)
    <camera>/rgb_linear/NNNNNN.exr   (rgb_exr: true) linear float16 R, G, B
    <camera>/depth/NNNNNN.exr    float32 channel Z: the rig's depth kind (z-depth along the optical
                                 axis unless the rig says range), metres; inf = no return, NaN =
                                 no valid measurement; stated in the header (nsim_depth)
    <camera>/mask/NNNNNN.png     (with people) 16-bit instance mask: 0 background, k = human k
    <camera>/boxes.json          (with people) COCO-style person boxes per frame
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
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.errors import InputError
from nsim.rendering.render_job import (
    ArtifactDir,
    Frame,
    PoseFrame,
    RecordedStream,
    RecordingPlan,
    RenderSources,
    TickFrame,
)
from nsim.rendering.render_plan import RenderConfig, scene_is_metric

if TYPE_CHECKING:
    from nsim.sensors.rig import Rig


def _world_units(scene: ArtifactDir) -> str:
    """What the world's lengths are: metres, unless the scene was trained on poses of arbitrary scale."""
    if not scene_is_metric(scene.file("scene.json")):
        return "arbitrary units (the poses had no metric scale; see scene.json units_per_m), z up"
    return "metres, z up"


def assemble(out_dir: Path, sources: RenderSources, cfg: RenderConfig, rig: Rig | None,
             frames: Sequence[Frame], shard_dirs: list[Path],
             recording: RecordingPlan | None = None) -> dict[str, Any]:
    """Hard-link every shard's files into the artifact, then write the frame-level files: trajectory and
    poses mode from ``frames`` (and trajectory mode's ``rig``), recording mode from ``recording`` (whose
    ``frames`` these are)."""
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
    if recording is not None:
        return _assemble_recording(out_dir, sources, cfg, recording, rows)
    meta: dict[str, Any] = {
        "mode": "trajectory" if sources.trajectory is not None else "poses",
        "scene": sources.scene.id,
        "frames": [f.to_json() for f in frames],
        "conventions": {
            "world": _world_units(sources.scene),
            "camera": "OpenCV axes (x right, y down, z forward)",
            "lidar": "x forward, y left, z up; rows = beams (ring 0 lowest), columns = azimuth",
            "body": "x forward, y left, z up",
            "rgb": "8-bit sRGB PNG",
            "depth": "float32 EXR channel Z, metres; see the nsim_depth header attribute",
        },
        "per_frame": rows,
    }
    summary: dict[str, Any] = {"mode": meta["mode"], "frames": len(frames), "humans": len(sources.humans)}
    if rig is not None:
        from nsim.io.transforms_json import Frame, TransformsData, write_transforms
        from nsim.io.tum import Trajectory, write_tum
        from nsim.sensors.rig import CameraSensor

        (out_dir / "rig.json").write_text(json.dumps(rig.to_dict(), indent=1, sort_keys=True, default=str) + "\n")
        body = np.stack([f.body_to_world for f in frames])
        times = np.array([f.time_s for f in frames])
        write_tum(out_dir / "robot.tum", Trajectory.from_poses(times, body))
        (out_dir / "cameras").mkdir()
        for s in rig.sensors:
            if isinstance(s, CameraSensor):
                tf = [Frame(file_path=f"{s.name}/rgb/{f.index:06d}.png", cam_to_world=s.world_pose(b), camera=s.camera,
                            timestamp_s=f.time_s) for f, b in zip(frames, body, strict=True)]
                write_transforms(out_dir / "cameras" / f"{s.name}.json", TransformsData(frames=tf))
        meta["sensors"] = [{"name": s.name, "type": s.type} for s in rig.sensors]
        summary["sensors"] = [s.name for s in rig.sensors]
        summary["rig"] = rig.name
        summary["rig_file"] = str(sources.rig_file)
        if sources.people:
            from nsim.io.coco import coco_from_mask_files, write_coco_json

            for s in rig.sensors:
                if isinstance(s, CameraSensor):
                    masks = sorted((out_dir / s.name / "mask").glob("*.png"))
                    write_coco_json(out_dir / s.name / "boxes.json",
                                    coco_from_mask_files(masks, [f"{s.name}/rgb/{m.name}" for m in masks]))
    (out_dir / "render.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    write_previews(out_dir, rig, frames, cfg)
    return summary


def _assemble_recording(out_dir: Path, sources: RenderSources, cfg: RenderConfig, recording: RecordingPlan,
                        rows: list[dict]) -> dict[str, Any]:
    """Recording mode's render.json (the contract in the module docstring) and previews."""
    frames, streams = recording.frames, recording.streams
    per_stream = []
    for st in streams:
        mine = [f for f in frames if f.stream == st.key]
        per_stream.append({"name": st.name, "kind": st.kind, "color": st.color,
                           "skipped_outside_trajectory": st.skipped_outside_trajectory,
                           **({"people_outside_run": st.people_outside_run} if sources.people else {}),
                           "frames": [f.to_json() for f in mine]})
    meta: dict[str, Any] = {
        "mode": "recording",
        "recording": sources.recording.id,
        "registration": sources.registration.id,
        "scene": sources.scene.id,
        "streams": per_stream,
        "conventions": {
            "world": _world_units(sources.scene),
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
    if sources.people:
        meta["people"] = _recording_people(out_dir, sources, cfg, recording)
        meta["conventions"].update({
            "people_time_s": "the run's simulation time whose people a frame shows: run_start_s + (odom_time_ns - "
                             "first_odometry_ns) / 1e9 + people_time_offset_s (see people); outside the run: nobody",
            "mask": "mask/<name>/NNNNNN.png per camera stream, 16-bit instance mask: 0 background, k + 1 = the "
                    "trajectory's person k (its order in position_m)",
            "boxes": "boxes/<name>.json per camera stream, COCO person boxes of the masks (file_name: the rendered "
                     "camera/<name>/NNNNNN.png)"})
    (out_dir / "render.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    by_stream = {st.key: [f.index for f in frames if f.stream == st.key] for st in streams}
    n = max(len(v) for v in by_stream.values())
    write_previews(out_dir, None, list(range(n)), cfg,
                   strip=lambda row: _recording_strip(out_dir, sources.recording.path, streams, by_stream, row))
    summary = {"mode": "recording", "frames": len(frames), "humans": len(sources.humans),
               "streams": {st.key: len(by_stream[st.key]) for st in streams},
               "skipped_outside_trajectory": sum(st.skipped_outside_trajectory for st in streams)}
    if sources.people:
        summary["people_outside_run"] = sum(st.people_outside_run for st in streams)
    return summary


def _recording_people(out_dir: Path, sources: RenderSources, cfg: RenderConfig,
                      recording: RecordingPlan) -> dict[str, Any]:
    """Recording mode with people: each camera stream's COCO boxes (``boxes/<name>.json``, from its masks)
    and render.json's ``people`` entry (the trajectory, the humans, the time origin)."""
    from nsim.io.coco import coco_from_mask_files, write_coco_json

    streams = recording.streams
    (out_dir / "boxes").mkdir()
    for st in streams:
        if st.kind == "camera":
            masks = sorted((out_dir / "mask" / st.name).glob("*.png"))
            write_coco_json(out_dir / "boxes" / f"{st.name}.json",
                            coco_from_mask_files(masks, [f"camera/{st.name}/{m.name}" for m in masks]))
    return {"trajectory": sources.trajectory.id, "humans": [h.id for h in sources.humans],
            "people_time_offset_s": cfg.people_time_offset_s, **dataclasses.asdict(recording.people),
            "people_outside_run": sum(st.people_outside_run for st in streams),
            "rule": "people_time_s = run_start_s + (odom_time_ns - first_odometry_ns) / 1e9 + people_time_offset_s: "
                    "people_time_offset_s 0 puts the run's first tick at the recording's first odometry stamp, as "
                    "nsim capture robot-log records a run"}


def _recording_strip(out_dir: Path, recording_dir: Path, streams: Sequence[RecordedStream],
                     by_stream: dict[str, list[int]], row: int, height: int = 160) -> np.ndarray:
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
        if row >= len(by_stream[st.key]) or st.kind == "depth":
            continue
        index = by_stream[st.key][row]
        rel = f"{st.kind}/{st.name}/{index:06d}"
        if st.kind == "camera":
            pair = np.concatenate([tile(recording_dir / f"{rel}.png"), tile(out_dir / f"{rel}.png")], axis=1)
            tiles.append(add_label(pair, [f"{st.name} #{index} recorded", "rendered"]))
        else:
            def xyz(path: Path) -> np.ndarray:
                p = read_points_exr(path)
                return np.stack([p[c].reshape(-1) for c in "XYZ"], -1)

            img = _bev_points(xyz(recording_dir / f"{rel}.exr"), colour=(110, 110, 110))
            img = _bev_points(xyz(out_dir / f"{rel}.exr"), img=img)
            tiles.append(add_label(cv2.resize(img, (height, height), interpolation=cv2.INTER_NEAREST),
                                   f"{st.name} #{index} (recorded grey)"))
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


def write_previews(out_dir: Path, rig: Rig | None, frames: Sequence[Any], cfg: RenderConfig,
                   strip: Callable[[Any], np.ndarray] | None = None) -> None:
    """The contact sheet (and video) of ``frames``, one row each; ``strip(frame) -> (H, W, 3) uint8`` draws
    one (default, for ``TickFrame``s and ``PoseFrame``s: the rig's cameras and LiDAR BEVs at the frame's index)."""
    from nsim.io.images import write_image

    if strip is None:
        def strip(f: TickFrame | PoseFrame) -> np.ndarray:
            return _frame_strip(out_dir, rig, f.index, f.time_s)
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
            for j, f in enumerate(frames):
                row = first if j == 0 else strip(f)
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
