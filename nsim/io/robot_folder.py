"""A robot's recording as a plain folder -- images per camera, a TUM trajectory, ROS camera_info YAML, a rig -- as arrays.

The same reader interface as :class:`nsim.io.robot_log.RobotLog`, for recordings that never were a
bag (a dataset's export, a robot whose driver writes files)::

    with RobotFolder("run/") as log:
        front = log.cameras["front"]                    # FolderCameraStream: stamps_ns (N,), camera, frame_id
        rgb = log.image(front, 0)                       # frame 0, decoded now (RGB uint8)
        for i, rgb in log.images(front): ...            # every frame, in order
        front_to_body = log.sensor_to_body(front.frame_id)
        trajectory = log.body_trajectory()              # stamps_ns (N,), body_to_odom (N, 4, 4)

**The layout** (``nsim import-log DIR`` reads a directory this way unless it holds ``metadata.yaml``,
which makes it a ROS 2 bag)::

    trajectory.tum                 the body's pose in the odometry frame, body_to_odom (TUM: stamp in
                                   seconds, tx ty tz qx qy qz qw; repeated stamps dropped with a warning)
    rig.yaml  or  rig.urdf         each sensor's extrinsic, sensor_to_body (below); exactly one of them
                                   (neither in a trajectory-only folder: trajectory.tum alone, no streams)
    cameras/<name>/                colour or grey frames: .png .jpg .jpeg .bmp .tif .tiff .webp .pgm .ppm
        camera_info.yaml           ROS camera_info YAML (below), required
        timestamps.txt | times.csv optional: the frames' stamps (below)
    depth/<name>/                  optional: depth frames, one format per stream: .png (16-bit integers in the
                                   unit below, 0 = no measurement), .exr (channel Z, metres) or .npy ((H, W)
                                   float, metres)
        camera_info.yaml           the depth image's intrinsics, required; with .png frames also their unit,
                                   ``depth_m_per_unit`` (metres per integer: 0.001 millimetres, 0.0002 TUM RGB-D)
        timestamps.txt | times.csv | depth.txt   optional (``depth.txt``: TUM RGB-D's, which also states
                                   the unit: 1/5000 m)
    lidar/<name>/                  optional: point clouds in the sensor's frame, .ply (vertex x y z, and
                                   intensity, ring, time when present) or .npy ((N, 3) float x y z, or a
                                   structured array with fields x, y, z and optionally intensity, ring, time)
        timestamps.txt | times.csv optional

**A TUM RGB-D sequence as downloaded** (``rgb/``, ``rgb.txt``, ``depth/``, ``depth.txt``,
``groundtruth.txt``) is read as it is, given the colour camera's calibration as ``camera_info.yaml``
at its top (TUM ships none; the error lists TUM's published intrinsics per sensor): camera ``rgb``
(frames listed by rgb.txt), depth ``rgb`` (depth.txt's frames, 1/5000 m; TUM registers them to the
colour camera, so they share its intrinsics and extrinsic), the body is the colour camera (frame
``rgb``, extrinsic identity) and its trajectory ``groundtruth.txt``, the camera's optical centre in
the motion-capture frame (``mocap``).

**Depth units are never guessed.** A 16-bit PNG holds integers whose unit the folder states: TUM
RGB-D's ``depth.txt`` beside the frames (its layout: 1/5000 m) or ``depth_m_per_unit`` in the
stream's camera_info.yaml (both: they must agree); otherwise the import stops with one line saying
how. ``depth_scale`` is refused: RealSense calls metres per unit that, Open3D and TUM the inverse,
and the two read each other's files 5x or 5,000,000x wrong. The unit is logged and recorded in the
recording (``recording.json``: ``depth_m_per_unit``, ``depth_unit``).

``<name>`` is the stream's name in the recording and the sensor's name in the rig (``cameras/front``
and ``depth/front`` share the extrinsic of sensor ``front``); it is also the stream's ``frame_id``.

**Timestamps** are integer nanoseconds on the recording's clock. A frame's stamp is its file name
(``1700000000100000000.png``: digits only = nanoseconds; ``1700000000.1.png``: a decimal point =
seconds, as TUM RGB-D names its frames; read exactly, never through a float), unless the folder has
a timestamps file: ``timestamps.txt`` or ``times.csv``, one row per frame, ``#`` lines skipped, the
columns split by commas or blanks: ``stamp`` (the frames then go in natural name order, ``img_2``
before ``img_10``, and the counts must agree) or ``stamp, filename`` (EuRoC's ``data.csv``, TUM
RGB-D's ``rgb.txt``: each row names one frame by its file name, the rows give the order, every frame
must be named). A stamp there follows the same rule (digits only: nanoseconds, a decimal point:
seconds). ``trajectory.tum``'s stamps are seconds (TUM), read exactly to the nanosecond. Per
stream the stamps must increase.

**camera_info.yaml** is the file ``camera_calibration`` writes and ``camera_info_manager`` reads
(kalibr's results convert to it)::

    image_width: 640
    image_height: 480
    camera_name: front                     # optional
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob            # plumb_bob | rational_polynomial | equidistant
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [...]}   # optional, not used
    projection_matrix: {rows: 3, cols: 4, data: [...]}      # optional, not used

It maps to nsim's camera exactly as a bag's CameraInfo does (:func:`nsim.io.rosbag.camera_from_info`,
the raw image's ``K`` and ``D``): plumb_bob -> OPENCV (PINHOLE when D is all zero),
rational_polynomial -> FULL_OPENCV, equidistant -> OPENCV_FISHEYE. The frames are the raw sensor's.
:func:`camera_info_yaml` writes one from an nsim camera.

**rig.yaml**::

    body_frame: body           # optional (default body): the frame trajectory.tum moves
    odom_frame: odom           # optional (default odom): the frame it moves in
    sensors:                   # name -> sensor_to_body, one of three forms
      front: {translation_m: [0.4, 0.0, 0.2], quaternion_wxyz: [0.5, -0.5, 0.5, -0.5]}
      back: {translation_m: [-0.4, 0.0, 0.2], quaternion_xyzw: [-0.5, -0.5, 0.5, 0.5]}   # ROS order
      top: {sensor_to_body: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1]]}

A quaternion is normalised as tf does; a 4 x 4 must be rigid. **rig.urdf**: a URDF
(:func:`nsim.sensors.urdf.load_urdf`, joints at position 0); the sensor ``<name>`` is the link named
``<name>`` (for a camera, its optical frame: +x right, +y down, +z forward); the body is the link
``base_link``, ``body`` or ``base_footprint`` (the first there is), else the root link; the odometry
frame is ``odom``.

**Errors.** Bad input raises :class:`~nsim.errors.InputError` with one line naming the file (and
line or key): no trajectory.tum, a stream without camera_info.yaml, an unknown distortion model, a
sensor missing from the rig, stamps that do not increase, a frame that does not decode or has
another size than its camera_info says, a timestamps file whose count differs from the frames', a
file that is not named by its stamp when there is no timestamps file, a file that links outside the
folder. What is checked when the folder opens: the trajectory, the rig, every camera_info.yaml and
timestamps file, and each stream's first frame; the other frames when they are read.

Everything here returns new arrays: nothing read is modified in place.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.recording_streams import BODY_FRAMES, CameraStreamInfo, DepthUnit, Trajectory
from nsim.io.rosbag import RING_FIELDS, TIME_FIELDS, LidarPoints, camera_from_info, matrix_from_transform
from nsim.io.topic_selection import check_keys

log = logging.getLogger(__name__)

TRAJECTORY_FILE = "trajectory.tum"
RIG_FILES = ("rig.yaml", "rig.urdf")
CAMERA_INFO_FILE = "camera_info.yaml"
TIMESTAMP_FILES = ("timestamps.txt", "times.csv", "rgb.txt", "depth.txt")  # the last two: TUM RGB-D's names
#: TUM RGB-D's depth list; beside 16-bit PNG depth it states their unit, 1/5000 m (TUM's file formats page).
TUM_DEPTH_FILE = "depth.txt"
#: TUM RGB-D's ground truth: the colour camera's optical centre in the motion-capture frame (TUM format).
TUM_GROUNDTRUTH_FILE = "groundtruth.txt"
TUM_DEPTH_UNIT = DepthUnit(1 / 5000, "TUM RGB-D layout (depth.txt beside the frames): 1/5000 m")
#: camera_info.yaml's key for a 16-bit depth PNG's unit, metres per integer.
DEPTH_UNIT_KEY = "depth_m_per_unit"
#: Stream folders: folder -> the stream kind it holds.
STREAM_DIRS = {"cameras": "camera", "depth": "depth", "lidar": "lidar"}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")
#: Depth file formats and the ROS encoding each stands for (16-bit millimetres, float metres).
DEPTH_SUFFIXES = {".png": "16UC1", ".exr": "32FC1", ".npy": "32FC1"}
LIDAR_SUFFIXES = (".ply", ".npy")
CAMERA_INFO_KEYS = ("image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                    "distortion_coefficients", "rectification_matrix", "projection_matrix")
RIG_KEYS = ("body_frame", "odom_frame", "sensors")
_NS = 1_000_000_000


def is_tum_sequence(path: str | os.PathLike) -> bool:
    """A TUM RGB-D sequence as downloaded: ``rgb.txt`` beside ``rgb/`` (and no ``cameras/`` folder)."""
    path = Path(path)
    return (path / "rgb.txt").is_file() and (path / "rgb").is_dir() and not (path / "cameras").exists()


def is_robot_folder(path: str | os.PathLike) -> bool:
    """True for a directory that is not a ROS 2 bag (a bag directory holds ``metadata.yaml``)."""
    path = Path(path)
    return path.is_dir() and not (path / "metadata.yaml").exists()


# ---------------------------------------------------------------------------- stamps


def stamp_ns(text: str, where: str, *, unit: str = "auto") -> int:
    """Integer nanoseconds of a stamp written as text, exactly (no float in between).

    unit ``auto``: digits only are nanoseconds, anything else numeric (``12.5``, ``1.7e9``) seconds;
    ``s``: always seconds (TUM). Halves of a nanosecond round to even. InputError naming ``where``
    for text that is not a finite number.
    """
    text = text.strip()
    if unit == "auto" and re.fullmatch(r"\d+", text):
        return int(text)
    try:
        seconds = Decimal(text)
    except InvalidOperation:
        raise InputError(f"{where}: {text!r} is not a timestamp (nanoseconds, or seconds with a decimal point)") \
            from None
    if not seconds.is_finite():
        raise InputError(f"{where}: {text!r} is not a finite timestamp")
    return int((seconds * _NS).to_integral_value(rounding=ROUND_HALF_EVEN))


def _natural_key(name: str) -> tuple:
    """Sort key putting ``img_2`` before ``img_10``."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", name) if p)


def read_tum_ns(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``stamps_ns (N,)`` int64 and ``body_to_odom (N, 4, 4)`` of a TUM file.

    The poses and every check are :func:`nsim.io.tum.read_tum`'s (a repeated stamp is dropped with a
    warning); the stamps are its first column read again as exact decimals, so a stamp written to the
    nanosecond (``1700000000.123456789``) comes back to the nanosecond, which float seconds cannot hold.
    """
    from nsim.io.tum import read_tum

    traj = read_tum(path)
    tokens = [line.split()[0] for line in path.read_text().splitlines()
              if line.split() and not line.split()[0].startswith("#")]
    as_read = np.array([float(t) for t in tokens])
    kept = np.r_[True, np.diff(as_read) != 0]  # read_tum's rule for repeats, on the same floats
    stamps = np.array([stamp_ns(t, f"{path}", unit="s") for t, k in zip(tokens, kept, strict=True) if k], np.int64)
    if len(stamps) != len(traj) or (len(stamps) > 1 and np.any(np.diff(stamps) <= 0)):
        raise InputError(f"{path}: timestamps closer than a nanosecond; nsim keeps stamps in nanoseconds")
    return stamps, traj.poses_se3()


def frame_stamps(folder: Path, suffixes: tuple[str, ...], table: Path | None = None) -> tuple[list[Path], np.ndarray]:
    """The frames of one stream folder in order and their ``stamps_ns (N,)`` int64 (module docstring).

    Files with other suffixes (and camera_info.yaml, the timestamps file, hidden files) are not
    frames. ``table``: the timestamps file when it lies elsewhere (a TUM RGB-D sequence's ``rgb.txt``
    beside ``rgb/``). InputError naming the file for a frame without a stamp, a timestamps file that
    does not match the frames, or stamps that do not increase.
    """
    frames = {p.name: p for p in folder.iterdir()
              if p.suffix.lower() in suffixes and not p.name.startswith(".") and not p.is_dir()}
    stamp_files = [table] if table is not None else [folder / n for n in TIMESTAMP_FILES if (folder / n).is_file()]
    if len(stamp_files) > 1:
        raise InputError(f"{folder}: both {' and '.join(TIMESTAMP_FILES)}; keep one")
    if not stamp_files:
        named = []
        for name, p in frames.items():
            stem = name[: -len(p.suffix)]
            if not re.fullmatch(r"\d+(\.\d+)?", stem):
                raise InputError(f"{p}: not named by its timestamp (nanoseconds, or seconds with a decimal point) "
                                 f"and no {' or '.join(TIMESTAMP_FILES)} beside it")
            named.append((stamp_ns(stem, str(p)), name))
        named.sort()
        for (a, name_a), (b, name_b) in zip(named, named[1:], strict=False):
            if a == b:
                raise InputError(f"{folder / name_b}: the same timestamp as {name_a} ({a} ns); stamps must increase")
        return [frames[n] for _, n in named], np.array([s for s, _ in named], np.int64).reshape(-1)
    inside = folder if table is None else table.parent
    table = stamp_files[0]
    if not table.resolve().is_relative_to(inside.resolve()):
        raise InputError(f"{table}: links outside its folder")
    rows: list[tuple[int, list[str]]] = []
    for number, line in enumerate(table.read_text().splitlines(), start=1):
        cells = [c for c in re.split(r"[,\s]+", line.strip()) if c]
        if cells and not cells[0].startswith("#"):
            rows.append((number, cells))
    widths = {len(cells) for _, cells in rows}
    if len(widths) > 1 or widths - {1, 2}:
        number = next(n for n, c in rows if len(c) not in (1, 2) or len(c) != len(rows[0][1]))
        raise InputError(f"{table}:{number}: expected one column (stamp) or two (stamp, filename) on every row")
    if widths == {2}:
        order = []
        for number, (_, name) in rows:
            name = Path(name).name
            if name not in frames:
                raise InputError(f"{table}:{number}: no frame {name!r} in {folder}")
            order.append(name)
        if len(set(order)) != len(order):
            dup = next(n for n in order if order.count(n) > 1)
            raise InputError(f"{table}: names {dup!r} twice")
        if missing := sorted(set(frames) - set(order), key=_natural_key):
            raise InputError(f"{table}: {len(missing)} frame(s) not listed, first {missing[0]!r}")
    else:
        order = sorted(frames, key=_natural_key)
        if len(rows) != len(order):
            raise InputError(f"{table}: {len(rows)} timestamps for {len(order)} frames in {folder}")
    stamps = np.array([stamp_ns(cells[0], f"{table}:{number}") for number, cells in rows], np.int64).reshape(-1)
    if len(stamps) > 1 and (bad := np.flatnonzero(np.diff(stamps) <= 0)).size:
        k = int(bad[0]) + 1
        raise InputError(f"{table}:{rows[k][0]}: timestamp {stamps[k]} ns is not after the previous row's "
                         f"{stamps[k - 1]} ns (stamps must increase)")
    return [frames[n] for n in order], stamps


# ---------------------------------------------------------------------------- camera_info YAML


def _yaml(path: Path) -> Any:
    from nsim.config import parse_yaml

    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    return parse_yaml(text, path, error=InputError)


def _matrix(data: Mapping, key: str, shape: tuple[int, int] | None, where: str) -> list[float]:
    """The ``data`` list of a camera_info matrix ``{rows, cols, data}``; ``shape`` None: any ``1 x n``."""
    value = data[key]
    if not isinstance(value, Mapping):
        raise InputError(f"{where}.{key}: expected a mapping with rows, cols and data, got {value!r}")
    check_keys(value, ("rows", "cols", "data"), f"{where}.{key}")
    rows, cols, values = value.get("rows"), value.get("cols"), value.get("data")
    if not isinstance(values, list) or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                               for v in values):
        raise InputError(f"{where}.{key}.data: expected a list of numbers, got {values!r}")
    want = shape if shape is not None else (1, len(values))
    if (rows, cols) != want or len(values) != want[0] * want[1]:
        raise InputError(f"{where}.{key}: expected rows {want[0]}, cols {want[1]} and as many values, got rows "
                         f"{rows!r}, cols {cols!r}, {len(values)} values")
    return [float(v) for v in values]


def camera_from_info_yaml(data: Any, where: str = CAMERA_INFO_FILE) -> Camera:
    """nsim Camera of parsed ROS camera_info YAML (module docstring), through
    :func:`nsim.io.rosbag.camera_from_info` (the raw image: ``K`` and ``D``). Unknown keys, missing
    keys, wrong shapes and every error of ``camera_from_info`` raise InputError naming ``where``."""
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected ROS camera_info YAML (a mapping), got {type(data).__name__}")
    check_keys(data, CAMERA_INFO_KEYS, where)
    for key in ("image_width", "image_height", "camera_matrix", "distortion_model", "distortion_coefficients"):
        if key not in data:
            raise InputError(f"{where}: missing key {key!r}")
    size = [data["image_width"], data["image_height"]]
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size):
        raise InputError(f"{where}: image_width and image_height must be positive integers, got {size}")
    if not isinstance(data["distortion_model"], str):
        raise InputError(f"{where}.distortion_model: expected a name, got {data['distortion_model']!r}")
    rect = _matrix(data, "rectification_matrix", (3, 3), where) if "rectification_matrix" in data else [0.0] * 9
    proj = _matrix(data, "projection_matrix", (3, 4), where) if "projection_matrix" in data else [0.0] * 12
    info = SimpleNamespace(  # a CameraInfo message's fields, as camera_from_info reads them
        width=size[0], height=size[1], distortion_model=data["distortion_model"],
        k=_matrix(data, "camera_matrix", (3, 3), where), d=_matrix(data, "distortion_coefficients", None, where),
        r=rect, p=proj, binning_x=0, binning_y=0, roi=SimpleNamespace(x_offset=0, y_offset=0, width=0, height=0))
    return camera_from_info(info, rectified=False, where=where)


def read_camera_info_yaml(path: str | os.PathLike) -> Camera:
    """nsim Camera of a ROS camera_info YAML file (:func:`camera_from_info_yaml`)."""
    path = Path(path)
    return camera_from_info_yaml(_yaml(path), str(path))


def camera_info_yaml(camera: Camera, name: str = "") -> dict[str, Any]:
    """ROS camera_info YAML content of ``camera`` (the inverse of :func:`camera_from_info_yaml`), with the
    model mapping of :func:`nsim.io.rosbag.camera_info_message`; dump it with ``yaml.safe_dump``."""
    from nsim.io.rosbag import camera_info_message

    msg = camera_info_message(0, name, camera)

    def matrix(values, rows: int) -> dict[str, Any]:
        values = [float(v) for v in np.asarray(values).reshape(-1)]
        return {"rows": rows, "cols": len(values) // rows, "data": values}

    return {"image_width": int(msg.width), "image_height": int(msg.height), "camera_name": name,
            "camera_matrix": matrix(msg.k, 3), "distortion_model": str(msg.distortion_model),
            "distortion_coefficients": matrix(msg.d, 1), "rectification_matrix": matrix(msg.r, 3),
            "projection_matrix": matrix(msg.p, 3)}


# ---------------------------------------------------------------------------- the rig


@dataclass(frozen=True)
class FolderRig:
    """The extrinsics of a folder's rig: ``sensor_to_body`` name -> ``(4, 4)``; the frames' names;
    ``path``: the rig file they were read from."""

    path: Path | None  # None: a trajectory-only folder, without a rig file
    sensor_to_body: Mapping[str, np.ndarray]
    body_frame: str = "body"
    odom_frame: str = "odom"


def _sensor_to_body(entry: Any, where: str) -> np.ndarray:
    """``(4, 4)`` of one rig.yaml sensor entry (module docstring)."""
    forms = ("translation_m", "quaternion_wxyz", "quaternion_xyzw", "sensor_to_body")
    if not isinstance(entry, Mapping):
        raise InputError(f"{where}: expected a mapping (translation_m with quaternion_wxyz or quaternion_xyzw, or "
                         f"sensor_to_body), got {entry!r}")
    check_keys(entry, forms, where)

    def numbers(key: str, n: int) -> np.ndarray:
        value = np.asarray(entry[key], dtype=object).reshape(-1)
        if value.size != n or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            raise InputError(f"{where}.{key}: expected {n} numbers, got {entry[key]!r}")
        out = value.astype(np.float64)
        if not np.all(np.isfinite(out)):
            raise InputError(f"{where}.{key}: not finite")
        return out

    if "sensor_to_body" in entry:
        if set(entry) != {"sensor_to_body"}:
            raise InputError(f"{where}: give sensor_to_body alone, or translation_m with a quaternion")
        from nsim.geometry.transforms import is_rotation

        m = numbers("sensor_to_body", 16).reshape(4, 4)
        if not np.allclose(m[3], [0, 0, 0, 1], atol=0) or not bool(is_rotation(m[:3, :3])):
            raise InputError(f"{where}.sensor_to_body: not a rigid transform (rotation and translation, last row "
                             "0 0 0 1)")
        return m
    quats = [k for k in ("quaternion_wxyz", "quaternion_xyzw") if k in entry]
    if "translation_m" not in entry or len(quats) != 1:
        raise InputError(f"{where}: expected translation_m and one of quaternion_wxyz, quaternion_xyzw")
    t = numbers("translation_m", 3)
    q = numbers(quats[0], 4)
    x, y, z, w = q if quats[0] == "quaternion_xyzw" else q[[1, 2, 3, 0]]
    transform = SimpleNamespace(translation=SimpleNamespace(x=t[0], y=t[1], z=t[2]),
                                rotation=SimpleNamespace(x=x, y=y, z=z, w=w))
    try:  # as tf reads a transform: the quaternion normalised
        return matrix_from_transform(transform)
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None


def read_rig_yaml(path: Path) -> FolderRig:
    """A :class:`FolderRig` from rig.yaml (module docstring); strict keys, errors name the key."""
    data = _yaml(path)
    where = str(path)
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected a mapping with sensors (and body_frame, odom_frame)")
    check_keys(data, RIG_KEYS, where)
    sensors = data.get("sensors")
    if not isinstance(sensors, Mapping) or not all(isinstance(k, str) and k for k in sensors):
        raise InputError(f"{where}.sensors: expected a mapping from sensor names to extrinsics, got {sensors!r}")
    frames = {}
    for key in ("body_frame", "odom_frame"):
        if key in data:
            if not isinstance(data[key], str) or not data[key].strip("/"):
                raise InputError(f"{where}.{key}: expected a frame name, got {data[key]!r}")
            frames[key] = data[key].strip("/")
    return FolderRig(path, {name: _sensor_to_body(e, f"{where}.sensors.{name}") for name, e in sensors.items()},
                     **frames)


def read_rig_urdf(path: Path, names: list[str]) -> FolderRig:
    """A :class:`FolderRig` of the sensors ``names`` from a URDF (module docstring): each the link of
    its name, in the body link's frame. A name without a link raises InputError naming the file."""
    from nsim.sensors.urdf import load_urdf

    urdf = load_urdf(path)
    body = next((f for f in BODY_FRAMES if f in urdf.links), urdf.root_link)
    out = {}
    for name in names:
        if name not in urdf.links:
            raise InputError(f"{path}: no link {name!r} for sensor {name!r} (links: {', '.join(urdf.links)})")
        out[name] = urdf.link_to_link(name, body)
    return FolderRig(path, out, body_frame=body)


# ---------------------------------------------------------------------------- streams


@dataclass(frozen=True)
class FolderCameraStream(CameraStreamInfo):
    """One camera (or depth camera) folder; frames are decoded on demand by :meth:`RobotFolder.image`.

    The attributes of :class:`nsim.io.recording_streams.CameraStreamInfo` (what a recording needs): topic: the
    stream's folder relative to the recording (``cameras/front``); info_topic: its camera_info.yaml,
    relative; frame_id: the stream's name (its sensor in the rig); camera: from camera_info.yaml;
    encoding: what the frames hold, in ROS's words (rgb8, mono8, mono16; depth 16UC1 for millimetre
    PNG, 32FC1 for metres); stamps_ns: (N,) int64; files: (N,) the frames, in order.
    """

    files: tuple[Path, ...]
    stamps_from_bag: int = 0
    depth_unit: DepthUnit | None = None  # depth: what the frames' numbers are (``depth_unit_of``)


@dataclass(frozen=True)
class FolderLidarStream:
    """One LiDAR folder (the attributes of :class:`nsim.io.recording_streams.LidarStream` a recording needs);
    fields: the first cloud's field names, in their order; files: (N,) the clouds, in order."""

    name: str
    topic: str
    frame_id: str
    fields: tuple[str, ...]
    stamps_ns: np.ndarray
    files: tuple[Path, ...]
    stamps_from_bag: int = 0

    def __len__(self) -> int:
        return len(self.stamps_ns)


def _image_encoding(image: np.ndarray) -> str | None:
    """The ROS encoding of a decoded colour/grey frame, None for one nsim does not keep."""
    if image.dtype == np.uint8:
        return "rgb8" if image.ndim == 3 else "mono8"
    if image.dtype == np.uint16 and image.ndim == 2:
        return "mono16"
    return None


def read_frame(path: Path) -> np.ndarray:
    """A colour or grey frame as a bag's compressed image decodes (:func:`nsim.io.rosbag.read_compressed_image`):
    ``(H, W, 3)`` uint8 RGB (alpha dropped), ``(H, W)`` uint8 or uint16 grey."""
    from nsim.io.rosbag import read_compressed_image

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    image = read_compressed_image(SimpleNamespace(format=path.suffix.lstrip(".").lower(),
                                                  data=np.frombuffer(data, np.uint8)), where=str(path))
    if _image_encoding(image) is None:
        raise InputError(f"{path}: a {image.dtype} image of shape {image.shape}; nsim reads 8-bit colour and 8- or "
                         "16-bit grey")
    return image


def _npy(path: Path) -> np.ndarray:
    """The array of a .npy file, its header checked before the data is read; never a pickle."""
    try:
        array = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({' '.join(str(exc).split())})") from None
    if not isinstance(array, np.ndarray):
        raise InputError(f"{path}: expected one .npy array")
    return array


def depth_unit(folder: Path, info: Path, stated: Any, suffix: str, tum: bool | None = None) -> DepthUnit | None:
    """The unit of a depth folder's frames (module docstring): ``stated`` (camera_info.yaml's
    ``depth_m_per_unit``, or None) and TUM's ``depth.txt`` for 16-bit PNGs; metres for float frames.
    InputError for a PNG folder that states none, a unit that is not a positive number, two that disagree,
    or a unit stated for float frames. ``tum``: whether TUM's layout states the unit (None: ``depth.txt`` in
    ``folder``)."""
    if stated is not None and (isinstance(stated, bool) or not isinstance(stated, int | float)
                               or not math.isfinite(stated) or stated <= 0):
        raise InputError(f"{info}: {DEPTH_UNIT_KEY} must be a positive number of metres per unit, got {stated!r}")
    if suffix != ".png":
        if stated is not None:
            raise InputError(f"{info}: {DEPTH_UNIT_KEY} is for 16-bit PNG depth; {suffix or 'no'} frames are metres")
        return DepthUnit(1.0, f"{suffix} frames: metres") if suffix else None
    tum = (folder / TUM_DEPTH_FILE).is_file() if tum is None else tum
    if stated is None:
        if tum:
            return TUM_DEPTH_UNIT
        raise InputError(f"{folder}: 16-bit PNG depth without its unit: add {DEPTH_UNIT_KEY} to {info.name} (metres "
                         f"per integer: 0.001 for millimetres, 0.0002 for TUM RGB-D), or keep TUM's {TUM_DEPTH_FILE} "
                         "beside the frames")
    if tum and not math.isclose(float(stated), TUM_DEPTH_UNIT.m_per_unit, rel_tol=1e-9):
        raise InputError(f"{info}: {DEPTH_UNIT_KEY} {stated} disagrees with {TUM_DEPTH_FILE} beside the frames "
                         f"(TUM RGB-D: {TUM_DEPTH_UNIT.m_per_unit} m per unit); keep one")
    return DepthUnit(float(stated), f"{DEPTH_UNIT_KEY} in {info.name}")


def read_depth_frame(path: Path, unit: DepthUnit | None) -> np.ndarray:
    """``(H, W)`` float32 metres of a depth file (NaN: no measurement where a PNG says 0); ``unit``: a PNG's."""
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_depth_png

    suffix = path.suffix.lower()
    if suffix == ".png":
        if unit is None:
            raise InputError(f"{path}: 16-bit PNG depth without its unit")
        return read_depth_png(path, unit.units_per_m)
    if suffix == ".exr":
        return read_depth_exr(path)
    array = _npy(path)
    if array.ndim != 2 or array.dtype.kind != "f":
        raise InputError(f"{path}: expected an (H, W) float array of metres, got {array.dtype} {array.shape}")
    return np.array(array, dtype=np.float32)


def read_cloud(path: Path, *, finite_only: bool = False) -> LidarPoints:
    """A point cloud file as :class:`nsim.io.rosbag.LidarPoints` (intensity, ring and time by the field
    names a PointCloud2 would use: ``RING_FIELDS``, ``TIME_FIELDS``)."""
    from nsim.io.ply import read_ply

    if path.suffix.lower() == ".ply":
        cloud = read_ply(path)
        xyz, fields = cloud.xyz, dict(cloud.fields)
    else:
        array = _npy(path)
        if array.dtype.names:
            if missing := [c for c in "xyz" if c not in array.dtype.names]:
                raise InputError(f"{path}: a structured array without {'/'.join(missing)} "
                                 f"(fields: {', '.join(array.dtype.names)})")
            xyz = np.stack([array[c] for c in "xyz"], axis=-1)
            fields = {n: array[n] for n in array.dtype.names if n not in "xyz"}
        elif array.ndim == 2 and array.shape[1] == 3 and array.dtype.kind == "f":
            xyz, fields = array, {}
        else:
            raise InputError(f"{path}: expected (N, 3) float x y z or a structured array with x, y, z; got "
                             f"{array.dtype} {array.shape}")
    xyz = np.array(xyz, dtype=np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(xyz), axis=1) if finite_only else slice(None)

    def scalar(name: str | None, dtype) -> np.ndarray | None:
        if name is None or name not in fields or np.asarray(fields[name]).shape != (len(xyz),):
            return None
        return np.asarray(fields[name])[keep].astype(dtype)

    time_field = next((n for n in TIME_FIELDS if n in fields), None)
    ring = next((r for n in RING_FIELDS if (r := scalar(n, np.int64)) is not None), None)
    return LidarPoints(xyz_m=np.ascontiguousarray(xyz[keep]), intensity=scalar("intensity", np.float64), ring=ring,
                       time=scalar(time_field, np.float64), time_field=time_field)


def _cloud_fields(path: Path) -> tuple[str, ...]:
    """The field names of a cloud file, in their order (x, y, z first for an (N, 3) array)."""
    if path.suffix.lower() == ".ply":
        from nsim.io.ply import read_ply

        cloud = read_ply(path)
        return ("x", "y", "z") + (("red", "green", "blue") if cloud.rgb is not None else ()) + tuple(cloud.fields)
    array = _npy(path)
    return tuple(array.dtype.names) if array.dtype.names else ("x", "y", "z")


# ---------------------------------------------------------------------------- the reader


class RobotFolder:
    """An open recording folder (see the module docstring), with :class:`nsim.io.robot_log.RobotLog`'s
    interface: ``name``, ``topics`` (the stream folders), ``cameras``, ``depth`` (name ->
    :class:`FolderCameraStream`), ``lidars`` (name -> :class:`FolderLidarStream`), ``rig``
    (:class:`FolderRig`), ``body_frame``, ``odom_frame``; :meth:`image`, :meth:`images`,
    :meth:`cloud`, :meth:`clouds`, :meth:`sensor_to_body`, :meth:`body_trajectory`; a context manager
    (there is nothing to close)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.name = str(self.path)
        if not self.path.is_dir():
            raise InputError(f"{self.path}: not a directory")
        self._root = self.path.resolve()
        if is_tum_sequence(self.path):
            self._open_tum_sequence()
            return
        trajectory = self.path / TRAJECTORY_FILE
        if not trajectory.is_file():
            raise InputError(f"{trajectory}: no such file; a recording folder needs the body's trajectory (TUM) "
                             "(a ROS 2 bag directory has metadata.yaml)")
        self._trajectory, self._trajectory_file = read_tum_ns(self._inside(trajectory)), TRAJECTORY_FILE
        self.cameras: dict[str, FolderCameraStream] = {}
        self.depth: dict[str, FolderCameraStream] = {}
        self.lidars: dict[str, FolderLidarStream] = {}
        for folder, kind in STREAM_DIRS.items():
            for d in sorted(p for p in (self.path / folder).glob("*") if p.is_dir() and not p.name.startswith(".")):
                if kind == "lidar":
                    self.lidars[d.name] = self._lidar_stream(d)
                else:
                    group = self.depth if kind == "depth" else self.cameras
                    group[d.name] = self._camera_stream(d, kind == "depth")
        self.topics = [s.topic for group in (self.cameras, self.depth, self.lidars) for s in group.values()]
        names = sorted({s.frame_id for group in (self.cameras, self.depth, self.lidars) for s in group.values()})
        rigs = [self.path / n for n in RIG_FILES if (self.path / n).is_file()]
        if not self.topics:
            if rigs:  # a rig without sensors is a misnamed stream folder more likely than a trajectory alone
                raise InputError(f"{self.path}: {rigs[0].name} but no stream folders (cameras/<name>/, depth/<name>/, "
                                 f"lidar/<name>/; a trajectory-only folder holds {TRAJECTORY_FILE} alone)")
            self.rig = FolderRig(None, {})  # a trajectory-only recording: no sensor needs an extrinsic
            self.body_frame, self.odom_frame = self.rig.body_frame, self.rig.odom_frame
            log.info("%s: no stream folders and no rig: a trajectory-only recording (%s alone)", self.path,
                     TRAJECTORY_FILE)
            return
        if len(rigs) != 1:
            raise InputError(f"{self.path}: " + ("no rig.yaml or rig.urdf (the sensors' extrinsics)" if not rigs
                                                 else "both rig.yaml and rig.urdf; keep one"))
        rig_path = self._inside(rigs[0])
        self.rig = read_rig_yaml(rig_path) if rig_path.suffix == ".yaml" else read_rig_urdf(rig_path, names)
        self.body_frame, self.odom_frame = self.rig.body_frame, self.rig.odom_frame

    def _open_tum_sequence(self) -> None:
        """A TUM RGB-D sequence as downloaded (module docstring): one colour camera ``rgb`` and its registered depth,
        the body being the colour camera (ground truth: its optical centre in the motion-capture frame)."""
        truth = self.path / TUM_GROUNDTRUTH_FILE
        if not truth.is_file():
            raise InputError(f"{truth}: no such file; a TUM RGB-D sequence's body trajectory is its ground truth")
        info = self.path / CAMERA_INFO_FILE
        if not info.is_file():
            raise InputError(f"{info}: no such file; write the colour camera's calibration as ROS camera_info YAML "
                             "(TUM's published intrinsics: freiburg1 fx 517.3 fy 516.5 cx 318.6 cy 255.3, plumb_bob "
                             "0.2624 -0.9531 -0.0054 0.0026 1.1633; freiburg2 520.9 521.0 325.1 249.7, 0.2312 -0.7849 "
                             "-0.0033 -0.0001 0.9172; freiburg3 535.4 539.2 320.1 247.6, none)")
        self._trajectory, self._trajectory_file = read_tum_ns(self._inside(truth)), TUM_GROUNDTRUTH_FILE
        self.cameras = {"rgb": self._camera_stream(self.path / "rgb", False, info=info,
                                                   table=self._inside(self.path / "rgb.txt"), name="rgb")}
        self.depth = {}
        if (self.path / TUM_DEPTH_FILE).is_file() and (self.path / "depth").is_dir():
            self.depth["rgb"] = self._camera_stream(self.path / "depth", True, info=info,
                                                    table=self._inside(self.path / TUM_DEPTH_FILE), name="rgb")
        self.lidars = {}
        self.topics = [s.topic for group in (self.cameras, self.depth) for s in group.values()]
        self.rig = FolderRig(None, {"rgb": np.eye(4)}, "rgb", "mocap")
        self.body_frame, self.odom_frame = self.rig.body_frame, self.rig.odom_frame
        log.info("%s: a TUM RGB-D sequence: camera rgb (%d frames), depth %s, the body trajectory from %s (the colour "
                 "camera in the motion-capture frame, %d poses)", self.path, len(self.cameras["rgb"]),
                 f"({len(self.depth['rgb'])} frames, registered to rgb)" if self.depth else "none",
                 TUM_GROUNDTRUTH_FILE, len(self._trajectory[0]))

    def _inside(self, path: Path) -> Path:
        """``path``, refused when it (through a link) lies outside the folder."""
        if not path.resolve().is_relative_to(self._root):
            raise InputError(f"{path}: links outside the recording folder {self.path}")
        return path

    def _camera_stream(self, d: Path, depth: bool, *, info: Path | None = None, table: Path | None = None,
                       name: str | None = None) -> FolderCameraStream:
        """The stream of frames folder ``d``; a TUM RGB-D sequence gives its ``info`` (the sequence's
        camera_info.yaml), ``table`` (rgb.txt, depth.txt) and ``name`` (both streams are the colour camera's)."""
        topic = d.relative_to(self.path).as_posix()
        name = name or d.name
        info = info or d / CAMERA_INFO_FILE
        if not info.is_file():
            raise InputError(f"{info}: no such file; every {'depth' if depth else 'camera'} folder needs its ROS "
                             "camera_info YAML")
        data = _yaml(self._inside(info))
        stated = None
        if depth and isinstance(data, Mapping):
            data = dict(data)
            if "depth_scale" in data:
                raise InputError(f"{info}: depth_scale is ambiguous (RealSense: metres per unit; Open3D, TUM: units "
                                 f"per metre); write {DEPTH_UNIT_KEY} (metres per integer: 0.001 for millimetres, "
                                 "0.0002 for TUM RGB-D's 1/5000 m)")
            stated = data.pop(DEPTH_UNIT_KEY, None)
        camera = camera_from_info_yaml(data, str(info))
        files, stamps = frame_stamps(d, tuple(DEPTH_SUFFIXES) if depth else IMAGE_SUFFIXES, table)
        files = [self._inside(p) for p in files]
        encoding, unit = "", None
        if depth:
            suffixes = sorted({p.suffix.lower() for p in files})
            if len(suffixes) > 1:
                raise InputError(f"{d}: depth frames in several formats ({', '.join(suffixes)}); keep one")
            encoding = DEPTH_SUFFIXES[suffixes[0]] if suffixes else ""
            unit = depth_unit(d, info, stated, suffixes[0] if suffixes else "",
                              tum=None if table is None else table.name == TUM_DEPTH_FILE)
            if unit is not None:
                log.info("%s: %s depth, %g m per unit (%s)", topic, suffixes[0], unit.m_per_unit, unit.source)
        stream = FolderCameraStream(name, topic, info.relative_to(self.path).as_posix(), name, camera, encoding, depth,
                                    stamps, tuple(files), depth_unit=unit)
        if files:  # the first frame decodes, at the camera's size; it sets the stream's encoding
            first = self._frame_checked(stream, 0)
            if not depth:
                stream = dataclasses.replace(stream, encoding=_image_encoding(first))
        return stream

    def _lidar_stream(self, d: Path) -> FolderLidarStream:
        files, stamps = frame_stamps(d, LIDAR_SUFFIXES)
        files = [self._inside(p) for p in files]
        fields = _cloud_fields(files[0]) if files else ()
        return FolderLidarStream(d.name, d.relative_to(self.path).as_posix(), d.name, fields, stamps, tuple(files))

    # ------------------------------------------------------------------ reading frames

    def _frame_checked(self, stream: FolderCameraStream, i: int) -> np.ndarray:
        path = stream.files[i]
        image = read_depth_frame(path, stream.depth_unit) if stream.is_depth else read_frame(path)
        cam = stream.camera
        if image.shape[:2] != (cam.height, cam.width):
            raise InputError(f"{path}: the image is {image.shape[1]}x{image.shape[0]}, its camera_info "
                             f"({stream.info_topic}) says {cam.width}x{cam.height}")
        if not stream.is_depth and stream.encoding and _image_encoding(image) != stream.encoding:
            raise InputError(f"{path}: {_image_encoding(image)}, the stream began with {stream.encoding}")
        return image

    def image(self, stream: FolderCameraStream, i: int) -> np.ndarray:
        """Frame ``i`` of a camera or depth stream, decoded: ``(H, W, 3)`` uint8 RGB, ``(H, W)`` uint8/uint16
        grey, or for depth ``(H, W)`` float32 metres -- what :meth:`RobotLog.image` gives for a bag."""
        if not 0 <= i < len(stream):
            raise IndexError(f"{stream.topic}: frame {i} out of range ({len(stream)} frames)")
        return self._frame_checked(stream, i)

    def images(self, stream: FolderCameraStream) -> Iterator[tuple[int, np.ndarray]]:
        """Every frame of a stream in order, ``(i, image)`` (one frame in memory)."""
        for i in range(len(stream)):
            yield i, self._frame_checked(stream, i)

    def cloud(self, stream: FolderLidarStream, i: int, *, finite_only: bool = False) -> LidarPoints:
        """Cloud ``i`` of a LiDAR stream (points in the sensor's frame)."""
        if not 0 <= i < len(stream):
            raise IndexError(f"{stream.topic}: cloud {i} out of range ({len(stream)} clouds)")
        return read_cloud(stream.files[i], finite_only=finite_only)

    def clouds(self, stream: FolderLidarStream, *, finite_only: bool = False) -> Iterator[tuple[int, LidarPoints]]:
        """Every cloud of a stream in order, ``(i, points)``."""
        for i in range(len(stream)):
            yield i, read_cloud(stream.files[i], finite_only=finite_only)

    # ------------------------------------------------------------------ frames and motion

    def sensor_to_body(self, frame_id: str, body_frame: str | None = None) -> np.ndarray:
        """``sensor_to_body (4, 4)`` of the sensor ``frame_id`` (a stream's name) from the rig file."""
        if body_frame is not None and body_frame != self.body_frame:
            raise InputError(f"{self.rig.path}: the rig gives extrinsics in {self.body_frame!r}, not {body_frame!r}")
        if frame_id not in self.rig.sensor_to_body:
            known = ", ".join(sorted(self.rig.sensor_to_body)) or "none"
            raise InputError(f"{self.rig.path}: no sensor {frame_id!r} (the stream folder of that name needs its "
                             f"extrinsic; sensors: {known})")
        return np.array(self.rig.sensor_to_body[frame_id], dtype=np.float64)

    def body_trajectory(self, source: str = "auto") -> Trajectory:
        """The body's poses in the odometry frame from trajectory.tum (:class:`nsim.io.recording_streams.Trajectory`).

        source: ``auto``; ``tf`` and ``odometry`` name a bag's topics, which a folder has not (InputError)."""
        if source not in ("auto", "tf", "odometry"):
            raise ValueError(f"source: expected auto, tf or odometry, got {source!r}")
        if source != "auto":
            raise InputError(f"{self.path}: trajectory={source} reads a bag's topics; a folder's trajectory is "
                             f"{TRAJECTORY_FILE} (trajectory=auto)")
        stamps, body_to_odom = self._trajectory
        return Trajectory(stamps.copy(), body_to_odom.copy(), self.odom_frame, self.body_frame, self._trajectory_file)

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        """Nothing stays open between reads; here for RobotLog's interface."""

    def __enter__(self) -> RobotFolder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()
