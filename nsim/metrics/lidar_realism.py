"""LiDAR realism: per-beam range error, hit/miss agreement, and the Chamfer distance of point clouds.

Scans are range images ``(channels, azimuth_samples)`` in metres as ``nsim.sensors.lidar`` lays them
out, beam for beam the same in simulation and ground truth; a beam *hits* where its range is finite
(``inf`` or NaN: no return). Range errors are ``|pred - gt|`` over the beams where both hit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from nsim.errors import InputError


@dataclass(frozen=True)
class LidarRangeMetrics:
    """Per-beam comparison of two scans of ``n_beams`` beams.

    range_error_*_m: statistics of |pred - gt| over the ``n_both_hit`` beams where both returned;
        None when no beam did (shown as n/a).
    range_bias_m: mean of (pred - gt) over those beams (None likewise).
    hit_agreement: fraction of beams where both hit or both missed.
    n_pred_only: beams that returned in the prediction only; n_gt_only: in the ground truth only.
    """

    range_error_median_m: float | None
    range_error_mean_m: float | None
    range_error_p95_m: float | None
    range_bias_m: float | None
    hit_agreement: float
    n_beams: int
    n_both_hit: int
    n_both_miss: int
    n_pred_only: int
    n_gt_only: int

    def row(self) -> dict[str, float | int | None]:
        return {
            "range err median [m]": self.range_error_median_m,
            "range err mean [m]": self.range_error_mean_m,
            "range err p95 [m]": self.range_error_p95_m,
            "hit agreement": self.hit_agreement,
        }


def lidar_range_metrics(
    pred_ranges_m: np.ndarray, gt_ranges_m: np.ndarray, mask: np.ndarray | None = None
) -> LidarRangeMetrics:
    """Compare two range images beam by beam (module docstring).

    pred_ranges_m, gt_ranges_m: (channels, azimuth_samples) metres, inf/NaN for no return.
    mask: optional bool of the same shape selecting the beams that count.
    Raises InputError for differing shapes, negative ranges or an empty mask.
    """
    pred, gt = np.asarray(pred_ranges_m, np.float64), np.asarray(gt_ranges_m, np.float64)
    if pred.shape != gt.shape:
        raise InputError(f"LiDAR range images differ in size: pred {pred.shape} vs ground truth {gt.shape}")
    if pred.size == 0:
        raise InputError("LiDAR range images are empty")
    for name, ranges in (("pred", pred), ("ground truth", gt)):
        with np.errstate(invalid="ignore"):
            negative = int((ranges < 0).sum())
        if negative:
            raise InputError(f"LiDAR {name} ranges: {negative} negative value(s)")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != pred.shape or mask.dtype != bool:
            raise InputError(
                f"mask: expected a bool array of shape {pred.shape}, got {mask.dtype} {mask.shape}"
            )
        if not mask.any():
            raise InputError("mask is empty (no beam selected)")
        pred, gt = pred[mask], gt[mask]
    pred, gt = pred.ravel(), gt.ravel()
    hit_p, hit_g = np.isfinite(pred), np.isfinite(gt)
    both = hit_p & hit_g
    stats: list[float | None] = [None] * 4
    if both.any():
        diff = pred[both] - gt[both]
        err = np.abs(diff)
        stats = [float(np.median(err)), float(err.mean()), float(np.percentile(err, 95)), float(diff.mean())]
    return LidarRangeMetrics(
        range_error_median_m=stats[0],
        range_error_mean_m=stats[1],
        range_error_p95_m=stats[2],
        range_bias_m=stats[3],
        hit_agreement=float(np.mean(hit_p == hit_g)),
        n_beams=int(pred.size),
        n_both_hit=int(both.sum()),
        n_both_miss=int((~hit_p & ~hit_g).sum()),
        n_pred_only=int((hit_p & ~hit_g).sum()),
        n_gt_only=int((~hit_p & hit_g).sum()),
    )


@dataclass(frozen=True)
class ChamferResult:
    """Mean nearest-neighbour distances between clouds A and B, in metres (not squared).

    a_to_b_m: mean over the points of A of the distance to the nearest point of B; b_to_a_m likewise;
    chamfer_m: their average, (a_to_b_m + b_to_a_m) / 2. n_a, n_b: finite points used.
    """

    chamfer_m: float
    a_to_b_m: float
    b_to_a_m: float
    n_a: int
    n_b: int


def _finite_points(points: np.ndarray, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim < 2 or points.shape[-1] != 3:
        raise InputError(f"Chamfer: {name} must be (..., 3) points, got {points.shape}")
    points = points.reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) == 0:
        raise InputError(f"Chamfer: {name} has no finite point")
    return points


def chamfer_distance(points_a: np.ndarray, points_b: np.ndarray) -> ChamferResult:
    """Chamfer distance between point clouds (..., 3) (e.g. (N, 3) or a scan's (C, A, 3) points).

    Points with a NaN/inf coordinate (beams without a return) are dropped. Nearest neighbours by
    ``scipy.spatial.cKDTree``. Raises InputError when either cloud has no finite point.
    """
    a, b = _finite_points(points_a, "points_a"), _finite_points(points_b, "points_b")
    a_to_b = float(cKDTree(b).query(a, k=1)[0].mean())
    b_to_a = float(cKDTree(a).query(b, k=1)[0].mean())
    return ChamferResult(
        chamfer_m=0.5 * (a_to_b + b_to_a), a_to_b_m=a_to_b, b_to_a_m=b_to_a, n_a=len(a), n_b=len(b)
    )
