"""Baking a scene: the NeRF's density and geometry features into the bricks of a ``nsim.rendering.baked.BakedScene``
(its layout, files and rendering are there), culled by the training cameras, optionally with a fitted surface.

Baking (``bake``: a trained ``SceneModel`` and its ``OccupancyGrid`` in, arrays out)
    Every occupied cell of the occupancy grid baked at train time holds a *brick*: a lattice of
    ``(B + 1)^3`` points spaced ``voxel = cell / B`` (``B = ceil(cell / voxel_m)``; a brick's
    boundary points are repeated in its neighbours', so that a cell is interpolated from its own
    brick alone). At each lattice point the field's density ``sigma`` (1/m) and geometry
    features (the density MLP's ``geo_feat_dim`` outputs, the colour head's input) are stored:
    averaged over ``supersample^3`` points spread over the voxel around it (densities plainly,
    features weighted by density), or the point itself (``supersample: 1``). Bricks whose density
    stays below ``prune_density`` everywhere are dropped (free space the grid kept for safety).
    The colour head is kept as it is, with the mean appearance embedding folded into its first
    bias (``ColorDecoder``): the same ``sigmoid(MLP([SH(dir), geo, code]))`` as
    ``SceneField.color``. This is the SNeRG idea (Hedman et al. 2021: a sparse grid of density
    and features, decoded by a small MLP) with the NeRF's own decoder instead of a distilled
    one, so no training is needed. Deterministic: the same model, grid and config give the same
    arrays (on one device).

Visibility culling (``cull_weight``; ``brick_visibility``, ``cull``)
    SNeRG's rule (Hedman et al. 2021, section 4.2: voxels whose maximum volume-rendering weight over
    the training rays is small are culled): every ``cull_stride``-th pixel of each training image casts
    a ray through the baked grid itself (no field evaluation), the weights of a ray's consecutive samples
    in one brick are summed, and a brick whose largest such sum over all rays stays below
    ``cull_weight`` goes: bricks outside every view and those behind opaque surfaces. A brick is
    interpolated from its own lattice alone, so the kept ones render exactly as before; rays from novel
    poses (Spot's fisheyes looking at the ceiling or behind walls) then cross the culled space as free
    space, skipped by the coarse march.

Surface (``surface``; ``bake_surface``)
    The bake's density meshed at ``surface_level``, the mesh fitted to the NeRF's median depths on the training
    rays and textured from the training images (``nsim.rendering.surface``; how it renders: ``nsim.rendering.baked``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nsim.errors import InputError
from nsim.rendering.bake_config import BakeConfig
from nsim.rendering.baked import BakedScene, ColorDecoder, march
from nsim.rendering.surface import BakedSurface, SurfaceTexture
from nsim.volume import quadrature
from nsim.volume.rays import Rays

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------------- baking
@dataclass(frozen=True, eq=False)
class BakePlan:
    """What a bake evaluates: the bricks and their unique lattice points.

    cells: (N, 3) int64, the occupied cells in C order (brick n is cell ``cells[n]``); lattice: (U, 3) int64,
    the distinct global lattice indices of all bricks (ascending by flat index); inverse: (N, P) int64,
    each brick's lattice points as rows of ``lattice``; lo: (3,) the box's minimum corner; voxel: (3,)."""

    aabb: Tensor
    shape: tuple[int, int, int]
    bricks_per_side: int
    cells: Tensor
    lattice: Tensor
    inverse: Tensor
    voxel: Tensor

    @property
    def n_points(self) -> int:
        return int(self.lattice.shape[0])

    def positions(self, start: int, stop: int) -> Tensor:
        """World positions ``(stop - start, 3)`` of lattice points ``[start, stop)``."""
        return self.aabb[0] + self.lattice[start:stop].to(torch.float32) * self.voxel


def bricks_per_side(cell_m: Tensor, voxel_m: float) -> int:
    return max(1, int(math.ceil(float(cell_m.max()) / voxel_m - 1e-4)))  # float32 cells: 0.2 / 0.05 is 4


def plan_bake(grid, cfg: BakeConfig) -> BakePlan:
    """The bricks of ``grid``'s (an ``OccupancyGrid``) occupied cells and their lattice points."""
    aabb = grid.aabb.float()
    device = aabb.device
    shape = tuple(int(s) for s in grid.shape)
    b = bricks_per_side(grid.cell_m, cfg.voxel_m)
    cells = torch.nonzero(grid.occupied, as_tuple=False).to(torch.int64)  # (N, 3), C order
    a = torch.arange(b + 1, device=device)
    local = torch.stack(torch.meshgrid(a, a, a, indexing="ij"), -1).reshape(-1, 3)  # (P, 3)
    glob = cells[:, None, :] * b + local[None]  # (N, P, 3)
    dims = torch.tensor([s * b + 1 for s in shape], device=device)
    flat = (glob[..., 0] * dims[1] + glob[..., 1]) * dims[2] + glob[..., 2]
    uniq, inverse = torch.unique(flat.reshape(-1), sorted=True, return_inverse=True)
    lattice = torch.stack([uniq // (dims[1] * dims[2]), (uniq // dims[2]) % dims[1], uniq % dims[2]], -1)
    voxel = (aabb[1] - aabb[0]) / torch.tensor(shape, dtype=torch.float32, device=device) / b
    return BakePlan(aabb, shape, b, cells, lattice, inverse.view(len(cells), -1), voxel)


@torch.no_grad()
def evaluate_lattice(field, plan: BakePlan, cfg: BakeConfig, start: int, stop: int) -> tuple[Tensor, Tensor]:
    """Density ``(n,)`` and geometry features ``(n, G)`` (float32) of lattice points ``[start, stop)``:
    averaged over ``supersample^3`` points spread over the voxel (features weighted by density + 1e-3)."""
    s = cfg.supersample
    x0 = plan.positions(start, stop)
    if s == 1:
        offsets = torch.zeros(1, 3, device=x0.device)
    else:
        a = (torch.arange(s, device=x0.device, dtype=torch.float32) + 0.5) / s - 0.5
        offsets = torch.stack(torch.meshgrid(a, a, a, indexing="ij"), -1).reshape(-1, 3) * plan.voxel
    sig_sum = torch.zeros(len(x0), device=x0.device)
    feat_sum = None
    w_sum = torch.zeros(len(x0), device=x0.device)
    for off in offsets:
        sig, geo = field.density(x0 + off)
        sig, geo = sig.float(), geo.float()
        w = sig + 1e-3
        sig_sum += sig
        feat_sum = geo * w[:, None] if feat_sum is None else feat_sum + geo * w[:, None]
        w_sum += w
    return sig_sum / len(offsets), feat_sum / w_sum[:, None]


def assemble(plan: BakePlan, density: Tensor, features: Tensor, decoder: ColorDecoder, cfg: BakeConfig,
             background: str, background_rgb, prune_density: float, meta: dict | None = None) -> BakedScene:
    """The baked scene from every lattice point's ``density (U,)`` and ``features (U, G)``: bricks whose
    density stays below ``prune_density`` dropped, the rest numbered in C order of their cells."""
    dens = density[plan.inverse]  # (N, P)
    keep = dens.amax(-1) >= prune_density if dens.numel() else torch.zeros(0, dtype=torch.bool, device=dens.device)
    cells = plan.cells[keep]
    index = torch.full(plan.shape, -1, dtype=torch.int32, device=dens.device)
    if len(cells):
        index[cells[:, 0], cells[:, 1], cells[:, 2]] = torch.arange(len(cells), dtype=torch.int32, device=dens.device)
    if cfg.feature_dtype == "none":  # colour from the field alone (field_samples): no features stored
        feats = torch.zeros(int(keep.sum()), plan.inverse.shape[1], 0, dtype=torch.float16, device=dens.device)
    else:
        feats = features[plan.inverse[keep]].to(getattr(torch, cfg.feature_dtype))
    stats = {"occupied_cells": int(len(plan.cells)), "pruned_bricks": int((~keep).sum()),
             "prune_density_per_m": float(prune_density), "lattice_points_evaluated": plan.n_points,
             "supersample": cfg.supersample, **(meta or {})}
    return BakedScene(aabb=plan.aabb.clone(), brick_index=index, density=dens[keep].contiguous(),
                      features=feats.contiguous(), bricks_per_side=plan.bricks_per_side, decoder=decoder,
                      step_voxels=cfg.step_voxels, block_cells=cfg.block_cells,
                      stop_transmittance=cfg.stop_transmittance, color_skip_weight=cfg.color_skip_weight,
                      background=background, background_rgb=torch.as_tensor(background_rgb, dtype=torch.float32),
                      meta=stats, field_color_samples=cfg.field_color_samples, field_samples=cfg.field_samples,
                      field_window_voxels=cfg.field_window_voxels, nerf_fallback_share=cfg.nerf_fallback_share,
                      nerf_fallback_voxels=cfg.nerf_fallback_voxels,
                      nerf_fallback_accumulation=cfg.nerf_fallback_accumulation)


def brick_visibility(baked: BakedScene, rays: Rays, chunk: int = 65536) -> Tensor:
    """Per brick ``(N,)`` float32, the largest volume-rendering weight it takes along any of ``rays``: a ray's
    weights summed over each run of its samples in one brick (so that the figure does not depend on the step),
    maximised over the rays. 0 for a brick no ray reaches (outside every view, or behind opaque surfaces)."""
    seen = torch.zeros(baked.n_bricks, dtype=torch.float32, device=baked.device)
    for a in range(0, len(rays), chunk):
        ray, t0, t1, sigma, brick, _ = march(baked, rays[a : a + chunk])
        if not ray.numel():
            continue
        w = quadrature.packed_render_weights(sigma, t1 - t0, ray)[0].float()
        run = torch.ones_like(ray, dtype=torch.bool)  # a new ray or a new brick along it
        run[1:] = (ray[1:] != ray[:-1]) | (brick[1:] != brick[:-1])
        run_id = torch.cumsum(run.to(torch.int64), 0) - 1
        run_w = torch.zeros(int(run_id[-1]) + 1, device=w.device).index_add_(0, run_id, w)
        seen.scatter_reduce_(0, brick[run], run_w, reduce="amax")
    return seen


def cull(baked: BakedScene, visibility: Tensor, min_weight: float) -> BakedScene:
    """``baked`` without the bricks whose ``visibility (N,)`` (:func:`brick_visibility`) is below ``min_weight``,
    the rest renumbered in their order (a brick is interpolated from its own lattice, so the kept ones render as
    before); ``meta`` counts the culled bricks."""
    keep = visibility >= min_weight
    old = baked.brick_index.view(-1)
    renum = torch.cumsum(keep.to(torch.int32), 0, dtype=torch.int32) - 1
    occupied = old >= 0
    new = torch.full_like(old, -1)
    new[occupied] = torch.where(keep[old[occupied].long()], renum[old[occupied].long()], -1)
    meta = {**baked.meta, "culled_bricks": int((~keep).sum()), "cull_weight": float(min_weight)}
    return dataclasses.replace(baked, brick_index=new.view(baked.brick_index.shape),
                               density=baked.density[keep].contiguous(), features=baked.features[keep].contiguous(),
                               meta=meta)


def training_rays(model, frames, stride: int, images: list | None = None) -> Rays | tuple[Rays, Tensor]:
    """The rays of every ``stride``-th pixel (both directions) of ``frames`` (``(camera, cam_to_world)`` pairs, the
    images the scene was trained on), clipped as the scene model clips its own rays. With ``images`` (one ``(H, W,
    3)`` uint8 image a frame, at its camera's size): also their colours ``(R, 3)`` in [0, 1]."""
    from nsim.rendering.renderer import camera_rays

    parts, colours = [], []
    for k, (camera, c2w) in enumerate(frames):
        rays, _, valid = camera_rays(model, camera, c2w)
        pick = torch.zeros(camera.height, camera.width, dtype=torch.bool, device=valid.device)
        pick[::stride, ::stride] = True
        idx = torch.nonzero(pick.view(-1) & valid.bool(), as_tuple=True)[0]
        parts.append(rays[idx])
        if images is not None:
            img = np.asarray(images[k])
            if img.shape[:2] != (camera.height, camera.width):
                raise InputError(f"bake: training image {k} is {img.shape[1]}x{img.shape[0]}, its camera "
                                 f"{camera.width}x{camera.height}")
            flat = torch.as_tensor(img.reshape(-1, img.shape[-1])[:, :3])
            colours.append(flat[idx.cpu()].float().div(255.0))
    if not parts:
        raise InputError("bake: visibility culling and the surface need the training cameras, and there are none")
    rays = Rays(*(torch.cat([getattr(r, f) for r in parts]) for f in ("origins", "dirs", "near", "far")))
    return rays if images is None else (rays, torch.cat(colours).to(rays.origins.device))


def decoder_of(model) -> ColorDecoder:
    """The colour head of a ``SceneModel`` with its mean appearance embedding (over the training images)."""
    codes = model.field.appearance_codes(None, 1, "mean", model.train_mask)
    return ColorDecoder.from_field(model.field, None if codes is None else codes[0])


def finish_bake(model, grid, plan: BakePlan, density: Tensor, features: Tensor, cfg: BakeConfig) -> BakedScene:
    """:func:`assemble` for a ``SceneModel`` baked over its ``OccupancyGrid``: pruned at ``cfg.prune_density``
    (default: the grid's own threshold), its colour head and background (no culling: :func:`bake_passes`)."""
    prune = grid.density_threshold if cfg.prune_density is None else cfg.prune_density
    return assemble(plan, density, features, decoder_of(model).to(density.device), cfg, model.sampler_cfg.background,
                    model.sampler_cfg.background_rgb, prune)


def bake_passes(model, grid, cfg: BakeConfig, frames, evaluate) -> BakedScene:
    """The whole bake, its lattices evaluated by ``evaluate(plan, cfg, name) -> (density (U,), features (U, G))``
    (``name``: ``"cull"`` or ``"bake"``, so that a caller can keep the two apart).

    Without ``cull_weight``: one bake at ``voxel_m``. With it: a first bake at ``cull_voxel_m`` (default
    ``voxel_m``), culled by the training cameras ``frames`` (``(camera, cam_to_world)`` pairs:
    :func:`training_rays`, :func:`brick_visibility`, :func:`cull`); when ``voxel_m`` cuts the cells finer, a
    second bake at ``voxel_m`` over the kept cells alone."""
    cfg.check()
    if cfg.cull_weight is None:
        plan = plan_bake(grid, cfg)
        return finish_bake(model, grid, plan, *evaluate(plan, cfg, "bake"), cfg)
    first_cfg = cfg if cfg.cull_voxel_m is None else dataclasses.replace(cfg, voxel_m=cfg.cull_voxel_m)
    plan = plan_bake(grid, first_cfg)
    first = finish_bake(model, grid, plan, *evaluate(plan, first_cfg, "cull"), first_cfg)
    culled = cull(first, brick_visibility(first, training_rays(model, frames or [], cfg.cull_stride)), cfg.cull_weight)
    if plan.bricks_per_side == bricks_per_side(grid.cell_m, cfg.voxel_m):
        return culled
    kept = dataclasses.replace(grid, occupied=culled.brick_index >= 0)
    plan = plan_bake(kept, cfg)
    fine = finish_bake(model, kept, plan, *evaluate(plan, cfg, "bake"), cfg)
    meta = {**fine.meta, "occupied_cells": culled.meta["occupied_cells"],
            "pruned_bricks": culled.meta["pruned_bricks"] + fine.meta["pruned_bricks"],
            "culled_bricks": culled.meta["culled_bricks"], "cull_weight": cfg.cull_weight,
            "cull_voxel_m": float(first_cfg.voxel_m),
            "lattice_points_evaluated": culled.meta["lattice_points_evaluated"] + plan.n_points}
    return dataclasses.replace(fine, meta=meta)


def nerf_targets(model, grid, rays: Rays, chunk: int = 8192) -> tuple[Tensor, Tensor, Tensor]:
    """The NeRF's median depth ``(R,)``, accumulation ``(R,)`` and colour ``(R, 3)`` of ``rays``: what a surface is
    fitted to (``method: proposal``, the renderer ``nsim render`` uses)."""
    from nsim.rendering.renderer import MarchConfig, render_rays

    with torch.no_grad():
        out = render_rays(model, rays, "proposal", grid, MarchConfig(), chunk)
    return out.depth_median, out.accumulation, out.rgb.clamp(0.0, 1.0)


def bake_surface(model, baked: BakedScene, cfg: BakeConfig, frames, targets, seed: int = 0,
                 images: list | None = None) -> BakedScene:
    """``baked`` with its surface (``nsim.rendering.surface``): marching cubes of its density, fitted to the NeRF's
    median depths on the training rays of ``frames`` (every ``surface_stride``-th pixel), textured with the
    training ``images``' colours there (one ``(H, W, 3)`` uint8 image a frame; None: the NeRF's colours).
    targets: ``rays -> (depth_median, accumulation, rgb)`` (:func:`nerf_targets`, or a caller's that keeps parts
    for resuming). Deterministic for one device and ``seed``."""
    from nsim.rendering.surface import MeshCaster, fit_mesh, fit_texture, mesh_of_bricks

    t0 = time.perf_counter()
    if images is not None:
        rays, pixels = training_rays(model, frames or [], cfg.surface_stride, images)
        depth, acc, _ = targets(rays)
        rgb = pixels
    else:
        rays = training_rays(model, frames or [], cfg.surface_stride)
        depth, acc, rgb = targets(rays)
    keep = torch.nonzero(acc > 0.5, as_tuple=True)[0]
    if not len(keep):
        raise InputError(f"bake: none of the {len(rays)} training rays ends on a surface in the NeRF (accumulation "
                         "0.5); set surface=false")
    near = rays.near[keep].cpu().numpy()
    d = rays.dirs[keep].cpu().numpy()
    o = rays.origins[keep].cpu().numpy() + d * near[:, None]
    t_max = np.maximum(rays.far[keep].cpu().numpy() - near, 0.0)
    target = depth[keep].cpu().numpy() - near
    t_nerf = time.perf_counter()
    level = cfg.surface_level
    if level is None:  # the field's density where the NeRF puts the surface (a seeded draw of those points)
        pick = torch.randperm(len(keep), generator=torch.Generator().manual_seed(seed))[:1 << 16].numpy()
        x = torch.as_tensor(o[pick] + d[pick] * target[pick, None], device=baked.device)
        with torch.no_grad():
            level = float(model.field.density(x)[0].float().median())
    v, f = mesh_of_bricks(baked.brick_index.cpu().numpy(), baked.density.cpu().numpy(), baked.bricks_per_side,
                          baked.aabb[0].cpu().numpy(), baked.voxel_m.cpu().numpy(), level, cfg.surface_min_area_m2)
    if not len(f):
        high = float(baked.density.max()) if baked.density.numel() else 0.0
        raise InputError(f"bake: no surface at density {level:.4g}/m (the baked density reaches {high:.3g}/m); "
                         "set surface_level below that")
    t_mesh = time.perf_counter()
    v, fit = fit_mesh(v, f, o, d, t_max, target, cfg.surface_fit_passes, cfg.surface_fit_ridge,
                      cfg.surface_fit_gate_m, cfg.surface_fit_step_m, cfg.surface_fit_smooth)
    t_fit = time.perf_counter()
    hit = MeshCaster(v, f).cast(o, d, t_max)
    on = np.nonzero(hit["face"] >= 0)[0]
    device = baked.device
    points = torch.as_tensor(o[on] + d[on] * hit["t"][on, None]).to(device)
    colours = rgb[keep][torch.as_tensor(on, device=rgb.device)].to(device)
    gen = torch.Generator().manual_seed(seed)
    texture = SurfaceTexture(baked.aabb.cpu(), cfg.texture_levels, cfg.texture_log2_size, cfg.texture_max_resolution,
                             cfg.texture_width, generator=gen).to(device)
    every = max(1, cfg.texture_steps // 10)
    psnr_fit = fit_texture(texture, points, colours, cfg.texture_steps, cfg.texture_batch, cfg.texture_lr, gen,
                           on_step=lambda s: s % every == every - 1 and log.info(
                               "bake: surface texture step %d/%d", s + 1, cfg.texture_steps))
    t_tex = time.perf_counter()
    rel = np.abs(hit["t"][on] - target[on]) / np.maximum(target[on], 1e-6)
    stats = {"level_per_m": round(level, 6), "texture_from": "nerf" if images is None else "images", "training_rays": len(rays), "rays_fitted": int(len(keep)),
             "rays_on_surface": int(len(on)), "fit": fit["passes"],
             "depth_rel_error_median": float(np.median(rel)) if len(rel) else None,
             "texture_psnr_fit": round(psnr_fit, 3)}
    log.info("bake: surface of %d faces; training depth error median %.3f %%; texture %.2f dB on its points; "
             "seconds: NeRF %.1f, mesh %.1f, fit %.1f, texture %.1f", len(f),
             100 * (stats["depth_rel_error_median"] or 0.0), psnr_fit, t_nerf - t0, t_mesh - t_nerf, t_fit - t_mesh,
             t_tex - t_fit)
    return dataclasses.replace(baked, surface=BakedSurface(v, f, texture, stats))


@torch.no_grad()
def bake(model, grid, cfg: BakeConfig = BakeConfig(), frames=None) -> BakedScene:
    """Bake a ``SceneModel`` over its ``OccupancyGrid`` (same device) into a :class:`BakedScene`; ``frames``: the
    training cameras, ``(camera, cam_to_world)`` pairs, for ``cfg.cull_weight`` (:func:`bake_passes`) and
    ``cfg.surface`` (:func:`bake_surface`)."""
    model.eval()

    def evaluate(plan: BakePlan, c: BakeConfig, _name: str) -> tuple[Tensor, Tensor]:
        sig, feats = [], []
        for a in range(0, plan.n_points, c.chunk_points):
            s, f = evaluate_lattice(model.field, plan, c, a, min(plan.n_points, a + c.chunk_points))
            sig.append(s)
            feats.append(f)
        device = grid.aabb.device
        density = torch.cat(sig) if sig else torch.zeros(0, device=device)
        return density, torch.cat(feats) if feats else torch.zeros(0, model.field_cfg.geo_feat_dim, device=device)

    baked = bake_passes(model, grid, cfg, frames, evaluate)
    if cfg.surface:
        baked = bake_surface(model, baked, cfg, frames, lambda r: nerf_targets(model, grid, r))
    return baked


__all__ = ["BakeConfig", "BakePlan", "assemble", "bake", "bake_passes", "bake_surface", "brick_visibility", "cull",
           "decoder_of", "evaluate_lattice", "finish_bake", "nerf_targets", "plan_bake", "training_rays"]
