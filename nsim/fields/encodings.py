"""Direction encoding: real spherical harmonics up to degree 4 (16 components).

Same basis and order as instant-NGP / nerfstudio (``l = 0..degree-1``, ``m = -l..l``),
written for unit directions ``(..., 3)``; degree ``d`` gives ``d**2`` components.
"""

from __future__ import annotations

import torch
from torch import Tensor

MAX_SH_DEGREE = 4


def spherical_harmonics(dirs: Tensor, degree: int) -> Tensor:
    """Real SH basis of unit ``dirs (..., 3)``: ``(..., degree**2)`` (degree in 1..4)."""
    if not 1 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"spherical_harmonics: degree must be in 1..{MAX_SH_DEGREE}, got {degree}")
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    out = [torch.full_like(x, 0.28209479177387814)]
    if degree > 1:
        out += [-0.48860251190291987 * y, 0.48860251190291987 * z, -0.48860251190291987 * x]
    if degree > 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.94617469575755997 * zz - 0.31539156525251999,
            -1.0925484305920792 * x * z,
            0.54627421529603959 * (xx - yy),
        ]
    if degree > 3:
        out += [
            0.59004358992664352 * y * (-3.0 * xx + yy),
            2.8906114426405538 * x * y * z,
            0.45704579946446572 * y * (1.0 - 5.0 * zz),
            0.3731763325901154 * z * (5.0 * zz - 3.0),
            0.45704579946446572 * x * (1.0 - 5.0 * zz),
            1.4453057213202769 * z * (xx - yy),
            0.59004358992664352 * x * (-xx + 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)
