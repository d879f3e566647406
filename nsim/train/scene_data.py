"""The scene trainer's data: frames as uint8 images at the training resolution, poses, intrinsics.

``SceneData.load(root, max_image_side=...)`` reads ``root/transforms.json`` (nerfstudio convention:
a capture or a poses artifact) and its images one at a time, shrinking each to at most
``max_image_side`` pixels on its longer side (``cv2.INTER_AREA``) before keeping it, so that a
folder of 12-megapixel photos never sits in memory at full size. The intrinsics shrink with the
images, exactly (``Camera.scaled``: ``f' = f s``, ``c' = (c + 0.5) s - 0.5`` in the OpenCV
pixel-centre convention of ``nsim.geometry.cameras``). Rays are not stored: the trainer builds each
batch's rays from the uint8 pixels it picks, the pixel directions (a per-camera table, or unprojected
per batch when there are many cameras) and the poses.
Held-out images can be read again at any resolution (``eval_camera``, ``eval_image``): scoring need
not happen at the training resolution.

Depth and masks, as nerfstudio reads them. A frame's ``depth_file_path`` is a z-depth image: a 16-bit
PNG (or 8-bit), a float TIFF or EXR (channel ``Z``), or a ``.npy`` array; stored value x the file's
``depth_unit_scale_factor`` (:func:`nsim.io.transforms_json.depth_unit_scale`: 1 for EXR, nerfstudio's
1e-3 otherwise, when the key is absent) = depth in the poses' units, and 0 means no depth
(:meth:`SceneData.read_depth_z`). Held-out scoring reads it at the scored size; depth supervision
(``loss.image_depth_weight``) keeps it at the training size as float16 (:meth:`SceneData.train_depth_z`,
2 bytes a pixel: 144 MB for 50 frames of 1600x900), both resized by nearest pixel. A frame's
``mask_path`` names an image whose 0 pixels are to be ignored (nonzero: kept); masks are read with
the images and kept as one bool a pixel at the training size (``SceneData.masks``): the trainer
draws rays from kept pixels only. Held-out scoring ignores masks.

Scale. Poses from ``nsim reconstruct`` are metric unless its ``transforms.json`` (``nsim_metric``,
``nsim_scale``) or ``report.json`` (``scale.source``) say otherwise (:func:`poses_scale`). The
trainer's lengths (near plane, box margin, occupancy cells, obstacle band, ...) are metres; for an
arbitrary-scale scene they are multiplied by :func:`units_per_metre`, a guess of how many scene
units a metre is, taken from the scene's size against a room capture's (see there).

A robot's own frames (``nsim train-scene --recording``, the paper's "a proportion of the real-world
camera data in the training"). A ``registration`` (``nsim register-log``) places a ``recording``
(``nsim import-log``) in the scene's world; :func:`read_recorded_frames` gives each camera frame its
recorded camera model and its world pose ``body_to_world(stamp - clock_offset_s) @ sensor_to_body``
(``nsim.rendering.recording``: the odometry clock, ``interpolate_poses``), dropping and counting the
frames outside the registered trajectory's span. :func:`split_recorded_frames` holds out a fixed
subset (:class:`RecordingConfig`) and picks the training share, evenly spaced;
:meth:`SceneData.with_recorded_frames` appends those frames after the capture's. They are brought to
the capture's training size exactly (:func:`fit_camera`): scaled uniformly (``Camera.scaled``) to
cover it, then centre-cropped (the principal point moves by the crop), so one ``(N, H, W, 3)``
array, one pixel-direction table and the obstacle map's views hold every camera model as it is.
A recorded camera of another aspect ratio loses the strips outside the capture's; one smaller
than it is enlarged (bilinear), which adds no detail but keeps every view's weight in the batch
equal (the trainer draws pixels uniformly). Pixels a model cannot unproject are masked.
Recorded frames always train: the capture's hold-out rule (``DataConfig.holdout_every``) applies
to the capture's frames only, and held-out robot frames never enter ``SceneData``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import param
from nsim.errors import InputError

log = logging.getLogger(__name__)

POINT_FILES = ("sparse_points.ply", "points3D.ply")
BOUNDS_MODES = ("auto", "cameras", "points", "fixed")
SCALE_MODES = ("auto", "metric", "arbitrary")
#: What a room capture measures, for :func:`units_per_metre`: the median distance from a camera centre
#: to a sparse point (every camera against every point), and the RMS distance of the camera centres
#: from their mean. Measured on the test room with ground-truth poses, its depth maps standing in for
#: the sparse points (150 frames, every 8th pixel: 3.39 m and 2.15 m; with 56 frames 3.55 m and 2.15 m;
#: ``tests/train/test_scene_data.py::test_room_measures_about_one_unit_per_metre``).
ROOM_CAMERA_TO_POINT_M = 3.4
ROOM_CAMERA_SPREAD_M = 2.1
MAX_SCALE_POINTS = 20_000  # points used for the median (every k-th), so the cost stays bounded
MAX_DEPTH_PIXELS = 1 << 28  # a .npy depth array larger than this is refused before it is read


@dataclass(frozen=True)
class DataConfig:
    """Split, image size, scale and scene box.

    bounds: ``cameras`` (camera centres' box + margin), ``points`` (sparse points' 1-99 % box + margin),
    ``fixed`` (``aabb_*_m``, in the poses' own units), ``auto`` (points if any, else cameras).
    max_image_side: the training images' longer side at most this many pixels (0: as captured).
    scale: ``auto`` takes the poses artifact's word (``report.json`` / ``transforms.json``: only
    ``arbitrary`` is not metric); ``metric`` / ``arbitrary`` override it. An arbitrary-scale scene's
    metre lengths are multiplied by :func:`units_per_metre`.
    """

    holdout_every: int = param(8, ge=0, help="hold out frame i when i % holdout_every == 0 (0: none)")
    max_image_side: int = param(1600, ge=0, help="train on copies whose longer side is at most this (px; "
                                "cv2.INTER_AREA, intrinsics scaled exactly); 0: the images as captured")
    scale: str = param("auto", choices=SCALE_MODES)
    bounds: str = param("auto", choices=BOUNDS_MODES)
    bounds_margin_m: float = param(2.0, ge=0.0)
    aabb_min_m: tuple[float, float, float] | None = None
    aabb_max_m: tuple[float, float, float] | None = None


SHARE_MEANING = ("the fraction of the training views that are robot frames: with T capture frames in training "
                 "(after the capture's own hold-out), round(share / (1 - share) * T) robot frames are added (at most "
                 "every candidate: a recorded frame inside the registered trajectory and not held out), shared among "
                 "the cameras in proportion to their candidates (largest remainder), evenly spaced in each camera's")
HELDOUT_MEANING = ("the frame at position j of its camera's recorded frames (recording.json's frames, 0-based, "
                   "inside the trajectory or not) is held out when j % holdout_every == 0, whatever the share and "
                   "the cameras; held-out frames never train (those inside the trajectory are listed for scoring)")


@dataclass(frozen=True)
class RecordingConfig:
    """Which of a registered robot recording's camera frames train the scene (``nsim train-scene --recording``).

    share: the fraction of the training views that are robot frames (``SHARE_MEANING``). Every training
    image is at the capture's training size, so it is also the robots' share of the training rays.
    holdout_every: the robot frames held out (``HELDOUT_MEANING``): fixed by the recording alone, so
    runs at different shares are scored on the same frames. cameras: the recording's cameras whose
    frames may train (empty: all); each must record colour.
    """

    share: float = param(0.25, gt=0.0, lt=1.0, help="fraction of the training views that are robot frames")
    holdout_every: int = param(8, ge=2, help="hold out robot frame j (per camera) when j % holdout_every == 0")
    cameras: tuple[str, ...] = param((), help="the recording's cameras that may train (empty: all)")


def shrink_factor(width: int, height: int, max_side: int) -> float:
    """The factor that brings the longer side to ``max_side`` (1.0 when it is already no longer, or max_side is 0)."""
    longest = max(width, height)
    return 1.0 if max_side <= 0 or longest <= max_side else max_side / longest


def camera_at(camera, max_side: int):
    """``camera`` (``nsim.geometry.cameras.Camera``) for its image shrunk to ``max_side`` (itself when no smaller)."""
    f = shrink_factor(camera.width, camera.height, max_side)
    return camera if f == 1.0 else camera.scaled(f)


def resize_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """``image (H, W, C)`` uint8 resized to ``(height, width)`` by pixel-area averaging (itself when the size matches)."""
    if image.shape[1] == width and image.shape[0] == height:
        return image
    import cv2

    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def fit_geometry(camera, width: int, height: int):
    """How an image of ``camera`` becomes ``width x height`` (:func:`fit_camera`): ``(scaled, x0, y0)``, the
    camera scaled uniformly (``Camera.scaled``) so that its image covers the size, and the top-left
    corner of the centred crop in that scaled image."""
    if (camera.width, camera.height) == (width, height):
        return camera, 0, 0
    scaled = camera.scaled(max(width / camera.width, height / camera.height))
    if scaled.width < width or scaled.height < height:  # cannot happen with round(); a guard on the arithmetic
        raise ValueError(f"fit_geometry: {scaled.width}x{scaled.height} does not cover {width}x{height}")
    return scaled, (scaled.width - width) // 2, (scaled.height - height) // 2


def fit_camera(camera, width: int, height: int):
    """``camera`` (``nsim.geometry.cameras.Camera``) for its image brought to exactly ``width x height``:
    scaled uniformly to cover it (``Camera.scaled``: ``f' = f s``, ``c' = (c + 0.5) s - 0.5``), then
    centre-cropped (``c'' = c' - (x0, y0)``). Exact for every model whose pixel is ``f x_d + c`` (pinhole,
    OpenCV, fisheye); an equirectangular camera cannot be cropped (its centre follows its size)."""
    scaled, x0, y0 = fit_geometry(camera, width, height)
    if (scaled.width, scaled.height) == (width, height):
        return scaled
    if camera.model == "EQUIRECTANGULAR":
        raise InputError(f"an equirectangular {camera.width}x{camera.height} camera cannot be cropped to "
                         f"{width}x{height} (its principal point follows its size)")
    from dataclasses import replace

    return replace(scaled, width=width, height=height, cx=scaled.cx - x0, cy=scaled.cy - y0)


def fit_image(image: np.ndarray, camera, fitted) -> np.ndarray:
    """``image (H, W, 3)`` uint8 of ``camera`` as the image of ``fitted = fit_camera(camera, w, h)``: resized to
    the scaled size (``cv2.INTER_AREA`` when shrinking, bilinear when enlarging; both keep pixel centres
    where ``Camera.scaled`` puts them), then the centred crop."""
    scaled, x0, y0 = fit_geometry(camera, fitted.width, fitted.height)
    if scaled.width > camera.width:
        import cv2

        image = cv2.resize(image, (scaled.width, scaled.height), interpolation=cv2.INTER_LINEAR)
    else:
        image = resize_image(image, scaled.width, scaled.height)
    return np.ascontiguousarray(image[y0:y0 + fitted.height, x0:x0 + fitted.width])


def valid_pixels(camera) -> np.ndarray | None:
    """``(H, W)`` bool: the pixels whose unprojected ray projects back onto them (within ``1e-3`` px): not a
    fisheye's corners past its model's reach (unprojected to the largest angle it can), nor a point
    where undistortion fails; None when every pixel is valid."""
    dirs = np.asarray(camera.pixel_dirs_cam())
    uv, ok = camera.project(np.where(np.isfinite(dirs), dirs, [0.0, 0.0, 1.0]))
    v, u = np.mgrid[0:camera.height, 0:camera.width]
    with np.errstate(invalid="ignore"):
        ok = np.asarray(ok) & np.isfinite(dirs).all(-1) & (np.hypot(uv[..., 0] - u, uv[..., 1] - v) < 1e-3)
    return None if ok.all() else ok


def recorded_masks(n_capture: int, camera_index: np.ndarray, cameras: list[Any]) -> np.ndarray | None:
    """``(N, H, W)`` bool masks for frames from ``n_capture`` on (recorded): :func:`valid_pixels` of their
    cameras, every capture pixel kept; None when every recorded pixel can be unprojected."""
    valid = {c: valid_pixels(cameras[c]) for c in sorted(set(np.asarray(camera_index[n_capture:]).tolist()))}
    if all(v is None for v in valid.values()):
        return None
    height, width = cameras[0].height, cameras[0].width
    masks = np.ones((len(camera_index), height, width), bool)
    for i in range(n_capture, len(camera_index)):
        if (v := valid[int(camera_index[i])]) is not None:
            masks[i] = v
    return masks


def resize_depth(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """z-depth ``(H, W)`` at ``(height, width)``: the nearest pixel centre (averaging would mix surfaces)."""
    if depth.shape[1] == width and depth.shape[0] == height:
        return depth
    import cv2

    return cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)


def read_depth_values(path: Path) -> np.ndarray:
    """The values a depth file stores, ``(H, W)`` float32 (not yet scaled by ``depth_unit_scale_factor``):
    channel ``Z`` of an EXR, a ``.npy`` array (read without pickles, its size checked before it is
    loaded), or any single-channel image OpenCV reads at its own bit depth (16-bit PNG, float TIFF).
    InputError names the file when it is none of these."""
    suffix = path.suffix.lower()
    if suffix == ".exr":
        from nsim.io.exr import read_depth_exr

        return read_depth_exr(path)
    if suffix == ".npy":
        try:
            values = np.load(path, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError) as e:
            raise InputError(f"{path}: not a readable .npy depth array ({e})") from None
        if values.ndim == 3 and values.shape[2] == 1:
            values = values[..., 0]
        if values.ndim != 2 or values.dtype.kind not in "uif" or values.size > MAX_DEPTH_PIXELS:
            raise InputError(f"{path}: expected an (H, W) numeric depth array of at most {MAX_DEPTH_PIXELS} "
                             f"values, got {values.dtype} {values.shape}")
        return np.asarray(values, dtype=np.float32)
    import cv2

    from nsim.io.images import _decode  # the same file checks as every image nsim reads

    values = _decode(path, cv2.IMREAD_UNCHANGED)
    if values.ndim == 3 and values.shape[2] == 1:
        values = values[..., 0]
    if values.ndim != 2 or values.dtype.kind not in "uf":
        raise InputError(f"{path}: expected a single-channel depth image (16-bit PNG, float TIFF), "
                         f"got {values.dtype} with shape {values.shape}")
    return values.astype(np.float32)


def scaled_depth(values: np.ndarray, scale: float) -> np.ndarray:
    """Depth ``(H, W)`` float32 in the poses' units from stored ``values`` and ``depth_unit_scale_factor``:
    ``values x scale`` (in float64, then rounded once), with a stored 0 or less meaning no depth (NaN);
    non-finite values (an EXR's inf, no hit) stay as they are."""
    depth = (np.asarray(values, dtype=np.float64) * scale).astype(np.float32)
    depth[values <= 0] = np.nan
    return depth


def read_mask(path: Path) -> np.ndarray:
    """A nerfstudio mask ``(H, W)`` bool: True where the pixel is kept (nonzero; in an RGB mask, any channel)."""
    import cv2

    from nsim.io.images import _decode

    mask = _decode(path, cv2.IMREAD_UNCHANGED)
    if mask.ndim == 3 and mask.shape[2] in (1, 3):
        return (mask != 0).any(-1)
    if mask.ndim != 2:
        raise InputError(f"{path}: expected a single-channel (or RGB) mask, got shape {mask.shape}")
    return mask != 0


def resize_mask(mask: np.ndarray, image_wh: tuple[int, int], width: int, height: int) -> np.ndarray:
    """``mask (h, w)`` bool of an image of size ``image_wh`` as the mask of that image shrunk to
    ``(height, width)``: first brought to the image's own size by nearest pixel (a mask of another
    size), then a training pixel is kept only when every image pixel it averages
    (``cv2.INTER_AREA``, as :func:`resize_image`) is kept, so that no ignored pixel's colour leaks
    into a training pixel."""
    import cv2

    mask = np.ascontiguousarray(mask, dtype=np.uint8)
    if (mask.shape[1], mask.shape[0]) != tuple(image_wh):
        mask = cv2.resize(mask, tuple(image_wh), interpolation=cv2.INTER_NEAREST_EXACT)
    if (mask.shape[1], mask.shape[0]) == (width, height):
        return mask.astype(bool)
    covered = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return covered >= 1.0 - 1e-5


def poses_scale(root: Path, extra: dict[str, Any]) -> tuple[str | None, bool]:
    """What the poses say about their scale: (source, metric). transforms.json's ``nsim_metric`` when it
    is there; else the source (``report.json``'s ``scale.source``, else transforms.json's ``nsim_scale``)
    is metric unless it is ``arbitrary``; no word at all: metric (a capture's ground truth)."""
    source = extra.get("nsim_scale") if isinstance(extra.get("nsim_scale"), str) else None
    report = root / "report.json"
    if report.is_file():
        try:
            found = json.loads(report.read_text()).get("scale", {}).get("source")
        except (json.JSONDecodeError, AttributeError, OSError):
            raise InputError(f"{report}: not the JSON object nsim reconstruct writes") from None
        if isinstance(found, str):
            source = found
    declared = extra.get("nsim_metric")
    if isinstance(declared, bool):
        return source, declared
    return source, source != "arbitrary"


@dataclass(eq=False)
class SceneData:
    """Frames of one capture, in memory at the training resolution.

    images: (N, H, W, 3) uint8; cam_to_world: (N, 4, 4) float64 OpenCV axes; cameras: the distinct
    intrinsics at the training resolution, camera_index: (N,) which one each frame uses (all the same
    size); full_cameras: the same intrinsics at the images' own resolution; image_paths: the image
    files (for scoring at another resolution); depth_paths: per frame the z-depth file or None, whose
    values x depth_unit_scale are in the poses' units; points_xyz: (P, 3) sparse points or None.
    max_image_side: what the images were shrunk to (0: not). masks: (N, H, W) bool at the training
    resolution, True where a pixel may train (None: no frame has a mask: every pixel);
    mask_paths: per frame the mask file or None. scale_source: what the poses artifact says about
    its scale (None: nothing); metric: whether lengths are metres. digest: of the original images,
    poses and intrinsics, and of the masks when there are any (not of the shrinking).
    n_capture: None, or the first ``n_capture`` frames are the capture's and the rest a robot's recorded
    frames (:meth:`with_recorded_frames`: training frames all, at the capture's training size).
    """

    root: Path
    names: list[str]
    images: np.ndarray
    cam_to_world: np.ndarray
    cameras: list[Any]
    camera_index: np.ndarray
    depth_paths: list[Path | None]
    points_xyz: np.ndarray | None = None
    digest: str = ""
    full_cameras: list[Any] | None = None
    image_paths: list[Path] | None = None
    max_image_side: int = 0
    scale_source: str | None = None
    metric: bool = True
    depth_unit_scale: float = 1.0
    masks: np.ndarray | None = None
    mask_paths: list[Path | None] | None = None
    n_capture: int | None = None

    @classmethod
    def load(cls, root: str | os.PathLike, points_file: str | None = None, max_image_side: int = 0,
             scale: str = "auto") -> SceneData:
        """Read ``root/transforms.json`` and its images (shrunk to ``max_image_side``, 0: as they are);
        ``scale`` as ``DataConfig.scale``. InputError names the file on problems."""
        from nsim.io.images import read_image
        from nsim.io.transforms_json import depth_unit_scale, read_transforms

        root = Path(root)
        data = read_transforms(root / "transforms.json")
        if not data.frames:
            raise InputError(f"{root / 'transforms.json'}: frames: no frames")
        depth_files = [f.depth_file_path for f in data.frames if f.depth_file_path]
        depth_scale = depth_unit_scale(root / "transforms.json", data, depth_files) if depth_files else 1.0
        mask_paths = [root / f.mask_path if f.mask_path else None for f in data.frames]
        masks = None
        full_cameras, camera_index, names, depth_paths, paths = [], [], [], [], []
        size = (data.frames[0].camera.width, data.frames[0].camera.height)
        h = hashlib.sha256()
        images = None
        for i, frame in enumerate(data.frames):
            cam = frame.camera
            if (cam.width, cam.height) != size:
                raise InputError(f"{root / 'transforms.json'}: frames[{i}]: image size {cam.width}x{cam.height} "
                                 f"differs from frames[0] ({size[0]}x{size[1]}); mixed sizes are not supported")
            if cam not in full_cameras:
                full_cameras.append(cam)
            camera_index.append(full_cameras.index(cam))
            img = read_image(root / frame.file_path)
            if img.shape[:2] != (cam.height, cam.width):
                raise InputError(f"{root / frame.file_path}: image is {img.shape[1]}x{img.shape[0]}, "
                                 f"transforms.json says {cam.width}x{cam.height}")
            h.update(img.tobytes())
            h.update(np.ascontiguousarray(frame.cam_to_world).tobytes())
            h.update(json.dumps(cam.to_dict(), sort_keys=True).encode())
            small = camera_at(cam, max_image_side)
            if images is None:  # one array for all frames, filled as they are read: no list + stack copy
                images = np.empty((len(data.frames), small.height, small.width, 3), np.uint8)
            images[i] = resize_image(img, small.width, small.height)
            del img
            if mask_paths[i] is not None:
                if masks is None:
                    masks = np.ones((len(data.frames), small.height, small.width), bool)
                mask = read_mask(mask_paths[i])
                h.update(np.packbits(mask).tobytes() + repr(mask.shape).encode())
                masks[i] = resize_mask(mask, (cam.width, cam.height), small.width, small.height)
            names.append(frame.file_path)
            paths.append(root / frame.file_path)
            depth_paths.append(root / frame.depth_file_path if frame.depth_file_path else None)
        points = None
        candidates = [points_file] if points_file else list(POINT_FILES)
        for name in candidates:
            if (root / name).is_file():
                from nsim.io.ply import read_ply

                points = np.asarray(read_ply(root / name).xyz, dtype=np.float64)
                h.update(points.tobytes())
                break
        source, metric = poses_scale(root, data.extra)
        if scale != "auto":
            metric = scale == "metric"
        return cls(root, names, images, np.stack([f.cam_to_world for f in data.frames]),
                   [camera_at(c, max_image_side) for c in full_cameras], np.asarray(camera_index), depth_paths,
                   points, h.hexdigest(), full_cameras=full_cameras, image_paths=paths, max_image_side=max_image_side,
                   scale_source=source, metric=metric, depth_unit_scale=depth_scale, masks=masks,
                   mask_paths=mask_paths)

    @property
    def n_frames(self) -> int:
        return len(self.names)

    @property
    def size_hw(self) -> tuple[int, int]:
        """The training images' (height, width)."""
        return self.images.shape[1], self.images.shape[2]

    @property
    def full_size_hw(self) -> tuple[int, int]:
        """The images' own (height, width), as captured."""
        cam = (self.full_cameras or self.cameras)[0]
        return cam.height, cam.width

    def with_max_image_side(self, max_image_side: int) -> SceneData:
        """This data with the images shrunk to ``max_image_side`` from the originals (itself when they already are).
        Recorded frames are fitted to the capture's new training size (:func:`fit_camera`)."""
        full = self.full_cameras or self.cameras
        cameras = self._cameras_at(max_image_side)
        if cameras == self.cameras:
            return self
        if self.image_paths is None:
            raise ValueError("SceneData without image_paths cannot be resized")
        from nsim.io.images import read_image

        width, height = cameras[0].width, cameras[0].height
        images = np.empty((self.n_frames, height, width, 3), np.uint8)
        for i, path in enumerate(self.image_paths):
            c = int(self.camera_index[i])
            if self._is_capture(i):
                images[i] = resize_image(read_image(path), width, height)
            else:
                images[i] = fit_image(read_image(path), full[c], cameras[c])
        masks = None if self.n_capture is None else recorded_masks(self.n_capture, self.camera_index, cameras)
        if self.masks is not None:
            masks = np.ones((self.n_frames, height, width), bool) if masks is None else masks
            for i, path in enumerate(self.mask_paths or []):
                if path is not None:
                    masks[i] = resize_mask(read_mask(path), (full[0].width, full[0].height), width, height)
        from dataclasses import replace

        return replace(self, images=images, cameras=cameras, full_cameras=full, max_image_side=max_image_side,
                       masks=masks)

    def _is_capture(self, i: int) -> bool:
        return self.n_capture is None or i < self.n_capture

    def _cameras_at(self, max_image_side: int) -> list[Any]:
        """The training cameras for ``max_image_side``: the capture's shrunk (:func:`camera_at`), a recording's
        fitted to the capture's training size (:func:`fit_camera`)."""
        full = self.full_cameras or self.cameras
        n = len(full) if self.n_capture is None else int(self.camera_index[: self.n_capture].max()) + 1
        capture = [camera_at(c, max_image_side) for c in full[:n]]
        return capture + [fit_camera(c, capture[0].width, capture[0].height) for c in full[n:]]

    def with_recorded_frames(self, frames: list[RecordedFrame]) -> SceneData:
        """This data with a robot's recorded ``frames`` appended as training frames (``n_capture`` set).

        Each image is read (its size checked against its camera) and fitted to the capture's training
        size (:func:`fit_camera`, :func:`fit_image`); its camera is one of ``full_cameras`` as recorded,
        fitted in ``cameras``. Pixels the fitted model cannot unproject are masked. The digest adds
        each frame's image, pose and camera. InputError names an image that does not match."""
        from dataclasses import replace

        from nsim.io.images import read_image

        if self.n_capture is not None:
            raise ValueError("SceneData already holds recorded frames")
        if not frames:
            return self
        n, m = self.n_frames, len(frames)
        height, width = self.size_hw
        full, cameras = list(self.full_cameras or self.cameras), list(self.cameras)
        n_cams = len(full)
        camera_index = list(self.camera_index)
        images = np.empty((n + m, height, width, 3), np.uint8)
        images[:n] = self.images
        h = hashlib.sha256(self.digest.encode())
        for k, f in enumerate(frames):
            if f.camera not in full[n_cams:]:  # a recorded camera never shares a capture camera's fit
                full.append(f.camera)
                cameras.append(fit_camera(f.camera, width, height))
            c = n_cams + full[n_cams:].index(f.camera)
            camera_index.append(c)
            img = read_image(f.path)
            if img.shape[:2] != (f.camera.height, f.camera.width):
                raise InputError(f"{f.path}: image is {img.shape[1]}x{img.shape[0]}, its camera "
                                 f"{f.camera_name!r} is {f.camera.width}x{f.camera.height}")
            h.update(img.tobytes())
            h.update(np.ascontiguousarray(f.cam_to_world, dtype=np.float64).tobytes())
            h.update(json.dumps(f.camera.to_dict(), sort_keys=True).encode())
            images[n + k] = fit_image(img, f.camera, cameras[c])
        camera_index = np.asarray(camera_index)
        masks = recorded_masks(n, camera_index, cameras)
        if self.masks is not None:
            masks = np.ones((n + m, height, width), bool) if masks is None else masks
            masks[:n] = self.masks
        return replace(self, names=[*self.names, *(f.name for f in frames)], images=images,
                       cam_to_world=np.concatenate([self.cam_to_world, np.stack([f.cam_to_world for f in frames])]),
                       cameras=cameras, camera_index=camera_index, depth_paths=[*self.depth_paths, *[None] * m],
                       digest=h.hexdigest(), full_cameras=full,
                       image_paths=[*(self.image_paths or []), *(f.path for f in frames)], masks=masks,
                       mask_paths=[*(self.mask_paths or [None] * n), *[None] * m], n_capture=n)

    def split(self, holdout_every: int) -> tuple[np.ndarray, np.ndarray]:
        """(train indices, held-out indices): capture frame i is held out when ``i % holdout_every == 0``;
        recorded frames (``n_capture`` on) always train."""
        n = self.n_frames if self.n_capture is None else self.n_capture
        idx = np.arange(n)
        recorded = np.arange(n, self.n_frames)
        if holdout_every <= 0:
            return np.concatenate([idx, recorded]), idx[:0]
        held = holdout_mask(self.root, n, holdout_every)
        return np.concatenate([idx[~held], recorded]), idx[held]

    def read_depth_z(self, i: int) -> np.ndarray | None:
        """Frame i's z-depth ``(h, w)`` float32 in the poses' units (stored value x ``depth_unit_scale``; NaN
        where it stores 0, no depth) at the depth file's own resolution, or None when the frame has none.
        (nsim's captures write their depth at the images' resolution; PolyCam's and Record3D's is smaller.)"""
        if self.depth_paths[i] is None:
            return None
        return scaled_depth(read_depth_values(self.depth_paths[i]), self.depth_unit_scale)

    def train_depth_z(self, frames) -> np.ndarray | None:
        """The z-depth of ``frames`` (indices) at the training resolution, for depth supervision:
        ``(N, H, W)`` float16 over all N frames (nearest pixel), 0 where there is no depth (no file, a
        frame not in ``frames``, a stored 0, non-finite, or beyond float16's range). None when none of
        ``frames`` has a depth pixel."""
        height, width = self.size_hw
        out = None
        for i in frames:
            depth = self.read_depth_z(int(i))
            if depth is None:
                continue
            depth = resize_depth(depth, width, height)
            with np.errstate(invalid="ignore", over="ignore"):
                z = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float16)
            z[~np.isfinite(z)] = 0.0  # beyond float16's 65504
            if out is None:
                out = np.zeros((self.n_frames, height, width), np.float16)
            out[int(i)] = z
        return None if out is None or not out.any() else out

    # ------------------------------------------------------------------ scoring at any resolution
    def eval_camera(self, i: int, image_side: int):
        """Frame ``i``'s intrinsics for scoring with the longer side at most ``image_side`` px (0: as captured)."""
        return camera_at((self.full_cameras or self.cameras)[self.camera_index[i]], image_side)

    def eval_image(self, i: int, camera) -> np.ndarray:
        """Frame ``i``'s image (H, W, 3) uint8 at ``camera``'s size: the training copy when that is the
        size, else the file read again and shrunk (``cv2.INTER_AREA``)."""
        if (camera.height, camera.width) == self.size_hw and (self._is_capture(i) or
                                                               camera == self.cameras[self.camera_index[i]]):
            return self.images[i]  # (a recorded frame's training copy is cropped: only for its own camera)
        if self.image_paths is None:
            raise ValueError("SceneData without image_paths has images at one size only")
        from nsim.io.images import read_image

        return resize_image(read_image(self.image_paths[i]), camera.width, camera.height)

    def eval_depth_z(self, i: int, camera) -> np.ndarray | None:
        """Frame ``i``'s ground-truth z-depth at ``camera``'s size (nearest pixel centre), or None."""
        depth = self.read_depth_z(i)
        return None if depth is None else resize_depth(depth, camera.width, camera.height)


def holdout_mask(root, n: int, holdout_every: int) -> np.ndarray:
    """``(n,)`` bool: capture frame ``i`` is held out when ``i % holdout_every == 0`` (0: none); InputError
    naming ``root`` when that leaves no training frame."""
    held = np.zeros(n, bool) if holdout_every <= 0 else np.arange(n) % holdout_every == 0
    if held.all():
        raise InputError(f"{root}: holding out every {holdout_every}th frame leaves no training frames")
    return held


def check_training_inputs(root: str | os.PathLike, cfg, device_kind: str):
    """Every check of ``nsim train-scene`` that ``root/transforms.json``, the files' presence and ``cfg`` (a
    ``TrainSceneConfig``) decide, before any image is read: frames, the hold-out, the training and scoring sizes
    (``data.max_image_side``, ``eval.image_side``), the scene box (``data.bounds``), the depth losses' inputs
    and the hash backend on ``device_kind`` (``cpu`` / ``cuda``). Returns the transforms
    (``nsim.io.transforms_json.TransformsData``). InputError (one line) on a problem."""
    import importlib.util

    from nsim.io.transforms_json import read_transforms

    root = Path(root)
    where = root / "transforms.json"
    data = read_transforms(where)
    if not data.frames:
        raise InputError(f"{where}: frames: no frames")
    size = (data.frames[0].camera.width, data.frames[0].camera.height)
    for i, frame in enumerate(data.frames):
        if (frame.camera.width, frame.camera.height) != size:
            raise InputError(f"{where}: frames[{i}]: image size {frame.camera.width}x{frame.camera.height} "
                             f"differs from frames[0] ({size[0]}x{size[1]}); mixed sizes are not supported")
    held = holdout_mask(root, len(data.frames), cfg.data.holdout_every)
    for setting, side in (("data.max_image_side", cfg.data.max_image_side), ("eval.image_side", cfg.eval.image_side)):
        for cam in {(f.camera.width, f.camera.height): f.camera for f in data.frames}.values():
            try:
                camera_at(cam, side)
            except ValueError:
                raise InputError(f"{setting}: {side} px shrinks the {cam.width}x{cam.height} images to nothing; "
                                 "set it larger (0: as captured)") from None
    d = cfg.data
    has_points = any((root / name).is_file() for name in POINT_FILES)
    if d.bounds == "fixed":
        fixed_box(d)
    elif d.bounds == "points" and not has_points:
        raise InputError(f"{root}: data.bounds is 'points' but there is no sparse point cloud ({', '.join(POINT_FILES)})")
    if cfg.loss.depth_weight > 0 and not has_points:
        raise InputError(f"{root}: loss.depth_weight > 0 needs a sparse point cloud ({', '.join(POINT_FILES)})")
    if cfg.loss.image_depth_weight > 0 and not any(f.depth_file_path for f, h in zip(data.frames, held, strict=True)
                                                    if not h):
        raise InputError(f"{root}: loss.image_depth_weight > 0 but no training frame has a depth image "
                         "(depth_file_path)")
    if cfg.field.backend == "tcnn":
        if device_kind != "cuda":
            raise InputError("field.backend: tcnn (tiny-cuda-nn) runs on CUDA only; use --device cuda, or "
                             "field.backend=auto or torch")
        if importlib.util.find_spec("tinycudann") is None:
            raise InputError("field.backend: tcnn, but tinycudann is not installed; use field.backend=auto or torch")
    return data


def fixed_box(cfg: DataConfig) -> tuple[np.ndarray, np.ndarray]:
    """``data.bounds: fixed``'s box ``(lo, hi)``; InputError when a corner is missing or the box is degenerate."""
    if cfg.aabb_min_m is None or cfg.aabb_max_m is None:
        raise InputError("data.bounds: 'fixed' needs data.aabb_min_m and data.aabb_max_m")
    lo, hi = np.asarray(cfg.aabb_min_m, float), np.asarray(cfg.aabb_max_m, float)
    if not np.all(hi - lo > 1e-3):
        raise InputError(f"data.bounds: degenerate scene box {lo.tolist()} .. {hi.tolist()}; "
                         "data.aabb_max_m must exceed data.aabb_min_m on every axis")
    return lo, hi


def scene_bounds(data: SceneData, cfg: DataConfig) -> np.ndarray:
    """The scene box ``(2, 3)`` in world units (metres for a metric scene; see :class:`DataConfig`).

    ``cfg`` holds the lengths to use: the trainer passes its config with the metre lengths already
    converted to scene units (``bounds_margin_m``), so this function never converts."""
    mode = cfg.bounds
    if mode == "auto":
        mode = "points" if data.points_xyz is not None and len(data.points_xyz) >= 8 else "cameras"
    if mode == "fixed":
        lo, hi = fixed_box(cfg)
    elif mode == "points":
        if data.points_xyz is None or len(data.points_xyz) < 8:
            raise InputError(f"{data.root}: data.bounds is 'points' but there is no sparse point cloud ({', '.join(POINT_FILES)})")
        lo, hi = np.percentile(data.points_xyz, 1, axis=0), np.percentile(data.points_xyz, 99, axis=0)
        centres = data.cam_to_world[:, :3, 3]
        lo, hi = np.minimum(lo, centres.min(0)), np.maximum(hi, centres.max(0))
        lo, hi = lo - cfg.bounds_margin_m, hi + cfg.bounds_margin_m
    else:
        centres = data.cam_to_world[:, :3, 3]
        lo, hi = centres.min(0) - cfg.bounds_margin_m, centres.max(0) + cfg.bounds_margin_m
    if not np.all(hi - lo > 1e-3):
        raise InputError(f"data.bounds: degenerate scene box {lo.tolist()} .. {hi.tolist()}; set data.bounds_margin_m > 0")
    return np.stack([lo, hi]).astype(np.float32)


def camera_to_point_median(centres: np.ndarray, points: np.ndarray) -> float:
    """Median distance from every camera centre ``(N, 3)`` to every point ``(P, 3)`` (at most
    ``MAX_SCALE_POINTS`` points, every k-th, so the answer is deterministic and the cost bounded)."""
    step = max(1, math.ceil(len(points) / MAX_SCALE_POINTS))
    pts = np.asarray(points, np.float64)[::step]
    d = np.linalg.norm(np.asarray(centres, np.float64)[:, None, :] - pts[None, :, :], axis=-1)
    return float(np.median(d))


def camera_spread(centres: np.ndarray) -> float:
    """RMS distance of the camera centres ``(N, 3)`` from their mean."""
    c = np.asarray(centres, np.float64)
    return float(np.sqrt(np.mean(np.sum((c - c.mean(0)) ** 2, axis=-1))))


def units_per_metre(data: SceneData) -> tuple[float, str]:
    """How many of the scene's units a metre is, and how that was found.

    Metric scenes: 1. Arbitrary-scale scenes: a guess from the scene's size against a room
    capture's -- the median camera-to-sparse-point distance over ``ROOM_CAMERA_TO_POINT_M`` when the
    scene has sparse points (the depth at which the capture saw things), else the camera centres'
    RMS spread over ``ROOM_CAMERA_SPREAD_M``. Right within a factor of two or so for a room walked
    through with a phone; it only sizes the trainer's lengths (near plane, box margin, cells), never
    turns the scene into metres.
    """
    if data.metric:
        return 1.0, "metric poses"
    centres = data.cam_to_world[:, :3, 3]
    if data.points_xyz is not None and len(data.points_xyz) >= 8:
        d = camera_to_point_median(centres, data.points_xyz)
        if d > 0 and math.isfinite(d):
            return d / ROOM_CAMERA_TO_POINT_M, (f"median camera-to-sparse-point distance {d:.6g} units / "
                                                f"{ROOM_CAMERA_TO_POINT_M} m (a room capture's)")
    spread = camera_spread(centres)
    if spread > 0 and math.isfinite(spread):
        return spread / ROOM_CAMERA_SPREAD_M, (f"RMS camera spread {spread:.6g} units / "
                                               f"{ROOM_CAMERA_SPREAD_M} m (a room capture's)")
    log.warning("%s: arbitrary scale and nothing to size the scene by (one camera position, no points): "
                "taking 1 unit per metre", data.root)
    return 1.0, "nothing to measure: 1 unit per metre assumed"


def image_mean_rgb(data: SceneData, train_ids) -> list[float]:
    """The mean colour of the training images' pixels, in [0, 1] (float64 sums, in a fixed order):
    the least-squares guess for a pixel the capture never showed (``nsim render``'s ``fill``)."""
    return [float(c) for c in data.images[np.asarray(train_ids)].reshape(-1, 3).mean(0, dtype=np.float64) / 255.0]


# ====================================================================== a robot's recorded frames
@dataclass(frozen=True, eq=False)
class RecordedFrame:
    """One camera frame of a registered recording: ``camera_name``; ``position`` among its camera's recorded
    frames (0-based); ``index`` in its topic (its file ``camera/<name>/NNNNNN.png``); ``stamp_ns`` on the
    cameras' clock; ``camera`` as recorded (CameraInfo); ``cam_to_world (4, 4)`` OpenCV axes, the scene's
    world; ``path`` the image file; ``name`` what ``SceneData.names`` calls it."""

    camera_name: str
    position: int
    index: int
    stamp_ns: int
    camera: Any
    cam_to_world: np.ndarray
    path: Path
    name: str


@dataclass(frozen=True, eq=False)
class RecordedFrames:
    """A registered recording's camera frames inside its registered trajectory (``frames``, camera by camera
    in the order given, each camera's in recorded order), and per camera how many it recorded and how
    many lay outside the trajectory's span (dropped: no pose without extrapolating)."""

    frames: tuple[RecordedFrame, ...]
    recorded: dict[str, int]
    outside: dict[str, int]


@dataclass(frozen=True)
class RecordedSplit:
    """Indices into ``RecordedFrames.frames``: ``train`` and ``held_out``; ``wanted``: the robot frames the
    share asked for before capping at the candidates."""

    train: tuple[int, ...]
    held_out: tuple[int, ...]
    wanted: int


def read_recorded_frames(registration_dir: str | os.PathLike, recording_dir: str | os.PathLike,
                         cameras: tuple[str, ...] = (), label: str = "recording") -> RecordedFrames:
    """The colour camera frames of the recording in ``recording_dir`` (``nsim import-log``) placed in the
    scene's world by the registration in ``registration_dir`` (``nsim register-log``).

    A frame stamped ``s`` on the cameras' clock was captured at odometry time ``s - clock_offset_s``
    (``nsim.rendering.recording.odometry_time_ns``); its pose is ``body_to_world`` interpolated there
    times the camera's ``sensor_to_body`` (``nsim.rendering.recording.sensor_poses``). ``cameras``: the
    camera names (empty: every camera stream). Reads no image but each camera's first (grey or 16-bit
    frames cannot train a colour field). ``label`` names the artifacts in errors. InputError on problems.
    """
    import cv2

    from nsim.geometry.cameras import Camera
    from nsim.rendering.recording import odometry_time_ns, read_registration

    reg_dir, rec_dir = Path(registration_dir), Path(recording_dir)
    registered = read_registration(reg_dir, label)
    streams = {k.split("/", 1)[1]: v for k, v in json.loads((rec_dir / "recording.json").read_text())["streams"].items()
               if v.get("kind") == "camera"}
    if len(set(cameras)) < len(cameras):
        raise InputError(f"{label}: cameras {list(cameras)} names a camera twice")
    if unknown := [c for c in cameras if c not in streams]:
        raise InputError(f"{label}: no camera {', '.join(map(repr, unknown))} in the recording (it has: "
                         f"{', '.join(sorted(streams)) or 'none'})")
    frames, recorded, outside = [], {}, {}
    for name in cameras or tuple(sorted(streams)):
        entry = streams[name]
        try:
            camera = Camera.from_dict(entry["camera"])
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{label}: camera {name!r}: no usable camera model ({e})") from None
        stamps = np.load(rec_dir / entry["dir"] / "stamps_ns.npy", allow_pickle=False)
        indices = np.asarray(entry["frames"], dtype=np.int64)
        if stamps.shape != indices.shape:
            raise InputError(f"{label}: camera {name!r}: {len(stamps)} stamps for {len(indices)} frames")
        paths = [rec_dir / entry["dir"] / f"{i:06d}.png" for i in indices]
        if paths:
            first = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
            if first is None:
                raise InputError(f"{paths[0]}: not a readable image")
            if first.ndim != 3 or first.dtype != np.uint8:
                raise InputError(f"{label}: camera {name!r} records {'grey' if first.ndim == 2 else first.dtype} "
                                 "images; a scene trains on colour (choose colour cameras with --recording-camera)")
        odom = odometry_time_ns(stamps, registered.clock_offset_s, on_camera_clock=True)
        inside, _, cam_to_world = registered.sensor_poses(odom, np.asarray(entry["sensor_to_body"], dtype=np.float64))
        recorded[name], outside[name] = len(indices), int((~inside).sum())
        frames += [RecordedFrame(name, int(j), int(indices[j]), int(stamps[j]), camera, cam_to_world[j], paths[j],
                                 f"recording:{entry['dir']}/{int(indices[j]):06d}.png")
                   for j in np.flatnonzero(inside)]
    return RecordedFrames(tuple(frames), recorded, outside)


def split_recorded_frames(recorded: RecordedFrames, capture_train: int, cfg: RecordingConfig) -> RecordedSplit:
    """Which recorded frames train and which are held out (``SHARE_MEANING``, ``HELDOUT_MEANING``), with
    ``capture_train`` capture frames in training. A function of its arguments alone."""
    frames = recorded.frames
    held = tuple(k for k, f in enumerate(frames) if f.position % cfg.holdout_every == 0)
    candidates: dict[str, list[int]] = {}
    for k, f in enumerate(frames):
        if f.position % cfg.holdout_every:
            candidates.setdefault(f.camera_name, []).append(k)
    total = sum(len(c) for c in candidates.values())
    wanted = round(cfg.share / (1.0 - cfg.share) * capture_train)
    n = min(wanted, total)
    # per camera: its proportional quota, the leftover frames to the largest remainders (ties: camera order)
    quota = {c: n * len(ks) / total for c, ks in candidates.items()} if total else {}
    count = {c: math.floor(q) for c, q in quota.items()}
    for c in sorted(quota, key=lambda c: -(quota[c] - count[c]))[: n - sum(count.values())]:
        count[c] += 1
    train = []
    for c, ks in candidates.items():  # evenly spaced, centred: the k-th of n_c at floor((k + 0.5) m / n_c)
        train += [ks[int((k + 0.5) * len(ks) / count[c])] for k in range(count[c])]
    return RecordedSplit(tuple(sorted(train)), held, wanted)


def recording_record(recorded: RecordedFrames, split: RecordedSplit, cfg: RecordingConfig, capture_train: int,
                     first_image: int, registration: str, recording: str) -> dict[str, Any]:
    """What ``scene.json`` says about the robot frames (its ``recording`` key): the artifacts, the rule
    (share, hold-out), per camera the counts, the frames that trained (``image``: their index in
    ``images`` and the appearance embeddings) and the held-out frames to score on."""
    from nsim.config import to_dict

    frames = recorded.frames
    n = len(split.train)

    def rows(ids, with_image: bool) -> list[dict[str, Any]]:
        return [{"camera": frames[k].camera_name, "index": frames[k].index, "stamp_ns": frames[k].stamp_ns,
                 **({"image": first_image + j} if with_image else {})} for j, k in enumerate(ids)]

    per_camera = {c: {"recorded": recorded.recorded[c], "outside_trajectory": recorded.outside[c],
                      "held_out": sum(frames[k].camera_name == c for k in split.held_out),
                      "train": sum(frames[k].camera_name == c for k in split.train)} for c in recorded.recorded}
    return {
        "registration": registration, "recording": recording,
        "options": to_dict(cfg), "share_meaning": SHARE_MEANING, "held_out_meaning": HELDOUT_MEANING,
        "share_trained": n / (capture_train + n) if capture_train + n else 0.0,
        "capture_train_frames": capture_train, "robot_train_frames": n, "robot_frames_wanted": split.wanted,
        "cameras": per_camera,
        "fit": "each robot frame scaled uniformly to cover the capture's training size, then centre-cropped "
               "(nsim.train.scene_data.fit_camera)",
        "train": rows(split.train, True),
        "held_out": rows(split.held_out, False),
    }

