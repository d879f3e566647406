"""A triangle mesh from a density field: lattice sampling, marching cubes, cropping, components, colours.

The lattice (``Lattice``) is a grid of *nodes* ``lo_m + (i, j, k) cell_m`` (world metres, z up);
the density sampled there, ``volume[i, j, k]``, feeds ``skimage.measure.marching_cubes`` at a
density ``level`` (1/m). Vertices come back in world metres, faces counter-clockwise seen from
the free side: face normals (right-hand rule) and vertex normals point from dense to empty
space, the way a camera sees the surface.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nsim.volume import quadrature

DensityFn = Callable[[Tensor], Tensor]  # x_world (N, 3) -> sigma (N,) 1/m
RadianceFn = Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]  # x (N, 3), unit dirs (N, 3) -> sigma (N,), rgb (N, 3)


class EmptySurface(ValueError):
    """The level does not cross the sampled density: ``low`` / ``high`` are the density's range (1/m)."""

    def __init__(self, level: float, low: float, high: float) -> None:
        super().__init__(f"no surface at level {level:g}: the density ranges over [{low:g}, {high:g}]")
        self.level, self.low, self.high = level, low, high


@dataclass(frozen=True)
class Lattice:
    """Nodes ``lo_m + (i, j, k) cell_m`` for ``(i, j, k) < shape`` (world metres, z up)."""

    lo_m: tuple[float, float, float]
    cell_m: float
    shape: tuple[int, int, int]

    @property
    def hi_m(self) -> np.ndarray:
        return np.asarray(self.lo_m) + (np.asarray(self.shape) - 1) * self.cell_m

    @property
    def n_nodes(self) -> int:
        return int(np.prod(self.shape))


def lattice_over(lo_m, hi_m, cell_m: float, max_nodes: int) -> tuple[Lattice, bool]:
    """The lattice covering the box ``[lo_m, hi_m]`` with spacing ``cell_m``, grown (coarser, by the
    smallest factor) until it has at most ``max_nodes`` nodes. Returns it and whether it grew."""
    lo = np.asarray(lo_m, dtype=np.float64)
    size = np.asarray(hi_m, dtype=np.float64) - lo
    if not (size > 0).all():
        raise ValueError(f"lattice_over: empty box {lo.tolist()} .. {np.asarray(hi_m).tolist()}")
    cell = float(cell_m)
    grew = False
    while True:
        shape = tuple(int(math.ceil(s / cell - 1e-9)) + 1 for s in size)
        if int(np.prod(shape)) <= max_nodes:
            return Lattice(tuple(float(v) for v in lo), cell, shape), grew
        cell *= (np.prod(shape) / max_nodes) ** (1.0 / 3.0) * 1.001
        grew = True


@torch.no_grad()
def sample_lattice(fn: DensityFn, lattice: Lattice, need: np.ndarray | None = None, chunk: int = 1 << 16,
                   device: str | torch.device = "cpu", on_slab: Callable[[int], None] | None = None) -> np.ndarray:
    """``fn`` at every node: ``volume (X, Y, Z)`` float32.

    need: ``(X, Y, Z)`` bool, the nodes worth evaluating (e.g. ``nodes_in_cells`` of the occupancy
    grid); the others get 0. on_slab(i): called after each slab ``volume[i]`` (progress).
    """
    nx, ny, nz = lattice.shape
    lo = np.asarray(lattice.lo_m, dtype=np.float64)
    out = np.zeros(lattice.shape, dtype=np.float32)
    for i in range(nx):
        flat = np.arange(ny * nz) if need is None else np.flatnonzero(need[i])
        row = out[i].reshape(-1)
        for a in range(0, len(flat), chunk):
            f = flat[a : a + chunk]
            ijk = np.stack([np.full(len(f), i), f // nz, f % nz], axis=1)
            x = torch.as_tensor((lo + ijk * lattice.cell_m).astype(np.float32), device=device)
            row[f] = fn(x).float().cpu().numpy()
        if on_slab is not None:
            on_slab(i)
    return out


def nodes_in_cells(cells: np.ndarray, lo_m, cell_m, lattice: Lattice, outside: bool = False) -> np.ndarray:
    """``(X, Y, Z)`` bool: the lattice node lies in a True cell of ``cells (A, B, C)`` (cell ``abc`` spans
    ``lo_m + abc cell_m`` to ``lo_m + (abc + 1) cell_m``; ``cell_m`` a scalar or per axis); nodes outside
    the grid get ``outside``. Separable per axis: no per-node arithmetic."""
    cell = np.broadcast_to(np.asarray(cell_m, dtype=np.float64), (3,))
    index, inside = [], []
    for a in range(3):
        node = lattice.lo_m[a] + np.arange(lattice.shape[a]) * lattice.cell_m
        k = np.floor((node - float(np.asarray(lo_m)[a])) / cell[a]).astype(np.int64)
        inside.append((k >= 0) & (k < cells.shape[a]))
        index.append(np.clip(k, 0, cells.shape[a] - 1))
    hit = cells[np.ix_(*index)]
    within = inside[0][:, None, None] & inside[1][None, :, None] & inside[2][None, None, :]
    return np.where(within, hit, outside)


def marching_cubes(volume_: np.ndarray, level: float, lattice: Lattice) -> tuple[np.ndarray, np.ndarray]:
    """The ``level`` iso-surface of ``volume_ (X, Y, Z)`` sampled on ``lattice``.

    Returns ``vertices (V, 3)`` float64 world metres and ``faces (F, 3)`` int64, counter-clockwise
    seen from the low-density side, none of zero area. Raises :class:`EmptySurface` when the level does not cross the data.
    """
    from skimage import measure

    low, high = float(volume_.min()), float(volume_.max())
    if not (low < level < high):
        raise EmptySurface(level, low, high)
    verts, faces, _normals, _values = measure.marching_cubes(volume_, level=level, spacing=(lattice.cell_m,) * 3,
                                                            gradient_direction="descent")
    verts = verts.astype(np.float64) + np.asarray(lattice.lo_m)
    # skimage winds faces clockwise seen from the low side of a field that is high inside: flip
    faces = faces[:, [0, 2, 1]].astype(np.int64)
    # where the level passes exactly through nodes, skimage leaves faces of zero area: drop them
    return keep_faces(verts, faces, face_areas(verts, faces) > 1e-8 * lattice.cell_m**2)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Un-normalised face normals ``(F, 3)`` (length = twice the face's area)."""
    v = vertices[faces]
    return np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(face_normals(vertices, faces), axis=-1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(V, 3)`` (a vertex in no face gets +z)."""
    acc = np.zeros_like(vertices, dtype=np.float64)
    fn = face_normals(vertices, faces)
    for c in range(3):
        np.add.at(acc, faces[:, c], fn)
    norm = np.linalg.norm(acc, axis=-1, keepdims=True)
    return np.where(norm > 1e-20, acc / np.maximum(norm, 1e-20), np.array([0.0, 0.0, 1.0]))


def keep_faces(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces where ``keep (F,)``, with unused vertices dropped (order preserved)."""
    faces = faces[keep]
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    return vertices[used], remap[faces]


def face_components(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """Connected component label of every face ``(F,)`` (faces sharing a vertex are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(faces) == 0:
        return np.zeros(0, dtype=np.int64)
    rows = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    cols = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return labels[faces[:, 0]]


def drop_small_components(vertices: np.ndarray, faces: np.ndarray, min_area_m2: float
                          ) -> tuple[np.ndarray, np.ndarray, int]:
    """Remove connected components whose area is below ``min_area_m2``; returns the mesh and how many went."""
    labels = face_components(len(vertices), faces)
    if labels.size == 0:
        return vertices, faces, 0
    area = np.bincount(labels, weights=face_areas(vertices, faces))
    small = area < min_area_m2
    present = np.bincount(labels) > 0
    v, f = keep_faces(vertices, faces, ~small[labels])
    return v, f, int((small & present).sum())


@torch.no_grad()
def seen_cells(origins: Tensor, dirs: Tensor, t_start: Tensor, t_end: Tensor, lo_m, cell_m: float,
               shape: tuple[int, int, int], max_points: int = 1 << 21) -> Tensor:
    """Cells ``(X, Y, Z)`` bool of the grid ``lo_m + ijk cell_m`` (cell ijk spans one ``cell_m`` cube)
    that some ray passes through between ``t_start`` and ``t_end`` (all ``(R,)``; rays ``(R, 3)``
    world, unit dirs), marked at steps of half a cell."""
    device = origins.device
    seen = torch.zeros(int(np.prod(shape)), dtype=torch.bool, device=device)
    lo = torch.as_tensor(np.asarray(lo_m, dtype=np.float32), device=device)
    shape_t = torch.tensor(shape, device=device)
    step = 0.5 * cell_m
    length = (t_end - t_start).clamp(min=0.0)
    order = torch.argsort(length, stable=True)  # similar lengths together: little padding
    steps = (torch.ceil(length[order] / step).long() + 1).cpu().numpy()
    a, n = 0, origins.shape[0]
    while a < n:
        cost = np.arange(1, n - a + 1) * steps[a:]  # points of the chunk [a, a + k): k * its longest ray
        b = a + max(1, int(np.searchsorted(cost, max_points, side="right")))
        idx = order[a:b]
        t = t_start[idx, None] + torch.arange(int(steps[b - 1]), device=device, dtype=torch.float32)[None, :] * step
        t = torch.minimum(t, t_end[idx, None])
        x = origins[idx, None, :] + dirs[idx, None, :] * t[..., None]
        ijk = torch.floor((x - lo) / cell_m).long()
        inside = ((ijk >= 0) & (ijk < shape_t)).all(-1)
        ijk = ijk[inside]
        seen[(ijk[:, 0] * shape[1] + ijk[:, 1]) * shape[2] + ijk[:, 2]] = True
        a = b
    return seen.view(shape)


def dilate(cells: Tensor, ring: int) -> Tensor:
    """``cells (X, Y, Z)`` bool grown by ``ring`` cells in every direction (a cube)."""
    if ring <= 0:
        return cells
    k = 2 * ring + 1
    return torch.nn.functional.max_pool3d(cells[None, None].float(), k, stride=1, padding=ring)[0, 0] > 0


def faces_in_cells(vertices: np.ndarray, faces: np.ndarray, cells: np.ndarray, lo_m, cell_m: float) -> np.ndarray:
    """``(F,)`` bool: the face's centroid lies in a True cell of ``cells`` (grid ``lo_m + ijk cell_m``)."""
    c = vertices[faces].mean(axis=1)
    ijk = np.floor((c - np.asarray(lo_m)) / cell_m).astype(np.int64)
    inside = ((ijk >= 0) & (ijk < np.asarray(cells.shape))).all(-1)
    ijk = np.clip(ijk, 0, np.asarray(cells.shape) - 1)
    return inside & cells[ijk[:, 0], ijk[:, 1], ijk[:, 2]]


@torch.no_grad()
def probe_colours(radiance_fn: RadianceFn, points: Tensor, normals: Tensor, probe_m: float, samples: int,
                  chunk: int = 1 << 14, on_chunk: Callable[[int], None] | None = None) -> Tensor:
    """Colour ``(N, 3)`` of the surface at ``points (N, 3)`` seen along ``-normals`` (looking into it).

    A short ray from ``point + probe_m n`` to ``point - probe_m n`` is volume-rendered with
    ``samples`` samples; the colour is the weighted mean of its samples' colours (the rendered
    colour without the background's share). Where it collects no weight, or with ``probe_m = 0``,
    it is the field's colour at the point itself. on_chunk(n): called after each chunk of n points.
    """
    n = points.shape[0]
    out = torch.zeros(n, 3, device=points.device)
    s = samples if probe_m > 0 else 1
    for a in range(0, n, chunk):
        p, nrm = points[a : a + chunk], normals[a : a + chunk]
        m = p.shape[0]
        d = -nrm
        if s == 1:
            _, rgb = radiance_fn(p, d)
            out[a : a + m] = rgb.float()
        else:
            out[a : a + m] = _probe(radiance_fn, p, d, probe_m, s)
        if on_chunk is not None:
            on_chunk(m)
    return out.clamp(0.0, 1.0)


def _probe(radiance_fn: RadianceFn, p: Tensor, d: Tensor, probe_m: float, s: int) -> Tensor:
    """Weighted mean colour ``(M, 3)`` of ``s`` samples on ``p + t d``, ``t`` in ``[-probe_m, probe_m]``."""
    m = p.shape[0]
    edges = torch.linspace(-probe_m, probe_m, s + 1, device=p.device)
    mid = 0.5 * (edges[1:] + edges[:-1])  # (S,) along d, 0 at the point
    x = p[:, None, :] + d[:, None, :] * mid[None, :, None]
    sigma, rgb = radiance_fn(x.reshape(-1, 3), d[:, None, :].expand(-1, s, -1).reshape(-1, 3))
    sigma, rgb = sigma.view(m, s).float(), rgb.view(m, s, 3).float()
    w, _ = quadrature.render_weights(sigma, (edges[1:] - edges[:-1]).expand(m, s))
    acc = w.sum(-1)
    mean = quadrature.accumulate(w, rgb) / acc.clamp(min=1e-6)[:, None]
    at_point = 0.5 * (rgb[:, (s - 1) // 2] + rgb[:, s // 2])
    return torch.where((acc > 1e-4)[:, None], mean, at_point)
