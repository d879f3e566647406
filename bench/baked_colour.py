"""Issue 25: how faithful can a baked scene's colour be with one lookup a ray? A ceiling, measured.

    python bench/baked_colour.py [--quick] [--workspace DIR] [--scene REF] [--capture REF] [--steps N]

The baked renderer's cost is its colour: ``field_samples: 16`` queries the scene field 16 times a camera ray, and
10x the NeRF's rays/s leaves one or two microseconds a ray for colour. The cheapest colour there is reads a baked
texture once a ray, at the point where the ray meets the surface (SNeRG's deferred shading reduced to one sample).
This script measures how good that can be, whatever the texture's storage: it fits the most flexible texture that
is still one lookup (instant-NGP's multiresolution hash grid: 12 levels, 2^19 rows, finest ``--max-resolution``
cells across the box, and a 32-wide decoder: ``nsim.fields``) to the training images' pixels at their rays' surface points, and scores the held-out
views at theirs, for two surfaces:

- ``nerf``: each ray's median depth from the NeRF itself (``method: proposal``), the best geometry nsim has;
- ``baked``: each ray's median depth from the baked density alone (``nsim bake``'s ``volume`` preset with
  ``--bake-set`` overrides, e.g. ``voxel_m=0.02 cull_voxel_m=0.04`` for a 2 cm lattice; no field queries).

Printed: each one's held-out PSNR against the images and against the NeRF's renders, beside the NeRF's own, and
the texture lookup's cost a ray (one thread, CPU seconds) beside the NeRF's. Uses the default capture and the
``scene/bench-gt`` checkpoint as ``bench/render.py`` does (``--scene``, else trains one; ``--quick``: the tiny
capture, a 300-step ``tiny`` scene, 200 texture steps). Training pixels: every ``--stride``-th (both ways) of
every training view.

JSON last line: ``nerf_psnr, texture_psnr_nerf_depth, texture_psnr_baked_depth, texture_vs_nerf_nerf_depth,
texture_vs_nerf_baked_depth, texture_us_per_ray, nerf_us_per_ray``.
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
from nsim.stages import capture  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render import get_scene  # noqa: E402  (bench/render.py: --scene, else scene/bench-gt, else train one)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workspace", type=Path, default=None)
    ap.add_argument("--scene", default=None)
    ap.add_argument("--capture", default=None, help="the capture the --scene was trained on (default: made here)")
    ap.add_argument("--steps", type=int, default=None, help="texture fitting steps (default 2000, 200 quick)")
    ap.add_argument("--stride", type=int, default=None, help="training pixels: every k-th both ways (default 2)")
    ap.add_argument("--heldout-views", type=int, default=None, help="held-out views scored (default 4, 2 quick)")
    ap.add_argument("--max-resolution", type=int, default=1024, help="the texture's finest hash-grid level, cells "
                    "across the scene box (the scene field's: 2048)")
    ap.add_argument("--bake-set", action="append", default=[], metavar="KEY=VALUE",
                    help="override of the bake preset for the baked surface (repeatable), e.g. voxel_m=0.02")
    args = ap.parse_args()
    q = args.quick
    steps = args.steps or (200 if q else 2000)
    stride = args.stride or 2
    n_views = args.heldout_views or (2 if q else 4)
    import torch

    torch.set_num_threads(2)
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(args.workspace or Path(tmp) / "ws")
        ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
        if args.capture is not None:
            cap_id = store.resolve(args.capture, kind="capture")
        else:
            cap_cfg = load_config(capture.Config, stage="capture", preset="tiny" if q else "default",
                                  overrides=["video=false"])
            cap_id = capture.run(capture.Inputs(), cap_cfg, ctx).capture
        scene_id = get_scene(ctx, cap_id, args.scene, q)
        res = measure(ctx, cap_id, scene_id, steps, stride, n_views, args.max_resolution, args.bake_set)
    print(json.dumps({"quick": q, "steps": steps, "stride": stride, "max_resolution": args.max_resolution,
                      "bake_set": args.bake_set, **res}))


def measure(ctx: RunContext, cap_id: str, scene_id: str, steps: int, stride: int, n_views: int, max_res: int,
            bake_set: list[str]) -> dict:
    import dataclasses

    import torch

    from nsim.fields.hash_encoding import HashEncoding
    from nsim.fields.mlp import MLP
    from nsim.io.images import read_image, to_float
    from nsim.io.transforms_json import read_transforms
    from nsim.metrics.image import psnr
    from nsim.rendering import OccupancyGrid, load_model
    from nsim.rendering.baked import BakedScene, render_baked
    from nsim.rendering.renderer import MarchConfig, camera_rays, render_rays
    from nsim.stages import bake

    store = ctx.store
    scene, cap = store.get(scene_id), store.get(cap_id)
    model = load_model(scene.path, "cpu")
    grid = OccupancyGrid.load(scene.file("occupancy_grid.npy"))
    bcfg = load_config(bake.Config, stage="bake", preset="volume", overrides=bake_set)
    baked_id = bake.run(bake.Inputs(scene=scene_id), bcfg, ctx).baked
    baked = BakedScene.load(store.get(baked_id).path)
    print(f"bake {baked_id[:12]}: {baked.n_bricks} bricks, lattice {float(baked.voxel_m.max()):.3f} m", flush=True)
    # the baked density alone: no field window, no NeRF fallback (one march a ray, as a texture lookup would need)
    baked = dataclasses.replace(baked, field_samples=0, nerf_fallback_share=None, nerf_fallback_accumulation=None)
    doc = json.loads(scene.file("scene.json").read_text())
    doc = doc.get("extra", doc)
    train = sorted(int(i) for i in doc["train_images"])
    frames = read_transforms(cap.file("transforms.json")).frames
    held = [i for i in range(len(frames)) if i not in set(train)][:n_views]
    size = doc.get("image_size_trained")

    def view(i: int):
        cam = frames[i].camera
        if size and int(size[0]) != cam.width:
            cam = cam.scaled(int(size[0]) / cam.width)
        rays, _, valid = camera_rays(model, cam, frames[i].cam_to_world)
        return cam, rays, valid, to_float(read_image(cap.path / frames[i].file_path)).reshape(-1, 3)

    def ends(out, rays):
        """(hit (R,) bool, points (R, 3)) where each ray meets the surface of a render ``out``: its median depth."""
        return out.accumulation > 0.5, rays.origins + rays.dirs * out.depth_median[:, None]

    @torch.no_grad()
    def surface(anchor: str, rays):
        out = (render_rays(model, rays, "proposal", grid, MarchConfig(), 8192) if anchor == "nerf"
               else render_baked(baked, rays, 65536, colour=False))
        return out, ends(out, rays)

    lo, hi = model.aabb[0].cpu(), model.aabb[1].cpu()
    # the held-out views: the NeRF's renders (its surface there too) and its cost a ray
    views, nerf_s, nerf_n = [], 0.0, 0
    for i in held:
        _cam, rays, _valid, gt = view(i)
        t0 = time.process_time()
        out, nerf_ends = surface("nerf", rays)
        nerf_s, nerf_n = nerf_s + time.process_time() - t0, nerf_n + len(rays)
        views.append((rays, gt, out.rgb.clamp(0, 1).numpy(), nerf_ends))
    res = {"nerf_psnr": float(np.mean([psnr(v[2], v[1]) for v in views])),
           "nerf_us_per_ray": 1e6 * nerf_s / max(nerf_n, 1)}
    print(f"NeRF: held-out PSNR {res['nerf_psnr']:.2f} dB over {len(views)} views", flush=True)
    # the training pixels, every stride-th both ways: rays and colours, read once for both surfaces
    pixels = []
    for i in train:
        cam, rays, valid, gt = view(i)
        pick = np.zeros((cam.height, cam.width), bool)
        pick[::stride, ::stride] = True
        idx = np.flatnonzero(pick.reshape(-1) & valid.numpy())
        pixels.append((rays[torch.as_tensor(idx)], torch.as_tensor(gt[idx])))
    for anchor in ("nerf", "baked"):
        xs, ys = [], []
        for rays, colours in pixels:
            _, (hit, x) = surface(anchor, rays)
            xs.append(((x[hit] - lo) / (hi - lo)).float())
            ys.append(colours[hit])
        u_all, y_all = torch.cat(xs), torch.cat(ys)
        gen = torch.Generator().manual_seed(0)
        enc = HashEncoding(12, 2, 19, 16, max_res, generator=gen)
        dec = MLP(enc.n_output_dims, 32, 1, 3, gen)
        opt = torch.optim.Adam([{"params": enc.parameters(), "eps": 1e-15}, {"params": dec.parameters()}], lr=1e-2)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** (s / steps))
        t0 = time.perf_counter()
        for _ in range(steps):
            b = torch.randint(0, len(u_all), (16384,), generator=gen)
            loss = ((torch.sigmoid(dec(enc(u_all[b]))) - y_all[b]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        fit_s = time.perf_counter() - t0
        scores, vs_nerf, look_s, look_n = [], [], 0.0, 0
        with torch.no_grad():
            for rays, gt, nerf_rgb, nerf_ends in views:
                hit, x = nerf_ends if anchor == "nerf" else surface(anchor, rays)[1]
                t0 = time.process_time()
                rgb = torch.sigmoid(dec(enc(((x - lo) / (hi - lo)).float())))
                look_s, look_n = look_s + time.process_time() - t0, look_n + len(rays)
                rgb = torch.where(hit[:, None], rgb, 0.0).numpy()
                scores.append(psnr(rgb, gt))
                vs_nerf.append(psnr(rgb, nerf_rgb))
        res[f"texture_psnr_{anchor}_depth"] = float(np.mean(scores))
        res[f"texture_vs_nerf_{anchor}_depth"] = float(np.mean(vs_nerf))
        res[f"texture_train_psnr_{anchor}_depth"] = float(-10 * np.log10(float(loss.detach())))
        res["texture_us_per_ray"] = 1e6 * look_s / max(look_n, 1)
        print(f"texture at the {anchor}'s median depth: {len(u_all)} training pixels, {steps} steps in {fit_s:.0f} s; "
              f"held-out {res[f'texture_psnr_{anchor}_depth']:.2f} dB against the images "
              f"(NeRF {res['nerf_psnr']:.2f}), {res[f'texture_vs_nerf_{anchor}_depth']:.2f} dB against the NeRF",
              flush=True)
    print(f"CPU time a ray (all threads): texture lookup {res['texture_us_per_ray']:.2f} us, "
          f"NeRF {res['nerf_us_per_ray']:.1f} us", flush=True)
    return res


if __name__ == "__main__":
    main()
