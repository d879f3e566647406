"""Samples along rays and what compositing them gives: the data every volume renderer in nsim exchanges.

The scene model (``nsim.rendering.model``), the human field (``nsim.human.nerf``) and the compositor
(``nsim.volume.compositing``) all speak in these two types. Shapes: rays ``(R,)``, samples ``(R, S)``.
"""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor


@dataclass
class RaySamples:
    """Samples along rays, for compositing with other fields' samples (e.g. the human field;
    ``nsim.volume.compositing``).

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
    weights: (R, S) of the final samples; samples: the final samples (when asked for);
    background: (R, 3) the colour the ray's remaining light ``1 - accumulation`` was composited
    over (``SamplerConfig.background``), for renderers that merge more samples later.
    Training extras: the final and proposal bins (spacing coordinate) and proposal weights."""

    rgb: Tensor
    depth: Tensor
    depth_median: Tensor
    accumulation: Tensor
    weights: Tensor
    samples: RaySamples | None = None
    background: Tensor | None = None
    bins: Tensor | None = None
    proposal_weights: list[Tensor] | None = None
    proposal_bins: list[Tensor] | None = None
