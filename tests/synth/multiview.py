"""Multi-view reprojection check of ground-truth renders (shared by the oracle tests and benches).

Frame i's pixels are lifted to 3D with i's ground-truth range, moved into frame j and
projected; where j sees the same point (its own range agrees) and both depth maps are smooth
around it, the colours of the two renders must agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class Reprojection:
    """n_checked: pixels of i compared; fraction_checked: of all pixels of i;
    median_abs_rgb: median over compared pixels of the mean-over-channels |rgb_i - rgb_j|;
    median_rel_range: median of |range_j(uv_j) - |p_j|| / |p_j| over compared pixels."""

    n_checked: int
    fraction_checked: float
    median_abs_rgb: float
    median_rel_range: float


def _smooth(range_m: np.ndarray, rel_tol: float) -> np.ndarray:
    """Pixels away from depth edges: the range's second differences (both axes, at the pixel and
    its 4 neighbours) stay below ``rel_tol`` times the range. Planes pass; steps and creases fail."""
    r = np.where(np.isfinite(range_m), range_m, np.nan).astype(np.float64)
    pad = np.pad(r, 1, mode="edge")
    d2x = np.abs(pad[1:-1, 2:] - 2 * r + pad[1:-1, :-2])
    d2y = np.abs(pad[2:, 1:-1] - 2 * r + pad[:-2, 1:-1])
    ok = np.nan_to_num(np.maximum(d2x, d2y) / r, nan=np.inf) < rel_tol
    return ndimage.binary_erosion(ok, structure=ndimage.generate_binary_structure(2, 1), border_value=1)


def reproject(camera, view_i, pose_i: np.ndarray, view_j, pose_j: np.ndarray,
              edge_rel_tol: float = 0.01, visible_rel_tol: float = 0.01) -> Reprojection:
    """Compare render ``view_i`` at ``pose_i`` with ``view_j`` at ``pose_j`` (GroundTruthView, cam_to_world)."""
    H, W = view_i.depth_range.shape
    jj, ii = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    dirs_i = np.asarray(camera.unproject(np.stack([jj, ii], axis=-1)))
    p_cam_i = dirs_i * view_i.depth_range[..., None].astype(np.float64)
    p_world = p_cam_i @ pose_i[:3, :3].T + pose_i[:3, 3]
    p_cam_j = (p_world - pose_j[:3, 3]) @ pose_j[:3, :3]
    uv_j, valid = camera.project(p_cam_j)
    valid &= np.isfinite(view_i.depth_range) & _smooth(view_i.depth_range, edge_rel_tol)
    map_x = np.where(valid, uv_j[..., 0], -10).astype(np.float32)
    map_y = np.where(valid, uv_j[..., 1], -10).astype(np.float32)
    range_j = view_j.depth_range.astype(np.float32)
    range_at = cv2.remap(range_j, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    smooth_j = cv2.remap(_smooth(view_j.depth_range, edge_rel_tol).astype(np.uint8), map_x, map_y,
                         cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    dist_j = np.linalg.norm(p_cam_j, axis=-1)
    rel = np.abs(range_at - dist_j) / dist_j
    checked = valid & smooth_j & (rel < visible_rel_tol)
    rgb_at = cv2.remap(view_j.rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    diff = np.abs(rgb_at - view_i.rgb).mean(axis=-1)
    n = int(checked.sum())
    return Reprojection(
        n_checked=n,
        fraction_checked=n / (H * W),
        median_abs_rgb=float(np.median(diff[checked])) if n else float("nan"),
        median_rel_range=float(np.median(rel[checked])) if n else float("nan"),
    )
