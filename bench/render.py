"""``nsim render`` on the test room: accuracy against the oracle, Spot's cameras, speed.

    python bench/render.py [--quick] [--workspace DIR] [--scene REF] [--ticks N] [--image-scale S]

Uses the default capture (robot-lab, 320x240, ground-truth poses) and a scene checkpoint:
``--scene REF``, else ``scene/bench-gt`` in ``--workspace`` (what ``bench/train_scene.py
--workspace DIR`` publishes), else it trains one with the train_scene ``cpu`` preset.
``--quick``: the tiny capture and a 300-step ``tiny`` scene (under a minute or two).

Measures, with the same renderer the stage uses (marching + occupancy grid):

1. held-out capture views (``nsim render --poses``, ``frames=heldout``): PSNR / SSIM against
   the captured images, depth AbsRel of the median depth against the capture's z-depth, beside
   train-scene's own held-out PSNR (``eval.json``; the proposal renderer);
2. LiDAR: Spot's VLP-16-like LiDAR along the simulated ``spot_run``, no noise, against the
   oracle's exact scan from the same poses: median / p95 range error where both return;
3. Spot's five fisheye cameras along ``spot_run`` against the oracle's images from the same
   poses: a per-camera PSNR / SSIM / depth AbsRel table (the paper's Table III reached
   9.4-11.8 dB on its real Spot);
4. speed: camera and LiDAR rays/s in-process on 2 cores, and the wall time of the same render
   on Ray with 2 workers against 1.

Prints tables and one JSON object on the last line.
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

from nsim.config import configs_dir, from_dict, load_config, to_dict  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.stages import capture, render, simulate, train_scene  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402

SPOT = configs_dir() / "robots" / "spot.yaml"


def abs_rel(pred: np.ndarray, gt: np.ndarray) -> float:
    ok = np.isfinite(pred) & np.isfinite(gt) & (gt > 0.05)
    return float(np.mean(np.abs(pred[ok] - gt[ok]) / gt[ok])) if ok.any() else float("nan")


def psnr_ssim(pred_u8: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    from nsim.metrics.image import psnr, ssim

    p = pred_u8.astype(np.float32) / 255.0
    g = np.clip(gt.astype(np.float32), 0, 1)
    return float(psnr(p, g)), float(ssim(p, g))


def get_scene(ctx: RunContext, cap_id: str, scene: str | None, quick: bool) -> str:
    store = ctx.store
    if scene is not None:
        return store.resolve(scene, kind="scene-checkpoint")
    try:
        return store.resolve("scene/bench-gt", kind="scene-checkpoint")
    except Exception:  # noqa: BLE001 - not there: train one
        pass
    overrides = ["optim.steps=300"] if quick else []
    cfg = load_config(train_scene.Config, stage="train_scene", preset="tiny" if quick else "cpu", overrides=overrides)
    t0 = time.perf_counter()
    out = train_scene.run(train_scene.Inputs(poses=cap_id), cfg, ctx)
    print(f"trained a scene checkpoint in {time.perf_counter() - t0:.0f} s", flush=True)
    return out.scene


def heldout(ctx: RunContext, cap_id: str, scene_id: str, method: str, max_views: int | None, step_m: float) -> dict:
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_image
    from nsim.io.transforms_json import read_transforms

    store = ctx.store
    cfg = from_dict(render.Config, {"frames": "heldout", "video": False, "method": method, "max_frames": max_views,
                                    "march": {"step_m": step_m}})
    ctx.force = True  # timed: render even if an earlier run is cached
    t0 = time.perf_counter()
    out = render.run(render.Inputs(poses=cap_id, scene=scene_id), cfg, ctx)
    wall = time.perf_counter() - t0
    ctx.force = False
    art, cap = store.get(out.render), store.get(cap_id)
    frames = json.loads(art.file("render.json").read_text())["frames"]
    tf = read_transforms(cap.file("transforms.json")).frames
    rows = []
    for f in frames:
        i = f["index"]
        pred = read_image(art.file(f"frames/rgb/{i:06d}.png"))
        gt = read_image(cap.path / tf[i].file_path).astype(np.float32) / 255.0
        p, s = psnr_ssim(pred, gt)
        d = read_depth_exr(art.file(f"frames/depth/{i:06d}.exr"))
        dg = read_depth_exr(cap.path / tf[i].depth_file_path)
        rows.append({"frame": i, "psnr": p, "ssim": s, "abs_rel": abs_rel(d, dg)})
    ev = json.loads(store.get(scene_id).file("eval.json").read_text())
    same = [v for v in ev["views"] if v["frame"] in {r["frame"] for r in rows}]
    n_rays = sum(tf[f["index"]].camera.width * tf[f["index"]].camera.height for f in frames)
    return {"method": method, "views": len(rows), "psnr": float(np.mean([r["psnr"] for r in rows])),
            "ssim": float(np.mean([r["ssim"] for r in rows])),
            "abs_rel_median_depth": float(np.mean([r["abs_rel"] for r in rows])),
            "train_scene_heldout_psnr_same_views": float(np.mean([v["psnr"] for v in same])) if same else float("nan"),
            "render_wall_s": wall, "camera_rays_per_s": n_rays / wall}


def spot_run(ctx: RunContext, quick: bool) -> str:
    from nsim.crowd.scenario import load_scenario

    cfg = load_config(simulate.Config, stage="simulate", preset="tiny" if quick else "default",
                      overrides=["video=false"])
    sc = load_scenario(configs_dir() / "scenarios" / "spot_run.json", store=ctx.store)
    return simulate.run(simulate.Inputs(sc), cfg, ctx).trajectory


def spot_render(ctx: RunContext, traj: str, scene_id: str, args, sensors: tuple[str, ...], engine=None,
                force: bool = False) -> tuple[str, float]:
    cfg = from_dict(render.Config, {
        "tick_stride": args.tick_stride, "max_frames": args.ticks, "image_scale": args.image_scale,
        "lidar_azimuth_scale": args.lidar_scale, "noise": False, "video": False, "sensors": list(sensors),
        "shard_frames": max(1, args.ticks // 4), "method": args.method, "march": {"step_m": args.march_step}})
    ctx.force = force
    t0 = time.perf_counter()
    out = render.run(render.Inputs(trajectory=traj, scene=scene_id, rig=SPOT), cfg, ctx, engine=engine)
    ctx.force = False
    return out.render, time.perf_counter() - t0


def score_spot(ctx: RunContext, art_id: str, oracle) -> dict:
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_image
    from nsim.io.lidar_exr import read_lidar_exr
    from nsim.sensors.rig import Rig

    art = ctx.store.get(art_id)
    meta = json.loads(art.file("render.json").read_text())
    rig = Rig.from_resolved(json.loads(art.file("rig.json").read_text()))
    from nsim.io.tum import read_tum

    body = read_tum(art.file("robot.tum")).poses_se3()
    table: dict[str, dict] = {}
    lidar_err = []
    for f, T in zip(meta["frames"], body, strict=True):
        i = f["index"]
        for s in rig.sensors:
            if s.type == "lidar":
                scan = read_lidar_exr(art.file(f"{s.name}/scan/{i:06d}.exr"))
                gt = oracle.lidar_gt(s.world_pose(T), s.config)
                both = np.isfinite(scan.range_m) & np.isfinite(gt.ranges_m)
                lidar_err.append(np.abs(scan.range_m[both] - gt.ranges_m[both]))
                row = table.setdefault(s.name, {"hit_agreement": []})
                row["hit_agreement"].append(float(np.mean(np.isfinite(scan.range_m) == np.isfinite(gt.ranges_m))))
                continue
            view = oracle.render_gt(s.camera, s.world_pose(T), supersample=2)
            pred = read_image(art.file(f"{s.name}/rgb/{i:06d}.png"))
            valid = np.isfinite(view.depth_range)
            gt_rgb = np.where(valid[..., None], view.rgb, 0.0)
            p, ss = psnr_ssim(np.where(valid[..., None], pred, 0).astype(np.uint8), gt_rgb)
            d = read_depth_exr(art.file(f"{s.name}/depth/{i:06d}.exr"))
            row = table.setdefault(s.name, {"psnr": [], "ssim": [], "abs_rel": []})
            row["psnr"].append(p)
            row["ssim"].append(ss)
            row["abs_rel"].append(abs_rel(d, view.depth_z))
    out = {name: {k: float(np.nanmean(v)) for k, v in row.items()} for name, row in table.items()}
    errs = np.concatenate(lidar_err) if lidar_err else np.zeros(0)
    lidar = {"median_range_error_m": float(np.median(errs)) if errs.size else float("nan"),
             "p95_range_error_m": float(np.percentile(errs, 95)) if errs.size else float("nan"), "returns": int(errs.size)}
    return {"cameras": out, "lidar": lidar, "ticks": len(meta["frames"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workspace", type=Path, default=None)
    ap.add_argument("--scene", default=None, help="scene checkpoint to use (default: scene/bench-gt, else train one)")
    ap.add_argument("--ticks", type=int, default=None, help="ticks of spot_run to render (default 12, 2 quick)")
    ap.add_argument("--tick-stride", type=int, default=None, help="every k-th tick (default 10)")
    ap.add_argument("--image-scale", type=float, default=None, help="Spot camera scale (default 0.5 = 320x240, 0.1 quick)")
    ap.add_argument("--lidar-scale", type=float, default=None, help="LiDAR azimuth scale (default 0.5, 0.05 quick)")
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray 1-vs-2 worker timing")
    ap.add_argument("--method", default="proposal", choices=("proposal", "march"), help="renderer for the Spot run")
    ap.add_argument("--march-step", type=float, default=0.02, help="march step (m) where marching is measured")
    args = ap.parse_args()
    q = args.quick
    args.ticks = args.ticks or (2 if q else 12)
    args.tick_stride = args.tick_stride or 10
    args.image_scale = args.image_scale or (0.1 if q else 0.5)
    args.lidar_scale = args.lidar_scale or (0.05 if q else 0.5)
    import torch

    torch.set_num_threads(2)
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        store = Store(ws)
        ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
        cap_cfg = load_config(capture.Config, stage="capture", preset="tiny" if q else "default", overrides=["video=false"])
        cap_id = capture.run(capture.Inputs(), cap_cfg, ctx).capture
        cap = store.get(cap_id)
        scene_id = get_scene(ctx, cap_id, args.scene, q)
        from nsim.synth.oracle import RoomOracle
        from nsim.synth.room import RoomSpec

        oracle = RoomOracle(RoomSpec.from_dict(json.loads(cap.file("room.json").read_text())["spec"]))

        results["heldout"] = {}
        for method, views, step in (("proposal", None, 0.01), ("march", 2, args.march_step)):
            h = heldout(ctx, cap_id, scene_id, method, views, step)
            results["heldout"][method] = h
            print(f"held-out capture views, {method} ({h['views']}): PSNR {h['psnr']:.2f} dB (train-scene's held-out "
                  f"PSNR on the same views {h['train_scene_heldout_psnr_same_views']:.2f}), SSIM {h['ssim']:.3f}, "
                  f"depth AbsRel (median) {h['abs_rel_median_depth']:.4f}; {h['camera_rays_per_s']:.0f} rays/s", flush=True)

        traj = spot_run(ctx, q)
        names = tuple(s.name for s in __import__("nsim.sensors.rig", fromlist=["Rig"]).Rig.load(SPOT).sensors)
        cams = tuple(n for n in names if n != "lidar")
        art_id, wall = spot_render(ctx, traj, scene_id, args, names)
        art = store.get(art_id)
        n_cam_rays = n_lidar_rays = 0
        from nsim.sensors.rig import Rig

        rig = Rig.from_resolved(json.loads(art.file("rig.json").read_text()))
        ticks = len(json.loads(art.file("render.json").read_text())["frames"])
        for s in rig.sensors:
            n = int(np.prod(s.ray_shape)) * ticks
            if s.type == "lidar":
                n_lidar_rays += n
            else:
                n_cam_rays += n
        # LiDAR alone, timed on its own
        lid_id, lid_wall = spot_render(ctx, traj, scene_id, args, ("lidar",), force=True)
        results["speed"] = {"spot_wall_s": wall, "camera_and_lidar_rays": n_cam_rays + n_lidar_rays,
                            "rays_per_s_all": (n_cam_rays + n_lidar_rays) / wall,
                            "lidar_rays_per_s": n_lidar_rays / lid_wall}
        results["spot"] = score_spot(ctx, art_id, oracle)
        if not args.no_ray:
            from nsim.rendering.engine import EngineConfig

            _, w1 = spot_render(ctx, traj, scene_id, args, cams[:2], EngineConfig(engine="ray", workers=1), force=True)
            _, w2 = spot_render(ctx, traj, scene_id, args, cams[:2], EngineConfig(engine="ray", workers=2), force=True)
            results["ray"] = {"one_worker_s": w1, "two_workers_s": w2, "speedup": w1 / w2}

    sp = results["spot"]
    print()
    print(f"Spot cameras along spot_run ({sp['ticks']} ticks, cameras scaled x{args.image_scale}), against the oracle:")
    print(f"{'camera':<12} {'PSNR':>7} {'SSIM':>6} {'AbsRel':>7}")
    for name, row in sp["cameras"].items():
        if "psnr" in row:
            print(f"{name:<12} {row['psnr']:7.2f} {row['ssim']:6.3f} {row['abs_rel']:7.4f}")
    li = sp["lidar"]
    print(f"LiDAR: median range error {li['median_range_error_m'] * 100:.2f} cm, p95 {li['p95_range_error_m'] * 100:.2f} cm "
          f"over {li['returns']} returns; hit agreement {sp['cameras']['lidar']['hit_agreement']:.3f}")
    s = results["speed"]
    print(f"speed (in-process, 2 threads): {s['rays_per_s_all']:.0f} rays/s cameras+LiDAR, LiDAR alone {s['lidar_rays_per_s']:.0f} rays/s")
    if "ray" in results:
        r = results["ray"]
        print(f"Ray: 1 worker {r['one_worker_s']:.1f} s, 2 workers {r['two_workers_s']:.1f} s (x{r['speedup']:.2f})")
    print(json.dumps({"quick": q, "image_scale": args.image_scale, **results}, default=lambda o: to_dict(o)))


if __name__ == "__main__":
    main()
