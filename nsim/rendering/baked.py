"""A baked scene: the scene NeRF's density and geometry features on a sparse voxel grid, for fast sensors.

Baking (``bake``: a trained ``SceneModel`` and its ``OccupancyGrid`` in, arrays out)
    Every occupied cell of the occupancy grid baked at train time holds a *brick*: a lattice of
    ``(B + 1)^3`` points spaced ``voxel = cell / B`` (``B = ceil(cell / voxel_m)``; a brick's
    boundary points are repeated in its neighbours', so that a cell is interpolated from its own
    brick alone). At each lattice point the field's density ``sigma`` (1/m) and geometry
    features (the density MLP's ``geo_feat_dim`` outputs, the colour head's input) are stored:
    averaged over ``supersample^3`` points spread over the voxel around it (densities plainly,
    features weighted by density), or the point itself (``supersample: 1``). Bricks whose density
    stays below ``prune_density`` everywhere are dropped (free space the grid kept for safety).
    The colour head is kept as it is, with the mean appearance embedding folded into its first
    bias (``ColorDecoder``): the same ``sigmoid(MLP([SH(dir), geo, code]))`` as
    ``SceneField.color``. This is the SNeRG idea (Hedman et al. 2021: a sparse grid of density
    and features, decoded by a small MLP) with the NeRF's own decoder instead of a distilled
    one, so no training is needed. Deterministic: the same model, grid and config give the same
    arrays (on one device).

Visibility culling (``cull_weight``; ``brick_visibility``, ``cull``)
    SNeRG's rule (Hedman et al. 2021, section 4.2: voxels whose maximum volume-rendering weight over
    the training rays is small are culled): every ``cull_stride``-th pixel of each training image casts
    a ray through the baked grid itself (no field evaluation), the weights of a ray's consecutive samples
    in one brick are summed, and a brick whose largest such sum over all rays stays below
    ``cull_weight`` goes: bricks outside every view and those behind opaque surfaces. A brick is
    interpolated from its own lattice alone, so the kept ones render exactly as before; rays from novel
    poses (Spot's fisheyes looking at the ceiling or behind walls) then cross the culled space as free
    space, skipped by the coarse march.

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
    interpolated features' (configs/bake/default.yaml has the measurements of both). Rays rendered without
    colour (``colour=False``: a LiDAR) decode none: their depth is the window's (the field's density alone)
    with ``field_samples``, else the baked density's.

Surface (``surface``; ``bake_surface``, ``nsim.rendering.surface``)
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
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nsim.config import param
from nsim.errors import ConfigError, InputError
from nsim.fields.encodings import spherical_harmonics
from nsim.fields.mlp import MLP
from nsim.rendering.model import BACKGROUNDS
from nsim.rendering.surface import BakedSurface, SurfaceTexture, render_surface
from nsim.volume import quadrature
from nsim.volume.rays import Rays
from nsim.volume.samples import RaySamples, RenderOutput

log = logging.getLogger(__name__)

FORMAT = 1
BAKED_FILE = "baked.json"
ARRAY_FILES = ("brick_index.npy", "density.npy", "features.npy")
FEATURE_DTYPES = ("float16", "float32", "none")


@dataclass(frozen=True)
class BakeConfig:
    """How a scene is baked (``bake``) and marched (``render_baked``); see the module docstring."""

    voxel_m: float = param(0.04, gt=0.0, le=1.0, help="target lattice spacing: each occupancy cell is cut into "
                                                      "ceil(cell / voxel_m) voxels per side")
    supersample: int = param(1, ge=1, le=4, help="points per voxel side averaged into a lattice value (1: the point)")
    prune_density: float | None = param(0.5, ge=0.0, help="drop bricks whose baked density (1/m) stays below "
                                                          "this everywhere (null: the occupancy grid's threshold)")
    feature_dtype: str = param("float16", choices=FEATURE_DTYPES, help="storage of the geometry features (none: "
                                                                       "not stored; colour from the field alone, "
                                                                       "field_samples > 0)")
    step_voxels: float = param(0.5, gt=0.0, le=4.0, help="render step as a fraction of the voxel")
    block_cells: int = param(16, ge=1, le=4096, help="coarse steps marched at once per ray")
    stop_transmittance: float = param(1e-4, ge=0.0, lt=1.0, help="early ray termination")
    color_skip_weight: float = param(1e-3, ge=0.0, lt=1.0, help="summed weight per ray whose colour may be skipped")
    chunk_points: int = param(1 << 16, ge=256, help="field evaluations per batch while baking")
    field_color_samples: int = param(0, ge=0, le=64, help="per ray, the samples of highest weight whose colour "
                                                          "comes from the scene field itself (0: baked features only)")
    field_samples: int = param(16, ge=0, le=64, help="per camera ray, field queries in a window around its baked "
                                                    "surface, volume-rendered for its colour and depth (0: "
                                                    "field_color_samples decides)")
    field_window_voxels: float = param(2.0, gt=0.0, le=16.0, help="field_samples: the window's half width in voxels")
    nerf_fallback_share: float | None = param(None, gt=0.0, le=1.0, help="camera rays whose baked weight beyond "
                                                "nerf_fallback_voxels of their median depth reaches this share (split "
                                                "between surfaces: depth edges) are rendered by the NeRF itself (null: "
                                                "none)")
    nerf_fallback_voxels: float = param(4.0, gt=0.0, le=16.0, help="nerf_fallback_share: the half width (voxels) "
                                                                  "around a ray's median depth that counts as one surface")
    nerf_fallback_accumulation: float | None = param(None, gt=0.0, le=1.0, help="camera rays whose baked "
                                                     "accumulation stays below this (no surface in the bake: space the "
                                                     "culling dropped) are rendered by the NeRF itself (null: none)")
    cull_weight: float | None = param(None, gt=0.0, lt=1.0, help="visibility culling: drop bricks whose volume-"
                                                              "rendering weight along every training ray stays below "
                                                              "this (null: keep every brick)")
    cull_stride: int = param(4, ge=1, le=64, help="visibility culling: every cull_stride-th pixel of each training "
                                                  "image (in both directions) casts a ray")
    cull_voxel_m: float | None = param(None, gt=0.0, le=1.0, help="visibility culling: the voxels of the first bake, "
                                                                "the one culled; voxel_m bakes only the kept cells "
                                                                "(null: voxel_m, one bake)")
    surface: bool = param(False, help="also bake a surface (nsim.rendering.surface): a mesh of the baked density "
                                      "fitted to the NeRF's median depths and a hash-grid texture; cameras, depth "
                                      "and LiDAR then render from it (one Embree cast and one lookup a ray)")
    surface_level: float | None = param(10.0, gt=0.0, help="surface: the density (1/m) whose iso-surface is meshed "
                                        "(null: the field's median density at the NeRF's median depth on the "
                                        "training rays)")
    surface_min_area_m2: float = param(0.0, ge=0.0, help="surface: mesh pieces smaller than this are dropped")
    surface_stride: int = param(1, ge=1, le=64, help="surface: every k-th pixel (both ways) of each training image "
                                                     "is a ray the mesh and texture are fitted to")
    surface_fit_passes: int = param(4, ge=0, le=32, help="surface: Gauss-Newton passes fitting the mesh to the "
                                                         "NeRF's median depths (0: marching cubes as it is)")
    surface_fit_ridge: float = param(0.5, gt=0.0, help="surface: ridge weight on each vertex's step (m^2 of "
                                                       "squared depth residual per m^2 of step)")
    surface_fit_smooth: float = param(10.0, ge=0.0, help="surface: weight of each vertex's step against its "
                                                        "neighbours' mean (the mesh Laplacian's; 0: none)")
    surface_fit_gate_m: float = param(0.15, gt=0.0, help="surface: rays whose hit lies farther than this from the "
                                                         "NeRF's depth are left out of a pass (another surface)")
    surface_fit_step_m: float = param(0.03, gt=0.0, help="surface: the most a vertex moves in one pass")
    texture_from: str = param("images", choices=("images", "nerf"), help="surface texture: fitted to the training "
                                                                         "images' pixels or to the NeRF's colours "
                                                                         "of them")
    texture_levels: int = param(12, ge=1, le=24, help="surface texture: hash-grid levels")
    texture_log2_size: int = param(19, ge=8, le=24, help="surface texture: log2 of each level's rows")
    texture_max_resolution: int = param(1024, ge=16, le=65536, help="surface texture: the finest level's cells "
                                                                    "across the scene box")
    texture_width: int = param(32, ge=4, le=256, help="surface texture: the decoder's hidden width")
    texture_steps: int = param(2000, ge=1, help="surface texture: Adam steps")
    texture_batch: int = param(16384, ge=16, help="surface texture: points per step")
    texture_lr: float = param(0.01, gt=0.0, help="surface texture: the first learning rate (falls tenfold over "
                                                 "the steps)")

    def check(self) -> None:
        """The settings that depend on each other (checked when baking, not per ``--set``: their order is free)."""
        if self.feature_dtype == "none" and self.field_samples == 0 and not self.surface:
            raise ConfigError("feature_dtype: none stores no colour features; it needs field_samples > 0 (colour "
                              "from the scene field)")


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


# ---------------------------------------------------------------------------------- baking
@dataclass(frozen=True, eq=False)
class BakePlan:
    """What a bake evaluates: the bricks and their unique lattice points.

    cells: (N, 3) int64, the occupied cells in C order (brick n is cell ``cells[n]``); lattice: (U, 3) int64,
    the distinct global lattice indices of all bricks (ascending by flat index); inverse: (N, P) int64,
    each brick's lattice points as rows of ``lattice``; lo: (3,) the box's minimum corner; voxel: (3,)."""

    aabb: Tensor
    shape: tuple[int, int, int]
    bricks_per_side: int
    cells: Tensor
    lattice: Tensor
    inverse: Tensor
    voxel: Tensor

    @property
    def n_points(self) -> int:
        return int(self.lattice.shape[0])

    def positions(self, start: int, stop: int) -> Tensor:
        """World positions ``(stop - start, 3)`` of lattice points ``[start, stop)``."""
        return self.aabb[0] + self.lattice[start:stop].to(torch.float32) * self.voxel


def bricks_per_side(cell_m: Tensor, voxel_m: float) -> int:
    return max(1, int(math.ceil(float(cell_m.max()) / voxel_m - 1e-4)))  # float32 cells: 0.2 / 0.05 is 4


def plan_bake(grid, cfg: BakeConfig) -> BakePlan:
    """The bricks of ``grid``'s (an ``OccupancyGrid``) occupied cells and their lattice points."""
    aabb = grid.aabb.float()
    device = aabb.device
    shape = tuple(int(s) for s in grid.shape)
    b = bricks_per_side(grid.cell_m, cfg.voxel_m)
    cells = torch.nonzero(grid.occupied, as_tuple=False).to(torch.int64)  # (N, 3), C order
    a = torch.arange(b + 1, device=device)
    local = torch.stack(torch.meshgrid(a, a, a, indexing="ij"), -1).reshape(-1, 3)  # (P, 3)
    glob = cells[:, None, :] * b + local[None]  # (N, P, 3)
    dims = torch.tensor([s * b + 1 for s in shape], device=device)
    flat = (glob[..., 0] * dims[1] + glob[..., 1]) * dims[2] + glob[..., 2]
    uniq, inverse = torch.unique(flat.reshape(-1), sorted=True, return_inverse=True)
    lattice = torch.stack([uniq // (dims[1] * dims[2]), (uniq // dims[2]) % dims[1], uniq % dims[2]], -1)
    voxel = (aabb[1] - aabb[0]) / torch.tensor(shape, dtype=torch.float32, device=device) / b
    return BakePlan(aabb, shape, b, cells, lattice, inverse.view(len(cells), -1), voxel)


@torch.no_grad()
def evaluate_lattice(field, plan: BakePlan, cfg: BakeConfig, start: int, stop: int) -> tuple[Tensor, Tensor]:
    """Density ``(n,)`` and geometry features ``(n, G)`` (float32) of lattice points ``[start, stop)``:
    averaged over ``supersample^3`` points spread over the voxel (features weighted by density + 1e-3)."""
    s = cfg.supersample
    x0 = plan.positions(start, stop)
    if s == 1:
        offsets = torch.zeros(1, 3, device=x0.device)
    else:
        a = (torch.arange(s, device=x0.device, dtype=torch.float32) + 0.5) / s - 0.5
        offsets = torch.stack(torch.meshgrid(a, a, a, indexing="ij"), -1).reshape(-1, 3) * plan.voxel
    sig_sum = torch.zeros(len(x0), device=x0.device)
    feat_sum = None
    w_sum = torch.zeros(len(x0), device=x0.device)
    for off in offsets:
        sig, geo = field.density(x0 + off)
        sig, geo = sig.float(), geo.float()
        w = sig + 1e-3
        sig_sum += sig
        feat_sum = geo * w[:, None] if feat_sum is None else feat_sum + geo * w[:, None]
        w_sum += w
    return sig_sum / len(offsets), feat_sum / w_sum[:, None]


def assemble(plan: BakePlan, density: Tensor, features: Tensor, decoder: ColorDecoder, cfg: BakeConfig,
             background: str, background_rgb, prune_density: float, meta: dict | None = None) -> BakedScene:
    """The baked scene from every lattice point's ``density (U,)`` and ``features (U, G)``: bricks whose
    density stays below ``prune_density`` dropped, the rest numbered in C order of their cells."""
    dens = density[plan.inverse]  # (N, P)
    keep = dens.amax(-1) >= prune_density if dens.numel() else torch.zeros(0, dtype=torch.bool, device=dens.device)
    cells = plan.cells[keep]
    index = torch.full(plan.shape, -1, dtype=torch.int32, device=dens.device)
    if len(cells):
        index[cells[:, 0], cells[:, 1], cells[:, 2]] = torch.arange(len(cells), dtype=torch.int32, device=dens.device)
    if cfg.feature_dtype == "none":  # colour from the field alone (field_samples): no features stored
        feats = torch.zeros(int(keep.sum()), plan.inverse.shape[1], 0, dtype=torch.float16, device=dens.device)
    else:
        feats = features[plan.inverse[keep]].to(getattr(torch, cfg.feature_dtype))
    stats = {"occupied_cells": int(len(plan.cells)), "pruned_bricks": int((~keep).sum()),
             "prune_density_per_m": float(prune_density), "lattice_points_evaluated": plan.n_points,
             "supersample": cfg.supersample, **(meta or {})}
    return BakedScene(aabb=plan.aabb.clone(), brick_index=index, density=dens[keep].contiguous(),
                      features=feats.contiguous(), bricks_per_side=plan.bricks_per_side, decoder=decoder,
                      step_voxels=cfg.step_voxels, block_cells=cfg.block_cells,
                      stop_transmittance=cfg.stop_transmittance, color_skip_weight=cfg.color_skip_weight,
                      background=background, background_rgb=torch.as_tensor(background_rgb, dtype=torch.float32),
                      meta=stats, field_color_samples=cfg.field_color_samples, field_samples=cfg.field_samples,
                      field_window_voxels=cfg.field_window_voxels, nerf_fallback_share=cfg.nerf_fallback_share,
                      nerf_fallback_voxels=cfg.nerf_fallback_voxels,
                      nerf_fallback_accumulation=cfg.nerf_fallback_accumulation)


def brick_visibility(baked: BakedScene, rays: Rays, chunk: int = 65536) -> Tensor:
    """Per brick ``(N,)`` float32, the largest volume-rendering weight it takes along any of ``rays``: a ray's
    weights summed over each run of its samples in one brick (so that the figure does not depend on the step),
    maximised over the rays. 0 for a brick no ray reaches (outside every view, or behind opaque surfaces)."""
    seen = torch.zeros(baked.n_bricks, dtype=torch.float32, device=baked.device)
    for a in range(0, len(rays), chunk):
        ray, t0, t1, sigma, brick, _ = _march(baked, rays[a : a + chunk])
        if not ray.numel():
            continue
        # packed volume rendering: w = T * (1 - exp(-sigma dt)), T the ray's transmittance before the sample
        tau = (sigma * (t1 - t0)).double()
        new_ray = torch.ones_like(ray, dtype=torch.bool)
        new_ray[1:] = ray[1:] != ray[:-1]
        incl = torch.cumsum(tau, 0)
        excl = incl - tau
        first = torch.cummax(torch.where(new_ray, torch.arange(len(ray), device=ray.device), 0), 0)[0]
        before = excl - excl[first]
        w = (torch.exp(-before) * -torch.expm1(-tau)).float()
        run = new_ray.clone()
        run[1:] |= brick[1:] != brick[:-1]
        run_id = torch.cumsum(run.to(torch.int64), 0) - 1
        run_w = torch.zeros(int(run_id[-1]) + 1, device=w.device).index_add_(0, run_id, w)
        seen.scatter_reduce_(0, brick[run], run_w, reduce="amax")
    return seen


def cull(baked: BakedScene, visibility: Tensor, min_weight: float) -> BakedScene:
    """``baked`` without the bricks whose ``visibility (N,)`` (:func:`brick_visibility`) is below ``min_weight``,
    the rest renumbered in their order (a brick is interpolated from its own lattice, so the kept ones render as
    before); ``meta`` counts the culled bricks."""
    keep = visibility >= min_weight
    old = baked.brick_index.view(-1)
    renum = torch.cumsum(keep.to(torch.int32), 0, dtype=torch.int32) - 1
    occupied = old >= 0
    new = torch.full_like(old, -1)
    new[occupied] = torch.where(keep[old[occupied].long()], renum[old[occupied].long()], -1)
    meta = {**baked.meta, "culled_bricks": int((~keep).sum()), "cull_weight": float(min_weight)}
    return dataclasses.replace(baked, brick_index=new.view(baked.brick_index.shape),
                               density=baked.density[keep].contiguous(), features=baked.features[keep].contiguous(),
                               meta=meta)


def training_rays(model, frames, stride: int, images: list | None = None) -> Rays | tuple[Rays, Tensor]:
    """The rays of every ``stride``-th pixel (both directions) of ``frames`` (``(camera, cam_to_world)`` pairs, the
    images the scene was trained on), clipped as the scene model clips its own rays. With ``images`` (one ``(H, W,
    3)`` uint8 image a frame, at its camera's size): also their colours ``(R, 3)`` in [0, 1]."""
    from nsim.rendering.renderer import camera_rays

    parts, colours = [], []
    for k, (camera, c2w) in enumerate(frames):
        rays, _, valid = camera_rays(model, camera, c2w)
        pick = torch.zeros(camera.height, camera.width, dtype=torch.bool, device=valid.device)
        pick[::stride, ::stride] = True
        idx = torch.nonzero(pick.view(-1) & valid.bool(), as_tuple=True)[0]
        parts.append(rays[idx])
        if images is not None:
            img = np.asarray(images[k])
            if img.shape[:2] != (camera.height, camera.width):
                raise InputError(f"bake: training image {k} is {img.shape[1]}x{img.shape[0]}, its camera "
                                 f"{camera.width}x{camera.height}")
            flat = torch.as_tensor(img.reshape(-1, img.shape[-1])[:, :3])
            colours.append(flat[idx.cpu()].float().div(255.0))
    if not parts:
        raise InputError("bake: visibility culling and the surface need the training cameras, and there are none")
    rays = Rays(*(torch.cat([getattr(r, f) for r in parts]) for f in ("origins", "dirs", "near", "far")))
    return rays if images is None else (rays, torch.cat(colours).to(rays.origins.device))


def decoder_of(model) -> ColorDecoder:
    """The colour head of a ``SceneModel`` with its mean appearance embedding (over the training images)."""
    codes = model.field.appearance_codes(None, 1, "mean", model.train_mask)
    return ColorDecoder.from_field(model.field, None if codes is None else codes[0])


def finish_bake(model, grid, plan: BakePlan, density: Tensor, features: Tensor, cfg: BakeConfig) -> BakedScene:
    """:func:`assemble` for a ``SceneModel`` baked over its ``OccupancyGrid``: pruned at ``cfg.prune_density``
    (default: the grid's own threshold), its colour head and background (no culling: :func:`bake_passes`)."""
    prune = grid.density_threshold if cfg.prune_density is None else cfg.prune_density
    return assemble(plan, density, features, decoder_of(model).to(density.device), cfg, model.sampler_cfg.background,
                    model.sampler_cfg.background_rgb, prune)


def bake_passes(model, grid, cfg: BakeConfig, frames, evaluate) -> BakedScene:
    """The whole bake, its lattices evaluated by ``evaluate(plan, cfg, name) -> (density (U,), features (U, G))``
    (``name``: ``"cull"`` or ``"bake"``, so that a caller can keep the two apart).

    Without ``cull_weight``: one bake at ``voxel_m``. With it: a first bake at ``cull_voxel_m`` (default
    ``voxel_m``), culled by the training cameras ``frames`` (``(camera, cam_to_world)`` pairs:
    :func:`training_rays`, :func:`brick_visibility`, :func:`cull`); when ``voxel_m`` cuts the cells finer, a
    second bake at ``voxel_m`` over the kept cells alone."""
    cfg.check()
    if cfg.cull_weight is None:
        plan = plan_bake(grid, cfg)
        return finish_bake(model, grid, plan, *evaluate(plan, cfg, "bake"), cfg)
    first_cfg = cfg if cfg.cull_voxel_m is None else dataclasses.replace(cfg, voxel_m=cfg.cull_voxel_m)
    plan = plan_bake(grid, first_cfg)
    first = finish_bake(model, grid, plan, *evaluate(plan, first_cfg, "cull"), first_cfg)
    culled = cull(first, brick_visibility(first, training_rays(model, frames or [], cfg.cull_stride)), cfg.cull_weight)
    if plan.bricks_per_side == bricks_per_side(grid.cell_m, cfg.voxel_m):
        return culled
    kept = dataclasses.replace(grid, occupied=culled.brick_index >= 0)
    plan = plan_bake(kept, cfg)
    fine = finish_bake(model, kept, plan, *evaluate(plan, cfg, "bake"), cfg)
    meta = {**fine.meta, "occupied_cells": culled.meta["occupied_cells"],
            "pruned_bricks": culled.meta["pruned_bricks"] + fine.meta["pruned_bricks"],
            "culled_bricks": culled.meta["culled_bricks"], "cull_weight": cfg.cull_weight,
            "cull_voxel_m": float(first_cfg.voxel_m),
            "lattice_points_evaluated": culled.meta["lattice_points_evaluated"] + plan.n_points}
    return dataclasses.replace(fine, meta=meta)


def nerf_targets(model, grid, rays: Rays, chunk: int = 8192) -> tuple[Tensor, Tensor, Tensor]:
    """The NeRF's median depth ``(R,)``, accumulation ``(R,)`` and colour ``(R, 3)`` of ``rays``: what a surface is
    fitted to (``method: proposal``, the renderer ``nsim render`` uses)."""
    from nsim.rendering.renderer import MarchConfig, render_rays

    with torch.no_grad():
        out = render_rays(model, rays, "proposal", grid, MarchConfig(), chunk)
    return out.depth_median, out.accumulation, out.rgb.clamp(0.0, 1.0)


def bake_surface(model, baked: BakedScene, cfg: BakeConfig, frames, targets, seed: int = 0,
                 images: list | None = None) -> BakedScene:
    """``baked`` with its surface (``nsim.rendering.surface``): marching cubes of its density, fitted to the NeRF's
    median depths on the training rays of ``frames`` (every ``surface_stride``-th pixel), textured with the
    training ``images``' colours there (one ``(H, W, 3)`` uint8 image a frame; None: the NeRF's colours).
    targets: ``rays -> (depth_median, accumulation, rgb)`` (:func:`nerf_targets`, or a caller's that keeps parts
    for resuming). Deterministic for one device and ``seed``."""
    from nsim.rendering.surface import MeshCaster, fit_mesh, fit_texture, mesh_of_bricks

    t0 = time.perf_counter()
    if images is not None:
        rays, pixels = training_rays(model, frames or [], cfg.surface_stride, images)
        depth, acc, _ = targets(rays)
        rgb = pixels
    else:
        rays = training_rays(model, frames or [], cfg.surface_stride)
        depth, acc, rgb = targets(rays)
    keep = torch.nonzero(acc > 0.5, as_tuple=True)[0]
    if not len(keep):
        raise InputError(f"bake: none of the {len(rays)} training rays ends on a surface in the NeRF (accumulation "
                         "0.5); set surface=false")
    near = rays.near[keep].cpu().numpy()
    d = rays.dirs[keep].cpu().numpy()
    o = rays.origins[keep].cpu().numpy() + d * near[:, None]
    t_max = np.maximum(rays.far[keep].cpu().numpy() - near, 0.0)
    target = depth[keep].cpu().numpy() - near
    t_nerf = time.perf_counter()
    level = cfg.surface_level
    if level is None:  # the field's density where the NeRF puts the surface (a seeded draw of those points)
        pick = torch.randperm(len(keep), generator=torch.Generator().manual_seed(seed))[:1 << 16].numpy()
        x = torch.as_tensor(o[pick] + d[pick] * target[pick, None], device=baked.device)
        with torch.no_grad():
            level = float(model.field.density(x)[0].float().median())
    v, f = mesh_of_bricks(baked.brick_index.cpu().numpy(), baked.density.cpu().numpy(), baked.bricks_per_side,
                          baked.aabb[0].cpu().numpy(), baked.voxel_m.cpu().numpy(), level, cfg.surface_min_area_m2)
    if not len(f):
        high = float(baked.density.max()) if baked.density.numel() else 0.0
        raise InputError(f"bake: no surface at density {level:.4g}/m (the baked density reaches {high:.3g}/m); "
                         "set surface_level below that")
    t_mesh = time.perf_counter()
    v, fit = fit_mesh(v, f, o, d, t_max, target, cfg.surface_fit_passes, cfg.surface_fit_ridge,
                      cfg.surface_fit_gate_m, cfg.surface_fit_step_m, cfg.surface_fit_smooth)
    t_fit = time.perf_counter()
    hit = MeshCaster(v, f).cast(o, d, t_max)
    on = np.nonzero(hit["face"] >= 0)[0]
    device = baked.device
    points = torch.as_tensor(o[on] + d[on] * hit["t"][on, None]).to(device)
    colours = rgb[keep][torch.as_tensor(on, device=rgb.device)].to(device)
    gen = torch.Generator().manual_seed(seed)
    texture = SurfaceTexture(baked.aabb.cpu(), cfg.texture_levels, cfg.texture_log2_size, cfg.texture_max_resolution,
                             cfg.texture_width, generator=gen).to(device)
    every = max(1, cfg.texture_steps // 10)
    psnr_fit = fit_texture(texture, points, colours, cfg.texture_steps, cfg.texture_batch, cfg.texture_lr, gen,
                           on_step=lambda s: s % every == every - 1 and log.info(
                               "bake: surface texture step %d/%d", s + 1, cfg.texture_steps))
    t_tex = time.perf_counter()
    rel = np.abs(hit["t"][on] - target[on]) / np.maximum(target[on], 1e-6)
    stats = {"level_per_m": round(level, 6), "texture_from": "nerf" if images is None else "images", "training_rays": len(rays), "rays_fitted": int(len(keep)),
             "rays_on_surface": int(len(on)), "fit": fit["passes"],
             "depth_rel_error_median": float(np.median(rel)) if len(rel) else None,
             "texture_psnr_fit": round(psnr_fit, 3)}
    log.info("bake: surface of %d faces; training depth error median %.3f %%; texture %.2f dB on its points; "
             "seconds: NeRF %.1f, mesh %.1f, fit %.1f, texture %.1f", len(f),
             100 * (stats["depth_rel_error_median"] or 0.0), psnr_fit, t_nerf - t0, t_mesh - t_nerf, t_fit - t_mesh,
             t_tex - t_fit)
    return dataclasses.replace(baked, surface=BakedSurface(v, f, texture, stats))


@torch.no_grad()
def bake(model, grid, cfg: BakeConfig = BakeConfig(), frames=None) -> BakedScene:
    """Bake a ``SceneModel`` over its ``OccupancyGrid`` (same device) into a :class:`BakedScene`; ``frames``: the
    training cameras, ``(camera, cam_to_world)`` pairs, for ``cfg.cull_weight`` (:func:`bake_passes`) and
    ``cfg.surface`` (:func:`bake_surface`)."""
    model.eval()

    def evaluate(plan: BakePlan, c: BakeConfig, _name: str) -> tuple[Tensor, Tensor]:
        sig, feats = [], []
        for a in range(0, plan.n_points, c.chunk_points):
            s, f = evaluate_lattice(model.field, plan, c, a, min(plan.n_points, a + c.chunk_points))
            sig.append(s)
            feats.append(f)
        device = grid.aabb.device
        density = torch.cat(sig) if sig else torch.zeros(0, device=device)
        return density, torch.cat(feats) if feats else torch.zeros(0, model.field_cfg.geo_feat_dim, device=device)

    baked = bake_passes(model, grid, cfg, frames, evaluate)
    if cfg.surface:
        baked = bake_surface(model, baked, cfg, frames, lambda r: nerf_targets(model, grid, r))
    return baked


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
def _march(baked: BakedScene, rays: Rays) -> tuple[Tensor, ...]:
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
            tau_s = (sig * (t1 - t0)).double()
            ray_loc = r[rr]  # index into alive
            cnt = torch.bincount(ray_loc, minlength=len(alive))
            first = torch.cumsum(cnt, 0) - cnt
            excl = torch.cumsum(tau_s, 0) - tau_s
            before = tau[alive][ray_loc] + excl - excl[first[ray_loc]]
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
    ray, t0, t1, sigma, brick, local = _march(baked, rays)
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


__all__ = ["BakeConfig", "BakePlan", "BakedScene", "ColorDecoder", "assemble", "bake", "bake_passes",
           "bake_surface", "brick_visibility", "cull", "decoder_of", "density_at", "evaluate_lattice", "features_at", "finish_bake",
           "fallback_rays", "locate", "nerf_targets", "plan_bake", "render_baked", "render_chunk", "training_rays"]
