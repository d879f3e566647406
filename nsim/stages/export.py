"""``nsim export``: a scene checkpoint's surfaces as files other tools open, as an ``export`` artifact.

Input: a ``scene-checkpoint`` (``nsim train-scene``) and the poses artifact it was trained on
(its training cameras). Everything is in the scene's world frame as trained: metres, right-handed,
z up (``nsim.geometry.conventions``), not re-centred, not rescaled; a point at ``(x, y, z)`` in
these files is at ``(x, y, z)`` in the simulator. Each file says so in its own metadata.

Artifact layout::

    points.ply     point cloud, binary little-endian PLY: x y z nx ny nz (float32) red green blue
                   (uchar); header comments state frame, units and source. One point per
                   training-camera ray that hit a surface (opacity >= points.min_accumulation):
                   at the ray's median (or expected) depth, its rendered colour, the normal
                   -grad(density) / |grad(density)| (autograd), facing the camera that saw it
    mesh.ply       the mesh, binary little-endian PLY: the vertex properties above and a face
                   element (vertex_indices: uchar count, int32 indices, counter-clockwise seen
                   from the free side, where the normals point); header comments as above
    mesh.glb       the same mesh as binary glTF 2.0: POSITION, NORMAL, COLOR_0 (RGBA uint8);
                   frame and units in asset.extras, the scene's and the mesh's extras (glTF
                   viewers assume y up: the z-up world shows lying on its back)
    preview.png    point cloud from above, mesh from above and in perspective, axes in metres
    export.json    frame, units, inputs, every file, the counts and settings behind them

The mesh is marching cubes (scikit-image) of the density at ``mesh.density_level`` (1/m; by default the
median density at the point cloud's points, where the training rays' weights reach half) on a
lattice of ``mesh.cell_m`` over the occupancy grid's occupied region (or the scene box), kept where
training rays looked (``mesh.crop_to_seen``), without pieces under ``mesh.min_component_area_m2``;
vertex colours are short probe rays looking into the surface along its normal.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from typing import Any

import numpy as np

from nsim.config import param
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.export.export_config import MeshConfig, PointsConfig
from nsim.stages.runner import SceneInputs, cached, device_kind, rerun, resolve_scene

STAGE = "export"
VERSION = 1
log = logging.getLogger(__name__)

FRAME = "world frame of the scene checkpoint as trained: right-handed, z up, metres; not re-centred or rescaled"


@dataclasses.dataclass(frozen=True)
class Config:
    points: PointsConfig = PointsConfig()
    mesh: MeshConfig = MeshConfig()
    preview_max_points: int = param(20000, ge=100, help="points / faces drawn in preview.png")


Inputs = SceneInputs


@dataclasses.dataclass(frozen=True)
class Outputs:
    export: str
    cache_hit: bool = False


# libraries whose version can change the files' bytes (the workspace's fingerprint covers torch and numpy)
LIBRARIES = ("scikit-image", "scipy", "trimesh", "plyfile", "matplotlib")


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    from importlib import metadata

    versions = {name: metadata.version(name) for name in LIBRARIES}
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed,
                                extra={"device": device_kind(ctx.device), "libraries": versions})


def training_views(ctx: RunContext, scene_id: str, view_stride: int) -> tuple[str, list[tuple[int, Any, np.ndarray]]]:
    """The poses artifact the scene trained on and its training views ``(frame, camera, cam_to_world)``."""
    from nsim.io.transforms_json import read_transforms

    store = ctx.store
    art = store.get(scene_id)
    meta = json.loads(art.file("scene.json").read_text())
    poses_id = art.manifest.get("inputs", {}).get("poses")
    if poses_id is None or not (store.root / "objects" / poses_id[:2] / poses_id).is_dir():
        raise InputError(f"scene {scene_id[:12]}: the poses artifact it was trained on ({str(poses_id)[:12]}) is not in "
                         f"the workspace {store.root}; export needs its cameras")
    frames = read_transforms(store.get(poses_id).file("transforms.json")).frames
    ids = meta.get("train_images")
    if not isinstance(ids, list) or not ids or not all(isinstance(i, int) and 0 <= i < len(frames) for i in ids):
        raise InputError(f"scene {scene_id[:12]}: scene.json: train_images: expected frame indices of "
                         f"poses {poses_id[:12]} ({len(frames)} frames)")
    names = meta.get("images")
    if names is not None and names != [f.file_path for f in frames]:
        raise InputError(f"scene {scene_id[:12]}: scene.json: images differ from poses {poses_id[:12]}'s frames")
    return poses_id, [(i, frames[i].camera, frames[i].cam_to_world) for i in ids[::view_stride]]


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    store = ctx.store
    inputs = Inputs(scene=resolve_scene(inputs.scene, ctx, STAGE, files=("scene.json", "occupancy_grid.npy")))
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(export=hit, cache_hit=True)
    # the inputs checked first: a bad argument fails without loading torch
    from nsim.export.extract import NoSurface, cast_views, mesh_from_density, point_cloud, surface_level
    from nsim.rendering import OccupancyGrid, load_model

    art = store.get(inputs.scene)
    poses_id, views = training_views(ctx, inputs.scene, cfg.points.view_stride)
    grid = OccupancyGrid.load(art.file("occupancy_grid.npy"), ctx.device)
    if cfg.mesh.region == "occupied" and not bool(grid.occupied.any()):  # (mesh_region's refusal, before any work)
        raise InputError(f"export {inputs.scene[:12]}: mesh: the scene's occupancy grid has no occupied cell (an "
                         "empty scene?); try --set mesh.region=box --set mesh.skip_free_cells=false")
    model = load_model(art.path, ctx.device)
    log.info("export: %d training views, %d rays each", len(views), cfg.points.rays_per_view)
    seconds = {}
    try:
        t0 = time.perf_counter()
        rays = cast_views(model, views, cfg.points, ctx.rng("export.points.pixels"), progress=ctx.show_progress)
        t1 = time.perf_counter()
        cloud = point_cloud(model, rays, cfg.points, ctx.rng("export.points.cap"))
        level = cfg.mesh.density_level
        if level is None:
            level = surface_level(model, cloud.xyz)
            log.info("export: density level %.4g 1/m (the median at the point cloud's points)", level)
        t2 = time.perf_counter()
        mesh = mesh_from_density(model, grid, rays, cfg.mesh, level, ctx.device, progress=ctx.show_progress)
        t3 = time.perf_counter()
        seconds = {"render_rays_s": t1 - t0, "point_cloud_s": t2 - t1, "mesh_s": t3 - t2}
    except NoSurface as e:
        raise InputError(f"export {inputs.scene[:12]}: {e}") from None
    log.info("export: %d points, mesh %d vertices / %d faces", len(cloud.xyz), len(mesh.vertices), len(mesh.faces))
    with store.publish(kind="export", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(),
                       seed=ctx.seed) as out:
        t4 = time.perf_counter()
        doc = write_export(out.dir, inputs.scene, poses_id, cloud, mesh, cfg)
        seconds["write_s"] = time.perf_counter() - t4
        out.summary.update({"points": doc["points"]["count"], "mesh_vertices": doc["mesh"]["vertices"],
                            "mesh_faces": doc["mesh"]["faces"], "mesh_area_m2": round(doc["mesh"]["area_m2"], 3),
                            "density_level_per_m": round(level, 6), "cell_m": doc["mesh"]["cell_m"]})
        out.timing.update({k: round(v, 2) for k, v in seconds.items()})
    return Outputs(export=out.ref)


def write_export(out_dir, scene_id: str, poses_id: str, cloud, mesh, cfg: Config) -> dict[str, Any]:
    """Write the artifact's files (see the module docstring); returns export.json's content."""
    from nsim.export.preview import write_preview
    from nsim.io.mesh import write_glb, write_surface_ply

    header = [f"frame: {FRAME}", "units: metres", f"source: nsim export of scene-checkpoint {scene_id}"]
    write_surface_ply(out_dir / "points.ply", cloud.xyz, cloud.rgb, cloud.normals, comments=[
        *header, "content: surface points seen by the training cameras; normals -grad(density), facing the camera"])
    write_surface_ply(out_dir / "mesh.ply", mesh.vertices, mesh.rgb, mesh.normals, mesh.faces, comments=[
        *header, f"content: marching cubes at density {mesh.stats['density_level_per_m']:.6g} 1/m; faces counter-clockwise "
                 "seen from the free side"])
    write_glb(out_dir / "mesh.glb", mesh.vertices, mesh.faces, mesh.rgb, mesh.normals, metadata={
        "frame": FRAME, "up_axis": "z", "units": "metres", "scene_checkpoint": scene_id,
        "note": "vertex data is in the z-up world frame; glTF viewers assume y up (rotate -90 deg about x to view upright)"})
    m = mesh.stats
    doc = {
        "format": 1,
        "frame": FRAME,
        "units": "metres (densities in 1/m)",
        "scene_checkpoint": scene_id,
        "poses": poses_id,
        "files": {
            "points.ply": "point cloud, binary little-endian PLY: x y z nx ny nz float32, red green blue uchar",
            "mesh.ply": "mesh, binary little-endian PLY: vertex (x y z nx ny nz float32, red green blue uchar), "
                        "face (vertex_indices: uchar count, int32), counter-clockwise seen from the free side",
            "mesh.glb": "the mesh as binary glTF 2.0 (POSITION, NORMAL, COLOR_0 RGBA uint8), z-up world coordinates",
            "preview.png": "point cloud top view, mesh top view and perspective view, axes in metres",
        },
        "points": {"count": int(len(cloud.xyz)), **cloud.stats, "bounds_m": _bounds(cloud.xyz),
                   "normals": "-grad(density)/|grad(density)| at the point (autograd), flipped to face the camera"
                              if cfg.points.orient_normals else "-grad(density)/|grad(density)| at the point (autograd)"},
        "mesh": {**m, "density_level_source": "mesh.density_level" if cfg.mesh.density_level is not None else
                 "automatic: the median density at the point cloud's points", "bounds_m": _bounds(mesh.vertices)},
    }
    (out_dir / "export.json").write_text(json.dumps(doc, indent=1) + "\n")
    write_preview(out_dir / "preview.png", cloud.xyz, cloud.rgb, mesh.vertices, mesh.faces, mesh.rgb,
                  f"nsim export of scene {scene_id[:12]}: world frame, z up, metres (mesh at density "
                  f"{m['density_level_per_m']:.3g} 1/m, cell {m['cell_m']:.3g} m)", cfg.preview_max_points)
    return doc


def _bounds(xyz: np.ndarray) -> list[list[float]] | None:
    if len(xyz) == 0:
        return None
    return [np.round(xyz.min(0).astype(np.float64), 6).tolist(), np.round(xyz.max(0).astype(np.float64), 6).tolist()]


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    return rerun(run, Inputs(scene=manifest["inputs"]["scene"]), Config, manifest, ctx).export
