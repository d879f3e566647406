"""Surfaces on disk: PLY (point clouds with normals, triangle meshes) and binary glTF (GLB).

PLY (via ``plyfile``), binary little-endian: one ``vertex`` element ``x y z`` (float32),
``nx ny nz`` (float32, when normals are given), ``red green blue`` (uchar), then, for a mesh, a
``face`` element with ``vertex_indices`` (uchar count, int32 indices; counter-clockwise seen from
the side the normals point to). Header ``comment`` lines carry the frame and units. ``nsim.io.ply.read_ply``
reads the vertices back (the normals land in its ``fields``); trimesh and MeshLab read both.

GLB (via ``trimesh``): one mesh with per-vertex colours (``COLOR_0``, RGBA uint8) and normals;
``metadata`` goes to the glTF ``asset.extras``, the scene's ``extras`` and the mesh's ``extras``.
Coordinates are written as given (no axis swap, no re-centring): glTF viewers assume y up, so a
z-up world shows lying on its back until rotated by -90 degrees about x.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from plyfile import PlyData

from nsim.io import atomic_path
from nsim.io.ply import write_ply_columns


def _check(xyz: np.ndarray, rgb: np.ndarray | None, normals: np.ndarray | None, faces: np.ndarray | None) -> None:
    n = len(xyz)
    if xyz.shape != (n, 3):
        raise ValueError(f"xyz: expected (N, 3), got {xyz.shape}")
    if rgb is not None and (rgb.shape != (n, 3) or rgb.dtype != np.uint8):
        raise ValueError(f"rgb: expected ({n}, 3) uint8, got {rgb.shape} {rgb.dtype}")
    if normals is not None and normals.shape != (n, 3):
        raise ValueError(f"normals: expected ({n}, 3), got {normals.shape}")
    if faces is not None:
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces: expected (F, 3), got {faces.shape}")
        if faces.size and (faces.min() < 0 or faces.max() >= n):
            raise ValueError(f"faces: indices outside [0, {n})")


def write_surface_ply(
    path: str | os.PathLike,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    faces: np.ndarray | None = None,
    comments: Sequence[str] = (),
) -> Path:
    """Write a point cloud (``faces`` None) or a triangle mesh as binary little-endian PLY, atomically.

    xyz: (N, 3) (stored float32); rgb: (N, 3) uint8; normals: (N, 3) (stored float32); faces:
    (F, 3) vertex indices; comments: header lines (one line each, no newlines).
    """
    xyz = np.asarray(xyz)
    rgb = None if rgb is None else np.asarray(rgb)
    normals = None if normals is None else np.asarray(normals)
    faces = None if faces is None else np.asarray(faces)
    _check(xyz, rgb, normals, faces)
    columns: dict[str, np.ndarray] = {c: xyz[:, i].astype("<f4") for i, c in enumerate("xyz")}
    if normals is not None:
        columns |= {c: normals[:, i].astype("<f4") for i, c in enumerate(("nx", "ny", "nz"))}
    if rgb is not None:
        columns |= {c: rgb[:, i] for i, c in enumerate(("red", "green", "blue"))}
    return write_ply_columns(path, columns, faces=faces, comments=comments)


def read_ply_comments(path: str | os.PathLike) -> list[str]:
    """The header ``comment`` lines of a PLY file."""
    with open(path, "rb") as f:
        return list(PlyData.read(f, mmap=False).comments)


def write_glb(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    rgb: np.ndarray,
    normals: np.ndarray | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Write a triangle mesh with vertex colours as binary glTF (GLB), atomically.

    vertices: (N, 3) metres (stored float32, as given); faces: (F, 3); rgb: (N, 3) uint8;
    normals: (N, 3) per-vertex (default: trimesh's area-weighted face normals); metadata: JSON-able,
    written to ``asset.extras`` and the scene's and the mesh's ``extras``. The bytes depend only
    on the inputs (no timestamps).
    """
    import trimesh

    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    rgb = np.asarray(rgb)
    _check(vertices, rgb, normals, faces)
    meta = json.loads(json.dumps(dict(metadata or {})))  # JSON-able, plain types
    rgba = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    mesh = trimesh.Trimesh(vertices=vertices.astype(np.float32), faces=faces.astype(np.int64),
                           vertex_colors=rgba, vertex_normals=None if normals is None else np.asarray(normals),
                           process=False, validate=False)
    mesh.metadata.update(meta)
    scene = trimesh.Scene()
    scene.add_geometry(mesh, geom_name="surface", node_name="surface")
    scene.metadata.update(meta)

    def add_asset_extras(tree: dict) -> None:
        tree["asset"]["extras"] = meta

    data = trimesh.exchange.gltf.export_glb(scene, include_normals=True, tree_postprocessor=add_asset_extras)
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "xb") as f:
        f.write(data)
    return path


def read_glb(path: str | os.PathLike):
    """The GLB's meshes as one ``trimesh.Trimesh`` (node transforms applied) and its ``asset`` dict."""
    import trimesh

    raw = Path(path).read_bytes()
    scene = trimesh.load(io.BytesIO(raw), file_type="glb", process=False)
    mesh = scene.to_mesh() if hasattr(scene, "to_mesh") else scene.dump(concatenate=True)
    # the JSON chunk: 12-byte header, then chunk length (u32), type, JSON
    length = int.from_bytes(raw[12:16], "little")
    asset = json.loads(raw[20 : 20 + length]).get("asset", {})
    return mesh, asset
