"""Occupancy grids baked from a density field: empty-space skipping and the robot's obstacle map.

``OccupancyGrid`` is a boolean voxel grid over the scene box ``aabb (2, 3)`` (world metres,
cells as cubic as the box allows): a cell is occupied when the density at any of
``samples_per_cell`` points in it (the centre, then seeded jittered points) exceeds
``density_threshold`` (1/m), dilated by ``dilate`` cells so that a density peak between
sample points is not lost. The marching renderer skips samples in free cells; with a
threshold whose integral over the skipped path is negligible it renders the same image.

``obstacle_map`` is the 2D map a ground robot and the crowd simulator need: a cell of the
floor plan is an obstacle when the density anywhere in the height band ``[z_lo, z_hi]``
above it exceeds the threshold; ``obstacle_polygons`` traces its outlines (metres, world xy,
the format of the capture's ``occupancy.json``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

DensityFn = Callable[[Tensor], Tensor]  # x_world (N, 3) -> sigma (N,)


def grid_shape(aabb: np.ndarray | Tensor, cell_m: float) -> tuple[int, int, int]:
    size = np.asarray(aabb[1], dtype=np.float64) - np.asarray(aabb[0], dtype=np.float64)
    return tuple(max(1, int(math.ceil(s / cell_m - 1e-9))) for s in size)


@torch.no_grad()
def max_density_on_grid(density_fn: DensityFn, lo: np.ndarray, hi: np.ndarray, shape: tuple[int, ...],
                        samples_per_cell: int, generator: torch.Generator | None, chunk: int,
                        device: str | torch.device = "cpu") -> Tensor:
    """Max of ``density_fn`` over the centre + ``samples_per_cell - 1`` jittered points of every cell: ``shape`` float."""
    lo_t = torch.as_tensor(lo, dtype=torch.float32, device=device)
    cell = (torch.as_tensor(hi, dtype=torch.float32, device=device) - lo_t) / torch.tensor(shape, dtype=torch.float32, device=device)
    axes = [torch.arange(n, dtype=torch.float32, device=device) for n in shape]
    ijk = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    best = torch.zeros(ijk.shape[0], device=device)
    if generator is None:
        generator = torch.Generator().manual_seed(0)  # jitter is part of the result: never unseeded
    for k in range(samples_per_cell):
        if k == 0:
            offset = torch.full_like(ijk, 0.5)
        else:
            offset = torch.rand(ijk.shape, generator=generator, device=generator.device).to(device)
        x = lo_t + (ijk + offset) * cell
        for a in range(0, x.shape[0], chunk):
            best[a : a + chunk] = torch.maximum(best[a : a + chunk], density_fn(x[a : a + chunk]).float())
    return best.view(*shape)


def _dilate(mask: Tensor, cells: int) -> Tensor:
    if cells <= 0:
        return mask
    k = 2 * cells + 1
    x = mask[None, None].float()
    if mask.dim() == 3:
        return torch.nn.functional.max_pool3d(x, k, stride=1, padding=cells)[0, 0] > 0
    return torch.nn.functional.max_pool2d(x, k, stride=1, padding=cells)[0, 0] > 0


@dataclass
class OccupancyGrid:
    """occupied: (X, Y, Z) bool over ``aabb (2, 3)``; density_threshold in 1/m."""

    aabb: Tensor
    occupied: Tensor
    density_threshold: float

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.occupied.shape)

    @property
    def cell_m(self) -> Tensor:
        return (self.aabb[1] - self.aabb[0]) / torch.tensor(self.shape, dtype=self.aabb.dtype, device=self.aabb.device)

    @property
    def occupied_fraction(self) -> float:
        return float(self.occupied.float().mean())

    def to(self, device) -> OccupancyGrid:
        return OccupancyGrid(self.aabb.to(device), self.occupied.to(device), self.density_threshold)

    @classmethod
    def bake(cls, density_fn: DensityFn, aabb: Tensor | np.ndarray, cell_m: float, density_threshold: float,
             samples_per_cell: int = 2, dilate: int = 1, generator: torch.Generator | None = None,
             chunk: int = 1 << 16, device: str | torch.device = "cpu") -> OccupancyGrid:
        aabb_np = np.asarray(torch.as_tensor(aabb).cpu(), dtype=np.float64)
        shape = grid_shape(aabb_np, cell_m)
        dens = max_density_on_grid(density_fn, aabb_np[0], aabb_np[1], shape, samples_per_cell, generator, chunk, device)
        occupied = _dilate(dens > density_threshold, dilate)
        return cls(torch.as_tensor(aabb_np, dtype=torch.float32, device=device), occupied, float(density_threshold))

    def query(self, x_world: Tensor, outside: bool = True) -> Tensor:
        """Occupancy of the cells holding ``x_world (..., 3)``; points outside the box get ``outside``."""
        shape_t = torch.tensor(self.shape, device=x_world.device)
        rel = (x_world - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        ijk = torch.floor(rel * shape_t).long()
        inside = ((ijk >= 0) & (ijk < shape_t)).all(-1)
        ijk = torch.minimum(ijk.clamp(min=0), shape_t - 1)
        flat = (ijk[..., 0] * self.shape[1] + ijk[..., 1]) * self.shape[2] + ijk[..., 2]
        occ = self.occupied.reshape(-1)[flat]
        return torch.where(inside, occ, torch.full_like(occ, outside))

    def save(self, path: str | Path) -> None:
        """``path`` (``.npy``, ``(X, Y, Z)`` uint8) and ``path`` with suffix ``.json`` (box, threshold).

        Plain ``.npy`` + JSON rather than ``.npz``: a zip stores the time of writing, and artifact
        files must repeat byte for byte.
        """
        import json

        path = Path(path)
        np.save(path, self.occupied.cpu().numpy().astype(np.uint8), allow_pickle=False)
        meta = {"units": "m", "frame": "world, z up", "aabb_m": self.aabb.cpu().tolist(), "shape": list(self.shape),
                "density_threshold": self.density_threshold,
                "layout": "occupied[i, j, k]: cell [min + (i, j, k) * cell, min + (i + 1, j + 1, k + 1) * cell)"}
        path.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> OccupancyGrid:
        import json

        path = Path(path)
        meta = json.loads(path.with_suffix(".json").read_text())
        occupied = np.load(path, allow_pickle=False).astype(bool)
        return cls(torch.tensor(meta["aabb_m"], dtype=torch.float32, device=device), torch.as_tensor(occupied, device=device),
                   float(meta["density_threshold"]))


# ---------------------------------------------------------------------- the 2D obstacle map
@dataclass
class ObstacleMap:
    """occupied: (NX, NY) bool, cell ``[x0 + i c, x0 + (i + 1) c) x [y0 + j c, ...)``; band_m: (z_lo, z_hi)."""

    origin_xy_m: tuple[float, float]
    cell_m: float
    occupied: np.ndarray
    band_m: tuple[float, float]

    def to_png(self, path: str | Path) -> None:
        """Black obstacles on white, image rows = +y downwards flipped so north is up (row 0 = max y)."""
        from nsim.io.images import write_image

        img = np.where(self.occupied.T[::-1, :, None], 0, 255).astype(np.uint8).repeat(3, axis=2)
        write_image(path, np.ascontiguousarray(img))

    def polygons(self, tolerance_cells: float = 0.5) -> list[np.ndarray]:
        """Outlines of the obstacles, ``(K, 2)`` world xy metres each, counter-clockwise."""
        from skimage import measure

        padded = np.pad(self.occupied.astype(np.float32), 1)
        out = []
        for contour in measure.find_contours(padded, 0.5):
            contour = measure.approximate_polygon(contour, tolerance=tolerance_cells)
            if len(contour) < 4:
                continue
            xy = (contour - 1.0 + 0.5) * self.cell_m + np.asarray(self.origin_xy_m)  # padded index -> cell centre
            area = 0.5 * np.sum(xy[:-1, 0] * xy[1:, 1] - xy[1:, 0] * xy[:-1, 1])
            if area < 0:
                xy = xy[::-1]
            out.append(xy[:-1] if np.allclose(xy[0], xy[-1]) else xy)
        return out


@torch.no_grad()
def obstacle_map(density_fn: DensityFn, aabb: Tensor | np.ndarray, band_m: tuple[float, float], cell_m: float,
                 density_threshold: float, samples_per_cell: int = 2, generator: torch.Generator | None = None,
                 chunk: int = 1 << 16, device: str | torch.device = "cpu") -> ObstacleMap:
    """2D obstacles over the scene box's xy extent: density above ``density_threshold`` in the height band."""
    aabb_np = np.asarray(torch.as_tensor(aabb).cpu(), dtype=np.float64)
    z_lo, z_hi = float(band_m[0]), float(band_m[1])
    if not z_hi > z_lo:
        raise ValueError(f"obstacle band: expected z_lo < z_hi, got {band_m}")
    lo = np.array([aabb_np[0, 0], aabb_np[0, 1], z_lo])
    hi = np.array([aabb_np[1, 0], aabb_np[1, 1], z_hi])
    nx, ny = grid_shape(aabb_np[:, :2], cell_m)
    nz = max(1, int(math.ceil((z_hi - z_lo) / cell_m)))
    hi[:2] = lo[:2] + np.array([nx, ny]) * cell_m
    dens = max_density_on_grid(density_fn, lo, hi, (nx, ny, nz), samples_per_cell, generator, chunk, device)
    occupied = (dens > density_threshold).any(-1).cpu().numpy()
    return ObstacleMap((float(lo[0]), float(lo[1])), float(cell_m), occupied, (z_lo, z_hi))
