"""The scene model: scene field + its training sampler, and its render outputs.

``SceneModel.render(rays)`` renders with the sampler the model is trained with, one of:

``sampler.kind: proposal`` (``render_proposal``; mip-NeRF 360 / nerfacto)
    ``n_0`` uniform bins in the spacing coordinate -> proposal field 0 -> resample ``n_1`` bins
    from its weights -> proposal field 1 -> ... -> ``final_samples`` bins -> scene field
    (density and colour) -> volume rendering (``nsim.volume.quadrature``).
``sampler.kind: grid`` (``render_grid``; instant-NGP / nerfacc)
    A coarse density grid over the scene box, kept by the trainer as a decaying maximum of the
    field's density (``update_grid``), marks the cells worth sampling. Rays are marched with a
    constant step through occupied cells only; the densities of those samples are evaluated
    block by block without gradients to find where each ray's transmittance falls below
    ``grid_stop_transmittance`` (early termination); only the samples before that point are
    evaluated again with gradients, with colour, and volume-rendered. On a CPU this costs a
    fraction of the proposal sampler's samples per ray once free space is carved out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from nsim.config import param
from nsim.fields.hash_encoding import HashEncoding
from nsim.fields.scene_field import ProposalField, ProposalFieldConfig, SceneField, SceneFieldConfig
from nsim.rendering.samplers import SPACINGS, pdf_resample, spacing_to_t, uniform_bins
from nsim.volume import quadrature
from nsim.volume.rays import Rays
from nsim.volume.samples import RaySamples, RenderOutput

SAMPLER_KINDS = ("proposal", "grid")
BACKGROUNDS = ("constant", "last_sample")


@dataclass(frozen=True)
class SamplerConfig:
    """Rays and the proposal sampler.

    near_m / far_m: ray range in metres; with ``clip_rays_to_box`` rays also stop where they
    leave the scene box (an enclosed room), else they run to ``far_m`` through the contracted
    space (open scenes). proposal_samples: samples per proposal stage (one proposal field
    each); final_samples: scene-field samples per ray. The proposal fields share the
    ``proposal_hash_*`` sizes except the finest resolution, one per field.

    kind: ``proposal`` or ``grid`` (see the module docstring). The ``grid_*`` settings (kind
    ``grid``): cell size of the density grid; marching step; ``grid_samples_per_ray``, the
    mean number of marching samples per ray a batch may take before the step grows (early in
    training, when every cell is still occupied, the step is enlarged so a batch never costs
    more than this); early-termination transmittance; marching block (samples per ray
    evaluated at once); the density (1/m) above which a cell is occupied (lowered to the grid's
    mean when that is smaller, as instant-NGP does); the grid update: every ``grid_update_every``
    training steps the grid is multiplied by ``grid_decay`` and a ``grid_update_fraction`` of
    its cells (all of them during the first ``grid_warmup_steps``) take the maximum of it and
    the field's density at a random point in the cell.

    background: what the light a ray has left after its last sample (``1 - accumulation``) is
    composited over: ``constant`` (the default), ``background_rgb``; ``last_sample`` (nerfacto's
    default), the colour of the ray's last sample (rays with no sample: ``background_rgb``). In a
    closed room every training ray ends on a surface, and over black a pixel's colour can only
    come from density, which depth and LiDAR need: over ``last_sample``, or over a grey
    constant, the micro test's model rendered its colours with almost no density and had no
    depth at all. Where the capture saw nothing (a ceiling it never looked at) the ray keeps
    its light; ``nsim render``'s ``fill`` decides what such pixels show.
    """

    kind: str = param("proposal", choices=SAMPLER_KINDS)
    near_m: float = param(0.05, ge=0.0)
    far_m: float = param(30.0, gt=0.0)
    clip_rays_to_box: bool = True
    spacing: str = param("linear", choices=SPACINGS)
    lindisp_break_m: float = param(1.0, gt=0.0)
    proposal_samples: tuple[int, ...] = (256, 96)
    final_samples: int = param(48, ge=1, le=1024)
    single_jitter: bool = True
    histogram_padding: float = param(0.01, ge=0.0)
    proposal_hash_levels: int = param(5, ge=1, le=16)
    proposal_hash_features_per_level: int = param(2, choices=(1, 2, 4, 8))
    proposal_hash_log2_table_size: int = param(17, ge=8, le=22)
    proposal_hash_base_resolution: int = param(16, ge=2)
    proposal_hash_max_resolutions: tuple[int, ...] = (128, 256)
    proposal_hidden_dim: int = param(16, ge=4, le=256)
    background: str = param("constant", choices=BACKGROUNDS)
    background_rgb: tuple[float, float, float] = (0.0, 0.0, 0.0)
    grid_cell_m: float = param(0.1, gt=0.0)
    grid_step_m: float = param(0.02, gt=0.0)
    grid_samples_per_ray: int = param(96, ge=1)
    grid_stop_transmittance: float = param(1e-4, ge=0.0, lt=1.0)
    grid_block_steps: int = param(24, ge=1)
    grid_density_threshold: float = param(0.5, gt=0.0)
    grid_update_every: int = param(16, ge=1)
    grid_update_fraction: float = param(0.25, gt=0.0, le=1.0)
    grid_warmup_steps: int = param(256, ge=0)
    grid_decay: float = param(0.8, gt=0.0, le=1.0)

    def __post_init__(self) -> None:
        if self.far_m <= self.near_m:
            raise ValueError(f"far_m ({self.far_m}) must exceed near_m ({self.near_m})")
        if not self.proposal_samples or any(n < 1 for n in self.proposal_samples):
            raise ValueError(f"proposal_samples: expected at least one positive count, got {list(self.proposal_samples)}")
        if len(self.proposal_hash_max_resolutions) != len(self.proposal_samples):
            raise ValueError(
                f"proposal_hash_max_resolutions: expected one per proposal stage ({len(self.proposal_samples)}), "
                f"got {list(self.proposal_hash_max_resolutions)}"
            )
        if not all(0.0 <= c <= 1.0 for c in self.background_rgb):
            raise ValueError(f"background_rgb: expected values in [0, 1], got {list(self.background_rgb)}")

    def proposal_field_config(self, k: int) -> ProposalFieldConfig:
        return ProposalFieldConfig(self.proposal_hash_levels, self.proposal_hash_features_per_level,
                                   self.proposal_hash_log2_table_size, self.proposal_hash_base_resolution,
                                   self.proposal_hash_max_resolutions[k], self.proposal_hidden_dim)


class SceneModel(nn.Module):
    """Scene field + proposal fields + sampler settings; ``aabb (2, 3)`` is the scene box (metres)."""

    def __init__(self, field_cfg: SceneFieldConfig, sampler_cfg: SamplerConfig, aabb: Tensor, n_images: int,
                 backend: str = "torch", generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.field_cfg = field_cfg
        self.sampler_cfg = sampler_cfg
        aabb = torch.as_tensor(aabb, dtype=torch.float32)
        self.register_buffer("aabb", aabb.clone())
        self.field = SceneField(field_cfg, aabb, n_images, backend=backend, generator=generator)
        self.proposals = nn.ModuleList(
            ProposalField(sampler_cfg.proposal_field_config(k), aabb, generator=generator, contract=field_cfg.contract)
            for k in range(len(sampler_cfg.proposal_samples) if sampler_cfg.kind == "proposal" else 0)
        )
        for enc in (m for m in self.modules() if isinstance(m, HashEncoding)):
            enc.compile_indices = field_cfg.compile_indices
        if sampler_cfg.kind == "grid":
            from nsim.rendering.occupancy import grid_shape

            shape = grid_shape(aabb, sampler_cfg.grid_cell_m)
            # grid_density: (X, Y, Z) decaying max of the density (1/m); grid_occupied: (X, Y, Z),
            # all cells occupied until the first update
            self.register_buffer("grid_density", torch.zeros(shape))
            self.register_buffer("grid_occupied", torch.ones(shape, dtype=torch.bool))
        self.register_buffer("background", torch.tensor(sampler_cfg.background_rgb, dtype=torch.float32))
        # which images the "mean" appearance averages over (the training images; set by the trainer)
        self.register_buffer("train_mask", torch.ones(max(1, n_images), dtype=torch.bool))

    # ------------------------------------------------------------------ dispatch
    def render(self, rays: Rays, generator: torch.Generator | None = None, anneal: float = 1.0,
               appearance: str | int | Tensor = "mean", return_samples: bool = False,
               proposal_grad: bool = False) -> RenderOutput:
        """Render ``rays`` with the model's own sampler (``sampler.kind``); arguments as
        :meth:`render_proposal` (``anneal`` and ``proposal_grad`` only matter there)."""
        if self.sampler_cfg.kind == "grid":
            return self.render_grid(rays, generator=generator, appearance=appearance, return_samples=return_samples)
        return self.render_proposal(rays, generator=generator, anneal=anneal, appearance=appearance,
                                    return_samples=return_samples, proposal_grad=proposal_grad)

    def ray_background(self, last_rgb: Tensor, has_last: Tensor | None = None) -> Tensor:
        """Per-ray background ``(R, 3)`` (``SamplerConfig.background``): for ``last_sample``,
        ``last_rgb (R, 3)``, the colour of each ray's last sample, where ``has_last (R,)`` (default:
        every ray); otherwise, and for rays without a last sample, ``background_rgb``."""
        const = self.background.to(last_rgb.dtype).expand_as(last_rgb)
        if self.sampler_cfg.background != "last_sample":
            return const
        if has_last is None:
            return last_rgb
        return torch.where(has_last[:, None], last_rgb, const)

    # ------------------------------------------------------------------ the occupancy-grid sampler
    def _grid_query(self, x_world: Tensor) -> Tensor:
        """Occupancy of the training grid's cells at ``x_world (..., 3)`` (outside the box: free)."""
        occ = self.grid_occupied
        shape_t = torch.tensor(occ.shape, device=x_world.device)
        rel = (x_world - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        ijk = torch.floor(rel * shape_t).long()
        inside = ((ijk >= 0) & (ijk < shape_t)).all(-1)
        ijk = torch.minimum(ijk.clamp(min=0), shape_t - 1)
        flat = (ijk[..., 0] * occ.shape[1] + ijk[..., 1]) * occ.shape[2] + ijk[..., 2]
        return occ.reshape(-1)[flat] & inside

    def _grid_candidates(self, rays: Rays, jitter: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Marching samples in occupied cells, ray-major and ordered along each ray.

        jitter: (R,) in [0, 1), the offset of every ray's first sample in steps. Returns
        ``counts (R,)`` and packed ``ray (M,)``, ``t0 (M,)``, ``t1 (M,)`` (metres). When the batch
        would take more than ``grid_samples_per_ray`` samples per ray on average, the step grows
        by the smallest integer factor that brings it under."""
        cfg = self.sampler_cfg
        n = len(rays)
        device = rays.origins.device
        length = (rays.far - rays.near).clamp(min=0.0)
        budget = cfg.grid_samples_per_ray * max(1, n)
        step = cfg.grid_step_m
        for _attempt in range(8):
            n_steps = max(1, int(math.ceil(float(length.max()) / step))) if n else 1
            rows, t_list = [], []
            total = 0
            block = max(1, (1 << 21) // max(1, n))  # bounds the (R, K, 3) positions to ~2M points
            for start in range(0, n_steps, block):
                k = torch.arange(start, min(n_steps, start + block), device=device, dtype=torch.float32)
                t0 = rays.near[:, None] + (k[None, :] + jitter[:, None]) * step  # (R, K)
                mid = 0.5 * (t0 + torch.minimum(t0 + step, rays.far[:, None]))  # where the density is evaluated
                x = rays.origins[:, None, :] + rays.dirs[:, None, :] * mid[..., None]
                keep = (t0 < rays.far[:, None]) & self._grid_query(x)
                r, c = torch.nonzero(keep, as_tuple=True)
                rows.append(r)
                t_list.append(t0[r, c])
                total += int(r.numel())
            if total <= budget or n == 0:
                break
            step = step * int(math.ceil(total / budget))
        ray = torch.cat(rows)
        t0 = torch.cat(t_list)
        # blocks were concatenated step-major within each block: sort by (ray, t) (stable, exact)
        order = torch.argsort(ray * (n_steps + 1) + torch.round((t0 - rays.near[ray]) / step).long(), stable=True)
        ray, t0 = ray[order], t0[order]
        t1 = torch.minimum(t0 + step, rays.far[ray])
        counts = torch.bincount(ray, minlength=n)
        return counts, ray, t0, t1

    @staticmethod
    def _slots(counts: Tensor, ray: Tensor) -> Tensor:
        """Position of each packed sample within its ray: ``(M,)``."""
        starts = torch.cumsum(counts, 0) - counts
        return torch.arange(ray.shape[0], device=ray.device) - starts[ray]

    def render_grid(self, rays: Rays, generator: torch.Generator | None = None, appearance: str | int | Tensor = "mean",
                    return_samples: bool = False) -> RenderOutput:
        """Render ``rays`` with the occupancy-grid marcher (see the module docstring).

        generator: jitters every ray's first sample (training); None starts each ray half a step
        in (deterministic rendering). Gradients flow through the surviving samples only."""
        cfg = self.sampler_cfg
        n = len(rays)
        device = rays.origins.device
        if generator is not None:
            jitter = torch.rand(n, generator=generator).to(device)
        else:
            jitter = torch.full((n,), 0.5, device=device)
        # without gradients, the first pass's densities and features are reused (no second pass)
        need_geo = not (torch.is_grad_enabled() and self.training)
        with torch.no_grad():
            counts, ray, t0, t1 = self._grid_candidates(rays, jitter)
            slot = self._slots(counts, ray)
            s_max = int(counts.max()) if n and ray.numel() else 0
            # block-wise early termination: densities of alive rays' next block of samples only
            keep = torch.zeros_like(ray, dtype=torch.bool)
            log_trans = torch.zeros(n, device=device)  # -sum sigma delta so far
            sigma_pass1 = torch.zeros(ray.shape[0], device=device)
            geo_pass1 = None
            blk = cfg.grid_block_steps
            stop = math.log(cfg.grid_stop_transmittance) if cfg.grid_stop_transmittance > 0 else -math.inf
            for start in range(0, s_max, blk):
                alive = log_trans > stop
                sel = alive[ray] & (slot >= start) & (slot < start + blk)
                if not bool(sel.any()):
                    break
                idx = torch.nonzero(sel, as_tuple=True)[0]
                mid = 0.5 * (t0[idx] + t1[idx])
                x = rays.origins[ray[idx]] + rays.dirs[ray[idx]] * mid[:, None]
                sig, geo = self.field.density(x)
                sig = sig.float()
                sigma_pass1[idx] = sig
                if need_geo:
                    if geo_pass1 is None:
                        geo_pass1 = torch.zeros(ray.shape[0], geo.shape[-1], device=device, dtype=geo.dtype)
                    geo_pass1[idx] = geo
                # transmittance before each sample of the block, per ray (samples are ray-major)
                r = ray[idx]
                tau, before_block = quadrature.packed_optical_depth(sig, t1[idx] - t0[idx], r)
                t_before = log_trans[r].double() - before_block
                keep[idx] = t_before > stop
                log_trans = log_trans - torch.zeros(n, device=device, dtype=torch.float64).index_add_(0, r, tau).float()
            ray, t0, t1 = ray[keep], t0[keep], t1[keep]
            counts = torch.bincount(ray, minlength=n)
            slot = self._slots(counts, ray)
            s_pad = max(1, int(counts.max()) if ray.numel() else 1)
        mid = 0.5 * (t0 + t1)
        if need_geo:
            sigma = sigma_pass1[keep]
            geo = geo_pass1[keep] if geo_pass1 is not None else None
        else:
            x = rays.origins[ray] + rays.dirs[ray] * mid[:, None]
            sigma, geo = self.field.density(x)
            sigma = sigma.float()
        image_index = None if rays.image_index is None else rays.image_index[ray]
        if ray.numel():
            codes = self.field.appearance_codes(image_index, ray.shape[0], appearance, self.train_mask)
            rgb = self.field.color(geo, rays.dirs[ray], codes).float()
        else:
            rgb = torch.zeros(0, 3, device=device)
        # padded (R, S) layout for volume rendering; padding: empty intervals at the far end
        far = rays.far[:, None].expand(n, s_pad)
        t0_p = far.clone().index_put((ray, slot), t0)
        t1_p = far.clone().index_put((ray, slot), t1)
        sigma_p = torch.zeros(n, s_pad, device=device, dtype=sigma.dtype).index_put((ray, slot), sigma)
        rgb_p = torch.zeros(n, s_pad, 3, device=device, dtype=rgb.dtype).index_put((ray, slot), rgb)
        weights, _ = quadrature.render_weights(sigma_p, t1_p - t0_p)
        acc = weights.sum(-1)
        # each ray's last kept sample: slot counts - 1 (rays without samples: background_rgb)
        last = rgb_p[torch.arange(n, device=device), (counts - 1).clamp(min=0)] if n else rgb_p[:, 0]
        bg = self.ray_background(last, counts > 0)
        out_rgb = quadrature.accumulate(weights, rgb_p) + (1.0 - acc)[:, None] * bg
        mid_p = 0.5 * (t0_p + t1_p)
        depth = torch.where(acc > quadrature.EPS, quadrature.expected_depth(weights, mid_p, acc), rays.far)
        return RenderOutput(
            rgb=out_rgb,
            depth=depth,
            depth_median=quadrature.median_depth(weights, mid_p),
            accumulation=acc,
            weights=weights,
            samples=RaySamples(t0_p, t1_p, sigma_p, rgb_p) if return_samples else None,
            background=bg,
        )

    @torch.no_grad()
    def update_grid(self, generator: torch.Generator, all_cells: bool = False, chunk: int = 1 << 16) -> float:
        """One training-grid update (see :class:`SamplerConfig`); returns the occupied fraction."""
        cfg = self.sampler_cfg
        dens = self.grid_density
        device = dens.device
        n_cells = dens.numel()
        if all_cells or cfg.grid_update_fraction >= 1.0:
            idx = torch.arange(n_cells, device=device)
        else:
            m = max(1, int(round(cfg.grid_update_fraction * n_cells)))
            idx = torch.randint(0, n_cells, (m,), generator=generator).to(device)
        shape = dens.shape
        ijk = torch.stack([idx // (shape[1] * shape[2]), (idx // shape[2]) % shape[1], idx % shape[2]], -1).float()
        cell = (self.aabb[1] - self.aabb[0]) / torch.tensor(shape, dtype=torch.float32, device=device)
        x = self.aabb[0] + (ijk + torch.rand(ijk.shape, generator=generator).to(device)) * cell
        sigma = torch.cat([self.field.density(x[a:a + chunk])[0].float() for a in range(0, x.shape[0], chunk)])
        flat = dens.view(-1)
        flat.mul_(cfg.grid_decay)
        flat.scatter_reduce_(0, idx, sigma, "amax")
        threshold = min(cfg.grid_density_threshold, float(flat.mean()))
        self.grid_occupied.copy_(dens > threshold)
        return float(self.grid_occupied.float().mean())

    # ------------------------------------------------------------------ the proposal sampler
    def _t_bins(self, rays: Rays, bins: Tensor) -> Tensor:
        cfg = self.sampler_cfg
        return spacing_to_t(bins, rays.near, rays.far, cfg.spacing, cfg.lindisp_break_m)

    def render_proposal(self, rays: Rays, generator: torch.Generator | None = None, anneal: float = 1.0,
                        appearance: str | int | Tensor = "mean", return_samples: bool = False,
                        proposal_grad: bool = False) -> RenderOutput:
        """Render ``rays`` with the proposal sampler (the training renderer).

        generator: jitters the samples (training); None renders deterministically. anneal:
        proposal weights are raised to this power before resampling (mip-NeRF 360's schedule).
        appearance: used for rays without ``image_index`` (see ``SceneField.appearance_codes``).
        proposal_grad: keep the proposal fields' graph (training, for the interlevel loss).
        """
        cfg = self.sampler_cfg
        n = len(rays)
        bins = uniform_bins(n, cfg.proposal_samples[0], generator, cfg.single_jitter, rays.origins.device)
        prop_weights, prop_bins = [], []
        for k, prop in enumerate(self.proposals):
            t = self._t_bins(rays, bins)
            mid = 0.5 * (t[:, 1:] + t[:, :-1])
            x = rays.origins[:, None, :] + rays.dirs[:, None, :] * mid[..., None]
            with torch.set_grad_enabled(proposal_grad and torch.is_grad_enabled()):
                sigma = prop(x.reshape(-1, 3)).view(n, -1)
                w, _ = quadrature.render_weights(sigma, t[:, 1:] - t[:, :-1])
            prop_weights.append(w)
            prop_bins.append(bins)
            n_next = cfg.proposal_samples[k + 1] if k + 1 < len(self.proposals) else cfg.final_samples
            w_resample = w.detach() ** anneal if anneal != 1.0 else w.detach()
            bins = pdf_resample(bins, w_resample, n_next, generator, cfg.single_jitter, cfg.histogram_padding)
        t = self._t_bins(rays, bins)
        t0, t1 = t[:, :-1], t[:, 1:]
        mid = 0.5 * (t0 + t1)
        x = rays.origins[:, None, :] + rays.dirs[:, None, :] * mid[..., None]
        s = mid.shape[1]
        sigma, geo = self.field.density(x.reshape(-1, 3))
        sigma = sigma.view(n, s)
        dirs = rays.dirs[:, None, :].expand(-1, s, -1).reshape(-1, 3)
        image_index = None if rays.image_index is None else rays.image_index[:, None].expand(-1, s).reshape(-1)
        codes = self.field.appearance_codes(image_index, n * s, appearance, self.train_mask)
        rgb = self.field.color(geo, dirs, codes).view(n, s, 3)
        weights, _ = quadrature.render_weights(sigma, t1 - t0)
        acc = weights.sum(-1)
        bg = self.ray_background(rgb[:, -1])
        out_rgb = quadrature.accumulate(weights, rgb) + (1.0 - acc)[:, None] * bg
        return RenderOutput(
            rgb=out_rgb,
            depth=quadrature.expected_depth(weights, mid, acc),
            depth_median=quadrature.median_depth(weights, mid),
            accumulation=acc,
            weights=weights,
            samples=RaySamples(t0, t1, sigma, rgb) if return_samples else None,
            background=bg,
            bins=bins,
            proposal_weights=prop_weights,
            proposal_bins=prop_bins,
        )


# ---------------------------------------------------------------------- saving and loading
MODEL_FILE = "model.pt"
SCENE_FILE = "scene.json"


def save_model(out_dir, model: SceneModel, extra: dict | None = None) -> None:
    """Write ``model.pt`` (state dict) and ``scene.json`` (configs, scene box, backend, ``extra``)."""
    import json
    from pathlib import Path

    from nsim.config import to_dict

    out_dir = Path(out_dir)
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    torch.save(state, out_dir / MODEL_FILE)
    meta = {
        "format": 1,
        "field": to_dict(model.field_cfg),
        "sampler": to_dict(model.sampler_cfg),
        "aabb_m": model.aabb.cpu().tolist(),
        "n_images": int(model.field.appearance.weight.shape[0]) if model.field.appearance is not None else 0,
        "hash_backend": model.field.encoding.backend,
        **(extra or {}),
    }
    (out_dir / SCENE_FILE).write_text(json.dumps(meta, indent=1) + "\n")


def load_model(model_dir, device: str | torch.device = "cpu") -> SceneModel:
    """Rebuild a :class:`SceneModel` written by :func:`save_model` (eval mode, on ``device``)."""
    import json
    from pathlib import Path

    from nsim.config import from_dict
    from nsim.errors import InputError

    model_dir = Path(model_dir)
    try:
        meta = json.loads((model_dir / SCENE_FILE).read_text())
    except (FileNotFoundError, json.JSONDecodeError) as exc:
        raise InputError(f"{model_dir / SCENE_FILE}: cannot read the scene description ({exc.__class__.__name__})") from None
    field_cfg = from_dict(SceneFieldConfig, meta["field"])
    sampler_cfg = from_dict(SamplerConfig, meta["sampler"])
    backend = meta.get("hash_backend", "torch")
    model = SceneModel(field_cfg, sampler_cfg, torch.tensor(meta["aabb_m"]), meta["n_images"], backend=backend)
    state = torch.load(model_dir / MODEL_FILE, map_location="cpu", weights_only=True)
    model.load_state_dict(state)
    # the training images' mean colour (scene trainer; absent from older checkpoints): nsim render's fill
    mean = meta.get("image_mean_rgb")
    model.image_mean_rgb = None if mean is None else tuple(float(c) for c in mean)
    return model.to(device).eval()
