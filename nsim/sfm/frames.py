"""Input frames for SfM: sharp, distinct frames from a video, or the images of a folder.

Video frames are chosen in two decoding passes, so memory stays small for long videos:

1. every frame is decoded once to measure its *sharpness* (variance of the Laplacian of a
   grey copy at most ``ANALYSIS_WIDTH`` pixels wide) and keep a tiny grey thumbnail;
2. the frame range is cut into ``n_frames`` equal spans; in each span the sharpest frame
   that is not blurred wins. A frame is *blurred* when its sharpness is below
   ``blur_ratio`` times the video's median sharpness (a per-video threshold: sharpness
   depends on the scene and resolution, so no absolute value works across videos). A winner
   whose thumbnail differs from the previously kept frame by less than
   ``dedup_threshold`` (mean absolute difference, grey levels in [0, 1]) is a near-duplicate
   (a camera standing still) and is dropped. The winners are then decoded again in full.

Timestamps are ``frame index / fps`` (the container's nominal rate), which is what a capture
artifact's TUM trajectory and transforms.json use; when the container reports no rate the
decoder's position is used instead. Selected frames are named ``frame_{index:05d}.png`` after
their index in the video, so a reference whose frames are named the same way (as a capture
artifact's are) can be matched by file name.
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from nsim.errors import InputError
from nsim.io.images import read_image, write_image

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v")
MIN_IMAGES = 3
#: Sharpness and thumbnails are computed on a grey copy at most this wide (resolution-independent-ish).
ANALYSIS_WIDTH = 320
THUMB_SIZE = (32, 24)

#: (phase, done, total) progress callback.
ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True, eq=False)
class SelectedFrame:
    """One input image.

    index: frame index in the video (position in sorted order for a folder);
    timestamp_s: seconds from the start of the video, None for a folder;
    image: (H, W, 3) uint8 RGB; sharpness: variance of the Laplacian (see module docstring);
    name: PNG file name the frame is (or will be) stored under.
    """

    index: int
    timestamp_s: float | None
    image: np.ndarray
    sharpness: float
    name: str


def sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of a grey copy of ``image`` ((H, W, 3) or (H, W) uint8).

    Images wider than ``ANALYSIS_WIDTH`` are downscaled first (area filter) so the value
    compares frames of one video rather than measuring the sensor's resolution.
    """
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if grey.shape[1] > ANALYSIS_WIDTH:
        h = max(1, round(grey.shape[0] * ANALYSIS_WIDTH / grey.shape[1]))
        grey = cv2.resize(grey, (ANALYSIS_WIDTH, h), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey.astype(np.float32) / 255.0, cv2.CV_32F).var())


def _thumbnail(image: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return cv2.resize(grey, THUMB_SIZE, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0


def _open_video(path: Path) -> cv2.VideoCapture:
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a video file")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise InputError(f"{path}: cannot open as a video (unreadable, corrupt or unsupported format)")
    return cap


def _read_rgb(cap: cv2.VideoCapture) -> np.ndarray | None:
    ok, bgr = cap.read()
    if not ok or bgr is None or bgr.size == 0:
        return None
    if bgr.ndim == 2:
        return cv2.cvtColor(bgr, cv2.COLOR_GRAY2RGB)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def choose_frames(
    sharpness_values: np.ndarray,
    thumbnails: np.ndarray,
    n_frames: int,
    blur_ratio: float = 0.4,
    dedup_threshold: float = 0.01,
) -> np.ndarray:
    """Indices (sorted, int64) of the frames to keep; the rule is in the module docstring.

    sharpness_values: (N,) float; thumbnails: (N, h, w) float in [0, 1].
    """
    sharp = np.asarray(sharpness_values, dtype=np.float64)
    n = len(sharp)
    if n == 0 or n_frames < 1:
        return np.zeros(0, dtype=np.int64)
    threshold = blur_ratio * float(np.median(sharp))
    edges = np.linspace(0, n, min(n_frames, n) + 1)
    kept: list[int] = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        span = np.arange(int(np.ceil(lo)), int(np.ceil(hi)))
        span = span[sharp[span] >= threshold]
        if span.size == 0:
            continue  # the whole span is blurred
        best = int(span[np.argmax(sharp[span])])  # first maximum: deterministic
        if kept and float(np.abs(thumbnails[best] - thumbnails[kept[-1]]).mean()) < dedup_threshold:
            continue
        kept.append(best)
    return np.asarray(kept, dtype=np.int64)


def select_video_frames(
    video_path: str | os.PathLike,
    n_frames: int,
    blur_ratio: float = 0.4,
    dedup_threshold: float = 0.01,
    progress: ProgressFn | None = None,
) -> list[SelectedFrame]:
    """About ``n_frames`` sharp, distinct frames spread over the video, in time order.

    Fewer come back when spans are entirely blurred or duplicates. Raises InputError naming
    the file when it cannot be opened or decoded, has no frames, or yields fewer than 3 frames.
    """
    path = Path(video_path)
    if n_frames < MIN_IMAGES:
        raise ValueError(f"n_frames: need at least {MIN_IMAGES}, got {n_frames}")
    cap = _open_video(path)
    fps = cap.get(cv2.CAP_PROP_FPS)
    fps = fps if np.isfinite(fps) and 0.0 < fps < 10_000.0 else None
    total_hint = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    sharp, thumbs, times, shape = [], [], [], None
    try:
        while True:
            pos_ms = cap.get(cv2.CAP_PROP_POS_MSEC)
            rgb = _read_rgb(cap)
            if rgb is None:
                break
            if shape is None:
                shape = rgb.shape
            elif rgb.shape != shape:
                raise InputError(f"{path}: frame {len(sharp)} is {rgb.shape[1]}x{rgb.shape[0]}, "
                                 f"earlier frames are {shape[1]}x{shape[0]}")
            sharp.append(sharpness(rgb))
            thumbs.append(_thumbnail(rgb))
            times.append(len(times) / fps if fps else pos_ms / 1000.0)
            if progress is not None:
                progress("frames", len(sharp), max(total_hint, len(sharp)))
    finally:
        cap.release()
    if not sharp:
        raise InputError(f"{path}: no frames could be decoded (empty or corrupt video)")
    keep = choose_frames(np.array(sharp), np.stack(thumbs), n_frames, blur_ratio, dedup_threshold)
    log.info("%s: %d frames decoded, %d selected (median sharpness %.3g)", path, len(sharp), len(keep),
             float(np.median(sharp)))
    if len(keep) < MIN_IMAGES:
        raise InputError(f"{path}: only {len(keep)} usable frames (of {len(sharp)}) after dropping blurred "
                         f"and duplicate frames; need at least {MIN_IMAGES}: record a longer or steadier video")
    # Second pass: decode again and keep the winners.
    wanted = set(keep.tolist())
    frames: list[SelectedFrame] = []
    cap = _open_video(path)
    try:
        for index in range(int(keep[-1]) + 1):
            if index in wanted:
                rgb = _read_rgb(cap)
                if rgb is None:
                    break
                frames.append(SelectedFrame(index, float(times[index]), rgb, float(sharp[index]),
                                            f"frame_{index:05d}.png"))
            elif not cap.grab():
                break
    finally:
        cap.release()
    if len(frames) != len(keep):
        raise InputError(f"{path}: decoding stopped early on the second pass (frame {len(frames)} of "
                         f"{len(keep)} selected); the file may be corrupt")
    return frames


def _natural_key(name: str) -> list:
    return [int(tok) if tok.isdigit() else tok.lower() for tok in re.split(r"(\d+)", name)]


def list_image_files(image_dir: str | os.PathLike) -> list[Path]:
    """JPG/JPEG/PNG files directly in ``image_dir`` (case-insensitive suffix), sorted by name.

    Plain (code point) name order, the order COLMAP's sequential matcher walks the images in:
    number files with zero padding (``img_0002`` before ``img_0010``). A warning is logged when
    the numbers in the names are not padded, since sequential matching then pairs the wrong frames.
    """
    d = Path(image_dir)
    if not d.is_dir():
        raise InputError(f"{d}: not a directory")
    files = sorted((p for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                   key=lambda p: p.name)
    if sorted(files, key=lambda p: _natural_key(p.name)) != files:
        log.warning("%s: file names sort differently as text and as numbers (no zero padding?); frames are "
                    "taken in text order, which sequential matching relies on: use --matcher exhaustive "
                    "or zero-padded names", d)
    return files


#: EXIF tags: the Exif sub-IFD, FocalLengthIn35mmFilm, and (IFD0) Orientation.
_EXIF_IFD, _EXIF_FOCAL_35MM, _EXIF_ORIENTATION = 0x8769, 0xA405, 0x0112


def exif_focal_35mm(path: str | os.PathLike) -> float | None:
    """The 35 mm-equivalent focal length (mm) an image's EXIF states, or None."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            exif = im.getexif()
            value = exif.get_ifd(_EXIF_IFD).get(_EXIF_FOCAL_35MM)
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError):
        return None
    try:
        f = float(value) if value is not None else 0.0
    except (TypeError, ValueError):
        return None
    return f if 4.0 <= f <= 2000.0 else None


def exif_hfov_deg(paths: list[Path]) -> float | None:
    """The horizontal field of view (across the long side, as ``colmap.initial_focal_px`` takes it)
    that the images' EXIF focal length gives, when every image states the same one; else None.

    A 35 mm-equivalent focal length f spans the 36 mm side of the film frame, which is the long
    side of the image whatever its orientation: hfov = 2 atan(18 / f).
    """
    values = {exif_focal_35mm(p) for p in paths}
    if len(values) != 1 or None in values:
        return None
    (f,) = values
    return math.degrees(2.0 * math.atan(18.0 / f))


def load_image_folder(image_dir: str | os.PathLike, shared_intrinsics: bool = True) -> list[SelectedFrame]:
    """Every JPG/JPEG/PNG image of a folder, in name order (see :func:`list_image_files`).

    Frames are named ``<stem>.png``: they are written losslessly as decoded (EXIF orientation
    applied), so SfM sees exactly these pixels; references match them by stem.

    Raises InputError when fewer than 3 images are found, an image cannot be decoded, or
    (with ``shared_intrinsics``) the images do not all have the same size.
    """
    d = Path(image_dir)
    files = list_image_files(d)
    if len(files) < MIN_IMAGES:
        raise InputError(f"{d}: found {len(files)} images (jpg/jpeg/png); need at least {MIN_IMAGES}")
    stems: dict[str, Path] = {}
    for f in files:
        if (other := stems.setdefault(f.stem.lower(), f)) is not f:
            raise InputError(f"{f}: has the same name as {other.name} apart from the suffix; rename one of them")
    frames = []
    for i, f in enumerate(files):
        rgb = read_image(f)
        if shared_intrinsics and frames and rgb.shape != frames[0].image.shape:
            first = frames[0]
            raise InputError(
                f"{f}: image is {rgb.shape[1]}x{rgb.shape[0]} but {first.name} is "
                f"{first.image.shape[1]}x{first.image.shape[0]}; shared intrinsics need one image size "
                "(resize the images or reconstruct with per-image intrinsics)"
            )
        frames.append(SelectedFrame(i, None, rgb, sharpness(rgb), f"{f.stem}.png"))
    return frames


def write_frames(frames: list[SelectedFrame], out_dir: str | os.PathLike) -> list[Path]:
    """Write each frame as ``out_dir / frame.name`` (PNG, lossless); returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        raise ValueError("write_frames: frame names are not unique")
    return [write_image(out / f.name, f.image) for f in frames]
