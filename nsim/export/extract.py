"""Point cloud and mesh of a trained scene model (``nsim.rendering.SceneModel``), as arrays.

``cast_views`` renders rays of the training cameras (a seeded subset of each view's pixels)
with the sampler the model trained with; ``point_cloud`` turns the rays that hit a surface into
coloured points with density normals; ``mesh_from_density`` runs marching cubes over the
density and colours the vertices. All positions are world metres, z up, as the model has them.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nsim.export import points as pts
from nsim.export.export_config import MeshConfig, PointsConfig
from nsim.progress import progress_bar
from nsim.volume import density_mesh as meshing

log = logging.getLogger(__name__)


@dataclass
class ViewRays:
    """Rendered rays of the training views (R rays). origins, dirs: (R, 3) world, unit dirs;
    near, far, depth_m, accumulation: (R,); rgb, background: (R, 3) (rgb composited over background)."""

    origins: Tensor
    dirs: Tensor
    near: Tensor
    far: Tensor
    depth_m: Tensor
    accumulation: Tensor
    rgb: Tensor
    background: Tensor


@dataclass
class Cloud:
    """xyz, normals: (N, 3) float32; rgb: (N, 3) uint8; stats: counts for the report."""

    xyz: np.ndarray
    rgb: np.ndarray
    normals: np.ndarray
    stats: dict


@dataclass
class Mesh:
    """vertices, normals: (V, 3); faces: (F, 3) int64; rgb: (V, 3) uint8; stats: for the report."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    rgb: np.ndarray
    stats: dict


SURFACE_ACCUMULATION = 0.5  # a ray with this opacity ends on a surface (seen region, seen space)


class NoSurface(ValueError):
    """Nothing to export; the message says which setting to change."""


# ---------------------------------------------------------------------------------- the rays
@torch.no_grad()
def cast_views(model, views: list[tuple[int, object, np.ndarray]], cfg: PointsConfig, rng: np.random.Generator,
               progress: bool = False) -> ViewRays:
    """Render ``cfg.rays_per_view`` seeded pixels of each view ``(frame index, camera, cam_to_world (4, 4))``."""
    from nsim.rendering.renderer import camera_rays, render_rays

    parts: list[ViewRays] = []
    with progress_bar(len(views), "export: rendering views", progress) as bar:
        for _index, camera, c2w in views:
            rays, _, valid = camera_rays(model, camera, c2w)
            ok = np.flatnonzero(valid.cpu().numpy())
            pick = ok if len(ok) <= cfg.rays_per_view else np.sort(rng.choice(ok, cfg.rays_per_view, replace=False))
            sub = rays[torch.as_tensor(pick, device=rays.origins.device)]
            out = render_rays(model, sub, "proposal", chunk=cfg.chunk_rays)
            depth = out.depth_median if cfg.depth_estimate == "median" else out.depth
            parts.append(ViewRays(sub.origins, sub.dirs, sub.near, sub.far, depth, out.accumulation, out.rgb,
                                  out.background.expand_as(out.rgb)))
            bar.advance()
    return ViewRays(*(torch.cat([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(ViewRays)))


def density_fn(model):
    return lambda x: model.field.density(x)[0]


def radiance_fn(model):
    """``(x, dirs) -> (sigma, rgb)`` with the training images' mean appearance."""

    def fn(x: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        sigma, geo = model.field.density(x)
        codes = model.field.appearance_codes(None, x.shape[0], "mean", model.train_mask)
        return sigma, model.field.color(geo, d, codes)

    return fn


# ---------------------------------------------------------------------------------- the point cloud
def point_cloud(model, rays: ViewRays, cfg: PointsConfig, rng: np.random.Generator, chunk: int = 1 << 15) -> Cloud:
    """Coloured points with density normals where the rays hit (see ``nsim.export.points``)."""
    hit, xyz = pts.ray_hits(rays.origins, rays.dirs, rays.depth_m, rays.accumulation, rays.far, cfg.min_accumulation)
    idx = torch.nonzero(hit, as_tuple=True)[0]
    if idx.numel() == 0:
        best = float(rays.accumulation.max()) if len(rays.accumulation) else 0.0
        raise NoSurface(f"points: no ray reaches opacity {cfg.min_accumulation:g} (the highest is {best:.3f}); "
                        f"lower points.min_accumulation (e.g. --set points.min_accumulation={max(0.05, best * 0.9):.2f})")
    keep = torch.as_tensor(pts.cap_indices(idx.numel(), cfg.max_points, rng), device=idx.device)
    idx = idx[keep]
    x = xyz[idx]
    rgb = pts.surface_rgb(rays.rgb[idx], rays.accumulation[idx], rays.background[idx])
    normals, ok = pts.density_normals(density_fn(model), x, chunk)
    flipped = torch.zeros_like(ok)
    if cfg.orient_normals:
        normals, flipped = pts.orient_towards_viewer(normals, rays.dirs[idx])
        flipped &= ok
    from nsim.io.images import to_uint8

    stats = {"rays": len(rays.depth_m), "rays_hit": int(hit.sum()), "points": int(idx.numel()),
             "normals_undefined": int((~ok).sum()), "normals_flipped": int(flipped.sum())}
    return Cloud(x.cpu().numpy().astype(np.float32), to_uint8(rgb.cpu().numpy()),
                 normals.cpu().numpy().astype(np.float32), stats)


# ---------------------------------------------------------------------------------- the mesh
def ray_ends(rays: ViewRays, margin_m: float) -> tuple[Tensor, Tensor]:
    """``(hit, t_end)`` ``(R,)``: a ray whose opacity reaches ``SURFACE_ACCUMULATION`` ends on a surface at
    its depth (``t_end`` = depth + ``margin_m``, within far); any other ray looked through to its far end."""
    hit = (rays.accumulation >= SURFACE_ACCUMULATION) & torch.isfinite(rays.depth_m)
    t_end = torch.where(hit, torch.minimum(rays.depth_m + margin_m, rays.far), rays.far)
    return hit, t_end


def mesh_region(model, grid, rays: ViewRays | None, cfg: MeshConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` world metres, inside the scene box: the box itself (``box``); the bounding box of the
    occupancy grid's occupied cells grown by a cell (``occupied``); the bounding box of the surface points
    the rays ended on grown by ``region_margin_m`` (``seen``)."""
    aabb = model.aabb.cpu().numpy().astype(np.float64)
    if cfg.region == "box":
        return aabb[0], aabb[1]
    if cfg.region == "occupied":
        occ = grid.occupied.cpu().numpy()
        if not occ.any():
            raise NoSurface("mesh: the scene's occupancy grid has no occupied cell (an empty scene?); "
                            "try --set mesh.region=box --set mesh.skip_free_cells=false")
        cell = grid.cell_m.cpu().numpy().astype(np.float64)
        ijk = np.argwhere(occ)
        lo, hi = aabb[0] + (ijk.min(0) - 1) * cell, aabb[0] + (ijk.max(0) + 2) * cell
    else:
        hit, _ = ray_ends(rays, 0.0)
        if not bool(hit.any()):
            raise NoSurface("mesh: no training ray ends on a surface (opacity >= "
                            f"{SURFACE_ACCUMULATION}); try --set mesh.region=box")
        ends = (rays.origins + rays.dirs * rays.depth_m[:, None])[hit].cpu().numpy().astype(np.float64)
        lo, hi = ends.min(0) - cfg.region_margin_m, ends.max(0) + cfg.region_margin_m
    lo, hi = np.maximum(lo, aabb[0]), np.minimum(hi, aabb[1])
    if not (hi > lo).all():
        raise NoSurface(f"mesh: the {cfg.region} region is empty inside the scene box; try --set mesh.region=box")
    return lo, hi


@torch.no_grad()
def surface_level(model, xyz: np.ndarray, chunk: int = 1 << 16) -> float:
    """The median density (1/m) at surface points ``xyz (N, 3)``: the automatic ``density_level``."""
    x = torch.as_tensor(np.asarray(xyz, dtype=np.float32), device=model.aabb.device)
    sigma = torch.cat([model.field.density(x[a : a + chunk])[0].float() for a in range(0, len(x), chunk)])
    return float(sigma.median())


def mesh_from_density(model, grid, rays: ViewRays, cfg: MeshConfig, level: float, device,
                      progress: bool = False) -> Mesh:
    """Marching cubes of the model's density at ``level`` (1/m; see ``nsim.volume.density_mesh``), cropped, cleaned, coloured.

    grid: the scene's ``OccupancyGrid`` (or None); rays: the cast training views (the ``seen``
    region and ``crop_to_seen``). With ``crop_to_seen`` the density is only evaluated near seen cells.
    """
    from nsim.io.images import to_uint8

    lo, hi = mesh_region(model, grid, rays, cfg)
    lattice, grew = meshing.lattice_over(lo, hi, cfg.cell_m, cfg.max_nodes)
    if grew:
        log.warning("mesh: %.4f m cells would need more than mesh.max_nodes=%d samples; using %.4f m",
                    cfg.cell_m, cfg.max_nodes, lattice.cell_m)
    need = None
    if grid is not None and cfg.skip_free_cells:
        need = meshing.nodes_in_cells(grid.occupied.cpu().numpy(), grid.aabb[0].cpu().numpy(),
                                      grid.cell_m.cpu().numpy(), lattice, outside=True)
    seen = None
    if cfg.crop_to_seen:
        _, t_end = ray_ends(rays, cfg.seen_margin_m)
        seen_shape = tuple(int(np.ceil(s / cfg.seen_cell_m)) + 1 for s in hi - lo)
        seen = meshing.seen_cells(rays.origins, rays.dirs, rays.near, t_end, lo, cfg.seen_cell_m, seen_shape)
        # faces in seen cells only use nodes within a lattice cell of them: the others need no density
        ring = int(np.ceil(lattice.cell_m / cfg.seen_cell_m))
        near_seen = meshing.nodes_in_cells(meshing.dilate(seen, ring).cpu().numpy(), lo, cfg.seen_cell_m, lattice)
        need = near_seen if need is None else need & near_seen
    with progress_bar(lattice.shape[0], "export: density lattice", progress) as bar:
        vol = meshing.sample_lattice(density_fn(model), lattice, need, cfg.chunk_points, device,
                                     on_slab=lambda _i: bar.advance())
    if need is not None:
        log.info("mesh: density at %d of %d lattice nodes", int(need.sum()), lattice.n_nodes)
    try:
        verts, faces = meshing.marching_cubes(vol, level, lattice)
    except meshing.EmptySurface as e:
        auto = "or --set mesh.density_level=null (the median density at the point cloud's points)"
        if e.high <= level:
            hint = f"lower mesh.density_level below that maximum {auto}"
        else:
            hint = f"raise mesh.density_level above {e.low:.3g} 1/m {auto}"
        raise NoSurface(f"mesh: empty at density level {level:.4g} 1/m (the density on the "
                        f"lattice ranges over [{e.low:.3g}, {e.high:.3g}] 1/m); {hint}") from None
    stats = {"density_level_per_m": level, "cell_m": lattice.cell_m, "lattice_shape": list(lattice.shape),
             "region": cfg.region, "region_lo_m": list(lattice.lo_m), "region_hi_m": lattice.hi_m.tolist(),
             "density_max_per_m": float(vol.max()), "faces_marching_cubes": int(len(faces))}
    if seen is not None:
        keep = meshing.faces_in_cells(verts, faces, seen.cpu().numpy(), lo, cfg.seen_cell_m)
        verts, faces = meshing.keep_faces(verts, faces, keep)
        stats["faces_unseen_dropped"] = int((~keep).sum())
    verts, faces, dropped = meshing.drop_small_components(verts, faces, cfg.min_component_area_m2)
    stats["components_dropped"] = dropped
    if len(faces) == 0:
        raise NoSurface(f"mesh: nothing left after cropping to seen space and dropping pieces under "
                        f"{cfg.min_component_area_m2:g} m2; lower mesh.min_component_area_m2, set "
                        "mesh.crop_to_seen=false, or lower mesh.density_level")
    normals = meshing.vertex_normals(verts, faces)
    with progress_bar(len(verts), "export: vertex colours", progress) as bar:
        rgb = meshing.probe_colours(radiance_fn(model), torch.as_tensor(verts, dtype=torch.float32, device=device),
                                    torch.as_tensor(normals, dtype=torch.float32, device=device), cfg.color_probe_m,
                                    cfg.color_samples, on_chunk=bar.advance)
    stats.update({"vertices": int(len(verts)), "faces": int(len(faces)),
                  "area_m2": float(meshing.face_areas(verts, faces).sum())})
    return Mesh(verts, faces, normals, to_uint8(rgb.cpu().numpy()), stats)
