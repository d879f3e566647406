"""``nsim render`` on the test room: accuracy against the oracle, Spot's cameras, speed.

    python bench/render.py [--quick] [--workspace DIR] [--scene REF] [--ticks N] [--image-scale S] [--baked]

Uses the default capture (robot-lab, 320x240, ground-truth poses) and a scene checkpoint:
``--scene REF``, else ``scene/bench-gt`` in ``--workspace`` (what ``bench/train_scene.py
--workspace DIR`` publishes), else it trains one with the train_scene ``cpu`` preset.
``--quick``: the tiny capture and a 300-step ``tiny`` scene (under a minute or two).

Measures, with the same renderer the stage uses (marching + occupancy grid):

1. held-out capture views (``nsim render --poses``, ``frames=heldout``): PSNR / SSIM against
   the captured images, depth AbsRel (``nsim.metrics.depth``, see ``abs_rel``) of the median depth
   against the capture's z-depth, beside
   train-scene's own held-out PSNR (``eval.json``; the proposal renderer);
2. LiDAR: Spot's VLP-16-like LiDAR along the simulated ``spot_run``, no noise, against the
   oracle's exact scan from the same poses: median / p95 range error where both return;
3. Spot's five fisheye cameras along ``spot_run`` against the oracle's images from the same
   poses: a per-camera PSNR / SSIM / depth AbsRel table (the paper's Table III reached
   9.4-11.8 dB on its real Spot), with the share of pixels whose surface no training view of
   the capture saw (projected into every training view, depth-tested against the capture's
   depth) and the PSNR over the pixels that some view did see;
4. speed: camera and LiDAR rays/s in-process on 2 cores, and the wall time of the same render
   on Ray with 2 workers against 1;
5. culling (``render.culling``): a human checkpoint (``--human REF``, else trained here through
   ``train_human`` on a ``capture synth --actor`` capture; ``--quick``: a 48x64 capture and 20
   steps), and two copies of the ``spot_run`` trajectory with every person moved to a fixed
   place in the robot's body frame at every tick: (a) 3-4.5 m *behind* the robot, rendered with
   Spot's two front cameras (checked: ``HumanSet.visible`` with culling returns nobody for any
   frame and sensor, and the human NeRF is never called); (b) 2.5-4 m *in front*, rendered with
   the front cameras and the LiDAR (checked: the people change the output; one tick with
   ``--quick``). The same frames
   are rendered by the stage with ``culling: true``, ``false`` (every person's NeRF queried on
   every ray's samples: no 2D-bound test, no ray-box test) and without human checkpoints;
   for (a) after one warm-up run, in rotating order, best of ``--culling-reps`` (3; 2 quick) at camera
   scale ``--culling-scale`` (default ``--image-scale``); every rendered file is compared
   (decoded arrays with ``np.array_equal``, NaN = NaN, and bytes). Reported: the stage's wall
   time both ways and the speed-up, where the time goes (``HumanSet.visible``, the scene's
   ``render_rays``, the human NeRF, the merge in ``HumanSet.composite``, the rest of the stage),
   and whether the outputs are identical. (Spot's 360-degree LiDAR would see the people behind
   the robot within its range, so (a) uses the two front cameras, which cannot.)

``--baked`` measures instead the baked scene (``nsim bake`` with ``--bake-preset``, default ``default``: the surface;
``tiny`` with ``--quick``; or ``--baked-id``, a bake made before; ``nsim render --set method=baked``) against the
NeRF (``method: proposal``, the stage's default), side by side in one run:

6. the bake's wall time (with ``--baked-id``: the time that bake recorded) and size on disk;
7. held-out capture views through the stage with both renderers: PSNR / SSIM / LPIPS of the baked images
   against the NeRF's, each one's PSNR / SSIM against the captured images and depth AbsRel against the
   capture's depth;
8. Spot along ``spot_run`` (``--ticks``, ``--image-scale``) with both: PSNR / SSIM / LPIPS baked against NeRF
   over the oracle's valid pixels, each one's depth AbsRel against the oracle and LiDAR median range error
   against the oracle's exact scan (``nsim.metrics.lidar_realism``);
9. speed: rays/s in-process on one tick's rays (cameras at ``--image-scale`` + LiDAR; the NeRF on a random
   ``--nerf-rays`` of them), 2 threads, the stage's chunk, each renderer as the stage runs it (the baked scene
   with the scene field attached, its LiDAR rays without colour); the wall time of one full Spot tick (five
   fisheyes at ``--tick-scale``, 1.0 = 640x480, and the 16x1800 LiDAR) and of the LiDAR sweep alone through
   the stage, files written, after a warm-up. Wall time: on a shared machine time them again when it is quiet.

Then issue 25's bars, met or not. Its JSON line leads with ``nerf_rays_s, baked_rays_s, speedup,
psnr_baked_vs_nerf, spot_tick_s, lidar_sweep_s, bake_s, bake_mb``. ``--quick --baked``: the tiny capture and scene, 3 held-out views, the tick at x0.25.

Prints tables and one JSON object on the last line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import configs_dir, from_dict, load_config, to_dict  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.metrics.image import psnr_from_mse  # noqa: E402
from nsim.rendering.people import HumanSet  # noqa: E402
from nsim.rendering.render_plan import adapt_rig, plan_frames  # noqa: E402
from nsim.stages import capture, render, simulate, train_scene  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402

SPOT = configs_dir() / "robots" / "spot.yaml"


def abs_rel(pred: np.ndarray, gt: np.ndarray) -> float:
    """AbsRel of ``nsim.metrics.depth`` per view (``view_abs_rel``, its default ``DepthConfig``: ground truth
    within 1 mm..10 m, predictions clamped into that range, so a rendered ``inf`` counts as 10 m) over the
    pixels whose prediction is a number (NaN: no ray, or nearer than the camera's minimum depth); NaN if
    none counts. The held-out scores of ``nsim train-scene`` (eval.json) are the same metric."""
    from nsim.metrics.depth import view_abs_rel

    return view_abs_rel(pred, gt)


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
    forced = dataclasses.replace(ctx, force=True)  # timed: render even if an earlier run is cached
    t0 = time.perf_counter()
    out = render.run(render.Inputs(poses=cap_id, scene=scene_id), cfg, forced)
    wall = time.perf_counter() - t0
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
    cfg = load_config(simulate.Config, stage="simulate", preset="tiny" if quick else "default",
                      overrides=["video=false"])
    sc = simulate.load_scenario(configs_dir() / "scenarios" / "spot_run.json", store=ctx.store)
    return simulate.run(simulate.Inputs(sc), cfg, ctx).trajectory


def spot_render(ctx: RunContext, traj: str, scene_id: str, args, sensors: tuple[str, ...], engine=None,
                force: bool = False) -> tuple[str, float]:
    cfg = from_dict(render.Config, {
        "tick_stride": args.tick_stride, "max_frames": args.ticks, "image_scale": args.image_scale,
        "lidar_azimuth_scale": args.lidar_scale, "noise": False, "video": False, "sensors": list(sensors),
        "shard_frames": max(1, args.ticks // 4), "method": args.method, "march": {"step_m": args.march_step}})
    t0 = time.perf_counter()
    out = render.run(render.Inputs(trajectory=traj, scene=scene_id, rig=SPOT, people=False), cfg,
                     dataclasses.replace(ctx, force=force), engine=engine)
    return out.render, time.perf_counter() - t0


def capture_coverage(cap, holdout_every: int):
    """``seen(points (N, 3)) -> (N,) bool``: whether some training view of the capture (frame ``i``
    with ``i % holdout_every != 0``) saw the world point: it projects inside the view, in front of
    it, and the capture's z-depth there agrees with the point's (3 % + 2 cm)."""
    from nsim.io.exr import read_depth_exr
    from nsim.io.transforms_json import read_transforms

    views = []
    for i, fr in enumerate(read_transforms(cap.file("transforms.json")).frames):
        if (holdout_every > 0 and i % holdout_every == 0) or fr.depth_file_path is None:
            continue
        views.append((fr.camera, np.linalg.inv(fr.cam_to_world), read_depth_exr(cap.file(fr.depth_file_path))))

    def seen(points: np.ndarray) -> np.ndarray:
        out = np.zeros(len(points), dtype=bool)
        for cam, w2c, depth in views:
            pc = points @ w2c[:3, :3].T + w2c[:3, 3]
            uv, ok = cam.project(pc)
            u = np.clip(np.round(uv[:, 0]).astype(int), 0, cam.width - 1)
            v = np.clip(np.round(uv[:, 1]).astype(int), 0, cam.height - 1)
            z = pc[:, 2]
            out |= ok & (np.abs(depth[v, u] - z) < 0.03 * np.abs(z) + 0.02)
        return out

    return seen


def score_spot(ctx: RunContext, art_id: str, oracle, seen=None) -> dict:
    """Per camera: PSNR / SSIM / depth AbsRel against the oracle; with ``seen`` (``capture_coverage``)
    also the share of valid pixels whose surface no training view saw and the PSNR over the others."""
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
                gt = oracle.lidar_gt(s.world_pose(T), s)  # the sensor: its own beams, as the render's
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
            if seen is not None:
                o, dirs = s.camera.pixel_rays(s.world_pose(T))
                pts = (o + dirs * np.where(valid, view.depth_range, 0.0)[..., None])[valid]
                ok = seen(pts)
                err = ((pred.astype(np.float32) / 255.0 - np.clip(view.rgb.astype(np.float32), 0, 1)) ** 2)[valid]
                row.setdefault("unseen_fraction", []).append(float(1.0 - ok.mean()))
                row.setdefault("psnr_seen", []).append(psnr_from_mse(max(float(err[ok].mean()), 1e-12)))
    out = {name: {k: float(np.nanmean(v)) for k, v in row.items()} for name, row in table.items()}
    errs = np.concatenate(lidar_err) if lidar_err else np.zeros(0)
    lidar = {"median_range_error_m": float(np.median(errs)) if errs.size else float("nan"),
             "p95_range_error_m": float(np.percentile(errs, 95)) if errs.size else float("nan"), "returns": int(errs.size)}
    return {"cameras": out, "lidar": lidar, "ticks": len(meta["frames"])}


# ---------------------------------------------------------------------------------- culling
CULL_BEHIND = ((-3.0, -1.5), (-3.5, -0.5), (-3.0, 0.5), (-3.5, 1.5), (-4.5, 0.0))  # body frame (x fwd, y left), m
CULL_FRONT = ((2.5, -0.8), (3.0, 0.0), (2.5, 0.8), (3.5, -1.5), (4.0, 1.2))
FRONT_CAMERAS = ("frontleft", "frontright")


def get_human(ctx: RunContext, human: str | None, quick: bool) -> tuple[str, float]:
    """A human checkpoint: ``--human REF``, else ``capture synth --actor`` + ``train_human`` (tiny preset)."""
    from nsim.stages import train_human

    if human is not None:
        return ctx.store.resolve(human, kind="human-checkpoint"), 0.0
    t0 = time.perf_counter()
    size = ["width=48", "height=64", "n_frames=16", "supersample=1"] if quick else ["width=96", "height=72", "n_frames=24"]
    cap_cfg = load_config(capture.Config, stage="capture", preset="default", overrides=["actor=true", "video=false", *size])
    cap_id = capture.run(capture.Inputs(), cap_cfg, ctx).capture
    over = ["optim.num_threads=2"]
    if quick:  # a few steps: the person's density only has to be non-zero; previews kept tiny
        over += ["optim.steps=20", "optim.rays_per_batch=256", "output.preview_views=1", "output.preview_width=16",
                 "output.preview_height=24", "output.gait_frames=2", "output.eval_views=1"]
    cfg = load_config(train_human.Config, stage="train_human", preset="tiny", overrides=over)
    out = train_human.run(train_human.Inputs(capture=cap_id), cfg, ctx)
    wall = time.perf_counter() - t0
    print(f"human checkpoint: actor capture + train-human ({cfg.optim.steps} steps) in {wall:.0f} s"
          f"{' (cached)' if out.cache_hit else ''}", flush=True)
    return out.human, wall


def placed_trajectory(ctx: RunContext, traj: str, offsets, tag: str) -> str:
    """``traj`` with person k at ``offsets[k % len]`` in the robot's body frame at every tick, facing the
    robot (a ``trajectory`` artifact in the ``nsim simulate`` format: the render stage reads it as is)."""
    import hashlib

    store = ctx.store
    a = dict(np.load(store.get(traj).file("trajectory.npz"), allow_pickle=False))
    poses = a["robot_pose_se3"]
    n_people = a["position_m"].shape[1]
    if n_people == 0:
        raise RuntimeError(f"trajectory {traj[:12]} has no people to place")
    off = np.array([offsets[k % len(offsets)] for k in range(n_people)], dtype=np.float64)  # (N, 2)
    world = np.einsum("tij,nj->tni", poses[:, :2, :2], off) + poses[:, None, :2, 3]
    yaw = np.arctan2(poses[:, 1, 0], poses[:, 0, 0])
    a["position_m"] = world
    a["velocity_mps"] = np.zeros_like(a["velocity_mps"])
    a["heading_rad"] = np.broadcast_to(yaw[:, None] + np.pi, a["heading_rad"].shape).copy()
    key = hashlib.sha256(f"bench.render.culling:{traj}:{tag}:{off.tolist()}".encode()).hexdigest()
    if (hit := store.lookup(key)) is not None:
        return hit.id
    with store.publish(kind="trajectory", stage="bench_render_culling", version=1, key=key,
                       config={"placement": tag, "body_frame_offsets_m": off.tolist()}, inputs={"trajectory": traj},
                       seed=ctx.seed) as out:
        np.savez(out.dir / "trajectory.npz", **a)
    return out.ref


def visible_people(ctx: RunContext, traj: str, human: str, frames: list, rig) -> dict[str, list[int]]:
    """``{"tick/sensor": [people]}`` that ``HumanSet.visible`` (culling on) keeps, with the rays the stage casts."""
    import torch

    store = ctx.store
    hs = HumanSet.load([str(store.get(human).path)], str(store.get(traj).file("trajectory.npz")),
                       torch.device("cpu"))
    seen = {}
    for f in frames:  # nsim.rendering.render_job.TickFrame
        body = np.asarray(f.body_to_world, dtype=np.float64)
        posed = hs.joint_transforms(f.index)
        for s in rig.sensors:
            o, d = s.rays(body)
            valid = np.isfinite(d).all(-1)
            o = torch.as_tensor(np.array(o, dtype=np.float32))
            d = torch.as_tensor(np.where(valid[:, None], d, [0.0, 0.0, 1.0]), dtype=torch.float32)
            cam, c2w = (s.camera, s.world_pose(body)) if s.type == "camera" else (None, None)
            seen[f"{f.index}/{s.name}"] = [p.k for p in hs.visible(posed, o, d, cam, c2w, True)]
    return seen


def _decode(path: Path):
    from nsim.io.coco import read_instance_mask
    from nsim.io.exr import read_exr
    from nsim.io.images import read_image

    if path.suffix == ".exr":
        return read_exr(path)
    if path.suffix == ".png":
        return read_instance_mask(path) if path.parent.name == "mask" else read_image(path)
    return None  # .ply / .json: bytes only


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def compare_renders(ctx: RunContext, ref_a: str, ref_b: str, humans_only: bool = False,
                    limit: int | None = 8) -> dict:
    """Every file under the sensors' folders of two render artifacts: decoded arrays equal (PNG, EXR:
    np.array_equal, NaN = NaN; PLY, JSON: bytes) and bytes equal. ``humans_only``: skip what only a
    render with humans writes (masks, boxes.json), to compare with a render without human checkpoints.
    ``images_identical``: the cameras' files only; ``channel_max_abs_diff``: per differing EXR channel."""
    art_a, art_b = ctx.store.get(ref_a), ctx.store.get(ref_b)
    sensors = json.loads(art_a.file("render.json").read_text())["sensors"]
    cameras = {s["name"] for s in sensors if s["type"] == "camera"}

    def files(art):
        out = {}
        for s in sensors:
            for p in sorted((art.path / s["name"]).rglob("*")):
                rel = p.relative_to(art.path).as_posix()
                if p.is_file() and not (humans_only and ("/mask/" in rel or rel.endswith("boxes.json"))):
                    out[rel] = p
        return out

    fa, fb = files(art_a), files(art_b)
    differ_arrays, differ_bytes, channels = [], [], {}
    for rel in sorted(set(fa) & set(fb)):
        same_bytes = fa[rel].read_bytes() == fb[rel].read_bytes()
        if not same_bytes:
            differ_bytes.append(rel)
        da, db = _decode(fa[rel]), _decode(fb[rel])
        if (da is None and not same_bytes) or (da is not None and not _same(da, db)):
            differ_arrays.append(rel)
        if isinstance(da, dict) and da.keys() == db.keys():
            for ch in da:
                x, y = da[ch], db[ch]
                if x.shape == y.shape and not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
                    both = np.isfinite(x) & np.isfinite(y) if x.dtype.kind == "f" else np.ones(x.shape, bool)
                    d = float(np.abs(x[both].astype(np.float64) - y[both]).max()) if both.any() else float("inf")
                    key = f"{rel.split('/')[0]}:{ch}"
                    channels[key] = max(channels.get(key, 0.0), d)
    missing = sorted(set(fa) ^ set(fb))
    on_camera = [r for r in missing + differ_arrays if r.split("/")[0] in cameras]
    return {"files": len(set(fa) & set(fb)), "only_in_one": missing[:limit], "arrays_differ": differ_arrays[:limit],
            "bytes_differ": differ_bytes[:limit], "channel_max_abs_diff": channels,
            "identical": not missing and not differ_arrays and bool(fa),
            "images_identical": not on_camera and any(r.split("/")[0] in cameras for r in fa),
            "bytes_identical": not missing and not differ_bytes and bool(fa)}


class _Meter:
    """Wall time and calls, while active, of the stage's human hooks (``HumanSet.visible`` / ``composite``),
    the human NeRF (``HumanModel.render_samples``) and the scene renderer (``render_rays``)."""

    def __init__(self) -> None:
        from nsim.human.nerf import HumanModel
        from nsim.rendering import renderer

        self.targets = [(HumanSet, "visible"), (HumanSet, "composite"), (HumanModel, "render_samples"),
                        (renderer, "render_rays")]
        self.real = {}
        self.reset()

    def reset(self) -> None:
        self.seconds = {name: 0.0 for _, name in self.targets}
        self.calls = {name: 0 for _, name in self.targets}

    def __enter__(self):
        for owner, name in self.targets:
            real = owner.__dict__[name]
            self.real[(owner, name)] = real

            def timed(*a, _real=real, _name=name, **k):
                t0 = time.perf_counter()
                try:
                    return _real(*a, **k)
                finally:
                    self.seconds[_name] += time.perf_counter() - t0
                    self.calls[_name] += 1

            setattr(owner, name, timed)
        return self

    def __exit__(self, *exc) -> None:
        for (owner, name), real in self.real.items():
            setattr(owner, name, real)


def culling_bench(ctx: RunContext, traj: str, scene_id: str, human: str, args) -> dict:
    import torch

    from nsim.sensors.rig import Rig

    behind = placed_trajectory(ctx, traj, CULL_BEHIND, "behind")
    front = placed_trajectory(ctx, traj, CULL_FRONT, "front")

    def cfg(culling: bool, sensors: tuple[str, ...], scale: float, ticks: int = args.ticks):
        return from_dict(render.Config, {
            "tick_stride": args.tick_stride, "max_frames": ticks, "image_scale": scale,
            "lidar_azimuth_scale": args.lidar_scale, "noise": False, "video": False, "sensors": list(sensors),
            "shard_frames": ticks, "method": args.method, "march": {"step_m": args.march_step}, "culling": culling})

    meter = _Meter()

    def stage(tr: str, culling: bool, sensors, scale: float, humans: tuple[str, ...], ticks: int = args.ticks) -> dict:
        forced = dataclasses.replace(ctx, force=True)  # timed: render even if an earlier run is cached
        meter.reset()
        t0, c0 = time.perf_counter(), time.process_time()
        with meter:
            out = render.run(render.Inputs(trajectory=tr, scene=scene_id, rig=SPOT, humans=humans, people=bool(humans)),
                             cfg(culling, sensors, scale, ticks), forced)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        return {"render": out.render, "wall_s": wall, "cpu_s": cpu, "seconds": dict(meter.seconds),
                "calls": dict(meter.calls)}

    res: dict = {"human": human, "scale": args.culling_scale, "ticks": args.ticks}
    # (a) out of view: behind the robot, Spot's front cameras
    probe = cfg(True, FRONT_CAMERAS, args.culling_scale)
    inputs = render.resolve_inputs(render.Inputs(trajectory=behind, scene=scene_id, rig=SPOT), ctx)
    frames = plan_frames(render.sources_of(inputs, ctx), probe)
    rig_a = adapt_rig(Rig.load(SPOT), probe)
    seen = visible_people(ctx, behind, human, frames, rig_a)
    res["people"] = int(np.load(ctx.store.get(behind).file("trajectory.npz"))["position_m"].shape[1])
    if any(seen.values()):
        raise RuntimeError(f"culling bench: people meant to be out of view are visible: {seen}")
    stage(behind, True, FRONT_CAMERAS, args.culling_scale, (human,))  # warm-up (first-call allocations), not timed
    runs: dict[str, list[dict]] = {"culled": [], "unculled": [], "no_humans": []}
    for rep in range(args.culling_reps):  # side by side, the order rotating
        modes = ("culled", "unculled", "no_humans")
        for mode in modes[rep % 3:] + modes[: rep % 3]:
            runs[mode].append(stage(behind, mode != "unculled", FRONT_CAMERAS, args.culling_scale,
                                    () if mode == "no_humans" else (human,)))
    best = {m: min(r, key=lambda x: x["wall_s"]) for m, r in runs.items()}

    def breakdown(run: dict) -> dict:
        sec = run["seconds"]
        out = {"visible_s": sec["visible"], "scene_render_rays_s": sec["render_rays"],
               "human_render_samples_s": sec["render_samples"]}
        # composite = the scene's render_rays (with samples) + every person's render_samples + the merge
        out["merge_and_composite_s"] = max(0.0, sec["composite"] - sec["render_samples"]
                                           - (sec["render_rays"] if sec["composite"] else 0.0))
        out["rest_of_stage_s"] = run["wall_s"] - sec["visible"] - sec["render_rays"] - sec["render_samples"] \
            - out["merge_and_composite_s"]
        return out

    a = {"sensors": list(FRONT_CAMERAS), "frames": len(frames), "visible_with_culling": 0,
         "rays": sum(int(np.prod(s.ray_shape)) for s in rig_a.sensors) * len(frames),
         **{f"{m}_s": best[m]["wall_s"] for m in best},
         **{f"{m}_all_s": [r["wall_s"] for r in runs[m]] for m in runs},
         **{f"{m}_cpu_s": min(r["cpu_s"] for r in runs[m]) for m in runs},
         "breakdown": {m: breakdown(best[m]) for m in best},
         "human_nerf_calls_culled": max(r["calls"]["render_samples"] for r in runs["culled"]),
         "human_nerf_calls_unculled": best["unculled"]["calls"]["render_samples"]}
    a["speedup"] = a["unculled_s"] / a["culled_s"]
    a["speedup_cpu"] = a["unculled_cpu_s"] / a["culled_cpu_s"]  # process CPU time: less hurt by a shared machine
    a["culled_over_no_humans"] = a["culled_s"] / a["no_humans_s"]
    a["unculled_over_no_humans"] = a["unculled_s"] / a["no_humans_s"]
    a["culled_vs_unculled"] = compare_renders(ctx, best["culled"]["render"], best["unculled"]["render"])
    a["culled_vs_no_humans"] = compare_renders(ctx, best["culled"]["render"], best["no_humans"]["render"], True)
    a["identical"] = a["culled_vs_unculled"]["identical"] and a["culled_vs_no_humans"]["identical"]
    res["out_of_view"] = a

    # (b) in view: in front of the robot; the front cameras and the LiDAR
    names = (*FRONT_CAMERAS, "lidar")
    ticks_b = 1 if args.quick else args.ticks  # in view, the human NeRF dominates: one tick is enough to compare
    b: dict = {"sensors": list(names), "scale": args.culling_scale, "ticks": ticks_b}
    done = {}
    for mode in ("culled", "unculled", "no_humans"):
        humans = () if mode == "no_humans" else (human,)
        try:
            done[mode] = stage(front, mode != "unculled", names, args.culling_scale, humans, ticks_b)
        except RuntimeError as exc:  # the stage failed (e.g. .numpy() on a tensor that requires grad)
            if "requires grad" not in str(exc):
                raise
            b.setdefault("stage_error", f"{type(exc).__name__}: {exc}".splitlines()[0])
            b["workaround"] = "rendered under torch.no_grad() by this bench"
            with torch.no_grad():
                done[mode] = stage(front, mode != "unculled", names, args.culling_scale, humans, ticks_b)
    for mode in done:
        b[f"{mode}_s"] = done[mode]["wall_s"]
    meta = json.loads(ctx.store.get(done["culled"]["render"]).file("render.json").read_text())
    b["people_px"] = sum(int(v.get("people_px", 0)) for row in meta["per_frame"] for v in row.values()
                         if isinstance(v, dict))
    b["human_nerf_calls_culled"] = done["culled"]["calls"]["render_samples"]
    b["culled_vs_unculled"] = compare_renders(ctx, done["culled"]["render"], done["unculled"]["render"])
    # not vacuous: the people change what the sensors see
    b["files_changed_by_people"] = len(compare_renders(ctx, done["culled"]["render"], done["no_humans"]["render"],
                                                       True, limit=None)["arrays_differ"])
    b["identical"] = b["culled_vs_unculled"]["identical"]
    b["images_identical"] = b["culled_vs_unculled"]["images_identical"]
    res["in_view"] = b
    return res


# ---------------------------------------------------------------------------------- baked (--baked)
def _file_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.iterdir() if f.is_file() and f.name != "manifest.json") / 1e6


def _pair_scores(pred_u8: np.ndarray, ref_u8: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """PSNR / SSIM / LPIPS of one 8-bit image against another (``nsim.metrics``; LPIPS n/a without weights)."""
    from nsim.metrics.image import psnr, ssim
    from nsim.metrics.lpips import lpips_or_na

    p = pred_u8.astype(np.float32) / 255.0
    r = ref_u8.astype(np.float32) / 255.0
    if p.ndim == 2:
        p, r = np.repeat(p[..., None], 3, -1), np.repeat(r[..., None], 3, -1)
    lp = lpips_or_na(p, r, mask=mask) if min(p.shape[:2]) >= 32 else float("nan")
    return {"psnr": float(psnr(p, r, mask)), "ssim": float(ssim(p, r, mask)),
            "lpips": float(lp) if isinstance(lp, float) else float("nan")}


def _mean(rows: list[dict], key: str) -> float:
    vals = [r[key] for r in rows if np.isfinite(r[key])]
    return float(np.mean(vals)) if vals else float("nan")


def _rays_per_s(ctx: RunContext, scene_id: str, baked_id: str, traj: str, args) -> dict:
    """In-process rendering speed on the same rays (one Spot tick's cameras at ``--image-scale`` and its
    LiDAR): the NeRF as the stage renders it by default (``method: proposal``) on a subset, the baked scene
    on all of them; 2 threads, the stage's chunk size."""
    import torch

    from nsim.rendering import OccupancyGrid, load_model
    from nsim.rendering.baked import BakedScene, render_baked
    from nsim.rendering.renderer import render_rays
    from nsim.sensors.rig import Rig
    from nsim.volume.rays import Rays, make_rays

    store = ctx.store
    scene = store.get(scene_id)
    dev = torch.device(ctx.device)
    model = load_model(scene.path, dev)
    grid = OccupancyGrid.load(scene.file("occupancy_grid.npy")).to(dev)
    baked = BakedScene.load(store.get(baked_id).path, dev)
    if baked.uses_field:  # as the render stage attaches it
        baked = baked.with_field(model.field)
    cfg = render.Config()
    rig = adapt_rig(Rig.load(SPOT), dataclasses.replace(cfg, image_scale=args.image_scale))
    body = np.load(store.get(traj).file("trajectory.npz"))["robot_pose_se3"][args.tick_stride]
    sc = model.sampler_cfg

    def rays_of(sensors) -> object:
        o, d = zip(*(s.rays(body) for s in sensors), strict=True)
        o = np.concatenate([x.reshape(-1, 3) for x in o])
        d = np.concatenate([x.reshape(-1, 3) for x in d])
        valid = np.isfinite(d).all(-1)
        d = np.where(valid[:, None], d, [0.0, 0.0, 1.0])
        return make_rays(torch.as_tensor(o, dtype=torch.float32), torch.as_tensor(d, dtype=torch.float32), sc.near_m,
                         sc.far_m, model.aabb.cpu() if sc.clip_rays_to_box else None), torch.as_tensor(valid)

    # a sensor's pixels outside its image: rendered (as the stage does) but never by the NeRF fallback
    cams, cams_valid = rays_of([s for s in rig.sensors if s.type != "lidar"])
    lidar, _ = rays_of([s for s in rig.sensors if s.type == "lidar"])
    rays = Rays(*(torch.cat([getattr(cams, f), getattr(lidar, f)]) for f in ("origins", "dirs", "near", "far")))
    g = torch.Generator().manual_seed(0)
    sub = rays[torch.randperm(len(rays), generator=g)[: min(len(rays), args.nerf_rays)]].to(dev)
    cams, cams_valid, lidar = cams.to(dev), cams_valid.to(dev), lidar.to(dev)

    def timed(fn) -> float:  # wall seconds, the device's queue drained at both ends
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        t = time.perf_counter()
        fn()
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        return time.perf_counter() - t

    # warm-up: first-call allocations (and CUDA's kernels)
    timed(lambda: render_baked(baked, sub[:2048], cfg.chunk_rays))
    timed(lambda: render_rays(model, sub[:2048], cfg.method, grid, cfg.march, cfg.chunk_rays))
    nerf_s = timed(lambda: render_rays(model, sub, cfg.method, grid, cfg.march, cfg.chunk_rays))
    # as the stage renders them: the cameras with colour, the LiDAR without (depth only)
    sent = []  # the camera rays the baked scene hands to the NeRF (nerf_fallback_*)

    def nerf(r):
        sent.append(len(r))
        return render_rays(model, r, cfg.method, grid, cfg.march, cfg.chunk_rays)

    cams_s = timed(lambda: render_baked(baked, cams, cfg.chunk_rays, fallback=nerf, may_fall_back=cams_valid))
    baked_s = cams_s + timed(lambda: render_baked(baked, lidar, cfg.chunk_rays, colour=False))
    return {"nerf_rays_s": len(sub) / nerf_s, "baked_rays_s": len(rays) / baked_s, "nerf_rays": len(sub),
            "baked_rays": len(rays), "baked_camera_rays_s": len(cams) / cams_s,
            "baked_lidar_rays_s": len(lidar) / (baked_s - cams_s), "lidar_rays": len(lidar),
            "lidar_sweep_render_s": baked_s - cams_s, "camera_rays_to_nerf_share": sum(sent) / max(len(cams), 1)}


def baked_bench(ctx: RunContext, cap_id: str, scene_id: str, traj: str, oracle, args) -> dict:
    """NeRF against baked, side by side in one run (module docstring, ``--baked``)."""
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_image
    from nsim.io.lidar_exr import read_lidar_exr
    from nsim.io.transforms_json import read_transforms
    from nsim.metrics.lidar_realism import lidar_range_metrics
    from nsim.sensors.rig import Rig
    from nsim.stages import bake

    store = ctx.store
    forced = dataclasses.replace(ctx, force=True)
    res: dict = {}
    # 1. the bake
    if args.baked_id:  # a bake made before (of this scene): its own recorded time
        baked_id = store.resolve(args.baked_id, kind="baked-scene")
        man = store.get(baked_id).manifest
        if man["inputs"]["scene"] != scene_id:
            sys.exit(f"--baked-id {args.baked_id}: a bake of scene {man['inputs']['scene'][:12]}, not {scene_id[:12]}")
        bcfg, bake_s = from_dict(bake.Config, man["config"]), float(man["timing"]["bake_s"])
    else:
        bcfg = load_config(bake.Config, stage="bake", preset=args.bake_preset or ("tiny" if args.quick else "default"))
        t0 = time.perf_counter()
        baked_id = bake.run(bake.Inputs(scene=scene_id), bcfg, forced).baked
        bake_s = time.perf_counter() - t0
    res["bake"] = {"bake_s": bake_s, "bake_mb": _file_mb(store.get(baked_id).path), "baked_id": baked_id,
                   "config": to_dict(bcfg), **store.get(baked_id).manifest["summary"]}
    print(f"bake: {res['bake']['bake_s']:.1f} s, {res['bake']['bake_mb']:.1f} MB, {res['bake']['bricks']} bricks",
          flush=True)

    def stage(method: str, inputs: render.Inputs, over: dict) -> tuple[str, float]:
        cfg = from_dict(render.Config, {"video": False, "noise": False, "method": method, **over})
        t = time.perf_counter()
        out = render.run(dataclasses.replace(inputs, baked=baked_id if method == "baked" else None), cfg, forced)
        return out.render, time.perf_counter() - t

    # 2. held-out capture views
    cap = store.get(cap_id)
    tf = read_transforms(cap.file("transforms.json")).frames
    over = {"frames": "heldout", "max_frames": args.heldout_views}
    arts = {m: stage(m, render.Inputs(poses=cap_id, scene=scene_id), over) for m in ("proposal", "baked")}
    rows = []
    for f in json.loads(store.get(arts["baked"][0]).file("render.json").read_text())["frames"]:
        i = f["index"]
        img = {m: read_image(store.get(a).file(f"frames/rgb/{i:06d}.png")) for m, (a, _) in arts.items()}
        gt = read_image(cap.path / tf[i].file_path)
        dg = read_depth_exr(cap.path / tf[i].depth_file_path)
        row = {"frame": i, **{f"{k}_vs_nerf": v for k, v in _pair_scores(img["baked"], img["proposal"]).items()}}
        for m, name in (("proposal", "nerf"), ("baked", "baked")):
            sc = _pair_scores(img[m], gt)
            row[f"{name}_psnr"], row[f"{name}_ssim"] = sc["psnr"], sc["ssim"]
            row[f"{name}_abs_rel"] = abs_rel(read_depth_exr(store.get(arts[m][0]).file(f"frames/depth/{i:06d}.exr")), dg)
        rows.append(row)
    res["heldout"] = {k: _mean(rows, k) for k in rows[0] if k != "frame"}
    res["heldout"].update({"views": len(rows), "nerf_stage_s": arts["proposal"][1], "baked_stage_s": arts["baked"][1]})
    h = res["heldout"]
    print(f"held-out views ({len(rows)}): PSNR vs GT NeRF {h['nerf_psnr']:.2f} / baked {h['baked_psnr']:.2f} dB; baked "
          f"vs NeRF PSNR {h['psnr_vs_nerf']:.2f} dB SSIM {h['ssim_vs_nerf']:.4f} LPIPS {h['lpips_vs_nerf']:.4f}; "
          f"depth AbsRel NeRF {h['nerf_abs_rel']:.4f} / baked {h['baked_abs_rel']:.4f}", flush=True)

    # 3. Spot along spot_run: both renderers against each other and against the oracle
    over = {"tick_stride": args.tick_stride, "max_frames": args.ticks, "image_scale": args.image_scale,
            "lidar_azimuth_scale": args.lidar_scale, "shard_frames": max(1, args.ticks)}
    spot = {m: stage(m, render.Inputs(trajectory=traj, scene=scene_id, rig=SPOT, people=False), over) for m in ("proposal", "baked")}
    art = {m: store.get(a) for m, (a, _) in spot.items()}
    rig = Rig.from_resolved(json.loads(art["baked"].file("rig.json").read_text()))
    from nsim.io.tum import read_tum

    body = read_tum(art["baked"].file("robot.tum")).poses_se3()
    meta = json.loads(art["baked"].file("render.json").read_text())
    cam_rows, lidar = [], {"proposal": [], "baked": []}
    for f, T in zip(meta["frames"], body, strict=True):
        i = f["index"]
        for s in rig.sensors:
            if s.type == "lidar":
                gt = oracle.lidar_gt(s.world_pose(T), s).ranges_m
                for m in lidar:
                    scan = read_lidar_exr(art[m].file(f"{s.name}/scan/{i:06d}.exr"))
                    lidar[m].append(lidar_range_metrics(scan.range_m, gt))
                continue
            view = oracle.render_gt(s.camera, s.world_pose(T), supersample=2)
            valid = np.isfinite(view.depth_range)
            img = {m: read_image(art[m].file(f"{s.name}/rgb/{i:06d}.png")) for m in art}
            row = {f"{k}_vs_nerf": v for k, v in _pair_scores(img["baked"], img["proposal"], valid).items()}
            for m, name in (("proposal", "nerf"), ("baked", "baked")):
                row[f"{name}_abs_rel"] = abs_rel(read_depth_exr(art[m].file(f"{s.name}/depth/{i:06d}.exr")), view.depth_z)
            cam_rows.append(row)
    res["spot"] = {k: _mean(cam_rows, k) for k in cam_rows[0]}
    for m, name in (("proposal", "nerf"), ("baked", "baked")):
        errs = [x.range_error_median_m for x in lidar[m] if x.range_error_median_m is not None]
        res["spot"][f"{name}_lidar_median_range_error_m"] = float(np.mean(errs)) if errs else float("nan")
        res["spot"][f"{name}_lidar_hit_agreement"] = float(np.mean([x.hit_agreement for x in lidar[m]]))
    res["spot"].update({"ticks": len(meta["frames"]), "nerf_stage_s": spot["proposal"][1],
                        "baked_stage_s": spot["baked"][1]})
    p = res["spot"]
    print(f"Spot ({p['ticks']} ticks, cameras x{args.image_scale}): baked vs NeRF PSNR {p['psnr_vs_nerf']:.2f} dB SSIM "
          f"{p['ssim_vs_nerf']:.4f} LPIPS {p['lpips_vs_nerf']:.4f}; depth AbsRel vs oracle NeRF {p['nerf_abs_rel']:.4f} / "
          f"baked {p['baked_abs_rel']:.4f}; LiDAR median range error NeRF "
          f"{p['nerf_lidar_median_range_error_m'] * 100:.2f} / baked {p['baked_lidar_median_range_error_m'] * 100:.2f} cm; "
          f"stage NeRF {p['nerf_stage_s']:.1f} s, baked {p['baked_stage_s']:.1f} s", flush=True)

    # 4. speed: rays/s in-process, a full Spot tick and a LiDAR sweep through the stage (files written)
    res["speed"] = _rays_per_s(ctx, scene_id, baked_id, traj, args)
    tick = {"tick_stride": args.tick_stride, "max_frames": 1, "image_scale": args.tick_scale, "lidar_azimuth_scale": 1.0,
            "shard_frames": 1}
    stage("baked", render.Inputs(trajectory=traj, scene=scene_id, rig=SPOT, people=False), {**tick, "image_scale": 0.05})  # warm-up
    _, res["speed"]["spot_tick_s"] = stage("baked", render.Inputs(trajectory=traj, scene=scene_id, rig=SPOT, people=False), tick)
    _, res["speed"]["lidar_sweep_s"] = stage("baked", render.Inputs(trajectory=traj, scene=scene_id, rig=SPOT, people=False),
                                             {**tick, "sensors": ["lidar"]})
    res["speed"]["tick_image_scale"] = args.tick_scale
    sp = res["speed"]
    sp["speedup"] = sp["baked_rays_s"] / sp["nerf_rays_s"]
    where = "2 threads" if ctx.device == "cpu" else ctx.device
    print(f"speed ({where}): NeRF {sp['nerf_rays_s']:.0f} rays/s, baked {sp['baked_rays_s']:.0f} rays/s "
          f"(x{sp['speedup']:.1f}); Spot tick (5 fisheyes at x{args.tick_scale} + LiDAR 16x1800) through the stage "
          f"{sp['spot_tick_s']:.2f} s, LiDAR sweep alone {sp['lidar_sweep_s']:.2f} s; "
          f"{100 * sp['camera_rays_to_nerf_share']:.1f} % of the camera rays rendered by the NeRF (fallback)", flush=True)
    res["summary"] = {"nerf_rays_s": sp["nerf_rays_s"], "baked_rays_s": sp["baked_rays_s"], "speedup": sp["speedup"],
                      "psnr_baked_vs_nerf": h["psnr_vs_nerf"], "spot_tick_s": sp["spot_tick_s"],
                      "lidar_sweep_s": sp["lidar_sweep_s"], "bake_s": res["bake"]["bake_s"],
                      "bake_mb": res["bake"]["bake_mb"], "device": ctx.device,
                      "camera_rays_to_nerf_share": sp["camera_rays_to_nerf_share"]}
    # issue 25's bars (the goals: the tick and the sweep at 640x480 on 2 cores)
    res["bars"] = {"speedup_ge_10": sp["speedup"] >= 10.0,
                   "heldout_psnr_within_0.5_db": h["baked_psnr"] >= h["nerf_psnr"] - 0.5,
                   "heldout_abs_rel_within_10_pct": h["baked_abs_rel"] <= 1.1 * h["nerf_abs_rel"],
                   "spot_abs_rel_within_10_pct": p["baked_abs_rel"] <= 1.1 * p["nerf_abs_rel"],
                   "lidar_error_within_10_pct": p["baked_lidar_median_range_error_m"]
                   <= 1.1 * p["nerf_lidar_median_range_error_m"],
                   "goal_spot_tick_le_12_s": sp["spot_tick_s"] <= 12.0 and args.tick_scale == 1.0,
                   "goal_lidar_sweep_le_0.3_s": sp["lidar_sweep_s"] <= 0.3}
    print("bars: " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in res["bars"].items()), flush=True)
    return res


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
    ap.add_argument("--no-culling", action="store_true", help="skip the culling section")
    ap.add_argument("--only-culling", action="store_true", help="run the culling section alone")
    ap.add_argument("--human", default=None, help="human checkpoint for the culling section (default: train one)")
    ap.add_argument("--culling-scale", type=float, default=None,
                    help="camera scale of the culling section (default: --image-scale)")
    ap.add_argument("--culling-reps", type=int, default=None, help="timed repetitions per mode (default 3, 2 quick)")
    ap.add_argument("--device", default="cpu", help="where to render and time (cpu, cuda, auto; issue 25's bars are "
                                                   "on 2 CPU cores)")
    ap.add_argument("--baked", action="store_true", help="only the baked scene against the NeRF (nsim bake, "
                                                         "method: baked): speed, images, depth, LiDAR, bake cost")
    ap.add_argument("--capture", default=None, help="the capture the --scene was trained on (default: made here "
                                                    "with the capture preset; a scene of another capture scores wrong)")
    ap.add_argument("--bake-preset", default=None, help="--baked: the bake preset (nsim/configs/bake/NAME.yaml; default: "
                                                        "default, tiny with --quick)")
    ap.add_argument("--baked-id", default=None, help="--baked: measure this baked-scene (id or ref) of the scene "
                                                     "instead of baking one (bake_s: the time it recorded)")
    ap.add_argument("--heldout-views", type=int, default=None, help="--baked: held-out views (default all, 3 quick)")
    ap.add_argument("--nerf-rays", type=int, default=None, help="--baked: rays the NeRF's speed is timed on "
                                                                "(default 30000, 4000 quick)")
    ap.add_argument("--tick-scale", type=float, default=None, help="--baked: camera scale of the timed Spot tick "
                                                                   "(default 1.0 = 640x480, 0.25 quick)")
    args = ap.parse_args()
    q = args.quick
    args.ticks = args.ticks or (2 if q else 12)
    args.tick_stride = args.tick_stride or 10
    args.image_scale = args.image_scale or (0.1 if q else 0.5)
    args.lidar_scale = args.lidar_scale or (0.05 if q else 0.5)
    args.culling_scale = args.culling_scale or args.image_scale
    args.culling_reps = args.culling_reps or (2 if q else 3)
    args.heldout_views = args.heldout_views or (3 if q else None)
    args.nerf_rays = args.nerf_rays or (4000 if q else 30000)
    args.tick_scale = args.tick_scale or (0.25 if q else 1.0)
    import torch

    torch.set_num_threads(2)
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        store = Store(ws)
        ctx = RunContext(store=store, device_spec=args.device, seed=0, progress=False)
        cap_cfg = load_config(capture.Config, stage="capture", preset="tiny" if q else "default", overrides=["video=false"])
        if args.capture is not None:  # the capture the scene was trained on (its held-out frames, its room)
            cap_id = store.resolve(args.capture, kind="capture")
        else:
            cap_id = capture.run(capture.Inputs(), cap_cfg, ctx).capture
        cap = store.get(cap_id)
        scene_id = get_scene(ctx, cap_id, args.scene, q)
        from nsim.synth.oracle import RoomOracle
        from nsim.synth.room import RoomSpec

        oracle = RoomOracle(RoomSpec.from_dict(json.loads(cap.file("room.json").read_text())["spec"]))

        traj = spot_run(ctx, q)
        if args.baked:
            results["baked"] = baked_bench(ctx, cap_id, scene_id, traj, oracle, args)
            print(json.dumps({"quick": q, "image_scale": args.image_scale, **results["baked"]["summary"],
                              "baked": results["baked"]}, default=lambda o: to_dict(o)))
            return
        if not args.only_culling:
            results["heldout"] = {}
            for method, views, step in (("proposal", None, 0.01), ("march", 2, args.march_step)):
                h = heldout(ctx, cap_id, scene_id, method, views, step)
                results["heldout"][method] = h
                print(f"held-out capture views, {method} ({h['views']}): PSNR {h['psnr']:.2f} dB (train-scene's held-out "
                      f"PSNR on the same views {h['train_scene_heldout_psnr_same_views']:.2f}), SSIM {h['ssim']:.3f}, "
                      f"depth AbsRel (median) {h['abs_rel_median_depth']:.4f}; {h['camera_rays_per_s']:.0f} rays/s", flush=True)

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
            holdout = json.loads(store.get(scene_id).file("manifest.json").read_text())["config"]["data"]["holdout_every"]
            results["spot"] = score_spot(ctx, art_id, oracle, capture_coverage(cap, holdout))
            if not args.no_ray:
                from nsim.rendering.engine import EngineConfig

                _, w1 = spot_render(ctx, traj, scene_id, args, cams[:2], EngineConfig(engine="ray", workers=1), force=True)
                _, w2 = spot_render(ctx, traj, scene_id, args, cams[:2], EngineConfig(engine="ray", workers=2), force=True)
                results["ray"] = {"one_worker_s": w1, "two_workers_s": w2, "speedup": w1 / w2}
        if not args.no_culling:
            human_id, human_s = get_human(ctx, args.human, q)
            results["culling"] = {"human_train_s": human_s, **culling_bench(ctx, traj, scene_id, human_id, args)}
            cu = results["culling"]
            results.update({
                "culling_out_of_view_culled_s": cu["out_of_view"]["culled_s"],
                "culling_out_of_view_unculled_s": cu["out_of_view"]["unculled_s"],
                "culling_out_of_view_no_humans_s": cu["out_of_view"]["no_humans_s"],
                "culling_out_of_view_speedup": cu["out_of_view"]["speedup"],
                "culling_out_of_view_speedup_cpu": cu["out_of_view"]["speedup_cpu"],
                "culling_out_of_view_identical": cu["out_of_view"]["identical"],
                "culling_in_view_identical": cu["in_view"]["identical"],
                "culling_in_view_images_identical": cu["in_view"]["images_identical"],
            })

    sp = results.get("spot")
    if sp is not None:
        print_spot(results, args)
    if "culling" in results:
        print_culling(results)
    print(json.dumps({"quick": q, "image_scale": args.image_scale, **results}, default=lambda o: to_dict(o)))


def print_spot(results: dict, args) -> None:
    sp = results["spot"]
    print()
    print(f"Spot cameras along spot_run ({sp['ticks']} ticks, cameras scaled x{args.image_scale}), against the oracle:")
    print(f"{'camera':<12} {'PSNR':>7} {'SSIM':>6} {'AbsRel':>7}  {'unseen':>7} {'PSNR seen':>9}")
    for name, row in sp["cameras"].items():
        if "psnr" in row:
            extra = (f"  {row['unseen_fraction'] * 100:6.1f}% {row['psnr_seen']:9.2f}" if "psnr_seen" in row else "")
            print(f"{name:<12} {row['psnr']:7.2f} {row['ssim']:6.3f} {row['abs_rel']:7.4f}{extra}")
    if any("psnr_seen" in row for row in sp["cameras"].values()):
        print("(unseen: valid pixels whose surface no training view of the capture saw; PSNR seen: over the others)")
    li = sp["lidar"]
    print(f"LiDAR: median range error {li['median_range_error_m'] * 100:.2f} cm, p95 {li['p95_range_error_m'] * 100:.2f} cm "
          f"over {li['returns']} returns; hit agreement {sp['cameras']['lidar']['hit_agreement']:.3f}")
    s = results["speed"]
    print(f"speed (in-process, 2 threads): {s['rays_per_s_all']:.0f} rays/s cameras+LiDAR, LiDAR alone {s['lidar_rays_per_s']:.0f} rays/s")
    if "ray" in results:
        r = results["ray"]
        print(f"Ray: 1 worker {r['one_worker_s']:.1f} s, 2 workers {r['two_workers_s']:.1f} s (x{r['speedup']:.2f})")


def print_culling(results: dict) -> None:
    cu = results["culling"]
    a, b = cu["out_of_view"], cu["in_view"]
    print()
    print(f"culling: {cu['people']} people, {a['frames']} ticks of spot_run, cameras x{cu['scale']}, the same frames "
          f"both ways; (a) best of {len(a['culled_all_s'])} alternating runs")
    print(f"{'case':<46} {'culled s':>9} {'unculled s':>11} {'speed-up':>9} {'identical':>10}")
    print(f"{'(a) behind the robot: ' + '+'.join(a['sensors']):<46} {a['culled_s']:9.2f} {a['unculled_s']:11.2f} "
          f"{a['speedup']:9.2f} {str(a['identical']):>10}")
    label_b = f"(b) in front, {b['ticks']} tick(s): " + "+".join(b["sensors"])
    print(f"{label_b:<46} {b['culled_s']:9.2f} {b['unculled_s']:11.2f} "
          f"{b['unculled_s'] / b['culled_s']:9.2f} {str(b['identical']):>10}")
    print(f"(a) process CPU time: culled {a['culled_cpu_s']:.2f} s, unculled {a['unculled_cpu_s']:.2f} s "
          f"(x{a['speedup_cpu']:.2f}), without human checkpoints {a['no_humans_cpu_s']:.2f} s")
    print(f"(a) without human checkpoints {a['no_humans_s']:.2f} s (culled / none x{a['culled_over_no_humans']:.2f}, "
          f"unculled / none x{a['unculled_over_no_humans']:.2f}); human NeRF calls: culled "
          f"{a['human_nerf_calls_culled']}, unculled {a['human_nerf_calls_unculled']}")
    print(f"{'(a) where the time goes, s':<28} {'visible':>8} {'scene':>8} {'human':>8} {'merge':>8} {'rest':>8}")
    for m, row in a["breakdown"].items():
        print(f"{m:<28} {row['visible_s']:8.2f} {row['scene_render_rays_s']:8.2f} {row['human_render_samples_s']:8.2f} "
              f"{row['merge_and_composite_s']:8.2f} {row['rest_of_stage_s']:8.2f}")
    diff = b["culled_vs_unculled"]
    if not diff["identical"]:
        print(f"(b) culled vs unculled: differing files {diff['arrays_differ']}; max |difference| per channel "
              f"{diff['channel_max_abs_diff']}; camera images identical: {diff['images_identical']}")
    print(f"(b) people cover {b['people_px']} mask px and change {b['files_changed_by_people']} of "
          f"{b['culled_vs_unculled']['files']} files against a render without them"
          + (f"; the stage failed ({b['stage_error']}), {b['workaround']}" if "stage_error" in b else ""))


if __name__ == "__main__":
    main()
