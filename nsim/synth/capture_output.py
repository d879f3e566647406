"""A test-room capture's files: the frames rendered by the room's oracle (or through the phone model),
depth, ``transforms.json``, the ground-truth trajectory, ``room.json``, ``occupancy.json``, the video and a
labelled preview (``nsim capture synth``'s artifact; the stage plans the path and calls these).
``cfg``: the stage's config (room, fps, video, supersample, phone settings).
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from nsim.progress import progress_bar


def write_capture(
    out_dir: Path,
    cfg,
    spec: Any,
    camera: Any,
    cam_to_world: np.ndarray,
    times_s: np.ndarray,
    oracle: Any,
    show_progress: bool,
    plan: Any = None,
    seed: int = 0,
    stage: str = "capture",
) -> None:
    """Render every frame and write the capture's files into ``out_dir``; through the phone model
    (``nsim.synth.phone``) when ``plan`` (a ``PhonePlan`` of ``cfg.phone``) is given."""
    from nsim.io import atomic_path
    from nsim.io.exr import write_depth_exr
    from nsim.io.images import to_uint8, write_image
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms
    from nsim.io.tum import Trajectory, write_tum
    from nsim.io.video import open_mp4
    from nsim.synth import phone
    from nsim.synth.room import occupancy_polygons, room_diagonal_m

    (out_dir / "images").mkdir()
    (out_dir / "depth").mkdir()
    frames = []
    writer = None
    thumbs = []
    video = contextlib.ExitStack()  # closes (finishes) the video after the last frame
    if cfg.video:
        writer = video.enter_context(open_mp4(out_dir / "video.mp4", float(cfg.fps)))
    with video, progress_bar(len(cam_to_world), f"rendering {cfg.room}", show_progress) as bar:
        for i, c2w in enumerate(cam_to_world):
            extra = {}
            if plan is None:
                rgb, depth_z, _ = oracle.render_gt(camera, c2w, supersample=cfg.supersample)
            else:
                rgb, depth_z = phone.shoot(oracle, camera, plan, i, c2w, cfg.supersample, seed)
                extra = phone.frame_metadata(plan, i)
            rgb_u8 = to_uint8(rgb)
            name = f"frame_{i:05d}"
            image_name = f"{name}.png" if cfg.phone.jpeg_quality is None else f"{name}.jpg"
            if cfg.phone.jpeg_quality is None:
                write_image(out_dir / "images" / image_name, rgb_u8)
            else:  # the phone's own JPEG settings (write_image would use OpenCV's default quality)
                with atomic_path(out_dir / "images" / image_name) as tmp:
                    tmp.write_bytes(phone.encode_jpeg(rgb_u8, cfg.phone.jpeg_quality))
            write_depth_exr(out_dir / "depth" / f"{name}.exr", depth_z.astype(np.float32))
            if writer is not None:
                writer.write(rgb_u8)
            frames.append(
                Frame(
                    file_path=f"images/{image_name}",
                    cam_to_world=c2w,
                    camera=camera,
                    depth_file_path=f"depth/{name}.exr",
                    timestamp_s=float(times_s[i]),
                    extra=extra,
                )
            )
            if i % max(1, len(cam_to_world) // 8) == 0 and len(thumbs) < 8:
                thumbs.append((i, float(times_s[i]), rgb_u8))
            bar.advance()
    top = {"nsim_capture": stage}
    if plan is not None:
        top["nsim_phone"] = phone.capture_metadata(cfg.phone)
    write_transforms(out_dir / "transforms.json", TransformsData(frames=frames, extra=top))
    write_tum(out_dir / "gt_trajectory.tum", Trajectory.from_poses(times_s, cam_to_world))
    (out_dir / "room.json").write_text(
        json.dumps({"preset": cfg.room, "room_seed": cfg.room_seed, "spec": spec.to_dict()}, indent=1) + "\n"
    )
    polygons = occupancy_polygons(spec)
    (out_dir / "occupancy.json").write_text(
        json.dumps(
            {
                "units": "m",
                "frame": "world, z up; polygons in the xy plane (counter-clockwise)",
                "room_diagonal_m": room_diagonal_m(spec),
                "polygons": [np.asarray(p, dtype=float).round(6).tolist() for p in polygons],
            },
            indent=1,
        )
        + "\n"
    )
    write_preview(out_dir / "preview.png", thumbs, polygons, cam_to_world, spec, cfg)


def write_preview(path: Path, thumbs, polygons, cam_to_world: np.ndarray, spec: Any, cfg) -> None:
    """Contact sheet of a few frames (``thumbs``: ``(index, time_s, rgb)``; each labelled with its
    index and time) beside a top-down view of the path over the obstacles, under a title."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nsim.io.images import write_image
    from nsim.io.labels import add_label, tile_grid

    thumb_w, dpi = 240, 80
    tiles = []
    for i, t_s, im in thumbs:
        thumb_h = max(1, round(thumb_w * im.shape[0] / im.shape[1]))
        interp = cv2.INTER_AREA if im.shape[1] > thumb_w else cv2.INTER_NEAREST
        tiles.append(add_label(cv2.resize(im, (thumb_w, thumb_h), interpolation=interp), f"frame {i}  {t_s:.2f} s"))
    sheet = tile_grid(tiles, ncol=4)
    height = max(sheet.shape[0], 360)
    fig = plt.figure(figsize=(6.0, height / dpi), dpi=dpi)
    ax = fig.add_subplot()
    for poly in polygons:
        p = np.asarray(poly)
        ax.fill(p[:, 0], p[:, 1], color="0.6", alpha=0.8, lw=0)
    pos = cam_to_world[:, :3, 3]
    order = np.argsort(-pos[:, 2], kind="stable")  # low passes drawn last, as smaller dots on top
    sc = ax.scatter(pos[order, 0], pos[order, 1], c=pos[order, 2], s=4 + 12 * pos[order, 2], cmap="viridis")
    fwd = cam_to_world[:, :3, 2]
    step = max(1, len(pos) // 30)
    ax.quiver(pos[::step, 0], pos[::step, 1], fwd[::step, 0], fwd[::step, 1], width=0.004, scale=15, color="C3")
    fig.colorbar(sc, ax=ax, label="camera height (m)", shrink=0.7)
    sx, sy, _ = spec.size_xyz_m
    ax.set_xlim(-0.3, sx + 0.3)
    ax.set_ylim(-0.3, sy + 0.3)
    ax.set_aspect("equal")
    ax.set_title("camera path from above")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.canvas.draw()
    top = np.array(fig.canvas.buffer_rgba())[..., :3]  # a copy: the buffer goes with the figure
    plt.close(fig)
    rows = max(sheet.shape[0], top.shape[0])
    out = np.concatenate([np.pad(im, ((0, rows - im.shape[0]), (0, 0), (0, 0)), constant_values=255)
                          for im in (sheet, top)], axis=1)
    write_image(path, add_label(out, f"{cfg.room}: {len(pos)} frames {cfg.width}x{cfg.height} {cfg.camera}"))


