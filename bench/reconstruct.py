"""`nsim reconstruct` on the test room: registration, pose accuracy, metric scale, speed.

    python bench/reconstruct.py [--quick] [--rooms robot-lab kitchen ...] [--cameras pinhole fisheye]

For each room and camera: a default-size capture (320x240, 150 frames; --quick: 160x120,
100 frames, robot-lab pinhole only), then `reconstruct` with `--reference` = the ground-truth
trajectory plus 1 cm of Gaussian noise per axis (SIMPLE_RADIAL for pinhole, OPENCV_FISHEYE for
fisheye). Scored against ground truth after a Sim(3) fit of camera centres: registered
fraction, median rotation error, median position error as % of the room diagonal, and the
metric scale error |s - 1| of the output against ground truth. Speed: frames/s of each SfM
phase (features, matching, the far-pair check, mapping) from the artifact's timing. Bounds checked: >= 95 %
registered, < 0.5 deg, < 1 % of the diagonal, scale within 2 %. Table, then one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.io.transforms_json import read_transforms  # noqa: E402
from nsim.io.tum import Trajectory, read_tum, write_tum  # noqa: E402
from nsim.sfm.align import fit_sim3, pose_errors  # noqa: E402
from nsim.stages import capture, reconstruct  # noqa: E402
from nsim.synth.room import ROOM_PRESETS, make_room, room_diagonal_m  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def bench_one(store: Store, tmp: Path, room: str, camera: str, quick: bool) -> dict:
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    overrides = [f"room={room}", f"camera={camera}"]
    if quick:
        overrides += ["n_frames=100", "width=160", "height=120", "video=false"]
    cap_cfg = load_config(capture.Config, stage="capture", preset="default", overrides=overrides)
    cap = store.get(capture.run(capture.Inputs(), cap_cfg, ctx).capture)
    gt = read_tum(cap.file("gt_trajectory.tum"))
    noisy_xyz = gt.positions_xyz + np.random.default_rng(0).normal(0.0, 0.01, gt.positions_xyz.shape)
    ref = tmp / f"{room}-{camera}-noisy.tum"
    write_tum(ref, Trajectory(gt.timestamps_s, noisy_xyz, gt.orientations_quat_wxyz))
    model = "SIMPLE_RADIAL" if camera == "pinhole" else "OPENCV_FISHEYE"
    rec_cfg = load_config(reconstruct.Config, stage="reconstruct", preset="tiny" if quick else "default",
                          overrides=[f"camera_model={model}", f"frames={cap_cfg.n_frames}"])
    out = reconstruct.run(reconstruct.Inputs(capture=cap.id, reference=ref), rec_cfg, ctx)
    art = store.get(out.poses)
    est = read_transforms(art.file("transforms.json"))
    gt_by_t = {round(float(t), 6): T for t, T in zip(gt.timestamps_s, gt.poses_se3(), strict=True)}
    est_poses = np.stack([f.cam_to_world for f in est.frames])
    gt_poses = np.stack([gt_by_t[round(float(f.timestamp_s), 6)] for f in est.frames])
    rot, pos = pose_errors(est_poses, gt_poses)
    scale = fit_sim3(est_poses[:, :3, 3], gt_poses[:, :3, 3], robust=False).s
    diag = room_diagonal_m(make_room(room, 0))
    phases = art.manifest["timing"].get("phases_s", {})
    n = cap_cfg.n_frames
    fps = {k.removesuffix("_s"): n / v for k, v in phases.items()
           if k in ("features_s", "matching_s", "far_pair_check_s", "mapping_s") and v > 0}
    row = {
        "room": room, "camera": camera, "frames": n, "registered": len(est.frames),
        "registered_pct": 100.0 * len(est.frames) / n,
        "median_rot_deg": float(np.median(rot)), "median_pos_pct_diag": float(100 * np.median(pos) / diag),
        "scale_err_pct": float(100 * abs(scale - 1.0)),
        "fps": {k: round(v, 2) for k, v in fps.items()},
        "wall_s": art.manifest["timing"]["wall_time_s"],
    }
    row["pass"] = bool(row["registered_pct"] >= 95 and row["median_rot_deg"] < 0.5
                       and row["median_pos_pct_diag"] < 1.0 and row["scale_err_pct"] < 2.0)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--rooms", nargs="+", default=None, choices=ROOM_PRESETS)
    ap.add_argument("--cameras", nargs="+", default=None, choices=("pinhole", "fisheye"))
    args = ap.parse_args()
    rooms = args.rooms or (["robot-lab"] if args.quick else list(ROOM_PRESETS))
    cameras = args.cameras or (["pinhole"] if args.quick else ["pinhole", "fisheye"])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "ws")
        for room in rooms:
            for camera in cameras:
                rows.append(bench_one(store, Path(tmp), room, camera, args.quick))
                r = rows[-1]
                print(f"  {room} {camera}: {r['registered']}/{r['frames']} registered, rot {r['median_rot_deg']:.3f} deg, "
                      f"pos {r['median_pos_pct_diag']:.3f} % diag, scale {r['scale_err_pct']:.3f} %, {r['wall_s']:.0f} s",
                      flush=True)
    head = f"{'room':<13} {'camera':<8} {'reg %':>6} {'rot deg':>8} {'pos %diag':>9} {'scale %':>8} " \
           f"{'feat f/s':>8} {'match f/s':>9} {'check f/s':>9} {'map f/s':>8} {'ok':>3}"
    print(head)
    for r in rows:
        f = r["fps"]
        print(f"{r['room']:<13} {r['camera']:<8} {r['registered_pct']:>6.1f} {r['median_rot_deg']:>8.3f} "
              f"{r['median_pos_pct_diag']:>9.3f} {r['scale_err_pct']:>8.3f} {f.get('features', 0):>8.1f} "
              f"{f.get('matching', 0):>9.2f} {f.get('far_pair_check', 0):>9.2f} {f.get('mapping', 0):>8.2f} "
              f"{'yes' if r['pass'] else 'NO':>3}")
    print(json.dumps({"bench": "reconstruct", "quick": args.quick, "rows": rows, "all_pass": all(r["pass"] for r in rows)}))


if __name__ == "__main__":
    main()
