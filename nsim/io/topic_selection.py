"""Which topics of a robot's bag to read: a :class:`Selection` (:func:`load_selection` reads it
from YAML, strictly), and the names streams get by default (:func:`default_stream_names`).

:class:`nsim.io.robot_log.RobotLog` applies a selection when it opens a bag::

    cameras:                      # colour/gray images; name -> topics
      front: {image: /front/image, info: /front/camera_info}
      back: /back/image_raw/compressed      # info: the CameraInfo topic in the image's namespace
    depth:                        # depth images (16UC1 millimetres or 32FC1 metres), same form
      front: /front/depth
    lidar: {top: /points}         # name -> PointCloud2 topic
    odometry: /odom               # nav_msgs/Odometry
    pose: /pose                   # geometry_msgs/PoseStamped or PoseWithCovarianceStamped: the body's path
    tf: /tf                       # default /tf and /tf_static when present
    tf_static: /tf_static
    body_frame: body              # default: the odometry's child frame (if named), else base_link / body / base_footprint
                                  # (a RealSense SDK bag: its reference stream's frame, nsim.io.realsense)
    odom_frame: odom              # default: the odometry's frame, else odom, else the pose topic's frame

A group left out (or ``null``) gets the defaults by message type: **cameras** and **depth** are the
Image and CompressedImage topics that have a CameraInfo topic in their namespace (``/a/b/image``
and ``/a/b/image/compressed`` look in ``/a/b/``: ``camera_info`` there, or the only CameraInfo
topic there) or else at ``info/camera_info`` beside it (``/a/b/data`` -> ``/a/info/camera_info``,
a RealSense SDK bag's layout); an Image whose first message is 16UC1 or 32FC1 is depth (in a
RealSense SDK bag: the ``Depth_N`` streams, :mod:`nsim.io.realsense`); a compressed topic whose raw
topic is in the bag is left to the raw one; images without a CameraInfo and compressedDepth topics
are skipped with a warning (never a topic the selection names: a group that names its topics takes
nothing from the defaults, and the other group's defaults leave those topics alone). **lidar**:
every PointCloud2 topic. **odometry**: the Odometry topic when there is exactly one (several: none,
with a warning). **pose**: the PoseStamped or PoseWithCovarianceStamped topic when there is exactly
one and no Odometry topic (topics named like a goal, ``/goal_pose``, are not taken; several: none,
with a warning). Default names are the topic's namespace when its last
part is a generic word (``/front/image`` -> ``front``, ``/velodyne/points`` -> ``velodyne``), the
whole topic otherwise (``/velodyne_points``), with ``/`` as ``_``; a RealSense SDK bag's streams are
named by their kind (``Color_0`` -> ``color``, ``Infrared_1`` -> ``infrared_1``). An image topic whose last part
starts with ``image_rect`` is rectified: its camera is the PINHOLE of the CameraInfo's ``P``
(``rectified: true|false`` overrides the guess); other images use ``K`` and ``D``
(:func:`nsim.io.rosbag.camera_from_info`), ``D`` in the CameraInfo's ``distortion_model`` unless the
entry's ``distortion`` (plumb_bob, rational_polynomial or equidistant) says how to read it, e.g.
a RealSense colour camera's ``Inverse Brown Conrady`` coefficients read as plumb_bob, as the
realsense2_camera driver publishes them (``front: {image: /front/image, distortion: plumb_bob}``).
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nsim.errors import InputError

#: The ROS distortion models a camera entry's ``distortion`` may name.
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
#: Last topic parts that name what a topic carries, not which sensor: dropped from default names.
GENERIC_TOPIC_PARTS = ("image", "image_raw", "image_rect", "image_color", "image_mono", "image_rect_color",
                       "image_rect_raw", "depth", "points", "points_raw", "cloud", "pointcloud", "point_cloud")


@dataclass(frozen=True)
class CameraTopics:
    """One camera's topics. info None: the CameraInfo in the image topic's namespace; rectified
    None: guessed from the topic (last part starts with ``image_rect``); distortion None: the
    CameraInfo's distortion_model, else the ROS model its ``D`` is read as."""

    image: str
    info: str | None = None
    rectified: bool | None = None
    distortion: str | None = None


@dataclass(frozen=True)
class Selection:
    """Which topics to read (see the module docstring); a group that is None gets the defaults."""

    cameras: Mapping[str, CameraTopics] | None = None
    depth: Mapping[str, CameraTopics] | None = None
    lidar: Mapping[str, str] | None = None
    odometry: str | None = None
    pose: str | None = None
    tf: str | None = None
    tf_static: str | None = None
    body_frame: str | None = None
    odom_frame: str | None = None

    @classmethod
    def from_data(cls, data: Any, where: str = "selection") -> Selection:
        """Strict reading of plain data (parsed YAML): unknown keys and wrong types raise
        :class:`InputError` naming ``where`` and the dotted key."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            raise InputError(f"{where}: expected a mapping, got {type(data).__name__}")
        keys = ("cameras", "depth", "lidar", "odometry", "pose", "tf", "tf_static", "body_frame", "odom_frame")
        check_keys(data, keys, where)
        out: dict[str, Any] = {}
        for group in ("cameras", "depth"):
            if data.get(group) is not None:
                out[group] = {name: _camera_topics(entry, f"{where}.{group}.{name}")
                              for name, entry in _mapping(data[group], f"{where}.{group}").items()}
        if data.get("lidar") is not None:
            lidar = {}
            for name, entry in _mapping(data["lidar"], f"{where}.lidar").items():
                if isinstance(entry, Mapping):
                    check_keys(entry, ("points",), f"{where}.lidar.{name}")
                    entry = entry.get("points")
                lidar[name] = _topic_name(entry, f"{where}.lidar.{name}")
            out["lidar"] = lidar
        for key in ("odometry", "pose", "tf", "tf_static"):
            if data.get(key) is not None:
                out[key] = _topic_name(data[key], f"{where}.{key}")
        for key in ("body_frame", "odom_frame"):
            if data.get(key) is not None:
                if not isinstance(data[key], str) or not data[key].strip("/"):
                    raise InputError(f"{where}.{key}: expected a frame name, got {data[key]!r}")
                out[key] = data[key].lstrip("/")
        return cls(**out)


def load_selection(path: str | os.PathLike) -> Selection:
    """A :class:`Selection` from a YAML file (strict; errors name the file and the dotted key)."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
    return Selection.from_data(data, str(path))


def check_keys(data: Mapping, known: Sequence[str], where: str) -> None:
    for key in data:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(known)})"
            raise InputError(f"{where}: unknown key {key!r}{hint}")


def _mapping(value: Any, where: str) -> Mapping:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and k for k in value):
        raise InputError(f"{where}: expected a mapping from names to topics, got {value!r}")
    return value


def _topic_name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip("/"):
        raise InputError(f"{where}: expected a topic name, got {value!r}")
    return "/" + value.lstrip("/")


def _camera_topics(entry: Any, where: str) -> CameraTopics:
    if isinstance(entry, str):
        return CameraTopics(_topic_name(entry, where))
    if not isinstance(entry, Mapping):
        raise InputError(f"{where}: expected a topic or a mapping with image (and info, rectified, distortion), got "
                         f"{entry!r}")
    check_keys(entry, ("image", "info", "rectified", "distortion"), where)
    if "image" not in entry:
        raise InputError(f"{where}: missing key 'image'")
    info = None if entry.get("info") is None else _topic_name(entry["info"], f"{where}.info")
    rectified = entry.get("rectified")
    if rectified is not None and not isinstance(rectified, bool):
        raise InputError(f"{where}.rectified: expected true or false, got {rectified!r}")
    distortion = entry.get("distortion")
    if distortion is not None and distortion not in DISTORTION_MODELS:
        raise InputError(f"{where}.distortion: expected one of {', '.join(DISTORTION_MODELS)}, got {distortion!r}")
    return CameraTopics(_topic_name(entry["image"], f"{where}.image"), info, rectified, distortion)



def default_stream_names(bases: Mapping[str, str]) -> dict[str, str]:
    """Default stream names from topics (``bases``: topic -> the topic that names it)."""

    def short(base: str) -> str:
        parts = [p for p in base.split("/") if p]
        if len(parts) > 1 and parts[-1] in GENERIC_TOPIC_PARTS:
            parts = parts[:-1]
        return "_".join(parts)

    def full(base: str) -> str:
        return "_".join(p for p in base.split("/") if p)

    names = {t: short(b) for t, b in bases.items()}
    clash = {n for n in names.values() if list(names.values()).count(n) > 1}
    names = {t: full(bases[t]) if names[t] in clash else names[t] for t in bases}
    seen: dict[str, int] = {}
    for t in sorted(names):
        n = names[t]
        seen[n] = seen.get(n, 0) + 1
        if seen[n] > 1:
            names[t] = f"{n}_{seen[n]}"
    return names
