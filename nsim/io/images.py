"""8-bit RGB images and 16-bit millimetre depth PNGs, via OpenCV (which is BGR on its side only).

Float <-> uint8 convention (exact round trip `to_uint8(to_float(u)) == u` for every uint8 `u`):
- `to_float(u) = u / 255` as float32, so 0 -> 0.0 and 255 -> 1.0.
- `to_uint8(x) = rint(clip(x, 0, 1) * 255)`: nearest level, ties to even (numpy's `rint`).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from nsim.errors import InputError
from nsim.io import atomic_path

MAX_DEPTH_PNG_MM = 65535


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] (any shape) -> uint8 in [0, 255]; values outside [0, 1] are clipped."""
    image = np.asarray(image)
    if image.dtype.kind != "f":
        raise ValueError(f"to_uint8: expected a float array, got {image.dtype}")
    if np.isnan(image).any():
        raise ValueError("to_uint8: image contains NaN")
    image = image.astype(np.promote_types(image.dtype, np.float32), copy=False)  # float16 is too coarse
    return np.rint(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


def to_float(image: np.ndarray) -> np.ndarray:
    """uint8 image (any shape) -> float32 in [0, 1]."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"to_float: expected uint8, got {image.dtype}")
    return image.astype(np.float32) / np.float32(255.0)


def _read_bytes(path: Path) -> np.ndarray:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror})") from None
    if not data:
        raise InputError(f"{path}: empty file")
    return np.frombuffer(data, dtype=np.uint8)


def _decode(path: Path, flags: int) -> np.ndarray:
    """The image in file ``path`` as OpenCV decodes it with ``flags`` (its channel order, its dtype).

    InputError naming the file when it is missing, unreadable, empty or not a decodable image.
    """
    image = cv2.imdecode(_read_bytes(path), flags)
    if image is None:
        raise InputError(f"{path}: not a readable image (corrupt or unsupported format)")
    return image


def _encode_atomic(path: Path, image: np.ndarray, ext: str | None = None) -> Path:
    """Encode `image` (OpenCV channel order) as `ext` (default: the extension of `path`, e.g. ".png") and
    write it atomically; ValueError when OpenCV cannot encode it."""
    ext = path.suffix if ext is None else ext
    try:
        ok, buf = cv2.imencode(ext, image)
    except cv2.error:
        ok = False
    if not ok:
        raise ValueError(f"{path}: OpenCV cannot encode {image.dtype} {image.shape} as {ext!r}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
    return path


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit image (PNG, JPEG, ...) as (H, W, 3) uint8 RGB.

    Grey images are replicated to three channels, alpha is dropped, and EXIF orientation is applied.
    A 16-bit image is an InputError (for depth use `read_depth_png`).
    """
    path = Path(path)
    image = _decode(path, cv2.IMREAD_COLOR_RGB | cv2.IMREAD_ANYDEPTH)
    if image.dtype != np.uint8:
        raise InputError(f"{path}: expected an 8-bit image, got {image.dtype}")
    return image


def write_image(path: str | os.PathLike, rgb: np.ndarray) -> Path:
    """Write an (H, W, 3) RGB or (H, W) grey image, uint8 or float in [0, 1] (see `to_uint8`).

    The format follows the extension; PNG is lossless, so `read_image(write_image(p, u)) == u`.
    """
    path = Path(path)
    rgb = np.asarray(rgb)
    if not (rgb.ndim == 2 or (rgb.ndim == 3 and rgb.shape[2] == 3)) or 0 in rgb.shape:
        raise ValueError(f"write_image: expected non-empty (H, W, 3) or (H, W), got shape {rgb.shape}")
    if rgb.dtype != np.uint8:
        rgb = to_uint8(rgb)
    return _encode_atomic(path, rgb[..., ::-1] if rgb.ndim == 3 else rgb)


def write_png16(path: str | os.PathLike, grey_u16: np.ndarray) -> Path:
    """Write an (H, W) uint16 grey image (a 16-bit camera's frame) as a lossless 16-bit PNG."""
    path = Path(path)
    grey_u16 = np.asarray(grey_u16)
    if grey_u16.dtype != np.uint16 or grey_u16.ndim != 2 or 0 in grey_u16.shape:
        raise ValueError(f"write_png16: expected non-empty (H, W) uint16, got {grey_u16.dtype} {grey_u16.shape}")
    return _encode_atomic(path.with_suffix(".png") if path.suffix != ".png" else path, grey_u16)


def write_depth_png_mm(path: str | os.PathLike, depth_m: np.ndarray) -> Path:
    """Write (H, W) depth in metres as a 16-bit PNG of whole millimetres (`rint(depth_m * 1000)`).

    0 means no depth: written for non-finite depth, depth that rounds to 0 mm or below, and depth beyond
    65.535 m (not saturated, since a clipped value would be a wrong measurement).
    """
    path = Path(path)
    depth_m = np.asarray(depth_m, dtype=np.float64)
    if depth_m.ndim != 2 or 0 in depth_m.shape:
        raise ValueError(f"write_depth_png_mm: expected non-empty (H, W), got shape {depth_m.shape}")
    with np.errstate(invalid="ignore"):
        depth_mm = np.rint(depth_m * 1000.0)
        valid = np.isfinite(depth_mm) & (depth_mm > 0) & (depth_mm <= MAX_DEPTH_PNG_MM)
    return _encode_atomic(path, np.where(valid, depth_mm, 0).astype(np.uint16))


def read_depth_png(path: str | os.PathLike, units_per_m: float) -> np.ndarray:
    """Read a single-channel 16-bit depth PNG as (H, W) float32 metres; 0 (no depth) -> NaN.

    units_per_m: what one metre is in the PNG's integers: 1000 for millimetres, 5000 for TUM RGB-D
    (``nsim.io.recording_streams.DepthUnit``); never guessed here."""
    path = Path(path)
    raw = _decode(path, cv2.IMREAD_UNCHANGED)
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise InputError(f"{path}: expected a single-channel 16-bit depth PNG, got {raw.dtype} shape {raw.shape}")
    depth_m = raw.astype(np.float32) / np.float32(units_per_m)
    depth_m[raw == 0] = np.nan
    return depth_m
