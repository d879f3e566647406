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
by gathering their ``(N, l, 8)`` corner rows in one ``embedding_bag``; all of it is one
autograd node (``_EncodeFunction``) with a hand-written backward that fills a single table
gradient: ``grid_sample``'s backward kernel for the dense levels, a deterministic
``index_add_`` for the gathered ones, and the analytic position gradient only when ``x``
needs it (pose refinement). ``tests/fields/reference.py`` holds a plain per-level, per-corner
loop twin that both paths are checked against.

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


def _corner_terms(x: Tensor, res: Tensor, mult: Tensor, offsets: Tensor, hashed: bool, table_mask: int):
    """The tensor math of :func:`corner_indices_weights` for ``l`` levels of one kind (dense or hashed)."""
    n, n_levels = x.shape[0], res.shape[0]
    res = res.to(x.dtype) if x.is_floating_point() and x.dtype != torch.float16 else res
    p = x.to(res.dtype)[:, None, :] * res[:, None]  # (N, l, 3)
    i0f = torch.minimum(torch.floor(p).clamp_(min=0.0), (res - 1.0)[:, None])
    frac = p - i0f
    a0 = i0f.to(torch.int32) * mult  # (N, l, 3)
    a = torch.stack([a0, a0 + mult], dim=-1)  # (N, l, 3, 2): per-axis term of corner 0 / 1
    ax, ay, az = a[:, :, 0], a[:, :, 1], a[:, :, 2]
    if hashed:
        idx = torch.bitwise_xor(ax[..., :, None, None], ay[..., None, :, None])
        idx = idx ^ az[..., None, None, :]
        idx = idx & table_mask
    else:  # dense levels: row = i + j (R + 1) + k (R + 1)^2
        idx = (ax[..., :, None, None] + ay[..., None, :, None]) + az[..., None, None, :]
    idx = idx.view(n, n_levels, 8) + offsets[:, None]
    wa = torch.stack([1.0 - frac, frac], dim=-1)  # (N, l, 3, 2)
    w = (wa[:, :, 0, :, None, None] * wa[:, :, 1, None, :, None] * wa[:, :, 2, None, None, :]).reshape(n, n_levels, 8)
    return idx.long(), w, wa


_compiled_corner_terms = None
_compile_failed = False


def _corner_terms_compiled():
    """``torch.compile`` of :func:`_corner_terms` (dynamic shapes: one kernel for any ``N`` and ``l``), or
    None where compiling is not possible here (no C++ compiler, an unsupported platform): eager then."""
    global _compiled_corner_terms
    if _compiled_corner_terms is None and not _compile_failed:
        _compiled_corner_terms = torch.compile(_corner_terms, dynamic=True)
    return None if _compile_failed else _compiled_corner_terms


def corner_indices_weights(x: Tensor, layout: GridLayout, consts: tuple[Tensor, Tensor, Tensor], levels: slice,
                           compiled: bool = False):
    """Rows and trilinear weights of the 8 corners of ``x (N, 3)`` at the levels ``levels``.

    Returns ``idx (N, l, 8)`` int64 (corner order ``(dx, dy, dz)``, dz fastest), ``w (N, l, 8)``
    (float32; float64 for float64 input) and the per-axis weights ``wa (N, l, 3, 2)`` (``[1 - f, f]``).
    ``compiled``: run the arithmetic through ``torch.compile`` (one fused loop instead of a dozen
    tensor passes; 4x faster on CPU for a training batch, same integers, same weights up to
    floating-point contraction); it falls back to eager, with a warning, if compiling fails.
    """
    global _compile_failed
    res, mult, offsets = (c[levels] for c in consts)
    start = levels.start or 0
    hashed = start >= layout.n_dense
    if not hashed and start + res.shape[0] > layout.n_dense:
        raise ValueError("corner_indices_weights: a call handles dense or hashed levels, not both")
    mask = layout.table_size - 1
    fn = _corner_terms_compiled() if compiled and not torch.is_grad_enabled() else None
    if fn is not None:
        try:  # fresh constants: a view's storage offset would be guarded on and recompile per level slice
            return fn(x, res.clone(), mult.clone(), offsets.clone(), hashed, mask)
        except Exception as err:  # noqa: BLE001 - any compiler failure: the eager path computes the same
            _compile_failed = True
            log.warning("hash encoding: torch.compile failed (%s); using the eager index computation",
                        str(err).splitlines()[0][:200] if str(err) else type(err).__name__)
    return _corner_terms(x, res, mult, offsets, hashed, mask)


def _dense_volume(table: Tensor, layout: GridLayout, level: int) -> Tensor:
    """Dense level ``level``'s rows as the ``grid_sample`` volume ``(1, F, D=k, H=j, W=i)`` (a view).

    Rows ``i + j (R + 1) + k (R + 1)^2`` are the volume ``[k, j, i]``; with ``align_corners``
    the grid coordinate ``2 x - 1`` puts vertex ``i`` at ``x = i / R``, the same
    interpolation as the gather path (the tests check both against the loop reference).
    """
    r1 = layout.resolutions[level] + 1
    off = layout.offsets[level]
    return table[off : off + r1**3].view(r1, r1, r1, table.shape[1]).permute(3, 0, 1, 2).unsqueeze(0)


class _EncodeFunction(torch.autograd.Function):
    """Every level of the encoding in one autograd node, with one table gradient buffer.

    Forward: dense levels through ``grid_sample`` (when ``dense_via_grid_sample``), the other
    levels by gathering their ``(N, l, 8)`` corner rows and summing them with the trilinear
    weights in one ``embedding_bag``. Backward: the table gradient is a single ``(rows, F)``
    buffer; ``grid_sample``'s backward kernel writes each dense level's volume gradient into its
    rows and the gathered levels add theirs with a deterministic ``index_add_`` (``embedding_bag``'s
    own backward sorts, 5x slower on CPU). Slicing dense levels out of the table under autograd
    instead costs a zero-filled table-sized gradient per level plus their sums: that was a third
    of a CPU training step. The position gradient is analytic and only computed when ``x``
    needs it (pose refinement).
    """

    @staticmethod
    def forward(ctx, x: Tensor, table: Tensor, layout: GridLayout, consts, dense_via_grid_sample: bool,
                compiled: bool):
        n, f = x.shape[0], table.shape[1]
        nd = layout.n_dense if dense_via_grid_sample else 0
        parts = []
        grid = None
        if nd:
            grid = (x * 2.0 - 1.0).view(1, -1, 1, 1, 3).to(table.dtype)  # (1, N, 1, 1, 3)
            for level in range(nd):
                out = torch.nn.functional.grid_sample(_dense_volume(table, layout, level), grid, mode="bilinear",
                                                      padding_mode="border", align_corners=True)
                parts.append(out.view(f, n).t())
        idx = w = wa = res = None
        if nd < layout.levels:
            # corner rows of dense and hashed levels come from separate calls (their row formulas differ)
            pieces = [sl for sl in (slice(0, layout.n_dense), slice(layout.n_dense, layout.levels))
                      if sl.stop > max(sl.start, nd)]
            cw = [corner_indices_weights(x, layout, consts, sl, compiled) for sl in pieces]
            idx, w, wa = (torch.cat(t, dim=1) if len(cw) > 1 else t[0] for t in zip(*cw, strict=True))
            res = consts[0][nd:]
            n_levels = idx.shape[1]
            w = w.to(table.dtype)
            out = torch.nn.functional.embedding_bag(
                idx.view(n * n_levels, 8), table, per_sample_weights=w.view(n * n_levels, 8), mode="sum"
            )
            parts.append(out.view(n, n_levels * f))
        ctx.save_for_backward(table, grid, idx, w, wa)
        ctx.layout, ctx.nd, ctx.res = layout, nd, res
        return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        table, grid, idx, w, wa = ctx.saved_tensors
        layout, nd = ctx.layout, ctx.nd
        need_x, need_table = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        n, f = grad_out.shape[0], table.shape[1]
        grad_out = grad_out.contiguous()
        grad_table = torch.zeros((layout.rows, f), dtype=table.dtype, device=table.device) if need_table else None
        grad_x = torch.zeros((n, 3), dtype=grad_out.dtype, device=grad_out.device) if need_x else None
        for level in range(nd):
            g = grad_out[:, level * f : (level + 1) * f].t().contiguous().view(1, f, n, 1, 1).to(table.dtype)
            g_vol, g_grid = torch.ops.aten.grid_sampler_3d_backward(
                g, _dense_volume(table, layout, level), grid, 0, 1, True, [need_table, need_x]
            )  # interpolation 0 = bilinear, padding 1 = border
            if need_table:
                r1 = layout.resolutions[level] + 1
                off = layout.offsets[level]
                grad_table[off : off + r1**3] += g_vol[0].permute(1, 2, 3, 0).reshape(-1, f)
            if need_x:
                grad_x += 2.0 * g_grid.view(n, 3).to(grad_x.dtype)  # grid = 2 x - 1
        if idx is not None:
            n_levels = idx.shape[1]
            go = grad_out[:, nd * f :].reshape(n, n_levels, f)
            if need_table:
                src = go[:, :, None, :].to(w.dtype) * w[..., None]  # (N, l, 8, F)
                grad_table.index_add_(0, idx.view(-1), src.view(-1, f))
            if need_x:
                feats = table[idx.view(-1)].view(n, n_levels, 2, 2, 2, f)
                g = (feats * go.view(n, n_levels, 1, 1, 1, f)).sum(-1)  # (N, l, 2, 2, 2): dLoss/dw per corner
                wx, wy, wz = wa[:, :, 0], wa[:, :, 1], wa[:, :, 2]  # (N, l, 2) each
                gx = g[:, :, 1] - g[:, :, 0]  # (N, l, 2, 2) over (dy, dz)
                gy = g[:, :, :, 1] - g[:, :, :, 0]  # over (dx, dz)
                gz = g[..., 1] - g[..., 0]  # over (dx, dy)
                dx = (gx * wy[..., :, None] * wz[..., None, :]).sum((-1, -2))
                dy = (gy * wx[..., :, None] * wz[..., None, :]).sum((-1, -2))
                dz = (gz * wx[..., :, None] * wy[..., None, :]).sum((-1, -2))
                grad_x += (torch.stack([dx, dy, dz], dim=-1) * ctx.res.to(dx.dtype)[:, None]).sum(1).to(grad_x.dtype)
        return grad_x, grad_table, None, None, None, None


def hash_grid_encode(
    x: Tensor, table: Tensor, layout: GridLayout, consts: tuple[Tensor, Tensor, Tensor] | None = None,
    dense_via_grid_sample: bool = True, compiled: bool = False,
) -> Tensor:
    """Encode ``x (N, 3)`` in ``[0, 1]^3`` with ``table (layout.rows, F)``: returns ``(N, L * F)``.

    ``dense_via_grid_sample``: dense levels through ``grid_sample`` (faster on CPU) instead of
    the gather path; both compute the same interpolation. ``compiled``: corner rows and weights
    through ``torch.compile`` (see :func:`corner_indices_weights`).
    """
    if consts is None:
        consts = _level_constants(layout, x.device)
    return _EncodeFunction.apply(x, table, layout, consts, dense_via_grid_sample, compiled)


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
        self.compile_indices = False  # set by the owner (SceneFieldConfig.compile_indices)

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
            out = hash_grid_encode(flat, self.table, self.layout, self._consts, self.dense_via_grid_sample,
                                   self.compile_indices)
        return out.reshape(*shape, self.n_output_dims)
