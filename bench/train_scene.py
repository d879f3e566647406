"""The scene NeRF on the test room: quality against wall-clock seconds, and rendering speed.

    python bench/train_scene.py [--quick] [--preset cpu] [--threads 2] [--workspace DIR]

Full run: the default capture (150 frames, 320x240, GT poses) and the ``cpu`` preset (the
10-minute claim). ``--quick``: the tiny capture and the ``tiny`` preset (under a minute).

Measures, on this machine:

1. training: held-out PSNR / SSIM / depth AbsRel (every 8th frame; a few views during
   training, all at the end) against training seconds (evaluation time is not counted);
2. off-path views: the oracle renders the room from poses off the capture path (camera
   30 cm to the side of a held-out pose, at a height of 0.5-0.7 m, level) and the model is
   scored there too;
3. rendering: rays/s of the proposal renderer, of dense marching (no grid, no early stop)
   and of marching with the baked occupancy grid, and the PSNR between the dense and the
   grid images (the grid must not change the image).

Depth AbsRel is reported for the *median* depth (the headline) and the normalised expected
depth, as z-depth against the capture's EXR depth (``nsim.metrics.depth.abs_rel``: ground truth
in [1 mm, 10 m], the prediction clamped into that range). Prints a table, writes a PNG of the curves
(``--out``, default ``bench/out/train_scene.png``) and ends with one JSON object on the last line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from nsim.config import from_dict, load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.metrics.depth import abs_rel  # noqa: E402
from nsim.metrics.image import psnr  # noqa: E402
from nsim.stages import capture  # noqa: E402
from nsim.train.loop import spread  # noqa: E402
from nsim.train.scene import SceneData, train_scene  # noqa: E402
from nsim.train.scene_config import TrainSceneConfig  # noqa: E402
from nsim.train.scene_eval import constant_color_psnr, image_scores  # noqa: E402
from nsim.train.scene_export import bake_occupancy  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def make_capture(root: Path, quick: bool, overrides: tuple[str, ...] = ()) -> Path:
    cfg = load_config(capture.Config, stage="capture", preset="tiny" if quick else "default",
                      overrides=["video=false", *overrides])
    store = Store(root)
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    return store.get(capture.run(capture.Inputs(), cfg, ctx).capture).path


def off_path_poses(data: SceneData, frames: list[int], seed: int = 0) -> list[np.ndarray]:
    """Poses 30 cm to the side of the given frames (alternating left / right), camera level
    (no pitch or roll, same heading), at a height drawn from [0.5, 0.7] m."""
    rng = np.random.default_rng(seed)
    out = []
    for k, i in enumerate(frames):
        c2w = data.cam_to_world[i]
        fwd = c2w[:3, 2].copy()
        fwd[2] = 0.0
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])  # OpenCV +x: to the right of +z (forward) in a z-up world
        down = np.array([0.0, 0.0, -1.0])
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, down, fwd
        side = 0.3 if k % 2 == 0 else -0.3
        pose[:3, 3] = c2w[:3, 3] + side * right
        pose[2, 3] = rng.uniform(0.5, 0.7)
        out.append(pose)
    return out


def score_off_path(model, oracle, data: SceneData, poses, method="proposal", grid=None) -> dict[str, float]:
    from nsim.rendering.renderer import render_camera

    cam = data.cameras[0]
    rows = []
    for pose in poses:
        gt = oracle.render_gt(cam, pose, supersample=2)
        view = render_camera(model, cam, pose, method=method, grid=grid)
        rows.append({**image_scores(view.rgb, gt.rgb, "none"), "abs_rel_median": abs_rel(view.depth_median_z, gt.depth_z),
                     "abs_rel_expected": abs_rel(view.depth_z, gt.depth_z)})
    return {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}


def render_speed(model, grid, data: SceneData, frame: int, n_rays: int, march_step_m: float) -> dict[str, float]:
    """rays/s of the three renderers on ``n_rays`` pixels of one view, and dense-vs-grid PSNR on them."""
    from nsim.rendering.renderer import MarchConfig, camera_rays, render_rays

    rays, _, _ = camera_rays(model, data.cameras[0], data.cam_to_world[frame])
    g = torch.Generator().manual_seed(0)
    pick = torch.randperm(len(rays), generator=g)[:n_rays]
    sub = rays[pick]
    out = {}
    dense_cfg = MarchConfig(step_m=march_step_m, stop_transmittance=0.0, color_skip_weight=0.0)
    fast_cfg = MarchConfig(step_m=march_step_m)
    t0 = time.perf_counter()
    prop = render_rays(model, sub, "proposal", chunk=4096)
    out["proposal_rays_per_s"] = n_rays / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    dense = render_rays(model, sub, "march", None, dense_cfg, chunk=1024)
    out["march_dense_rays_per_s"] = n_rays / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    fast = render_rays(model, sub, "march", grid, fast_cfg, chunk=4096)
    out["march_grid_rays_per_s"] = n_rays / (time.perf_counter() - t0)
    out["grid_speedup"] = out["march_grid_rays_per_s"] / out["march_dense_rays_per_s"]
    out["psnr_grid_vs_dense"] = psnr(fast.rgb.clamp(0, 1).numpy(), dense.rgb.clamp(0, 1).numpy())
    out["psnr_march_vs_proposal"] = psnr(fast.rgb.clamp(0, 1).numpy(), prop.rgb.clamp(0, 1).numpy())
    return out


def plot(path: Path, results: dict[str, dict], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), dpi=90)
    for label, r in results.items():
        curve = r["curve"]
        t = [c["seconds"] for c in curve]
        for ax, key in zip(axes, ("psnr", "ssim", "abs_rel_median"), strict=True):
            ax.plot(t, [c.get(key, float("nan")) for c in curve], "o-", label=f"{label} poses")
    for ax, label in zip(axes, ("held-out PSNR (dB)", "held-out SSIM", "depth AbsRel (median)"), strict=True):
        ax.set_xlabel("training seconds")
        ax.set_title(label)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def reconstructed_data(ws: Path, cap_dir: Path, quick: bool) -> SceneData:
    """Poses from ``nsim reconstruct`` on the capture's frames (metric via the ground-truth TUM
    as odometry), with the capture's depth EXRs attached by frame name (for scoring only)."""
    from nsim.stages import reconstruct

    store = Store(ws)
    cap_id = next(a.id for a in store.artifacts() if a.path == cap_dir)
    n = json.loads((cap_dir / "manifest.json").read_text())["config"]["n_frames"]
    cfg = load_config(reconstruct.Config, stage="reconstruct", preset="tiny" if quick else "default",
                      overrides=[f"frames={n}"])
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    out = reconstruct.run(reconstruct.Inputs(capture=cap_id, reference=cap_dir / "gt_trajectory.tum"), cfg, ctx)
    data = SceneData.load(store.get(out.poses).path)
    data.source_id = out.poses
    cap = SceneData.load(cap_dir)
    by_name = {Path(nm).name: dp for nm, dp in zip(cap.names, cap.depth_paths, strict=True)}
    data.depth_paths = [by_name.get(Path(nm).name) for nm in data.names]
    return data


def bench_one(label: str, data: SceneData, cfg: TrainSceneConfig, oracle, args, work: Path, ws: Path) -> dict:
    """Train on ``data``, score held-out and off-path views, time the renderers; print a table.

    The trained model is also published to the workspace as the ``train_scene`` stage would
    (same action key) and tagged ``scene/bench-<label>``, so ``bench/render.py --workspace`` reuses it."""
    held = [int(i) for i in data.split(cfg.data.holdout_every)[1]]
    views = spread(held, args.eval_views)
    every = max(1, cfg.optim.steps // max(1, args.evals))
    curve: list[dict] = []

    def on_log(trainer, stats):
        if trainer.step % every == 0 and trainer.step < cfg.optim.steps:
            ev = trainer.evaluate(views)["mean"]
            curve.append({"step": trainer.step, "seconds": trainer.train_seconds, **ev})
            print(f"  [{label}] step {trainer.step:6d} {trainer.train_seconds:8.1f} s  PSNR {ev['psnr']:6.2f}  "
                  f"SSIM {ev['ssim']:.3f}  AbsRel {ev.get('abs_rel_median', float('nan')):.4f}", flush=True)

    log_every = math.gcd(every, cfg.output.log_every)
    cfg = from_dict(TrainSceneConfig, {**_to_plain(cfg), "output": {**_to_plain(cfg.output), "log_every": log_every,
                                                                  "checkpoint_every": cfg.optim.steps}})
    t_wall = time.perf_counter()
    result = train_scene(data, cfg, work, device="cpu", seed=0, on_log=on_log)
    wall_s = time.perf_counter() - t_wall
    trainer = result.trainer
    from nsim.stages import train_scene as stage

    ctx = RunContext(store=Store(ws), device_spec="cpu", seed=0, progress=False)
    inputs = stage.Inputs(poses=data.source_id)
    scene_id = stage.publish(ctx, stage.action_key(inputs, cfg, ctx), inputs, cfg,
                             ctx.store.get(data.source_id).kind, data, result)
    ctx.store.set_ref(f"scene/bench-{label.split()[0]}", scene_id)
    torch.set_num_threads(args.render_threads)
    final = trainer.evaluate(held)["mean"]
    curve.append({"step": trainer.step, "seconds": trainer.train_seconds, **final})
    baseline = constant_color_psnr(data, cfg.data.holdout_every)
    model = trainer.model.eval()
    t0 = time.perf_counter()
    grid = bake_occupancy(trainer)
    bake_s = time.perf_counter() - t0
    poses = off_path_poses(data, spread(held, args.off_path_views))
    off = score_off_path(model, oracle, data, poses)
    off_grid = score_off_path(model, oracle, data, poses, method="march", grid=grid)
    speed = render_speed(model, grid, data, held[len(held) // 2], args.speed_rays, 0.01)

    print()
    print(f"[{label}] {data.n_frames} frames {data.size_hw[1]}x{data.size_hw[0]}")
    print(f"{'step':>6} {'train s':>8} {'PSNR':>7} {'SSIM':>6} {'AbsRel med':>10} {'AbsRel exp':>10}")
    for c in curve:
        print(f"{c['step']:6d} {c['seconds']:8.1f} {c['psnr']:7.2f} {c['ssim']:6.3f} "
              f"{c.get('abs_rel_median', float('nan')):10.4f} {c.get('abs_rel_expected', float('nan')):10.4f}")
    print(f"held-out (all {len(held)} views)      PSNR {final['psnr']:.2f}  SSIM {final['ssim']:.3f}  "
          f"AbsRel median {final.get('abs_rel_median', float('nan')):.4f}  "
          f"expected {final.get('abs_rel_expected', float('nan')):.4f}")
    print(f"off-path (0.5-0.7 m, 30 cm aside)  PSNR {off['psnr']:.2f}  SSIM {off['ssim']:.3f}  "
          f"AbsRel median {off['abs_rel_median']:.4f}   (marching + grid: PSNR {off_grid['psnr']:.2f})")
    print(f"constant-colour baseline PSNR {baseline:.2f}")
    print(f"training wall {wall_s:.1f} s (train clock {trainer.train_seconds:.1f} s), occupancy bake {bake_s:.1f} s, "
          f"occupied {grid.occupied_fraction:.3f}")
    print(f"render rays/s: proposal {speed['proposal_rays_per_s']:.0f}, march dense {speed['march_dense_rays_per_s']:.0f}, "
          f"march + grid {speed['march_grid_rays_per_s']:.0f} (x{speed['grid_speedup']:.1f}); "
          f"PSNR grid vs dense {speed['psnr_grid_vs_dense']:.1f} dB, march vs proposal {speed['psnr_march_vs_proposal']:.1f} dB")
    print(flush=True)
    return {
        "frames": data.n_frames, "steps": trainer.step,
        "train_seconds": round(trainer.train_seconds, 1), "wall_seconds": round(wall_s, 1),
        "heldout": {k: round(v, 4) for k, v in final.items()},
        "off_path": {k: round(v, 4) for k, v in off.items()},
        "off_path_march_grid_psnr": round(off_grid["psnr"], 3),
        "constant_color_psnr": round(baseline, 3),
        "occupied_fraction": round(grid.occupied_fraction, 4),
        "curve": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items()} for c in curve],
        "render": {k: round(v, 2) for k, v in speed.items()},
        "occupancy_bake_seconds": round(bake_s, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--preset", default=None, help="train_scene preset (default: cpu, tiny with --quick)")
    ap.add_argument("--set", action="append", default=[], help="config override key=value (repeatable)")
    ap.add_argument("--poses", choices=("gt", "reconstruct", "both"), default=None,
                    help="ground-truth poses, poses from nsim reconstruct, or both (default: both; gt with --quick)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads for training (default: the preset's "
                    "optim.num_threads; the cpu preset uses one per op and its second core through "
                    "optim.batch_threads)")
    ap.add_argument("--render-threads", type=int, default=2, help="torch threads for the final scoring and the "
                    "rendering speed test (default 2: big render chunks do use both cores)")
    ap.add_argument("--evals", type=int, default=None, help="evaluations during training (default 8, 2 with --quick)")
    ap.add_argument("--eval-views", type=int, default=4, help="held-out views per evaluation during training")
    ap.add_argument("--off-path-views", type=int, default=4)
    ap.add_argument("--speed-rays", type=int, default=None, help="rays for the speed test (default 4096, 1024 quick)")
    ap.add_argument("--workspace", type=Path, default=None, help="reuse captures here (default: a temp dir)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out" / "train_scene.png")
    args = ap.parse_args()
    preset = args.preset or ("tiny" if args.quick else "cpu")
    poses_mode = args.poses or ("gt" if args.quick else "both")
    args.evals = args.evals if args.evals is not None else (2 if args.quick else 8)
    args.speed_rays = args.speed_rays or (1024 if args.quick else 4096)
    overrides = [*([f"optim.num_threads={args.threads}"] if args.threads else []),
                 *(["optim.steps=300"] if args.quick else []), *args.set]
    cfg = load_config(TrainSceneConfig, stage="train_scene", preset=preset, overrides=overrides)
    args.threads = cfg.optim.num_threads or torch.get_num_threads()
    torch.set_num_threads(args.threads)
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.room import RoomSpec

    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        cap_dir = make_capture(ws, args.quick)
        oracle = RoomOracle(RoomSpec.from_dict(json.loads((cap_dir / "room.json").read_text())["spec"]))
        if poses_mode in ("gt", "both"):
            data = SceneData.load(cap_dir)
            data.source_id = next(a.id for a in Store(ws).artifacts() if a.path == cap_dir)
            results["gt"] = bench_one("gt poses", data, cfg, oracle, args, Path(tmp) / "work_gt", ws)
        if poses_mode in ("reconstruct", "both"):
            t0 = time.perf_counter()
            data = reconstructed_data(ws, cap_dir, args.quick)
            rec_s = time.perf_counter() - t0
            results["reconstruct"] = {"reconstruct_seconds": round(rec_s, 1),
                                      **bench_one("reconstructed poses", data, cfg, oracle, args, Path(tmp) / "work_rec", ws)}

    title = (f"train_scene preset={preset}, {args.threads} torch thread(s) x {cfg.optim.batch_threads} batch thread(s) "
             f"training, {args.render_threads} rendering")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    plot(args.out, results, title)
    print(title)
    print(f"{'poses':<12} {'train s':>8} {'PSNR':>7} {'SSIM':>6} {'AbsRel med':>10} {'AbsRel exp':>10} "
          f"{'off-path PSNR':>13} {'grid x':>7} {'grid-vs-dense dB':>16}")
    for label, r in results.items():
        h = r["heldout"]
        print(f"{label:<12} {r['train_seconds']:8.1f} {h['psnr']:7.2f} {h['ssim']:6.3f} {h.get('abs_rel_median', float('nan')):10.4f} "
              f"{h.get('abs_rel_expected', float('nan')):10.4f} {r['off_path']['psnr']:13.2f} "
              f"{r['render']['grid_speedup']:7.1f} {r['render']['psnr_grid_vs_dense']:16.1f}")
    print(f"curves: {args.out}")
    print(json.dumps({"preset": preset, "threads": args.threads, "batch_threads": cfg.optim.batch_threads,
                      "render_threads": args.render_threads, **results}))


def _to_plain(cfg) -> dict:
    from nsim.config import to_dict

    return to_dict(cfg)


if __name__ == "__main__":
    main()
