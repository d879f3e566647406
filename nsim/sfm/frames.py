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

Every decoded frame gets exactly one selection status (:class:`FrameAccount`), decided in the
order the rule applies: ``blurred`` (sharpness below the threshold), ``not sampled`` (sharp
enough, but a sharper frame of its span was picked), ``duplicate`` (its span's pick, too
close to the previously kept frame) or ``kept``. A span whose frames are all blurred picks
none. Each kept frame then gets SfM's verdict (``used``, ``not registered`` or
:data:`POSE_JUMP`), the statuses report.json's list of images uses:
:func:`video_frame_report` writes the whole account, not-sampled frames as runs.
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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

#: What frame selection decided for a video frame (see the module docstring).
BLURRED, NOT_SAMPLED, DUPLICATE, KEPT = "blurred", "not sampled", "duplicate", "kept"
#: What SfM made of a kept frame or an input image (report.json's ``images[].status``).
USED, NOT_REGISTERED = "used", "not registered"
POSE_JUMP = "registered, then dropped: its pose jumped away from both neighbours"
#: Short labels for the one-line summary.
_LABELS = {POSE_JUMP: "dropped for a pose jump", DUPLICATE: "duplicates"}


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


def frame_name(index: int) -> str:
    """The file name a video frame is stored under."""
    return f"frame_{index:05d}.png"


@dataclass(frozen=True, eq=False)
class FrameAccount:
    """What selection decided for each of a video's N frames (the rule: module docstring).

    sharpness: (N,) float64; status: (N,) str, one of BLURRED, NOT_SAMPLED, DUPLICATE, KEPT;
    window: (N,) int64, the span each frame lies in (-1 when there are none); picked: (W,)
    int64, each span's pick, -1 where all its frames are blurred; difference: (N,) float64,
    for a pick the mean absolute difference of its thumbnail from that of the previously kept
    frame, ``compared_with`` ((N,) int64), NaN and -1 for the other frames and the first pick.
    blur_threshold = blur_ratio x median_sharpness.
    """

    sharpness: np.ndarray
    status: np.ndarray
    window: np.ndarray
    picked: np.ndarray
    difference: np.ndarray
    compared_with: np.ndarray
    median_sharpness: float
    blur_ratio: float
    blur_threshold: float
    dedup_threshold: float

    @property
    def kept(self) -> np.ndarray:
        """Indices (sorted, int64) of the kept frames."""
        return np.flatnonzero(self.status == KEPT).astype(np.int64)

    def counts(self) -> dict[str, int]:
        """Frames per selection status (every status, zeros included); they sum to N."""
        return {s: int(np.count_nonzero(self.status == s)) for s in (BLURRED, NOT_SAMPLED, DUPLICATE, KEPT)}


def account_frames(
    sharpness_values: np.ndarray,
    thumbnails: np.ndarray,
    n_frames: int,
    blur_ratio: float = 0.4,
    dedup_threshold: float = 0.01,
) -> FrameAccount:
    """Every frame's selection status and the measure that decided it (rule: module docstring).

    sharpness_values: (N,) float; thumbnails: (N, h, w) float in [0, 1].
    """
    sharp = np.asarray(sharpness_values, dtype=np.float64)
    n = len(sharp)
    median = float(np.median(sharp)) if n else 0.0
    threshold = blur_ratio * median
    status = np.where(sharp < threshold, BLURRED, NOT_SAMPLED).astype(object)
    window = np.full(n, -1, dtype=np.int64)
    difference = np.full(n, np.nan)
    compared_with = np.full(n, -1, dtype=np.int64)
    n_windows = min(n_frames, n) if n_frames >= 1 else 0
    edges = np.linspace(0, n, n_windows + 1)
    picked = np.full(n_windows, -1, dtype=np.int64)
    last_kept = -1
    for w, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        span = np.arange(int(np.ceil(lo)), int(np.ceil(hi)))
        window[span] = w
        span = span[status[span] != BLURRED]
        if span.size == 0:
            continue  # the whole span is blurred
        best = int(span[np.argmax(sharp[span])])  # first maximum: deterministic
        picked[w] = best
        if last_kept >= 0:
            difference[best] = float(np.abs(thumbnails[best] - thumbnails[last_kept]).mean())
            compared_with[best] = last_kept
            if difference[best] < dedup_threshold:
                status[best] = DUPLICATE
                continue
        status[best] = KEPT
        last_kept = best
    return FrameAccount(sharp, status, window, picked, difference, compared_with, median, float(blur_ratio),
                        float(threshold), float(dedup_threshold))


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
    return account_frames(sharpness_values, thumbnails, n_frames, blur_ratio, dedup_threshold).kept


def _opt(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def video_frame_report(account: FrameAccount, timestamps_s: Sequence[float], fates: Mapping[str, str],
                       fps: float | None = None) -> dict[str, Any]:
    """report.json's account of every video frame: what selection, then SfM, made of it.

    timestamps_s: (N,) every decoded frame's time; fates: kept frame name -> SfM's status
    (a kept frame missing from it stays ``kept``). ``frames`` lists, in index order, one entry
    per frame (``index``, ``timestamp_s``, ``status``, the measure that decided it), except
    that consecutive not-sampled frames of one span make one entry with ``last``, ``count``,
    ``last_timestamp_s`` and ``picked`` (the frame taken from their span instead). Kept frames
    carry their ``name`` (as in ``images``). ``counts`` (statuses, summing to
    ``frames_decoded``) and ``frames_sampled`` (the spans' picks: kept and duplicate frames)
    summarize it.
    """
    times = np.asarray(timestamps_s, dtype=np.float64)
    n = len(account.status)
    if len(times) != n:
        raise ValueError(f"video_frame_report: {len(times)} timestamps for {n} frames")
    entries: list[dict[str, Any]] = []
    i = 0
    while i < n:
        status = account.status[i]
        entry: dict[str, Any] = {"index": i, "timestamp_s": float(times[i])}
        if status == NOT_SAMPLED:
            j = i
            while j + 1 < n and account.status[j + 1] == NOT_SAMPLED and account.window[j + 1] == account.window[i]:
                j += 1
            w = int(account.window[i])
            entry.update(status=NOT_SAMPLED, last=j, count=j - i + 1, last_timestamp_s=float(times[j]),
                         picked=int(account.picked[w]) if w >= 0 else None)
            entries.append(entry)
            i = j + 1
            continue
        entry["sharpness"] = float(account.sharpness[i])
        if status == KEPT:
            name = frame_name(i)
            entry.update(name=name, status=fates.get(name, KEPT))
        else:
            entry["status"] = status
        if status in (KEPT, DUPLICATE):
            entry["difference"] = _opt(account.difference[i])
            entry["compared_with"] = int(account.compared_with[i]) if account.compared_with[i] >= 0 else None
        entries.append(entry)
        i += 1
    counts: dict[str, int] = {BLURRED: 0, NOT_SAMPLED: 0, DUPLICATE: 0, USED: 0}
    for e in entries:
        counts[e["status"]] = counts.get(e["status"], 0) + e.get("count", 1)
    return {
        "frames_decoded": n,
        "fps": fps,
        "windows": len(account.picked),
        "frames_sampled": int(np.count_nonzero(np.isin(account.status, (KEPT, DUPLICATE)))),
        "median_sharpness": account.median_sharpness,
        "blur_ratio": account.blur_ratio,
        "blur_threshold": account.blur_threshold,
        "dedup_threshold": account.dedup_threshold,
        "counts": counts,
        "frames": entries,
    }


def frame_summary_line(video_report: dict[str, Any]) -> str:
    """One line of counts from :func:`video_frame_report`'s output, e.g. ``"120 of 1800 video
    frames sampled (97 used, 15 not registered, 8 duplicates); 40 blurred, 1640 not sampled
    (a sharper frame of their span was sampled)"``."""
    counts = dict(video_report["counts"])
    blurred, not_sampled = counts.pop(BLURRED, 0), counts.pop(NOT_SAMPLED, 0)
    duplicates = counts.pop(DUPLICATE, 0)
    sampled = [f"{c} {_LABELS.get(s, s)}" for s, c in counts.items() if c]
    sampled += [f"{duplicates} {_LABELS[DUPLICATE]}"] if duplicates else []
    what = f" ({', '.join(sampled)})" if sampled else ""
    why = " (a sharper frame of their span was sampled)" if not_sampled else ""
    return (f"{video_report['frames_sampled']} of {video_report['frames_decoded']} video frames sampled{what}; "
            f"{blurred} blurred, {not_sampled} not sampled{why}")


@dataclass(frozen=True, eq=False)
class VideoSelection:
    """The frames taken from a video and the account of all its frames.

    frames: the kept frames, in time order; account: every decoded frame's selection status;
    timestamps_s: (N,) float64, every decoded frame's time; fps: the container's rate (None
    when it reports none).
    """

    frames: list[SelectedFrame]
    account: FrameAccount
    timestamps_s: np.ndarray
    fps: float | None

    def report(self, fates: Mapping[str, str]) -> dict[str, Any]:
        """:func:`video_frame_report` of this video (fates: kept frame name -> SfM's status)."""
        return video_frame_report(self.account, self.timestamps_s, fates, self.fps)


def select_video(
    video_path: str | os.PathLike,
    n_frames: int,
    blur_ratio: float = 0.4,
    dedup_threshold: float = 0.01,
    progress: ProgressFn | None = None,
) -> VideoSelection:
    """About ``n_frames`` sharp, distinct frames spread over the video, in time order, and
    what became of every other frame.

    Fewer come back when spans are entirely blurred or duplicates. Raises InputError naming
    the file when it cannot be opened or decoded, has no frames, or yields fewer than 3 frames.
    """
    path = Path(video_path)
    if n_frames < MIN_IMAGES:
        raise ValueError(f"n_frames: need at least {MIN_IMAGES}, got {n_frames}")
    cap = _open_video(path)
    fps = cap.get(cv2.CAP_PROP_FPS)
    fps = float(fps) if np.isfinite(fps) and 0.0 < fps < 10_000.0 else None
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
    account = account_frames(np.array(sharp), np.stack(thumbs), n_frames, blur_ratio, dedup_threshold)
    keep, counts = account.kept, account.counts()
    log.info("%s: %d frames decoded, %d kept, %d duplicates, %d blurred, %d not sampled (median sharpness %.3g)",
             path, len(sharp), len(keep), counts[DUPLICATE], counts[BLURRED], counts[NOT_SAMPLED],
             account.median_sharpness)
    if len(keep) < MIN_IMAGES:
        raise InputError(f"{path}: only {len(keep)} usable frames (of {len(sharp)}: {counts[BLURRED]} blurred, "
                         f"{counts[DUPLICATE]} duplicates) after dropping blurred and duplicate frames; need at "
                         f"least {MIN_IMAGES}: record a longer or steadier video")
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
                frames.append(SelectedFrame(index, float(times[index]), rgb, float(sharp[index]), frame_name(index)))
            elif not cap.grab():
                break
    finally:
        cap.release()
    if len(frames) != len(keep):
        raise InputError(f"{path}: decoding stopped early on the second pass (frame {len(frames)} of "
                         f"{len(keep)} selected); the file may be corrupt")
    return VideoSelection(frames, account, np.asarray(times, dtype=np.float64), fps)


def select_video_frames(
    video_path: str | os.PathLike,
    n_frames: int,
    blur_ratio: float = 0.4,
    dedup_threshold: float = 0.01,
    progress: ProgressFn | None = None,
) -> list[SelectedFrame]:
    """The frames :func:`select_video` keeps."""
    return select_video(video_path, n_frames, blur_ratio, dedup_threshold, progress).frames


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


#: A file stem that is a timestamp: seconds with a decimal point (TUM RGB-D: ``1305031102.175304``) or whole
#: nanoseconds (16 digits or more: since 1970-04-26), as ``nsim import-log`` reads frame names.
STAMP_STEM = re.compile(r"\d+\.\d+|\d{16,}")


def stamps_from_names(names: Sequence[str], where: str) -> dict[str, float] | None:
    """``name -> seconds`` when every frame's stem is a timestamp (``STAMP_STEM``), None when none is;
    InputError naming ``where`` and a frame of each kind when some are and some are not."""
    stems = {n: Path(n).stem for n in names}
    stamped = [n for n, s in stems.items() if STAMP_STEM.fullmatch(s)]
    if not stamped:
        return None
    if len(stamped) < len(stems):
        other = next(n for n in stems if n not in stamped)
        raise InputError(f"{where}: {stamped[0]} is named by its timestamp but {other} is not; name every image by "
                         "its timestamp or none")
    return {n: (int(s) / 1e9 if "." not in s else float(s)) for n, s in stems.items()}


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
