"""ROS bag export: write a few ticks, read them back with rosbags' readers and nsim's RobotLog, compare every value."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader

from nsim.errors import InputError
from nsim.geometry import Camera, make_se3
from nsim.io.robot_log import RobotLog
from nsim.io.rosbag import (
    TYPESTORE,
    BagWriter,
    check_bag_destination,
    compressed_image_message,
    jpeg_components,
    matrix_from_transform,
    read_compressed_image,
    read_image,
    read_pointcloud,
    stamp_ns,
)
from nsim.sensors import Rig
from nsim.synth.phone import encode_jpeg


@pytest.fixture(scope="module")
def rig() -> Rig:
    return Rig.from_data({
        "name": "mini",
        "sensors": [
            {"name": "front", "type": "camera", "mount": {"xyz_m": [0.4, 0.0, 0.1], "rpy_deg": [78.0, 30.0, -20.0]},
             "intrinsics": {"model": "OPENCV_FISHEYE", "width": 16, "height": 12, "preset": "spot_fisheye"}, "depth": True},
            {"name": "cam", "type": "camera", "mount": {"xyz_m": [0.1, 0.0, 0.2]},
             "intrinsics": {"model": "OPENCV", "width": 8, "height": 6, "fx": 5.0, "dist": [0.1, -0.01, 0.001, 0.002, 0.003]},
             "color": "gray"},
            {"name": "lidar", "type": "lidar", "mount": {"xyz_m": [0.0, 0.0, 0.3], "rpy_deg": [0.0, 0.0, 10.0]},
             "lidar": {"channels": 4, "vertical_fov_deg": [-15, 15], "azimuth_samples": 10}},
        ],
    })


def _poses(n: int) -> list[np.ndarray]:
    out = []
    for k in range(n):  # 0.5 m/s forward while turning at 0.2 rad/s, sampled at 10 Hz
        yaw = 0.02 * k
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
        out.append(make_se3(R, np.array([0.05 * k, 0.0, 0.5])))
    return out


def _write(path: Path, rig: Rig, n: int = 3, **kwargs):
    rng = np.random.default_rng(0)
    ticks = []
    with BagWriter(path, rig, **kwargs) as bag:
        for k, pose in enumerate(_poses(n)):
            rgb = rng.integers(0, 256, size=(12, 16, 3), dtype=np.uint8)
            gray = rng.uniform(0.0, 1.0, size=(6, 8)).astype(np.float32)
            depth = rng.uniform(0.2, 5.0, size=(12, 16)).astype(np.float32)
            depth[0, 0], depth[0, 1] = np.inf, np.nan
            lidar = rig["lidar"]
            ranges = rng.uniform(1.0, 9.0, size=lidar.ray_shape)
            ranges[1, 2] = np.inf
            scan = lidar.scan(ranges, intensity=rng.uniform(0, 1, size=lidar.ray_shape))
            bag.write_tick(0.1 * k, pose, images={"front": rgb, "cam": gray}, depths={"front": depth},
                           clouds={"lidar": scan})
            ticks.append({"pose": pose, "rgb": rgb, "gray": gray, "depth": depth, "scan": scan})
    return ticks


def _messages(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    with Reader(path) as reader:
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, TYPESTORE.deserialize_cdr(raw, conn.msgtype)))
    return out


def test_bag_round_trip(tmp_path, rig):
    path = tmp_path / "run"
    ticks = _write(path, rig)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no temporary debris
    with Reader(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        tf_static = next(c for c in reader.connections if c.topic == "/tf_static")
        assert tf_static.ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL
    assert types == {
        "/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage", "/odom": "nav_msgs/msg/Odometry",
        "/front/image": "sensor_msgs/msg/Image", "/front/depth": "sensor_msgs/msg/Image",
        "/front/camera_info": "sensor_msgs/msg/CameraInfo", "/cam/image": "sensor_msgs/msg/Image",
        "/cam/camera_info": "sensor_msgs/msg/CameraInfo", "/lidar/points": "sensor_msgs/msg/PointCloud2",
    }
    msgs = _messages(path)
    assert len(msgs["/tf_static"]) == 1 and all(len(msgs[t]) == 3 for t in types if t != "/tf_static")
    assert len(msgs["/front/camera_info"]) == 3  # one per tick although the camera sent image and depth

    (_, static), = msgs["/tf_static"]
    frames = {t.child_frame_id: t for t in static.transforms}
    assert set(frames) == {"front_optical", "cam_optical", "lidar"}
    for name, frame in (("front", "front_optical"), ("cam", "cam_optical"), ("lidar", "lidar")):
        assert frames[frame].header.frame_id == "body"
        np.testing.assert_allclose(matrix_from_transform(frames[frame].transform), rig[name].sensor_to_body, atol=1e-12)

    for k, tick in enumerate(ticks):
        t_ns = round(0.1 * k * 1e9)
        stamp_of = {topic: msgs[topic][k][0] for topic in types if topic != "/tf_static"}
        assert set(stamp_of.values()) == {t_ns}
        tf = msgs["/tf"][k][1].transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("odom", "body")
        assert tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec == t_ns
        np.testing.assert_allclose(matrix_from_transform(tf.transform), tick["pose"], atol=1e-12)

        image = msgs["/front/image"][k][1]
        assert (image.encoding, image.header.frame_id, image.step) == ("rgb8", "front_optical", 48)
        np.testing.assert_array_equal(read_image(image), tick["rgb"])
        gray = msgs["/cam/image"][k][1]
        assert gray.encoding == "mono8"
        np.testing.assert_array_equal(read_image(gray), np.rint(tick["gray"] * 255).astype(np.uint8))
        depth = msgs["/front/depth"][k][1]
        assert depth.encoding == "32FC1"
        np.testing.assert_array_equal(read_image(depth).view(np.uint32), tick["depth"].view(np.uint32))  # inf, NaN too

        cloud = read_pointcloud(msgs["/lidar/points"][k][1])
        scan = tick["scan"]
        assert msgs["/lidar/points"][k][1].header.frame_id == "lidar" and len(cloud) == scan.hit.sum() == 39
        np.testing.assert_array_equal(np.stack([cloud["x"], cloud["y"], cloud["z"]], 1), scan.xyz_m[scan.hit])
        np.testing.assert_array_equal(cloud["intensity"], scan.intensity[scan.hit])
        np.testing.assert_array_equal(cloud["ring"], scan.ring[scan.hit])
        assert cloud.dtype["ring"] == np.dtype("<u2")


def test_camera_info(tmp_path, rig):
    _write(tmp_path / "run", rig, n=1)
    msgs = _messages(tmp_path / "run")
    fish = msgs["/front/camera_info"][0][1]
    cam: Camera = rig["front"].camera
    assert fish.distortion_model == "equidistant" and (fish.width, fish.height) == (16, 12)
    np.testing.assert_allclose(fish.d, cam.dist)
    np.testing.assert_allclose(fish.k.reshape(3, 3), cam.K)
    np.testing.assert_allclose(fish.p.reshape(3, 4), np.hstack([cam.K, np.zeros((3, 1))]))
    np.testing.assert_allclose(fish.r.reshape(3, 3), np.eye(3))
    plumb = msgs["/cam/camera_info"][0][1]
    assert plumb.distortion_model == "plumb_bob"
    np.testing.assert_allclose(plumb.d, [0.1, -0.01, 0.001, 0.002, 0.003])


def test_odometry_twist_is_in_the_body_frame(tmp_path, rig):
    _write(tmp_path / "run", rig, n=3)
    odom = [m for _, m in _messages(tmp_path / "run")["/odom"]]
    assert (odom[0].header.frame_id, odom[0].child_frame_id) == ("odom", "body")
    first = odom[0].twist.twist
    assert (first.linear.x, first.angular.z) == (0.0, 0.0)
    for msg, pose in zip(odom, _poses(3), strict=True):
        np.testing.assert_allclose(matrix_from_transform(msg.pose.pose), pose, atol=1e-12)
    tw = odom[2].twist.twist
    speed_body = _poses(3)[2][:3, :3].T @ (_poses(3)[2][:3, 3] - _poses(3)[1][:3, 3]) / 0.1
    np.testing.assert_allclose([tw.linear.x, tw.linear.y, tw.linear.z], speed_body, atol=1e-9)
    np.testing.assert_allclose([tw.angular.x, tw.angular.y, tw.angular.z], [0.0, 0.0, 0.2], atol=1e-9)


def test_namespace_mcap_and_offset(tmp_path, rig):
    _write(tmp_path / "run", rig, n=2, namespace="/spot", storage="mcap", time_offset_ns=1_700_000_000 * 10**9)
    assert (tmp_path / "run" / "run.mcap").is_file()
    msgs = _messages(tmp_path / "run")
    assert "/spot/front/image" in msgs and "/spot/odom" in msgs and "/tf" in msgs
    assert msgs["/spot/odom"][1][1].header.stamp.sec == 1_700_000_000 and msgs["/spot/odom"][1][0] % 10**9 == 10**8


def test_no_bag_is_left_by_a_failure(tmp_path, rig):
    with pytest.raises(RuntimeError, match="boom"), BagWriter(tmp_path / "run", rig) as bag:
        bag.write_tick(0.0, np.eye(4))
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "run").mkdir()
    with pytest.raises(InputError, match="exists already"):
        BagWriter(tmp_path / "run", rig)
    with BagWriter(tmp_path / "other", rig) as bag:
        bag.write_tick(0.1, np.eye(4))
        with pytest.raises(ValueError, match="increasing"):
            bag.write_tick(0.1, np.eye(4))


def test_bag_destination(tmp_path):
    assert check_bag_destination(tmp_path / "new") == tmp_path / "new"
    (tmp_path / "empty").mkdir()
    (tmp_path / "file").write_text("x")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    for name in ("empty", "file", "dangling"):  # never overwritten, not even an empty directory
        with pytest.raises(InputError, match=rf"^--rosbag {tmp_path / name}: exists already"):
            check_bag_destination(tmp_path / name, "--rosbag")
    with pytest.raises(InputError, match=r"parent directory .*missing does not exist$"):
        check_bag_destination(tmp_path / "missing" / "bag")
    with pytest.raises(InputError, match=r"parent directory .*file is not a directory$"):
        check_bag_destination(tmp_path / "file" / "bag")
    assert list(tmp_path.iterdir()) and not (tmp_path / "missing").exists()  # nothing created


@pytest.mark.skipif(__import__("os").geteuid() == 0, reason="root writes anywhere")
def test_bag_destination_unwritable_parent(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        with pytest.raises(InputError, match="is not writable$"):
            check_bag_destination(locked / "bag")
    finally:
        locked.chmod(0o700)


# ---------------------------------------------------------------------------- a clock per sensor, JPEG


def _any_messages(path: Path) -> dict[str, list]:
    """topic -> [(bag time, message)] of a ROS 1 or ROS 2 bag."""
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    return out


def _header(msg):
    return msg.transforms[0].header if hasattr(msg, "transforms") else msg.header


@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "ros1"])
def test_sensors_with_their_own_stamps_and_jpeg(tmp_path, rig, storage):
    """Odometry, depth and LiDAR at 10 Hz; the cameras' clock 30 ms ahead, one of them JPEG."""
    path = tmp_path / ("run.bag" if storage == "ros1" else "run")
    rng = np.random.default_rng(1)
    lidar = rig["lidar"]
    t0, dt, offset = 1_000_000_000, 100_000_000, 30_000_000
    jpegs, grays = [], []
    with BagWriter(path, rig, storage=storage) as bag:
        for k, pose in enumerate(_poses(3)):
            depth = rng.uniform(0.2, 5.0, size=(12, 16)).astype(np.float32)
            scan = lidar.scan(rng.uniform(1.0, 9.0, size=lidar.ray_shape))
            bag.write_odometry(None, pose, t_ns=t0 + k * dt)
            bag.write_sensors(t_ns=t0 + k * dt, depths={"front": depth}, clouds={"lidar": scan})
            jpegs.append(encode_jpeg(rng.integers(0, 256, size=(12, 16, 3), dtype=np.uint8), 90))
            grays.append(rng.integers(0, 256, size=(6, 8), dtype=np.uint8))
            bag.write_sensors(t_ns=t0 + k * dt + offset, compressed_images={"front": jpegs[-1]}, images={"cam": grays[-1]})
    msgs = _any_messages(path)
    odom_ns = [t0 + k * dt for k in range(3)]
    camera_ns = [t + offset for t in odom_ns]
    stamps = {topic: [stamp_ns(_header(m)) for _, m in ms] for topic, ms in msgs.items()}
    for topic, ms in msgs.items():  # the bag time is the header stamp
        assert [t for t, _ in ms] == stamps[topic], topic
    assert stamps == {
        "/tf_static": [t0], "/tf": odom_ns, "/odom": odom_ns, "/front/depth": odom_ns, "/lidar/points": odom_ns,
        "/front/image/compressed": camera_ns, "/cam/image": camera_ns, "/cam/camera_info": camera_ns,
        "/front/camera_info": sorted(odom_ns + camera_ns),  # with the depth and with the JPEG
    }
    for (_, msg), data in zip(msgs["/front/image/compressed"], jpegs, strict=True):
        assert (msg.format, msg.header.frame_id) == ("rgb8; jpeg compressed bgr8", "front_optical")
        assert bytes(msg.data) == data  # as given, not encoded again
    # the twist differences the odometry calls only (0.1 s apart), whatever was written between them
    tw = msgs["/odom"][2][1].twist.twist
    p1, p2 = _poses(3)[1], _poses(3)[2]
    np.testing.assert_allclose([tw.linear.x, tw.linear.y, tw.linear.z], p2[:3, :3].T @ (p2[:3, 3] - p1[:3, 3]) / 0.1,
                               atol=1e-9)
    np.testing.assert_allclose([tw.angular.x, tw.angular.y, tw.angular.z], [0.0, 0.0, 0.2], atol=1e-9)

    with RobotLog(path) as log:
        front, cam = log.cameras["front"], log.cameras["cam"]
        assert front.msgtype == "sensor_msgs/msg/CompressedImage" and front.encoding == "rgb8; jpeg compressed bgr8"
        assert front.camera == rig["front"].camera and cam.camera.K.tolist() == rig["cam"].camera.K.tolist()
        for stream in (front, cam):
            assert (stream.stamps_ns - log.odometry.stamps_ns).tolist() == [offset] * 3
        assert log.depth["front"].stamps_ns.tolist() == log.lidars["lidar"].stamps_ns.tolist() == odom_ns
        for i, data in enumerate(jpegs):
            decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
            np.testing.assert_array_equal(log.image(front, i), decoded)
            np.testing.assert_array_equal(log.image(cam, i), grays[i])
        np.testing.assert_allclose(log.body_trajectory().body_to_odom, np.stack(_poses(3)), atol=1e-12)


def test_time_order_is_per_topic(tmp_path, rig):
    gray = np.zeros((6, 8), np.uint8)
    with BagWriter(tmp_path / "run", rig) as bag:
        bag.write_sensors(0.2, images={"cam": gray})
        bag.write_odometry(0.1, np.eye(4))  # before the image, on other topics
        with pytest.raises(ValueError, match=r"^/cam/image: stamps must be increasing on each topic, got 0.15 s after 0.2 s"):
            bag.write_tick(0.15, np.eye(4), images={"cam": gray})
        bag.write_odometry(0.15, np.eye(4))  # the failed tick wrote nothing, /odom included
        with pytest.raises(ValueError, match="increasing"):
            bag.write_odometry(0.15, np.eye(4))
        with pytest.raises(TypeError, match="t_s .* or t_ns"):
            bag.write_sensors(0.3, t_ns=300_000_000, images={"cam": gray})
        with pytest.raises(TypeError, match="t_s .* or t_ns"):
            bag.write_sensors(images={"cam": gray})
        with pytest.raises(ValueError, match="negative"):
            bag.write_odometry(-0.5, np.eye(4))
        with pytest.raises(ValueError, match=r"compressed_images\['cam'\]: JPEG"):
            bag.write_sensors(0.3, compressed_images={"cam": b"not a jpeg"})
        bag.write_sensors(t_ns=300_000_001, images={"cam": gray})
    msgs = _messages(tmp_path / "run")
    assert [t for t, _ in msgs["/odom"]] == [100_000_000, 150_000_000]
    assert [t for t, _ in msgs["/cam/image"]] == [200_000_000, 300_000_001]
    assert [t for t, _ in msgs["/tf_static"]] == [200_000_000]  # the first call's stamp
    assert msgs["/odom"][1][1].twist.twist.linear.x == 0.0  # the pose did not move


def test_compressed_image_message_from_bytes():
    rgb = np.random.default_rng(2).integers(0, 256, size=(10, 14, 3), dtype=np.uint8)
    data = encode_jpeg(rgb, 80)
    assert jpeg_components(data) == 3
    msg = compressed_image_message(7, "f", data)
    assert msg.format == "rgb8; jpeg compressed bgr8" and msg.data.tobytes() == data
    np.testing.assert_array_equal(read_compressed_image(msg),
                                  cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[..., ::-1])
    ok, gray = cv2.imencode(".jpg", rgb[..., 0])
    assert ok and jpeg_components(gray.tobytes()) == 1
    mono = compressed_image_message(7, "f", gray.tobytes())
    assert mono.format == "mono8; jpeg compressed mono8" and read_compressed_image(mono).shape == (10, 14)
    # the array path encodes as before: the same format string
    assert compressed_image_message(7, "f", rgb).format == msg.format
    with pytest.raises(ValueError, match="fmt jpeg"):
        compressed_image_message(7, "f", data, "png")
    for bad in (b"", b"\x89PNG\r\n", data[:2] + b"\xff\xda" + data[4:]):
        with pytest.raises(ValueError, match="JPEG"):
            compressed_image_message(7, "f", bad)


def test_luminar_layout_time_in_two_fields_and_laser_id_as_ring():
    """A Luminar-style cloud (seen in a public ROS 1 bag): time as uint32 time_sec + time_nsec, beam as laser_id."""
    from nsim.io.rosbag import lidar_points, points_message

    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("time_sec", "<u4"), ("time_nsec", "<u4"),
                   ("laser_id", "<u2")])
    pts = np.zeros(3, dtype=dt)
    pts["x"] = [1.0, 2.0, 3.0]
    pts["time_sec"] = 1_600_000_000
    pts["time_nsec"] = [0, 250_000_000, 999_999_999]
    pts["laser_id"] = [0, 5, 9]
    out = lidar_points(points_message(1, "lidar", pts))
    assert out.time_field == "time_sec+time_nsec"
    np.testing.assert_allclose(out.time - 1.6e9, [0.0, 0.25, 0.999999999], atol=1e-6)
    assert out.ring.tolist() == [0, 5, 9] and out.xyz_m[:, 0].tolist() == [1.0, 2.0, 3.0]
