"""Surface points from rendered rays: where each ray ends, its colour there, the density's normal.

Rays are world-frame (metres, z up) with unit directions, so ``t`` is a distance along the ray.
A ray *hits* a surface when its opacity reaches ``min_accumulation`` and its depth lies before
its far end; the point is ``origin + t dir``. Its colour is the rendered colour with the
background's share removed (``(rgb - (1 - acc) bg) / acc``: the weighted mean of the samples'
colours). Its normal is ``-grad sigma / |grad sigma|`` at the point (density increases into
matter, so the negated gradient points out of it, towards the free space the camera looked
through).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

DensityFn = Callable[[Tensor], Tensor]  # x_world (N, 3) -> sigma (N,) 1/m


def ray_hits(origins: Tensor, dirs: Tensor, depth_m: Tensor, accumulation: Tensor, far_m: Tensor,
             min_accumulation: float) -> tuple[Tensor, Tensor]:
    """Which rays hit a surface and where.

    origins, dirs: (R, 3) (dirs unit); depth_m, accumulation, far_m: (R,). Returns ``hit (R,)``
    bool (opacity >= ``min_accumulation``, finite depth before ``far_m``) and ``xyz (R, 3)``
    (``origin + depth dir``; meaningless where not hit).
    """
    hit = (accumulation >= min_accumulation) & torch.isfinite(depth_m) & (depth_m < far_m - 1e-4)
    xyz = origins + dirs * torch.nan_to_num(depth_m, posinf=0.0)[:, None]
    return hit, xyz


def surface_rgb(rgb: Tensor, accumulation: Tensor, background: Tensor) -> Tensor:
    """Colour of the samples alone ``(R, 3)`` in [0, 1]: ``(rgb - (1 - acc) bg) / acc``.

    rgb: (R, 3) rendered (composited over ``background (R, 3)``); accumulation: (R,) opacity.
    """
    acc = accumulation.clamp(min=1e-6)[:, None]
    return ((rgb - (1.0 - accumulation)[:, None] * background) / acc).clamp(0.0, 1.0)


def density_normals(density_fn: DensityFn, x_world: Tensor, chunk: int = 1 << 16) -> tuple[Tensor, Tensor]:
    """Unit normals ``-grad sigma / |grad sigma|`` at ``x_world (N, 3)`` by autograd.

    Returns ``normals (N, 3)`` and ``ok (N,)``: False where the gradient vanishes or is not
    finite (those normals are zero).
    """
    out = torch.zeros_like(x_world)
    ok = torch.zeros(x_world.shape[0], dtype=torch.bool, device=x_world.device)
    for a in range(0, x_world.shape[0], chunk):
        x = x_world[a : a + chunk].detach().clone().requires_grad_(True)
        with torch.enable_grad():
            sigma = density_fn(x)
            (grad,) = torch.autograd.grad(sigma.sum(), x)
        norm = torch.linalg.vector_norm(grad, dim=-1)
        good = torch.isfinite(grad).all(-1) & (norm > 1e-12)
        out[a : a + chunk] = torch.where(good[:, None], -grad / norm.clamp(min=1e-12)[:, None], 0.0)
        ok[a : a + chunk] = good
    return out.detach(), ok


def orient_towards_viewer(normals: Tensor, view_dirs: Tensor) -> tuple[Tensor, Tensor]:
    """Flip normals that face away from the camera that saw the point (``n . d > 0``).

    normals, view_dirs: (N, 3) (``view_dirs``: the rays' directions, camera -> point). Returns
    the oriented normals and ``flipped (N,)``.
    """
    flipped = (normals * view_dirs).sum(-1) > 0
    return torch.where(flipped[:, None], -normals, normals), flipped


def cap_indices(n: int, max_count: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``max_count`` of ``range(n)``, drawn without replacement by ``rng``, ascending."""
    if n <= max_count:
        return np.arange(n)
    return np.sort(rng.choice(n, size=max_count, replace=False))

