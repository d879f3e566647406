"""A robot's recording -- a ROS 1 ``.bag`` or a ROS 2 bag directory (sqlite3 or mcap) -- as arrays.

::

    with RobotLog("run.bag") as log:                    # or RobotLog(path, load_selection("topics.yaml"))
        front = log.cameras["front"]                    # CameraStream: stamps_ns (N,), camera, frame_id
        rgb = log.image(front, 0)                       # frame 0, decoded now (RGB uint8)
        for i, rgb in log.images(front): ...            # every frame, streamed
        front_to_body = log.sensor_to_body(front.frame_id)
        trajectory = log.body_trajectory()              # stamps_ns (N,), body_to_odom (N, 4, 4)
        pairs = associate(front.stamps_ns, log.lidars["top"].stamps_ns, tolerance_ns=20_000_000)

(``load_selection`` is :func:`nsim.io.topic_selection.load_selection`, ``associate``
:func:`nsim.io.header_stamps.associate`.)

A bag is one or more ROS 1 ``.bag`` files (a split recording) or one ROS 2 bag directory, read
with ``rosbags`` (:mod:`nsim.io.bag_topics`); nothing is executed or unpickled. A RealSense SDK bag
(realsense-viewer's, rs-record's) is read in its own layout (:mod:`nsim.io.realsense`: its cameras,
extrinsics as static links to its reference stream, which is the body, and each depth stream's
stated unit in ``CameraStream.depth_unit``). A bag may hold no camera, depth or LiDAR stream at all
(a trajectory alone).

Topics come from a :class:`~nsim.io.topic_selection.Selection`, or by message type where it leaves
a group out (:mod:`nsim.io.topic_selection` says how). Stamps are the messages' header stamps in
integer nanoseconds (:mod:`nsim.io.header_stamps`); a stream's ``stamps_from_bag`` counts those
that came from the bag's receive time instead, and a warning names the topic. The streams, odometry
and trajectory a log returns are the dataclasses of :mod:`nsim.io.recording_streams`.

**Frames.** Frame ids lose a leading ``/`` (ROS 1's tf allowed one; tf2 does not). /tf and
/tf_static become ``log.tf``, a :class:`~nsim.io.tf_tree.TfTree` (how links chain and how moving
ones are sampled). :meth:`RobotLog.sensor_to_body` chains /tf_static links;
:meth:`RobotLog.body_trajectory` takes odom -> body from /tf, else from the Odometry topic, else
from the PoseStamped topic (``log.pose``, :mod:`nsim.io.log_trajectory`). An Odometry whose
``child_frame_id`` is empty (ROS 1 Stage's ground truth) is taken to give the body's pose (a warning
says so), as a PoseStamped's always does.

**Errors.** Bad input raises :class:`~nsim.errors.InputError` with one line that names the bag,
the topic and, where one message is at fault, its index in the topic (0-based, bag order): a topic
that is not in the bag (with the ones of the wanted type that are), an image topic without
CameraInfo, an unknown encoding, an image whose size differs from its CameraInfo, a compressed
image that does not decode, a PointCloud2 without x/y/z, stamps that do not increase, a missing tf
link, a bad quaternion, a depth stream whose unit nothing states, a trajectory of one pose, a bag cut
short (ROS 1: no index; while reading: the topics read).

Everything here returns new arrays: nothing read is modified in place.
"""

from __future__ import annotations

import difflib
import logging
import os
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError

from nsim.errors import InputError, name_list
from nsim.geometry.cameras import Camera
from nsim.io import log_trajectory, realsense
from nsim.io.bag_topics import TopicSummary, bag_paths, open_bag_reader
from nsim.io.header_stamps import HeaderStamps
from nsim.io.recording_streams import (
    BODY_FRAMES,
    ROS_DEPTH_UNITS,
    CameraStream,
    DepthUnit,
    LidarStream,
    MessageIndex,
    Odometry,
    PoseTopic,
    Trajectory,
)
from nsim.io.rosbag import (
    DEPTH_ENCODINGS,
    IMAGE_ENCODINGS,
    LidarPoints,
    camera_from_info,
    lidar_points,
    matrix_from_transform,
    read_compressed_image,
    read_image,
    stamp_ns,
)
from nsim.io.tf_tree import MovingLink, StaticLink, TfTree
from nsim.io.topic_selection import CameraTopics, Selection, default_stream_names

log = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
_READER_ERRORS = (Ros1ReaderError, Ros2ReaderError)


class _Topic:
    """What one pass over the bag gathers about one stream topic."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.stamps = HeaderStamps()
        self.log_times: list[int] = []
        self.connection: list[int] = []
        self.rank: list[int] = []
        self.last: dict[int, tuple[int, int]] = {}  # connection -> (last bag time, rank)
        self.first = None  # the first message, deserialized
        self.size: tuple[int, int] | None = None  # (width, height) of raw images
        self.encoding: str | None = None
        self.frame_id: str | None = None
        self.calibration: dict[tuple, Camera] = {}  # CameraInfo topics: (rectified, distortion) -> camera of message 0
        self.units: list[float] = []  # RealSense depth images: the depth_units after each message's data

    def place(self, connection: int, log_time_ns: int) -> None:
        t, rank = self.last.get(connection, (None, -1))
        rank = rank + 1 if t == log_time_ns else 0
        self.last[connection] = (log_time_ns, rank)
        self.log_times.append(log_time_ns)
        self.connection.append(connection)
        self.rank.append(rank)

    def index(self) -> MessageIndex:
        return MessageIndex(np.array(self.log_times, np.int64), np.array(self.connection, np.int64),
                            np.array(self.rank, np.int64))


class RobotLog:
    """An open robot recording (see the module docstring). Use as a context manager, or ``close()``.

    Attributes, all read when it opens: ``paths``; ``topics`` (name -> :class:`TopicSummary`);
    ``cameras`` and ``depth`` (name -> :class:`CameraStream`); ``lidars`` (name ->
    :class:`LidarStream`); ``odometry`` (:class:`Odometry` or None); ``pose`` (:class:`PoseTopic` or
    None); ``tf`` (:class:`TfTree`); ``body_frame`` and ``odom_frame`` (str or None); ``realsense``
    (a RealSense SDK bag). Image and cloud data stay in the bag until
    :meth:`image` / :meth:`images` / :meth:`cloud` / :meth:`clouds` read them.
    """

    def __init__(self, paths: str | os.PathLike | Sequence[str | os.PathLike],
                 selection: Selection | Mapping | None = None):
        if selection is not None and not isinstance(selection, Selection):
            selection = Selection.from_data(selection)
        self.paths = bag_paths(paths)
        self.name = str(self.paths[0]) + (f" (+{len(self.paths) - 1} more)" if len(self.paths) > 1 else "")
        self._reader: AnyReader | None = open_bag_reader(self.paths, self.name)
        try:
            self._connections = {name: list(info.connections) for name, info in self._reader.topics.items()}
            self.topics = {name: TopicSummary(name, info.msgtype, info.msgcount)
                           for name, info in self._reader.topics.items()}
            self.realsense = realsense.is_realsense_bag(self.topics)
            self._load(selection or Selection())
        except BaseException:
            self._reader.close()
            raise

    # ------------------------------------------------------------------ plumbing

    def _where(self, topic: str, index: int | None = None) -> str:
        return f"bag {self.name}: {topic}" + ("" if index is None else f" message {index}")

    def _of_type(self, msgtypes: Sequence[str]) -> list[str]:
        return sorted(t for t, s in self.topics.items() if s.msgtype in msgtypes)

    def _require(self, topic: str, msgtypes: Sequence[str], what: str) -> str:
        """``topic`` if the bag has it with one of ``msgtypes``; InputError naming it otherwise."""
        short = " or ".join(t.rsplit("/", 1)[-1] for t in msgtypes)
        if topic not in self.topics and topic.lstrip("/") in self.topics:
            topic = topic.lstrip("/")  # a ROS 1 bag's topic written without its leading slash (ROS 1 allowed it)
        if topic not in self.topics:
            have = self._of_type(msgtypes)
            close = difflib.get_close_matches(topic, list(self.topics), n=1)
            hint = f"; did you mean {close[0]}?" if close else ""
            raise InputError(f"{self._where(topic)}: no such topic ({what}){hint} (the bag's {short} topics: "
                             f"{name_list(have)})")
        msgtype = self.topics[topic].msgtype
        if msgtype not in msgtypes:
            raise InputError(f"{self._where(topic)}: is {msgtype or 'of several types'}, {what} needs {short}")
        return topic

    def _deserialize(self, raw: bytes, msgtype: str, topic: str, index: int):
        return self._decode(raw, msgtype, topic, index)[0]

    def _decode(self, raw: bytes, msgtype: str, topic: str, index: int) -> tuple[Any, float | None]:
        """The message, and the float32 librealsense appends to a ROS 1 Image (its depth_units) or None."""
        try:
            return self._reader.deserialize(raw, msgtype), None
        except (AnyReaderError, KeyError, ValueError, IndexError) as exc:
            if msgtype == IMAGE and not self._reader.is2 and self.realsense and len(raw) > 4:
                try:
                    return self._reader.deserialize(raw[:-4], msgtype), float(np.frombuffer(raw[-4:], "<f4")[0])
                except (AnyReaderError, KeyError, ValueError, IndexError):
                    pass
            raise InputError(f"{self._where(topic, index)}: does not deserialize as {msgtype}: {exc}") from None

    def _messages(self, connections: list, start: int | None = None, stop: int | None = None) -> Iterator:
        if self._reader is None:
            raise RuntimeError(f"RobotLog {self.name}: closed")
        messages = self._reader.messages(connections=connections, start=start, stop=stop)
        try:
            yield from messages
        except (AnyReaderError, OSError, ValueError, KeyError, IndexError) + _READER_ERRORS as exc:
            topics = name_list(sorted({c.topic for c in connections}))
            raise InputError(f"bag {self.name}: cut short or damaged while reading {topics}: "
                             f"{' '.join(str(exc).split())}") from None
        finally:
            messages.close()

    def _first(self, topic: str):
        """The first message of ``topic``, deserialized, or None when it has none."""
        messages = self._messages(self._connections[topic])
        try:
            for conn, _, raw in messages:
                return self._deserialize(raw, conn.msgtype, topic, 0)
            return None
        finally:
            messages.close()

    # ------------------------------------------------------------------ choosing topics

    def _base(self, image_topic: str) -> str:
        """The raw image topic a compressed one was made from (``/a/image/compressed`` -> ``/a/image``)."""
        if self.topics[image_topic].msgtype == COMPRESSED_IMAGE and image_topic.rsplit("/", 1)[-1] == "compressed":
            return image_topic[: -len("/compressed")]
        return image_topic

    def _sibling_info(self, image_topic: str) -> tuple[str | None, str, int]:
        """The CameraInfo topic of an image topic: ``camera_info`` in its namespace, or the only
        CameraInfo topic there (``/a/b/image/compressed`` looks in ``/a/b/``), else ``info/camera_info``
        beside the namespace (``/a/b/data`` -> ``/a/info/camera_info``: a RealSense SDK bag's). Returns it
        (or None), the namespace and how many CameraInfo topics it has."""
        namespace = self._base(image_topic).rsplit("/", 1)[0]
        siblings = [t for t in self._of_type([CAMERA_INFO]) if t.rsplit("/", 1)[0] == namespace]
        if namespace + "/camera_info" in siblings:
            return namespace + "/camera_info", namespace, len(siblings)
        beside = namespace.rsplit("/", 1)[0] + "/info/camera_info"
        if not siblings and self.topics.get(beside, TopicSummary(beside, None, 0)).msgtype == CAMERA_INFO:
            return beside, namespace, 0
        return (siblings[0] if len(siblings) == 1 else None), namespace, len(siblings)

    def _default_cameras(self, named: set[str], colour: bool, depth: bool,
                         ) -> tuple[dict[str, CameraTopics], dict[str, CameraTopics]]:
        """The default cameras (if ``colour``) and depth cameras (if ``depth``): image topics with a CameraInfo,
        but none the selection names (``named``), and warnings only for topics a wanted group would take."""
        found: dict[str, tuple[str, str, bool]] = {}  # topic -> (topic that names it, info topic, is depth)
        for topic in self._of_type([IMAGE, COMPRESSED_IMAGE]):
            compressed = self.topics[topic].msgtype == COMPRESSED_IMAGE
            last = topic.rsplit("/", 1)[-1]
            base = self._base(topic)
            if topic in named or base in named:
                continue
            if base != topic and self.topics.get(base, TopicSummary(base, None, 0)).msgtype == IMAGE:
                continue  # the raw topic is read instead
            first = self._first(topic)
            if compressed and (last == "compressedDepth" or
                               (first is not None and "compresseddepth" in str(first.format).lower())):
                if depth:
                    log.warning("%s: compressedDepth images are not read; skipped", self._where(topic))
                continue
            rs = realsense.stream_of(topic) if self.realsense else None  # RealSense: Depth_N, whatever the encoding
            is_depth = rs.is_depth if rs else not compressed and first is not None and first.encoding in DEPTH_ENCODINGS
            if not (depth if is_depth else colour):
                continue
            info, namespace, _ = self._sibling_info(topic)
            if info is None:
                log.warning("%s: no CameraInfo topic in %s/; skipped (name it in the selection to read it)",
                            self._where(topic), namespace)
                continue
            found[topic] = (base, info, is_depth)
        out: tuple[dict[str, CameraTopics], dict[str, CameraTopics]] = ({}, {})
        for group, want_depth in zip(out, (False, True), strict=True):
            topics = {t: base for t, (base, _, d) in found.items() if d == want_depth}
            names = (self.realsense and realsense.default_names(topics)) or default_stream_names(topics)
            for topic, name in names.items():
                group[name] = CameraTopics(topic, found[topic][1])
        return out

    def _resolve(self, sel: Selection) -> tuple[dict, dict, dict, str | None, str | None, str | None, str | None]:
        named = {e.image for group in (sel.cameras, sel.depth) if group is not None for e in group.values()}
        default_colour, default_depth = self._default_cameras(named, sel.cameras is None, sel.depth is None) \
            if sel.cameras is None or sel.depth is None else ({}, {})
        cameras = dict(default_colour if sel.cameras is None else sel.cameras)
        depth = dict(default_depth if sel.depth is None else sel.depth)
        for group_name, group in (("cameras", cameras), ("depth", depth)):
            for name, entry in group.items():
                what = f"{group_name}.{name}"
                image = self._require(entry.image, (IMAGE, COMPRESSED_IMAGE), what)
                info = entry.info
                if info is None:
                    info, namespace, n = self._sibling_info(image)
                    if info is None:
                        raise InputError(f"{self._where(image)}: no CameraInfo for this image topic "
                                         f"({n or 'no'} CameraInfo topics in {namespace}/; give {what}.info)")
                else:
                    info = self._require(info, (CAMERA_INFO,), f"{what}.info")
                rectified = entry.rectified
                if rectified is None:
                    rectified = self._base(image).rsplit("/", 1)[-1].startswith("image_rect")
                group[name] = CameraTopics(image, info, rectified, entry.distortion)
        if sel.lidar is None:
            points = self._of_type([POINT_CLOUD])
            names = default_stream_names({t: t for t in points})
            lidar = {names[t]: t for t in points}
        else:
            lidar = {name: self._require(topic, (POINT_CLOUD,), f"lidar.{name}") for name, topic in sel.lidar.items()}
        if sel.odometry is not None:
            odometry = self._require(sel.odometry, (ODOMETRY,), "odometry")
        else:
            found = self._of_type([ODOMETRY])
            odometry = found[0] if len(found) == 1 else None
            if len(found) > 1:
                log.warning("bag %s: several Odometry topics (%s); none read (choose one: odometry: TOPIC)",
                            self.name, ", ".join(found))
        if sel.pose is not None:
            pose = self._require(sel.pose, POSE_TYPES, "pose")
        else:
            found = [t for t in self._of_type(POSE_TYPES) if "goal" not in t.lower()]
            pose = found[0] if len(found) == 1 and not self._of_type([ODOMETRY]) else None
            if len(found) > 1 and not self._of_type([ODOMETRY]):
                log.warning("bag %s: several PoseStamped topics (%s); none read (choose one: pose: TOPIC)",
                            self.name, name_list(found))
        tf = self._require(sel.tf, TF_TYPES, "tf") if sel.tf else (
            "/tf" if self.topics.get("/tf", TopicSummary("", None, 0)).msgtype in TF_TYPES else None)
        tf_static = self._require(sel.tf_static, TF_TYPES, "tf_static") if sel.tf_static else (
            "/tf_static" if self.topics.get("/tf_static", TopicSummary("", None, 0)).msgtype in TF_TYPES else None)
        return cameras, depth, lidar, odometry, pose, tf, tf_static

    # ------------------------------------------------------------------ the pass over the bag

    def _load(self, sel: Selection) -> None:
        cameras, depth, lidar, odometry_topic, pose_topic, tf_topic, tf_static_topic = self._resolve(sel)
        gather: dict[str, _Topic] = {}
        kinds: dict[str, str] = {}
        info_modes: dict[str, set[tuple]] = {}  # CameraInfo topic -> read as (rectified, distortion), one or more
        for group in (cameras, depth):
            for entry in group.values():
                kinds[entry.image] = "image"
                kinds[entry.info] = "info"
                info_modes.setdefault(entry.info, set()).add((bool(entry.rectified), entry.distortion or ""))
        kinds.update({topic: "points" for topic in lidar.values()})
        if odometry_topic:
            kinds[odometry_topic] = "odometry"
        if pose_topic:
            kinds[pose_topic] = "pose"
        if tf_topic:
            kinds[tf_topic] = "tf"
        if tf_static_topic:
            kinds[tf_static_topic] = "tf_static"
        for topic in kinds:
            gather[topic] = _Topic(topic)
        conn_index = {(c.id, id(c.owner)): k for topic in kinds for k, c in enumerate(self._connections[topic])}
        counts = dict.fromkeys(kinds, 0)
        odom: dict[str, list] = {"pose": [], "linear": [], "angular": []}
        path: list[np.ndarray] = []  # the pose topic's poses
        static: dict[str, StaticLink] = {}
        moving: dict[tuple[str, str], tuple[HeaderStamps, list[np.ndarray]]] = {}
        connections = [c for topic in kinds for c in self._connections[topic]]
        for conn, log_time, raw in (self._messages(connections) if connections else ()):
            topic = conn.topic
            i = counts[topic]
            counts[topic] += 1
            where = self._where(topic, i)
            g = gather[topic]
            kind = kinds[topic]
            msg, units = self._decode(raw, conn.msgtype, topic, i)
            if kind in ("image", "points", "odometry", "pose"):
                g.place(conn_index[(conn.id, id(conn.owner))], log_time)
                g.stamps.add(stamp_ns(msg.header), log_time, where)
                if g.first is None:
                    g.first, g.frame_id = msg, msg.header.frame_id.lstrip("/")
            if kind == "image" and conn.msgtype == IMAGE:
                self._check_image(g, msg, where)
                g.units.append(units or 0.0)
            elif kind == "info":
                if g.first is None:
                    g.first = msg
                for mode in sorted(info_modes[topic]):
                    cam = camera_from_info(msg, rectified=mode[0], where=where, distortion=mode[1] or None)
                    if g.calibration.setdefault(mode, cam) != cam:
                        raise InputError(f"{where}: the calibration differs from message 0's; nsim takes one "
                                         "per camera")
            elif kind == "points":
                names = [str(f.name) for f in msg.fields]
                if missing := [c for c in "xyz" if c not in names]:
                    raise InputError(f"{where}: PointCloud2 without {'/'.join(missing)} "
                                     f"(fields: {', '.join(names) or 'none'})")
            elif kind == "odometry":
                if (msg.header.frame_id.lstrip("/"), msg.child_frame_id.lstrip("/")) != (
                        g.first.header.frame_id.lstrip("/"), g.first.child_frame_id.lstrip("/")):
                    raise InputError(f"{where}: frames {msg.header.frame_id!r} -> {msg.child_frame_id!r} differ from "
                                     f"the first message's {g.first.header.frame_id!r} -> {g.first.child_frame_id!r}")
                odom["pose"].append(_pose(msg.pose.pose, where))
                tw = msg.twist.twist
                odom["linear"].append([tw.linear.x, tw.linear.y, tw.linear.z])
                odom["angular"].append([tw.angular.x, tw.angular.y, tw.angular.z])
            elif kind == "pose":
                if msg.header.frame_id.lstrip("/") != g.frame_id:
                    raise InputError(f"{where}: frame {msg.header.frame_id!r} differs from the first message's "
                                     f"{g.first.header.frame_id!r}")
                path.append(_pose(getattr(msg.pose, "pose", msg.pose), where))  # PoseStamped, PoseWithCovarianceStamped
            elif kind in ("tf", "tf_static"):
                for tr in msg.transforms:
                    parent, child = tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/")
                    if not parent or not child or parent == child:
                        log.warning("%s: transform %r -> %r ignored", where, parent, child)
                        continue
                    pose = _pose(tr.transform, f"{where} ({parent} -> {child})")
                    if kind == "tf_static":
                        static[child] = StaticLink(parent, child, pose)
                        continue
                    stamps, poses = moving.setdefault((parent, child), (HeaderStamps(), []))
                    if stamps.add(stamp_ns(tr.header), log_time, f"{where} ({parent} -> {child})", strict=False):
                        poses.append(pose)

        rs_links, rs_body = realsense.extrinsic_links({  # a RealSense SDK bag's extrinsics, and its body frame
            t: _pose(m, self._where(t, 0)) for t in self._of_type([realsense.TRANSFORM])
            if (m := self._first(t)) is not None
        }) if self.realsense else ([], None)
        static |= {link.child: link for link in rs_links if link.child not in static}
        self.tf = TfTree(tuple(static.values()), tuple(
            MovingLink(p, c, np.array(s.stamps, np.int64), np.array(poses).reshape(-1, 4, 4))
            for (p, c), (s, poses) in moving.items()))
        tf_from_bag = sum(s.from_bag for s, _ in moving.values())
        if tf_from_bag:
            log.warning("%s: %d transforms have no header stamp; their bag times are used", self._where(tf_topic),
                        tf_from_bag)
        self.cameras = {name: self._camera_stream(name, e, gather) for name, e in cameras.items()}
        self.depth = {name: self._camera_stream(name, e, gather, depth=True) for name, e in depth.items()}
        self.lidars = {name: self._lidar_stream(name, topic, gather[topic]) for name, topic in lidar.items()}
        self.odometry = None
        if odometry_topic:
            g = gather[odometry_topic]
            self._warn_bag_stamps(g)
            self.odometry = Odometry(
                odometry_topic, g.first.header.frame_id.lstrip("/") if g.first else "",
                g.first.child_frame_id.lstrip("/") if g.first else "", np.array(g.stamps.stamps, np.int64),
                np.array(odom["pose"]).reshape(-1, 4, 4), np.array(odom["linear"], np.float64).reshape(-1, 3),
                np.array(odom["angular"], np.float64).reshape(-1, 3), g.stamps.from_bag)
        self.pose = None
        if pose_topic:
            g = gather[pose_topic]
            self._warn_bag_stamps(g)
            self.pose = PoseTopic(pose_topic, g.frame_id or "", np.array(g.stamps.stamps, np.int64),
                                  np.array(path).reshape(-1, 4, 4), g.stamps.from_bag)
        frames = self.tf.frames
        self.body_frame = sel.body_frame or (self.odometry.child_frame_id if self.odometry and
                                             self.odometry.child_frame_id else None) or next(
            (f for f in BODY_FRAMES if f in frames), None) or rs_body
        self.odom_frame = sel.odom_frame or (self.odometry.frame_id if self.odometry and self.odometry.frame_id
                                             else None) or ("odom" if "odom" in frames else None) or (
            self.pose.frame_id if self.pose and self.pose.frame_id else None)
        if self.odometry is not None and len(self.odometry.stamps_ns) and not self.odometry.child_frame_id:
            log.warning("%s: child_frame_id is empty; its poses are taken as the body's (body frame: %s)",
                        self._where(self.odometry.topic), self.body_frame or "unnamed")

    def _depth_unit(self, name: str, entry: CameraTopics, g: _Topic) -> DepthUnit | None:
        """A depth Image stream's unit where the bag states it (RealSense), None where REP 118 does; InputError for
        an encoding whose unit nothing states."""
        rs = realsense.stream_of(entry.image) if self.realsense else None
        if rs is not None and rs.is_depth and g.encoding in ("mono16", "16UC1"):
            stated, topic = realsense.stated_units(rs, {t: s.msgtype for t, s in self.topics.items()}, lambda t: [
                self._deserialize(raw, c.msgtype, t, i) for i, (c, _, raw) in enumerate(self._messages(self._connections[t]))],
                self.name)
            return realsense.depth_unit(rs, self._where(entry.image), g.units, stated, topic)
        if g.encoding == "mono16":
            raise InputError(f"{self._where(entry.image, 0)}: depth.{name} is mono16, a gray image without a depth "
                             "unit (depth is 16UC1 millimetres or 32FC1 metres, REP 118)")
        return None

    def _check_image(self, g: _Topic, msg, where: str) -> None:
        """Encoding known and constant, size constant (the pixels are checked when decoded)."""
        if msg.encoding not in IMAGE_ENCODINGS:
            raise InputError(f"{where}: unknown image encoding {msg.encoding!r} (nsim reads {', '.join(IMAGE_ENCODINGS)})")
        if g.encoding is None:
            g.encoding, g.size = msg.encoding, (int(msg.width), int(msg.height))
        elif msg.encoding != g.encoding or (int(msg.width), int(msg.height)) != g.size:
            raise InputError(f"{where}: {msg.width}x{msg.height} {msg.encoding}, the topic began with "
                             f"{g.size[0]}x{g.size[1]} {g.encoding}")

    def _warn_bag_stamps(self, g: _Topic) -> None:
        if g.stamps.from_bag:
            log.warning("%s: %d of %d messages have no header stamp; their bag times are used",
                        self._where(g.topic), g.stamps.from_bag, len(g.stamps.stamps))

    def _camera_stream(self, name: str, entry: CameraTopics, gather: dict[str, _Topic], depth: bool = False) -> CameraStream:
        g, info = gather[entry.image], gather[entry.info]
        group = "depth" if depth else "cameras"
        camera = info.calibration.get((bool(entry.rectified), entry.distortion or ""))
        if camera is None:
            raise InputError(f"{self._where(entry.info)}: no CameraInfo message for {group}.{name} ({entry.image})")
        msgtype = self.topics[entry.image].msgtype
        encoding = g.encoding or ""
        if msgtype == COMPRESSED_IMAGE:
            encoding = str(g.first.format) if g.first is not None else ""
        if depth and msgtype == COMPRESSED_IMAGE:
            raise InputError(f"{self._where(entry.image)}: depth.{name} is a CompressedImage; nsim reads depth from "
                             "16UC1 or 32FC1 Image topics")
        if depth and g.encoding is not None and g.encoding not in DEPTH_ENCODINGS + ("mono16",):
            raise InputError(f"{self._where(entry.image, 0)}: depth.{name} has encoding {g.encoding!r}, not a depth "
                             "encoding (16UC1 millimetres, 32FC1 metres)")
        if g.size is not None and g.size != (camera.width, camera.height):
            raise InputError(f"{self._where(entry.image, 0)}: the image is {g.size[0]}x{g.size[1]}, its CameraInfo "
                             f"({entry.info}) says {camera.width}x{camera.height}")
        self._warn_bag_stamps(g)
        rs = realsense.stream_of(entry.image) if self.realsense else None
        frame_id = rs.frame_id if rs else g.frame_id or info.first.header.frame_id.lstrip("/")  # RealSense: "0" or ""
        stream = CameraStream(name=name, topic=entry.image, info_topic=entry.info, frame_id=frame_id, camera=camera,
                              encoding=encoding, is_depth=depth, stamps_ns=np.array(g.stamps.stamps, np.int64),
                              msgtype=msgtype, stamps_from_bag=g.stamps.from_bag, messages=g.index(),
                              depth_unit=self._depth_unit(name, entry, g) if depth else None)
        if msgtype == COMPRESSED_IMAGE and len(stream):
            self._frame_checked(stream, g.first, 0)  # the first frame decodes, at the camera's size
        return stream

    def _lidar_stream(self, name: str, topic: str, g: _Topic) -> LidarStream:
        self._warn_bag_stamps(g)
        fields = tuple(str(f.name) for f in g.first.fields) if g.first is not None else ()
        return LidarStream(name, topic, g.frame_id or "", fields, np.array(g.stamps.stamps, np.int64),
                           g.stamps.from_bag, g.index())

    # ------------------------------------------------------------------ reading frames

    def _message(self, topic: str, messages: MessageIndex, i: int):
        n = len(messages.log_time_ns)
        if not 0 <= i < n:
            raise IndexError(f"{topic}: message {i} out of range ({n} messages)")
        conn = self._connections[topic][int(messages.connection[i])]
        t = int(messages.log_time_ns[i])
        rank = int(messages.rank[i])
        found = self._messages([conn], start=t, stop=t + 1)
        try:
            for k, (c, _, raw) in enumerate(found):
                if k == rank:
                    return self._deserialize(raw, c.msgtype, topic, i)
        finally:
            found.close()
        raise InputError(f"{self._where(topic, i)}: no longer found in the bag")

    def _frame_checked(self, stream: CameraStream, msg, i: int) -> np.ndarray:
        where = self._where(stream.topic, i)
        if stream.msgtype == COMPRESSED_IMAGE:
            image = read_compressed_image(msg, where=where)
        else:
            unit = stream.depth_unit or ROS_DEPTH_UNITS["16UC1"]
            image = read_image(msg, depth_m=stream.is_depth, units_per_m=unit.units_per_m, where=where)
        cam = stream.camera
        if image.shape[:2] != (cam.height, cam.width):
            raise InputError(f"{where}: the image is {image.shape[1]}x{image.shape[0]}, its CameraInfo "
                             f"({stream.info_topic}) says {cam.width}x{cam.height}")
        return image

    def image(self, stream: CameraStream, i: int) -> np.ndarray:
        """Frame ``i`` of a camera or depth stream, decoded: ``(H, W, 3)`` uint8 RGB, ``(H, W)``
        uint8/uint16 gray, or for depth ``(H, W)`` float32 metres (see :class:`CameraStream`)."""
        return self._frame_checked(stream, self._message(stream.topic, stream.messages, i), i)

    def images(self, stream: CameraStream) -> Iterator[tuple[int, np.ndarray]]:
        """Every frame of a stream in order, ``(i, image)``, read in one pass (one frame in memory)."""
        for i, msg in self._stream_messages(stream.topic, stream.messages):
            yield i, self._frame_checked(stream, msg, i)

    def _stream_messages(self, topic: str, messages: MessageIndex) -> Iterator[tuple[int, Any]]:
        for i, (conn, log_time, raw) in enumerate(self._messages(self._connections[topic])):
            if i >= len(messages.log_time_ns) or log_time != messages.log_time_ns[i]:
                raise InputError(f"{self._where(topic, i)}: the bag changed while it was open")
            yield i, self._deserialize(raw, conn.msgtype, topic, i)

    def cloud(self, stream: LidarStream, i: int, *, finite_only: bool = False) -> LidarPoints:
        """Cloud ``i`` of a LiDAR stream as :class:`nsim.io.rosbag.LidarPoints` (points in ``stream.frame_id``)."""
        msg = self._message(stream.topic, stream.messages, i)
        return lidar_points(msg, finite_only=finite_only, where=self._where(stream.topic, i))

    def clouds(self, stream: LidarStream, *, finite_only: bool = False) -> Iterator[tuple[int, LidarPoints]]:
        """Every cloud of a stream in order, ``(i, points)``, read in one pass."""
        for i, msg in self._stream_messages(stream.topic, stream.messages):
            yield i, lidar_points(msg, finite_only=finite_only, where=self._where(stream.topic, i))

    # ------------------------------------------------------------------ frames and motion

    def _body(self, body_frame: str | None) -> str:
        body = (body_frame or self.body_frame or "").lstrip("/")
        if not body:
            o = self.odometry
            why = f"the Odometry {o.topic} has no child_frame_id" if o is not None else "no Odometry"
            raise InputError(f"bag {self.name}: the body frame is unknown ({why}, no {'/'.join(BODY_FRAMES)} frame in "
                             "tf): give body_frame in the selection")
        return body

    def sensor_to_body(self, frame_id: str, body_frame: str | None = None) -> np.ndarray:
        """``sensor_to_body (4, 4)`` of ``frame_id`` through /tf_static (see :meth:`TfTree.sensor_to_body`)."""
        return self.tf.sensor_to_body(frame_id, self._body(body_frame))

    def body_trajectory(self, source: str = "auto") -> Trajectory:
        """The body's poses in the odom frame over time (:mod:`nsim.io.log_trajectory`).

        source: ``tf`` (the path from body to odom on /tf and /tf_static), ``odometry`` (the Odometry topic; an
        Odometry without child_frame_id gives the body's pose), ``pose`` (the PoseStamped topic: the body's pose in
        its header's frame), or ``auto``: tf where it has a path, else odometry, else pose (InputError with every
        reason when none works, and one line saying how to give a trajectory when the bag has none of them). A
        trajectory of fewer than two poses is InputError.
        """
        sources = {"tf": self._tf_trajectory, "odometry": self._odometry_trajectory, "pose": self._pose_trajectory}
        if source not in ("auto", *sources):
            raise ValueError(f"source: expected auto, tf, odometry or pose, got {source!r}")
        if source != "auto":
            return sources[source]()
        if not self.tf.moving and self.odometry is None and self.pose is None:
            raise InputError(f"bag {self.name}: no trajectory (no moving /tf link, no Odometry or PoseStamped topic "
                             "read): give the body's poses with nsim import-log BAG --trajectory FILE.tum, or name a "
                             "topic in the selection (odometry: TOPIC or pose: TOPIC)")
        errors: list[tuple[str, InputError]] = []
        for name in ("tf", "odometry", "pose"):
            if name == "tf" or getattr(self, name) is not None:
                try:
                    trajectory = sources[name]()
                except InputError as exc:
                    errors.append((name, exc))
                    continue
                if errors:
                    log.info("bag %s: trajectory from %s (%s)", self.name, trajectory.source,
                             "; ".join(f"from {n}: {e}" for n, e in errors))
                return trajectory
        (_, last), before = errors[-1], errors[:-1]
        raise InputError(f"{last} (and " + "; ".join(f"from {n}: {e}" for n, e in before) + ")") from None

    def _tf_trajectory(self) -> Trajectory:
        if not self.odom_frame:
            raise InputError(f"bag {self.name}: the odom frame is unknown: give odom_frame in the selection")
        return log_trajectory.from_tf(self.tf, self.odom_frame, self._body(None), self.name)

    def _odometry_trajectory(self) -> Trajectory:
        o = self.odometry
        if o is None:
            raise InputError(f"bag {self.name}: no Odometry topic to take the trajectory from")
        body = self._body(None) if o.child_frame_id else self.body_frame or ""  # no child: the body's poses
        return log_trajectory.from_topic(self.tf, "odometry", o.topic, o.frame_id, o.child_frame_id, o.stamps_ns,
                                         o.child_to_parent, self.odom_frame or o.frame_id, body, self.name)

    def _pose_trajectory(self) -> Trajectory:
        p = self.pose
        if p is None:
            raise InputError(f"bag {self.name}: no PoseStamped topic to take the trajectory from (pose: TOPIC in the "
                             "selection)")
        return log_trajectory.from_topic(self.tf, "pose", p.topic, p.frame_id, "", p.stamps_ns, p.body_to_frame,
                                         self.odom_frame or p.frame_id, self.body_frame or "", self.name)

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        """Close the bag (idempotent); streams and arrays read so far stay usable."""
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def __enter__(self) -> RobotLog:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


def _pose(transform, where: str) -> np.ndarray:
    try:
        return matrix_from_transform(transform)
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None

