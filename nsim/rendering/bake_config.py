"""How a scene is baked and marched (``BakeConfig``), apart from the baking (``nsim.rendering.bake_bricks``): the
bake and render stages hold these settings, and reading a config must not load torch."""

from __future__ import annotations

from dataclasses import dataclass

from nsim.config import param
from nsim.errors import ConfigError

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
