"""The marching renderer's settings (``nsim.rendering.renderer.march``), apart from the renderer: the render
stage's config holds them, and reading a config must not load torch."""

from __future__ import annotations

from dataclasses import dataclass

from nsim.config import param


@dataclass(frozen=True)
class MarchConfig:
    """The marching renderer. step_m: sample spacing along the ray (metres)."""

    step_m: float = param(0.01, gt=0.0)
    block_steps: int = param(64, ge=1)
    stop_transmittance: float = param(1e-4, ge=0.0, lt=1.0)
    color_skip_weight: float = param(1e-3, ge=0.0, lt=1.0,
                                     help="summed weight per ray whose colour may be skipped (bounds the error)")
