"""Neighbour search for the crowd: agent pairs by KD-tree, wall segments by a uniform grid.

Both searches keep the per-step cost of the social force model near-linear in the number of
agents: each agent only meets the agents within ``cutoff_m`` (``neighbour_pairs``) and the wall
segments whose bounding box, grown by the grid's reach, touches its grid cell
(``SegmentGrid.candidates``). Everything is 2D, in world metres on the floor plane (x, y).

Obstacles are polygons ``(K, 2)`` (any orientation, implicitly closed), solid unless they have
holes (rings of free space inside them, e.g. the room inside a ring of walls); the crowd model
only sees their boundary segments ``(M, 2, 2)`` as ``[[x0, y0], [x1, y1]]``, hole boundaries included.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


def neighbour_pairs(position_m: np.ndarray, cutoff_m: float) -> np.ndarray:
    """Unordered pairs of agents closer than ``cutoff_m``: ``(P, 2)`` int64 with ``i < j``.

    position_m: (N, 2). The pairs are sorted (by ``i``, then ``j``) so the result, and every sum
    built from it, does not depend on the KD-tree's internal order.
    """
    n = len(position_m)
    if n < 2 or cutoff_m <= 0.0:
        return np.zeros((0, 2), dtype=np.int64)
    from scipy.spatial import cKDTree  # scipy on use: a command failing on its arguments starts fast

    pairs = cKDTree(position_m).query_pairs(float(cutoff_m), output_type="ndarray").astype(np.int64)
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    key = np.sort(np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(pairs[:, 0], pairs[:, 1]))
    return np.stack([key // n, key % n], axis=1)


def segments_from_polygons(polygons: Sequence[np.ndarray]) -> np.ndarray:
    """Boundary segments ``(M, 2, 2)`` of closed polygons, each ``(K, 2)`` with ``K >= 2``.

    A 2-vertex "polygon" is a single wall segment (one segment, not two).
    """
    segs = []
    for k, poly in enumerate(polygons):
        p = np.asarray(poly, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
            raise ValueError(f"polygons[{k}]: expected shape (K >= 2, 2), got {p.shape}")
        if len(p) == 2:
            segs.append(p[None])
        else:
            segs.append(np.stack([p, np.roll(p, -1, axis=0)], axis=1))
    if not segs:
        return np.zeros((0, 2, 2))
    out = np.concatenate(segs, axis=0)
    return out[np.any(out[:, 0] != out[:, 1], axis=1)]  # drop zero-length edges (repeated vertices)


def _in_ring(p: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Even-odd test of points ``p (N, 2)`` against one closed ring ``(K >= 3, 2)``: ``(N,)`` bool."""
    a, b = ring, np.roll(ring, -1, axis=0)
    x, y = p[:, 0:1], p[:, 1:2]
    crosses = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[None, :, 0] + (y - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (b[None, :, 1] - a[None, :, 1])
    return (np.count_nonzero(crosses & (x < x_at), axis=1) % 2) == 1


def points_in_polygons(
    points_m: np.ndarray,
    polygons: Sequence[np.ndarray],
    holes: Sequence[Sequence[np.ndarray]] | None = None,
) -> np.ndarray:
    """Which points lie strictly inside any polygon and outside its holes: ``(N,)`` bool (even-odd rule per ring).

    holes: for each polygon, its holes (rings of free space inside it); None: no holes.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    inside_any = np.zeros(len(p), dtype=bool)
    if holes is not None and len(holes) != len(polygons):
        raise ValueError(f"holes: expected one list per polygon ({len(polygons)}), got {len(holes)}")
    for k, poly in enumerate(polygons):
        v = np.asarray(poly, dtype=np.float64)
        if len(v) < 3:
            continue
        inside = _in_ring(p, v)
        for hole in holes[k] if holes is not None else ():
            h = np.asarray(hole, dtype=np.float64)
            if len(h) >= 3 and inside.any():
                inside &= ~_in_ring(p, h)
        inside_any |= inside
    return inside_any


def closest_points_on_segments(point_m: np.ndarray, segment_m: np.ndarray) -> np.ndarray:
    """Closest point on each segment to each point (row-wise): ``(Q, 2)``.

    point_m: (Q, 2); segment_m: (Q, 2, 2).
    """
    a, b = segment_m[:, 0], segment_m[:, 1]
    ab = b - a
    len2 = np.einsum("qi,qi->q", ab, ab)
    t = np.einsum("qi,qi->q", point_m - a, ab) / np.maximum(len2, 1e-300)
    return a + np.clip(t, 0.0, 1.0)[:, None] * ab


def segments_intersect(p0: np.ndarray, p1: np.ndarray, segment_m: np.ndarray) -> np.ndarray:
    """Whether each line of sight ``p0[k] -> p1[k]`` crosses each segment: ``(K, M)`` bool.

    p0, p1: (K, 2); segment_m: (M, 2, 2). Touching at an end point counts as crossing.
    """
    if len(p0) == 0 or len(segment_m) == 0:
        return np.zeros((len(p0), len(segment_m)), dtype=bool)

    def orient(a, b, c):  # sign of the cross product (b - a) x (c - a), broadcast
        return np.sign(
            (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1])
            - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
        )

    a, b = p0[:, None, :], p1[:, None, :]
    c, d = segment_m[None, :, 0, :], segment_m[None, :, 1, :]
    o1, o2 = orient(a, b, c), orient(a, b, d)
    o3, o4 = orient(c, d, a), orient(c, d, b)
    return (o1 * o2 <= 0) & (o3 * o4 <= 0) & ~((o1 == 0) & (o2 == 0))  # collinear overlaps: ignored


@dataclass(frozen=True)
class SegmentGrid:
    """Static wall segments bucketed in a uniform grid for near-constant-time candidate look-ups.

    A segment is listed in every cell that its bounding box, grown by ``reach_m``, overlaps, so
    ``candidates(p)`` returns a superset of the segments within ``reach_m`` of ``p``. Built once per
    map (``SegmentGrid.build``) and shared by every step.

    segments_m: (M, 2, 2). origin_m: (2,) corner of cell (0, 0). cell_m: cell side.
    shape: (cells along x, cells along y). cell_keys: (C,) sorted non-empty cell keys
    ``ix * shape[1] + iy``; cell_start: (C + 1,) offsets into ``cell_segments`` (CSR).
    """

    segments_m: np.ndarray
    reach_m: float
    origin_m: np.ndarray
    cell_m: float
    shape: tuple[int, int]
    cell_keys: np.ndarray
    cell_start: np.ndarray
    cell_segments: np.ndarray

    @staticmethod
    def build(segments_m: np.ndarray, reach_m: float, cell_m: float | None = None) -> SegmentGrid:
        """Index ``segments_m (M, 2, 2)`` for look-ups within ``reach_m`` (cells of side ``cell_m``)."""
        seg = np.array(segments_m, dtype=np.float64).reshape(-1, 2, 2)
        if not np.all(np.isfinite(seg)):
            raise ValueError("segments_m: expected finite coordinates")
        if not (reach_m > 0.0 and math.isfinite(reach_m)):
            raise ValueError(f"reach_m: expected a finite value > 0, got {reach_m!r}")
        cell = float(cell_m if cell_m is not None else reach_m)
        empty = np.zeros(0, dtype=np.int64)
        if len(seg) == 0:
            return SegmentGrid(
                seg, float(reach_m), np.zeros(2), cell, (1, 1), empty, np.zeros(1, np.int64), empty
            )
        lo = seg.min(axis=1) - reach_m  # (M, 2)
        hi = seg.max(axis=1) + reach_m
        origin = lo.min(axis=0)
        span = hi.max(axis=0) - origin
        shape = (int(span[0] // cell) + 1, int(span[1] // cell) + 1)
        i0 = np.floor((lo - origin) / cell).astype(np.int64)
        i1 = np.floor((hi - origin) / cell).astype(np.int64)
        nx, ny = i1[:, 0] - i0[:, 0] + 1, i1[:, 1] - i0[:, 1] + 1
        count = nx * ny
        seg_of = np.repeat(np.arange(len(seg)), count)
        local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        ix = i0[seg_of, 0] + local // ny[seg_of]
        iy = i0[seg_of, 1] + local % ny[seg_of]
        keys = ix * shape[1] + iy
        order = np.lexsort((seg_of, keys))
        keys, seg_of = keys[order], seg_of[order]
        cell_keys, starts = np.unique(keys, return_index=True)
        cell_start = np.append(starts, len(keys)).astype(np.int64)
        return SegmentGrid(
            seg, float(reach_m), origin, cell, shape, cell_keys, cell_start, seg_of.astype(np.int64)
        )

    def candidates(self, position_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate (agent, segment) pairs: ``agent_index (Q,)``, ``segment_index (Q,)``.

        Every segment within ``reach_m`` of ``position_m[k]`` appears with agent ``k`` (plus some
        farther ones). Agents outside the grid are farther than ``reach_m`` from every segment.
        """
        n = len(position_m)
        if n == 0 or len(self.cell_keys) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        idx = np.floor((position_m - self.origin_m) / self.cell_m).astype(np.int64)
        inside = (
            (idx[:, 0] >= 0) & (idx[:, 0] < self.shape[0]) & (idx[:, 1] >= 0) & (idx[:, 1] < self.shape[1])
        )
        keys = idx[:, 0] * self.shape[1] + idx[:, 1]
        slot = np.clip(np.searchsorted(self.cell_keys, keys), 0, len(self.cell_keys) - 1)
        hit = inside & (self.cell_keys[slot] == keys)
        start = np.where(hit, self.cell_start[slot], 0)
        count = np.where(hit, self.cell_start[slot + 1] - self.cell_start[slot], 0)
        agent = np.repeat(np.arange(n, dtype=np.int64), count)
        local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        return agent, self.cell_segments[np.repeat(start, count) + local]
