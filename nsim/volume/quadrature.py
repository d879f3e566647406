"""Volume rendering along rays, exactly as NeRF (Mildenhall et al. 2020, eq. 3) writes it.

Samples are intervals ``[t_i, t_{i+1})`` along unit-direction rays (so ``t`` is in metres)
with density ``sigma_i`` (1/m) and colour ``c_i``:

    delta_i = t_{i+1} - t_i
    alpha_i = 1 - exp(-sigma_i delta_i)
    T_i     = exp(-sum_{j<i} sigma_j delta_j) = prod_{j<i} (1 - alpha_j)
    w_i     = T_i alpha_i,      C = sum_i w_i c_i + (1 - sum_i w_i) c_background

Shapes: rays ``(R,)``, samples ``(R, S)``, bin edges ``(R, S + 1)``; packed samples (``packed_*``: the
samples of all rays in one array, grouped by ray) ``(K,)`` with a ray index each. The proposal-sampler
losses of mip-NeRF 360 (``interlevel_loss``, ``distortion_loss``) take bin edges in the
normalised *spacing* coordinate ``s`` in ``[0, 1]`` (see ``samplers``), as the paper does.
"""

from __future__ import annotations

import torch
from torch import Tensor

EPS = 1e-10


def render_weights(sigma: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
    """``w (R, S)`` and transmittance ``T (R, S)`` from densities and interval lengths ``(R, S)``."""
    sigma_delta = sigma * deltas
    alpha = 1.0 - torch.exp(-sigma_delta)
    accumulated = torch.cumsum(sigma_delta, dim=-1)
    transmittance = torch.exp(-torch.cat([torch.zeros_like(accumulated[..., :1]), accumulated[..., :-1]], dim=-1))
    return transmittance * alpha, transmittance


def packed_optical_depth(sigma: Tensor, deltas: Tensor, ray: Tensor) -> tuple[Tensor, Tensor]:
    """Optical depth of *packed* samples (the samples of many rays in one flat array, as marchers keep them).

    sigma, deltas: ``(K,)`` densities (1/m) and interval lengths; ray: ``(K,)`` int64, each sample's ray, the
    samples grouped by ray (a ray's all consecutive) and in order along it. Returns, both ``(K,)`` float64,
    ``tau = sigma * delta`` of each sample and ``before``, the sum of ``tau`` over the samples before it on its
    ray: its transmittance is ``T = exp(-before)`` (:func:`render_weights`'s ``T`` for the padded layout). Summed
    in float64 along the whole array, each ray's sum at its first sample subtracted."""
    tau = (sigma * deltas).double()
    excl = torch.cumsum(tau, 0) - tau
    new_ray = torch.ones_like(ray, dtype=torch.bool)
    new_ray[1:] = ray[1:] != ray[:-1]
    first = torch.cummax(torch.where(new_ray, torch.arange(len(ray), device=ray.device), 0), 0)[0]
    return tau, excl - excl[first]


def packed_render_weights(sigma: Tensor, deltas: Tensor, ray: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`render_weights` for packed samples (:func:`packed_optical_depth`'s layout): ``w (K,)`` and ``T (K,)``,
    float64, ``w = T * (1 - exp(-sigma delta))``."""
    tau, before = packed_optical_depth(sigma, deltas, ray)
    transmittance = torch.exp(-before)
    return transmittance * -torch.expm1(-tau), transmittance


def accumulate(weights: Tensor, values: Tensor) -> Tensor:
    """``sum_i w_i v_i``: weights ``(R, S)``, values ``(R, S, C)`` -> ``(R, C)``."""
    return torch.einsum("rs,rsc->rc", weights, values)


def expected_depth(weights: Tensor, t_mid: Tensor, accumulation: Tensor | None = None) -> Tensor:
    """Normalised expected depth ``sum w t / sum w`` ``(R,)``: the weights' mean, whatever their total."""
    if accumulation is None:
        accumulation = weights.sum(-1)
    depth = (weights * t_mid).sum(-1) / accumulation.clamp(min=EPS)
    return torch.clamp(depth, t_mid[..., 0], t_mid[..., -1])


def median_depth(weights: Tensor, t_mid: Tensor) -> Tensor:
    """Median of the normalised weight distribution ``(R,)``: the first sample whose cumulative
    weight reaches half the ray's accumulation (the first sample when the ray is empty)."""
    cumulative = torch.cumsum(weights, dim=-1)
    half = 0.5 * cumulative[..., -1:]
    index = torch.searchsorted(cumulative.contiguous(), half.contiguous(), side="left").clamp(max=t_mid.shape[-1] - 1)
    return torch.gather(t_mid, -1, index)[..., 0]


def _outer(t0: Tensor, t1: Tensor, y1: Tensor) -> Tensor:
    """Upper envelope: the weight ``y1`` on bins ``t1`` (R, S1+1) that overlaps each bin of ``t0`` (R, S0+1)."""
    cy1 = torch.cat([torch.zeros_like(y1[..., :1]), torch.cumsum(y1, dim=-1)], dim=-1)
    n1 = y1.shape[-1]
    idx_lo = (torch.searchsorted(t1[..., :-1].contiguous(), t0[..., :-1].contiguous(), side="right") - 1).clamp(0, n1 - 1)
    idx_hi = torch.searchsorted(t1[..., 1:].contiguous(), t0[..., 1:].contiguous(), side="right").clamp(0, n1 - 1)
    return torch.gather(cy1[..., 1:], -1, idx_hi) - torch.gather(cy1[..., :-1], -1, idx_lo)


def interlevel_loss(
    final_weights: Tensor, final_bins: Tensor, proposal_weights: list[Tensor], proposal_bins: list[Tensor]
) -> Tensor:
    """mip-NeRF 360's proposal loss (eq. 13): proposal histograms must bound the final one from above.

    The final weights and bins are held fixed (``detach``); each proposal's bins are ``(R, S_k + 1)``.
    """
    w = final_weights.detach()
    c = final_bins.detach()
    loss = final_weights.new_zeros(())
    for wp, cp in zip(proposal_weights, proposal_bins, strict=True):
        bound = _outer(c, cp, wp)
        loss = loss + (torch.clamp(w - bound, min=0.0) ** 2 / (w + 1e-7)).sum(-1).mean()
    return loss


def distortion_loss(weights: Tensor, bins: Tensor) -> Tensor:
    """mip-NeRF 360's distortion loss (eq. 15), O(S) per ray, averaged over rays.

    ``sum_{i,j} w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (s_{i+1} - s_i)`` with ``m`` the bin midpoints.
    """
    return distortion_loss_intervals(weights, bins[..., :-1], bins[..., 1:])


def distortion_loss_intervals(weights: Tensor, starts: Tensor, ends: Tensor) -> Tensor:
    """:func:`distortion_loss` for intervals ``[starts, ends)`` ``(R, S)`` that need not touch
    (e.g. marching samples with gaps where empty cells were skipped), ascending along each ray.
    Zero-width padding intervals with zero weight add nothing."""
    mid = 0.5 * (starts + ends)
    width = ends - starts
    w_before = torch.cumsum(weights, dim=-1) - weights  # sum_{j<i} w_j
    wm_before = torch.cumsum(weights * mid, dim=-1) - weights * mid  # sum_{j<i} w_j m_j
    pairwise = 2.0 * (weights * (mid * w_before - wm_before)).sum(-1)  # mid ascending: |m_i - m_j| = m_i - m_j
    self_term = (weights**2 * width).sum(-1) / 3.0
    return (pairwise + self_term).mean()


def opacity_loss(accumulation: Tensor, eps: float = 1e-4) -> Tensor:
    """Mean binary entropy of the rays' ``accumulation (R,)``: zero where a ray is fully opaque
    or fully clear, largest at 1/2 (a half-transparent surface)."""
    a = accumulation.float().clamp(eps, 1.0 - eps)
    return -(a * torch.log(a) + (1.0 - a) * torch.log1p(-a)).mean()
