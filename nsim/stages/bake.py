"""``nsim bake``: a scene checkpoint baked for fast sensors, as a ``baked-scene`` artifact.

Input: a ``scene-checkpoint`` (``nsim train-scene``): its field and the occupancy grid baked at train
time. The core (``nsim.rendering.bake_bricks``) puts a brick of lattice points into every occupied cell,
stores the field's density and geometry features there, drops the bricks that hold no density (and, with
``cull_weight``, those no training camera sees: SNeRG's visibility culling, the training rays marched
through the baked grid itself) and keeps the colour head with the mean appearance embedding; ``nsim render --set
method=baked`` marches it (``--baked ID``, or baked on demand), the scene field volume-rendered only in a window
around each camera ray's baked surface (``field_samples``; a LiDAR's rays take the window's depth from the
field's density, with no colour). With ``surface`` (the default preset) the bake also holds a surface
(``nsim.rendering.surface``): the density meshed, the mesh fitted to the NeRF's median depths on the training
rays and textured from the training images (read from the poses artifact the scene names); cameras, depth and
LiDAR then render from the mesh, camera rays that miss it from the NeRF.

Artifact layout (``nsim.rendering.baked.BakedScene.save``)::

    baked.json                 layout, sizes, the marcher's settings, the scene checkpoint's id, bake statistics
    brick_index.npy            (X, Y, Z) int32: brick of each occupancy cell, -1 for none
    density.npy                (N, (B + 1)^3) float32: density (1/m) at each brick's lattice points
    features.npy               (N, (B + 1)^3, G) float16: the field's geometry features there (G = 0 with
                               feature_dtype none: the scene field colours the rays, field_samples)
    color_layer<k>_{weight,bias}.npy   the colour head (appearance folded into the first bias)
    surface_vertices.npy       (V, 3) float32, surface_faces.npy (F, 3) int32: the fitted mesh (surface only)
    texture_table.npy, texture_layer<k>_{weight,bias}.npy   its hash-grid texture (surface only)

Resume: the lattice (both lattices with ``cull_voxel_m``: the culled first bake's, then the fine one's
over the kept cells) is evaluated in parts of ``PART_POINTS`` points, each written to
``<workspace>/tmp/bake.<key>.resume/`` as it is done; a killed bake started again with the same
inputs, config and device evaluates only the missing parts and publishes the same artifact. The
surface's NeRF depths and colours on the training rays are kept the same way, ``PART_RAYS`` rays a part. The
folder goes once the artifact is published. The device is part of the action key.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from nsim.context import RunContext
from nsim.errors import InputError
from nsim.io import atomic_path
from nsim.rendering.bake_config import BakeConfig
from nsim.stages.runner import SceneInputs, cached, device_kind, rerun, resolve_scene

STAGE = "bake"
VERSION = 1
PART_POINTS = 1 << 20  # lattice points per resume part
PART_RAYS = 1 << 18  # surface: training rays the NeRF renders per resume part

log = logging.getLogger(__name__)

Config = BakeConfig
Inputs = SceneInputs


@dataclasses.dataclass(frozen=True)
class Outputs:
    baked: str
    cache_hit: bool = False
    parts_reused: int = 0


def training_frames(scene_id: str, ctx: RunContext, setting: str = "cull_weight") -> tuple[list, list[Path]]:
    """The cameras the scene was trained on, ``(camera, cam_to_world)`` pairs at the size it trained at, and their
    images' paths: the poses artifact its manifest names, the images ``scene.json`` lists as ``train_images``."""
    import json

    from nsim.io.transforms_json import read_transforms

    store = ctx.store
    art = store.get(scene_id)
    doc = json.loads(art.file("scene.json").read_text())
    doc = doc.get("extra", doc)
    poses = art.manifest.get("inputs", {}).get("poses")
    if poses is None or "train_images" not in doc:
        raise InputError(f"bake {scene_id[:12]}: {setting} needs the training cameras; the scene names no poses "
                         f"artifact or train_images (set {setting}={'false' if setting == 'surface' else 'null'})")
    root = store.get(poses).path
    frames = read_transforms(root / "transforms.json").frames
    size = doc.get("image_size_trained")
    ids = doc["train_images"]
    if not isinstance(ids, list) or not all(isinstance(i, int) and 0 <= i < len(frames) for i in ids):
        raise InputError(f"bake {scene_id[:12]}: scene.json: train_images: expected frame indices of poses "
                         f"{poses[:12]} ({len(frames)} frames)")
    out, paths = [], []
    for i in ids:
        cam = frames[int(i)].camera
        if size and int(size[0]) != cam.width:
            cam = cam.scaled(int(size[0]) / cam.width)
        out.append((cam, np.asarray(frames[int(i)].cam_to_world, dtype=np.float32)))
        paths.append(root / frames[int(i)].file_path)
    return out, paths


def training_images(frames: list, paths: list[Path]) -> list[np.ndarray]:
    """The training images at ``paths`` (:func:`training_frames`), each ``(H, W, 3)`` uint8 at its camera's size,
    shrunk as the trainer shrinks them (pixel-area averaging)."""
    from nsim.io.images import read_image
    from nsim.train.scene_data import resize_image

    return [resize_image(read_image(path), cam.width, cam.height) for (cam, _), path in zip(frames, paths, strict=True)]


def _save_part(path: Path, arr) -> None:
    """One resume part, written whole or not at all (``nsim.io.atomic_path``)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a file object: np.save would append .npy to the name
        np.save(fh, arr.cpu().numpy(), allow_pickle=False)


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed,
                                extra={"device": device_kind(ctx.device)})


def resume_dir(ctx: RunContext, key: str) -> Path:
    return ctx.store.root / "tmp" / f"{STAGE}.{key[:24]}.resume"


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    """Bake (or resume, or find in the run cache)."""
    store = ctx.store
    inputs = Inputs(scene=resolve_scene(inputs.scene, ctx, STAGE, files=("occupancy_grid.npy",)))
    cfg.check()
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(baked=hit, cache_hit=True)
    # the training cameras (scene.json, the poses artifact) and images are read and checked before the model loads
    frames, paths = training_frames(inputs.scene, ctx, "surface" if cfg.surface else "cull_weight") \
        if cfg.cull_weight is not None or cfg.surface else (None, None)
    # the texture is fitted to the training images
    images = training_images(frames, paths) if cfg.surface and cfg.texture_from == "images" else None
    import torch  # the inputs checked first: a bad argument fails without loading torch

    from nsim.rendering import OccupancyGrid, load_model
    from nsim.rendering.bake_bricks import bake_passes, bake_surface, evaluate_lattice, nerf_targets

    art = store.get(inputs.scene)
    t0 = time.perf_counter()
    model = load_model(art.path, ctx.device).eval()
    grid = OccupancyGrid.load(art.file("occupancy_grid.npy"), ctx.device)
    work = resume_dir(ctx, key)
    work.mkdir(parents=True, exist_ok=True)
    reused = 0

    def evaluate(plan, c, name):
        nonlocal reused
        sig, feats = [], []
        for a in range(0, plan.n_points, PART_POINTS):
            b = min(plan.n_points, a + PART_POINTS)
            part = (work / f"{name}_{a:012d}_density.npy", work / f"{name}_{a:012d}_features.npy")
            if part[0].is_file() and part[1].is_file():
                s, f = (torch.as_tensor(np.load(p, allow_pickle=False)).to(ctx.device) for p in part)
                reused += 1
            else:
                pieces = [evaluate_lattice(model.field, plan, c, d, min(b, d + c.chunk_points))
                          for d in range(a, b, c.chunk_points)]
                s, f = torch.cat([p[0] for p in pieces]), torch.cat([p[1] for p in pieces])
                _save_part(part[1], f)
                _save_part(part[0], s)  # density last: its presence marks a complete part
            sig.append(s)
            feats.append(f)
        density = torch.cat(sig) if sig else torch.zeros(0, device=ctx.device)
        return density, torch.cat(feats) if feats else torch.zeros(0, model.field_cfg.geo_feat_dim, device=ctx.device)

    def targets(rays):  # the NeRF's depth and colour of the surface's training rays, in resumable parts
        parts = []
        for a in range(0, len(rays), PART_RAYS):
            path = work / f"surface_{a:012d}.npy"
            if path.is_file():
                part = torch.as_tensor(np.load(path, allow_pickle=False)).to(ctx.device)
                nonlocal reused
                reused += 1
            else:
                depth, acc, rgb = nerf_targets(model, grid, rays[a : a + PART_RAYS])
                part = torch.cat([depth[:, None], acc[:, None], rgb], 1)
                _save_part(path, part)
            parts.append(part)
            log.info("bake: the NeRF's surface on %d of %d training rays", min(len(rays), a + PART_RAYS), len(rays))
        t = torch.cat(parts) if parts else torch.zeros(0, 5, device=ctx.device)
        return t[:, 0], t[:, 1], t[:, 2:]

    baked = bake_passes(model, grid, cfg, frames, evaluate)
    if cfg.surface:
        baked = bake_surface(model, baked, cfg, frames, targets, seed=ctx.seed, images=images)
    bake_s = time.perf_counter() - t0
    with store.publish(kind="baked-scene", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(),
                       seed=ctx.seed) as out:
        doc = baked.save(out.dir, extra={"scene_checkpoint": inputs.scene})
        size = sum(p.stat().st_size for p in out.dir.iterdir() if p.is_file())
        out.summary.update({"bricks": doc["bricks"], "bricks_per_side": doc["bricks_per_side"],
                            "voxel_m": doc["voxel_m"], "occupied_cells": doc["occupied_cells"],
                            "pruned_bricks": doc["pruned_bricks"], "culled_bricks": doc.get("culled_bricks", 0),
                            **({"surface_faces": doc["surface"]["faces"]} if "surface" in doc else {}),
                            "size_mb": round(size / 1e6, 3)})
        out.timing["bake_s"] = round(bake_s, 2)
        if reused:
            out.timing["parts_reused"] = reused
    shutil.rmtree(work, ignore_errors=True)
    log.info("bake: %d bricks of %d^3 voxels (%.1f MB) in %.1f s", doc["bricks"], doc["bricks_per_side"], size / 1e6,
             bake_s)
    return Outputs(baked=out.ref, parts_reused=reused)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    return rerun(run, Inputs(scene=manifest["inputs"]["scene"]), Config, manifest, ctx).baked
