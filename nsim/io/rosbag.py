"""ROS 2 bag export of rendered sensor data, with the ``rosbags`` library (no ROS installation needed).

``BagWriter`` takes a run tick by tick and writes (``NS`` = the optional ``namespace``):

================================  ============================  ===========================================
topic                             type                          content
================================  ============================  ===========================================
``NS/<camera>/image``             sensor_msgs/msg/Image         ``rgb8`` (H, W, 3) or ``mono8`` (H, W)
``NS/<camera>/depth``             sensor_msgs/msg/Image         ``32FC1`` metres (inf = no return, NaN = invalid)
``NS/<camera>/camera_info``       sensor_msgs/msg/CameraInfo    with every image or depth of that camera
``NS/<lidar>/points``             sensor_msgs/msg/PointCloud2   returns only: x y z intensity (float32), ring (uint16)
``/tf``                           tf2_msgs/msg/TFMessage        ``odom -> body`` at every tick
``/tf_static``                    tf2_msgs/msg/TFMessage        ``body -> <sensor frame>`` once (transient local)
``NS/odom``                       nav_msgs/msg/Odometry         body pose in ``odom``, body-frame twist
================================  ============================  ===========================================

Frames: ``odom`` is the world of the run, ``body`` the robot's body (x forward, y left, z up).
A camera ``c``'s data is in frame ``c_optical`` (OpenCV axes, as ROS requires of image frames, REP
103), a LiDAR ``l``'s in frame ``l`` (x forward, y left, z up). Times: message stamps and bag times
are ``time_offset_ns + round(t_s * 1e9)``. Twist: the backward difference of consecutive ticks,
expressed in the body frame (zero at the first tick).

CameraInfo: ``K`` and ``P = [K | 0]`` in OpenCV's pixel convention (the same as nsim's), ``R = I``;
``distortion_model`` ``plumb_bob`` with ``D = (k1, k2, p1, p2, k3)`` for PINHOLE (zeros) and OPENCV,
``equidistant`` with ``D = (k1, k2, k3, k4)`` for OPENCV_FISHEYE (Kannala-Brandt, as
``camera_calibration`` and ``image_geometry`` use it). EQUIRECTANGULAR has no ROS model (ValueError).

The bag (sqlite3 by default, or mcap; bag format version 8) is written under a temporary name and
renamed into place on ``close``; an error inside ``with BagWriter(...)`` leaves no bag. The bag
directory must not exist yet, not even empty (as with ``ros2 bag record -o`` and rosbags' own
``Writer``), and its parent must be a writable directory: :func:`check_bag_destination`.
``read_image``, ``read_pointcloud`` and ``matrix_from_transform`` turn messages back into arrays.
"""

from __future__ import annotations

import math
import os
import shutil
import uuid
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.images import to_uint8
from nsim.sensors.rig import CameraSensor, OrganizedScan, Rig

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
T = TYPESTORE.types
_INFINITE = QosTime(2147483647, 4294967295)
#: /tf_static is latched: late subscribers (rviz, tf2 buffers) still get the sensor frames.
TF_STATIC_QOS = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                    _INFINITE, _INFINITE, QosLiveliness.AUTOMATIC, _INFINITE, False)
CLOUD_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "ring"],
                        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2"],
                        "offsets": [0, 4, 8, 12, 16], "itemsize": 20})


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


def _stamp(t_ns: int):
    return T["builtin_interfaces/msg/Time"](sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def _header(t_ns: int, frame_id: str):
    return T["std_msgs/msg/Header"](stamp=_stamp(t_ns), frame_id=frame_id)


def _transform_msg(pose: np.ndarray):
    """geometry_msgs/Transform of a rigid ``(4, 4)``."""
    q = Rotation.from_matrix(pose[:3, :3]).as_quat()  # xyzw
    if q[3] < 0:
        q = -q
    x, y, z = (float(v) for v in pose[:3, 3])
    return T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
        rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )


def matrix_from_transform(transform) -> np.ndarray:
    """``(4, 4)`` from a geometry_msgs/Transform (or a Pose, via ``position``/``orientation``)."""
    t = getattr(transform, "translation", None) or transform.position
    q = getattr(transform, "rotation", None) or transform.orientation
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    out[:3, 3] = [t.x, t.y, t.z]
    return out


def image_message(t_ns: int, frame_id: str, image: np.ndarray):
    """sensor_msgs/Image: ``(H, W, 3)`` -> rgb8, ``(H, W)`` -> mono8; uint8, or floats in [0, 1]
    quantised with ``nsim.io.images.to_uint8``. (Depth goes through ``depth_message``.)"""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        image = to_uint8(image)
    if image.ndim == 3 and image.shape[2] == 3:
        encoding, channels = "rgb8", 3
    elif image.ndim == 2:
        encoding, channels = "mono8", 1
    else:
        raise ValueError(f"image: expected (H, W, 3) or (H, W), got shape {image.shape}")
    h, w = image.shape[:2]
    return T["sensor_msgs/msg/Image"](
        header=_header(t_ns, frame_id), height=h, width=w, encoding=encoding, is_bigendian=0,
        step=w * channels, data=np.ascontiguousarray(image).reshape(-1),
    )


def depth_message(t_ns: int, frame_id: str, depth_m: np.ndarray):
    """sensor_msgs/Image ``32FC1`` (little-endian float32 metres) from ``depth_m (H, W)``."""
    depth = np.asarray(depth_m, dtype="<f4")
    if depth.ndim != 2:
        raise ValueError(f"depth: expected (H, W), got shape {depth.shape}")
    h, w = depth.shape
    return T["sensor_msgs/msg/Image"](
        header=_header(t_ns, frame_id), height=h, width=w, encoding="32FC1", is_bigendian=0, step=w * 4,
        data=np.ascontiguousarray(depth).view(np.uint8).reshape(-1),
    )


def camera_info_message(t_ns: int, frame_id: str, camera: Camera):
    """sensor_msgs/CameraInfo of ``camera`` (see the module docstring for the distortion models)."""
    if camera.model == "OPENCV_FISHEYE":
        model, d = "equidistant", np.array(camera.dist, dtype=np.float64)
    elif camera.model in ("PINHOLE", "OPENCV"):
        model, d = "plumb_bob", np.array(camera.dist if camera.dist else (0.0,) * 5, dtype=np.float64)
    else:
        raise ValueError(f"camera_info: ROS has no distortion model for {camera.model}")
    K = camera.K
    P = np.concatenate([K, np.zeros((3, 1))], axis=1)
    return T["sensor_msgs/msg/CameraInfo"](
        header=_header(t_ns, frame_id), height=camera.height, width=camera.width, distortion_model=model,
        d=d, k=K.reshape(-1).copy(), r=np.eye(3).reshape(-1), p=P.reshape(-1), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def pointcloud_message(t_ns: int, frame_id: str, scan: OrganizedScan):
    """sensor_msgs/PointCloud2 of a sweep's returns (height 1, dense), fields x y z intensity ring."""
    hit = scan.hit
    points = np.zeros(int(hit.sum()), dtype=CLOUD_DTYPE)
    xyz = scan.xyz_m[hit]
    points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    points["intensity"] = scan.intensity[hit]
    points["ring"] = scan.ring[hit]
    field = T["sensor_msgs/msg/PointField"]
    fields = [field(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", 8), ("intensity", 12))]
    fields.append(field(name="ring", offset=16, datatype=4, count=1))  # 7 = FLOAT32, 4 = UINT16
    return T["sensor_msgs/msg/PointCloud2"](
        header=_header(t_ns, frame_id), height=1, width=len(points), fields=fields, is_bigendian=False,
        point_step=CLOUD_DTYPE.itemsize, row_step=CLOUD_DTYPE.itemsize * len(points),
        data=points.view(np.uint8).reshape(-1), is_dense=True,
    )


def read_image(msg) -> np.ndarray:
    """Array of a sensor_msgs/Image written here: rgb8 ``(H, W, 3)`` / mono8 ``(H, W)`` uint8, 32FC1 ``(H, W)`` float32."""
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.encoding == "rgb8":
        return data.reshape(msg.height, msg.step)[:, : msg.width * 3].reshape(msg.height, msg.width, 3).copy()
    if msg.encoding == "mono8":
        return data.reshape(msg.height, msg.step)[:, : msg.width].copy()
    if msg.encoding == "32FC1":
        dtype = ">f4" if msg.is_bigendian else "<f4"
        rows = data.reshape(msg.height, msg.step)[:, : msg.width * 4]
        return np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width).astype(np.float32)
    raise ValueError(f"read_image: unsupported encoding {msg.encoding!r}")


def read_pointcloud(msg) -> np.ndarray:
    """Structured array ``(N,)`` of a PointCloud2 with its named fields (FLOAT32/UINT16/... scalars)."""
    types = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
    order = ">" if msg.is_bigendian else "<"
    dtype = np.dtype({"names": [f.name for f in msg.fields], "formats": [order + types[f.datatype] for f in msg.fields],
                      "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_step})
    data = np.asarray(msg.data, dtype=np.uint8)
    return data.view(dtype).reshape(msg.height * msg.width).copy()


class BagWriter:
    """Writes a ROS 2 bag incrementally, one simulation tick at a time (see the module docstring).

    ``with BagWriter(out / "run", rig) as bag: bag.write_tick(t_s, body_to_world, images=..., ...)``.

    path: the bag directory to create (see :func:`check_bag_destination`; InputError otherwise). rig: gives the static transforms, the
    frame of each sensor and the CameraInfo of each camera; without one, pass ``static_transforms``
    (``{frame_id: frame_to_body (4, 4)}``) and ``infos`` yourself. storage: ``sqlite3`` | ``mcap``.
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
        self.path = check_bag_destination(path)
        if storage not in ("sqlite3", "mcap"):
            raise ValueError(f"storage: expected sqlite3 or mcap, got {storage!r}")
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
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(self._tmp_dir / self.path.name, version=8, storage_plugin=plugin)
        self._writer.open()
        self._connections: dict[str, object] = {}
        self._last: tuple[int, np.ndarray] | None = None
        self._closed = False

    # ------------------------------------------------------------------ plumbing

    def _topic(self, *parts: str) -> str:
        return "/".join([self.namespace, *parts]) if self.namespace else "/" + "/".join(parts)

    def _write(self, topic: str, msg, t_ns: int, qos: Qos | None = None) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msg.__msgtype__, typestore=TYPESTORE,
                                               offered_qos_profiles=[qos] if qos else [])
            self._connections[topic] = conn
        self._writer.write(conn, t_ns, bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__)))

    def _tf(self, t_ns: int, parent: str, child: str, pose: np.ndarray):
        return T["geometry_msgs/msg/TransformStamped"](header=_header(t_ns, parent), child_frame_id=child,
                                                       transform=_transform_msg(pose))

    def _camera_for(self, name: str, infos: Mapping[str, Camera] | None) -> Camera | None:
        if infos is not None and name in infos:
            return infos[name]
        if self.rig is not None and name in self.rig.names and isinstance(self.rig[name], CameraSensor):
            return self.rig[name].camera
        return None

    # ------------------------------------------------------------------ public

    def write_tick(
        self,
        t_s: float,
        robot_pose: np.ndarray,
        images: Mapping[str, np.ndarray] | None = None,
        depths: Mapping[str, np.ndarray] | None = None,
        clouds: Mapping[str, OrganizedScan] | None = None,
        infos: Mapping[str, Camera] | None = None,
    ) -> None:
        """Write one tick at time ``t_s`` (seconds, increasing from tick to tick).

        robot_pose: ``body_to_world (4, 4)``. images: camera name -> ``(H, W, 3)`` RGB or ``(H, W)``
        gray (uint8, or float in [0, 1]); depths: camera name -> ``(H, W)`` metres; clouds: LiDAR
        name -> its sweep (points in the sensor frame); infos: camera name -> intrinsics, overriding
        the rig's (a camera with neither gets no CameraInfo).
        """
        if self._closed:
            raise RuntimeError("BagWriter: already closed")
        if not math.isfinite(t_s):
            raise ValueError(f"t_s: expected a finite time, got {t_s}")
        t_ns = self.time_offset_ns + int(round(t_s * 1e9))
        pose = np.asarray(robot_pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"robot_pose: expected a finite (4, 4), got shape {pose.shape}")
        if self._last is not None and t_ns <= self._last[0]:
            raise ValueError(f"t_s: ticks must be increasing, got {t_s} after {(self._last[0] - self.time_offset_ns) / 1e9}")
        if self._last is None and self.static_transforms:
            statics = [self._tf(t_ns, self.body_frame, child, T_) for child, T_ in self.static_transforms.items()]
            self._write("/tf_static", T["tf2_msgs/msg/TFMessage"](transforms=statics), t_ns, TF_STATIC_QOS)
        self._write("/tf", T["tf2_msgs/msg/TFMessage"](transforms=[self._tf(t_ns, self.odom_frame, self.body_frame, pose)]), t_ns)
        self._write(self._topic("odom"), self._odometry(t_ns, pose), t_ns)
        with_info = []
        for name, image in (images or {}).items():
            self._write(self._topic(name, "image"), image_message(t_ns, camera_frame(name), image), t_ns)
            with_info.append(name)
        for name, depth in (depths or {}).items():
            self._write(self._topic(name, "depth"), depth_message(t_ns, camera_frame(name), depth), t_ns)
            with_info.append(name)
        for name in dict.fromkeys(with_info):
            camera = self._camera_for(name, infos)
            if camera is not None:
                self._write(self._topic(name, "camera_info"), camera_info_message(t_ns, camera_frame(name), camera), t_ns)
        for name, scan in (clouds or {}).items():
            self._write(self._topic(name, "points"), pointcloud_message(t_ns, name, scan), t_ns)
        self._last = (t_ns, pose)

    def _odometry(self, t_ns: int, pose: np.ndarray):
        linear = np.zeros(3)
        angular = np.zeros(3)
        if self._last is not None:
            dt = (t_ns - self._last[0]) * 1e-9
            prev = self._last[1]
            linear = pose[:3, :3].T @ (pose[:3, 3] - prev[:3, 3]) / dt
            angular = Rotation.from_matrix(prev[:3, :3].T @ pose[:3, :3]).as_rotvec() / dt
        vec = T["geometry_msgs/msg/Vector3"]
        tr = _transform_msg(pose)
        return T["nav_msgs/msg/Odometry"](
            header=_header(t_ns, self.odom_frame),
            child_frame_id=self.body_frame,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=tr.translation.x, y=tr.translation.y, z=tr.translation.z),
                    orientation=tr.rotation,
                ),
                covariance=np.zeros(36),
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=vec(x=float(linear[0]), y=float(linear[1]), z=float(linear[2])),
                                                   angular=vec(x=float(angular[0]), y=float(angular[1]), z=float(angular[2]))),
                covariance=np.zeros(36),
            ),
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
