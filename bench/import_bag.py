"""Reading robot recordings with ``nsim.io.robot_log.RobotLog``: what it finds, how fast, how much memory.

    python bench/import_bag.py BAG [BAG ...] [--selection topics.yaml] [--trajectory auto|tf|odometry]
    python bench/import_bag.py --quick

Each BAG is one recording: a ROS 1 ``.bag``, a ROS 2 bag directory (``metadata.yaml`` with
``.db3`` or ``.mcap``) or a lone ``.mcap``; ``a.bag+b.bag`` joins the files of a split ROS 1
recording. For each it opens the bag (one pass over the selected topics), prints its topics and
the streams found -- cameras and depth with model, size, frame count and rate; LiDARs with points
per cloud; the odometry with its pose count and path length; the tf frames and links; the body
trajectory with its source, length and duration -- then decodes every image and every cloud,
streamed one at a time, as an importer does. ``--selection`` (a topics YAML,
``nsim.io.topic_selection.load_selection``) applies to every BAG.

``--quick`` writes small bags itself with ``nsim.io.rosbag.BagWriter`` (a camera with depth, a
gray camera and a LiDAR on a moving body; sqlite3, mcap and ROS 1) in a temporary directory,
reads them the same way and checks what it reads against what it wrote (``quick_ok``).

Times are wall seconds (open: the index pass; decode: every image and cloud); ``peak_rss_gb`` is
the process's peak resident memory (``ru_maxrss``) after the last bag. A bag that cannot be read is
reported in one line and counted in ``errors`` (exit status 2). The last line is one JSON object:
``bags, messages, images_decoded, clouds_decoded, points_decoded, odometry_poses,
trajectory_poses, trajectory_length_m, open_s, decode_s, read_s, peak_rss_gb, errors, per_bag``.
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.errors import InputError  # noqa: E402
from nsim.io.robot_log import RobotLog  # noqa: E402
from nsim.io.topic_selection import Selection, load_selection  # noqa: E402


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def rate_hz(stamps_ns: np.ndarray) -> float:
    if len(stamps_ns) < 2 or stamps_ns[-1] == stamps_ns[0]:
        return 0.0
    return (len(stamps_ns) - 1) / ((stamps_ns[-1] - stamps_ns[0]) / 1e9)


def path_length_m(poses: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum()) if len(poses) > 1 else 0.0


def read_bag(paths: list[Path], selection: Selection | None, trajectory: str) -> dict[str, Any]:
    """Open, describe (printed) and decode one recording; returns its row of numbers."""
    row: dict[str, Any] = {"bag": "+".join(str(p) for p in paths)}
    t0 = time.perf_counter()
    with RobotLog(paths, selection) as log:
        open_s = time.perf_counter() - t0
        messages = sum(t.count for t in log.topics.values())
        print(f"\n== {log.name}: {len(log.topics)} topics, {messages} messages, opened in {open_s:.2f} s")
        width = max((len(t) for t in log.topics), default=5)
        for name, t in sorted(log.topics.items()):
            print(f"  {name:<{width}}  {t.msgtype or '(several types)':<40} {t.count:>7}")
        try:
            traj, traj_error = log.body_trajectory(trajectory), None
        except InputError as exc:
            traj, traj_error = None, str(exc)

        def in_span(stamps_ns: np.ndarray) -> str:
            if traj is None or not len(traj.stamps_ns):
                return ""
            inside = int(((stamps_ns >= traj.stamps_ns[0]) & (stamps_ns <= traj.stamps_ns[-1])).sum())
            return f", {inside}/{len(stamps_ns)} in the trajectory's span"

        for group, streams in (("camera", log.cameras), ("depth", log.depth)):
            for name, s in sorted(streams.items()):
                c = s.camera
                print(f"  {group} {name}: {s.topic} ({s.encoding}), {c.model} {c.width}x{c.height} fx {c.fx:.1f}, "
                      f"{len(s)} frames at {rate_hz(s.stamps_ns):.1f} Hz, frame {s.frame_id!r}{in_span(s.stamps_ns)}"
                      + (f", {s.stamps_from_bag} stamps from bag time" if s.stamps_from_bag else ""))
        for name, s in sorted(log.lidars.items()):
            print(f"  lidar {name}: {s.topic}, {len(s)} clouds at {rate_hz(s.stamps_ns):.1f} Hz, frame {s.frame_id!r}, "
                  f"fields {','.join(s.fields)}{in_span(s.stamps_ns)}")
        o = log.odometry
        if o is not None:
            print(f"  odometry: {o.topic}, {o.frame_id!r} -> {o.child_frame_id!r}, {len(o.stamps_ns)} poses at "
                  f"{rate_hz(o.stamps_ns):.1f} Hz, path {path_length_m(o.child_to_parent):.2f} m")
        else:
            print("  odometry: none")
        moving = ", ".join(f"{m.parent}->{m.child} ({len(m.stamps_ns)})" for m in log.tf.moving) or "none"
        print(f"  tf: {len(log.tf.frames)} frames, {len(log.tf.static)} static links, moving: {moving}")
        print(f"  body frame {log.body_frame!r}, odom frame {log.odom_frame!r}")
        if traj is not None:
            duration_s = (traj.stamps_ns[-1] - traj.stamps_ns[0]) / 1e9 if len(traj.stamps_ns) else 0.0
            length = path_length_m(traj.body_to_odom)
            print(f"  trajectory: {traj.source}, {len(traj.stamps_ns)} poses, {length:.2f} m in {duration_s:.1f} s")
            row.update(trajectory_source=traj.source, trajectory_poses=len(traj.stamps_ns), trajectory_length_m=length,
                       trajectory_duration_s=duration_s)
        else:
            print(f"  trajectory: none ({traj_error})")
            row.update(trajectory_source=None, trajectory_poses=0, trajectory_length_m=0.0, trajectory_duration_s=0.0,
                       trajectory_error=traj_error)
        t1 = time.perf_counter()
        images = 0
        for streams in (log.cameras, log.depth):
            for s in streams.values():
                for _, image in log.images(s):
                    images += 1
                    assert image.shape[:2] == (s.camera.height, s.camera.width)
        clouds, points = 0, 0
        per_cloud = {}
        for name, s in log.lidars.items():
            n = 0
            for _, cloud in log.clouds(s):
                clouds += 1
                n += len(cloud)
            points += n
            per_cloud[name] = n / max(len(s), 1)
        decode_s = time.perf_counter() - t1
    for name, n in sorted(per_cloud.items()):
        print(f"  lidar {name}: {n:.0f} points per cloud")
    print(f"  decoded {images} images and {clouds} clouds ({points} points) in {decode_s:.2f} s; "
          f"peak RSS so far {peak_rss_gb():.3f} GB")
    row.update(messages=messages, cameras=len(log.cameras), depth=len(log.depth), lidars=len(log.lidars),
               images_decoded=images, clouds_decoded=clouds, points_decoded=points,
               odometry_poses=0 if o is None else len(o.stamps_ns), tf_frames=len(log.tf.frames),
               open_s=open_s, decode_s=decode_s, read_s=open_s + decode_s, peak_rss_gb=peak_rss_gb())
    return row


def write_quick_bags(root: Path) -> tuple[list[Path], dict[str, Any]]:
    """Three small bags (sqlite3, mcap, ROS 1) of one run, and what was written in them."""
    from scipy.spatial.transform import Rotation

    from nsim.geometry import make_se3
    from nsim.io.rosbag import BagWriter
    from nsim.sensors import Rig

    rig = Rig.from_data({
        "name": "quick",
        "sensors": [
            {"name": "front", "type": "camera", "mount": {"xyz_m": [0.4, 0.0, 0.3], "rpy_deg": [-90.0, 0.0, -90.0]},
             "intrinsics": {"model": "OPENCV", "width": 64, "height": 48, "fx": 50.0,
                            "dist": [0.05, -0.01, 0.0, 0.0, 0.0]}, "depth": True},
            {"name": "side", "type": "camera", "mount": {"xyz_m": [0.0, 0.2, 0.3], "rpy_deg": [-90.0, 0.0, 0.0]},
             "intrinsics": {"model": "PINHOLE", "width": 32, "height": 24, "fx": 20.0}, "color": "gray"},
            {"name": "top", "type": "lidar", "mount": {"xyz_m": [0.0, 0.0, 0.5]},
             "lidar": {"channels": 8, "vertical_fov_deg": [-15, 15], "azimuth_samples": 90}},
        ],
    })
    ticks, dt_s = 20, 0.1
    rng = np.random.default_rng(0)
    poses = [make_se3(Rotation.from_euler("z", 0.05 * k).as_matrix(), np.array([0.1 * k, 0.02 * k, 0.0]))
             for k in range(ticks)]
    frames = []
    for _ in range(ticks):
        lidar = rig["top"]
        frames.append({"rgb": rng.integers(0, 256, (48, 64, 3), dtype=np.uint8),
                       "depth": rng.uniform(0.5, 8.0, (48, 64)).astype(np.float32),
                       "gray": rng.integers(0, 256, (24, 32), dtype=np.uint8),
                       "scan": lidar.scan(rng.uniform(1, 20, lidar.ray_shape),
                                          intensity=rng.uniform(0, 1, lidar.ray_shape))})
    paths = []
    for storage in ("sqlite3", "mcap", "ros1"):
        path = root / (f"quick_{storage}.bag" if storage == "ros1" else f"quick_{storage}")
        with BagWriter(path, rig, storage=storage, time_offset_ns=1_700_000_000 * 10**9) as bag:
            for k, (pose, f) in enumerate(zip(poses, frames, strict=True)):
                bag.write_tick(k * dt_s, pose, images={"front": f["rgb"], "side": f["gray"]},
                               depths={"front": f["depth"]}, clouds={"top": f["scan"]})
        paths.append(path)
    truth = {"images": 3 * ticks, "clouds": ticks, "poses": np.stack(poses),
             "points": sum(int(f["scan"].hit.sum()) for f in frames)}
    return paths, truth


def check_quick(paths: list[Path], truth: dict[str, Any]) -> bool:
    """Every bag read back as written: counts, points and the trajectory (to 1e-9 m)."""
    ok = True
    for path in paths:
        with RobotLog(path) as log:
            traj = log.body_trajectory()
            ok &= sorted(log.cameras) == ["front", "side"] and list(log.depth) == ["front"]
            ok &= bool(np.allclose(traj.body_to_odom, truth["poses"], rtol=0, atol=1e-9))
    return bool(ok)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bags", nargs="*", help="bags to read (a+b: the files of one split ROS 1 recording)")
    ap.add_argument("--selection", type=Path, default=None, help="topics YAML applied to every bag")
    ap.add_argument("--trajectory", default="auto", choices=("auto", "tf", "odometry"))
    ap.add_argument("--quick", action="store_true", help="write small bags and read those (no data needed)")
    ap.add_argument("-v", "--verbose", action="store_true", help="show the reader's warnings and notes")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR, format="  %(levelname)s %(message)s")
    if not args.bags and not args.quick:
        ap.error("give at least one BAG, or --quick")
    selection = load_selection(args.selection) if args.selection is not None else None
    with tempfile.TemporaryDirectory() as tmp:
        recordings = [[Path(p) for p in arg.split("+")] for arg in args.bags]
        truth = None
        if args.quick:
            t = time.perf_counter()
            quick_paths, truth = write_quick_bags(Path(tmp))
            print(f"wrote {len(quick_paths)} quick bags in {time.perf_counter() - t:.2f} s")
            recordings += [[p] for p in quick_paths]
        rows, errors = [], []
        for k, paths in enumerate(recordings):
            try:
                rows.append(read_bag(paths, selection, args.trajectory))
                rows[-1]["quick"] = k >= len(args.bags)
            except InputError as exc:
                print(f"\n== {'+'.join(map(str, paths))}: cannot be read: {exc}")
                errors.append(str(exc))
        quick_ok = check_quick(quick_paths, truth) if args.quick else None
    total = {k: sum(r[k] for r in rows) for k in ("messages", "images_decoded", "clouds_decoded", "points_decoded",
                                                   "odometry_poses", "trajectory_poses", "trajectory_length_m",
                                                   "open_s", "decode_s", "read_s")}
    print(f"\n{'bag':<60} {'msgs':>8} {'images':>7} {'clouds':>7} {'odom':>6} {'traj m':>8} {'read s':>7}")
    for r in rows:
        name = r["bag"] if len(r["bag"]) <= 60 else "..." + r["bag"][-57:]
        print(f"{name:<60} {r['messages']:>8} {r['images_decoded']:>7} {r['clouds_decoded']:>7} "
              f"{r['odometry_poses']:>6} {r['trajectory_length_m']:>8.2f} {r['read_s']:>7.2f}")
    out = {"bench": "import_bag", "quick": args.quick, "bags": len(rows), **total, "peak_rss_gb": peak_rss_gb(),
           "errors": errors, "per_bag": rows}
    if args.quick:
        quick_rows = [r for r in rows if r.get("quick")]
        out["quick_ok"] = quick_ok and len(quick_rows) == 3 and all(
            (r["images_decoded"], r["clouds_decoded"], r["points_decoded"]) == (truth["images"], truth["clouds"],
                                                                                truth["points"]) for r in quick_rows)
    print(json.dumps(out))
    if errors or out.get("quick_ok") is False:
        sys.exit(2)


if __name__ == "__main__":
    main()
