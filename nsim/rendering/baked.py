"""A baked scene (``BakedScene``): the scene NeRF's density and geometry features on a sparse voxel grid, its files,
and rendering it by ray marching, for fast sensors. How a scene is baked: ``nsim.rendering.bake_bricks``.

Layout
    Every occupied cell of the occupancy grid holds a *brick*: a lattice of ``(B + 1)^3`` points spaced ``voxel =
    cell / B`` (a brick's boundary points are repeated in its neighbours', so that a cell is interpolated from its
    own brick alone), each with the field's density ``sigma`` (1/m) and geometry features (the density MLP's
    ``geo_feat_dim`` outputs, the colour head's input). The colour head (``ColorDecoder``) is the NeRF's own with
    the mean appearance embedding folded into its first bias: the same ``sigmoid(MLP([SH(dir), geo, code]))`` as
    ``SceneField.color``.

Rendering (``render_baked``: rays in, a ``RenderOutput`` out)
    Two-level marching with a constant step. Coarse steps of ``step_c`` (the smallest side of
    an occupancy cell) test whole segments: the segment ``[t_j, t_j + step_c)`` moves by at most
    one cell along each axis, so every cell it touches lies between the cells of its two ends,
    in the 2 x 2 x 2 block from their per-axis minimum; a segment whose block holds no brick is
    skipped as a whole (exactly: nothing in it is baked). Flagged segments are cut
    into ``M = ceil(B / step_voxels)`` fine steps; a fine sample in an occupied cell takes the
    trilinear density of its brick. Blocks of ``block_cells`` coarse steps are marched for the
    rays still alive; a ray stops once its transmittance is below ``stop_transmittance`` and
    only the samples before that point are kept (early termination, as the NeRF's grid
    sampler). The kept samples are volume-rendered with ``nsim.volume.quadrature`` exactly as
    ``SceneModel.render_grid`` does (padded ``(R, S)`` samples: weights, normalised expected
    depth, median depth, accumulation, the background). Colour is decoded only for samples
    whose weight reaches ``color_skip_weight / n`` (``n`` the ray's kept samples): the skipped
    ones count as black, so a ray's colour is off by at most ``color_skip_weight`` per channel.
    Colour from the scene field (the field attached with ``with_field``; ``nsim render`` attaches the
    checkpoint's): with ``field_samples = m > 0`` (instant-NGP's division of labour: the baked structure decides
    where a ray's light comes from, the field is queried only there) the field is volume-rendered by itself over
    ``m`` bins within ``field_window_voxels`` of each ray's baked median depth (``_field_window``): ``m`` field
    queries a ray instead of the NeRF's ``final_samples`` and proposal samples. The window's colour becomes the
    ray's (times the baked accumulation) and its depth replaces the baked one where the window holds most of the
    surface. Otherwise, with ``field_color_samples = k > 0``,
    the ``k`` heaviest samples of each ray take the field's colour at their midpoints and the rest the
    interpolated features' (nsim/configs/bake/default.yaml has the measurements of both). Rays rendered without
    colour (``colour=False``: a LiDAR) decode none: their depth is the window's (the field's density alone)
    with ``field_samples``, else the baked density's.

Surface (``surface``; ``nsim.rendering.bake_bricks.bake_surface``, ``nsim.rendering.surface``)
    The bake's density meshed at ``surface_level``, the mesh fitted to the NeRF's median depths on the training
    rays and textured from the training images. A baked scene with a surface renders every ray from it (one
    Embree cast and one texture lookup; ``render_chunk``): the brick grid and the field window are then not used,
    and camera rays that miss the mesh go to the NeRF (``nerf_fallback_accumulation``).

Shapes: rays ``(R,)``; ``brick_index (X, Y, Z)`` int32 (``-1``: no brick); ``density (N, P)``
float32 and ``features (N, P, G)`` with ``P = (B + 1)^3`` lattice points per brick, lattice point
``(a, b, c)`` of brick ``n`` at ``cell_min(n) + (a, b, c) * voxel``, flattened ``(a * (B + 1) + b) *
(B + 1) + c``. World metres, z up (``nsim.geometry.conventions``).

Files (``BakedScene.save`` / ``load``): ``baked.json`` (layout, sizes, the scene's sampler
settings, the decoder's shape) and plain ``.npy`` arrays (no pickles, no zip timestamps: the same
bake writes the same bytes).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nsim.errors import InputError
from nsim.fields.encodings import spherical_harmonics
from nsim.fields.mlp import MLP
from nsim.rendering.model import BACKGROUNDS
from nsim.rendering.surface import BakedSurface, SurfaceTexture, render_surface
from nsim.volume import quadrature
from nsim.volume.rays import Rays
from nsim.volume.samples import RaySamples, RenderOutput

FORMAT = 1
BAKED_FILE = "baked.json"
ARRAY_FILES = ("brick_index.npy", "density.npy", "features.npy")


# ---------------------------------------------------------------------------------- the colour head
class ColorDecoder(nn.Module):
    """``SceneField.color`` with a fixed appearance code: ``rgb = sigmoid(MLP([SH(dirs), geo]))``.

    The code's share of the first layer is folded into its bias (``b + W_code @ code``), so the
    network reads ``sh_degree**2 + geo_dim`` inputs."""

    def __init__(self, weights: list[Tensor], biases: list[Tensor], sh_degree: int) -> None:
        super().__init__()
        dims = [weights[0].shape[1]] + [w.shape[0] for w in weights]
        hidden = dims[1] if len(weights) > 1 else 1
        self.sh_degree = int(sh_degree)
        # the layers' values are replaced below: initialise from a private generator, not the global one
        self.mlp = MLP(dims[0], hidden, len(weights) - 1, dims[-1], torch.Generator().manual_seed(0))
        with torch.no_grad():
            for layer, w, b in zip(self.mlp.layers, weights, biases, strict=True):
                if tuple(layer.weight.shape) != tuple(w.shape) or tuple(layer.bias.shape) != tuple(b.shape):
                    raise ValueError(f"ColorDecoder: layer shapes {[tuple(x.shape) for x in weights]} are not an MLP's")
                layer.weight.copy_(w)
                layer.bias.copy_(b)
        self.requires_grad_(False)

    @property
    def geo_dim(self) -> int:
        return self.mlp.layers[0].in_features - self.sh_degree**2

    @classmethod
    def from_field(cls, field, code: Tensor | None) -> ColorDecoder:
        """The decoder of a ``SceneField`` with the appearance ``code (A,)`` (None: the field has none)."""
        layers = list(field.color_mlp.layers)
        weights = [layer.weight.detach().float().cpu().clone() for layer in layers]
        biases = [layer.bias.detach().float().cpu().clone() for layer in layers]
        keep = field.cfg.sh_degree**2 + field.cfg.geo_feat_dim
        if code is not None:
            w_code = weights[0][:, keep:]
            biases[0] = biases[0] + w_code @ code.detach().float().cpu()
        weights[0] = weights[0][:, :keep].contiguous()
        return cls(weights, biases, field.cfg.sh_degree)

    def forward(self, geo: Tensor, dirs: Tensor) -> Tensor:
        """geo ``(N, G)``, unit dirs ``(N, 3)`` -> rgb ``(N, 3)`` in (0, 1)."""
        x = torch.cat([spherical_harmonics(dirs, self.sh_degree).to(geo.dtype), geo], dim=-1)
        return torch.sigmoid(self.mlp(x).float())

    def arrays(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        return ([layer.weight.detach().cpu().numpy().astype(np.float32) for layer in self.mlp.layers],
                [layer.bias.detach().cpu().numpy().astype(np.float32) for layer in self.mlp.layers])

    def moved(self, device) -> ColorDecoder:
        """A copy on ``device`` (this one stays where it is)."""
        weights, biases = self.arrays()
        return ColorDecoder([torch.as_tensor(w) for w in weights], [torch.as_tensor(b) for b in biases],
                            self.sh_degree).to(device)


# ---------------------------------------------------------------------------------- the baked scene
@dataclass(frozen=True, eq=False)
class BakedScene:
    """A baked scene (module docstring). aabb: (2, 3) the occupancy grid's box; brick_index: (X, Y, Z)
    int32; density: (N, P) float32, 1/m; features: (N, P, G); bricks_per_side: B; decoder: the colour
    head; step_voxels, block_cells, stop_transmittance, color_skip_weight: the marcher's settings;
    background, background_rgb (3,): what a ray's remaining light is composited over (the scene
    model's ``SamplerConfig.background``); meta: baked.json's other entries."""

    aabb: Tensor
    brick_index: Tensor
    density: Tensor
    features: Tensor
    bricks_per_side: int
    decoder: ColorDecoder
    step_voxels: float
    block_cells: int
    stop_transmittance: float
    color_skip_weight: float
    background: str
    background_rgb: Tensor
    meta: dict = dataclasses.field(default_factory=dict)
    field_color_samples: int = 0
    field_samples: int = 0
    field_window_voxels: float = 1.5
    nerf_fallback_share: float | None = None
    nerf_fallback_voxels: float = 4.0
    nerf_fallback_accumulation: float | None = None
    field: nn.Module | None = None
    surface: BakedSurface | None = None
    block_occupied: Tensor = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        # flat (X * Y * Z,) bool: a brick among the 2 x 2 x 2 cells from (i, j, k) to (i + 1, j + 1, k + 1)
        # (the coarse march's test)
        occ = torch.nn.functional.pad((self.brick_index >= 0).float()[None, None], (0, 1, 0, 1, 0, 1))
        block = torch.nn.functional.max_pool3d(occ, 2, stride=1)[0, 0] > 0
        object.__setattr__(self, "block_occupied", block.reshape(-1))

    # -- geometry
    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.brick_index.shape)

    @property
    def cell_m(self) -> Tensor:
        """(3,) the occupancy cell's sides."""
        return (self.aabb[1] - self.aabb[0]) / torch.tensor(self.shape, dtype=torch.float32, device=self.aabb.device)

    @property
    def voxel_m(self) -> Tensor:
        """(3,) the lattice spacing."""
        return self.cell_m / self.bricks_per_side

    @property
    def n_bricks(self) -> int:
        return int(self.density.shape[0])

    @property
    def device(self) -> torch.device:
        return self.density.device

    def to(self, device) -> BakedScene:
        return dataclasses.replace(self, aabb=self.aabb.to(device), brick_index=self.brick_index.to(device),
                                   density=self.density.to(device), features=self.features.to(device),
                                   decoder=self.decoder.moved(device),
                                   background_rgb=self.background_rgb.to(device),
                                   surface=None if self.surface is None else self.surface.to(device))

    @property
    def uses_field(self) -> bool:
        """Whether rendering queries the scene field (``field_samples`` or ``field_color_samples``): then a
        renderer attaches it (:meth:`with_field`). Never with a surface, which renders every ray."""
        return self.surface is None and (self.field_samples > 0 or self.field_color_samples > 0)

    @property
    def falls_back(self) -> bool:
        """Whether some camera rays are rendered by the NeRF (``nerf_fallback_share`` or
        ``nerf_fallback_accumulation``): then a renderer passes it (``render_baked``'s ``fallback``)."""
        return self.nerf_fallback_share is not None or self.nerf_fallback_accumulation is not None

    def with_field(self, field) -> BakedScene:
        """This scene with the ``SceneField`` it was baked from attached (on the scene's device), for
        ``field_samples`` / ``field_color_samples`` (:attr:`uses_field`)."""
        return dataclasses.replace(self, field=field)

    def nbytes(self) -> int:
        grid = sum(int(t.numel() * t.element_size()) for t in (self.brick_index, self.density, self.features))
        return grid + (0 if self.surface is None else self.surface.nbytes())

    # -- files
    def save(self, out_dir: str | Path, extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """Write ``baked.json`` and the arrays into ``out_dir``; returns baked.json's content."""
        out_dir = Path(out_dir)
        np.save(out_dir / "brick_index.npy", self.brick_index.cpu().numpy().astype(np.int32), allow_pickle=False)
        np.save(out_dir / "density.npy", self.density.cpu().numpy().astype(np.float32), allow_pickle=False)
        np.save(out_dir / "features.npy", self.features.cpu().numpy(), allow_pickle=False)
        weights, biases = self.decoder.arrays()
        decoder_files = []
        for k, (w, b) in enumerate(zip(weights, biases, strict=True)):
            np.save(out_dir / f"color_layer{k}_weight.npy", w, allow_pickle=False)
            np.save(out_dir / f"color_layer{k}_bias.npy", b, allow_pickle=False)
            decoder_files.append([f"color_layer{k}_weight.npy", f"color_layer{k}_bias.npy"])
        surface = None
        if self.surface is not None:
            np.save(out_dir / "surface_vertices.npy", self.surface.vertices.astype(np.float32), allow_pickle=False)
            np.save(out_dir / "surface_faces.npy", self.surface.faces.astype(np.int32), allow_pickle=False)
            for stem, arr in self.surface.texture.arrays().items():
                np.save(out_dir / f"{stem}.npy", arr, allow_pickle=False)
            surface = {"vertices": len(self.surface.vertices), "faces": len(self.surface.faces),
                       "texture": self.surface.texture.settings, **self.surface.stats}
        doc = {
            "format": FORMAT,
            "units": "metres; density in 1/m",
            "frame": "world frame of the scene checkpoint, z up",
            "aabb_m": self.aabb.cpu().tolist(),
            "grid_shape": list(self.shape),
            "bricks": self.n_bricks,
            "bricks_per_side": self.bricks_per_side,
            "voxel_m": [round(float(v), 9) for v in self.voxel_m.cpu()],
            "geo_dim": int(self.features.shape[-1]),
            "feature_dtype": str(self.features.dtype).removeprefix("torch."),
            "sh_degree": self.decoder.sh_degree,
            "decoder_layers": decoder_files,
            "step_voxels": self.step_voxels,
            "block_cells": self.block_cells,
            "stop_transmittance": self.stop_transmittance,
            "color_skip_weight": self.color_skip_weight,
            "field_color_samples": self.field_color_samples,
            "field_samples": self.field_samples,
            "field_window_voxels": self.field_window_voxels,
            "nerf_fallback_share": self.nerf_fallback_share,
            "nerf_fallback_voxels": self.nerf_fallback_voxels,
            "nerf_fallback_accumulation": self.nerf_fallback_accumulation,
            "background": self.background,
            "background_rgb": [float(c) for c in self.background_rgb.cpu()],
            **({"surface": surface} if surface is not None else {}),
            "layout": "brick_index[i, j, k]: brick of occupancy cell (i, j, k) or -1; density[n, (a * (B + 1) + b) * "
                      "(B + 1) + c] and features[n, ...]: lattice point cell_min + (a, b, c) * voxel of brick n",
            **self.meta,
            **(extra or {}),
        }
        (out_dir / BAKED_FILE).write_text(json.dumps(doc, indent=1) + "\n")
        return doc

    @classmethod
    def load(cls, baked_dir: str | Path, device: str | torch.device = "cpu") -> BakedScene:
        """Read a baked scene written by :meth:`save`, checked (one-line ``InputError`` when it is not one)."""
        baked_dir = Path(baked_dir)
        where = baked_dir / BAKED_FILE
        try:
            doc = json.loads(where.read_text())
        except (FileNotFoundError, NotADirectoryError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{where}: not a baked scene ({exc.__class__.__name__})") from None
        try:
            if doc.get("format") != FORMAT:
                raise ValueError(f"format {doc.get('format')!r}, expected {FORMAT}")
            b = int(doc["bricks_per_side"])
            p = (b + 1) ** 3
            shape = tuple(int(s) for s in doc["grid_shape"])
            n = int(doc["bricks"])
            g = int(doc["geo_dim"])
            index = _read_array(baked_dir / "brick_index.npy", shape, np.int32)
            density = _read_array(baked_dir / "density.npy", (n, p), np.float32)
            features = _read_array(baked_dir / "features.npy", (n, p, g), np.dtype(doc["feature_dtype"]))
            if index.size and (index.min() < -1 or index.max() >= n or np.count_nonzero(index >= 0) != n):
                raise ValueError("brick_index: expected -1 or each brick 0..N-1 once")
            if not (np.isfinite(density).all() and (density >= 0).all() and np.isfinite(features).all()):
                raise ValueError("density / features: non-finite or negative values")
            weights, biases = [], []
            for wf, bf in doc["decoder_layers"]:
                if "/" in wf or "/" in bf:
                    raise ValueError("decoder_layers: file names only")
                weights.append(torch.as_tensor(_read_array(baked_dir / wf, None, np.float32)))
                biases.append(torch.as_tensor(_read_array(baked_dir / bf, None, np.float32)))
            decoder = ColorDecoder(weights, biases, int(doc["sh_degree"]))
            surface = _load_surface(baked_dir, doc["surface"], aabb=torch.tensor(doc["aabb_m"], dtype=torch.float32)) \
                if doc.get("surface") is not None else None
            if g == 0 and int(doc.get("field_samples", 0)) == 0 and surface is None:
                raise ValueError("no features stored (feature_dtype none) and field_samples 0: no colour")
            if g and decoder.geo_dim != g:
                raise ValueError(f"decoder reads {decoder.geo_dim} features, the grid holds {g}")
            if doc["background"] not in BACKGROUNDS:
                raise ValueError(f"background {doc['background']!r}")
            aabb = torch.tensor(doc["aabb_m"], dtype=torch.float32)
            if aabb.shape != (2, 3) or not bool((aabb[1] > aabb[0]).all()):
                raise ValueError("aabb_m: expected [[x0, y0, z0], [x1, y1, z1]] with x1 > x0 ...")
            known = {"format", "units", "frame", "aabb_m", "grid_shape", "bricks", "bricks_per_side", "voxel_m", "geo_dim",
                     "feature_dtype", "sh_degree", "decoder_layers", "step_voxels", "block_cells", "stop_transmittance",
                     "color_skip_weight", "field_color_samples", "field_samples", "field_window_voxels",
                     "nerf_fallback_share", "nerf_fallback_voxels", "nerf_fallback_accumulation", "background",
                     "background_rgb", "layout", "surface"}
            baked = cls(aabb=aabb, brick_index=torch.as_tensor(index), density=torch.as_tensor(density),
                        features=torch.as_tensor(features), bricks_per_side=b, decoder=decoder,
                        step_voxels=float(doc["step_voxels"]), block_cells=int(doc["block_cells"]),
                        stop_transmittance=float(doc["stop_transmittance"]),
                        color_skip_weight=float(doc["color_skip_weight"]), background=doc["background"],
                        field_color_samples=int(doc.get("field_color_samples", 0)),
                        field_samples=int(doc.get("field_samples", 0)),
                        field_window_voxels=float(doc.get("field_window_voxels", 1.5)),
                        nerf_fallback_share=(None if doc.get("nerf_fallback_share") is None
                                             else float(doc["nerf_fallback_share"])),
                        nerf_fallback_voxels=float(doc.get("nerf_fallback_voxels", 4.0)),
                        nerf_fallback_accumulation=(None if doc.get("nerf_fallback_accumulation") is None
                                                    else float(doc["nerf_fallback_accumulation"])),
                        background_rgb=torch.tensor(doc["background_rgb"], dtype=torch.float32),
                        surface=surface, meta={k: v for k, v in doc.items() if k not in known})
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: not a readable baked scene ({exc})") from None
        return baked.to(device)


def _load_surface(baked_dir: Path, doc: dict, aabb: Tensor) -> BakedSurface:
    """The surface ``BakedScene.save`` wrote (``ValueError`` naming what is wrong)."""
    n_v, n_f = int(doc["vertices"]), int(doc["faces"])
    vertices = np.array(_read_array(baked_dir / "surface_vertices.npy", (n_v, 3), np.float32))
    faces = np.array(_read_array(baked_dir / "surface_faces.npy", (n_f, 3), np.int32))
    if not np.isfinite(vertices).all():
        raise ValueError("surface_vertices.npy: non-finite values")
    if faces.size and (faces.min() < 0 or faces.max() >= n_v):
        raise ValueError(f"surface_faces.npy: vertex indices outside 0..{n_v - 1}")
    settings = doc["texture"]
    arrays = {stem: _read_array(baked_dir / f"{stem}.npy", None, np.float32) for stem in SurfaceTexture.file_stems()}
    texture = SurfaceTexture.from_arrays(aabb, settings, arrays)
    return BakedSurface(vertices, faces, texture, {k: v for k, v in doc.items()
                                                   if k not in ("vertices", "faces", "texture")})


def _read_array(path: Path, shape: tuple[int, ...] | None, dtype) -> np.ndarray:
    """A ``.npy`` file of ``dtype`` (and ``shape`` when given), its header checked before the data is read."""
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (FileNotFoundError, ValueError, OSError) as exc:
        raise ValueError(f"{path.name}: {exc.__class__.__name__}") from None
    if arr.dtype != np.dtype(dtype) or (shape is not None and tuple(arr.shape) != tuple(shape)):
        raise ValueError(f"{path.name}: {arr.dtype} {tuple(arr.shape)}, expected {np.dtype(dtype)} {shape}")
    return np.array(arr)


# ---------------------------------------------------------------------------------- rendering
def _cells_of(baked: BakedScene, u: Tensor) -> tuple[Tensor, Tensor]:
    """Flat index ``(...,)`` and ``ijk (..., 3)`` of the occupancy cells holding fine lattice coordinates
    ``u (..., 3)`` (clamped into the grid)."""
    shape = baked.brick_index.shape
    ijk = torch.floor(u * (1.0 / baked.bricks_per_side)).to(torch.int64)
    ijk = torch.minimum(ijk.clamp(min=0), torch.tensor(shape, device=u.device) - 1)
    return (ijk[..., 0] * shape[1] + ijk[..., 1]) * shape[2] + ijk[..., 2], ijk


def _trilinear(baked: BakedScene, brick: Tensor, local: Tensor) -> tuple[Tensor, Tensor]:
    """Lattice rows ``(n, 8)`` and trilinear weights ``(n, 8)`` of points at ``local (n, 3)`` (in voxels,
    ``[0, B]``) of bricks ``brick (n,)``."""
    b = baked.bricks_per_side
    i0 = torch.floor(local).clamp(0, b - 1)
    f = (local - i0).clamp(0.0, 1.0)
    i0 = i0.to(torch.int64)
    p = b + 1
    base = brick * (p**3) + (i0[:, 0] * p + i0[:, 1]) * p + i0[:, 2]
    d = torch.tensor([dx * p * p + dy * p + dz for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], device=local.device)
    fx, fy, fz = f[:, 0:1], f[:, 1:2], f[:, 2:3]
    wx = torch.cat([1 - fx, fx], -1)
    wy = torch.cat([1 - fy, fy], -1)
    wz = torch.cat([1 - fz, fz], -1)
    w = (wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]).reshape(-1, 8)
    return base[:, None] + d, w


def density_at(baked: BakedScene, brick: Tensor, local: Tensor) -> Tensor:
    """Trilinear density ``(n,)`` (1/m) at ``local (n, 3)`` of bricks ``brick (n,)``."""
    rows, w = _trilinear(baked, brick, local)
    return (baked.density.view(-1)[rows] * w).sum(-1)


def features_at(baked: BakedScene, brick: Tensor, local: Tensor) -> Tensor:
    """Trilinear geometry features ``(n, G)`` float32 at ``local (n, 3)`` of bricks ``brick (n,)``."""
    rows, w = _trilinear(baked, brick, local)
    g = baked.features.shape[-1]
    return (baked.features.view(-1, g)[rows].float() * w[..., None]).sum(1)


def locate(baked: BakedScene, x_world: Tensor) -> tuple[Tensor, Tensor]:
    """Brick ``(...,)`` int64 (-1: free) and local lattice coordinates ``(..., 3)`` of world points ``x_world (..., 3)``
    (points outside the box: free)."""
    u = (x_world - baked.aabb[0]) / baked.voxel_m
    flat, ijk = _cells_of(baked, u)
    brick = baked.brick_index.view(-1)[flat].to(torch.int64)
    shape = torch.tensor(baked.shape, device=x_world.device) * baked.bricks_per_side
    inside = ((u >= 0) & (u <= shape)).all(-1)
    return torch.where(inside, brick, -1), u - ijk * baked.bricks_per_side


def steps(baked: BakedScene) -> tuple[float, float, int]:
    """``(step_c, step_f, M)``: the coarse step (the cell's smallest side, a hair less: a segment's ends never
    lie more than one cell apart), the fine step and ``M = step_c / step_f``."""
    step_c = float(baked.cell_m.min()) * (1.0 - 1e-4)
    m = max(1, int(math.ceil(baked.bricks_per_side / baked.step_voxels - 1e-9)))
    return step_c, step_c / m, m


@torch.no_grad()
def march(baked: BakedScene, rays: Rays) -> tuple[Tensor, ...]:
    """The kept samples of every ray, ray-major and ordered along each ray: ``ray, t0, t1, sigma, brick,
    local`` (packed, ``(K,)`` / ``(K, 3)``)."""
    n = len(rays)
    device = rays.origins.device
    step_c, step_f, m_fine = steps(baked)
    block_occ = baked.block_occupied
    shape = baked.shape
    index_flat = baked.brick_index.view(-1)
    b = baked.bricks_per_side
    inv_voxel = 1.0 / baked.voxel_m
    top = torch.tensor(baked.shape, device=device, dtype=torch.float32) * b  # the box's far corner in voxels
    ou = (rays.origins - baked.aabb[0]) * inv_voxel  # (R, 3) fine lattice coordinates of the origins
    du = rays.dirs * inv_voxel
    length = (rays.far - rays.near).clamp(min=0.0)
    n_coarse = max(1, int(math.ceil(float(length.max()) / step_c))) if n else 0
    stop_tau = -math.log(baked.stop_transmittance) if baked.stop_transmittance > 0 else math.inf
    tau = torch.zeros(n, dtype=torch.float64, device=device)  # optical depth so far
    alive = torch.arange(n, device=device)
    fine = torch.arange(m_fine, device=device)
    kept: list[tuple[Tensor, ...]] = []
    for start in range(0, n_coarse, baked.block_cells):
        if alive.numel() == 0:
            break
        j = torch.arange(start, min(n_coarse, start + baked.block_cells), device=device)
        near, far = rays.near[alive], rays.far[alive]
        tj = near[:, None] + torch.cat([j, j[-1:] + 1])[None, :].to(near.dtype) * step_c  # (A, Kc + 1)
        ijk = _cells_of(baked, ou[alive, None, :] + tj[..., None] * du[alive, None, :])[1]
        lo = torch.minimum(ijk[:, :-1], ijk[:, 1:])  # segment [t_j, t_j+1) lies in the cells lo .. lo + 1
        tj = tj[:, :-1]
        flag = block_occ[(lo[..., 0] * shape[1] + lo[..., 1]) * shape[2] + lo[..., 2]] & (tj < far[:, None])
        r, c = torch.nonzero(flag, as_tuple=True)  # (F,): ray-major, along each ray
        if r.numel():
            kf = j[c, None] * m_fine + fine  # (F, M) fine step indices
            t0 = near[r, None] + kf.to(near.dtype) * step_f
            t1 = torch.minimum(t0 + step_f, far[r, None])
            mid = 0.5 * (t0 + t1)
            uf = ou[alive[r], None, :] + mid[..., None] * du[alive[r], None, :]  # (F, M, 3)
            flat, ijk = _cells_of(baked, uf)
            brick = index_flat[flat].to(torch.int64)
            inside = ((uf >= 0) & (uf <= top)).all(-1)  # rays not clipped to the box: nothing is baked outside it
            rr, cc = torch.nonzero((t1 > t0) & (brick >= 0) & inside, as_tuple=True)  # ray-major, along each ray
        if r.numel() and rr.numel():
            local = uf[rr, cc] - (ijk[rr, cc] * b).to(uf.dtype)
            brick, kf, t0, t1 = brick[rr, cc], kf[rr, cc], t0[rr, cc], t1[rr, cc]
            sig = density_at(baked, brick, local)
            # optical depth before each sample: the ray's so far + the block's samples before it
            ray_loc = r[rr]  # index into alive
            tau_s, before_s = quadrature.packed_optical_depth(sig, t1 - t0, ray_loc)
            before = tau[alive][ray_loc] + before_s
            keep = before < stop_tau
            if bool(keep.any()):
                kept.append((alive[ray_loc[keep]], kf[keep], t0[keep], t1[keep], sig[keep], brick[keep], local[keep]))
            block_tau = torch.zeros(len(alive), dtype=torch.float64, device=device).index_add_(0, ray_loc, tau_s)
            tau = tau.index_add(0, alive, block_tau)
        block_end = near + float(j[-1] + 1) * step_c
        done = (block_end >= far) | (tau[alive] >= stop_tau)
        alive = alive[~done]
    if not kept:
        z = torch.zeros(0, device=device)
        return (torch.zeros(0, dtype=torch.int64, device=device), z, z, z, torch.zeros(0, dtype=torch.int64, device=device),
                torch.zeros(0, 3, device=device))
    ray, kf, t0, t1, sig, brick, local = (torch.cat([k[i] for k in kept]) for i in range(7))
    order = torch.argsort(ray * (n_coarse * m_fine + 1) + kf, stable=True)  # blocks were appended block-major
    return ray[order], t0[order], t1[order], sig[order], brick[order], local[order]


def _composite(baked: BakedScene, rays: Rays, t0_p: Tensor, t1_p: Tensor, sigma_p: Tensor, rgb_p: Tensor,
               counts: Tensor, return_samples: bool, weights: Tensor) -> RenderOutput:
    """Volume rendering of padded ``(R, S)`` samples (``counts (R,)`` kept, the rest empty at the far end) with
    their ``weights`` (``quadrature.render_weights``) as ``SceneModel.render_grid`` does it: the background
    (``last_sample``: each ray's last kept sample), normalised expected depth, median depth, accumulation."""
    n = len(rays)
    device = rays.origins.device
    acc = weights.sum(-1)
    const = baked.background_rgb.to(device).expand(n, 3)
    if baked.background == "last_sample" and n:
        last = rgb_p[torch.arange(n, device=device), (counts - 1).clamp(min=0)]
        bg = torch.where((counts > 0)[:, None], last, const)
    else:
        bg = const
    out_rgb = quadrature.accumulate(weights, rgb_p) + (1.0 - acc)[:, None] * bg
    mid_p = 0.5 * (t0_p + t1_p)
    depth = torch.where(acc > quadrature.EPS, quadrature.expected_depth(weights, mid_p, acc), rays.far)
    return RenderOutput(rgb=out_rgb, depth=depth, depth_median=quadrature.median_depth(weights, mid_p), accumulation=acc,
                        weights=weights, samples=RaySamples(t0_p, t1_p, sigma_p, rgb_p) if return_samples else None,
                        background=bg)


def _field_window(baked: BakedScene, rays: Rays, centre: Tensor, colour: bool = True) -> tuple[Tensor, ...]:
    """``field_samples = m``: the scene field volume-rendered by itself in a window around each ray's baked median
    depth ``centre (R,)``: ``m`` equal bins over ``centre +- field_window_voxels`` voxels (clipped to the ray), the
    field's density at their midpoints (``m`` field queries; the colour head only where the weight is not
    negligible, ``color_skip_weight``), weights as ``quadrature.render_weights``.
    Returns the window's colour normalised by its weight ``(R, 3)`` (``colour=False``: zeros, no colour head),
    its expected and median depth ``(R,)`` and its weight ``(R,)`` (how much of the surface the window holds)."""
    m = baked.field_samples
    half = baked.field_window_voxels * float(baked.voxel_m.max())
    a = torch.maximum(centre - half, rays.near)
    b = torch.minimum(centre + half, rays.far)
    edges = a[:, None] + (b - a)[:, None] * torch.linspace(0.0, 1.0, m + 1, device=centre.device)[None]
    t0, t1 = edges[:, :-1], edges[:, 1:]
    mid = 0.5 * (t0 + t1)
    x = rays.origins[:, None, :] + rays.dirs[:, None, :] * mid[..., None]
    sigma, geo = baked.field.density(x.reshape(-1, 3))
    w, _ = quadrature.render_weights(sigma.float().view(-1, m), t1 - t0)
    acc = w.sum(-1)
    # colour where a bin's weight reaches color_skip_weight / m of the window's (the skipped ones change the
    # normalised colour by at most color_skip_weight), and the middle bin of a clear window (its colour then)
    clear = acc <= quadrature.EPS
    need = w >= (baked.color_skip_weight / m) * acc[:, None]
    need[:, m // 2] |= clear
    need &= colour
    idx = torch.nonzero(need.view(-1), as_tuple=True)[0]
    rgb = torch.zeros(len(centre) * m, 3, device=centre.device)
    rgb[idx] = baked.decoder(geo[idx].float(), rays.dirs[idx // m])
    rgb = rgb.view(-1, m, 3)
    colour = quadrature.accumulate(w, rgb) / acc.clamp(min=quadrature.EPS)[:, None]
    colour = torch.where(clear[:, None], rgb[:, m // 2], colour)
    return colour, quadrature.expected_depth(w, mid, acc), quadrature.median_depth(w, mid), acc


@torch.no_grad()
def render_chunk(baked: BakedScene, rays: Rays, return_samples: bool = False, colour: bool = True,
                 fallback=None, may_fall_back: Tensor | None = None) -> RenderOutput:
    """Render ``rays`` (all at once: chunk outside) from the baked scene (module docstring). ``colour=False``
    (a LiDAR): depth and accumulation, no colour decoded (rgb is the background). fallback: the NeRF's renderer
    (``rays -> RenderOutput``) for the camera rays ``nerf_fallback_share`` and ``nerf_fallback_accumulation`` flag
    (:func:`fallback_rays`); their per-ray outputs are the NeRF's (not with ``return_samples``: the people's merge
    needs the baked samples). may_fall_back: ``(R,)`` bool, the rays that may (None: all; a sensor's pixels
    outside its image, whose outputs are dropped, need no NeRF)."""
    n = len(rays)
    device = rays.origins.device
    may = fallback is not None and colour and not return_samples
    if baked.surface is not None:  # the fitted mesh and its texture; rays that miss it may go to the NeRF
        out = render_surface(baked.surface, rays, baked.background_rgb, colour, return_samples)
        if may and baked.nerf_fallback_accumulation is not None:
            out = _fall_back(out, rays, out.accumulation < baked.nerf_fallback_accumulation, fallback, may_fall_back)
        return out
    ray, t0, t1, sigma, brick, local = march(baked, rays)
    counts = torch.bincount(ray, minlength=n)
    starts = torch.cumsum(counts, 0) - counts
    slot = torch.arange(ray.shape[0], device=device) - starts[ray]
    s_pad = max(1, int(counts.max()) if ray.numel() else 1)
    # padded (R, S) layout for volume rendering; padding: empty intervals at the far end (as render_grid)
    far = rays.far[:, None].expand(n, s_pad)
    t0_p = far.clone().index_put((ray, slot), t0)
    t1_p = far.clone().index_put((ray, slot), t1)
    sigma_p = torch.zeros(n, s_pad, device=device).index_put((ray, slot), sigma)
    weights, _ = quadrature.render_weights(sigma_p, t1_p - t0_p)
    window = None
    rgb_p = torch.zeros(n, s_pad, 3, device=device)
    windowed = baked.field is not None and baked.field_samples > 0
    if windowed and ray.numel():
        # the field's own colour and depth from a window around the baked surface (a LiDAR's: its depth alone);
        # every sample of a ray takes the window's colour: the ray's is acc * colour + (1 - acc) * background
        live = torch.nonzero(weights.sum(-1) > quadrature.EPS, as_tuple=True)[0]
        mid_p = 0.5 * (t0_p + t1_p)
        window = (live, *_field_window(baked, rays[live], quadrature.median_depth(weights[live], mid_p[live]), colour))
        if colour:
            rgb_p[live] = window[1][:, None, :].expand(-1, s_pad, -1)
    if colour and not windowed:  # (a windowed chunk whose rays cross no brick has nothing to colour)
        if baked.features.shape[-1] == 0:
            raise ValueError("render_chunk: a baked scene without features (feature_dtype none) needs the scene field "
                             "attached (with_field) and field_samples > 0")
        # colour where the weight reaches the ray's skip budget shared over its samples (and the last sample,
        # which the last_sample background needs)
        w = weights[ray, slot]
        keep = w >= baked.color_skip_weight / counts[ray].clamp(min=1).to(w.dtype)
        if baked.background == "last_sample":
            keep |= slot == counts[ray] - 1
        idx = torch.nonzero(keep, as_tuple=True)[0]
        if idx.numel():
            geo = features_at(baked, brick[idx], local[idx])
            rgb_p[ray[idx], slot[idx]] = baked.decoder(geo, rays.dirs[ray[idx]])
        k = min(baked.field_color_samples, s_pad)
        if baked.field is not None and k > 0 and ray.numel():
            # the heaviest samples of each ray: their colour from the field's own geometry features
            w_top, s_top = torch.topk(weights, k, dim=-1)
            r_top, c_top = torch.nonzero(w_top > 0, as_tuple=True)
            if r_top.numel():
                sl = s_top[r_top, c_top]
                mid = 0.5 * (t0_p[r_top, sl] + t1_p[r_top, sl])
                x = rays.origins[r_top] + rays.dirs[r_top] * mid[:, None]
                geo = baked.field.density(x)[1].float()
                rgb_p[r_top, sl] = baked.decoder(geo, rays.dirs[r_top])
    out = _composite(baked, rays, t0_p, t1_p, sigma_p, rgb_p, counts, return_samples, weights)
    if window is not None:  # the window's depth where it holds most of the surface
        live, _, depth, median, acc = window
        sure = acc > 0.5
        out.depth[live] = torch.where(sure, depth, out.depth[live])
        out.depth_median[live] = torch.where(sure, median, out.depth_median[live])
    if may and baked.falls_back:
        out = _fall_back(out, rays, fallback_rays(baked, weights, 0.5 * (t0_p + t1_p)), fallback, may_fall_back)
    return out


def _fall_back(out: RenderOutput, rays: Rays, flagged: Tensor, fallback, may_fall_back: Tensor | None) -> RenderOutput:
    """``out`` with the per-ray outputs of the ``flagged (R,)`` rays (those ``may_fall_back`` allows) replaced by
    ``fallback``'s (the NeRF's renderer, ``rays -> RenderOutput``)."""
    if may_fall_back is not None:
        flagged = flagged & may_fall_back
    split = torch.nonzero(flagged, as_tuple=True)[0]
    if split.numel():
        from nsim.rendering.renderer import PER_RAY_FIELDS

        nerf = fallback(rays[split])
        for f in PER_RAY_FIELDS:  # (copies: the background may be one colour expanded over the rays)
            mixed = getattr(out, f).clone()
            mixed[split] = getattr(nerf, f).to(mixed.dtype)
            setattr(out, f, mixed)
    return out


def fallback_rays(baked: BakedScene, weights: Tensor, mid: Tensor) -> Tensor:
    """``(R,)`` bool: the rays the NeRF renders instead (``render_chunk``'s fallback), from their baked weights
    ``(R, S)`` and sample midpoints ``mid (R, S)``: those that put at least ``nerf_fallback_share`` of the weights'
    sum farther than ``nerf_fallback_voxels`` from their median depth (light from two surfaces, a depth edge, which
    one field window around the median cannot reproduce), and those whose sum, the accumulation, stays below
    ``nerf_fallback_accumulation`` (no surface in the bake: what no training camera saw, culled)."""
    acc = weights.sum(-1)
    out = torch.zeros_like(acc, dtype=torch.bool)
    if baked.nerf_fallback_share is not None:
        half = baked.nerf_fallback_voxels * float(baked.voxel_m.max())
        far = (mid - quadrature.median_depth(weights, mid)[:, None]).abs() > half
        out |= (acc > quadrature.EPS) & ((weights * far).sum(-1) >= baked.nerf_fallback_share * acc)
    if baked.nerf_fallback_accumulation is not None:
        out |= acc < baked.nerf_fallback_accumulation
    return out


def render_baked(baked: BakedScene, rays: Rays, chunk: int = 65536, return_samples: bool = False,
                 colour: bool = True, fallback=None, may_fall_back: Tensor | None = None) -> RenderOutput:
    """Render any rays from the baked scene in chunks of ``chunk`` rays; the per-ray outputs (and, with
    ``return_samples``, the kept samples) as ``nsim.rendering.renderer.render_rays`` returns them. ``colour=False``:
    depth and accumulation only (a LiDAR; :func:`render_chunk`)."""
    from nsim.rendering.renderer import PER_RAY_FIELDS, _concat, _no_rays, _per_ray_like

    if chunk < 1:
        raise ValueError(f"render_baked: chunk must be >= 1, got {chunk}")
    n = len(rays)
    if n == 0:
        return _no_rays(rays, return_samples)
    if return_samples:
        return _concat([render_chunk(baked, rays[a : a + chunk], True, colour) for a in range(0, n, chunk)])
    out = None
    for a in range(0, n, chunk):
        o = render_chunk(baked, rays[a : a + chunk], colour=colour, fallback=fallback,
                         may_fall_back=None if may_fall_back is None else may_fall_back[a : a + chunk])
        if out is None:
            out = _per_ray_like(o, n)
        for f in PER_RAY_FIELDS:
            getattr(out, f)[a : a + len(o.rgb)] = getattr(o, f)
        del o
    return out


__all__ = ["BakedScene", "ColorDecoder", "density_at", "fallback_rays", "features_at", "locate", "march",
           "render_baked", "render_chunk", "steps"]
