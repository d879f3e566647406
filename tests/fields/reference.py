"""Plain, loop-based twins of the fast field code (slow; for the tests only)."""

from __future__ import annotations

import math

import torch

from nsim.fields.hash_encoding import PRIMES, GridLayout


def hash_encode_loop(x: torch.Tensor, table: torch.Tensor, layout: GridLayout) -> torch.Tensor:
    """Multiresolution hash encoding written level by level and corner by corner with Python ints.

    x: (N, 3) in [0, 1]; table: (layout.rows, F). Differentiable in both (plain autograd).
    """
    out = []
    for level, r in enumerate(layout.resolutions):
        p = x * r
        i0 = torch.clamp(torch.floor(p.detach()), 0, r - 1)
        frac = p - i0
        i0 = i0.long().tolist()
        feats = torch.zeros(x.shape[0], table.shape[1], dtype=table.dtype)
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    rows = []
                    for i, j, k in i0:
                        ci, cj, ck = i + dx, j + dy, k + dz
                        if level < layout.n_dense:
                            row = ci + cj * (r + 1) + ck * (r + 1) ** 2
                        else:
                            row = ((ci * PRIMES[0]) ^ (cj * PRIMES[1]) ^ (ck * PRIMES[2])) % layout.table_size
                        rows.append(layout.offsets[level] + row)
                    wx = frac[:, 0] if dx else 1 - frac[:, 0]
                    wy = frac[:, 1] if dy else 1 - frac[:, 1]
                    wz = frac[:, 2] if dz else 1 - frac[:, 2]
                    feats = feats + (wx * wy * wz)[:, None] * table[torch.tensor(rows)]
        out.append(feats)
    return torch.cat(out, dim=-1)


def expected_resolutions(levels: int, base: int, finest: int) -> list[int]:
    b = math.exp((math.log(finest) - math.log(base)) / (levels - 1))
    return [int(math.floor(base * b**level + 1e-9)) for level in range(levels)]
