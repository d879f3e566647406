"""nerfstudio ``transforms.json``: per-frame image paths, poses and camera intrinsics.

On disk (nerfstudio / instant-ngp convention): ``transform_matrix`` is cam_to_world with
**OpenGL camera axes** (+y up, +z backward) and ``cx, cy`` put the centre of the top-left pixel
at 0.5. In memory (``nsim.geometry.conventions``): cam_to_world with OpenCV axes and OpenCV
``cx, cy``. Both conversions happen here and nowhere else.

Intrinsics (``camera_model, fl_x, fl_y, cx, cy, w, h, k1, k2, k3, k4, p1, p2``) may sit at the
top level (shared) or in a frame (overriding the top level), as nerfstudio allows. A missing
``camera_model`` means PINHOLE, or OPENCV when any distortion key is present. The writer puts
every key whose value all frames share at the top level and the rest in the frames.

Besides the images (``file_path``), a frame may name a ``depth_file_path`` and a ``mask_path``,
and the top level a ``ply_file_path`` (sparse points in the same world as the poses);
:func:`linked_files` resolves all of them, confined to a root folder. Depth images store
``value x depth_unit_scale_factor`` = depth in the poses' units (:func:`depth_unit_scale`).
:func:`declared_world` reads what nsim's own keys say about the world (metric, z up).

Unknown top-level and per-frame keys are kept in ``extra`` and written back unchanged. Floats
round-trip exactly (JSON floats are written with ``repr`` precision); the ``+-0.5`` pixel shift
of ``cx, cy`` is exact unless ``cx + 0.5`` crosses a power of two (then off by one ulp).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
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
from nsim.io.canonical import round_decimals

INTRINSIC_KEYS = ("camera_model", "w", "h", "fl_x", "fl_y", "cx", "cy", "k1", "k2", "k3", "k4", "k5", "k6", "p1",
                  "p2")
DIST_KEYS = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")
#: Which distortion keys each model uses, in ``Camera.dist`` order.
MODEL_DIST_KEYS = {
    "PINHOLE": (),
    "OPENCV": ("k1", "k2", "p1", "p2", "k3"),
    "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4"),
    "FULL_OPENCV": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),  # nsim's extension: nerfstudio has no k5, k6
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
#: Tried in this order after a ``file_path`` that names no file and has no image suffix
#: (NeRF-synthetic's ``./train/r_0``), as nerfstudio's loaders do.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".JPG", ".PNG")


@dataclass(frozen=True)
class LinkedFile:
    """A file that a transforms.json names.

    where: the field, e.g. ``frames[3].depth_file_path`` or ``ply_file_path``; value: the path as
    written; path: the file, resolved (symlinks followed) and inside the root, or None when it
    does not exist; rel: its POSIX path relative to the root, as named (lexically normalised,
    with the image suffix that was found), or relative to the resolved root when the lexical
    path leaves it (a symlinked folder).
    """

    where: str
    value: str
    path: Path | None
    rel: str


@dataclass(frozen=True)
class FrameFiles:
    """The files one frame names: its image, and its depth and mask when the frame has those keys."""

    image: LinkedFile
    depth: LinkedFile | None = None
    mask: LinkedFile | None = None


class _Linker:
    """Resolves the paths of one transforms.json inside ``root`` (see :func:`linked_files`)."""

    def __init__(self, path: Path, root: str | os.PathLike | None):
        self.name, self.base = str(path), path.parent
        given = Path(root if root is not None else self.base)
        self.root, self.root_lexical = given.resolve(), Path(os.path.normpath(given.absolute()))

    def _resolve(self, where: str, value: str) -> Path:
        try:
            resolved = (self.base / value).resolve()
        except (OSError, RuntimeError, ValueError) as e:  # symlink loop, NUL byte
            raise InputError(f"{self.name}: {where}: {value}: not a usable path ({e})") from None
        if not resolved.is_relative_to(self.root):
            raise InputError(f"{self.name}: {where}: {value} resolves outside {self.root}")
        return resolved

    def link(self, where: str, value: str, image: bool = False) -> LinkedFile:
        resolved = self._resolve(where, value)
        found = value if resolved.is_file() else None
        if found is None and image and PurePosixPath(value).suffix.lower() not in IMAGE_SUFFIXES:
            for suffix in IMAGE_SUFFIXES:
                candidate = self._resolve(where, value + suffix)
                if candidate.is_file():
                    found, resolved = value + suffix, candidate
                    break
        lexical = Path(os.path.normpath(self.base.absolute() / (found or value)))
        rel = (lexical.relative_to(self.root_lexical) if lexical.is_relative_to(self.root_lexical)
               else resolved.relative_to(self.root))
        return LinkedFile(where, value, resolved if found is not None else None, rel.as_posix())


def linked_files(path: str | os.PathLike, data: TransformsData,
                 root: str | os.PathLike | None = None) -> tuple[list[FrameFiles], LinkedFile | None]:
    """The files ``path`` names: each frame's image, depth and mask, and the top-level ``ply_file_path``.

    Paths are relative to the folder of ``path``. A transforms.json is untrusted: every path it
    names must resolve, symlinks followed, inside ``root`` (default: the folder of ``path``),
    whether or not the file exists; InputError names the field otherwise, e.g. ``t.json:
    frames[3].file_path: ../../etc/hostname resolves outside /data/scan``. A ``file_path``
    without an image suffix that names no file is tried with each of ``IMAGE_SUFFIXES``.
    Files that do not exist come back with ``path=None``; the caller decides what that means.
    Returns (one FrameFiles per frame, in frame order; the point cloud or None).
    """
    path = Path(path)
    linker = _Linker(path, root)
    frames = []
    for i, frame in enumerate(data.frames):
        image = linker.link(f"frames[{i}].file_path", frame.file_path, image=True)
        depth, mask = (None if (value := getattr(frame, key)) is None
                       else linker.link(f"frames[{i}].{key}", value) for key in ("depth_file_path", "mask_path"))
        frames.append(FrameFiles(image, depth, mask))
    ply = data.extra.get("ply_file_path")
    if ply is not None and not isinstance(ply, str):
        raise InputError(f"{path}: ply_file_path: expected a string, got {ply!r}")
    return frames, None if ply is None else linker.link("ply_file_path", ply)


def check_frame_images(path: str | os.PathLike, data: TransformsData, images: list[Path | None]) -> None:
    """Decode every frame's image and check its size against the frame's ``w``, ``h``.

    images: one per frame of ``data`` (e.g. ``FrameFiles.image.path``); None (a skipped frame)
    is not checked. Raises InputError naming the frame and file: a truncated or unreadable
    image, or ``t.json: frames[2].file_path: b.png: image is 64x48, but w=80, h=60``.
    """
    from nsim.io.images import read_image

    for i, (frame, image) in enumerate(zip(data.frames, images, strict=True)):
        if image is None:
            continue
        where = f"{path}: frames[{i}].file_path: {frame.file_path}"
        try:
            height, width = read_image(image).shape[:2]
        except InputError as e:
            raise InputError(f"{where}: {str(e).removeprefix(f'{image}: ')}") from None
        cam = frame.camera
        if (width, height) != (cam.width, cam.height):
            raise InputError(f"{where}: image is {width}x{height}, but w={cam.width}, h={cam.height}")


# ---------------------------------------------------------------------------- what a file says of its world

#: Top-level keys nsim writes into the transforms.json of a poses artifact: ``nsim_scale`` the
#: scale source (``nsim.sfm.metric.ScaleReport.source``), ``nsim_metric`` whether the units are
#: metres, ``nsim_z_up`` whether +z is up with the floor at z = 0. A capture artifact's file has
#: ``nsim_capture`` (ground truth: metric and z-up).
SCALE_KEY, METRIC_KEY, Z_UP_KEY, CAPTURE_KEY = "nsim_scale", "nsim_metric", "nsim_z_up", "nsim_capture"
#: Stored depth value x this = depth in the file's world units (nerfstudio's name for it).
DEPTH_SCALE_KEY = "depth_unit_scale_factor"
#: nerfstudio's default for depth images without a factor: 16-bit PNGs in millimetres.
DEFAULT_DEPTH_UNIT_SCALE = 1e-3


def declared_world(path: str | os.PathLike, data: TransformsData) -> tuple[str | None, bool]:
    """What ``data`` (read from ``path``) declares about its world: (why it is metric or None, z up).

    Only nsim's own keys declare anything: an nsim capture (``nsim_capture``) is metric and z-up;
    a poses artifact says so in ``nsim_metric`` and ``nsim_z_up`` (booleans). Exports of
    PolyCam, Record3D or nerfstudio carry no such marker: their scale is declared with
    ``nsim reconstruct --import ... --metric``.
    """
    extra = data.extra
    if CAPTURE_KEY in extra:
        return f"an nsim capture ({CAPTURE_KEY})", True
    for key in (METRIC_KEY, Z_UP_KEY):
        if key in extra and not isinstance(extra[key], bool):
            raise InputError(f"{path}: {key}: expected true or false, got {extra[key]!r}")
    if METRIC_KEY not in extra and Z_UP_KEY not in extra and SCALE_KEY in extra:  # written before nsim_metric
        source = extra[SCALE_KEY]
        metric = f"{SCALE_KEY}: {source}" if source in ("reference", "known_distance", "camera_height") else None
        return metric, source in ("known_distance", "camera_height", "arbitrary")
    metric = f"{METRIC_KEY}: true" if extra.get(METRIC_KEY) is True else None
    return metric, extra.get(Z_UP_KEY) is True


def depth_unit_scale(path: str | os.PathLike, data: TransformsData, depth_files: list[str]) -> float:
    """Stored depth value x this = depth in the world units of ``data`` (read from ``path``).

    The top-level ``depth_unit_scale_factor`` when present (a number > 0); otherwise 1 when every
    depth file (``depth_files``: names as written) is an EXR (float metres, as nsim writes them),
    else ``DEFAULT_DEPTH_UNIT_SCALE`` (nerfstudio's millimetre PNGs).
    """
    value = data.extra.get(DEPTH_SCALE_KEY)
    if value is not None:
        number = _Reader(Path(path)).number(value, DEPTH_SCALE_KEY)
        if number <= 0.0:
            raise InputError(f"{path}: {DEPTH_SCALE_KEY}: expected a number > 0, got {value!r}")
        return number
    exr = {PurePosixPath(f).suffix.lower() == ".exr" for f in depth_files}
    if len(exr) > 1:
        raise InputError(f"{path}: the depth files are partly EXR, partly not: give {DEPTH_SCALE_KEY} "
                         "(stored value x factor = depth in the file's units)")
    return 1.0 if exr == {True} else DEFAULT_DEPTH_UNIT_SCALE


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

    Poses are rounded to 1e-9 (``nsim.io.canonical``), so the same poses give the same bytes on every CPU.

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
        out["applied_transform"] = round_decimals(data.applied_transform).tolist()
    frames = []
    for i, (frame, cam) in enumerate(zip(data.frames, cameras, strict=True)):
        _check_extra(frame.extra, FRAME_KEYS + INTRINSIC_KEYS, f"frames[{i}].extra")
        d: dict[str, Any] = {"file_path": frame.file_path,
                             "transform_matrix": round_decimals(opencv_to_opengl_c2w(frame.cam_to_world)).tolist()}
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
