"""The scene's radiance field and the proposal density fields (nerfacto-style).

``SceneField``: world point -> scene-box normalisation and contraction (or, for a scene that
lies inside its box, the box alone) -> multiresolution
hash encoding -> density MLP -> density ``sigma`` (1/m, ``trunc_exp``) and a geometry
feature; geometry feature + spherical-harmonics direction encoding + a per-image
appearance embedding (NeRF-W) -> colour MLP -> ``rgb`` in (0, 1).

``ProposalField``: a small hash grid and a tiny MLP that give density only; the proposal
sampler uses them to decide where the scene field is evaluated.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from nsim.config import param
from nsim.errors import ConfigError
from nsim.fields.contraction import box_to_unit, world_to_unit
from nsim.fields.encodings import spherical_harmonics
from nsim.fields.hash_encoding import BACKENDS, HashEncoding
from nsim.fields.mlp import MLP


@dataclass(frozen=True)
class SceneFieldConfig:
    """The scene field's size. Hash grid: ``hash_levels`` levels of ``hash_features_per_level``
    features from ``hash_base_resolution`` to ``hash_max_resolution`` over the contracted cube,
    ``2**hash_log2_table_size`` rows per hashed level."""

    hash_levels: int = param(16, ge=1, le=32)
    hash_features_per_level: int = param(2, choices=(1, 2, 4, 8))
    hash_log2_table_size: int = param(19, ge=8, le=24)
    hash_base_resolution: int = param(16, ge=2, le=1024)
    hash_max_resolution: int = param(2048, ge=0, le=65536, help="the finest level's cells across the grid; 0: from "
                                     "the data, one cell per training pixel at the capture's median depth "
                                     "(nsim.train.scene.finest_hash_resolution)")
    hidden_dim: int = param(64, ge=4, le=1024)
    geo_feat_dim: int = param(15, ge=1, le=256)
    color_hidden_dim: int = param(64, ge=4, le=1024)
    color_hidden_layers: int = param(2, ge=0, le=8)
    sh_degree: int = param(4, ge=1, le=4)
    appearance_dim: int = param(32, ge=0, le=256, help="per-image appearance embedding (NeRF-W); 0 disables")
    appearance_init_std: float = param(1.0, ge=0.0, le=10.0, help="the embeddings' initial spread (normal, this "
                                       "standard deviation); small: images start alike and part only where the data asks")
    contract: bool = param(True, help="mip-NeRF 360 contraction beyond the scene box; false: the box fills the grid")
    backend: str = param("auto", choices=BACKENDS, help="hash encoding: torch, tcnn (CUDA) or auto")
    compile_indices: bool = param(False, help="torch.compile the hash grid's corner rows and weights (all fields): "
                                  "4x faster index arithmetic, ~20 s of compiling on first use (cached after); "
                                  "falls back to eager where compiling fails")
    density_bias: float = param(-1.0, ge=-20.0, le=20.0, help="sigma = exp(mlp + bias): sets the initial density "
                                "(exp(-1) = 0.37/m; the grid sampler wants a clear start, e.g. -3: 0.05/m)")

    def __post_init__(self) -> None:
        if self.hash_max_resolution == 1:
            raise ConfigError("field.hash_max_resolution: expected 0 (from the data) or >= 2, got 1")


@dataclass(frozen=True)
class ProposalFieldConfig:
    """One proposal density field (a small hash grid + one hidden layer)."""

    hash_levels: int = 5
    hash_features_per_level: int = 2
    hash_log2_table_size: int = 17
    hash_base_resolution: int = 16
    hash_max_resolution: int = 128
    hidden_dim: int = 16


class TruncExp(torch.autograd.Function):
    """``exp(x)`` whose gradient is clamped at ``x = 15`` (instant-NGP's density activation)."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=15.0))


def trunc_exp(x: Tensor) -> Tensor:
    return TruncExp.apply(x)


class SceneField(nn.Module):
    """Density and view-dependent colour of the scene.

    aabb: (2, 3) scene box in world metres (a buffer, saved with the weights); n_images: number
    of appearance embeddings (one per image of the capture, training and held-out alike).
    """

    def __init__(self, cfg: SceneFieldConfig, aabb: Tensor, n_images: int, backend: str = "torch",
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).clone())
        self.encoding = HashEncoding(cfg.hash_levels, cfg.hash_features_per_level, cfg.hash_log2_table_size,
                                     cfg.hash_base_resolution, cfg.hash_max_resolution, backend=backend,
                                     generator=generator)
        self.density_mlp = MLP(self.encoding.n_output_dims, cfg.hidden_dim, 1, 1 + cfg.geo_feat_dim, generator)
        color_in = cfg.sh_degree**2 + cfg.geo_feat_dim + cfg.appearance_dim
        self.color_mlp = MLP(color_in, cfg.color_hidden_dim, cfg.color_hidden_layers, 3, generator)
        self.appearance = None
        if cfg.appearance_dim > 0:
            self.appearance = nn.Embedding(max(1, n_images), cfg.appearance_dim)
            with torch.no_grad():
                self.appearance.weight.normal_(0.0, cfg.appearance_init_std, generator=generator)

    def density(self, x_world: Tensor) -> tuple[Tensor, Tensor]:
        """``x_world (N, 3)`` -> ``sigma (N,)`` (1/m) and geometry features ``(N, geo_feat_dim)``."""
        unit = world_to_unit(x_world, self.aabb) if self.cfg.contract else box_to_unit(x_world, self.aabb)
        h = self.density_mlp(self.encoding(unit))
        sigma = trunc_exp(h[..., 0].float() + self.cfg.density_bias)
        return sigma, h[..., 1:]

    def appearance_codes(self, image_index: Tensor | None, n: int, appearance: str | int | Tensor = "mean",
                         mean_over: Tensor | None = None) -> Tensor | None:
        """Appearance embeddings ``(n, appearance_dim)`` for the colour MLP (None when disabled).

        ``image_index (n,)`` picks each ray's own image (-1: the mean code, as ``"mean"``: a training ray dropped
        to the mean, ``optim.appearance_mean_share``); otherwise ``appearance`` decides: ``"mean"`` (over the
        images selected by ``mean_over``, indices or a mask; default all), an image index, ``"zero"``, or an
        explicit vector ``(appearance_dim,)``.
        """
        if self.appearance is None:
            return None
        table = self.appearance.weight
        if image_index is not None:  # no host sync on whether any ray was dropped: one select, exact either way
            codes = self.appearance(image_index.clamp(min=0))
            mean = (table if mean_over is None else table[mean_over]).mean(0)
            return torch.where((image_index < 0)[:, None], mean.to(codes), codes)
        if isinstance(appearance, Tensor):
            code = appearance.to(table)
        elif appearance == "mean":
            code = (table if mean_over is None else table[mean_over]).mean(0)
        elif appearance == "zero":
            code = torch.zeros_like(table[0])
        elif isinstance(appearance, int) and 0 <= appearance < table.shape[0]:
            code = table[appearance]
        else:
            raise ValueError(f"appearance: expected 'mean', 'zero', an image index < {table.shape[0]} or a vector, got {appearance!r}")
        return code.expand(n, -1)

    def color(self, geo: Tensor, dirs: Tensor, codes: Tensor | None) -> Tensor:
        """geo ``(N, G)``, unit dirs ``(N, 3)``, codes ``(N, A)`` or None -> rgb ``(N, 3)`` in (0, 1)."""
        parts = [spherical_harmonics(dirs, self.cfg.sh_degree).to(geo.dtype), geo]
        if codes is not None:
            parts.append(codes.to(geo.dtype))
        return torch.sigmoid(self.color_mlp(torch.cat(parts, dim=-1)).float())


class ProposalField(nn.Module):
    """Density only: ``x_world (N, 3)`` -> ``sigma (N,)``."""

    def __init__(self, cfg: ProposalFieldConfig, aabb: Tensor, generator: torch.Generator | None = None,
                 contract: bool = True) -> None:
        super().__init__()
        self.contract = contract
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).clone())
        self.encoding = HashEncoding(cfg.hash_levels, cfg.hash_features_per_level, cfg.hash_log2_table_size,
                                     cfg.hash_base_resolution, cfg.hash_max_resolution, backend="torch",
                                     generator=generator)
        self.mlp = MLP(self.encoding.n_output_dims, cfg.hidden_dim, 1, 1, generator)

    def forward(self, x_world: Tensor) -> Tensor:
        unit = world_to_unit(x_world, self.aabb) if self.contract else box_to_unit(x_world, self.aabb)
        return trunc_exp(self.mlp(self.encoding(unit))[..., 0].float() - 1.0)
