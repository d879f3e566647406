"""A phone's capture against a clean one: registration, poses and held-out PSNR at equal training.

    python bench/phone_capture.py [--room robot-lab] [--workspace DIR] [--preset cpu] [--steps N]
    python bench/phone_capture.py --quick

The test room filmed twice along the same path: by the renderer (``capture synth``, the default
preset) and as a phone films it (``--preset phone``: exposure and white-balance drift, noise,
motion blur, rolling shutter, vignetting, JPEG; ground truth unchanged). Each goes through what a
user runs: ``nsim reconstruct`` (SfM on the frames, metric from the capture's ground-truth
trajectory as a robot's odometry), then ``nsim train-scene --preset cpu`` on those poses; the clean
capture trains on its exact poses (``--clean-poses gt``, the default: the stricter reference, and
the same scene as ``bench/walkable_map.py``'s) or goes through reconstruct too (``sfm``). Reports
per capture: frames registered of given, pose agreement with the ground truth after Sim(3), the
training seconds, held-out PSNR with the mean appearance embedding and with the half-image
protocol (the embedding fitted on the left half, the right half scored), and the gap between the
two captures. ``--quick``: 100 frames at 160x120 and a 300-step tiny train-scene (a path check).

The last line is one JSON object with ``heldout_psnr_half_phone``, ``heldout_psnr_half_clean``,
``gap_db``, ``registered_fraction_phone``, ``train_s_phone`` and the per-capture rows.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from real_capture import estimated_poses, heldout_scores, nsim, pose_agreement, reference_poses  # noqa: E402

from nsim.workspace.store import Store  # noqa: E402


def one_capture(ws: Path, log: Path, preset: str, room: str, quick: bool, train_preset: str,
                steps: int | None, sfm: bool = True) -> dict[str, Any]:
    sets = ["--set", "n_frames=100", "--set", "width=160", "--set", "height=120", "--set", "video=false"] if quick else []
    cap, cap_s, _ = nsim(ws, "capture", "synth", "--preset", preset, "--room", room, *sets,
                         "--tag", f"capture/{preset}-{room}", log=log)
    store = Store(ws)
    cap_dir = store.get(cap).path
    n_frames = store.get(cap).manifest["config"]["n_frames"]
    row: dict[str, Any] = {"capture": cap[:12], "capture_s": round(cap_s, 1), "poses": "ground truth"}
    poses = cap  # the capture's own exact poses
    if sfm:
        poses, rec_s, _ = nsim(ws, "reconstruct", cap, "--reference", str(cap_dir / "gt_trajectory.tum"),
                               "--frames", str(n_frames), "--tag", f"poses/{preset}-{room}", log=log)
        report = json.loads(store.get(poses).file("report.json").read_text())
        given = report.get("images_given", report.get("frames_given"))
        used = report.get("images_registered", report.get("frames", given))
        row.update(poses=poses[:12], reconstruct_s=round(rec_s, 1), images_given=given, images_registered=used,
                   registered_fraction=round(used / given, 4) if given else None)
        row.update(pose_agreement(estimated_poses(store, poses), reference_poses(cap_dir / "transforms.json")))
    step_args = ["--steps", str(steps)] if steps else []
    scene, wall, rss = nsim(ws, "train-scene", "--preset", train_preset, "--poses", poses, *step_args,
                            "--tag", f"scene/{preset}-{room}", log=log)
    timing = store.get(scene).manifest.get("timing", {})
    scores = heldout_scores(store, scene)
    row.update(scene=scene[:12], train_s=round(float(timing.get("train_seconds", float("nan"))), 1),
               train_scene_wall_s=round(wall, 1), peak_rss_gb=round(rss, 2),
               heldout_psnr=scores.get("psnr"), heldout_ssim=scores.get("ssim"), heldout_lpips=scores.get("lpips"),
               heldout_psnr_half=next((v for k, v in scores.items() if "psnr" in k and "half" in k), None),
               protocols=scores.get("protocols"))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--room", default="robot-lab", help="test-room preset")
    ap.add_argument("--workspace", type=Path, default=None, help="keep the workspace here (default: a temp dir)")
    ap.add_argument("--preset", default="cpu", help="train-scene preset")
    ap.add_argument("--steps", type=int, default=None, help="train-scene steps (default: the preset's)")
    ap.add_argument("--clean-poses", choices=("gt", "sfm"), default="gt",
                    help="the clean capture trains on its exact poses (gt: the stricter reference, and the scene "
                         "bench/walkable_map.py trains) or on reconstruct's (sfm)")
    ap.add_argument("--quick", action="store_true", help="100 frames at 160x120, 300 steps (a path check)")
    args = ap.parse_args()
    train_preset, steps = ("tiny", args.steps or 300) if args.quick else (args.preset, args.steps)
    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        log = Path(tmp) / "nsim.log" if args.workspace is None else ws.with_suffix(".log")
        rows = {}
        for name, preset in (("clean", "default"), ("phone", "phone")):
            rows[name] = one_capture(ws, log, preset, args.room, args.quick, train_preset, steps,
                                     sfm=name == "phone" or args.clean_poses == "sfm")
            r = rows[name]
            print(f"{name:6s} registered {r.get('images_registered')}/{r.get('images_given')}  rot {r.get('rot_err_deg')}  "
                  f"train {r['train_s']} s  PSNR mean {r['heldout_psnr']}  half {r['heldout_psnr_half']}", flush=True)
    half_p, half_c = rows["phone"]["heldout_psnr_half"], rows["clean"]["heldout_psnr_half"]
    print(json.dumps({"bench": "phone_capture", "quick": args.quick, "room": args.room, "train_preset": train_preset,
                      "steps": steps, "heldout_psnr_half_phone": half_p, "heldout_psnr_half_clean": half_c,
                      "gap_db": round(half_c - half_p, 3) if half_p is not None and half_c is not None else None,
                      "registered_fraction_phone": rows["phone"]["registered_fraction"],
                      "train_s_phone": rows["phone"]["train_s"], "rows": rows}))


if __name__ == "__main__":
    main()
