"""What an export extracts (``PointsConfig``, ``MeshConfig``), apart from the extraction (``nsim.export.extract``):
the export stage holds these settings, and reading a config must not load torch."""

from __future__ import annotations

from dataclasses import dataclass

from nsim.config import param


@dataclass(frozen=True)
class PointsConfig:
    """The point cloud: rays through ``rays_per_view`` pixels (drawn without replacement, seeded)
    of every ``view_stride``-th training view; a ray gives a point where its opacity reaches
    ``min_accumulation``; at most ``max_points`` points are kept (a seeded draw)."""

    view_stride: int = param(1, ge=1, help="use every k-th training view")
    rays_per_view: int = param(4096, ge=1, help="pixels per view (all of them if the image has fewer)")
    depth_estimate: str = param("median", choices=("median", "expected"),
                                help="where a ray ends: the median of its weights or their normalised mean")
    min_accumulation: float = param(0.9, gt=0.0, le=1.0, help="opacity a ray needs to give a point")
    max_points: int = param(1_000_000, ge=1, help="cap on the points written")
    orient_normals: bool = param(True, help="flip normals that face away from the camera that saw the point")
    chunk_rays: int = param(8192, ge=64, help="rays rendered at once")


@dataclass(frozen=True)
class MeshConfig:
    """The mesh: marching cubes of the density on a lattice of ``cell_m`` spacing."""

    cell_m: float = param(0.02, gt=0.0, help="lattice spacing (grows, with a warning, past max_nodes)")
    max_nodes: int = param(64_000_000, ge=1000, help="most density samples on the lattice")
    region: str = param("seen", choices=("seen", "occupied", "box"),
                        help="seen: the bounding box of the surfaces the training rays ended on (+ region_margin_m); "
                             "occupied: that of the scene's occupancy grid; box: the whole scene box")
    region_margin_m: float = param(0.3, ge=0.0, help="growth of the seen region")
    density_level: float | None = param(None, gt=0.0, help="iso-level of the surface, density in 1/m; null: the "
                                        "median density at the point cloud's points (where the training rays' "
                                        "weights reach half their total)")
    skip_free_cells: bool = param(True, help="density 0 in the occupancy grid's free cells (not evaluated)")
    crop_to_seen: bool = param(True, help="keep only faces in cells some training ray passed through "
                                          "(up to seen_margin_m beyond its depth)")
    seen_cell_m: float = param(0.1, gt=0.0, help="cell of the seen-space grid")
    seen_margin_m: float = param(0.1, ge=0.0, help="how far beyond its surface a ray counts as looking")
    min_component_area_m2: float = param(0.05, ge=0.0, help="drop connected pieces smaller than this")
    color_probe_m: float = param(0.05, ge=0.0, help="vertex colour: half-length of the probe ray along the normal "
                                                     "(0: the field's colour at the vertex)")
    color_samples: int = param(16, ge=1, help="samples on each probe ray")
    chunk_points: int = param(65536, ge=256, help="density queries at once")
