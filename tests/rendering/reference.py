"""Plain twins and toy scenes for the rendering tests."""

from __future__ import annotations

import torch
from torch import nn

from nsim.rendering.model import SamplerConfig, SceneModel


def render_weights_loop(sigma: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """NeRF's weights ray by ray, sample by sample: w_i = prod_{j<i}(1 - a_j) a_i, a = 1 - exp(-s d)."""
    out = torch.zeros_like(sigma)
    for r in range(sigma.shape[0]):
        trans = 1.0
        for i in range(sigma.shape[1]):
            alpha = 1.0 - float(torch.exp(-sigma[r, i] * deltas[r, i]))
            out[r, i] = trans * alpha
            trans *= 1.0 - alpha
    return out


def distortion_quadratic(weights: torch.Tensor, bins: torch.Tensor) -> torch.Tensor:
    """mip-NeRF 360 eq. 15 with the double sum written out."""
    mid = 0.5 * (bins[..., 1:] + bins[..., :-1])
    width = bins[..., 1:] - bins[..., :-1]
    pair = (weights[:, :, None] * weights[:, None, :] * (mid[:, :, None] - mid[:, None, :]).abs()).sum((1, 2))
    return (pair + (weights**2 * width).sum(-1) / 3.0).mean()


def inverse_cdf_loop(bins: torch.Tensor, weights: torch.Tensor, u: torch.Tensor, padding: float) -> torch.Tensor:
    """Inverse transform sampling of one histogram per ray, quantile by quantile."""
    out = torch.zeros(bins.shape[0], u.shape[-1], dtype=bins.dtype)
    for r in range(bins.shape[0]):
        w = weights[r] + padding
        cdf = torch.cat([torch.zeros(1, dtype=w.dtype), torch.cumsum(w / w.sum(), 0)])
        for k, q in enumerate(u[r].tolist()):
            i = max(0, min(int((cdf <= q).sum()) - 1, len(w) - 1))
            frac = (q - float(cdf[i])) / float(cdf[i + 1] - cdf[i])
            out[r, k] = bins[r, i] + min(max(frac, 0.0), 1.0) * (bins[r, i + 1] - bins[r, i])
    return out


class BoxField(nn.Module):
    """Analytic scene: density ``sigma_in`` inside an axis-aligned box, ``sigma_out`` outside; colour
    varies with position. Duck-types the parts of ``SceneField`` the renderers use."""

    def __init__(self, lo, hi, sigma_in: float = 50.0, sigma_out: float = 0.0) -> None:
        super().__init__()
        self.lo, self.hi = torch.tensor(lo), torch.tensor(hi)
        self.sigma_in, self.sigma_out = sigma_in, sigma_out
        self.calls = 0
        self.color_calls = 0

    def density(self, x):
        self.calls += x.shape[0]
        inside = ((x >= self.lo) & (x <= self.hi)).all(-1)
        sigma = torch.where(inside, torch.full_like(x[:, 0], self.sigma_in), torch.full_like(x[:, 0], self.sigma_out))
        return sigma, x

    def appearance_codes(self, image_index, n, appearance="mean", mean_over=None):
        return None

    def color(self, geo, dirs, codes):
        self.color_calls += geo.shape[0]
        return torch.sigmoid(torch.stack([torch.sin(3 * geo[:, 0]), torch.cos(2 * geo[:, 1]), geo[:, 2]], -1))


class ToyModel(nn.Module):
    """A ``SceneModel`` stand-in around a :class:`BoxField` (for the marching renderer)."""

    ray_background = SceneModel.ray_background

    def __init__(self, field: BoxField, aabb, background: str = "constant") -> None:
        super().__init__()
        self.field = field
        self.register_buffer("aabb", torch.tensor(aabb))
        self.register_buffer("background", torch.zeros(3))
        self.register_buffer("train_mask", torch.ones(1, dtype=torch.bool))
        self.sampler_cfg = SamplerConfig(background=background)
