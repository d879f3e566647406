"""RealSense SDK bags: the ROS 1 ``.bag`` files ``realsense-viewer`` and ``rs-record`` write (librealsense's
``ros_writer``, file format version 3; 2 has the options elsewhere), as :class:`nsim.io.robot_log.RobotLog` reads them.

Their layout (``D`` device, ``S`` sensor, ``<Kind>_<i>`` a stream: ``Depth_0``, ``Color_0``,
``Infrared_1``, ``Fisheye_1``, ``Accel_0``, ...)::

    /file_version                                   std_msgs/UInt32 (3)
    /device_D/info, /device_D/sensor_S/info         diagnostic_msgs/KeyValue (name, serial number, ...)
    /device_D/sensor_S/<Kind>_<i>/info              realsense_msgs/StreamInfo (fps, encoding)
    /device_D/sensor_S/<Kind>_<i>/info/camera_info  sensor_msgs/CameraInfo (K, D; R and P zero)
    /device_D/sensor_S/<Kind>_<i>/image/data        sensor_msgs/Image (header frame_id "0" or empty)
    /device_D/sensor_S/<Kind>_<i>/image/metadata    diagnostic_msgs/KeyValue
    /device_D/sensor_S/<Kind>_<i>/tf/<g>            geometry_msgs/Transform: the stream's extrinsics
    /device_D/sensor_S/option/<Name>/value          std_msgs/Float32 (``Depth Units``: metres per unit)
    /device_D/sensor_S/option/<Name>/description    std_msgs/String
    /device_D/sensor_S/Accel_0/imu/data             sensor_msgs/Imu (not read)

**Cameras.** An ``image/data`` topic's CameraInfo is ``info/camera_info`` beside it (the rule of
:mod:`nsim.io.topic_selection`); its distortion names (``Brown Conrady``, ...) are librealsense's
(:func:`nsim.io.rosbag.camera_from_info`; a camera entry's ``distortion: plumb_bob`` in the selection
reads a refused model's coefficients as plumb_bob, as realsense2_camera does). ``Depth_<i>`` streams are depth (encoding ``mono16``:
librealsense's Z16; ``16UC1`` there is an infrared Y16 image, so the encoding does not decide);
the others are cameras. Default names: the kind in lower case, with the index unless it is 0
(``color``, ``depth``, ``infrared_1``), with ``device_D_sensor_S_`` in front where two would clash.

**Frames.** The images' frame ids say nothing (``0``, or empty); a stream's frame is ``<Kind>_<i>`` (``device_D/<Kind>_<i>``
past device 0). ``tf/<g>`` holds librealsense's extrinsics from the reference stream of group ``g``
to the stream (``p_stream = R p_reference + t``); each becomes a static link to the group's
reference frame. That frame is the stream whose extrinsics are the identity (the depth stream's
first: on a D400 the depth stream is the reference), or ``realsense_reference_<g>`` when none is.
The **body frame** is group 0's reference frame of the first device (``RobotLog.body_frame``), so
``sensor_to_body`` gives each stream's pose on the camera. Such a bag has no trajectory:
``body_trajectory`` says so and how to give one (``nsim import-log BAG --trajectory FILE.tum``).

**Depth units.** A depth image holds integers of a unit the bag states, never guessed (a D400 writes
0.001 m, an L515 0.00025 m): the ``depth_units`` float that newer librealsense versions append to
each depth Image (four bytes after ``data``, outside the message's definition: such images are read
without them and the value kept), else the sensor's ``option/Depth Units/value`` (or ``Depth_Units``;
``property`` in file format 2). Neither is one line naming the option topic; values that change, or frames and
option that disagree, are one line too. The unit lands in the stream's ``depth_unit``
(:func:`nsim.io.recording_streams.depth_unit_of`), so depth frames come back in metres.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from nsim.errors import InputError
from nsim.geometry.transforms import invert_se3
from nsim.io.recording_streams import DepthUnit
from nsim.io.tf_tree import StaticLink

FILE_VERSION = "/file_version"
DEPTH_KIND = "Depth"
DEPTH_UNITS = "Depth Units"
TRANSFORM = "geometry_msgs/msg/Transform"
FLOAT32 = "std_msgs/msg/Float32"
KEY_VALUE = "diagnostic_msgs/msg/KeyValue"
_PREFIX = r"/device_(\d+)/sensor_(\d+)/([A-Za-z]+)_(\d+)"
_IMAGE = re.compile(_PREFIX + r"/image/data$")
_EXTRINSICS = re.compile("(" + _PREFIX + r")/tf/(\d+)$")


@dataclass(frozen=True, order=True)
class Stream:
    """One stream of a RealSense SDK bag: ``/device_<device>/sensor_<sensor>/<kind>_<index>``."""

    device: int
    sensor: int
    kind: str
    index: int

    @property
    def prefix(self) -> str:
        return f"/device_{self.device}/sensor_{self.sensor}/{self.kind}_{self.index}"

    @property
    def image_topic(self) -> str:
        return self.prefix + "/image/data"

    @property
    def frame_id(self) -> str:
        name = f"{self.kind}_{self.index}"
        return name if self.device == 0 else f"device_{self.device}/{name}"

    @property
    def depth_units_topic(self) -> str:
        return f"/device_{self.device}/sensor_{self.sensor}/option/{DEPTH_UNITS}/value"

    @property
    def is_depth(self) -> bool:
        return self.kind == DEPTH_KIND


def is_realsense_bag(topics: Mapping) -> bool:
    """Whether a bag's topics (name -> anything) are librealsense's layout: ``/file_version`` and a stream's image."""
    return FILE_VERSION in topics and any(_IMAGE.match(t) for t in topics)


def stream_of(topic: str) -> Stream | None:
    """The stream whose ``image/data`` topic ``topic`` is, or None."""
    m = _IMAGE.match(topic)
    return None if m is None else Stream(int(m[1]), int(m[2]), m[3], int(m[4]))


def default_names(topics: Iterable[str]) -> dict[str, str] | None:
    """Names for image topics that are all RealSense streams (None otherwise): ``color``, ``depth``, ``infrared_1``
    (the kind in lower case, the index unless 0); where two would share one, ``device_D_sensor_S_`` goes in front."""
    streams = {t: stream_of(t) for t in topics}
    if not all(streams.values()):
        return None
    short = {t: s.kind.lower() + ("" if s.index == 0 else f"_{s.index}") for t, s in streams.items()}
    taken = list(short.values())
    return {t: n if taken.count(n) == 1 else f"device_{streams[t].device}_sensor_{streams[t].sensor}_{n}"
            for t, n in short.items()}


def extrinsic_links(extrinsics: Mapping[str, np.ndarray]) -> tuple[list[StaticLink], str | None]:
    """Static links from the ``tf/<g>`` topics (topic -> its first Transform as a ``(4, 4)``, which maps the
    reference stream's points into the stream's): ``stream frame -> reference frame of group g``, the
    reference named after the stream whose extrinsics are the identity (a depth stream first), else
    ``realsense_reference_<g>`` (``realsense_reference_<d>_<g>`` past device 0). Returns the links and the body
    frame: the first device's group 0 reference (its first group's without a group 0; None without extrinsics)."""
    groups: dict[tuple[int, int], list[tuple[Stream, np.ndarray]]] = {}
    for topic, reference_to_stream in sorted(extrinsics.items()):
        m = _EXTRINSICS.match(topic)
        if m is None:
            continue
        stream = Stream(int(m[2]), int(m[3]), m[4], int(m[5]))
        groups.setdefault((stream.device, int(m[6])), []).append((stream, np.asarray(reference_to_stream, np.float64)))
    links, references = [], {}
    for (device, group), members in sorted(groups.items()):
        identity = [s for s, t in members if np.allclose(t, np.eye(4), atol=1e-6)]
        if identity:
            reference = min(identity, key=lambda s: (not s.is_depth, s)).frame_id
        else:
            reference = f"realsense_reference_{group}" if device == 0 else f"realsense_reference_{device}_{group}"
        references[(device, group)] = reference
        for stream, reference_to_stream in members:
            if stream.frame_id != reference:
                links.append(StaticLink(reference, stream.frame_id, invert_se3(reference_to_stream)))
    return links, (references[min(references)] if references else None)


def stated_units(stream: Stream, msgtypes: Mapping[str, str | None], read: Callable[[str], list], bag: str,
                 ) -> tuple[list, str]:
    """The Depth Units option of a depth stream's sensor as the bag states it, and where: the Float32 values of
    ``option/Depth Units/value`` (librealsense also wrote ``Depth_Units``), else the ``Depth Units`` entries of the
    sensor's ``property`` KeyValue topic (file format 2). ``msgtypes``: the bag's topic -> type; ``read``: a topic's
    messages; ``bag`` names the bag in errors. No such topic: ``[]`` and the option topic's name."""
    sensor = f"/device_{stream.device}/sensor_{stream.sensor}"
    for topic, msgtype in sorted(msgtypes.items()):
        m = re.fullmatch(re.escape(sensor) + r"/option/([^/]+)/value", topic)
        if m and msgtype == FLOAT32 and _key(m[1]) == _key(DEPTH_UNITS):
            return [float(msg.data) for msg in read(topic)], topic
    topic = sensor + "/property"
    if msgtypes.get(topic) == KEY_VALUE:
        values = [msg.value for msg in read(topic) if _key(str(msg.key)) == _key(DEPTH_UNITS)]
        try:
            return [float(v) for v in values], topic
        except ValueError:
            raise InputError(f"bag {bag}: {topic}: Depth Units {values} is not a number") from None
    return [], stream.depth_units_topic


def depth_unit(stream: Stream, where: str, frame_units: Sequence[float], stated: Sequence[float], option: str,
               ) -> DepthUnit:
    """The unit of a RealSense depth stream (see the module docstring): ``frame_units`` the ``depth_units`` its
    frames carry (0 for none), ``stated`` the values of its sensor's Depth Units option on topic ``option`` (empty
    for none, :func:`stated_units`). ``where`` names the bag and image topic for the one-line errors."""

    def metres(values: Sequence[float], what: str) -> float:
        found = sorted({_float32_decimal(v) for v in values})
        if len(found) > 1:
            raise InputError(f"{where}: {what} changes during the recording ({', '.join(map(str, found))} m per unit); "
                             "nsim takes one unit per depth stream")
        if not (np.isfinite(found[0]) and found[0] > 0):
            raise InputError(f"{where}: {what} is {found[0]} m per unit; expected a positive number")
        return found[0]

    if any(frame_units):
        if not all(frame_units):
            raise InputError(f"{where}: some frames carry librealsense's depth_units and some do not")
        m = metres(frame_units, "the frames' depth_units")
        if stated and metres(stated, option) != m:
            raise InputError(f"{where}: the frames' depth_units ({m} m) differ from {option} ({metres(stated, option)} m)")
        return DepthUnit(m, f"RealSense bag: each depth frame's depth_units ({m} m per unit)")
    if stated:
        m = metres(stated, option)
        return DepthUnit(m, f"RealSense bag: {option} ({m} m per unit)")
    raise InputError(f"{where}: a RealSense depth stream without its unit: no {option} topic and no depth_units in "
                     "the frames (nsim does not guess it: a D400 records 0.001 m, an L515 0.00025 m)")


def _key(name: str) -> str:
    return "_".join(name.replace("_", " ").lower().split())


def _float32_decimal(value: float) -> float:
    """A float32 as the shortest decimal that rounds to it (0.001 stored as float32 reads 0.001, not 0.0010000000475)."""
    return float(str(np.float32(value)))
