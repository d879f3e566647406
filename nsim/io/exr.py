"""OpenEXR images: named (H, W) channels, lossless, bit-exact for float32/float16/uint32.

Uses the `OpenEXR` v3 Python API (OpenCV's headless build cannot read EXR). Conventions:
- depth: one float32 channel `Z` in metres along the camera +z axis; `inf` means the ray hit nothing,
  `NaN` means no valid measurement. Both are stored and read back bit-exactly.
- RGB: channels `R`, `G`, `B`, linear, float16 or float32.
- organised LiDAR points: one channel per quantity (`X`, `Y`, `Z`, `intensity`, `range`, ...), each
  (H, W) with rows = beams and columns = azimuth steps.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping
from pathlib import Path

import numpy as np
import OpenEXR

from nsim.errors import InputError
from nsim.io import atomic_path

# Lossless codecs only: lossy ones (PXR24, B44, DWA) would silently change ground-truth depth.
_COMPRESSION = {
    "NONE": OpenEXR.NO_COMPRESSION,
    "RLE": OpenEXR.RLE_COMPRESSION,
    "ZIPS": OpenEXR.ZIPS_COMPRESSION,
    "ZIP": OpenEXR.ZIP_COMPRESSION,
    "PIZ": OpenEXR.PIZ_COMPRESSION,
}


def _storage_array(name: str, array: np.ndarray, as_half: bool) -> np.ndarray:
    """The C-contiguous float16/float32/uint32 array that stores `array` as channel `name`."""
    array = np.asarray(array)
    if array.ndim != 2 or 0 in array.shape:
        raise ValueError(f"EXR channel {name!r}: expected a non-empty (H, W) array, got shape {array.shape}")
    if array.dtype.kind in "bu":
        if as_half:
            raise ValueError(f"EXR channel {name!r}: cannot store integer data as half")
        if array.dtype.itemsize > 4:
            raise ValueError(f"EXR channel {name!r}: {array.dtype} does not fit uint32")
        dtype = np.uint32
    elif array.dtype.kind == "f":
        dtype = np.float16 if as_half or array.dtype == np.float16 else np.float32
    else:
        raise ValueError(f"EXR channel {name!r}: unsupported dtype {array.dtype} (float or unsigned int)")
    # The OpenEXR binding reads the buffer as C-ordered: non-contiguous views would be scrambled.
    with np.errstate(over="ignore"):  # float16 overflow to ±inf is documented behaviour
        return np.ascontiguousarray(array, dtype=dtype)


def write_exr(
    path: str | os.PathLike,
    channels: Mapping[str, np.ndarray],
    half: bool | Collection[str] = False,
    compression: str = "ZIP",
    attributes: Mapping[str, str] | None = None,
) -> Path:
    """Write named (H, W) channels (all the same shape) to a single-part scanline EXR, atomically.

    Storage per channel: float16 if named in `half` (or `half is True`, or the array is already
    float16; float32 values beyond ±65504 become ±inf); uint32 for bool/unsigned ints; float32 for other
    floats (float64 is rounded to float32). `compression` is one of NONE, RLE, ZIPS, ZIP, PIZ (all
    lossless). `attributes`: extra string attributes for the header (e.g. what a depth
    channel means). Returns `path`.
    """
    if not channels:
        raise ValueError("write_exr: no channels given")
    if compression not in _COMPRESSION:
        raise ValueError(f"write_exr: compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")
    half_names = set(channels) if half is True else set(half or ())
    if unknown := half_names - set(channels):
        raise ValueError(f"write_exr: half names unknown channels {sorted(unknown)}")
    arrays = {name: _storage_array(name, a, name in half_names) for name, a in channels.items()}
    shapes = {a.shape for a in arrays.values()}
    if len(shapes) != 1:
        raise ValueError(f"write_exr: channels differ in shape: { {n: a.shape for n, a in arrays.items()} }")
    header = {"compression": _COMPRESSION[compression], "type": OpenEXR.scanlineimage}
    for key, value in (attributes or {}).items():
        if key in header or not isinstance(value, str):
            raise ValueError(f"write_exr: attribute {key!r} must be a new name with a string value")
        header[key] = value
    path = Path(path)
    with atomic_path(path) as tmp, OpenEXR.File(header, arrays) as exr:
        exr.write(str(tmp))
    return path


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every channel of a single-part EXR: name -> (H, W) float16, float32 or uint32 array.

    Channels are kept separate (no RGB grouping) and returned in the file's (alphabetical) order.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            if len(exr.parts) != 1:
                raise InputError(f"{path}: multi-part EXR ({len(exr.parts)} parts) is not supported")
            if exr.header().get("type") in (OpenEXR.deepscanline, OpenEXR.deeptile):
                raise InputError(f"{path}: deep EXR images are not supported")
            channels = {name: ch.pixels for name, ch in exr.channels().items()}
    except InputError:
        raise
    except Exception as err:  # the binding raises bare RuntimeError/ValueError for corrupt files
        raise InputError(f"{path}: not a readable OpenEXR file ({err})") from None
    for name, pixels in channels.items():
        if pixels.ndim != 2:
            raise InputError(f"{path}: channel {name!r} has shape {pixels.shape}, expected (H, W)")
    return channels


def _channel(path: Path, channels: dict[str, np.ndarray], name: str, float_only: bool = True) -> np.ndarray:
    if name not in channels:
        raise InputError(f"{path}: missing channel {name!r} (has {sorted(channels)})")
    if float_only and channels[name].dtype.kind != "f":
        raise InputError(f"{path}: channel {name!r} is {channels[name].dtype}, expected float")
    return channels[name]


def write_depth_exr(path: str | os.PathLike, depth_m: np.ndarray, attributes: Mapping[str, str] | None = None) -> Path:
    """Write (H, W) depth in metres as one float32 channel `Z`; inf = no hit, NaN = invalid.

    `attributes`: header strings saying what the depth is (e.g. ``nsim_depth: z-depth``)."""
    return write_exr(path, {"Z": np.asarray(depth_m, dtype=np.float32)}, attributes=attributes)


def read_depth_exr(path: str | os.PathLike) -> np.ndarray:
    """Read channel `Z` of a depth EXR as (H, W) float32 metres (a half channel is widened exactly)."""
    path = Path(path)
    return _channel(path, read_exr(path), "Z").astype(np.float32, copy=False)


def write_rgb_exr(path: str | os.PathLike, rgb: np.ndarray, dtype: type = np.float16) -> Path:
    """Write linear (H, W, 3) colour as channels R, G, B stored as `dtype` (np.float16 or np.float32)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"write_rgb_exr: expected (H, W, 3), got shape {rgb.shape}")
    if np.dtype(dtype) not in (np.float16, np.float32):
        raise ValueError(f"write_rgb_exr: dtype must be float16 or float32, got {dtype}")
    rgb = rgb.astype(dtype, copy=False)
    return write_exr(path, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})


def read_rgb_exr(path: str | os.PathLike) -> np.ndarray:
    """Read channels R, G, B as (H, W, 3) in their stored dtype (float16, or float32 if any is)."""
    path = Path(path)
    channels = read_exr(path)
    return np.stack([_channel(path, channels, c) for c in "RGB"], axis=-1)


def write_points_exr(path: str | os.PathLike, points: Mapping[str, np.ndarray]) -> Path:
    """Write an organised LiDAR scan: channels `X`, `Y`, `Z` (metres, sensor frame) plus any extras.

    Every channel is (H, W) with rows = beams and columns = azimuth steps, e.g. `intensity` (float32),
    `range` (float32 metres, inf = no return), `ring` (uint32). Floats are stored as float32.
    """
    if missing := {"X", "Y", "Z"} - set(points):
        raise ValueError(f"write_points_exr: missing channels {sorted(missing)}")
    return write_exr(path, points)


def read_points_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read an organised LiDAR scan written by `write_points_exr`: name -> (H, W) array."""
    path = Path(path)
    channels = read_exr(path)
    for name in "XYZ":
        _channel(path, channels, name)
    return channels


def read_exr_attributes(path: str | os.PathLike) -> dict[str, str]:
    """The string attributes of an EXR header (e.g. ``nsim_depth``), without reading pixels."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            header = dict(exr.header())  # copy inside the block: the binding empties it on close
    except Exception as err:  # noqa: BLE001 - the binding raises bare errors for corrupt files
        raise InputError(f"{path}: not a readable OpenEXR file ({err})") from None
    return {k: v for k, v in header.items() if isinstance(v, str)}
