"""The ``recording`` artifact's files, written from an opened robot log (the core of ``nsim import-log``).

``kept_frames`` / ``inside_trajectory`` choose and check frames; ``write_recording`` writes
recording.json, the trajectory (TUM and int64 ns), every kept frame (PNG, EXR) and ``preview.png``;
the layout is in :mod:`nsim.stages.import_log`'s docstring. Arrays and readers in, files out: no
workspace code here.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from nsim.io.recording_streams import DepthUnit, depth_unit_of

log = logging.getLogger("nsim.stages.import_log")


def kept_frames(n: int, stride: int, max_frames: int) -> np.ndarray:
    """Indices kept of ``n`` frames: every ``stride``-th, then at most ``max_frames`` evenly spaced (0: all)."""
    idx = np.arange(0, n, stride, dtype=np.int64)
    if max_frames and len(idx) > max_frames:
        idx = idx[np.unique(np.round(np.linspace(0, len(idx) - 1, max_frames)).astype(np.int64))]
    return idx


def inside_trajectory(stamps_ns: np.ndarray, traj_ns: np.ndarray, max_gap_s: float) -> np.ndarray:
    """``(N,)`` bool: each stamp lies within the trajectory's span and within ``max_gap_s`` of a pose stamp."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    if len(traj_ns) == 0:
        return np.zeros(len(stamps_ns), dtype=bool)
    j = np.clip(np.searchsorted(traj_ns, stamps_ns), 1, max(1, len(traj_ns) - 1))
    gap = np.minimum(np.abs(stamps_ns - traj_ns[j - 1]), np.abs(traj_ns[np.minimum(j, len(traj_ns) - 1)] - stamps_ns))
    span = (stamps_ns >= traj_ns[0]) & (stamps_ns <= traj_ns[-1])
    return span & (gap <= int(round(max_gap_s * 1e9)))


def source_description(log_paths: list[str], is_folder: bool) -> dict[str, Any]:
    """What recording.json says of the log: the bags' names or the folder's, and what the stamps are."""
    clock = "(each stream on its sensor's clock)"
    if is_folder:
        return {"folder": {"name": Path(log_paths[0]).name},
                "time": f"int64 nanoseconds, the frames' stamps as the folder gives them {clock}"}
    return {"bags": [{"name": Path(p).name} for p in log_paths],
            "time": f"int64 nanoseconds, the messages' header stamps {clock}"}


def write_recording(out_dir: Path, rl, traj, plan: list, log_paths: list[str], is_folder: bool, max_gap_s: float,
                    show_progress: bool) -> dict[str, Any]:
    """Write the artifact's files (module docstring) from an open ``RobotLog`` or ``RobotFolder``; returns
    recording.json's content."""
    from nsim.io.exr import write_depth_exr, write_points_exr
    from nsim.io.images import write_image, write_png16
    from nsim.io.tum import Trajectory, write_tum
    from nsim.progress import progress_bar

    np.save(out_dir / "trajectory_ns.npy", traj.stamps_ns.astype(np.int64), allow_pickle=False)
    write_tum(out_dir / "trajectory.tum", Trajectory.from_poses(traj.stamps_ns / 1e9, traj.body_to_odom))
    steps = np.linalg.norm(np.diff(traj.body_to_odom[:, :3, 3], axis=0), axis=-1)
    doc: dict[str, Any] = {
        "format": 1,
        **source_description(list(log_paths), is_folder),
        "body_frame": traj.body_frame, "odom_frame": traj.odom_frame,
        "trajectory": {"source": traj.source, "poses": int(len(traj.stamps_ns)),
                       "duration_s": float((traj.stamps_ns[-1] - traj.stamps_ns[0]) / 1e9),
                       "length_m": float(steps.sum()), "file": "trajectory.tum",
                       "meaning": "body_to_odom: the body's pose in the odometry frame"},
        "trajectory_only": not plan,
        "streams": {},
    }
    total = sum(len(keep) for *_, keep in plan)
    with progress_bar(total, "importing frames", show_progress) as bar:
        done, last_log = 0, time.monotonic()
        for kind, name, s, extrinsic, keep in plan:
            d = out_dir / kind / name
            d.mkdir(parents=True)
            read_one = rl.cloud if kind == "lidar" else rl.image
            medians = []  # depth: each frame's median valid depth (m), for the plausibility check
            if len(keep) == len(s.stamps_ns):  # every frame: one streaming pass
                source = rl.clouds(s) if kind == "lidar" else rl.images(s)
            else:  # a subset: decode only the frames kept
                source = ((int(i), read_one(s, int(i))) for i in keep)
            for i, data in source:
                path = d / f"{i:06d}"
                if kind == "camera":
                    if data.dtype == np.uint16:
                        write_png16(path.with_suffix(".png"), data)
                    else:
                        write_image(path.with_suffix(".png"), data)
                elif kind == "depth":
                    write_depth_exr(path.with_suffix(".exr"), data, {"nsim_depth": "z-depth, metres"})
                    valid = data[np.isfinite(data) & (data > 0)]
                    if valid.size:
                        medians.append(float(np.median(valid)))
                else:
                    channels = {"X": data.xyz_m[:, 0], "Y": data.xyz_m[:, 1], "Z": data.xyz_m[:, 2]}
                    channels |= {f: v for f in ("intensity", "ring", "time") if (v := getattr(data, f)) is not None}
                    write_points_exr(path.with_suffix(".exr"), {  # one row of N points
                        k: np.asarray(v, dtype=np.uint32 if k == "ring" else np.float32)[None, :]
                        for k, v in channels.items()})
                done += 1
                bar.advance()
                if not show_progress and time.monotonic() - last_log > 10.0:
                    log.info("import-log: %d / %d frames written", done, total)
                    last_log = time.monotonic()
            stamps = s.stamps_ns[keep]
            np.save(d / "stamps_ns.npy", stamps.astype(np.int64), allow_pickle=False)
            inside = inside_trajectory(stamps, traj.stamps_ns, max_gap_s)
            entry = {"kind": kind, "topic": s.topic, "frame_id": s.frame_id,
                     "sensor_to_body": np.asarray(extrinsic).tolist(), "frames": [int(i) for i in keep],
                     "frames_in_topic": len(s.stamps_ns), "inside_trajectory": int(inside.sum()),
                     "stamps_from_bag": int(s.stamps_from_bag), "dir": f"{kind}/{name}"}
            if kind == "lidar":
                entry["fields"] = list(s.fields)
            else:
                entry |= {"camera": s.camera.to_dict(), "encoding": s.encoding, "info_topic": s.info_topic}
            if kind == "depth":
                entry |= depth_record(f"{kind}/{name}", depth_unit_of(s), medians)
            if len(stamps) and inside.sum() < len(stamps):
                log.warning("import-log: %s %s: %d of %d frames lie outside the trajectory (%s) by more than %g s",
                            kind, name, len(stamps) - int(inside.sum()), len(stamps), traj.source, max_gap_s)
            doc["streams"][f"{kind}/{name}"] = entry
    (out_dir / "recording.json").write_text(json.dumps(doc, indent=1) + "\n")
    write_preview(out_dir / "preview.png", out_dir, doc, traj)
    return doc


#: A depth stream whose median valid depth lies outside this range (m) is reported: likely a wrong unit.
PLAUSIBLE_DEPTH_M = (0.1, 20.0)


def depth_record(name: str, unit: DepthUnit, frame_medians: list[float]) -> dict[str, Any]:
    """recording.json's depth fields of one stream: its unit (what a frame's number was in metres, and who said
    so) and the median of its frames' median valid depths, with a warning when that is outside
    ``PLAUSIBLE_DEPTH_M`` (a unit 5x or 1000x off lands there)."""
    median = float(np.median(frame_medians)) if frame_medians else None
    lo, hi = PLAUSIBLE_DEPTH_M
    if median is not None and not lo <= median <= hi:
        log.warning("import-log: %s: median depth %.3g m, outside %g-%g m: is the unit right? (%g m per unit: %s)",
                    name, median, lo, hi, unit.m_per_unit, unit.source)
    return {"depth_m_per_unit": unit.m_per_unit, "depth_unit": unit.source,
            "median_depth_m": None if median is None else round(median, 6)}


def write_preview(path: Path, out_dir: Path, doc: dict[str, Any], traj) -> None:
    """The trajectory from above, coloured by time, and each camera's first kept frame, labelled."""
    import matplotlib

    matplotlib.use("Agg")
    import cv2
    import matplotlib.pyplot as plt

    cams = [(k, v) for k, v in doc["streams"].items() if v["kind"] == "camera" and v["frames"]]
    cols = 1 + min(len(cams), 5)
    fig, axes = plt.subplots(1, cols, figsize=(4.0 * cols, 4.0), squeeze=False)
    ax = axes[0, 0]
    xy = traj.body_to_odom[:, :2, 3]
    t = (traj.stamps_ns - traj.stamps_ns[0]) / 1e9
    sc = ax.scatter(xy[:, 0], xy[:, 1], c=t, s=4, cmap="viridis")
    ax.plot(xy[0, 0], xy[0, 1], "k^", label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"x in {doc['odom_frame']} (m)")
    ax.set_ylabel(f"y in {doc['odom_frame']} (m)")
    ax.set_title(f"body trajectory ({doc['trajectory']['source']})\n{doc['trajectory']['length_m']:.1f} m, "
                 f"{doc['trajectory']['duration_s']:.1f} s", fontsize=9)
    ax.legend(fontsize=8)
    fig.colorbar(sc, ax=ax, label="time (s)", fraction=0.046)
    for a, (k, v) in zip(axes[0, 1:], cams, strict=False):
        img = cv2.imread(str(out_dir / v["dir"] / f"{v['frames'][0]:06d}.png"), cv2.IMREAD_UNCHANGED)
        img = img[..., ::-1] if img.ndim == 3 else img
        a.imshow(img, cmap="gray" if img.ndim == 2 else None)
        a.set_title(f"{k}: {v['camera']['model']} {v['camera']['width']}x{v['camera']['height']}\n"
                    f"{len(v['frames'])} frames, {v['topic']}", fontsize=8)
        a.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
