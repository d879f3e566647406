"""The scene model: scene field + proposal fields + the proposal sampler, and its render outputs.

``SceneModel.render_proposal(rays)`` is the renderer the model is trained with (mip-NeRF 360 /
nerfacto): ``n_0`` uniform bins in the spacing coordinate -> proposal field 0 -> resample
``n_1`` bins from its weights -> proposal field 1 -> ... -> ``final_samples`` bins -> scene
field (density and colour) -> volume rendering (``nsim.rendering.volume``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from nsim.config import param
from nsim.fields.scene_field import ProposalField, ProposalFieldConfig, SceneField, SceneFieldConfig
from nsim.rendering import volume
from nsim.rendering.rays import Rays
from nsim.rendering.samplers import SPACINGS, pdf_resample, spacing_to_t, uniform_bins


@dataclass(frozen=True)
class SamplerConfig:
    """Rays and the proposal sampler.

    near_m / far_m: ray range in metres; with ``clip_rays_to_box`` rays also stop where they
    leave the scene box (an enclosed room), else they run to ``far_m`` through the contracted
    space (open scenes). proposal_samples: samples per proposal stage (one proposal field
    each); final_samples: scene-field samples per ray. The proposal fields share the
    ``proposal_hash_*`` sizes except the finest resolution, one per field.
    """

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
    background_rgb: tuple[float, float, float] = (0.0, 0.0, 0.0)

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


@dataclass
class RaySamples:
    """Samples along rays, for compositing with other fields' samples (e.g. the human field).

    t_starts, t_ends: (R, S) metres along the (unit) ray; sigma: (R, S) 1/m; rgb: (R, S, 3).
    Padding samples have ``t_starts == t_ends`` and ``sigma == 0``.
    """

    t_starts: Tensor
    t_ends: Tensor
    sigma: Tensor
    rgb: Tensor


@dataclass
class RenderOutput:
    """Per-ray results. rgb: (R, 3); depth: (R,) normalised expected range (``sum w t / sum w``,
    metres along the unit ray); depth_median: (R,) median range; accumulation: (R,) opacity;
    weights: (R, S) of the final samples; samples: the final samples (when asked for).
    Training extras: the final and proposal bins (spacing coordinate) and proposal weights."""

    rgb: Tensor
    depth: Tensor
    depth_median: Tensor
    accumulation: Tensor
    weights: Tensor
    samples: RaySamples | None = None
    bins: Tensor | None = None
    proposal_weights: list[Tensor] | None = None
    proposal_bins: list[Tensor] | None = None


def composite(samples: RaySamples, background_rgb: Tensor | None = None) -> RenderOutput:
    """Volume-render samples that may come from several fields, in any order along the ray.

    Sorts each ray's samples by ``t_starts`` first, so scene and human samples can simply be
    concatenated along ``S``. Overlapping intervals are treated as consecutive.
    """
    order = torch.argsort(samples.t_starts, dim=-1, stable=True)
    t0 = torch.gather(samples.t_starts, -1, order)
    t1 = torch.gather(samples.t_ends, -1, order)
    sigma = torch.gather(samples.sigma, -1, order)
    rgb = torch.gather(samples.rgb, 1, order[..., None].expand(-1, -1, 3))
    weights, _ = volume.render_weights(sigma, t1 - t0)
    acc = weights.sum(-1)
    out = volume.accumulate(weights, rgb)
    if background_rgb is not None:
        out = out + (1.0 - acc)[:, None] * background_rgb
    mid = 0.5 * (t0 + t1)
    return RenderOutput(out, volume.expected_depth(weights, mid, acc), volume.median_depth(weights, mid), acc, weights,
                        RaySamples(t0, t1, sigma, rgb))


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
            for k in range(len(sampler_cfg.proposal_samples))
        )
        self.register_buffer("background", torch.tensor(sampler_cfg.background_rgb, dtype=torch.float32))
        # which images the "mean" appearance averages over (the training images; set by the trainer)
        self.register_buffer("train_mask", torch.ones(max(1, n_images), dtype=torch.bool))

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
                w, _ = volume.render_weights(sigma, t[:, 1:] - t[:, :-1])
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
        weights, _ = volume.render_weights(sigma, t1 - t0)
        acc = weights.sum(-1)
        out_rgb = volume.accumulate(weights, rgb) + (1.0 - acc)[:, None] * self.background
        return RenderOutput(
            rgb=out_rgb,
            depth=volume.expected_depth(weights, mid, acc),
            depth_median=volume.median_depth(weights, mid),
            accumulation=acc,
            weights=weights,
            samples=RaySamples(t0, t1, sigma, rgb) if return_samples else None,
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
    return model.to(device).eval()
