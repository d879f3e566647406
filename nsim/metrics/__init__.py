"""Evaluation metrics against ground truth: arrays in, numbers out (no I/O).

``image``: PSNR, SSIM; ``lpips``: LPIPS (AlexNet / VGG, weights from ``scripts/fetch_lpips_weights.py``);
``depth``: AbsRel, SqRel, RMSE, logRMSE, delta thresholds; ``lidar``: per-beam range error, hit/miss
agreement, Chamfer distance; ``trajectory``: ATE and RPE (evo's definitions); ``slam``: SLAM (pycolmap
or an external TUM file) on simulated vs real frames, both ATEs and their difference; ``detection``: box
IoU, matching, HOG / ONNX / COCO-JSON detections on simulated vs real frames; ``tables``: Markdown,
text, LaTeX (booktabs), CSV and JSON with n/a for values that could not be computed; ``paper_tables``:
the paper's five tables and plots from per-frame records. Each metric is defined here once (PSNR:
``image.psnr_from_mse``; AbsRel: ``depth.scored_depths`` and ``depth.abs_rel``) and called, never
copied, elsewhere. Bad input raises ``nsim.errors.InputError`` (images: floating point in [0, 1], or
[0, data_range], of equal shape; uint8 or [-1, 1] images are refused); missing LPIPS weights raise
``LpipsUnavailable``. ``slam`` imports pycolmap only when SLAM runs.
"""

from nsim.metrics.depth import (
    DepthConfig,
    DepthErrors,
    DepthMetrics,
    abs_rel,
    depth_error_map,
    depth_metrics,
    mean_depth_metrics,
    valid_depth_mask,
)
from nsim.metrics.detection import (
    DetectionComparison,
    Detections,
    HogPeopleDetector,
    MatchConfig,
    OnnxConfig,
    OnnxDetector,
    YoloDecodeConfig,
    box_iou,
    box_iou_xywh,
    compare_detections,
    decode_yolo,
    evaluate_detection,
    match_boxes,
    nms,
    read_coco_detections,
)
from nsim.metrics.image import psnr, psnr_from_mse, ssim
from nsim.metrics.lidar_realism import ChamferResult, LidarRangeMetrics, chamfer_distance, lidar_range_metrics
from nsim.metrics.lpips import LpipsUnavailable, load_lpips, lpips_distance, lpips_or_na, unavailable_reason
from nsim.metrics.paper_tables import (
    TABLE_BUILDERS,
    DepthRecord,
    DetectionRecord,
    ImageRecord,
    SlamRecord,
    detection_table,
    plot_bars,
    plot_depth_error_map,
    plot_per_frame,
    scenes_table,
    slam_table,
    spot_depth_table,
    spot_rgb_table,
)
from nsim.metrics.results_table import Column, NotAvailable, Table, to_markdown, to_text
from nsim.metrics.slam import SlamComparison, SlamRun, compare_slam, evaluate_slam, run_colmap_slam
from nsim.metrics.trajectory import AteResult, RpeResult, align_trajectories, ate, rpe, rpe_per_delta

__all__ = [
    "TABLE_BUILDERS",
    "AteResult",
    "ChamferResult",
    "Column",
    "DepthConfig",
    "DepthErrors",
    "DepthMetrics",
    "DepthRecord",
    "DetectionComparison",
    "DetectionRecord",
    "Detections",
    "HogPeopleDetector",
    "ImageRecord",
    "LidarRangeMetrics",
    "LpipsUnavailable",
    "MatchConfig",
    "NotAvailable",
    "OnnxConfig",
    "OnnxDetector",
    "RpeResult",
    "SlamComparison",
    "SlamRecord",
    "SlamRun",
    "Table",
    "YoloDecodeConfig",
    "abs_rel",
    "align_trajectories",
    "ate",
    "box_iou",
    "box_iou_xywh",
    "chamfer_distance",
    "compare_detections",
    "compare_slam",
    "decode_yolo",
    "depth_error_map",
    "depth_metrics",
    "detection_table",
    "evaluate_detection",
    "evaluate_slam",
    "lidar_range_metrics",
    "load_lpips",
    "lpips_distance",
    "lpips_or_na",
    "match_boxes",
    "mean_depth_metrics",
    "nms",
    "plot_bars",
    "plot_depth_error_map",
    "plot_per_frame",
    "psnr",
    "psnr_from_mse",
    "read_coco_detections",
    "rpe",
    "rpe_per_delta",
    "run_colmap_slam",
    "scenes_table",
    "slam_table",
    "spot_depth_table",
    "spot_rgb_table",
    "ssim",
    "to_markdown",
    "to_text",
    "unavailable_reason",
    "valid_depth_mask",
]
