"""``nsim evaluate``'s settings (``nsim/configs/evaluate/*.yaml``): which table, and how each is computed."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from nsim.config import param, param_from
from nsim.sfm.options import SfmOptions

if TYPE_CHECKING:
    from nsim.metrics.depth import DepthConfig

TABLES = ("scenes", "spot-rgb", "spot-depth", "lidar", "slam", "detection")


@dataclasses.dataclass(frozen=True)
class SlamConfig:
    camera: str = param("left", help="the rig camera whose frames SfM runs on")
    stride: int = param(1, ge=1, help="use every k-th rendered frame")
    max_frames: int | None = param(None, ge=3, help="use at most this many frames")
    camera_model: str = param_from(SfmOptions, "camera_model", "OPENCV_FISHEYE")
    matcher: str = param_from(SfmOptions, "matcher")
    overlap: int = param_from(SfmOptions, "overlap")
    max_features: int = param_from(SfmOptions, "max_features", 4096)
    min_registered_fraction: float = param_from(SfmOptions, "min_registered_fraction",
                                                help="fewer registered frames: SfM failed (n/a)")
    alignment: str = param("sim3", choices=("se3", "sim3"), help="ATE alignment (monocular SfM has no scale: sim3)")
    max_dt_s: float = param(0.01, gt=0.0, help="largest timestamp gap when associating poses")


@dataclasses.dataclass(frozen=True)
class DetectionConfig:
    detector: str = param("hog", choices=("hog", "onnx", "coco"),
                          help="hog: OpenCV's people detector; onnx: --onnx weights; coco: --coco-sim/--coco-real files")
    iou_threshold: float = param(0.5, gt=0.0, le=1.0, help="a simulated box matches a real one at this IoU")
    hog_upscale: float = param(2.0, gt=0.0, le=8.0, help="enlarge images first (the HOG window is 64x128 px)")
    hog_hit_threshold: float = param(0.0, help="HOG SVM margin below which windows are dropped")
    upright: bool = param(True, help="turn each camera's frames by quarter turns so the world's up is up before "
                                     "detecting (Spot's front cameras are rolled ~90 deg, its right one upside down)")


@dataclasses.dataclass(frozen=True)
class Config:
    table: str = param("scenes", choices=TABLES, help="which table to compute")
    cameras: tuple[str, ...] = param((), help="rig cameras to score (empty: all that apply)")
    lpips_net: str = param("alex", choices=("alex", "vgg", "none"), help="LPIPS backbone (none: not computed)")
    oracle_supersample: int = param(2, ge=1, le=8, help="sub-pixel rays per axis of the oracle's ground-truth images")
    scenes_ground_truth: str = param("captured", choices=("captured", "oracle"),
                                     help="scenes: the captured frames, or the oracle at the rendered cameras")
    region: str = param("all", choices=("all", "people"), help="score every pixel, or only the people's")
    depth_min_m: float = param(0.1, gt=0.0, help="ground-truth depths below this do not count")
    depth_max_m: float = param(10.0, gt=0.0, help="ground-truth depths above this do not count")
    median_scaling: bool = param(False, help="scale each predicted depth map by median(gt) / median(pred)")
    error_maps: int = param(2, ge=0, help="depth error map PNGs per group (first frames)")
    slam: SlamConfig = SlamConfig()
    detection: DetectionConfig = DetectionConfig()

    def depth_config(self) -> DepthConfig:
        """The depth metrics' settings (``nsim.metrics.depth``): valid range and median scaling."""
        from nsim.metrics.depth import DepthConfig

        return DepthConfig(self.depth_min_m, self.depth_max_m, self.median_scaling)
