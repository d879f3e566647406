"""nerfstudio ``transforms.json``: per-frame image paths, poses and camera intrinsics.

On disk (nerfstudio / instant-ngp convention): ``transform_matrix`` is cam_to_world with
**OpenGL camera axes** (+y up, +z backward) and ``cx, cy`` put the centre of the top-left pixel
at 0.5. In memory (``nsim.geometry.conventions``): cam_to_world with OpenCV axes and OpenCV
``cx, cy``. Both conversions happen here and nowhere else.

Intrinsics (``camera_model, fl_x, fl_y, cx, cy, w, h, k1, k2, k3, k4, p1, p2``) may sit at the
top level (shared) or in a frame (overriding the top level), as nerfstudio allows. A missing
``camera_model`` means PINHOLE, or OPENCV when any distortion key is present. The writer puts
every key whose value all frames share at the top level and the rest in the frames.

Unknown top-level and per-frame keys are kept in ``extra`` and written back unchanged. Floats
round-trip exactly (JSON floats are written with ``repr`` precision); the ``+-0.5`` pixel shift
of ``cx, cy`` is exact unless ``cx + 0.5`` crosses a power of two (then off by one ulp).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from nsim.errors import InputError
from nsim.geometry.cameras import MODELS, Camera
from nsim.geometry.conventions import (
    opencv_to_opengl_c2w,
    opengl_to_opencv_c2w,
    principal_point_from_colmap,
    principal_point_to_colmap,
)
from nsim.geometry.transforms import is_rotation
from nsim.io import atomic_path

INTRINSIC_KEYS = ("camera_model", "w", "h", "fl_x", "fl_y", "cx", "cy", "k1", "k2", "k3", "k4", "p1", "p2")
DIST_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
#: Which distortion keys each model uses, in ``Camera.dist`` order.
MODEL_DIST_KEYS = {
    "PINHOLE": (),
    "OPENCV": ("k1", "k2", "p1", "p2", "k3"),
    "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4"),
    "EQUIRECTANGULAR": (),
}
FRAME_KEYS = ("file_path", "transform_matrix", "depth_file_path", "mask_path", "timestamp")
TOP_KEYS = ("frames", "applied_transform")
#: Max deviation of R^T R from I (and det R from 1) accepted for a pose's rotation.
ROTATION_TOLERANCE = 1e-4


@dataclass(frozen=True, eq=False)
class Frame:
    """One image. cam_to_world: (4, 4) float64, OpenCV axes; paths as written in the file.

    timestamp_s is the file's ``timestamp`` key (seconds); extra holds unknown per-frame keys.
    """

    file_path: str
    cam_to_world: np.ndarray
    camera: Camera
    depth_file_path: str | None = None
    mask_path: str | None = None
    timestamp_s: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c2w = np.asarray(self.cam_to_world, dtype=np.float64)
        if c2w.shape != (4, 4):
            raise ValueError(f"Frame.cam_to_world: expected shape (4, 4), got {c2w.shape}")
        object.__setattr__(self, "cam_to_world", c2w)


@dataclass(frozen=True, eq=False)
class TransformsData:
    """Contents of a transforms.json.

    applied_transform: (3, 4) or (4, 4) float64 as stored by nerfstudio (the world transform it
    applied to COLMAP's poses; a world-frame matrix, so no camera-axes conversion), or None.
    extra: unknown top-level keys, preserved on a round trip.
    """

    frames: list[Frame]
    applied_transform: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------- reading


class _Reader:
    """Parses one file; every failure raises InputError("<file>: <field path>: <problem>")."""

    def __init__(self, path: Path):
        self.name = str(path)

    def fail(self, where: str, problem: str) -> NoReturn:
        raise InputError(f"{self.name}: {where}: {problem}")

    def number(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(where, f"expected a number, got {value!r}")
        if not math.isfinite(value):
            self.fail(where, f"must be finite, got {value}")
        return float(value)

    def integer(self, value: Any, where: str) -> int:
        number = self.number(value, where)
        if number != int(number) or number <= 0:
            self.fail(where, f"expected a positive integer, got {value!r}")
        return int(number)

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            self.fail(where, f"expected a string, got {value!r}")
        return value

    def matrix(self, value: Any, where: str, shapes: tuple[tuple[int, int], ...]) -> np.ndarray:
        try:
            m = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(where, "expected a matrix (list of lists of numbers)")
        if m.shape not in shapes:
            want = " or ".join(f"{r}x{c}" for r, c in shapes)
            self.fail(where, f"expected a {want} matrix, got shape {m.shape}")
        if np.isnan(m).any():
            self.fail(where, "contains NaN")
        if not np.isfinite(m).all():
            self.fail(where, "contains inf")
        return m

    def pose(self, value: Any, where: str) -> np.ndarray:
        m = self.matrix(value, where, ((4, 4),))
        if np.abs(m[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
            self.fail(where, f"last row must be [0, 0, 0, 1], got {m[3].tolist()}")
        if not is_rotation(m[:3, :3], ROTATION_TOLERANCE):
            self.fail(where, "upper-left 3x3 is not a rotation (orthonormal, det +1); scaled poses are not supported")
        return opengl_to_opencv_c2w(m)

    def camera(self, raw: dict, top: dict, where: str) -> Camera:
        def get(key: str) -> tuple[Any, str]:
            if key in raw:
                return raw[key], f"{where}.{key}"
            return top.get(key), key if key in top else f"{where}.{key}"

        model, model_at = get("camera_model")
        if model is None:
            model = "OPENCV" if any(get(k)[0] is not None for k in DIST_KEYS) else "PINHOLE"
        elif model not in MODELS:
            self.fail(model_at, f"unknown camera_model {model!r}, expected one of {list(MODELS)}")

        def required(key: str, parse) -> Any:
            value, at = get(key)
            if value is None:
                self.fail(at, "missing (neither in the frame nor at the top level)")
            return parse(value, at)

        width, height = required("w", self.integer), required("h", self.integer)
        coeffs = {}
        for key in DIST_KEYS:
            value, at = get(key)
            coeffs[key] = 0.0 if value is None else self.number(value, at)
            if coeffs[key] != 0.0 and key not in MODEL_DIST_KEYS[model]:
                self.fail(at, f"camera_model {model} has no {key} coefficient, got {coeffs[key]}")
        if model == "EQUIRECTANGULAR":
            return Camera.equirect(width, height)  # the intrinsics follow from the size
        fx, fy = required("fl_x", self.number), required("fl_y", self.number)
        for key, value in (("fl_x", fx), ("fl_y", fy)):
            if value <= 0.0:
                self.fail(get(key)[1], f"focal length must be > 0, got {value}")
        cx, cy = principal_point_from_colmap(required("cx", self.number), required("cy", self.number))
        dist = tuple(coeffs[k] for k in MODEL_DIST_KEYS[model])
        return Camera(model, width, height, fx, fy, cx, cy, dist)

    def frame(self, raw: Any, top: dict, where: str) -> Frame:
        if not isinstance(raw, dict):
            self.fail(where, f"expected an object, got {type(raw).__name__}")
        if "file_path" not in raw:
            self.fail(f"{where}.file_path", "missing")
        if "transform_matrix" not in raw:
            self.fail(f"{where}.transform_matrix", "missing")
        optional = {}
        for key in ("depth_file_path", "mask_path"):
            if key in raw:
                optional[key] = self.string(raw[key], f"{where}.{key}")
        if "timestamp" in raw:
            optional["timestamp_s"] = self.number(raw["timestamp"], f"{where}.timestamp")
        return Frame(
            file_path=self.string(raw["file_path"], f"{where}.file_path"),
            cam_to_world=self.pose(raw["transform_matrix"], f"{where}.transform_matrix"),
            camera=self.camera(raw, top, where),
            extra={k: v for k, v in raw.items() if k not in FRAME_KEYS and k not in INTRINSIC_KEYS},
            **optional,
        )


def read_transforms(path: str | os.PathLike) -> TransformsData:
    """Read a nerfstudio transforms.json; poses come back in OpenCV axes.

    Raises InputError naming the file and field (``transforms.json: frames[3].transform_matrix:
    contains NaN``) for a missing file, bad JSON, missing or malformed fields, non-rigid poses
    and unknown camera models.
    """
    path = Path(path)
    reader = _Reader(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read: {e}") from None
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: invalid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a JSON object at the top level, got {type(meta).__name__}")
    if "frames" not in meta:
        reader.fail("frames", "missing")
    if not isinstance(meta["frames"], list):
        reader.fail("frames", f"expected a list, got {type(meta['frames']).__name__}")
    top = {k: meta[k] for k in INTRINSIC_KEYS if k in meta}
    frames = [reader.frame(raw, top, f"frames[{i}]") for i, raw in enumerate(meta["frames"])]
    applied = meta.get("applied_transform")
    if applied is not None:
        applied = reader.matrix(applied, "applied_transform", ((3, 4), (4, 4)))
    extra = {k: v for k, v in meta.items() if k not in TOP_KEYS and k not in INTRINSIC_KEYS}
    return TransformsData(frames=frames, applied_transform=applied, extra=extra)


# ---------------------------------------------------------------------------- the files frames name

PATH_KEYS = ("file_path", "depth_file_path", "mask_path")


def frame_image_paths(path: str | os.PathLike, data: TransformsData,
                      root: str | os.PathLike | None = None) -> list[Path]:
    """Each frame's image (``file_path``), resolved against the folder of ``path``, in frame order.

    A transforms.json is untrusted: every path it names (``depth_file_path`` and ``mask_path``
    too, which need not exist) must resolve, symlinks followed, inside ``root`` (default: the
    folder of ``path``). Raises InputError naming the frame, e.g. ``t.json: frames[3].file_path:
    ../../etc/hostname resolves outside /data/scan``, or ``... does not exist``.
    """
    path = Path(path)
    base = path.parent
    root = Path(root if root is not None else base).resolve()
    images = []
    for i, frame in enumerate(data.frames):
        for key in PATH_KEYS:
            if (value := getattr(frame, key)) is None:
                continue
            where = f"{path}: frames[{i}].{key}: {value}"
            try:
                resolved = (base / value).resolve()
            except (OSError, RuntimeError, ValueError) as e:  # symlink loop, NUL byte
                raise InputError(f"{where}: not a usable path ({e})") from None
            if not resolved.is_relative_to(root):
                raise InputError(f"{where} resolves outside {root}")
            if key == "file_path":
                if not resolved.is_file():
                    raise InputError(f"{where} does not exist")
                images.append(resolved)
    return images


def check_frame_images(path: str | os.PathLike, data: TransformsData, images: list[Path]) -> None:
    """Decode every frame's image (``frame_image_paths``) and check its size against the frame's ``w``, ``h``.

    Raises InputError naming the frame and file: a truncated or unreadable image, or
    ``t.json: frames[2].file_path: b.png: image is 64x48, but w=80, h=60``.
    """
    from nsim.io.images import read_image

    for i, (frame, image) in enumerate(zip(data.frames, images, strict=True)):
        where = f"{path}: frames[{i}].file_path: {frame.file_path}"
        try:
            height, width = read_image(image).shape[:2]
        except InputError as e:
            raise InputError(f"{where}: {str(e).removeprefix(f'{image}: ')}") from None
        cam = frame.camera
        if (width, height) != (cam.width, cam.height):
            raise InputError(f"{where}: image is {width}x{height}, but w={cam.width}, h={cam.height}")


# ---------------------------------------------------------------------------- writing


def _camera_json(camera: Camera) -> dict[str, Any]:
    """Intrinsic keys of one camera in nerfstudio's convention (cx, cy shifted by +0.5)."""
    cx, cy = principal_point_to_colmap(camera.cx, camera.cy)
    d = {"camera_model": camera.model, "w": camera.width, "h": camera.height,
         "fl_x": camera.fx, "fl_y": camera.fy, "cx": cx, "cy": cy}
    coeffs = dict(zip(MODEL_DIST_KEYS[camera.model], camera.dist, strict=True))
    if camera.model == "OPENCV" and coeffs["k3"] == 0.0:
        del coeffs["k3"]  # nerfstudio's colmap export writes (k1, k2, p1, p2) only
    return d | coeffs


def _check_extra(extra: dict, known: tuple[str, ...], where: str) -> None:
    if clash := sorted(set(extra) & set(known)):
        raise ValueError(f"{where}: keys {clash} are reserved by transforms.json, not extra")


def write_transforms(path: str | os.PathLike, data: TransformsData) -> Path:
    """Write ``data`` as a nerfstudio transforms.json (OpenGL axes, atomically). Returns the path.

    Intrinsic keys equal in every frame go to the top level, the others into each frame.
    """
    _check_extra(data.extra, TOP_KEYS + INTRINSIC_KEYS, "TransformsData.extra")
    cameras = [_camera_json(f.camera) for f in data.frames]
    shared = {}
    if cameras:
        shared = {k: v for k, v in cameras[0].items() if all(k in c and c[k] == v for c in cameras)}
    out: dict[str, Any] = dict(shared)
    out.update(data.extra)
    if data.applied_transform is not None:
        out["applied_transform"] = np.asarray(data.applied_transform, dtype=np.float64).tolist()
    frames = []
    for i, (frame, cam) in enumerate(zip(data.frames, cameras, strict=True)):
        _check_extra(frame.extra, FRAME_KEYS + INTRINSIC_KEYS, f"frames[{i}].extra")
        d: dict[str, Any] = {"file_path": frame.file_path,
                             "transform_matrix": opencv_to_opengl_c2w(frame.cam_to_world).tolist()}
        d.update({k: v for k, v in cam.items() if k not in shared})
        for key, attr in (("depth_file_path", "depth_file_path"), ("mask_path", "mask_path"), ("timestamp", "timestamp_s")):
            if (value := getattr(frame, attr)) is not None:
                d[key] = value
        d.update(frame.extra)
        frames.append(d)
    out["frames"] = frames
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(out, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return path
