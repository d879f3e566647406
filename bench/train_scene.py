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
depth, as z-depth against the capture's EXR depth. Prints a table, writes a PNG of the curves
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
from nsim.stages import capture  # noqa: E402
from nsim.train.scene import (  # noqa: E402
    SceneData,
    TrainSceneConfig,
    _spread,
    abs_rel,
    bake_occupancy,
    constant_color_psnr,
    image_metrics,
    psnr,
    train_scene,
)
from nsim.workspace.store import Store  # noqa: E402


def make_capture(root: Path, quick: bool) -> Path:
    cfg = load_config(capture.Config, stage="capture", preset="tiny" if quick else "default",
                      overrides=["video=false"])
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
        rows.append({**image_metrics(view.rgb, gt.rgb), "abs_rel_median": abs_rel(view.depth_median_z, gt.depth_z),
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
    dense_cfg = MarchConfig(step_m=march_step_m, stop_transmittance=0.0, color_weight_threshold=0.0)
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


def plot(path: Path, curve: list[dict], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), dpi=90)
    t = [c["seconds"] for c in curve]
    for ax, key, label in zip(axes, ("psnr", "ssim", "abs_rel_median"), ("held-out PSNR (dB)", "held-out SSIM",
                                                                         "depth AbsRel (median)"), strict=True):
        ax.plot(t, [c[key] for c in curve], "o-")
        ax.set_xlabel("training seconds")
        ax.set_title(label)
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--preset", default=None, help="train_scene preset (default: cpu, tiny with --quick)")
    ap.add_argument("--set", action="append", default=[], help="config override key=value (repeatable)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--evals", type=int, default=8, help="evaluations during training")
    ap.add_argument("--eval-views", type=int, default=4, help="held-out views per evaluation during training")
    ap.add_argument("--off-path-views", type=int, default=4)
    ap.add_argument("--speed-rays", type=int, default=4096)
    ap.add_argument("--workspace", type=Path, default=None, help="reuse captures here (default: a temp dir)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out" / "train_scene.png")
    args = ap.parse_args()
    preset = args.preset or ("tiny" if args.quick else "cpu")
    overrides = [f"optim.num_threads={args.threads}", *args.set]
    cfg = load_config(TrainSceneConfig, stage="train_scene", preset=preset, overrides=overrides)
    torch.set_num_threads(args.threads)

    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        cap_dir = make_capture(ws, args.quick)
        data = SceneData.load(cap_dir)
        held = [int(i) for i in data.split(cfg.data.holdout_every)[1]]
        views = _spread(held, args.eval_views)
        every = max(1, cfg.optim.steps // max(1, args.evals))
        curve: list[dict] = []

        def on_log(trainer, stats):
            if trainer.step % every == 0 and trainer.step < cfg.optim.steps:
                ev = trainer.evaluate(views)["mean"]
                curve.append({"step": trainer.step, "seconds": trainer.train_seconds, **ev})
                print(f"  step {trainer.step:6d} {trainer.train_seconds:8.1f} s  PSNR {ev['psnr']:6.2f}  "
                      f"SSIM {ev['ssim']:.3f}  AbsRel {ev.get('abs_rel_median', float('nan')):.4f}", flush=True)

        log_every = math.gcd(every, cfg.output.log_every)
        cfg = from_dict(TrainSceneConfig, {**json.loads(json.dumps(_to_plain(cfg))),
                                           "output": {**_to_plain(cfg.output), "log_every": log_every,
                                                      "checkpoint_every": cfg.optim.steps}})
        t_wall = time.perf_counter()
        result = train_scene(data, cfg, Path(tmp) / "work", device="cpu", seed=0, on_log=on_log)
        wall_s = time.perf_counter() - t_wall
        trainer = result.trainer
        final = trainer.evaluate(held)["mean"]
        curve.append({"step": trainer.step, "seconds": trainer.train_seconds, **final})
        baseline = constant_color_psnr(data, cfg.data.holdout_every)

        # off the capture path, scored against the oracle
        import json as _json

        from nsim.synth.oracle import RoomOracle
        from nsim.synth.room import RoomSpec

        oracle = RoomOracle(RoomSpec.from_dict(_json.loads((cap_dir / "room.json").read_text())["spec"]))
        model = trainer.model.eval()
        t0 = time.perf_counter()
        grid = bake_occupancy(trainer)
        bake_s = time.perf_counter() - t0
        off = score_off_path(model, oracle, data, off_path_poses(data, _spread(held, args.off_path_views)))
        off_grid = score_off_path(model, oracle, data, off_path_poses(data, _spread(held, args.off_path_views)),
                                  method="march", grid=grid)
        speed = render_speed(model, grid, data, held[len(held) // 2], args.speed_rays, 0.01)

    title = f"train_scene preset={preset}, {data.n_frames} frames {data.size_hw[1]}x{data.size_hw[0]}, {args.threads} threads"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    plot(args.out, curve, title)
    print()
    print(title)
    print(f"{'step':>6} {'train s':>8} {'PSNR':>7} {'SSIM':>6} {'AbsRel med':>10} {'AbsRel exp':>10}")
    for c in curve:
        print(f"{c['step']:6d} {c['seconds']:8.1f} {c['psnr']:7.2f} {c['ssim']:6.3f} "
              f"{c.get('abs_rel_median', float('nan')):10.4f} {c.get('abs_rel_expected', float('nan')):10.4f}")
    print()
    print(f"held-out (all {len(held)} views)      PSNR {final['psnr']:.2f}  SSIM {final['ssim']:.3f}  "
          f"AbsRel median {final.get('abs_rel_median', float('nan')):.4f}  expected {final.get('abs_rel_expected', float('nan')):.4f}")
    print(f"off-path (0.5-0.7 m, 30 cm aside)  PSNR {off['psnr']:.2f}  SSIM {off['ssim']:.3f}  AbsRel median {off['abs_rel_median']:.4f}"
          f"   (marching + grid: PSNR {off_grid['psnr']:.2f})")
    print(f"constant-colour baseline PSNR {baseline:.2f}")
    print(f"training wall {wall_s:.1f} s (train clock {trainer.train_seconds:.1f} s), occupancy bake {bake_s:.1f} s, "
          f"occupied {grid.occupied_fraction:.3f}")
    print(f"render rays/s: proposal {speed['proposal_rays_per_s']:.0f}, march dense {speed['march_dense_rays_per_s']:.0f}, "
          f"march + grid {speed['march_grid_rays_per_s']:.0f} (x{speed['grid_speedup']:.1f}); "
          f"PSNR grid vs dense {speed['psnr_grid_vs_dense']:.1f} dB, march vs proposal {speed['psnr_march_vs_proposal']:.1f} dB")
    print(f"curves: {args.out}")
    summary = {
        "preset": preset, "threads": args.threads, "frames": data.n_frames, "steps": trainer.step,
        "train_seconds": round(trainer.train_seconds, 1), "wall_seconds": round(wall_s, 1),
        "heldout": {k: round(v, 4) for k, v in final.items()},
        "off_path": {k: round(v, 4) for k, v in off.items()},
        "off_path_march_grid_psnr": round(off_grid["psnr"], 3),
        "constant_color_psnr": round(baseline, 3),
        "curve": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items()} for c in curve],
        "render": {k: round(v, 2) for k, v in speed.items()},
        "occupancy_bake_seconds": round(bake_s, 1),
    }
    print(json.dumps(summary))


def _to_plain(cfg):
    from nsim.config import to_dict

    return to_dict(cfg)


if __name__ == "__main__":
    main()
