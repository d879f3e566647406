"""Occupancy grids baked from a density field: empty-space skipping and the robot's obstacle map.

``OccupancyGrid`` is a boolean voxel grid over the scene box ``aabb (2, 3)`` (world metres,
cells as cubic as the box allows): a cell is occupied when the density at any of
``samples_per_cell`` points in it (the centre, then seeded jittered points) exceeds
``density_threshold`` (1/m), dilated by ``dilate`` cells so that a density peak between
sample points is not lost. The marching renderer skips samples in free cells; with a
threshold whose integral over the skipped path is negligible it renders the same image.

``obstacle_map`` is the 2D map a ground robot and the crowd simulator need (``ObstacleMap``):
a cell of the floor plan is *occupied* when, somewhere in the height band ``[z_lo, z_hi]`` above
it, the training views' rays stop (their half-transmittance points), or the density exceeds the
threshold where no training ray went through and on (haze is carved away as a depth sensor's
occupancy mapper carves free space); *unknown* when no training camera saw into it
(``observed_columns``), else *free*. Nobody walks where it is occupied or unknown (unless
asked to: ``unknown_walkable``). ``ObstacleMap.regions`` traces those cells as polygons with
holes (``regions_from_mask``: a ring of walls around a free room is a polygon whose hole is the
room) and ``ObstacleMap.save`` writes them as ``occupancy.json`` (the capture's ``polygons``
plus a ``holes`` list per polygon), the cells as ``.npy`` / PNG and as a nav2 map
(``nsim.io.nav2``). ``room_free_space_iou`` (``free_space_iou`` against ``room_free_space``)
scores a map against a test room's ground truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from nsim.io.nav2 import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN  # noqa: F401  (re-exported: the cell codes)

DensityFn = Callable[[Tensor], Tensor]  # x_world (N, 3) -> sigma (N,)


def grid_shape(aabb: np.ndarray | Tensor, cell_m: float) -> tuple[int, int, int]:
    size = np.asarray(aabb[1], dtype=np.float64) - np.asarray(aabb[0], dtype=np.float64)
    return tuple(max(1, int(math.ceil(s / cell_m - 1e-9))) for s in size)


@torch.no_grad()
def max_density_on_grid(density_fn: DensityFn, lo: np.ndarray, hi: np.ndarray, shape: tuple[int, ...],
                        samples_per_cell: int, generator: torch.Generator | None, chunk: int,
                        device: str | torch.device = "cpu", skip: OccupancyGrid | None = None) -> Tensor:
    """Max of ``density_fn`` over the centre + ``samples_per_cell - 1`` jittered points of every cell: ``shape`` float.

    ``skip``: an occupancy grid baked from the same field at a lower density: points in its empty
    cells count as density 0 without evaluating the field (empty-space skipping, as the renderer's)."""
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
            xs = x[a : a + chunk]
            if skip is None:
                best[a : a + chunk] = torch.maximum(best[a : a + chunk], density_fn(xs).float())
                continue
            keep = torch.nonzero(skip.query(xs), as_tuple=True)[0]
            if len(keep):
                part = best[a : a + chunk]
                part[keep] = torch.maximum(part[keep], density_fn(xs[keep]).float())
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

OBSTACLE_FILES = ("obstacles.json", "occupancy.json", "obstacles.png", "obstacle_cells.npy", "obstacle_cells.png",
                  "map.yaml", "map.pgm")
"""What ``ObstacleMap.save`` writes (``obstacles.json`` and ``occupancy.json`` are the same document)."""


@dataclass(frozen=True, eq=False)
class CameraViews:
    """Where a scene was observed from: its training views.

    cam_to_world: (N, 4, 4) OpenCV axes; cameras: the distinct intrinsics
    (``nsim.geometry.cameras.Camera``), ``camera_index (N,)`` which one view ``n`` uses;
    near_m / far_m: the range along each pixel ray that training rendered.
    """

    cam_to_world: np.ndarray
    cameras: tuple
    camera_index: np.ndarray
    near_m: float = 0.0
    far_m: float = math.inf

    def __post_init__(self) -> None:
        c2w = np.asarray(self.cam_to_world, dtype=np.float64)
        idx = np.asarray(self.camera_index, dtype=np.int64).reshape(-1)
        if c2w.ndim != 3 or c2w.shape[1:] != (4, 4) or len(idx) != len(c2w):
            raise ValueError(f"CameraViews: expected cam_to_world (N, 4, 4) and camera_index (N,), got "
                             f"{c2w.shape} and {idx.shape}")
        if len(idx) and (idx.min() < 0 or idx.max() >= len(self.cameras)):
            raise ValueError(f"CameraViews.camera_index: expected values in [0, {len(self.cameras)})")
        if not 0.0 <= self.near_m < self.far_m:
            raise ValueError(f"CameraViews: expected 0 <= near_m < far_m, got {self.near_m}, {self.far_m}")
        object.__setattr__(self, "cam_to_world", c2w)
        object.__setattr__(self, "camera_index", idx)
        object.__setattr__(self, "cameras", tuple(self.cameras))


@dataclass(frozen=True, eq=False)
class Region:
    """One obstacle of the floor plan, world xy metres: ``outer_m (K, 2)`` counter-clockwise and
    ``holes_m``, the free space inside it, each ``(K, 2)`` clockwise (rings implicitly closed)."""

    outer_m: np.ndarray
    holes_m: tuple[np.ndarray, ...] = ()


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def regions_from_mask(mask: np.ndarray, origin_xy_m: tuple[float, float], cell_m: float,
                      tolerance_cells: float = 0.25) -> list[Region]:
    """Outlines of the True cells of ``mask (NX, NY)`` (cell ``[x0 + i c, x0 + (i + 1) c) x ...``) as polygons with holes.

    Marching squares at level 0.5 over the mask padded with False, with obstacles 8-connected and
    free space 4-connected (a diagonal gap between two obstacle cells is closed: nobody walks
    through it). Outlines run half-way between cell centres; Douglas-Peucker with
    ``tolerance_cells < 0.5`` keeps every free cell's centre outside the regions. Each connected
    obstacle component is one ``Region``: its outer boundary, and the boundaries of the free
    pockets it encloses as holes (a ring of walls around a free room is a region with a hole,
    never a solid block); an obstacle standing inside a hole is a region of its own. Regions come
    in scan order of their components, so the same mask gives the same list.
    """
    from scipy import ndimage
    from skimage import measure

    if not 0.0 <= tolerance_cells < 0.5:
        raise ValueError(f"tolerance_cells: expected in [0, 0.5), got {tolerance_cells}")
    padded = np.pad(np.asarray(mask, dtype=bool), 1)
    labels, n = ndimage.label(padded, structure=np.ones((3, 3), dtype=bool))
    rings: list[list[tuple[float, np.ndarray]]] = [[] for _ in range(n + 1)]
    for contour in measure.find_contours(padded.astype(np.float32), 0.5, fully_connected="high"):
        r, c = contour[0]  # on the edge between an obstacle cell and a free one: find the obstacle's component
        a, b = (int(math.floor(r)), int(math.floor(c))), (int(math.ceil(r)), int(math.ceil(c)))
        k = labels[a] if padded[a] else labels[b]
        simple = measure.approximate_polygon(contour, tolerance=tolerance_cells) if tolerance_cells > 0 else contour
        if len(simple) < 4:  # closed rings repeat their first point: fewer than 3 corners left
            simple = contour
        xy = (simple[:-1] - 0.5) * cell_m + np.asarray(origin_xy_m, dtype=np.float64)  # padded index -> centre
        rings[k].append((abs(_signed_area(xy)), xy))
    out = []
    for k in range(1, n + 1):
        if not rings[k]:
            continue
        outer_at = max(range(len(rings[k])), key=lambda q: rings[k][q][0])  # the boundary enclosing the others
        outer = rings[k][outer_at][1]
        outer = outer if _signed_area(outer) > 0 else outer[::-1]
        holes = tuple(h if _signed_area(h) < 0 else h[::-1] for q, (_, h) in enumerate(rings[k]) if q != outer_at)
        out.append(Region(np.ascontiguousarray(outer), tuple(np.ascontiguousarray(h) for h in holes)))
    return out


@dataclass
class ObstacleMap:
    """The floor plan a ground robot and the crowd simulator need, at the height band ``band_m = (z_lo, z_hi)``.

    Cell ``[i, j]`` is ``[x0 + i c, x0 + (i + 1) c) x [y0 + j c, y0 + (j + 1) c)`` (``origin_xy_m =
    (x0, y0)``, ``c = cell_m``). occupied: (NX, NY) bool, the density exceeds the threshold
    somewhere in the band; observed: (NX, NY) bool, some training camera saw into the column
    (``obstacle_map`` says how), or None when the map was baked without cameras (every cell
    counts as observed). A cell is *free* when observed and not occupied, *occupied* when
    observed and occupied, else *unknown* (never seen: behind walls, outside the room, inside
    thick matter).
    """

    origin_xy_m: tuple[float, float]
    cell_m: float
    occupied: np.ndarray
    band_m: tuple[float, float]
    observed: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.occupied.shape)

    @property
    def free(self) -> np.ndarray:
        """(NX, NY) bool: observed and below the density threshold (where one may walk)."""
        return ~self.occupied if self.observed is None else self.observed & ~self.occupied

    @property
    def unknown(self) -> np.ndarray:
        """(NX, NY) bool: never observed."""
        return np.zeros(self.shape, dtype=bool) if self.observed is None else ~self.observed

    def cells(self) -> np.ndarray:
        """(NX, NY) int8: ``CELL_FREE``, ``CELL_OCCUPIED`` or ``CELL_UNKNOWN``."""
        out = np.where(self.occupied, np.int8(CELL_OCCUPIED), np.int8(CELL_FREE)).astype(np.int8)
        out[self.unknown] = CELL_UNKNOWN
        return out

    def blocked(self, unknown_walkable: bool = False) -> np.ndarray:
        """(NX, NY) bool, where nobody may walk: occupied and unknown cells; with ``unknown_walkable``
        the density alone decides (unknown cells below the threshold count as free)."""
        return self.occupied.copy() if unknown_walkable else ~self.free

    def cell_centres_m(self) -> np.ndarray:
        """(NX, NY, 2) world xy of the cell centres."""
        nx, ny = self.shape
        x = self.origin_xy_m[0] + (np.arange(nx) + 0.5) * self.cell_m
        y = self.origin_xy_m[1] + (np.arange(ny) + 0.5) * self.cell_m
        return np.stack(np.meshgrid(x, y, indexing="ij"), axis=-1)

    def to_png(self, path: str | Path, unknown_walkable: bool = False) -> None:
        """Black where nobody may walk, white where one may; row 0 = max y (north up)."""
        from nsim.io.images import write_image

        img = np.where(self.blocked(unknown_walkable).T[::-1, :, None], 0, 255).astype(np.uint8).repeat(3, axis=2)
        write_image(path, np.ascontiguousarray(img))

    def regions(self, unknown_walkable: bool = False, tolerance_cells: float = 0.25) -> list[Region]:
        """The blocked cells (see ``blocked``) as polygons with holes (``regions_from_mask``)."""
        return regions_from_mask(self.blocked(unknown_walkable), self.origin_xy_m, self.cell_m, tolerance_cells)

    def occupancy_doc(self, unknown_walkable: bool = False, tolerance_cells: float = 0.25, units: str = "m") -> dict:
        """The ``occupancy.json`` document: the obstacles as polygons with holes, and where the cells are.

        ``polygons``: outer rings (counter-clockwise, ``[[x, y], ...]``), as in the capture's file,
        so a reader that knows only ``polygons`` still finds every obstacle; ``holes``: one list per
        polygon of its holes (clockwise rings of free space inside it). A file without ``holes``
        has none. units: ``"m"``, or ``"arbitrary"`` for a scene without metric scale (lengths in its poses' units).
        """
        regions = self.regions(unknown_walkable, tolerance_cells)
        nx, ny = self.shape
        return {
            "units": units,
            "frame": "world, z up; polygons in the xy plane (outer rings counter-clockwise, holes clockwise)",
            "height_band_m": [float(v) for v in self.band_m],
            "cell_m": float(self.cell_m),
            "origin_xy_m": [float(v) for v in self.origin_xy_m],
            "shape": [int(nx), int(ny)],
            "cells": {"file": "obstacle_cells.npy",
                      "layout": "int8 [i, j]: cell [x0 + i c, x0 + (i + 1) c) x [y0 + j c, y0 + (j + 1) c)",
                      "free": CELL_FREE, "occupied": CELL_OCCUPIED, "unknown": CELL_UNKNOWN},
            "unknown": "free" if unknown_walkable else "obstacle",
            "nav2_map": "map.yaml",
            "polygons": [np.round(r.outer_m, 6).tolist() for r in regions],
            "holes": [[np.round(h, 6).tolist() for h in r.holes_m] for r in regions],
        }

    def save(self, out_dir: str | Path, unknown_walkable: bool = False, units: str = "m") -> list[str]:
        """Write ``OBSTACLE_FILES`` into ``out_dir``: the polygons (``occupancy_doc``, as
        ``obstacles.json`` and ``occupancy.json``), ``obstacles.png`` (``to_png``), the cells as
        ``obstacle_cells.npy`` and as an image ``obstacle_cells.png``, and the nav2 map
        ``map.yaml`` + ``map.pgm`` (``nsim.io.nav2``). Returns the names written."""
        import json

        from nsim.io.images import write_image
        from nsim.io.nav2 import cells_to_image, write_nav2_map

        out_dir = Path(out_dir)
        doc = json.dumps(self.occupancy_doc(unknown_walkable, units=units), indent=1) + "\n"
        (out_dir / "obstacles.json").write_text(doc)
        (out_dir / "occupancy.json").write_text(doc)  # the name the crowd simulator reads from any layout artifact
        self.to_png(out_dir / "obstacles.png", unknown_walkable)
        cells = self.cells()
        np.save(out_dir / "obstacle_cells.npy", cells, allow_pickle=False)
        write_image(out_dir / "obstacle_cells.png", cells_to_image(cells))
        write_nav2_map(out_dir / "map.yaml", cells, self.origin_xy_m, self.cell_m)
        return list(OBSTACLE_FILES)

    @classmethod
    def load(cls, directory: str | Path) -> ObstacleMap:
        """The map ``save`` wrote into ``directory`` (from ``occupancy.json`` and ``obstacle_cells.npy``).

        Occupied-but-unseen cells come back as unknown (the cells keep three states), so
        ``load(d).cells()`` equals the saved cells.
        """
        import json

        from nsim.errors import InputError

        directory = Path(directory)
        try:
            doc = json.loads((directory / "occupancy.json").read_text())
            cells = np.load(directory / doc["cells"]["file"], allow_pickle=False)
            shape = tuple(doc["shape"])
            origin = (float(doc["origin_xy_m"][0]), float(doc["origin_xy_m"][1]))
            cell, band = float(doc["cell_m"]), tuple(float(v) for v in doc["height_band_m"])
        except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
            raise InputError(f"{directory}: no readable obstacle map ({exc.__class__.__name__}: {exc})") from None
        if cells.dtype != np.int8 or cells.shape != shape:
            raise InputError(f"{directory}: obstacle_cells.npy: expected int8 {shape}, got {cells.dtype} {cells.shape}")
        return cls(origin, cell, cells == CELL_OCCUPIED, band, cells != CELL_UNKNOWN)


# ---------------------------------------------------------------------- what the cameras saw
STOP_OPTICAL_DEPTH = math.log(2.0)
"""A ray sees no further than where its transmittance falls to 1/2 (the median depth a NeRF renders)."""


@torch.no_grad()
def opaque_range(sigma: Tensor, lo: Tensor, hi: Tensor, origins: Tensor, dirs: Tensor, near_m: float, far_m: float,
                 step_m: float, stop_optical_depth: float = STOP_OPTICAL_DEPTH, block: int = 64,
                 z_range: tuple[float, float] | None = None) -> Tensor:
    """Range along each ray at which its optical depth first exceeds ``stop_optical_depth``: ``(R,)`` (inf: never).

    sigma: (X, Y, Z) density (1/m) over the box ``[lo, hi]`` (3,), constant per cell; origins, dirs:
    (R, 3), dirs unit. Samples at ``t0 + k step_m`` from ``t0 = max(near_m, where the ray enters
    the box)`` until it leaves the box or passes ``far_m``, each adding ``sigma step_m``.
    ``z_range (z0, z1)``: only stops within that slab are wanted: a ray is followed (from ``t0``, so
    what lies before the slab still occludes) only until it leaves the slab, and one that leaves it
    without stopping, or never reaches it, gets inf. A camera above the slab looking up costs nothing.
    """
    shape = torch.tensor(sigma.shape, device=sigma.device)
    cell = (hi - lo) / shape
    safe = torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    ta, tb = (lo - origins) / safe, (hi - origins) / safe
    t_in = torch.clamp(torch.minimum(ta, tb).amax(-1), min=near_m)
    t_out = torch.clamp(torch.maximum(ta, tb).amin(-1), max=far_m)
    if z_range is not None:
        dz = safe[:, 2]
        za, zb = (z_range[0] - origins[:, 2]) / dz, (z_range[1] - origins[:, 2]) / dz
        t_out = torch.minimum(t_out, torch.maximum(za, zb))  # where the ray leaves the slab for good
    out = torch.full((len(origins),), math.inf, device=sigma.device)
    flat = sigma.reshape(-1).float()
    live = torch.nonzero(t_in < t_out).squeeze(-1)
    tau = torch.zeros(len(live), device=sigma.device)
    ks = torch.arange(block, device=sigma.device, dtype=origins.dtype)
    start = 0
    while live.numel():
        t = t_in[live, None] + (start + ks) * step_m  # (L, B)
        x = origins[live, None] + t[..., None] * dirs[live, None]
        ijk = torch.minimum(torch.floor((x - lo) / cell).long().clamp(min=0), shape - 1)
        s = flat[(ijk[..., 0] * sigma.shape[1] + ijk[..., 1]) * sigma.shape[2] + ijk[..., 2]]
        s = torch.where(t <= t_out[live, None], s, torch.zeros_like(s))
        acc = tau[:, None] + torch.cumsum(s * step_m, dim=-1)
        hit = acc > stop_optical_depth
        any_hit = hit.any(-1)
        first = torch.argmax(hit.to(torch.uint8), dim=-1)
        out[live[any_hit]] = t[any_hit, first[any_hit]]
        keep = ~any_hit & (t[:, -1] < t_out[live])
        live, tau = live[keep], acc[keep, -1]
        start += block
    return out


HIT_MIN_RAYS = 2
"""Rays of the training views that must stop in a band cell (``observed_columns``' hits) to make it occupied."""
HIT_DEPTH_CELLS = 1.0
"""How far past the half-transmittance point a ray's stop is taken (in cells): into the matter it met, not in front."""
OBSTACLE_DEPTH_PIXELS = 256 * 192
"""Pixels of each view's depth map in ``obstacle_map`` (the camera scaled down to about this many, its
aspect kept; a smaller camera as it is). On the five test rooms' trained scenes (320 x 240 captures, cpu
preset, 5 cm cells) 256 x 192 against 128 x 96: free-space IoU 0.910 against 0.905 on the kitchen (its
nooks between cabinets are carved by finer rays), 0.933-0.944 against 0.929-0.940 on the others; the
bake takes about twice as long. A pixel count, not a width: a portrait phone photo at 256 px wide
would cast 2.4 times the rays of a landscape one."""


@torch.no_grad()
def observed_columns(sigma: Tensor, density_threshold: float, lo: np.ndarray, hi: np.ndarray,
                     band_layers: tuple[int, int], views: CameraViews, depth_pixels: int = 128 * 96,
                     surface_tolerance_cells: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the training views saw of the band layers ``[k0, k1)`` of the density grid ``sigma (X, Y, Z)``
    (1/m, constant per cell, over the box ``[lo, hi]``): ``(observed (X, Y) bool, carved (X, Y, K) bool,
    hits (X, Y, K) int32)``, ``K = k1 - k0``.

    Per view, a depth map of about ``depth_pixels`` pixels (the camera scaled down) holds the range at which
    each pixel ray's transmittance falls to 1/2 (``opaque_range``: the median depth the NeRF renders;
    steps of half a cell from ``near_m`` to ``far_m``).

    * *observed*: a column is observed when some view saw one of its band cells: the cell projects
      into the image, its centre lies within ``[near_m, far_m]`` and nearer than that depth eroded
      by the 3 x 3 minimum (a cell glimpsed past a silhouette at this coarse resolution is not
      counted); a cell above ``density_threshold`` may lie up to ``surface_tolerance_cells`` cell
      diagonals behind it, as the surface the ray stopped at.
    * *carved*: some view's rays went through the cell and on (its centre nearer than the eroded
      depth), as an occupancy mapper carves free space along a depth ray: whatever density the
      cell holds did not stop light, so it is haze a NeRF left in the air, not matter.
    * *hits*: how many of the views' pixel rays stopped in the cell: the ray's half-transmittance
      point, taken ``HIT_DEPTH_CELLS`` cells further along the ray (into what stopped it). A thin
      surface (a table top) that point samples of the density miss still stops rays.

    Only the density grid, the poses and the intrinsics enter, without randomness: the same inputs
    give the same map.
    """
    device = sigma.device
    X, Y, Z = sigma.shape
    lo_t = torch.as_tensor(lo, dtype=torch.float32, device=device)
    hi_t = torch.as_tensor(hi, dtype=torch.float32, device=device)
    shape = torch.tensor([X, Y, Z], device=device)
    cell = (hi_t - lo_t) / shape.float()
    k0, k1 = band_layers
    ii, jj, kk = torch.meshgrid(torch.arange(X, device=device), torch.arange(Y, device=device),
                                torch.arange(k0, k1, device=device), indexing="ij")
    ijk = torch.stack([ii, jj, kk], -1).reshape(-1, 3)
    centres = lo_t + (ijk.float() + 0.5) * cell
    column = ijk[:, 0] * Y + ijk[:, 1]
    is_dense = sigma[ijk[:, 0], ijk[:, 1], ijk[:, 2]] > density_threshold
    slack = float(surface_tolerance_cells) * float(torch.linalg.vector_norm(cell))
    seen = torch.zeros(X * Y, dtype=torch.bool, device=device)
    carved = torch.zeros(len(centres), dtype=torch.bool, device=device)
    hits = torch.zeros(X * Y * (k1 - k0), dtype=torch.int32, device=device)
    remaining = torch.arange(len(centres), device=device)  # the cells not carved yet
    step_m = 0.5 * float(cell.min())
    # only where a ray stops near the band matters (a stop further on is "beyond every band cell"):
    # rays are followed until they leave the band's slab widened by the surface slack and the hit
    # depth, plus two cells for pixel-centre against cell-centre directions
    margin = slack + (HIT_DEPTH_CELLS + 2.0) * float(cell.max())
    slab = (float(lo_t[2] + k0 * cell[2]) - margin, float(lo_t[2] + k1 * cell[2]) + margin)
    small_cams = {}
    for n in range(len(views.cam_to_world)):
        ci = int(views.camera_index[n])
        if ci not in small_cams:
            cam = views.cameras[ci]
            pixels = cam.width * cam.height
            small = cam.scaled(math.sqrt(depth_pixels / pixels)) if pixels > depth_pixels else cam
            d = small.pixel_dirs_cam(like=torch.zeros((), dtype=torch.float64)).to(torch.float32).to(device)
            small_cams[ci] = (small, d)
        small, dirs_cam = small_cams[ci]
        h, w = dirs_cam.shape[:2]
        c2w = torch.as_tensor(views.cam_to_world[n], dtype=torch.float32, device=device)
        rot, origin = c2w[:3, :3], c2w[:3, 3]
        ok_dir = torch.isfinite(dirs_cam).all(-1).reshape(-1)
        d_world = torch.nn.functional.normalize(dirs_cam.reshape(-1, 3)[ok_dir] @ rot.T, dim=-1)
        stop = opaque_range(sigma, lo_t, hi_t, origin.expand_as(d_world), d_world, views.near_m, views.far_m, step_m,
                            z_range=slab)
        # hits: where the rays stopped, one cell into the matter, counted per band cell
        stopped = torch.isfinite(stop)
        end = origin + (stop[stopped, None] + HIT_DEPTH_CELLS * float(cell.min())) * d_world[stopped]
        e = torch.floor((end - lo_t) / cell).long()
        inb = ((e >= 0) & (e < shape)).all(-1) & (e[:, 2] >= k0) & (e[:, 2] < k1)
        e = e[inb]
        hits.index_add_(0, (e[:, 0] * Y + e[:, 1]) * (k1 - k0) + e[:, 2] - k0,
                        torch.ones(len(e), dtype=torch.int32, device=device))
        if remaining.numel() == 0:
            continue
        depth = torch.zeros(h * w, device=device)  # a pixel the model cannot unproject sees nothing
        depth[ok_dir] = stop
        depth = -torch.nn.functional.max_pool2d(-depth.view(1, 1, h, w), 3, stride=1, padding=1)[0, 0]
        rel = centres[remaining] - origin
        rng = torch.linalg.vector_norm(rel, dim=-1)
        uv, inside = small.project(rel @ rot)
        u = torch.round(uv[:, 0]).long().clamp(0, w - 1)
        v = torch.round(uv[:, 1]).long().clamp(0, h - 1)
        reach = depth[v, u]
        ok = inside & (rng >= views.near_m) & (rng <= views.far_m)
        nearer = torch.where(is_dense[remaining], rng <= reach + slack, rng < reach)
        seen[column[remaining[ok & nearer]]] = True
        carved[remaining[ok & (rng < reach)]] = True
        remaining = remaining[~carved[remaining]]
    return (seen.view(X, Y).cpu().numpy(), carved.view(X, Y, k1 - k0).cpu().numpy(),
            hits.view(X, Y, k1 - k0).cpu().numpy())


@torch.no_grad()
def obstacle_map(density_fn: DensityFn, aabb: Tensor | np.ndarray, band_m: tuple[float, float], cell_m: float,
                 density_threshold: float, samples_per_cell: int = 2, generator: torch.Generator | None = None,
                 chunk: int = 1 << 16, device: str | torch.device = "cpu", views: CameraViews | None = None,
                 depth_pixels: int = OBSTACLE_DEPTH_PIXELS, skip: OccupancyGrid | None = None) -> ObstacleMap:
    """2D obstacles over the scene box's xy extent: density above ``density_threshold`` in the height band.

    With ``views`` (the training cameras), also which cells were observed (``observed_columns``):
    the density is sampled on a column grid that reaches from the band to the cameras' heights
    (within the box), so that whatever stands between a camera and the band occludes it.
    With views, a band cell is occupied when at least ``HIT_MIN_RAYS`` of the views' rays stopped
    in it or its density is above the threshold, and no view's rays went through its centre and on
    (``observed_columns``: hits and carving, on depth maps of ``depth_pixels`` pixels; a thin table top
    stops rays though point samples of its density miss it, and what rays cross is not matter:
    haze in the air, and the soft front a NeRF draws a few centimetres before a surface, where rays
    grazing the surface stop: the carving decides at the cell's centre, as the ground truth does).
    Without views, the density alone decides. Observed follows the transmittance.
    ``skip``: the scene's occupancy grid (baked at a density far below ``density_threshold``): the
    field is not evaluated in its empty cells (they count as density 0: below the threshold, and
    too thin to stop a ray).
    """
    aabb_np = np.asarray(torch.as_tensor(aabb).cpu(), dtype=np.float64)
    z_lo, z_hi = float(band_m[0]), float(band_m[1])
    if not z_hi > z_lo:
        raise ValueError(f"obstacle band: expected z_lo < z_hi, got {band_m}")
    nx, ny = grid_shape(aabb_np[:, :2], cell_m)
    nz = max(1, int(math.ceil((z_hi - z_lo) / cell_m)))
    dz = (z_hi - z_lo) / nz
    below = above = 0
    if views is not None and len(views.cam_to_world):
        cam_z = views.cam_to_world[:, 2, 3]
        z_top = min(float(cam_z.max()), float(aabb_np[1, 2]))
        z_bottom = max(float(cam_z.min()), float(aabb_np[0, 2]))
        above = max(0, int(math.ceil((z_top - z_hi) / dz - 1e-9)))
        below = max(0, int(math.ceil((z_lo - z_bottom) / dz - 1e-9)))
    lo = np.array([aabb_np[0, 0], aabb_np[0, 1], z_lo - below * dz])
    hi = np.array([aabb_np[0, 0] + nx * cell_m, aabb_np[0, 1] + ny * cell_m, z_hi + above * dz])
    dens = max_density_on_grid(density_fn, lo, hi, (nx, ny, below + nz + above), samples_per_cell, generator,
                               chunk, device, skip)
    dense = (dens[:, :, below : below + nz] > density_threshold).cpu().numpy()
    observed = None
    if views is not None:
        observed, carved, hits = observed_columns(dens, density_threshold, lo, hi, (below, below + nz), views,
                                                  depth_pixels)
        dense = (dense | (hits >= HIT_MIN_RAYS)) & ~carved
    occupied = dense.any(-1)
    return ObstacleMap((float(lo[0]), float(lo[1])), float(cell_m), occupied, (z_lo, z_hi), observed)


# ---------------------------------------------------------------------- scoring against ground truth
def free_space_truth(like: ObstacleMap, interior_xy_m: np.ndarray, boxes_xyz_m: np.ndarray) -> np.ndarray:
    """The true free cells of ``like``'s grid: ``(NX, NY)`` bool.

    A cell is free when its centre lies inside the walls' interior ``interior_xy_m [[x0, y0], [x1, y1]]``
    and outside the footprint of every box ``boxes_xyz_m (B, 2, 3)`` (min, max corners) whose
    height range overlaps the map's band.
    """
    xy = like.cell_centres_m()
    inner = np.asarray(interior_xy_m, dtype=np.float64)
    free = np.all((xy > inner[0]) & (xy < inner[1]), axis=-1)
    z_lo, z_hi = like.band_m
    for lo, hi in np.asarray(boxes_xyz_m, dtype=np.float64).reshape(-1, 2, 3):
        if hi[2] <= z_lo or lo[2] >= z_hi:
            continue
        free &= ~np.all((xy >= lo[:2]) & (xy <= hi[:2]), axis=-1)
    return free


def room_free_space(spec, like: ObstacleMap) -> np.ndarray:
    """``free_space_truth`` of a test room (``nsim.synth.room.RoomSpec``): its interior and furniture."""
    X, Y, _ = spec.size_xyz_m
    boxes = np.array([[b.min_xyz_m, b.max_xyz_m] for b in spec.boxes]).reshape(-1, 2, 3)
    return free_space_truth(like, np.array([[0.0, 0.0], [X, Y]]), boxes)


def free_space_iou(free: np.ndarray, true_free: np.ndarray) -> float:
    """Intersection over union of two free-space masks of the same grid (1.0 when both are empty)."""
    free, true_free = np.asarray(free, dtype=bool), np.asarray(true_free, dtype=bool)
    if free.shape != true_free.shape:
        raise ValueError(f"free_space_iou: shapes differ, {free.shape} vs {true_free.shape}")
    union = int(np.count_nonzero(free | true_free))
    return 1.0 if union == 0 else int(np.count_nonzero(free & true_free)) / union


def room_free_space_iou(om: ObstacleMap, spec) -> float:
    """Free-space IoU of a scene's map against a test room's ground truth (issue 20's bar: >= 0.9).

    For a bench: ``room_free_space_iou(ObstacleMap.load(scene_dir), RoomSpec.from_dict(room["spec"]))``
    with ``room`` the capture's ``room.json``.
    """
    return free_space_iou(om.free, room_free_space(spec, om))
