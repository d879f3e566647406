"""Where to put samples along rays: uniform bins in a spacing coordinate, and PDF resampling.

A ray's samples are bins with edges ``s`` in ``[0, 1]`` (the *spacing* coordinate of
mip-NeRF 360) mapped to metres ``t`` in ``[near, far]`` through a spacing function ``g``:
``t = g^-1(s g(far) + (1 - s) g(near))``. Two spacing functions:

``linear``
    ``g(t) = t``: uniform in metres (a room: every distance matters alike).
``lindisp``
    nerfstudio's piecewise ``g(t) = t / (2 b)`` for ``t < b``, ``1 - b / (2 t)`` beyond (linear up
    to ``b`` metres, then uniform in disparity): for scenes that reach far away.

``pdf_resample`` draws new bin edges by inverse transform sampling of a histogram (the
proposal sampler of mip-NeRF 360 / nerfstudio's ``PDFSampler``). Random draws come only from
an explicit ``torch.Generator`` (training); without one the samples are deterministic
(evaluation, rendering).
"""

from __future__ import annotations

import torch
from torch import Tensor

SPACINGS = ("linear", "lindisp")


def _g(t: Tensor, spacing: str, break_m: float) -> Tensor:
    if spacing == "linear":
        return t
    return torch.where(t < break_m, t / (2.0 * break_m), 1.0 - break_m / (2.0 * t.clamp(min=1e-9)))


def _g_inv(y: Tensor, spacing: str, break_m: float) -> Tensor:
    if spacing == "linear":
        return y
    return torch.where(y < 0.5, y * 2.0 * break_m, break_m / (2.0 * (1.0 - y).clamp(min=1e-9)))


def spacing_to_t(s: Tensor, near: Tensor, far: Tensor, spacing: str = "linear", break_m: float = 1.0) -> Tensor:
    """Bin edges ``s (R, K)`` in [0, 1] -> metres, with ``near, far (R,)``."""
    g_near = _g(near, spacing, break_m)[..., None]
    g_far = _g(far, spacing, break_m)[..., None]
    return _g_inv(s * g_far + (1.0 - s) * g_near, spacing, break_m)


def uniform_bins(n_rays: int, n_samples: int, generator: torch.Generator | None = None,
                 single_jitter: bool = False, device: str | torch.device = "cpu") -> Tensor:
    """``n_samples`` equal bins over [0, 1] per ray: edges ``(R, n_samples + 1)``.

    With a generator the edges are stratified-jittered (one offset per ray with ``single_jitter``,
    else per edge), the outer edges stay at 0 and 1.
    """
    edges = torch.linspace(0.0, 1.0, n_samples + 1, device=device).expand(n_rays, -1)
    if generator is None:
        return edges.contiguous()
    shape = (n_rays, 1) if single_jitter else (n_rays, n_samples + 1)
    u = torch.rand(shape, generator=generator, device=generator.device).to(device)
    mid = 0.5 * (edges[:, 1:] + edges[:, :-1])
    lower = torch.cat([edges[:, :1], mid], dim=-1)
    upper = torch.cat([mid, edges[:, -1:]], dim=-1)
    out = lower + (upper - lower) * u
    out[:, 0], out[:, -1] = 0.0, 1.0
    return out


def pdf_resample(bins: Tensor, weights: Tensor, n_samples: int, generator: torch.Generator | None = None,
                 single_jitter: bool = False, histogram_padding: float = 0.01) -> Tensor:
    """New bin edges ``(R, n_samples + 1)`` drawn from the histogram ``weights (R, S)`` on ``bins (R, S + 1)``.

    Inverse transform sampling of the piecewise-constant PDF ``(w + padding) / sum``; the
    ``n_samples + 1`` quantiles are evenly spaced (deterministic, centred) or stratified with
    jitter from ``generator``; so the new bins span where the histogram has its mass.
    """
    weights = weights.detach() + histogram_padding
    pdf = weights / weights.sum(-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[..., :1]), torch.cumsum(pdf, dim=-1).clamp(max=1.0)], dim=-1)
    n_rays, n_edges = bins.shape[0], n_samples + 1
    if generator is None:
        u = torch.linspace(0.0, 1.0 - 1.0 / n_edges, n_edges, device=bins.device, dtype=bins.dtype) + 0.5 / n_edges
        u = u.expand(n_rays, -1).contiguous()
    else:
        shape = (n_rays, 1) if single_jitter else (n_rays, n_edges)
        jitter = torch.rand(shape, generator=generator, device=generator.device).to(bins.device, bins.dtype)
        u = torch.linspace(0.0, 1.0 - 1.0 / n_edges, n_edges, device=bins.device, dtype=bins.dtype) + jitter / n_edges
        u = u.clamp(max=1.0 - 1e-6)
    idx = torch.searchsorted(cdf, u, side="right")
    below = (idx - 1).clamp(0, cdf.shape[-1] - 1)
    above = idx.clamp(0, cdf.shape[-1] - 1)
    cdf_lo, cdf_hi = torch.gather(cdf, -1, below), torch.gather(cdf, -1, above)
    bin_lo, bin_hi = torch.gather(bins, -1, below), torch.gather(bins, -1, above)
    frac = torch.nan_to_num((u - cdf_lo) / (cdf_hi - cdf_lo), nan=0.0).clamp(0.0, 1.0)
    return (bin_lo + frac * (bin_hi - bin_lo)).detach()
