"""RealSense bags: the SDK's own layout (what realsense-viewer and rs-record write: /device_0/sensor_N/<Stream>_i/...,
CameraInfo beside the image under info/, librealsense's distortion names, extrinsics on tf/0, the depth unit as an
option or after each frame's data), written here topic by topic as librealsense's ros_writer does, and the
realsense2_camera ROS driver's layout; read back through RobotLog and compared with what was written."""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry import Camera, make_se3
from nsim.io.recording_streams import depth_unit_of
from nsim.io.robot_log import RobotLog
from nsim.io.rosbag import build_message, camera_from_info, camera_info_message, image_message

W, H = 16, 12
T0 = 1_700_000_000 * 10**9
TICK = 33_000_000
STORE = get_typestore(Stores.ROS1_NOETIC)
STORE.register(get_types_from_msg("uint32 fps\nstring encoding\nbool is_recommended", "realsense_msgs/msg/StreamInfo"))
COLOR_D = (0.12, -0.25, 0.001, -0.002, 0.1)  # k1 k2 p1 p2 k3, as librealsense writes Brown Conrady
COLOR_K = (13.5, 13.0, 7.75, 5.25)  # fx fy ppx ppy
DEPTH_K = (11.0, 11.0, 7.5, 5.5)
#: librealsense's extrinsics from the reference (depth) stream to colour: p_color = R p_depth + t.
DEPTH_TO_COLOR = make_se3(Rotation.from_euler("xyz", [0.01, -0.02, 0.005]).as_matrix(), [0.015, 0.0003, -0.0002])
DEPTH_PREFIX, COLOR_PREFIX = "/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"
UNITS_TOPIC = "/device_0/sensor_0/option/Depth Units/value"


def msg(msgtype: str, **fields):
    return build_message(STORE, msgtype, **fields)


def rs_camera_info(k, d, model):
    """CameraInfo as ros_writer fills it: K, D and the model name; R and P left zero."""
    fx, fy, cx, cy = k
    return msg("sensor_msgs/msg/CameraInfo", header=header(0, ""), height=H, width=W, distortion_model=model,
               D=np.array(d, np.float64), K=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], np.float64), R=np.zeros(9),
               P=np.zeros(12), binning_x=0, binning_y=0,
               roi=msg("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def header(t_ns: int, frame_id: str):
    stamp = msg("builtin_interfaces/msg/Time", sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    return msg("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)


def transform(m: np.ndarray):
    q = Rotation.from_matrix(m[:3, :3]).as_quat()
    return msg("geometry_msgs/msg/Transform",
               translation=msg("geometry_msgs/msg/Vector3", x=m[0, 3], y=m[1, 3], z=m[2, 3]),
               rotation=msg("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))


def depth_values(k: int) -> np.ndarray:
    rng = np.random.default_rng(k)
    values = rng.integers(1000, 20000, (H, W)).astype(np.uint16)
    values[0, :3] = 0  # no measurement
    return values


def color_pixels(k: int) -> np.ndarray:
    return np.random.default_rng(100 + k).integers(0, 256, (H, W, 3)).astype(np.uint8)


def write_realsense_bag(path: Path, *, n: int = 3, units: float | None = 0.00025, frame_units: float | None = None,
                        depth_encoding: str = "mono16", color_model: str = "Brown Conrady",
                        color_d=COLOR_D, stream_info: bool = True, units_topic: str = UNITS_TOPIC,
                        lz4: bool = False) -> Path:
    """A bag laid out as librealsense's ros_writer lays it out (one depth and one colour stream, n frames each).

    units: the Depth Units option (None: no option topic); frame_units: the depth_units float appended to each
    depth Image after its data, as librealsense 2.35+ does (None: not appended); units_topic: where the option is
    (``/device_0/sensor_0/property``: file format 2's KeyValue); lz4: compressed chunks, as ros_writer's
    compress_while_record writes them."""
    writer = Writer1(path)
    if lz4:
        writer.set_compression(Writer1.CompressionFormat.LZ4)
    writer.open()
    conns: dict[str, object] = {}

    def write(topic: str, message, t_ns: int, tail: bytes = b"") -> None:
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, message.__msgtype__, typestore=STORE)
        writer.write(conns[topic], t_ns, bytes(STORE.serialize_ros1(message, message.__msgtype__)) + tail)

    static = 1  # ros::TIME_MIN, where ros_writer puts the file's static information
    write("/file_version", msg("std_msgs/msg/UInt32", data=3), static)
    write("/device_0/info", msg("diagnostic_msgs/msg/KeyValue", key="Name", value="Intel RealSense L515"), static)
    for sensor, name in ((0, "L500 Depth Sensor"), (1, "RGB Camera")):
        write(f"/device_0/sensor_{sensor}/info", msg("diagnostic_msgs/msg/KeyValue", key="Name", value=name), static)
    if units is not None and units_topic.endswith("/property"):
        write(units_topic, msg("diagnostic_msgs/msg/KeyValue", key="Depth Units", value=str(units)), static)
    elif units is not None:
        write(units_topic, msg("std_msgs/msg/Float32", data=units), static)
        write("/device_0/sensor_0/option/Depth Units/description",
              msg("std_msgs/msg/String", data="Number of meters represented by a single depth unit"), static)
    for prefix, k, d, model, encoding in ((DEPTH_PREFIX, DEPTH_K, (0.0,) * 5, "None", depth_encoding),
                                          (COLOR_PREFIX, COLOR_K, color_d, color_model, "rgb8")):
        if stream_info:
            write(prefix + "/info", msg("realsense_msgs/msg/StreamInfo", fps=30, encoding=encoding, is_recommended=True),
                  static)
        write(prefix + "/info/camera_info", rs_camera_info(k, d, model), static)
    for i in range(n):
        t = T0 + i * TICK
        depth = image_message(t, "0", depth_values(i), encoding="16UC1", store=STORE)  # librealsense's odd frame id
        depth.encoding = depth_encoding
        tail = b"" if frame_units is None else struct.pack("<f", frame_units)
        write(DEPTH_PREFIX + "/image/data", depth, t, tail)
        write(DEPTH_PREFIX + "/image/metadata", msg("diagnostic_msgs/msg/KeyValue", key="system_time", value=str(t)), t)
        color = image_message(t + 1000, "0", color_pixels(i), encoding="rgb8", store=STORE)
        write(COLOR_PREFIX + "/image/data", color, t + 1000)
        if i == 0:  # ros_writer writes each stream's extrinsics once, with its first frame, at the static time
            write(DEPTH_PREFIX + "/tf/0", transform(np.eye(4)), static)
            write(COLOR_PREFIX + "/tf/0", transform(DEPTH_TO_COLOR), static)
        accel = msg("sensor_msgs/msg/Imu", header=header(t, ""),
                    orientation=msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9),
                    angular_velocity=msg("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=msg("geometry_msgs/msg/Vector3", x=0.0, y=-9.8, z=0.0),
                    linear_acceleration_covariance=np.zeros(9))
        write("/device_0/sensor_2/Accel_0/imu/data", accel, t)
    writer.close()
    return path


def test_realsense_bag_imports(tmp_path, caplog):
    path = write_realsense_bag(tmp_path / "l515.bag")
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path) as log:
        assert log.realsense
        assert set(log.cameras) == {"color"} and set(log.depth) == {"depth"}
        color, depth = log.cameras["color"], log.depth["depth"]
        assert (color.topic, color.info_topic) == (COLOR_PREFIX + "/image/data", COLOR_PREFIX + "/info/camera_info")
        assert color.camera == Camera("OPENCV", W, H, *COLOR_K, COLOR_D)  # Brown Conrady read as plumb_bob
        assert depth.camera == Camera("PINHOLE", W, H, *DEPTH_K)  # librealsense's None
        assert (color.frame_id, depth.frame_id) == ("Color_0", "Depth_0")
        assert len(color) == len(depth) == 3
        np.testing.assert_array_equal(depth.stamps_ns, T0 + np.arange(3) * TICK)
        # extrinsics: the body is the reference stream (depth); colour sits where tf/0 says
        assert log.body_frame == "Depth_0"
        np.testing.assert_allclose(log.sensor_to_body("Color_0"), np.linalg.inv(DEPTH_TO_COLOR), atol=1e-12)
        np.testing.assert_array_equal(log.sensor_to_body("Depth_0"), np.eye(4))
        # depth in metres from the bag's own unit: 0.25 mm, not REP 118's millimetres
        unit = depth_unit_of(depth)
        assert unit.m_per_unit == 0.00025 and unit.units_per_m == 4000.0
        assert UNITS_TOPIC in unit.source
        for i, frame in log.images(depth):
            values = depth_values(i)
            expected = values.astype(np.float32) / np.float32(4000.0)
            np.testing.assert_array_equal(frame[values > 0], expected[values > 0])
            assert np.isnan(frame[values == 0]).all()
        np.testing.assert_array_equal(log.image(color, 2), color_pixels(2))
        with pytest.raises(InputError, match=r"no trajectory .*--trajectory FILE\.tum") as err:
            log.body_trajectory()
        assert "\n" not in str(err.value)
    assert "skipped" not in caplog.text


def test_realsense_frame_depth_units(tmp_path):
    """librealsense 2.35+ appends depth_units to each depth Image; those frames read, the unit is theirs."""
    path = write_realsense_bag(tmp_path / "d435.bag", units=None, frame_units=0.001, lz4=True)
    with RobotLog(path) as log:
        depth = log.depth["depth"]
        unit = depth_unit_of(depth)
        assert unit.m_per_unit == 0.001 and unit.units_per_m == 1000.0  # float32's 0.001 read as 0.001
        assert "depth_units" in unit.source
        values = depth_values(1)
        frame = log.image(depth, 1)
        np.testing.assert_array_equal(frame[values > 0], values[values > 0].astype(np.float32) / np.float32(1000.0))
    path = write_realsense_bag(tmp_path / "both.bag", units=0.001, frame_units=0.00025)
    with pytest.raises(InputError, match="differ from"):
        RobotLog(path)


@pytest.mark.parametrize("topic", ["/device_0/sensor_0/option/Depth_Units/value", "/device_0/sensor_0/property"])
def test_realsense_depth_units_elsewhere(tmp_path, topic):
    """librealsense also wrote the option as Depth_Units, and file format 2 as a KeyValue on property."""
    path = write_realsense_bag(tmp_path / "old.bag", units_topic=topic)
    with RobotLog(path) as log:
        unit = depth_unit_of(log.depth["depth"])
        assert unit.m_per_unit == 0.00025 and topic in unit.source


def test_realsense_depth_without_unit(tmp_path):
    for encoding in ("mono16", "16UC1"):
        path = write_realsense_bag(tmp_path / f"{encoding}.bag", units=None, depth_encoding=encoding)
        with pytest.raises(InputError) as err:
            RobotLog(path)
        text = str(err.value)
        assert f"bag {path}: {DEPTH_PREFIX}/image/data" in text and UNITS_TOPIC in text and "\n" not in text


def test_realsense_bag_cut_short(tmp_path):
    full = write_realsense_bag(tmp_path / "full.bag").read_bytes()
    for cut in (len(full) // 3, len(full) - 10):
        path = tmp_path / f"cut{cut}.bag"
        path.write_bytes(full[:cut])
        with pytest.raises(InputError) as err:
            RobotLog(path)
        text = str(err.value)
        assert text.startswith(f"bag {path}: ") and "\n" not in text and "reindex" in text
    unindexed = bytearray(full)  # a recording stopped before it closed: the header's index_pos still 0
    at = unindexed.find(b"index_pos=") + len(b"index_pos=")
    unindexed[at:at + 8] = bytes(8)
    path = tmp_path / "unindexed.bag"
    path.write_bytes(bytes(unindexed))
    with pytest.raises(InputError, match=r"not indexed.*rosbag reindex"):
        RobotLog(path)


def test_realsense_without_stream_info_type_and_selection(tmp_path, caplog):
    """No custom StreamInfo topic; a selection naming the colour stream only: depth still by default, and no
    warning about the named topic."""
    path = write_realsense_bag(tmp_path / "plain.bag", stream_info=False)
    selection = {"cameras": {"rgb": COLOR_PREFIX + "/image/data"}}
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path, selection) as log:
        assert set(log.cameras) == {"rgb"} and set(log.depth) == {"depth"}
        assert log.cameras["rgb"].info_topic == COLOR_PREFIX + "/info/camera_info"
    assert "skipped" not in caplog.text


@pytest.mark.parametrize("model,d,ok", [
    ("Brown Conrady", COLOR_D, "OPENCV"),
    ("brown_conrady", COLOR_D, "OPENCV"),
    ("Kannala Brandt4", (0.1, -0.02, 0.003, -0.001, 0.0), "OPENCV_FISHEYE"),
    ("Modified Brown Conrady", (0.1, -0.02, 0.0, 0.0, 0.01), "OPENCV"),
    ("Inverse Brown Conrady", (0.0,) * 5, "PINHOLE"),
    ("None", (0.0,) * 5, "PINHOLE"),
    ("Inverse Brown Conrady", COLOR_D, None),
    ("Modified Brown Conrady", COLOR_D, None),
    ("Ftheta", (0.9, 0.0, 0.0, 0.0, 0.0), None),
])
def test_realsense_distortion_models(model, d, ok):
    info = rs_camera_info(COLOR_K, d, model)
    if ok is None:
        with pytest.raises(InputError, match=f"^info: distortion model '{model}' with D = .* cannot hold"):
            camera_from_info(info, where="info")
        return
    cam = camera_from_info(info, where="info")
    assert cam.model == ok and (cam.fx, cam.fy, cam.cx, cam.cy) == COLOR_K
    if ok == "OPENCV":
        assert cam.dist == tuple(d)


def test_realsense_inverse_brown_conrady_in_a_bag(tmp_path):
    """A D455's colour stream: refused as labelled, read as plumb_bob where the selection says so."""
    path = write_realsense_bag(tmp_path / "d455.bag", color_model="Inverse Brown Conrady")
    with pytest.raises(InputError, match=rf"{COLOR_PREFIX}/info/camera_info message 0: distortion model "
                                         r"'Inverse Brown Conrady'.*distortion: plumb_bob in the selection"):
        RobotLog(path)
    selection = {"cameras": {"color": {"image": COLOR_PREFIX + "/image/data", "distortion": "plumb_bob"}}}
    with RobotLog(path, selection) as log:
        assert log.cameras["color"].camera == Camera("OPENCV", W, H, *COLOR_K, COLOR_D)
    with pytest.raises(InputError, match=r"selection.cameras.color.distortion: expected one of plumb_bob"):
        RobotLog(path, {"cameras": {"color": {"image": COLOR_PREFIX + "/image/data", "distortion": "brown"}}})


def test_realsense2_camera_driver_layout(tmp_path, caplog):
    """realsense2_camera's topics (ROS driver, not the SDK's recorder): defaults find colour and both depths."""
    color_cam = Camera("OPENCV", W, H, *COLOR_K, COLOR_D)
    depth_cam = Camera("PINHOLE", W, H, *DEPTH_K)
    writer = Writer1(tmp_path / "ros.bag")
    writer.open()
    conns = {}

    def write(topic, message, t):
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, message.__msgtype__, typestore=STORE)
        writer.write(conns[topic], t, bytes(STORE.serialize_ros1(message, message.__msgtype__)))

    for i in range(2):
        t = T0 + i * TICK
        write("/camera/color/image_raw", image_message(t, "camera_color_optical_frame", color_pixels(i), store=STORE), t)
        write("/camera/color/camera_info", camera_info_message(t, "camera_color_optical_frame", color_cam, store=STORE), t)
        for ns, frame in (("aligned_depth_to_color", "camera_color_optical_frame"),
                          ("depth", "camera_depth_optical_frame")):
            last = "image_raw" if ns == "aligned_depth_to_color" else "image_rect_raw"
            write(f"/camera/{ns}/{last}", image_message(t, frame, depth_values(i), encoding="16UC1", store=STORE), t)
            cam = color_cam if ns == "aligned_depth_to_color" else depth_cam
            write(f"/camera/{ns}/camera_info", camera_info_message(t, frame, cam, store=STORE), t)
    writer.close()
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(tmp_path / "ros.bag") as log:
        assert not log.realsense
        assert set(log.cameras) == {"camera_color"}
        assert set(log.depth) == {"camera_aligned_depth_to_color", "camera_depth"}
        assert log.cameras["camera_color"].camera == color_cam
        assert log.depth["camera_depth"].camera == depth_cam  # image_rect_raw: the P of its CameraInfo
        assert depth_unit_of(log.depth["camera_depth"]).m_per_unit == 0.001  # REP 118's 16UC1
        values = depth_values(1)
        frame = log.image(log.depth["camera_aligned_depth_to_color"], 1)
        np.testing.assert_array_equal(frame[values > 0], values[values > 0] / np.float32(1000.0))
    assert "skipped" not in caplog.text
