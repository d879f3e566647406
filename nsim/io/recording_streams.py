"""What a robot recording holds once opened: its streams, its odometry and the body's trajectory.

The dataclasses that both readers return -- :class:`nsim.io.robot_log.RobotLog` (a ROS bag) and
:class:`nsim.io.robot_folder.RobotFolder` (a folder of files) -- with stamps in integer
nanoseconds (:mod:`nsim.io.header_stamps`) and poses as ``(4, 4)`` matrices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nsim.geometry.cameras import Camera

#: Default body frames, tried in this order when neither the selection nor an Odometry names one.
BODY_FRAMES = ("base_link", "body", "base_footprint")


@dataclass(frozen=True)
class MessageIndex:
    """Where a stream's messages lie in the bag, to read message ``i`` again.

    log_time_ns: (N,) int64 bag (receive) times; connection: (N,) int64, index into the topic's
    connections; rank: (N,) int64, the message's place among those of its connection with the
    same bag time (0 unless several share it).
    """

    log_time_ns: np.ndarray
    connection: np.ndarray
    rank: np.ndarray


@dataclass(frozen=True)
class CameraStreamInfo:
    """What a recording knows of one camera (or depth camera) stream, wherever its frames are held: a
    bag's topic (:class:`CameraStream`) or a folder (``nsim.io.robot_folder.FolderCameraStream``).

    name: the stream's name (its sensor in the rig); topic, info_topic: where its frames and its
    camera info are; stamps_ns: (N,) int64 header stamps (:mod:`nsim.io.header_stamps`); camera:
    intrinsics of the frames as decoded (for depth, of the depth image); frame_id: the images' frame
    (OpenCV axes by REP 103); encoding: the Image encoding, or the CompressedImage format string;
    is_depth: frames come back as float32 metres (NaN = no measurement for 16UC1's 0; 32FC1 as recorded).
    """

    name: str
    topic: str
    info_topic: str
    frame_id: str
    camera: Camera
    encoding: str
    is_depth: bool
    stamps_ns: np.ndarray

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass(frozen=True)
class DepthUnit:
    """What one integer (or float) of a depth stream's frames is in metres, and who says so.

    m_per_unit: metres per stored unit (16-bit PNG / 16UC1: 0.001 for millimetres, 0.0002 for TUM RGB-D's
    1/5000 m; float frames: 1.0); source: where that comes from, in words, for the log and the recording."""

    m_per_unit: float
    source: str

    @property
    def units_per_m(self) -> float:
        """The divisor a 16-bit frame is scaled by (1000 for millimetres, 5000 for TUM), exact in float32."""
        return float(np.float32(1.0 / self.m_per_unit))


#: ROS's depth encodings and their units by convention (REP 118).
ROS_DEPTH_UNITS = {"16UC1": DepthUnit(0.001, "16UC1: millimetres (ROS REP 118)"),
                   "32FC1": DepthUnit(1.0, "32FC1: metres (ROS REP 118)")}


def depth_unit_of(stream: CameraStreamInfo) -> DepthUnit:
    """The unit of a depth stream's frames: the one its reader stated (``stream.depth_unit``: a folder's, or a
    RealSense SDK bag's own, :mod:`nsim.io.realsense`), else the ROS convention of its encoding."""
    unit = getattr(stream, "depth_unit", None)
    if unit is not None:
        return unit
    if stream.encoding not in ROS_DEPTH_UNITS:
        raise ValueError(f"{stream.topic}: {stream.encoding!r} is not a depth encoding with a known unit")
    return ROS_DEPTH_UNITS[stream.encoding]


@dataclass(frozen=True)
class CameraStream(CameraStreamInfo):
    """One camera (or depth camera) topic (:class:`CameraStreamInfo`). Frames are decoded on demand by
    :meth:`nsim.io.robot_log.RobotLog.image`. msgtype: the topic's message type; stamps_from_bag: how many stamps came
    from the bag's receive times; messages: where each frame's message is; depth_unit: a depth stream's unit where
    the bag states it (a RealSense SDK bag), None where its encoding's convention holds (:func:`depth_unit_of`)."""

    msgtype: str
    stamps_from_bag: int
    messages: MessageIndex
    depth_unit: DepthUnit | None = None


@dataclass(frozen=True)
class LidarStream:
    """One PointCloud2 topic; clouds are read on demand by :meth:`nsim.io.robot_log.RobotLog.cloud`.

    stamps_ns: (N,) int64 header stamps; frame_id: the clouds' frame; fields: the first cloud's
    field names, in their order.
    """

    name: str
    topic: str
    frame_id: str
    fields: tuple[str, ...]
    stamps_ns: np.ndarray
    stamps_from_bag: int
    messages: MessageIndex

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass(frozen=True)
class Odometry:
    """A nav_msgs/Odometry topic, read whole.

    stamps_ns: (N,) int64; child_to_parent: (N, 4, 4), the pose of ``child_frame_id`` (the body)
    in ``frame_id`` (odom), i.e. body-in-odom; linear_mps, angular_radps: (N, 3) the twist, in
    ``child_frame_id`` as ROS specifies.
    """

    topic: str
    frame_id: str
    child_frame_id: str
    stamps_ns: np.ndarray
    child_to_parent: np.ndarray
    linear_mps: np.ndarray
    angular_radps: np.ndarray
    stamps_from_bag: int



@dataclass(frozen=True)
class PoseTopic:
    """A geometry_msgs/PoseStamped (or PoseWithCovarianceStamped) topic taken as the body's path, read whole.

    stamps_ns: (N,) int64; body_to_frame: (N, 4, 4), the body's pose in ``frame_id`` (the header's frame:
    the odom frame).
    """

    topic: str
    frame_id: str
    stamps_ns: np.ndarray
    body_to_frame: np.ndarray
    stamps_from_bag: int


@dataclass(frozen=True)
class Trajectory:
    """The body's motion: stamps_ns (N,) int64, body_to_odom (N, 4, 4) (the body's pose in odom).

    source: where it came from (``tf: odom -> body``, ``odometry /odom`` or ``pose /pose``); body_frame is empty
    when an Odometry without child_frame_id or a PoseStamped topic gave the poses and no body frame is known."""

    stamps_ns: np.ndarray
    body_to_odom: np.ndarray
    odom_frame: str
    body_frame: str
    source: str

