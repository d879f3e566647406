"""Volume compositing of sample sets along the same rays: the one definition, for training and rendering.

Several fields can put samples on the same rays (the scene NeRF, each person's human NeRF). They
are composited together in depth order: every ray's samples are concatenated over the sets and
sorted by ``t_starts`` (stably: ties keep the sets' order), then volume-rendered once
(``nsim.volume.quadrature``). Overlapping intervals are treated as consecutive (their optical
depths add). Shapes: rays ``(R,)``, set ``k`` has ``(R, S_k)`` samples, merged ``(R, S)`` with
``S = sum S_k``.

Used by the human trainer (``nsim.human.nerf.render_merged``: a person's samples with the
scene's) and by the renderer (``nsim.rendering.people.HumanSet.composite``: the scene's with
every visible person's), so the two cannot drift apart.
"""

from __future__ import annotations

import torch
from torch import Tensor

from nsim.volume import quadrature
from nsim.volume.samples import RaySamples, RenderOutput


def merge_samples(*sets: RaySamples) -> tuple[RaySamples, Tensor]:
    """Concatenate sample sets on the same rays and sort each ray's samples by ``t_starts``.

    Every set is ``(R, S_k)``; returns the merged ``(R, sum S_k)`` samples and ``source (R, S)``
    int64: the index of the set each sample came from.
    """
    if not sets:
        raise ValueError("merge_samples: expected at least one sample set")
    t0 = torch.cat([s.t_starts for s in sets], dim=1)
    t1 = torch.cat([s.t_ends for s in sets], dim=1)
    sigma = torch.cat([s.sigma for s in sets], dim=1)
    rgb = torch.cat([s.rgb for s in sets], dim=1)
    source = torch.cat([torch.full_like(s.t_starts, k, dtype=torch.long) for k, s in enumerate(sets)], dim=1)
    order = torch.argsort(t0, dim=1, stable=True)
    rgb = torch.gather(rgb, 1, order[..., None].expand(-1, -1, rgb.shape[-1]))
    merged = RaySamples(torch.gather(t0, 1, order), torch.gather(t1, 1, order), torch.gather(sigma, 1, order), rgb)
    return merged, torch.gather(source, 1, order)


def composite_sets(*sets: RaySamples, background_rgb: Tensor | None = None) -> tuple[RenderOutput, Tensor]:
    """Volume-render sample sets together in depth order, over ``background_rgb`` ((3,) or (R, 3)).

    Returns the ``RenderOutput`` (rgb, expected and median depth, accumulation, the merged
    samples' ``weights (R, S)``, the merged ``samples``, the ``background`` (R, 3) when given)
    and ``source (R, S)``, the set each merged sample came from (see :func:`set_weights`).
    """
    merged, source = merge_samples(*sets)
    t0, t1 = merged.t_starts, merged.t_ends
    weights, _ = quadrature.render_weights(merged.sigma, t1 - t0)
    acc = weights.sum(-1)
    out = quadrature.accumulate(weights, merged.rgb)
    bg = None
    if background_rgb is not None:
        bg = background_rgb.to(out)
        out = out + (1.0 - acc)[:, None] * bg
        bg = bg.expand_as(out)
    mid = 0.5 * (t0 + t1)
    return RenderOutput(out, quadrature.expected_depth(weights, mid, acc), quadrature.median_depth(weights, mid), acc, weights,
                        merged, background=bg), source


def composite(samples: RaySamples, background_rgb: Tensor | None = None) -> RenderOutput:
    """Volume-render samples in any order along the ray (e.g. several fields' concatenated along
    ``S``): :func:`composite_sets` of one set."""
    return composite_sets(samples, background_rgb=background_rgb)[0]


def set_weights(weights: Tensor, source: Tensor, n_sets: int) -> Tensor:
    """Each set's share of the merged ``weights (R, S)`` (``source (R, S)`` from
    :func:`merge_samples`): its visible opacity ``(n_sets, R)``, e.g. a person's mask."""
    return torch.stack([(weights * (source == k)).sum(-1) for k in range(n_sets)])


__all__ = ["composite", "composite_sets", "merge_samples", "set_weights"]
