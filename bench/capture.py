"""The test room's oracle and capture speed: rays/s and frames/s.

    python bench/capture.py [--quick]

Measures, on this machine: the exact ray caster on random rays from the walk loop,
``render_gt`` (pinhole and fisheye, 320x240, 1 and 2x2 rays per pixel), ``lidar_gt`` for a
16 x 1800 VLP-16-like scan, and the whole ``capture synth`` stage (render + PNG + EXR + video
+ hashing) in frames/s. Prints a table, then one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.geometry.cameras import Camera  # noqa: E402
from nsim.sensors.lidar import LidarConfig  # noqa: E402
from nsim.stages import capture  # noqa: E402
from nsim.synth.oracle import RoomOracle  # noqa: E402
from nsim.synth.path import handheld_path  # noqa: E402
from nsim.synth.room import make_room  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    repeat = 1 if args.quick else 3
    spec = make_room("robot-lab", 0)
    oracle = RoomOracle(spec)
    rng = np.random.default_rng(0)
    poses = handheld_path(spec, 8, seed=0)
    n_rays = 200_000 if args.quick else 2_000_000
    origins = poses[rng.integers(0, len(poses), n_rays), :3, 3]
    dirs = rng.normal(size=(n_rays, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rows = {}  # (label, json key) -> rays/s
    rows[("cast (random rays)", "cast")] = n_rays / best_of(lambda: oracle.cast_rays(origins, dirs), repeat)
    w, h = (160, 120) if args.quick else (320, 240)
    for name, cam in (("pinhole", Camera.pinhole_from_fov(w, h, 75.0)), ("fisheye", Camera.fisheye_spot_like(w, h))):
        for ss in (1, 2):
            t = best_of(lambda cam=cam, ss=ss: oracle.render_gt(cam, poses[0], supersample=ss), repeat)
            rows[(f"render_gt {name} {w}x{h} ss={ss}", f"render_gt_{name}_ss{ss}")] = w * h * ss * ss / t
    lidar = LidarConfig()
    lidar_pose = np.eye(4)  # LiDAR frame: x forward, y left, z up; level, at Spot's mount height
    lidar_pose[:3, 3] = (*spec.walk_loop_xy_m[:2], 0.7)  # the walk loop's centre
    rows[("lidar_gt 16x1800", "lidar_gt")] = lidar.channels * lidar.azimuth_samples / best_of(
        lambda: oracle.lidar_gt(lidar_pose, lidar), repeat
    )
    n_frames = 10 if args.quick else 40
    preset = "tiny" if args.quick else "default"
    cfg = load_config(capture.Config, stage="capture", preset=preset, overrides=[f"n_frames={n_frames}"])
    with tempfile.TemporaryDirectory() as tmp:
        ctx = RunContext(store=Store(Path(tmp) / "ws"), device_spec="cpu", seed=0, progress=False)
        t0 = time.perf_counter()
        capture.run(capture.Inputs(), cfg, ctx)
        stage_s = time.perf_counter() - t0
    fps = n_frames / stage_s
    print(f"{'what':<36} {'rays/s':>12}")
    for (label, _), v in rows.items():
        print(f"{label:<36} {v:>12,.0f}")
    print(f"capture synth ({preset}, {cfg.width}x{cfg.height}, ss={cfg.supersample}, {n_frames} frames): "
          f"{fps:.2f} frames/s")
    out = {"bench": "capture", "quick": args.quick, "render_resolution": [w, h]}
    out.update({f"{key}_rays_s": round(v) for (_, key), v in rows.items()})
    out["capture_frames_s"] = round(fps, 2)
    out["capture_resolution"] = [cfg.width, cfg.height]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
