"""A labelled picture of an export: the point cloud and the mesh from above, the mesh in perspective.

All panels are in the world frame (metres, z up). The top quarter of the height range is cut
away (for a room: its ceiling), so the views from above show the floor, the furniture and the
walls rather than the ceiling.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

CUTAWAY = 0.25  # fraction of the height range cut away at the top


def _subset(n: int, k: int) -> np.ndarray:
    """At most ``k`` evenly spaced indices of ``range(n)`` (deterministic)."""
    return np.arange(n) if n <= k else np.linspace(0, n - 1, k).round().astype(np.int64)


def _marker_size(n: int) -> float:
    return float(np.clip(4000.0 / max(n, 1), 0.5, 12.0))


def _pixel_m(vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Raster pixel: the median edge length (vertices fill the pixels), at least 1/500 of the extent."""
    f = faces[_subset(len(faces), 10000)]
    edge = np.median(np.linalg.norm(vertices[f[:, 1]] - vertices[f[:, 0]], axis=-1)) if len(f) else 0.0
    return float(max(edge, (hi[:2] - lo[:2]).max() / 500.0, 1e-6))


def top_raster(xyz: np.ndarray, rgb: np.ndarray, lo: np.ndarray, hi: np.ndarray, pixel_m: float
               ) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The view from above: an RGBA image ``(H, W, 4)`` float (row 0 = lowest y) whose pixel of ``pixel_m``
    holds the colour of its highest point (transparent where none), and its extent for ``imshow``."""
    shape = np.maximum(np.ceil((hi[:2] - lo[:2]) / pixel_m).astype(int), 1)
    img = np.zeros((shape[1], shape[0], 4))
    if len(xyz):
        ij = np.clip(np.floor((xyz[:, :2] - lo[:2]) / pixel_m).astype(int), 0, shape - 1)
        pix = ij[:, 1] * shape[0] + ij[:, 0]
        order = np.lexsort((xyz[:, 2], pix))  # by pixel, then height
        last = np.r_[pix[order][1:] != pix[order][:-1], True]  # the highest point of each pixel
        top = order[last]
        img.reshape(-1, 4)[pix[top], :3] = rgb[top] / 255.0
        img.reshape(-1, 4)[pix[top], 3] = 1.0
    return img, (float(lo[0]), float(lo[0] + shape[0] * pixel_m), float(lo[1]), float(lo[1] + shape[1] * pixel_m))


def write_preview(path: Path, cloud_xyz: np.ndarray, cloud_rgb: np.ndarray, mesh_vertices: np.ndarray,
                  mesh_faces: np.ndarray, mesh_rgb: np.ndarray, title: str, max_points: int = 20000) -> None:
    """PNG with three panels: point cloud from above, mesh from above (a raster of its highest vertices), mesh
    vertices in perspective; at most ``max_points`` points drawn per scatter. Deterministic bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    both = np.concatenate([cloud_xyz.reshape(-1, 3), mesh_vertices.reshape(-1, 3)]).astype(np.float64)
    lo, hi = both.min(0), both.max(0)
    z_cut = hi[2] - CUTAWAY * (hi[2] - lo[2])

    fig = plt.figure(figsize=(15.0, 5.2), dpi=80)
    ax = fig.add_subplot(1, 3, 1)
    i = _subset(len(cloud_xyz), max_points)
    i = i[cloud_xyz[i, 2] <= z_cut]
    i = i[np.argsort(cloud_xyz[i, 2], kind="stable")]  # low points first: each pixel shows the highest
    ax.scatter(cloud_xyz[i, 0], cloud_xyz[i, 1], c=cloud_rgb[i] / 255.0, s=_marker_size(len(i)), lw=0)
    ax.set_title(f"point cloud from above, z <= {z_cut:.2f} m ({len(cloud_xyz)} points)", fontsize=9)

    ax2 = fig.add_subplot(1, 3, 2)
    below = mesh_vertices[:, 2] <= z_cut
    img, extent = top_raster(mesh_vertices[below], mesh_rgb[below], lo, hi, _pixel_m(mesh_vertices, mesh_faces, lo, hi))
    ax2.imshow(img, origin="lower", extent=extent, interpolation="nearest")
    ax2.set_title(f"mesh from above, z <= {z_cut:.2f} m ({len(mesh_faces)} faces)", fontsize=9)
    for a in (ax, ax2):
        a.set_xlim(lo[0], hi[0])
        a.set_ylim(lo[1], hi[1])
        a.set_aspect("equal")
        a.set_xlabel("x (m)")
        a.set_ylabel("y (m)")
        a.grid(alpha=0.3)

    ax3 = fig.add_subplot(1, 3, 3, projection="3d")
    v = _subset(len(mesh_vertices), max_points)
    v = v[mesh_vertices[v, 2] <= z_cut]
    ax3.scatter(mesh_vertices[v, 0], mesh_vertices[v, 1], mesh_vertices[v, 2], c=mesh_rgb[v] / 255.0,
                s=_marker_size(len(v)), lw=0, depthshade=False)
    ax3.set_xlim(lo[0], hi[0])
    ax3.set_ylim(lo[1], hi[1])
    ax3.set_zlim(lo[2], hi[2])
    ax3.set_box_aspect(np.maximum(hi - lo, 1e-3))
    ax3.view_init(elev=35, azim=-60)
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax3.set_title(f"mesh vertices in perspective (z up), z <= {z_cut:.2f} m", fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
