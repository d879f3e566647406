"""Multiresolution hash encoding (Müller et al. 2022, instant-NGP), vectorised in PyTorch.

Level ``l`` of ``L`` is a grid of resolution ``R_l = floor(base * b**l)`` with
``b = exp((ln max - ln base) / (L - 1))`` over the unit cube ``[0, 1]^3``: a point ``x``
lies in the cell with corner ``i0 = floor(x R_l)`` (clamped to ``[0, R_l - 1]``), and its
feature is the trilinear interpolation of the ``F``-vectors stored at the cell's 8 corners
``i0 + {0, 1}^3``. A level whose ``(R_l + 1)^3`` vertices fit in ``T = 2**log2_table_size``
rows is stored densely (``i + j (R + 1) + k (R + 1)^2``); finer levels hash the vertex into
``T`` rows with the paper's ``(i * 1) xor (j * 2654435761) xor (k * 805459861) mod T``.
Every level's rows live in one flat parameter ``table (sum_l T_l, F)``; the output is
``(..., L * F)`` with level-major order ``[l0f0, l0f1, l1f0, ...]``.

The torch path (vectorised; what runs on CPU): dense levels go through ``grid_sample`` (a
fused trilinear kernel; the flat rows of a dense level *are* its voxel volume), hashed levels
through ``_GatherFunction``, which computes the ``(N, l, 8)`` corner rows and weights once per
call, gathers and sums them in one ``embedding_bag`` and has a hand-written backward: the
table gradient is a deterministic ``index_add_`` (``embedding_bag``'s own backward sorts, 5x
slower on CPU), the position gradient is analytic and only computed when ``x`` needs it
(pose refinement). ``tests/fields/reference.py`` holds a plain per-level, per-corner loop twin
that both paths are checked against.

On CUDA, ``backend="auto"`` uses tiny-cuda-nn's fused kernel when the package is importable
(it is optional; its parameters are laid out differently, so a checkpoint records which
backend made it) and falls back to the torch path otherwise.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

log = logging.getLogger(__name__)

PRIMES = (1, 2654435761, 805459861)
BACKENDS = ("auto", "torch", "tcnn")
_INT32_WRAP = 1 << 32


@dataclass(frozen=True)
class GridLayout:
    """Where each level lives in the flat table.

    resolutions: ``R_l`` per level; sizes: rows per level; offsets: first row of each level;
    n_dense: the first ``n_dense`` levels are dense, the rest hashed (resolutions grow).
    """

    resolutions: tuple[int, ...]
    sizes: tuple[int, ...]
    offsets: tuple[int, ...]
    n_dense: int
    table_size: int
    growth: float

    @property
    def levels(self) -> int:
        return len(self.resolutions)

    @property
    def rows(self) -> int:
        return self.offsets[-1] + self.sizes[-1]


def grid_layout(levels: int, log2_table_size: int, base_resolution: int, max_resolution: int) -> GridLayout:
    """Per-level resolutions and table rows; raises ValueError for an impossible layout."""
    if levels < 1 or base_resolution < 1 or max_resolution < base_resolution or not 4 <= log2_table_size <= 26:
        raise ValueError(
            f"hash grid: need levels >= 1, 1 <= base <= max resolution and 4 <= log2_table_size <= 26, got "
            f"{levels=}, {base_resolution=}, {max_resolution=}, {log2_table_size=}"
        )
    growth = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (levels - 1)) if levels > 1 else 1.0
    table = 1 << log2_table_size
    res, sizes, offsets = [], [], []
    row = 0
    for level in range(levels):
        r = max(1, int(math.floor(base_resolution * growth**level + 1e-9)))
        res.append(r)
        sizes.append(min(table, (r + 1) ** 3))
        offsets.append(row)
        row += sizes[-1]
    dense = [(r + 1) ** 3 <= table for r in res]
    n_dense = sum(dense)
    if dense != [True] * n_dense + [False] * (levels - n_dense):
        raise ValueError("hash grid: dense levels must come first (resolutions must not decrease)")
    return GridLayout(tuple(res), tuple(sizes), tuple(offsets), n_dense, table, growth)


def _level_constants(layout: GridLayout, device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
    """Float resolutions (L,), int32 per-axis multipliers (L, 3) and int32 row offsets (L,)."""
    mult = []
    for level, r in enumerate(layout.resolutions):
        if level < layout.n_dense:
            mult.append((1, r + 1, (r + 1) ** 2))
        else:  # int32 two's complement of the primes: products wrap mod 2^32, the low bits are exact
            mult.append(tuple(p - _INT32_WRAP if p >= 1 << 31 else p for p in PRIMES))
    res = torch.tensor(layout.resolutions, dtype=torch.float32, device=device)
    return res, torch.tensor(mult, dtype=torch.int32, device=device), torch.tensor(layout.offsets, dtype=torch.int32, device=device)


def corner_indices_weights(x: Tensor, layout: GridLayout, consts: tuple[Tensor, Tensor, Tensor], levels: slice):
    """Rows and trilinear weights of the 8 corners of ``x (N, 3)`` at the levels ``levels``.

    Returns ``idx (N, l, 8)`` int64 (corner order ``(dx, dy, dz)``, dz fastest), ``w (N, l, 8)``
    (float32; float64 for float64 input) and the per-axis weights ``wa (N, l, 3, 2)`` (``[1 - f, f]``).
    """
    res, mult, offsets = (c[levels] for c in consts)
    n, n_levels = x.shape[0], res.shape[0]
    start = levels.start or 0
    res = res.to(x.dtype) if x.is_floating_point() and x.dtype != torch.float16 else res
    p = x.to(res.dtype)[:, None, :] * res[:, None]  # (N, l, 3)
    i0f = torch.minimum(torch.floor(p).clamp_(min=0.0), (res - 1.0)[:, None])
    frac = p - i0f
    a0 = i0f.to(torch.int32) * mult  # (N, l, 3)
    a = torch.stack([a0, a0 + mult], dim=-1)  # (N, l, 3, 2): per-axis term of corner 0 / 1
    ax, ay, az = a[:, :, 0], a[:, :, 1], a[:, :, 2]
    if start < layout.n_dense:  # dense levels: row = i + j (R + 1) + k (R + 1)^2
        if start + n_levels > layout.n_dense:
            raise ValueError("corner_indices_weights: a call handles dense or hashed levels, not both")
        idx = (ax[..., :, None, None] + ay[..., None, :, None]) + az[..., None, None, :]
    else:
        idx = torch.bitwise_xor(ax[..., :, None, None], ay[..., None, :, None])
        idx = idx ^ az[..., None, None, :]
        idx &= layout.table_size - 1
    idx = idx.view(n, n_levels, 8) + offsets[:, None]
    wa = torch.stack([1.0 - frac, frac], dim=-1)  # (N, l, 3, 2)
    w = (wa[:, :, 0, :, None, None] * wa[:, :, 1, None, :, None] * wa[:, :, 2, None, None, :]).reshape(n, n_levels, 8)
    return idx.long(), w, wa


class _GatherFunction(torch.autograd.Function):
    """Gather + trilinear interpolation over some levels, with a deterministic index_add backward."""

    @staticmethod
    def forward(ctx, x: Tensor, table: Tensor, layout: GridLayout, consts, levels: slice):
        n = x.shape[0]
        idx, w, wa = corner_indices_weights(x, layout, consts, levels)
        n_levels = idx.shape[1]
        w = w.to(table.dtype)
        out = torch.nn.functional.embedding_bag(
            idx.view(n * n_levels, 8), table, per_sample_weights=w.view(n * n_levels, 8), mode="sum"
        )
        ctx.save_for_backward(idx, w, wa, table if ctx.needs_input_grad[0] else None)
        ctx.rows = layout.rows
        ctx.res = consts[0][levels]
        return out.view(n, n_levels * table.shape[1])

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        idx, w, wa, table = ctx.saved_tensors
        n, n_levels, _ = idx.shape
        f = grad_out.shape[1] // n_levels
        grad_out = grad_out.contiguous().view(n, n_levels, f)
        grad_x = grad_table = None
        if ctx.needs_input_grad[1]:
            src = grad_out[:, :, None, :].to(w.dtype) * w[..., None]  # (N, l, 8, F)
            grad_table = torch.zeros((ctx.rows, f), dtype=w.dtype, device=idx.device)
            grad_table.index_add_(0, idx.view(-1), src.view(-1, f))
        if ctx.needs_input_grad[0]:
            feats = table[idx.view(-1)].view(n, n_levels, 2, 2, 2, f)
            g = (feats * grad_out.view(n, n_levels, 1, 1, 1, f)).sum(-1)  # (N, l, 2, 2, 2): dLoss/dw per corner
            wx, wy, wz = wa[:, :, 0], wa[:, :, 1], wa[:, :, 2]  # (N, l, 2) each
            gx = g[:, :, 1] - g[:, :, 0]  # (N, l, 2, 2) over (dy, dz)
            gy = g[:, :, :, 1] - g[:, :, :, 0]  # over (dx, dz)
            gz = g[..., 1] - g[..., 0]  # over (dx, dy)
            dx = (gx * wy[..., :, None] * wz[..., None, :]).sum((-1, -2))
            dy = (gy * wx[..., :, None] * wz[..., None, :]).sum((-1, -2))
            dz = (gz * wx[..., :, None] * wy[..., None, :]).sum((-1, -2))
            grad_x = (torch.stack([dx, dy, dz], dim=-1) * ctx.res.to(dx.dtype)[:, None]).sum(1)  # (N, 3)
        return grad_x, grad_table, None, None, None


def _dense_level(x: Tensor, table: Tensor, layout: GridLayout, level: int) -> Tensor:
    """One dense level through ``grid_sample`` (a fused trilinear kernel): ``(N, F)``.

    Rows ``i + j (R + 1) + k (R + 1)^2`` are the volume ``[k, j, i]``; with ``align_corners``
    the grid coordinate ``2 x - 1`` puts vertex ``i`` at ``x = i / R``, the same
    interpolation as the gather path (the tests check both against the loop reference).
    """
    r1 = layout.resolutions[level] + 1
    off = layout.offsets[level]
    f = table.shape[1]
    vol = table[off : off + r1**3].view(r1, r1, r1, f).permute(3, 0, 1, 2).unsqueeze(0)  # (1, F, D=k, H=j, W=i)
    grid = (x * 2.0 - 1.0).view(1, -1, 1, 1, 3).to(table.dtype)
    out = torch.nn.functional.grid_sample(vol, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return out.view(f, -1).t()


def hash_grid_encode(
    x: Tensor, table: Tensor, layout: GridLayout, consts: tuple[Tensor, Tensor, Tensor] | None = None,
    dense_via_grid_sample: bool = True,
) -> Tensor:
    """Encode ``x (N, 3)`` in ``[0, 1]^3`` with ``table (layout.rows, F)``: returns ``(N, L * F)``.

    ``dense_via_grid_sample``: dense levels through ``grid_sample`` (faster on CPU) instead of
    the gather path; both compute the same interpolation.
    """
    if consts is None:
        consts = _level_constants(layout, x.device)
    parts = []
    nd = layout.n_dense
    if nd and dense_via_grid_sample:
        parts += [_dense_level(x, table, layout, level) for level in range(nd)]
    elif nd:
        parts.append(_GatherFunction.apply(x, table, layout, consts, slice(0, nd)))
    if nd < layout.levels:
        parts.append(_GatherFunction.apply(x, table, layout, consts, slice(nd, layout.levels)))
    return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]


def _tcnn_module(levels, features_per_level, log2_table_size, base_resolution, growth):
    try:
        import tinycudann as tcnn  # optional: the fused CUDA kernel
    except ImportError:
        return None
    return tcnn.Encoding(
        n_input_dims=3,
        encoding_config={
            "otype": "HashGrid",
            "n_levels": levels,
            "n_features_per_level": features_per_level,
            "log2_hashmap_size": log2_table_size,
            "base_resolution": base_resolution,
            "per_level_scale": growth,
        },
    )


class HashEncoding(nn.Module):
    """``x (..., 3)`` in ``[0, 1]^3`` -> features ``(..., levels * features_per_level)``.

    Points outside the unit cube are clamped onto it. ``backend``: ``torch`` (everywhere),
    ``tcnn`` (tiny-cuda-nn, CUDA only) or ``auto`` (tcnn when on CUDA and importable, decided
    at :meth:`to`-time via :meth:`resolve_backend`). The table is initialised uniformly in
    ``[-init_scale, init_scale]`` from ``generator``.
    """

    def __init__(
        self,
        levels: int = 16,
        features_per_level: int = 2,
        log2_table_size: int = 19,
        base_resolution: int = 16,
        max_resolution: int = 2048,
        init_scale: float = 1e-4,
        backend: str = "torch",
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        if backend not in BACKENDS:
            raise ValueError(f"HashEncoding.backend: expected one of {BACKENDS}, got {backend!r}")
        self.layout = grid_layout(levels, log2_table_size, base_resolution, max_resolution)
        self.features_per_level = features_per_level
        self.n_output_dims = levels * features_per_level
        self.backend = "torch"
        self._tcnn = None
        if backend == "tcnn":
            self._tcnn = _tcnn_module(levels, features_per_level, log2_table_size, base_resolution, self.layout.growth)
            if self._tcnn is None:
                raise ImportError("HashEncoding(backend='tcnn'): tinycudann is not installed")
            self.backend = "tcnn"
            self.table = None
        else:
            table = torch.empty(self.layout.rows, features_per_level)
            table.uniform_(-init_scale, init_scale, generator=generator)
            self.table = nn.Parameter(table)
        self._consts: tuple[Tensor, Tensor, Tensor] | None = None
        self.dense_via_grid_sample = True

    @staticmethod
    def resolve_backend(backend: str, device: str | torch.device) -> str:
        """``auto`` -> ``tcnn`` when ``device`` is CUDA and tinycudann imports, else ``torch``."""
        if backend != "auto":
            return backend
        if torch.device(device).type != "cuda":
            return "torch"
        try:
            import tinycudann  # noqa: F401
        except ImportError:
            log.info("tinycudann is not installed: using the torch hash encoding on CUDA")
            return "torch"
        return "tcnn"

    def forward(self, x: Tensor) -> Tensor:
        shape = x.shape[:-1]
        flat = x.reshape(-1, 3).clamp(0.0, 1.0)
        if self._tcnn is not None:
            out = self._tcnn(flat).float()
        else:
            if self._consts is None or self._consts[0].device != flat.device:
                self._consts = _level_constants(self.layout, flat.device)
            out = hash_grid_encode(flat, self.table, self.layout, self._consts, self.dense_via_grid_sample)
        return out.reshape(*shape, self.n_output_dims)
