"""ROS bags with the ``rosbags`` library (no ROS installation needed): export of rendered sensor
data, and the one place where ROS messages become arrays and back.

``BagWriter`` writes a run message by message (``NS`` = the optional ``namespace``):

================================  ===============================  ======================================================
topic                             type                             content
================================  ===============================  ======================================================
``NS/<camera>/image``             sensor_msgs/msg/Image            ``rgb8`` (H, W, 3) or ``mono8`` (H, W)
``NS/<camera>/image/compressed``  sensor_msgs/msg/CompressedImage  JPEG bytes as given (``rgb8; jpeg compressed bgr8``)
``NS/<camera>/depth``             sensor_msgs/msg/Image            ``32FC1`` metres (inf = no return, NaN = invalid)
``NS/<camera>/camera_info``       sensor_msgs/msg/CameraInfo       with every image, JPEG or depth of that camera
``NS/<lidar>/points``             sensor_msgs/msg/PointCloud2      returns only: x y z intensity (float32), ring (uint16)
``/tf``                           tf2_msgs/msg/TFMessage           ``odom -> body`` with every odometry
``/tf_static``                    tf2_msgs/msg/TFMessage           ``body -> <sensor frame>`` once (latched)
``NS/odom``                       nav_msgs/msg/Odometry            body pose in ``odom``, body-frame twist
================================  ===============================  ======================================================

Frames: ``odom`` is the world of the run, ``body`` the robot's body (x forward, y left, z up).
A camera ``c``'s data is in frame ``c_optical`` (OpenCV axes, as ROS requires of image frames, REP
103), a LiDAR ``l``'s in frame ``l`` (x forward, y left, z up).

Times: each call carries its own stamp, so every sensor can have its own clock:
:meth:`BagWriter.write_odometry` (``/tf`` and ``odom``) and :meth:`BagWriter.write_sensors` (images,
JPEGs, depth, CameraInfo, clouds) at any stamps, :meth:`BagWriter.write_tick` both at one. A
stamp is ``time_offset_ns + round(t_s * 1e9)``, or exactly ``time_offset_ns + t_ns``; it is the
messages' header stamp and their bag time, must not be negative, and must increase from message to
message *on each topic* (topics may interleave in any order). ``/tf_static`` carries the first
call's stamp. Twist: the backward difference of consecutive odometry calls, expressed in the body
frame (zero at the first).

CameraInfo: ``K`` and ``P = [K | 0]`` in OpenCV's pixel convention (the same as nsim's), ``R = I``;
``distortion_model`` ``plumb_bob`` with ``D = (k1, k2, p1, p2, k3)`` for PINHOLE (zeros) and OPENCV,
``rational_polynomial`` with ``D = (k1, k2, p1, p2, k3, k4, k5, k6)`` for FULL_OPENCV,
``equidistant`` with ``D = (k1, k2, k3, k4)`` for OPENCV_FISHEYE (Kannala-Brandt, as
``camera_calibration`` and ``image_geometry`` use it). EQUIRECTANGULAR has no ROS model (ValueError).

Formats (``storage``): a ROS 2 bag directory with ``sqlite3`` (default) or ``mcap`` storage (bag
format version 8; /tf_static offered as transient local), or ``ros1``: one ROS 1 ``.bag`` file
(format 2.0, messages built from rosbags' ``ROS1_NOETIC`` typestore plus ``tf2_msgs/TFMessage``,
/tf_static latched). The bag is written under a temporary name and renamed into place on
``close``; an error inside ``with BagWriter(...)`` leaves no bag. The destination must not exist
yet, not even as an empty directory (as with ``ros2 bag record -o`` and rosbags' own writers), and
its parent must be a writable directory: :func:`check_bag_destination`.

Messages to arrays (ROS 1 or ROS 2 messages alike; bad content raises
:class:`~nsim.errors.InputError` with one line that starts with the caller's ``where``):
:func:`read_image` (every encoding in ``IMAGE_ENCODINGS``; depth as metres on request),
:func:`read_compressed_image`, :func:`camera_from_info`, :func:`read_pointcloud` (any field layout)
and :func:`lidar_points`, :func:`matrix_from_transform` (ROS quaternions are xyzw; nsim's wxyz
never appear here because only matrices leave this module), :func:`stamp_ns`. Arrays to messages:
:func:`image_message`, :func:`depth_message`, :func:`compressed_image_message` (from pixels, or JPEG
bytes as they are), :func:`camera_info_message`, :func:`pointcloud_message`, :func:`points_message`,
each for either typestore (``store=``), and :func:`build_message` for any other message of either
store.
:mod:`nsim.io.robot_log` reads whole recordings with these.
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import uuid
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.images import to_uint8
from nsim.sensors.rig import CameraSensor, OrganizedScan, Rig

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
T = TYPESTORE.types
#: ROS 1 (Noetic) messages, plus tf2_msgs/TFMessage, which rosbags' Noetic store lacks (its
#: definition and so its MD5 ``94810edda583a504dfda3829e70d7eec`` are ROS's).
ROS1_TYPESTORE = get_typestore(Stores.ROS1_NOETIC)
ROS1_TYPESTORE.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
STORAGES = ("sqlite3", "mcap", "ros1")
_INFINITE = QosTime(2147483647, 4294967295)
#: /tf_static is latched: late subscribers (rviz, tf2 buffers) still get the sensor frames.
TF_STATIC_QOS = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                    _INFINITE, _INFINITE, QosLiveliness.AUTOMATIC, _INFINITE, False)
CLOUD_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "ring"],
                        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2"],
                        "offsets": [0, 4, 8, 12, 16], "itemsize": 20})
#: Image encoding -> (channels, numpy type without byte order).
_IMAGE_LAYOUT = {"rgb8": (3, "u1"), "bgr8": (3, "u1"), "mono8": (1, "u1"), "8UC1": (1, "u1"),
                 "mono16": (1, "u2"), "16UC1": (1, "u2"), "32FC1": (1, "f4")}
IMAGE_ENCODINGS = tuple(_IMAGE_LAYOUT)
#: Encodings that are depth by convention (REP 118): 16UC1 millimetres, 32FC1 metres.
DEPTH_ENCODINGS = ("16UC1", "32FC1")
#: PointField datatype -> numpy type without byte order.
_POINT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def check_bag_destination(path: str | os.PathLike, what: str = "bag") -> Path:
    """``path`` as a Path if a bag can be created there, else :class:`InputError` naming it.

    The directory must not exist (a bag is never overwritten, not even an empty directory) and its
    parent must be an existing, writable directory (nothing is created above the bag). ``what``
    names the setting in the message, e.g. ``--rosbag``. Cheap: call it before the work whose
    result goes into the bag.
    """
    path = Path(path)
    if os.path.lexists(path):
        raise InputError(f"{what} {path}: exists already; a bag is never overwritten (choose a new directory)")
    parent = path.parent
    if not parent.is_dir():
        why = "is not a directory" if os.path.lexists(parent) else "does not exist"
        raise InputError(f"{what} {path}: the parent directory {parent} {why}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{what} {path}: the parent directory {parent} is not writable")
    return path


def camera_frame(name: str) -> str:
    """The ROS frame id of camera ``name``'s optical frame."""
    return f"{name}_optical"


def build_message(store, msgtype: str, **fields):
    """A message of ``store``'s ``msgtype`` from ROS 2 field names.

    The ROS 1 spellings are filled in: ``CameraInfo``'s ``D K R P`` (ROS 2: ``d k r p``) and the
    header's ``seq`` (0), so one builder serves both stores.
    """
    names = [name for name, _ in store.fielddefs[msgtype][1]]
    values = {}
    for name in names:
        if name in fields:
            values[name] = fields.pop(name)
        elif name.lower() in fields:
            values[name] = fields.pop(name.lower())
        elif name == "seq":
            values[name] = 0
    if fields:
        raise TypeError(f"{msgtype}: no fields {sorted(fields)} in this typestore")
    return store.types[msgtype](**values)


def _field(msg, name: str):
    """Field ``name`` of a message in its ROS 2 spelling, or the ROS 1 one (``CameraInfo.K`` for ``k``)."""
    value = getattr(msg, name, None)
    return getattr(msg, name.upper()) if value is None else value


def _stamp(t_ns: int, store=TYPESTORE):
    return build_message(store, "builtin_interfaces/msg/Time", sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def _header(t_ns: int, frame_id: str, store=TYPESTORE):
    return build_message(store, "std_msgs/msg/Header", stamp=_stamp(t_ns, store), frame_id=frame_id)


def stamp_ns(header) -> int:
    """A header's stamp in integer nanoseconds (``sec * 10**9 + nanosec``)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _transform_msg(pose: np.ndarray, store=TYPESTORE):
    """geometry_msgs/Transform of a rigid ``(4, 4)`` (quaternion xyzw with w >= 0, as ROS writes it)."""
    q = Rotation.from_matrix(np.array(pose[:3, :3])).as_quat()  # xyzw (a copy: scipy 1.15.0 and older refuse read-only arrays)
    if q[3] < 0:
        q = -q
    x, y, z = (float(v) for v in pose[:3, 3])
    return build_message(store, "geometry_msgs/msg/Transform",
                translation=build_message(store, "geometry_msgs/msg/Vector3", x=x, y=y, z=z),
                rotation=build_message(store, "geometry_msgs/msg/Quaternion",
                              x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))


def matrix_from_transform(transform) -> np.ndarray:
    """``(4, 4)`` from a geometry_msgs/Transform (or a Pose, via ``position``/``orientation``).

    The quaternion (ROS order xyzw) is normalised; a zero or non-finite one, or a non-finite
    translation, raises ``ValueError``.
    """
    t = getattr(transform, "translation", None) or transform.position
    q = getattr(transform, "rotation", None) or transform.orientation
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    xyz = np.array([t.x, t.y, t.z], dtype=np.float64)
    norm = float(np.linalg.norm(quat))
    if not (np.all(np.isfinite(quat)) and np.all(np.isfinite(xyz)) and norm > 1e-9):
        raise ValueError(f"transform: expected a finite translation and a non-zero quaternion, got {xyz.tolist()} "
                         f"and (x, y, z, w) {quat.tolist()}")
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat(quat / norm).as_matrix()
    out[:3, 3] = xyz
    return out


# ---------------------------------------------------------------------------- arrays -> messages


def image_message(t_ns: int, frame_id: str, image: np.ndarray, *, encoding: str | None = None, store=TYPESTORE):
    """sensor_msgs/Image of ``image`` (little-endian, rows unpadded).

    encoding None: ``(H, W, 3)`` -> rgb8, ``(H, W)`` -> mono8, from uint8 or from floats in [0, 1]
    quantised with ``nsim.io.images.to_uint8``. Or name it: ``rgb8`` / ``bgr8`` (an RGB
    ``(H, W, 3)`` uint8, stored in that channel order), ``mono8`` (``(H, W)`` uint8), ``mono16`` /
    ``16UC1`` (``(H, W)`` uint16; 16UC1 is depth in millimetres, see :func:`depth_message`).
    """
    image = np.asarray(image)
    if encoding is None:
        if image.dtype != np.uint8:
            image = to_uint8(image)
        encoding = "rgb8" if image.ndim == 3 else "mono8"
    want = {"rgb8": (3, np.uint8), "bgr8": (3, np.uint8), "mono8": (2, np.uint8),
            "mono16": (2, np.uint16), "16UC1": (2, np.uint16)}
    if encoding not in want:
        raise ValueError(f"image: encoding {encoding!r} is not one of {', '.join(want)} (32FC1: depth_message)")
    ndim, dtype = want[encoding]
    if image.ndim != ndim or (ndim == 3 and image.shape[2] != 3) or image.dtype != dtype:
        shape = "(H, W, 3)" if ndim == 3 else "(H, W)"
        raise ValueError(f"image: {encoding} needs {shape} {np.dtype(dtype).name}, got {image.shape} {image.dtype}")
    if encoding == "bgr8":
        image = image[..., ::-1]
    h, w = image.shape[:2]
    data = np.ascontiguousarray(image).astype(np.dtype(dtype).newbyteorder("<"), copy=False)
    return build_message(store, "sensor_msgs/msg/Image", header=_header(t_ns, frame_id, store), height=h, width=w,
                encoding=encoding, is_bigendian=0, step=data[0].nbytes, data=data.view(np.uint8).reshape(-1))


def depth_message(t_ns: int, frame_id: str, depth_m: np.ndarray, *, encoding: str = "32FC1", store=TYPESTORE):
    """sensor_msgs/Image of a depth map ``depth_m (H, W)`` in metres, little-endian.

    ``32FC1``: float32 metres as given (inf = no return, NaN = invalid). ``16UC1``: uint16
    millimetres, rounded; 0 where the depth is not finite or rounds outside ``[1, 65535]`` mm
    (REP 118: 0 = no measurement).
    """
    depth = np.asarray(depth_m, dtype=np.float64 if encoding == "16UC1" else "<f4")
    if depth.ndim != 2:
        raise ValueError(f"depth: expected (H, W), got shape {depth.shape}")
    if encoding == "16UC1":
        with np.errstate(invalid="ignore"):
            mm = np.rint(depth * 1000.0)
            ok = np.isfinite(mm) & (mm >= 1) & (mm <= 65535)
        return image_message(t_ns, frame_id, np.where(ok, mm, 0).astype(np.uint16), encoding="16UC1", store=store)
    if encoding != "32FC1":
        raise ValueError(f"depth: encoding must be 32FC1 or 16UC1, got {encoding!r}")
    h, w = depth.shape
    return build_message(store, "sensor_msgs/msg/Image", header=_header(t_ns, frame_id, store), height=h, width=w,
                encoding="32FC1", is_bigendian=0, step=w * 4, data=np.ascontiguousarray(depth).view(np.uint8).reshape(-1))


def compressed_image_message(t_ns: int, frame_id: str, image: np.ndarray | bytes, fmt: str = "jpeg", *,
                             store=TYPESTORE):
    """sensor_msgs/CompressedImage as ``image_transport``'s compressed plugin writes it, with the
    format string ``"<encoding>; <fmt> compressed <stored encoding>"``.

    image: an RGB ``(H, W, 3)`` or gray ``(H, W)`` uint8 array (gray uint16 too for ``png``),
    encoded here with OpenCV (colour stored as BGR) as fmt ``jpeg`` (quality 95) or ``png``; or
    the bytes of a JPEG already encoded (fmt ``jpeg``), written as they are: a JPEG of 3
    components (e.g. ``nsim.synth.phone.encode_jpeg``'s; decoders give BGR) is ``rgb8; jpeg
    compressed bgr8``, one of 1 component ``mono8; jpeg compressed mono8``. Bytes that are not a
    JPEG raise ValueError.
    """
    if isinstance(image, (bytes, bytearray, memoryview)):
        if fmt != "jpeg":
            raise ValueError(f"compressed image: encoded bytes must be a JPEG (fmt jpeg), got fmt {fmt!r}")
        data = bytes(image)
        channels = jpeg_components(data)
        if channels == 3:
            encoding, stored = "rgb8", "bgr8"
        elif channels == 1:
            encoding = stored = "mono8"
        else:
            raise ValueError(f"compressed image: a JPEG of {channels} components (ROS has 1 or 3)")
        return build_message(store, "sensor_msgs/msg/CompressedImage", header=_header(t_ns, frame_id, store),
                             format=f"{encoding}; jpeg compressed {stored}", data=np.frombuffer(data, np.uint8).copy())
    image = np.asarray(image)
    if fmt not in ("jpeg", "png"):
        raise ValueError(f"compressed image: fmt must be jpeg or png, got {fmt!r}")
    if image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8:
        encoding, stored, pixels = "rgb8", "bgr8", image[..., ::-1]
    elif image.ndim == 2 and (image.dtype == np.uint8 or (image.dtype == np.uint16 and fmt == "png")):
        encoding = stored = "mono8" if image.dtype == np.uint8 else "mono16"
        pixels = image
    else:
        raise ValueError(f"compressed image: expected (H, W, 3) or (H, W) uint8 (uint16 for png), got {image.shape} {image.dtype}")
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if fmt == "jpeg" else []
    ok, buf = cv2.imencode("." + ("jpg" if fmt == "jpeg" else "png"), np.ascontiguousarray(pixels), params)
    if not ok:
        raise ValueError(f"compressed image: OpenCV could not encode {fmt}")
    return build_message(store, "sensor_msgs/msg/CompressedImage", header=_header(t_ns, frame_id, store),
                format=f"{encoding}; {fmt} compressed {stored}", data=buf.reshape(-1).astype(np.uint8))


#: JPEG markers that start a frame header (SOF0..SOF15 but DHT, JPG and DAC).
_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def jpeg_components(data: bytes) -> int:
    """The number of colour components of JPEG ``data`` (1 gray, 3 colour), read from its frame
    header without decoding; ValueError when ``data`` is not a JPEG or has no frame header before
    its first scan."""
    if data[:3] != b"\xff\xd8\xff":
        raise ValueError(f"JPEG: the data ({len(data)} bytes) does not start with a JPEG marker")
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            i += 2
            continue
        if marker in _JPEG_FRAME_MARKERS:
            if i + 10 > len(data):
                break
            return data[i + 9]
        if marker in (0xDA, 0xD9):  # a scan or the end before any frame header
            break
        i += 2 + int.from_bytes(data[i + 2:i + 4], "big")
    raise ValueError(f"JPEG: no frame header in the data ({len(data)} bytes)")


def camera_info_message(t_ns: int, frame_id: str, camera: Camera, *, store=TYPESTORE):
    """sensor_msgs/CameraInfo of ``camera`` (see the module docstring for the distortion models)."""
    if camera.model == "OPENCV_FISHEYE":
        model, d = "equidistant", np.array(camera.dist, dtype=np.float64)
    elif camera.model in ("PINHOLE", "OPENCV"):
        model, d = "plumb_bob", np.array(camera.dist if camera.dist else (0.0,) * 5, dtype=np.float64)
    elif camera.model == "FULL_OPENCV":
        model, d = "rational_polynomial", np.array(camera.dist, dtype=np.float64)
    else:
        raise ValueError(f"camera_info: ROS has no distortion model for {camera.model}")
    K = camera.K
    P = np.concatenate([K, np.zeros((3, 1))], axis=1)
    return build_message(store, "sensor_msgs/msg/CameraInfo",
                header=_header(t_ns, frame_id, store), height=camera.height, width=camera.width, distortion_model=model,
                d=d, k=K.reshape(-1).copy(), r=np.eye(3).reshape(-1), p=P.reshape(-1), binning_x=0, binning_y=0,
                roi=build_message(store, "sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0,
                         do_rectify=False))


def pointcloud_message(t_ns: int, frame_id: str, scan: OrganizedScan, *, store=TYPESTORE):
    """sensor_msgs/PointCloud2 of a sweep's returns (height 1, dense), fields x y z intensity ring."""
    hit = scan.hit
    points = np.zeros(int(hit.sum()), dtype=CLOUD_DTYPE)
    xyz = scan.xyz_m[hit]
    points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    points["intensity"] = scan.intensity[hit]
    points["ring"] = scan.ring[hit]
    return points_message(t_ns, frame_id, points, store=store)


def points_message(t_ns: int, frame_id: str, points: np.ndarray, *, height: int = 1, store=TYPESTORE):
    """sensor_msgs/PointCloud2 of a structured array ``points (N,)`` as laid out in memory.

    Every named field becomes a PointField at its offset (``count`` from a sub-array shape); the
    dtype's ``itemsize`` is the point step, so padding between and after fields is kept. The
    field types must be ROS's (int8 .. uint32, float32, float64) in one byte order, which sets
    ``is_bigendian``. ``height`` > 1 writes an organised cloud of ``N / height`` columns.
    """
    points = np.ascontiguousarray(points)
    if points.dtype.names is None or points.ndim != 1:
        raise ValueError(f"points: expected a structured (N,) array, got {points.dtype} {points.shape}")
    codes = {v: k for k, v in _POINT_TYPES.items()}
    fields, big = [], set()
    for name in points.dtype.names:
        ftype, offset = points.dtype.fields[name][:2]
        base, count = (ftype.subdtype[0], int(np.prod(ftype.subdtype[1]))) if ftype.subdtype else (ftype, 1)
        if base.kind + str(base.itemsize) not in codes:
            raise ValueError(f"points: field {name!r} has type {base}, which PointCloud2 cannot hold")
        if base.itemsize > 1:
            big.add(base.byteorder == ">" or (base.byteorder == "=" and sys.byteorder == "big"))
        fields.append(build_message(store, "sensor_msgs/msg/PointField", name=name, offset=offset,
                           datatype=codes[base.kind + str(base.itemsize)], count=count))
    if len(big) > 1:
        raise ValueError("points: fields in both byte orders")
    if len(points) % height:
        raise ValueError(f"points: {len(points)} points do not make {height} rows")
    width = len(points) // height
    step = points.dtype.itemsize
    return build_message(store, "sensor_msgs/msg/PointCloud2", header=_header(t_ns, frame_id, store), height=height, width=width,
                fields=fields, is_bigendian=bool(big and big.pop()), point_step=step, row_step=step * width,
                data=points.view(np.uint8).reshape(-1), is_dense=True)


# ---------------------------------------------------------------------------- messages -> arrays


def read_image(msg, *, depth_m: bool = False, units_per_m: float = 1000.0, where: str = "image") -> np.ndarray:
    """Array of a sensor_msgs/Image, honouring ``step`` (row padding) and ``is_bigendian``.

    rgb8 and bgr8 -> ``(H, W, 3)`` uint8 **RGB**; mono8 / 8UC1 -> ``(H, W)`` uint8; mono16 /
    16UC1 -> ``(H, W)`` uint16; 32FC1 -> ``(H, W)`` float32. ``depth_m``: a 16-bit image is
    depth in units of ``1 / units_per_m`` metres (1000: millimetres, REP 118's 16UC1; a RealSense
    bag states its own, :mod:`nsim.io.realsense`) and comes back as float32 metres (the value
    divided by ``float32(units_per_m)``) with NaN where it is 0 (no measurement); 32FC1 is metres
    already; 8-bit images are refused. Bad input (an encoding not listed, rows shorter than the
    width, too few bytes) raises :class:`InputError` with ``where`` at the front of its one line.
    """
    encoding = msg.encoding
    if encoding not in _IMAGE_LAYOUT:
        raise InputError(f"{where}: unknown image encoding {encoding!r} (nsim reads {', '.join(IMAGE_ENCODINGS)})")
    channels, code = _IMAGE_LAYOUT[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * np.dtype(code).itemsize
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h == 0 or w == 0:
        raise InputError(f"{where}: empty {w}x{h} image")
    if step < row:
        raise InputError(f"{where}: step {step} is shorter than a row of {w} {encoding} pixels ({row} bytes)")
    if data.size < step * (h - 1) + row:
        raise InputError(f"{where}: {data.size} bytes of data, a {w}x{h} {encoding} image with step {step} needs {step * h}")
    if data.size < step * h:  # a last row without its padding
        data = np.concatenate([data, np.zeros(step * h - data.size, np.uint8)])
    rows = np.ascontiguousarray(data[: step * h].reshape(h, step)[:, :row])
    order = ">" if msg.is_bigendian else "<"
    image = rows.view(order + code).reshape(h, w, channels).astype(code)  # native byte order
    if encoding == "bgr8":
        image = image[..., ::-1]
    image = np.ascontiguousarray(image[..., 0] if channels == 1 else image)
    if not depth_m:
        return image
    if encoding == "32FC1":
        return image
    if code != "u2":
        raise InputError(f"{where}: {encoding} is not a depth encoding (16UC1 millimetres or 32FC1 metres)")
    depth = image.astype(np.float32) / np.float32(units_per_m)
    depth[image == 0] = np.nan
    return depth


def read_compressed_image(msg, *, where: str = "image") -> np.ndarray:
    """Array of a sensor_msgs/CompressedImage (JPEG, PNG, anything ``cv2.imdecode`` reads).

    Colour comes back as ``(H, W, 3)`` uint8 RGB (the stream holds BGR, as image_transport
    writes it; an alpha channel is dropped), gray as ``(H, W)`` uint8 or uint16 (16-bit PNG).
    ``compressedDepth`` (the depth plugin's own header before the PNG) is not read. Data that does
    not decode raises :class:`InputError` naming ``where`` and the format.
    """
    fmt = str(msg.format)
    if "compresseddepth" in fmt.lower():
        raise InputError(f"{where}: compressedDepth images ({fmt!r}) are not supported; record raw depth images")
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise InputError(f"{where}: the compressed image (format {fmt!r}, {data.size} bytes) does not decode")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        image = image[..., 2::-1]
    elif image.ndim != 2:
        raise InputError(f"{where}: the compressed image decodes to an unexpected shape {image.shape}")
    return np.ascontiguousarray(image)


def camera_from_info(msg, *, rectified: bool = False, where: str = "camera_info", distortion: str | None = None,
                     ) -> Camera:
    """nsim Camera of a sensor_msgs/CameraInfo (ROS 1 or ROS 2).

    The raw image (``rectified`` False) is ``K`` with ``D``: ``plumb_bob`` -> OPENCV ``(k1, k2,
    p1, p2, k3)`` (PINHOLE when D is all zero or empty), ``rational_polynomial`` -> FULL_OPENCV
    ``(k1, k2, p1, p2, k3, k4, k5, k6)`` (PINHOLE when all zero), ``equidistant`` ->
    OPENCV_FISHEYE ``(k1, k2, k3, k4)`` (Kannala-Brandt, as ``cv2.fisheye``). Trailing
    coefficients beyond a model's own must be zero. A rectified image (``image_rect*``) is the
    PINHOLE of ``P``'s left 3x3. ROS and OpenCV share the pixel convention (centre of the first
    pixel at 0), so the numbers are taken as they are.

    A region of interest (``roi`` with a non-zero size) crops: ``c' = c - offset``, size = the
    ROI's. Binning ``b`` > 1 then merges ``b`` pixels: ``f' = f / b``, ``c' = (c + 0.5) / b - 0.5``
    (exact for pixel centres; ``image_geometry`` uses ``c / b``, 0.25 px apart at ``b = 2``),
    size ``// b``. Bad input (uncalibrated K of zeros, skew, unknown model, coefficients nsim's
    model cannot hold) raises :class:`InputError` starting with ``where``.

    librealsense's names (a RealSense SDK bag's CameraInfo, ``rs2_distortion``) are read too: ``Brown
    Conrady`` is plumb_bob (the same equations and coefficient order), ``Kannala Brandt4`` equidistant,
    ``None`` a PINHOLE (its coefficients unused, as librealsense leaves them); ``Modified Brown
    Conrady`` (tangential terms on the radially distorted point) is plumb_bob only where p1 = p2 = 0,
    ``Inverse Brown Conrady`` (coefficients that undistort) and ``Ftheta`` only where D is all zero:
    otherwise one line refuses them, as nsim's models cannot hold them. ``distortion`` (a ROS model name)
    reads ``D`` in that model whatever ``distortion_model`` says (the caller's knowing choice).
    """
    K = np.asarray(_field(msg, "k"), dtype=np.float64).reshape(3, 3)
    D = [float(v) for v in _field(msg, "d")]
    if not np.all(np.isfinite(K)) or not np.all(np.isfinite(D)):
        raise InputError(f"{where}: K or D is not finite")
    model, D = (distortion, D) if distortion else _ros_distortion_model(str(msg.distortion_model), D, where)
    if not K.any():
        raise InputError(f"{where}: uncalibrated camera (K is all zero)")
    if rectified:
        P = np.asarray(_field(msg, "p"), dtype=np.float64).reshape(3, 4)
        K, D, model = P[:, :3], [], "plumb_bob"
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise InputError(f"{where}: K = {K.reshape(-1).tolist()} is not a camera matrix [fx s cx; 0 fy cy; 0 0 1]")
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        raise InputError(f"{where}: K has skew {K[0, 1]}, which nsim's camera models do not have")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    def first(n: int, name: str) -> list[float]:
        if any(D[n:]):
            raise InputError(f"{where}: {name} takes {n} coefficients, D = {D} has more that are not zero")
        return D[:n]

    if model in ("plumb_bob", "rational_polynomial") and not any(D):
        cam_model, dist = "PINHOLE", []
    elif model == "plumb_bob":
        if len(D) < 4:
            raise InputError(f"{where}: plumb_bob needs (k1, k2, p1, p2[, k3]), D = {D}")
        cam_model, dist = "OPENCV", first(5, "plumb_bob")
    elif model == "rational_polynomial":
        if len(D) < 8:
            raise InputError(f"{where}: rational_polynomial needs (k1, k2, p1, p2, k3, k4, k5, k6), D = {D}")
        cam_model, dist = "FULL_OPENCV", first(8, "rational_polynomial")
    elif model == "equidistant":
        if len(D) < 4:
            raise InputError(f"{where}: equidistant needs (k1, k2, k3, k4), D = {D}")
        cam_model, dist = "OPENCV_FISHEYE", first(4, "equidistant")
    else:
        raise InputError(f"{where}: unknown distortion model {model!r} (nsim reads plumb_bob, rational_polynomial, "
                         "equidistant and librealsense's Brown Conrady, Kannala Brandt4)")

    width, height = int(msg.width), int(msg.height)
    roi = msg.roi
    if int(roi.width) and int(roi.height):
        cx, cy = cx - int(roi.x_offset), cy - int(roi.y_offset)
        width, height = int(roi.width), int(roi.height)
    bx, by = max(int(msg.binning_x), 1), max(int(msg.binning_y), 1)
    fx, cx, width = fx / bx, (cx + 0.5) / bx - 0.5, width // bx
    fy, cy, height = fy / by, (cy + 0.5) / by - 0.5, height // by
    try:
        return Camera(cam_model, width, height, fx, fy, cx, cy, tuple(dist))
    except ValueError as exc:
        raise InputError(f"{where}: {str(exc).replace('Camera.', '')}") from None


#: librealsense's distortion names (``rs2_distortion_to_string``), lower case with ``_`` for spaces, as ROS's.
_REALSENSE_MODELS = ("none", "brown_conrady", "modified_brown_conrady", "inverse_brown_conrady", "ftheta",
                     "kannala_brandt4")


def _ros_distortion_model(model: str, D: list[float], where: str) -> tuple[str, list[float]]:
    """The ROS model and coefficients a CameraInfo's ``distortion_model`` and ``D`` stand for
    (librealsense's names mapped, see :func:`camera_from_info`); ROS's own and unknown names come
    back as they are."""
    key = "_".join(model.lower().split())
    if key not in _REALSENSE_MODELS:
        return model, D
    if key == "none":
        return "plumb_bob", []  # no distortion: librealsense does not use the coefficients
    if key == "brown_conrady":
        return "plumb_bob", D
    if key == "kannala_brandt4":
        return "equidistant", D
    if key == "modified_brown_conrady" and not any(D[2:4]):
        return "plumb_bob", D  # without tangential terms it is Brown-Conrady
    if not any(D):
        return "plumb_bob", D
    why = {"modified_brown_conrady": "tangential terms applied to the radially distorted point (p1, p2 not zero)",
           "inverse_brown_conrady": "coefficients that undistort pixels rather than distort points",
           "ftheta": "an F-Theta fisheye"}[key]
    raise InputError(f"{where}: distortion model {model!r} with D = {D} is librealsense's {why}, which nsim's camera "
                     "models cannot hold (to read D as plumb_bob, as realsense2_camera publishes it, give the camera "
                     "distortion: plumb_bob in the selection)")


def read_pointcloud(msg, *, where: str = "points") -> np.ndarray:
    """Structured array ``(N,)``, ``N = height * width`` (row-major), of a PointCloud2 with its named fields.

    Any layout: fields in any order at any offsets (padding between and after them), every
    PointField datatype, ``count`` > 1 as a sub-array, rows padded to ``row_step``, either byte
    order (returned in native order). Fields named ``""`` or ``"_"`` (padding, as PCL names it)
    are skipped. Bad layouts raise :class:`InputError` starting with ``where``.
    """
    order = ">" if msg.is_bigendian else "<"
    step = int(msg.point_step)
    names, formats, offsets = [], [], []
    for f in msg.fields:
        name = str(f.name)
        if name in ("", "_"):
            continue
        if f.datatype not in _POINT_TYPES:
            raise InputError(f"{where}: field {name!r} has unknown PointField datatype {f.datatype}")
        if name in names:
            raise InputError(f"{where}: field {name!r} appears twice")
        count = max(int(f.count), 1)
        code = order + _POINT_TYPES[f.datatype]
        if int(f.offset) + np.dtype(code).itemsize * count > step:
            raise InputError(f"{where}: field {name!r} at offset {f.offset} does not fit a point step of {step} bytes")
        names.append(name)
        formats.append(code if count == 1 else (code, (count,)))
        offsets.append(int(f.offset))
    native = [(np.dtype(f).newbyteorder("=") if isinstance(f, str) else (np.dtype(f[0]).newbyteorder("="), f[1]))
              for f in formats]
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": max(step, 1)})
    h, w = int(msg.height), int(msg.width)
    row = w * step
    row_step = int(msg.row_step) or row
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    packed = np.dtype({"names": names, "formats": native})
    if h * w == 0:
        return np.zeros(0, dtype=packed)
    if step == 0:
        raise InputError(f"{where}: point_step is 0")
    if row_step < row:
        raise InputError(f"{where}: row_step {row_step} is shorter than {w} points of {step} bytes")
    need = row_step * (h - 1) + row
    if data.size < need:
        raise InputError(f"{where}: {data.size} bytes of data, {h} rows of {w} points need {need}")
    if row_step == row:
        rows = data[: h * row]
    else:  # drop the padding at the end of each row
        rows = np.pad(data[:need], (0, h * row_step - need)).reshape(h, row_step)[:, :row]
    points = np.ascontiguousarray(rows).reshape(-1).view(dtype)
    out = np.zeros(len(points), dtype=packed)
    for name in names:
        out[name] = points[name]
    return out


@dataclass(frozen=True)
class LidarPoints:
    """The usual fields of a PointCloud2 as plain arrays, ``N`` points in the message's order.

    xyz_m: (N, 3) float64, the cloud's frame; intensity: (N,) float64 or None; ring: (N,) int64
    or None (field ``ring`` or ``laser_id``); time: (N,) float64 or None, the per-point time *as
    recorded* in field ``time_field`` (``time_sec+time_nsec``: the sum of Luminar's two fields)
    (units are the driver's: Velodyne ``time`` is seconds from the sweep's start, Ouster ``t``
    nanoseconds, Hesai ``timestamp`` absolute seconds, Livox ``offset_time`` nanoseconds).
    """

    xyz_m: np.ndarray
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    time: np.ndarray | None = None
    time_field: str | None = None

    def __len__(self) -> int:
        return len(self.xyz_m)


#: Field names tried, in order, for a point's time (then ``time_sec`` + ``time_nsec`` together).
TIME_FIELDS = ("time", "t", "timestamp", "time_stamp", "offset_time")
#: Field names tried, in order, for a point's beam (Velodyne / Ouster ``ring``, Luminar ``laser_id``).
RING_FIELDS = ("ring", "laser_id")


def lidar_points(msg, *, finite_only: bool = False, where: str = "points") -> LidarPoints:
    """x y z (required), intensity, ring and time (when present) of a PointCloud2 as :class:`LidarPoints`.

    finite_only: drop points whose x, y or z is not finite (an organised cloud's misses); by
    default every point is kept, so index ``i`` is pixel ``(i // width, i % width)``. A cloud
    without x, y or z raises :class:`InputError` naming ``where`` and the fields it has.
    """
    points = read_pointcloud(msg, where=where)
    names = points.dtype.names or ()
    if missing := [c for c in "xyz" if c not in names]:
        raise InputError(f"{where}: PointCloud2 without {'/'.join(missing)} (fields: {', '.join(names) or 'none'})")
    for c in "xyz":
        if points.dtype[c].shape:
            raise InputError(f"{where}: field {c!r} has count {points.dtype[c].shape[0]}, expected 1")
    xyz = np.stack([points[c].astype(np.float64) for c in "xyz"], axis=1)
    keep = np.all(np.isfinite(xyz), axis=1) if finite_only else slice(None)

    def scalar(name: str, dtype) -> np.ndarray | None:
        if name not in names or points.dtype[name].shape:
            return None
        return points[name][keep].astype(dtype)

    time_field = next((n for n in TIME_FIELDS if n in names and not points.dtype[n].shape), None)
    time = scalar(time_field, np.float64) if time_field else None
    if time is None and (sec := scalar("time_sec", np.float64)) is not None \
            and (nsec := scalar("time_nsec", np.float64)) is not None:
        time, time_field = sec + nsec * 1e-9, "time_sec+time_nsec"  # Luminar: absolute seconds in two fields
    ring = next((r for n in RING_FIELDS if (r := scalar(n, np.int64)) is not None), None)
    return LidarPoints(xyz_m=np.ascontiguousarray(xyz[keep]), intensity=scalar("intensity", np.float64),
                       ring=ring, time=time, time_field=time_field)


class BagWriter:
    """Writes a ROS 2 or ROS 1 bag incrementally, call by call (see the module docstring).

    ``with BagWriter(out / "run", rig) as bag: bag.write_tick(t_s, body_to_world, images=..., ...)``, or
    with a clock per sensor: ``bag.write_odometry(t_s, body_to_world)`` and ``bag.write_sensors(t_s,
    images=..., compressed_images=..., depths=..., clouds=...)`` at their own stamps.

    path: the bag directory to create (see :func:`check_bag_destination`; InputError otherwise). rig: gives the static transforms, the
    frame of each sensor and the CameraInfo of each camera; without one, pass ``static_transforms``
    (``{frame_id: frame_to_body (4, 4)}``) and ``infos`` yourself. storage: ``sqlite3`` | ``mcap``
    (a ROS 2 bag directory) | ``ros1`` (one ROS 1 bag file, whose name must end in ``.bag``).

    Times: every ``write_*`` takes ``t_s`` (seconds) or, exactly, ``t_ns`` (integer nanoseconds):
    one of the two. The stamp is ``time_offset_ns + round(t_s * 1e9)`` or ``time_offset_ns +
    t_ns``: the header stamp and the bag time of everything the call writes. A negative stamp, or
    one that is not after the previous stamp on a topic the call writes, raises ValueError and the
    call writes nothing.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        rig: Rig | None = None,
        *,
        namespace: str = "",
        odom_frame: str = "odom",
        body_frame: str = "body",
        static_transforms: Mapping[str, np.ndarray] | None = None,
        storage: str = "sqlite3",
        time_offset_ns: int = 0,
    ) -> None:
        if storage not in STORAGES:
            raise ValueError(f"storage: expected one of {', '.join(STORAGES)}, got {storage!r}")
        self.path = check_bag_destination(path)
        if storage == "ros1" and self.path.suffix != ".bag":
            raise InputError(f"bag {self.path}: a ROS 1 bag is one file whose name ends in .bag")
        self.storage = storage
        self._store = ROS1_TYPESTORE if storage == "ros1" else TYPESTORE
        self.rig = rig
        self.namespace = namespace.rstrip("/")
        self.odom_frame, self.body_frame = odom_frame, body_frame
        self.time_offset_ns = int(time_offset_ns)
        statics = {}
        if rig is not None:
            for s in rig.sensors:
                statics[camera_frame(s.name) if isinstance(s, CameraSensor) else s.name] = np.asarray(s.sensor_to_body)
        statics.update({k: np.asarray(v, dtype=np.float64) for k, v in (static_transforms or {}).items()})
        self.static_transforms = statics
        self._tmp_dir = self.path.parent / f".{self.path.name}.{uuid.uuid4().hex[:12]}.tmp"
        self._tmp_dir.mkdir()
        if storage == "ros1":
            self._writer = Writer1(self._tmp_dir / self.path.name)
        else:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self._writer = Writer(self._tmp_dir / self.path.name, version=8, storage_plugin=plugin)
        try:
            self._writer.open()
        except BaseException:
            shutil.rmtree(self._tmp_dir, ignore_errors=True)
            raise
        self._connections: dict[str, object] = {}
        self._last_stamp_ns: dict[str, int] = {}  # topic -> its latest stamp
        self._last_odometry: tuple[int, np.ndarray] | None = None  # (stamp, body_to_odom) of the last odometry
        self._wrote_statics = False
        self._closed = False

    # ------------------------------------------------------------------ plumbing

    def _topic(self, *parts: str) -> str:
        return "/".join([self.namespace, *parts]) if self.namespace else "/" + "/".join(parts)

    def _write(self, topic: str, msg, t_ns: int, latched: bool = False) -> None:
        """Write ``msg`` (built from ``self._store``) on ``topic``; ``latched``: transient local / latching."""
        conn = self._connections.get(topic)
        store = self._store
        if conn is None:
            if self.storage == "ros1":
                conn = self._writer.add_connection(topic, msg.__msgtype__, typestore=store, latching=1 if latched else None)
            else:
                conn = self._writer.add_connection(topic, msg.__msgtype__, typestore=store,
                                                   offered_qos_profiles=[TF_STATIC_QOS] if latched else [])
            self._connections[topic] = conn
        raw = store.serialize_ros1(msg, msg.__msgtype__) if self.storage == "ros1" else store.serialize_cdr(msg, msg.__msgtype__)
        self._writer.write(conn, t_ns, bytes(raw))

    def _stamp_ns(self, t_s: float | None, t_ns: int | None) -> int:
        """The stamp of a call given ``t_s`` or ``t_ns`` (checked: one of them, finite, not negative)."""
        if self._closed:
            raise RuntimeError("BagWriter: already closed")
        if (t_s is None) == (t_ns is None):
            raise TypeError("BagWriter: give the time as t_s (seconds) or t_ns (integer nanoseconds), one of them")
        if t_ns is not None:
            if isinstance(t_ns, bool) or not isinstance(t_ns, (int, np.integer)):
                raise TypeError(f"t_ns: expected integer nanoseconds, got {t_ns!r}")
            stamp = self.time_offset_ns + int(t_ns)
        else:
            if not math.isfinite(t_s):
                raise ValueError(f"t_s: expected a finite time, got {t_s}")
            stamp = self.time_offset_ns + int(round(t_s * 1e9))
        if stamp < 0:
            raise ValueError(f"t_s: the stamp {stamp} ns is negative (bag times start at 0)")
        return stamp

    def _seconds(self, stamp_ns: int) -> float:
        return (stamp_ns - self.time_offset_ns) / 1e9

    def _emit(self, t_ns: int, messages: list[tuple[str, object]]) -> None:
        """Write ``(topic, message)`` pairs at ``t_ns`` after checking every topic's order (all or nothing);
        the first call that writes anything writes /tf_static before."""
        for topic, _ in messages:
            last = self._last_stamp_ns.get(topic)
            if last is not None and t_ns <= last:
                raise ValueError(f"{topic}: stamps must be increasing on each topic, got {self._seconds(t_ns)} s "
                                 f"after {self._seconds(last)} s")
        if not messages:
            return
        if not self._wrote_statics:
            self._wrote_statics = True
            if self.static_transforms:
                statics = [self._tf(t_ns, self.body_frame, child, T_) for child, T_ in self.static_transforms.items()]
                self._write("/tf_static", build_message(self._store, "tf2_msgs/msg/TFMessage", transforms=statics), t_ns,
                            latched=True)
        for topic, msg in messages:
            self._write(topic, msg, t_ns)
            self._last_stamp_ns[topic] = t_ns

    def _tf(self, t_ns: int, parent: str, child: str, pose: np.ndarray):
        return build_message(self._store, "geometry_msgs/msg/TransformStamped", header=_header(t_ns, parent, self._store),
                    child_frame_id=child, transform=_transform_msg(pose, self._store))

    def _camera_for(self, name: str, infos: Mapping[str, Camera] | None) -> Camera | None:
        if infos is not None and name in infos:
            return infos[name]
        if self.rig is not None and name in self.rig.names and isinstance(self.rig[name], CameraSensor):
            return self.rig[name].camera
        return None

    def _odometry_messages(self, t_ns: int, robot_pose: np.ndarray) -> tuple[np.ndarray, list[tuple[str, object]]]:
        pose = np.asarray(robot_pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"robot_pose: expected a finite (4, 4), got shape {pose.shape}")
        odom_to_body = [self._tf(t_ns, self.odom_frame, self.body_frame, pose)]
        tf = build_message(self._store, "tf2_msgs/msg/TFMessage", transforms=odom_to_body)
        return pose, [("/tf", tf), (self._topic("odom"), self._odometry(t_ns, pose))]

    def _sensor_messages(self, t_ns: int, images, depths, compressed_images, clouds, infos) -> list[tuple[str, object]]:
        out, with_info = [], []
        store = self._store
        for name, image in (images or {}).items():
            out.append((self._topic(name, "image"), image_message(t_ns, camera_frame(name), image, store=store)))
            with_info.append(name)
        for name, data in (compressed_images or {}).items():
            try:
                msg = compressed_image_message(t_ns, camera_frame(name), data, "jpeg", store=store)
            except ValueError as exc:
                raise ValueError(f"compressed_images[{name!r}]: {exc}") from None
            out.append((self._topic(name, "image", "compressed"), msg))
            with_info.append(name)
        for name, depth in (depths or {}).items():
            out.append((self._topic(name, "depth"), depth_message(t_ns, camera_frame(name), depth, store=store)))
            with_info.append(name)
        for name in dict.fromkeys(with_info):
            camera = self._camera_for(name, infos)
            if camera is not None:
                info = camera_info_message(t_ns, camera_frame(name), camera, store=store)
                out.append((self._topic(name, "camera_info"), info))
        for name, scan in (clouds or {}).items():
            out.append((self._topic(name, "points"), pointcloud_message(t_ns, name, scan, store=store)))
        return out

    # ------------------------------------------------------------------ public

    def write_odometry(self, t_s: float | None, robot_pose: np.ndarray, *, t_ns: int | None = None) -> None:
        """Write the robot's pose ``robot_pose`` (``body_to_odom (4, 4)``) at ``t_s`` (or ``t_ns``):
        ``/tf`` ``odom -> body`` and ``NS/odom``, whose twist is the backward difference from the
        previous ``write_odometry`` (or ``write_tick``) call."""
        stamp = self._stamp_ns(t_s, t_ns)
        pose, messages = self._odometry_messages(stamp, robot_pose)
        self._emit(stamp, messages)
        self._last_odometry = (stamp, pose)

    def write_sensors(
        self,
        t_s: float | None = None,
        *,
        t_ns: int | None = None,
        images: Mapping[str, np.ndarray] | None = None,
        depths: Mapping[str, np.ndarray] | None = None,
        compressed_images: Mapping[str, bytes] | None = None,
        clouds: Mapping[str, OrganizedScan] | None = None,
        infos: Mapping[str, Camera] | None = None,
    ) -> None:
        """Write sensor data taken at ``t_s`` (or ``t_ns``), each camera's CameraInfo once with it.

        images: camera name -> ``(H, W, 3)`` RGB or ``(H, W)`` gray (uint8, or float in [0, 1]);
        compressed_images: camera name -> JPEG bytes, written as they are (see
        :func:`compressed_image_message`); depths: camera name -> ``(H, W)`` metres; clouds: LiDAR
        name -> its sweep (points in the sensor frame); infos: camera name -> intrinsics,
        overriding the rig's (a camera with neither gets no CameraInfo).
        """
        stamp = self._stamp_ns(t_s, t_ns)
        self._emit(stamp, self._sensor_messages(stamp, images, depths, compressed_images, clouds, infos))

    def write_tick(
        self,
        t_s: float | None,
        robot_pose: np.ndarray,
        images: Mapping[str, np.ndarray] | None = None,
        depths: Mapping[str, np.ndarray] | None = None,
        clouds: Mapping[str, OrganizedScan] | None = None,
        infos: Mapping[str, Camera] | None = None,
        *,
        compressed_images: Mapping[str, bytes] | None = None,
        t_ns: int | None = None,
    ) -> None:
        """Write one tick at time ``t_s`` (or ``t_ns``): :meth:`write_odometry` of ``robot_pose``
        and :meth:`write_sensors` of the rest, all at that one stamp (checked together: an error
        writes nothing)."""
        stamp = self._stamp_ns(t_s, t_ns)
        pose, messages = self._odometry_messages(stamp, robot_pose)
        messages += self._sensor_messages(stamp, images, depths, compressed_images, clouds, infos)
        self._emit(stamp, messages)
        self._last_odometry = (stamp, pose)

    def _odometry(self, t_ns: int, pose: np.ndarray):
        linear = np.zeros(3)
        angular = np.zeros(3)
        if self._last_odometry is not None and t_ns > self._last_odometry[0]:  # else _emit refuses the stamp
            dt = (t_ns - self._last_odometry[0]) * 1e-9
            prev = self._last_odometry[1]
            linear = pose[:3, :3].T @ (pose[:3, 3] - prev[:3, 3]) / dt
            angular = Rotation.from_matrix(prev[:3, :3].T @ pose[:3, :3]).as_rotvec() / dt
        store = self._store

        def vec(v: np.ndarray):
            return build_message(store, "geometry_msgs/msg/Vector3", x=float(v[0]), y=float(v[1]), z=float(v[2]))

        tr = _transform_msg(pose, store)
        position = build_message(store, "geometry_msgs/msg/Point", x=tr.translation.x, y=tr.translation.y, z=tr.translation.z)
        return build_message(
            store, "nav_msgs/msg/Odometry",
            header=_header(t_ns, self.odom_frame, store),
            child_frame_id=self.body_frame,
            pose=build_message(store, "geometry_msgs/msg/PoseWithCovariance",
                      pose=build_message(store, "geometry_msgs/msg/Pose", position=position, orientation=tr.rotation),
                      covariance=np.zeros(36)),
            twist=build_message(store, "geometry_msgs/msg/TwistWithCovariance",
                       twist=build_message(store, "geometry_msgs/msg/Twist", linear=vec(linear), angular=vec(angular)),
                       covariance=np.zeros(36)),
        )

    def close(self) -> Path:
        """Finish the bag and move it into place; returns its path."""
        if not self._closed:
            self._closed = True
            self._writer.close()
            os.replace(self._tmp_dir / self.path.name, self.path)
            self._tmp_dir.rmdir()
        return self.path

    def abort(self) -> None:
        """Drop everything written: no bag is left behind."""
        if not self._closed:
            self._closed = True
            self._writer.abort()
            shutil.rmtree(self._tmp_dir, ignore_errors=True)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
