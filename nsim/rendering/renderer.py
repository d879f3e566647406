"""Rendering API for the later stages: any camera model and pose, LiDAR beams, chunked.

Two ways to render the same model:

``method="proposal"``
    The sampler the model was trained with (``SceneModel.render``): its proposal networks,
    or, for a model trained with ``sampler.kind: grid``, its training occupancy grid.
``method="march"``
    Ray marching with a constant step ``step_m`` from near to far, in blocks of
    ``block_steps`` samples, with early ray termination (a ray stops once its transmittance
    falls below ``stop_transmittance``), colour skipped on the lightest samples of each ray as
    long as their summed weight stays within ``color_skip_weight`` (those samples count as
    black, so the colour error is at most that much per channel), and, with an
    :class:`~nsim.rendering.occupancy.OccupancyGrid`, no field evaluation at all in free cells
    (empty-space skipping). Without the grid, with ``stop_transmittance = 0`` and
    ``color_skip_weight = 0`` every sample is evaluated: the dense reference.

    A per-sample weight threshold is not enough for the colour: a NeRF's free space carries a
    faint haze, and a thousand samples of weight 5e-5 each add up to 0.05 of the pixel (a
    1e-4 threshold cost 36 dB against the dense image on the default test room).

Every entry point returns a :class:`~nsim.volume.samples.RenderOutput`. ``render_rays`` keeps
only its per-ray fields (rgb, depth, depth_median, accumulation, background: 36 bytes a ray), chunk
by chunk, so a 1920x1080 view does not hold gigabytes of per-sample output; with
``return_samples=True`` it carries the per-sample ``(t_starts, t_ends, sigma, rgb)`` of the
samples that were evaluated, so a later renderer can merge them with another field's samples
along the same rays (``nsim.volume.compositing``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nsim.geometry.cameras import dirs_to_world, fill_invalid_dirs
from nsim.rendering.march_config import MarchConfig
from nsim.rendering.model import SceneModel
from nsim.rendering.occupancy import OccupancyGrid
from nsim.volume import quadrature
from nsim.volume.rays import Rays, make_rays
from nsim.volume.samples import RaySamples, RenderOutput

METHODS = ("proposal", "march")
AUTO = "auto"  # march with the grid when one is given, else the proposal sampler


@dataclass
class _Acc:
    rgb: Tensor
    depth: Tensor
    acc: Tensor
    trans: Tensor


@torch.no_grad()
def march(model: SceneModel, rays: Rays, grid: OccupancyGrid | None = None, cfg: MarchConfig = MarchConfig(),
          appearance: str | int | Tensor = "mean", return_samples: bool = False) -> RenderOutput:
    """Render ``rays`` by marching (see the module docstring). All rays in one call: chunk outside."""
    n = len(rays)
    device = rays.origins.device
    length = (rays.far - rays.near).clamp(min=0.0)
    n_steps = max(1, int(math.ceil(float(length.max()) / cfg.step_m))) if n else 1
    acc = _Acc(torch.zeros(n, 3, device=device), torch.zeros(n, device=device), torch.zeros(n, device=device),
               torch.ones(n, device=device))
    weights_all = torch.zeros(n, n_steps, device=device)
    skip_left = torch.full((n,), cfg.color_skip_weight, device=device)  # colour-skip budget left per ray
    kept: list[tuple[Tensor, Tensor, Tensor, Tensor, Tensor]] = []  # (ray, step, t0, sigma, rgb) of evaluated samples
    alive = torch.arange(n, device=device)
    for start in range(0, n_steps, cfg.block_steps):
        if alive.numel() == 0:
            break
        k = torch.arange(start, min(n_steps, start + cfg.block_steps), device=device)
        t0 = rays.near[alive, None] + k[None, :] * cfg.step_m  # (A, K)
        t1 = torch.minimum(t0 + cfg.step_m, rays.far[alive, None])
        inside = t1 > t0
        mid = 0.5 * (t0 + t1)
        x = rays.origins[alive, None, :] + rays.dirs[alive, None, :] * mid[..., None]
        todo = inside if grid is None else inside & grid.query(x)
        sigma = torch.zeros_like(t0)
        rgb = torch.zeros(*t0.shape, 3, device=device)
        if bool(todo.any()):
            s_todo, geo = model.field.density(x[todo])
            sigma[todo] = s_todo.to(sigma.dtype)
            weights_blk, trans_blk = quadrature.render_weights(sigma, (t1 - t0).clamp(min=0.0))
            weights_blk = weights_blk * acc.trans[alive, None]
            colour = todo
            if cfg.color_skip_weight > 0:
                # skip the lightest samples while their running sum stays within the ray's budget
                w_sorted, order = torch.sort(weights_blk, dim=-1, stable=True)
                skip_sorted = torch.cumsum(w_sorted, -1) <= skip_left[alive, None]
                skip = torch.zeros_like(todo).scatter(-1, order, skip_sorted)
                colour = todo & ~skip
                skip_left[alive] -= (weights_blk * (todo & skip)).sum(-1)
            if bool(colour.any()):
                sel = colour[todo]  # the colour samples among the density samples
                rows = torch.nonzero(colour, as_tuple=True)[0]
                dirs = rays.dirs[alive][rows]
                codes = model.field.appearance_codes(None, dirs.shape[0], appearance, model.train_mask)
                rgb[colour] = model.field.color(geo[sel], dirs, codes).to(rgb.dtype)
            acc.rgb[alive] += quadrature.accumulate(weights_blk, rgb)
            acc.depth[alive] += (weights_blk * mid).sum(-1)
            acc.acc[alive] += weights_blk.sum(-1)
            # transmittance after the block: T * exp(-sum sigma delta)
            acc.trans[alive] = acc.trans[alive] * trans_blk[:, -1] * torch.exp(-(sigma[:, -1] * (t1 - t0)[:, -1].clamp(min=0)))
            weights_all[alive[:, None], k[None, :]] = weights_blk
            if return_samples:
                r, c = torch.nonzero(todo, as_tuple=True)
                kept.append((alive[r], k[c], t0[r, c], sigma[r, c], rgb[r, c]))
        done = t1[:, -1] >= rays.far[alive] - 1e-9
        if cfg.stop_transmittance > 0:
            done |= acc.trans[alive] < cfg.stop_transmittance
        alive = alive[~done]
    bg = _march_background(model, rays, cfg, acc.trans, appearance)
    rgb = acc.rgb + (1.0 - acc.acc)[:, None] * bg
    t_mid_all = rays.near[:, None] + (torch.arange(n_steps, device=device)[None, :] + 0.5) * cfg.step_m
    depth = acc.depth / acc.acc.clamp(min=quadrature.EPS)
    depth = torch.where(acc.acc > quadrature.EPS, depth, rays.far)
    median = quadrature.median_depth(weights_all, torch.minimum(t_mid_all, rays.far[:, None]))
    samples = _pack_samples(kept, n, cfg.step_m, rays.far, device) if return_samples else None
    return RenderOutput(rgb=rgb, depth=depth, depth_median=median, accumulation=acc.acc, weights=weights_all,
                        samples=samples, background=bg)


def _march_background(model: SceneModel, rays: Rays, cfg: MarchConfig, trans: Tensor, appearance) -> Tensor:
    """Per-ray background ``(R, 3)`` for the marcher (``SamplerConfig.background``).

    ``last_sample``: the field's colour at the midpoint of the ray's last marching step (the
    interval that ends at ``far``), evaluated whether or not the occupancy grid marks that cell,
    so the dense and the grid march agree. Only rays that marched to ``far`` need it; a ray that
    stopped early (transmittance below ``stop_transmittance``) has at most that much light left
    and takes the model's ``background`` buffer, as does a ray of zero length; the other
    settings use the buffer for every ray."""
    n = len(rays)
    if model.sampler_cfg.background != "last_sample" or n == 0:
        return model.background.expand(n, 3)
    length = (rays.far - rays.near).clamp(min=0.0)
    reached = length > 0
    if cfg.stop_transmittance > 0:
        reached &= trans >= cfg.stop_transmittance
    idx = torch.nonzero(reached, as_tuple=True)[0]
    last = torch.zeros(n, 3, device=rays.origins.device)
    if idx.numel():
        k_last = torch.ceil(length[idx] / cfg.step_m) - 1  # index of the step that ends at far
        t0 = rays.near[idx] + k_last * cfg.step_m
        mid = 0.5 * (t0 + torch.minimum(t0 + cfg.step_m, rays.far[idx]))
        x = rays.origins[idx] + rays.dirs[idx] * mid[:, None]
        _, geo = model.field.density(x)
        codes = model.field.appearance_codes(None, idx.numel(), appearance, model.train_mask)
        last[idx] = model.field.color(geo, rays.dirs[idx], codes).to(last.dtype)
    return model.ray_background(last, reached)


def _pack_samples(kept, n: int, step_m: float, far: Tensor, device) -> RaySamples:
    """Evaluated samples as padded ``(R, S_max)`` arrays in ray order (padding: empty intervals)."""
    if not kept:
        z = torch.zeros(n, 0, device=device)
        return RaySamples(z, z, z, torch.zeros(n, 0, 3, device=device))
    ray = torch.cat([k[0] for k in kept])
    step = torch.cat([k[1] for k in kept])
    t0 = torch.cat([k[2] for k in kept])
    sigma = torch.cat([k[3] for k in kept])
    rgb = torch.cat([k[4] for k in kept])
    order = torch.argsort(ray * (step.max() + 1) + step)
    ray, t0, sigma, rgb = ray[order], t0[order], sigma[order], rgb[order]
    counts = torch.bincount(ray, minlength=n)
    s_max = int(counts.max())
    slot = torch.arange(ray.shape[0], device=device) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
    out_t0 = far[:, None].expand(n, s_max).clone()
    out_t1 = out_t0.clone()
    out_sigma = torch.zeros(n, s_max, device=device)
    out_rgb = torch.zeros(n, s_max, 3, device=device)
    out_t0[ray, slot] = t0
    out_t1[ray, slot] = torch.minimum(t0 + step_m, far[ray])
    out_sigma[ray, slot] = sigma
    out_rgb[ray, slot] = rgb
    return RaySamples(out_t0, out_t1, out_sigma, out_rgb)


def render_rays(model: SceneModel, rays: Rays, method: str = AUTO, grid: OccupancyGrid | None = None,
                march_cfg: MarchConfig = MarchConfig(), chunk: int = 8192, appearance: str | int | Tensor = "mean",
                return_samples: bool = False) -> RenderOutput:
    """Render any rays in chunks of ``chunk`` rays (no gradients).

    method: ``proposal``, ``march`` (with ``grid`` if given; without it every sample is
    evaluated), or ``auto``: ``march`` when a grid is given, else ``proposal``.

    Returns the per-ray outputs only -- rgb, depth, depth_median, accumulation, background -- each
    chunk's copied into arrays for all ``R`` rays as soon as it is rendered and the rest of it (weights,
    bins, proposal weights: about 1 KB a ray) dropped, so memory grows by some 40 bytes a ray, not by
    a chunk's whole output per chunk; ``weights`` is then None. With ``return_samples`` the samples
    and weights of every ray are kept (padded to the longest chunk's), as a merging renderer needs.
    The values are those of the chunks, bit for bit, whichever way they are kept.
    """
    if method == AUTO:
        method = "march" if grid is not None else "proposal"
    if method not in METHODS:
        raise ValueError(f"render_rays: method must be one of {METHODS}, got {method!r}")
    if chunk < 1:
        raise ValueError(f"render_rays: chunk must be >= 1, got {chunk}")
    model.eval()
    n = len(rays)
    if n == 0:
        return _no_rays(rays, return_samples)

    def one(a: int) -> RenderOutput:
        sub = rays[a : a + chunk]
        if method == "proposal":
            return model.render(sub, appearance=appearance, return_samples=return_samples)
        return march(model, sub, grid, march_cfg, appearance, return_samples)

    with torch.no_grad():
        if return_samples:
            return _concat([one(a) for a in range(0, n, chunk)])
        out: RenderOutput | None = None
        for a in range(0, n, chunk):
            o = one(a)
            if out is None:
                out = _per_ray_like(o, n)
            for f in PER_RAY_FIELDS:
                src = getattr(o, f)
                if src is not None:
                    getattr(out, f)[a : a + len(src)] = src
            del o  # the chunk's per-sample tensors go before the next chunk is rendered
    return out


# what render_rays keeps of each chunk without return_samples (RenderOutput fields, one row a ray)
PER_RAY_FIELDS = ("rgb", "depth", "depth_median", "accumulation", "background")


def _no_rays(rays: Rays, return_samples: bool) -> RenderOutput:
    """The output for no rays (the samplers need at least one)."""
    z = rays.near.new_zeros(0)
    z3 = rays.near.new_zeros(0, 3)
    samples = RaySamples(z[:, None], z[:, None], z[:, None], z3[:, None]) if return_samples else None
    return RenderOutput(rgb=z3, depth=z, depth_median=z.clone(), accumulation=z.clone(), background=z3.clone(),
                        weights=z[:, None] if return_samples else None, samples=samples)


def _per_ray_like(o: RenderOutput, n: int) -> RenderOutput:
    """Empty per-ray arrays for ``n`` rays shaped, typed and placed like chunk output ``o``'s."""

    def like(t: Tensor | None) -> Tensor | None:
        return None if t is None else torch.empty((n, *t.shape[1:]), dtype=t.dtype, device=t.device)

    return RenderOutput(**{f: like(getattr(o, f)) for f in PER_RAY_FIELDS}, weights=None)


def _pad_cat(tensors: list[Tensor], fill: float) -> Tensor:
    s = max(t.shape[1] for t in tensors)
    padded = []
    for t in tensors:
        if t.shape[1] < s:
            pad = torch.full((t.shape[0], s - t.shape[1], *t.shape[2:]), fill, dtype=t.dtype, device=t.device)
            t = torch.cat([t, pad], dim=1)
        padded.append(t)
    return torch.cat(padded)


def _concat(outs: list[RenderOutput]) -> RenderOutput:
    if len(outs) == 1:
        return outs[0]
    samples = None
    if outs[0].samples is not None:
        ss = [o.samples for o in outs]
        far = torch.cat([s.t_ends.max(dim=1).values if s.t_ends.shape[1] else torch.zeros(s.t_ends.shape[0]) for s in ss])
        t0 = _pad_cat([s.t_starts for s in ss], float("inf"))
        t1 = _pad_cat([s.t_ends for s in ss], float("inf"))
        t0 = torch.where(torch.isinf(t0), far[:, None].expand_as(t0), t0)
        t1 = torch.where(torch.isinf(t1), far[:, None].expand_as(t1), t1)
        samples = RaySamples(t0, t1, _pad_cat([s.sigma for s in ss], 0.0), _pad_cat([s.rgb for s in ss], 0.0))
    return RenderOutput(
        rgb=torch.cat([o.rgb for o in outs]),
        depth=torch.cat([o.depth for o in outs]),
        depth_median=torch.cat([o.depth_median for o in outs]),
        accumulation=torch.cat([o.accumulation for o in outs]),
        weights=_pad_cat([o.weights for o in outs], 0.0),
        samples=samples,
        background=torch.cat([o.background for o in outs]) if outs[0].background is not None else None,
    )


@dataclass
class RenderedView:
    """One camera view: rgb (H, W, 3) in [0, 1]; depth_z / depth_median_z: (H, W) z-depth
    (metres along the optical axis, NaN where the pixel has no ray); range_m: (H, W) expected
    distance along the pixel ray; accumulation: (H, W); samples: per-pixel samples (H*W rows) or None."""

    rgb: np.ndarray
    depth_z: np.ndarray
    depth_median_z: np.ndarray
    range_m: np.ndarray
    accumulation: np.ndarray
    samples: RaySamples | None = None


def camera_rays(model: SceneModel, camera, cam_to_world: np.ndarray | Tensor) -> tuple[Rays, Tensor, Tensor]:
    """Rays through every pixel of ``camera`` at ``cam_to_world (4, 4)`` (OpenCV axes).

    Returns the rays (row-major pixels), the pixels' camera-axes directions ``(H*W, 3)`` and
    a validity mask ``(H*W,)`` (pixels the camera model cannot unproject are invalid).
    """
    device = model.aabb.device
    d, valid = fill_invalid_dirs(np.asarray(camera.pixel_dirs_cam()).reshape(-1, 3))
    d = torch.as_tensor(d, dtype=torch.float32).to(device)
    c2w = torch.as_tensor(np.asarray(cam_to_world, dtype=np.float32) if not isinstance(cam_to_world, Tensor)
                          else cam_to_world.float()).to(device)
    origins, dirs = dirs_to_world(d, c2w)
    cfg = model.sampler_cfg
    rays = make_rays(origins, dirs, cfg.near_m, cfg.far_m, model.aabb if cfg.clip_rays_to_box else None)
    return rays, d, torch.as_tensor(valid).to(device)


def render_camera(model: SceneModel, camera, cam_to_world: np.ndarray | Tensor, method: str = AUTO,
                  grid: OccupancyGrid | None = None, march_cfg: MarchConfig = MarchConfig(), chunk: int = 8192,
                  appearance: str | int | Tensor = "mean", return_samples: bool = False) -> RenderedView:
    """Render one view of any camera model (``nsim.geometry.cameras.Camera``) at ``cam_to_world (4, 4)``."""
    h, w = camera.height, camera.width
    rays, dirs_cam, valid = camera_rays(model, camera, cam_to_world)
    out = render_rays(model, rays, method, grid, march_cfg, chunk, appearance, return_samples)
    z = dirs_cam[:, 2]
    nan = torch.tensor(float("nan"), device=z.device)

    def depth_z(r: Tensor) -> np.ndarray:
        return torch.where(valid & (z > 1e-9), r * z, nan).view(h, w).cpu().numpy()

    rgb = torch.where(valid[:, None], out.rgb.clamp(0.0, 1.0), 0.0)
    return RenderedView(rgb=rgb.view(h, w, 3).cpu().numpy(), depth_z=depth_z(out.depth),
                        depth_median_z=depth_z(out.depth_median), range_m=out.depth.view(h, w).cpu().numpy(),
                        accumulation=out.accumulation.view(h, w).cpu().numpy(), samples=out.samples)


def lidar_rays(model: SceneModel, lidar_to_world: np.ndarray, lidar) -> tuple[Rays, tuple[int, int]]:
    """Rays of every beam of ``lidar`` at ``lidar_to_world (4, 4)`` (LiDAR frame x forward, y left, z up).

    lidar: a ``nsim.sensors.lidar.LidarConfig`` (beams evenly over its vertical FoV) or a rig's
    ``LidarSensor`` (its own beams, explicit ``vertical_angles_deg`` included): the beams are
    ``beams_and_config(lidar)``'s, as the oracle's ``lidar_gt``'s. Returns the rays, row-major over the
    range image (index ``ring * A + a``), with ``[near, far]`` within ``[min_range_m, max_range_m]``,
    and the range image's shape ``(channels, azimuth_samples)``.
    """
    from nsim.sensors.lidar import beams_and_config

    beams, cfg_lidar = beams_and_config(lidar)
    device = model.aabb.device
    pose = torch.as_tensor(np.asarray(lidar_to_world, dtype=np.float32), device=device)
    d = torch.as_tensor(beams.directions().reshape(-1, 3), dtype=torch.float32, device=device) @ pose[:3, :3].T
    origins = pose[:3, 3].expand_as(d)
    cfg = model.sampler_cfg
    rays = make_rays(origins, d, max(cfg.near_m, cfg_lidar.min_range_m), min(cfg.far_m, cfg_lidar.max_range_m),
                     model.aabb if cfg.clip_rays_to_box else None)
    return rays, beams.shape


def render_lidar(model: SceneModel, lidar_to_world: np.ndarray, lidar, method: str = AUTO,
                 grid: OccupancyGrid | None = None, march_cfg: MarchConfig = MarchConfig(), chunk: int = 8192,
                 min_accumulation: float = 0.5, use_median: bool = True) -> np.ndarray:
    """Range image ``(channels, azimuth_samples)`` float32 of a spinning LiDAR: a
    ``nsim.sensors.lidar.LidarConfig`` or a rig's ``LidarSensor`` (beams: :func:`lidar_rays`).

    A beam returns the median (or expected) depth of its ray; ``inf`` when the ray's opacity is
    below ``min_accumulation`` or the range is outside ``[min_range_m, max_range_m]``.
    """
    from nsim.sensors.lidar import beams_and_config

    cfg_lidar = beams_and_config(lidar)[1]
    rays, shape = lidar_rays(model, lidar_to_world, lidar)
    out = render_rays(model, rays, method, grid, march_cfg, chunk)
    r = out.depth_median if use_median else out.depth
    ok = (out.accumulation >= min_accumulation) & (r >= cfg_lidar.min_range_m) & (r <= cfg_lidar.max_range_m)
    r = torch.where(ok, r, torch.tensor(float("inf"), device=r.device))
    return r.view(shape).cpu().numpy().astype(np.float32)
