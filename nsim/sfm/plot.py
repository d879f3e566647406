"""Top-down picture of a reconstruction: sparse points and the camera path, seen from +z."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from nsim.io import atomic_path


def write_top_down_png(
    path: str | os.PathLike,
    cam_to_world: np.ndarray,
    points_xyz: np.ndarray,
    title: str = "",
    units: str = "m",
    reference_xyz: np.ndarray | None = None,
) -> Path:
    """Write a PNG of the xy plane: points (grey, a 1-99% window), camera path and headings.

    cam_to_world: (N, 4, 4) OpenCV axes in a z-up world; points_xyz: (P, 3);
    reference_xyz: optional (M, 3) reference camera centres drawn as a dashed line.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c2w = np.asarray(cam_to_world, dtype=np.float64)
    pts = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    centres = c2w[:, :3, 3]
    fig, ax = plt.subplots(figsize=(6, 6), dpi=100)
    if len(pts):
        lo, hi = np.percentile(pts[:, :2], [1, 99], axis=0)
        keep = np.all((pts[:, :2] >= lo) & (pts[:, :2] <= hi), axis=1)
        ax.scatter(pts[keep, 0], pts[keep, 1], s=0.5, c="0.55", lw=0, label=f"{len(pts)} sparse points")
    if reference_xyz is not None and len(reference_xyz):
        ref = np.asarray(reference_xyz)
        ax.plot(ref[:, 0], ref[:, 1], "--", color="tab:green", lw=1, label="reference")
    if len(centres):
        ax.plot(centres[:, 0], centres[:, 1], "-", color="tab:blue", lw=1, label=f"{len(centres)} cameras")
        fwd = c2w[:, :3, 2]
        span = np.ptp(centres[:, :2], axis=0).max() if len(centres) > 1 else 1.0
        step = max(1, len(centres) // 40)
        ax.quiver(centres[::step, 0], centres[::step, 1], fwd[::step, 0], fwd[::step, 1], color="tab:red",
                  angles="xy", scale_units="xy", scale=1.0 / (0.06 * max(span, 1e-9)), width=0.004)
        ax.plot(centres[0, 0], centres[0, 1], "o", color="tab:blue", ms=5)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x [{units}]")
    ax.set_ylabel(f"y [{units}]")
    ax.set_title(title or "top-down view (+z up)")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
