"""Evaluation metrics against ground truth: arrays in, numbers out (no I/O).

``image``: PSNR, SSIM; ``lpips``: LPIPS (AlexNet / VGG, weights from ``scripts/fetch_lpips_weights.py``);
``depth``: AbsRel, SqRel, RMSE, logRMSE, delta thresholds; ``lidar``: per-beam range error, hit/miss
agreement, Chamfer distance; ``trajectory``: ATE and RPE (evo's definitions); ``tables``: Markdown and
fixed-width rendering with n/a for values that could not be computed. Bad input raises
``nsim.errors.InputError``; missing LPIPS weights raise ``LpipsUnavailable``.
"""

from nsim.metrics.depth import DepthConfig, DepthMetrics, depth_metrics, mean_depth_metrics, valid_depth_mask
from nsim.metrics.image import psnr, ssim
from nsim.metrics.lidar import ChamferResult, LidarRangeMetrics, chamfer_distance, lidar_range_metrics
from nsim.metrics.lpips import LpipsUnavailable, load_lpips, lpips_distance, lpips_or_na, unavailable_reason
from nsim.metrics.tables import NotAvailable, to_markdown, to_text
from nsim.metrics.trajectory import AteResult, RpeResult, align_trajectories, ate, rpe, rpe_per_delta

__all__ = [
    "AteResult",
    "ChamferResult",
    "DepthConfig",
    "DepthMetrics",
    "LidarRangeMetrics",
    "LpipsUnavailable",
    "NotAvailable",
    "RpeResult",
    "align_trajectories",
    "ate",
    "chamfer_distance",
    "depth_metrics",
    "lidar_range_metrics",
    "load_lpips",
    "lpips_distance",
    "lpips_or_na",
    "mean_depth_metrics",
    "psnr",
    "rpe",
    "rpe_per_delta",
    "ssim",
    "to_markdown",
    "to_text",
    "unavailable_reason",
    "valid_depth_mask",
]
