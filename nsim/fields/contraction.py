"""Scene box normalisation and mip-NeRF 360 scene contraction.

World points are first mapped affinely so that the scene box ``[aabb_min, aabb_max]``
(metres, world frame) becomes ``[-1, 1]^3``; then the contraction of mip-NeRF 360
(Barron et al. 2022, eq. 10)

    contract(x) = x                              if ||x|| <= 1
                  (2 - 1 / ||x||) (x / ||x||)    otherwise

maps all of space into the ball (``order=2``) or cube (``order=inf``, the default, as
nerfstudio uses with hash grids: it fills the grid) of radius 2. Finally
``(contract(x) + 2) / 4`` puts it in ``[0, 1]^3`` for the hash encoding. The box should hold
the part of the scene that needs full resolution (for a room: the room); beyond it the
resolution falls off with ``1 / distance``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def contract(x: Tensor, order: float = math.inf) -> Tensor:
    """mip-NeRF 360 contraction of ``x (..., 3)`` (already box-normalised); output norm < 2."""
    if order == math.inf:
        norm = x.abs().amax(dim=-1, keepdim=True)
    else:
        norm = torch.linalg.vector_norm(x, ord=order, dim=-1, keepdim=True)
    if not bool((norm > 1.0).any()):  # every point inside the box (a room): the identity
        return x
    safe = norm.clamp(min=1.0)
    return torch.where(norm <= 1.0, x, (2.0 - 1.0 / safe) * (x / safe))


def normalise_to_box(x_world: Tensor, aabb: Tensor) -> Tensor:
    """World ``(..., 3)`` -> box coordinates, ``aabb (2, 3)`` mapped to ``[-1, 1]^3``."""
    return (x_world - aabb[0]) / (aabb[1] - aabb[0]) * 2.0 - 1.0


def world_to_unit(x_world: Tensor, aabb: Tensor, order: float = math.inf) -> Tensor:
    """World ``(..., 3)`` -> the hash grid's ``[0, 1]^3``: box-normalise, contract, rescale."""
    return (contract(normalise_to_box(x_world, aabb), order) + 2.0) * 0.25


def unit_to_world(u: Tensor, aabb: Tensor, order: float = math.inf) -> Tensor:
    """Inverse of :func:`world_to_unit` for points strictly inside the unit cube."""
    y = u * 4.0 - 2.0
    norm = torch.linalg.vector_norm(y, ord=order, dim=-1, keepdim=True)
    safe = norm.clamp(min=1.0, max=2.0 - 1e-7)
    inv = (1.0 / (2.0 - safe)) * (y / safe)  # ||x|| = 1 / (2 - ||y||)
    x = torch.where(norm <= 1.0, y, inv)
    return (x + 1.0) * 0.5 * (aabb[1] - aabb[0]) + aabb[0]


def box_to_unit(x_world: Tensor, aabb: Tensor) -> Tensor:
    """World ``(..., 3)`` -> ``[0, 1]^3`` with the scene box filling the cube (no contraction; points
    outside the box are clamped onto it): for scenes that lie inside their box."""
    return ((x_world - aabb[0]) / (aabb[1] - aabb[0])).clamp(0.0, 1.0)
