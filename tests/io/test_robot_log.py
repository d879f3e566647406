"""Robot recordings: small bags in every format (ROS 2 sqlite3, ROS 2 mcap, ROS 1) with every image
encoding, compressed images, each CameraInfo model, odd PointCloud2 layouts, tf and odometry, read
back and compared with the ground truth they were written from; and each kind of bad input."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry import Camera, make_se3
from nsim.io.bag_topics import list_topics
from nsim.io.header_stamps import associate
from nsim.io.robot_log import RobotLog
from nsim.io.rosbag import (
    ROS1_TYPESTORE,
    TYPESTORE,
    BagWriter,
    build_message,
    camera_from_info,
    camera_info_message,
    compressed_image_message,
    depth_message,
    image_message,
    lidar_points,
    points_message,
    read_compressed_image,
    read_image,
    read_pointcloud,
)
from nsim.io.tf_tree import StaticLink, TfTree
from nsim.io.topic_selection import CameraTopics, Selection, load_selection
from nsim.sensors import Rig

FORMATS = ("sqlite3", "mcap", "ros1")
T0 = 1_700_000_000 * 10**9  # stamps in a real clock's range
TICK = 100_000_000
W, H = 16, 12


# ---------------------------------------------------------------------------- writing bags by hand


class RawBag:
    """rosbags' writers with messages built for the format's typestore (for what BagWriter cannot write)."""

    def __init__(self, path: Path, fmt: str):
        self.fmt = fmt
        self.store = ROS1_TYPESTORE if fmt == "ros1" else TYPESTORE
        if fmt == "ros1":
            self.writer = Writer1(path)
        else:
            plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=8, storage_plugin=plugin)
        self.writer.open()
        self.conns: dict[str, object] = {}

    def msg(self, msgtype: str, **fields):
        return build_message(self.store, msgtype, **fields)

    def header(self, t_ns: int, frame_id: str):
        stamp = self.msg("builtin_interfaces/msg/Time", sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return self.msg("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)

    def write(self, topic: str, msg, t_ns: int) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msg.__msgtype__, typestore=self.store)
        conn = self.conns[topic]
        raw = (self.store.serialize_ros1 if self.fmt == "ros1" else self.store.serialize_cdr)(msg, msg.__msgtype__)
        self.writer.write(conn, t_ns, bytes(raw))

    def transform(self, t_ns: int, parent: str, child: str, pose: np.ndarray):
        q = Rotation.from_matrix(pose[:3, :3]).as_quat()
        tr = self.msg("geometry_msgs/msg/Transform",
                      translation=self.msg("geometry_msgs/msg/Vector3", x=pose[0, 3], y=pose[1, 3], z=pose[2, 3]),
                      rotation=self.msg("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))
        return self.msg("geometry_msgs/msg/TransformStamped", header=self.header(t_ns, parent), child_frame_id=child,
                        transform=tr)

    def close(self) -> None:
        self.writer.close()


def bag_path(tmp_path: Path, fmt: str, name: str = "run") -> Path:
    return tmp_path / (name + ".bag" if fmt == "ros1" else name)


def _rigid(rng) -> np.ndarray:
    return make_se3(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-1, 1, 3))


CAMERAS = {
    "rgb": Camera("OPENCV", W, H, 12.0, 12.5, 7.25, 5.5, (-0.1, 0.02, 1e-3, -2e-3, 0.003)),
    "bgr": Camera("FULL_OPENCV", W, H, 11.0, 11.0, 7.5, 5.5, (0.3, -0.05, 1e-3, -5e-4, 0.002, 0.6, -0.02, 0.005)),
    "gray": Camera("PINHOLE", W, H, 10.0, 10.0, 7.5, 5.5),
    "gray16": Camera.fisheye_spot_like(W, H),
    "jpeg": Camera("PINHOLE", W, H, 9.0, 9.5, 7.0, 6.0),
    "png": Camera("OPENCV", W, H, 10.0, 10.0, 7.5, 5.5, (0.01, 0.0, 0.0, 0.0, 0.0)),
    "depth16": Camera("PINHOLE", W, H, 8.0, 8.0, 7.5, 5.5),
    "depth32": Camera("FULL_OPENCV", W, H, 8.0, 8.0, 7.5, 5.5, (0.1, 0.0, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0)),
}
LIDAR_DTYPE = np.dtype({"names": ["intensity", "ring", "x", "y", "z", "t"],  # intensity first, float64 xyz, padding
                        "formats": ["<f8", "<u2", "<f8", "<f8", "<f8", "<u4"],
                        "offsets": [0, 8, 16, 24, 32, 40], "itemsize": 48})
VELODYNE_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "ring", "time"],  # big-endian, as some drivers
                           "formats": [">f4", ">f4", ">f4", ">f4", ">u2", ">f4"],
                           "offsets": [0, 4, 8, 16, 20, 24], "itemsize": 32})


def write_rich_bag(path: Path, fmt: str, n: int = 3) -> dict:
    """Every kind of sensor the reader knows, ``n`` ticks; returns the ground truth."""
    rng = np.random.default_rng(7)
    bag = RawBag(path, fmt)
    s = bag.store
    frames = {name: _rigid(rng) for name in CAMERAS}  # <name>_optical -> body
    mast_to_body, lidar_to_mast, velodyne_to_body, body_to_footprint = (_rigid(rng) for _ in range(4))
    statics = [bag.transform(T0, "body", f"{name}_optical", pose) for name, pose in frames.items()]
    statics += [bag.transform(T0, "body", "mast", mast_to_body), bag.transform(T0, "mast", "lidar", lidar_to_mast),
                bag.transform(T0, "/body", "velodyne", velodyne_to_body),  # a ROS 1 style leading slash
                bag.transform(T0, "base_footprint", "body", body_to_footprint)]
    bag.write("/tf_static", bag.msg("tf2_msgs/msg/TFMessage", transforms=statics), T0)
    truth: dict = {"frames": frames, "lidar_to_body": mast_to_body @ lidar_to_mast, "velodyne_to_body": velodyne_to_body,
                   "stamps": [], "images": {k: [] for k in CAMERAS}, "lidar": [], "velodyne": [], "body_to_odom": [],
                   "twist": []}
    for k in range(n):
        t = T0 + k * TICK
        truth["stamps"].append(t)
        footprint_to_odom = _rigid(rng)
        bag.write("/tf", bag.msg("tf2_msgs/msg/TFMessage",
                                 transforms=[bag.transform(t, "odom", "base_footprint", footprint_to_odom)]), t)
        body_to_odom = footprint_to_odom @ body_to_footprint
        truth["body_to_odom"].append(body_to_odom)
        q = Rotation.from_matrix(body_to_odom[:3, :3]).as_quat()
        twist = rng.normal(size=6)
        truth["twist"].append(twist)
        vec = [bag.msg("geometry_msgs/msg/Vector3", x=v[0], y=v[1], z=v[2]) for v in (twist[:3], twist[3:])]
        pose = bag.msg("geometry_msgs/msg/Pose",
                       position=bag.msg("geometry_msgs/msg/Point", x=body_to_odom[0, 3], y=body_to_odom[1, 3],
                                        z=body_to_odom[2, 3]),
                       orientation=bag.msg("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))
        bag.write("/odom", bag.msg("nav_msgs/msg/Odometry", header=bag.header(t, "odom"), child_frame_id="body",
                                   pose=bag.msg("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=np.zeros(36)),
                                   twist=bag.msg("geometry_msgs/msg/TwistWithCovariance",
                                                 twist=bag.msg("geometry_msgs/msg/Twist", linear=vec[0], angular=vec[1]),
                                                 covariance=np.zeros(36))), t)

        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        padded = np.zeros((H, W * 3 + 4), np.uint8)  # rows padded to step = 52
        padded[:, : W * 3] = rgb.reshape(H, -1)
        padded[:, W * 3:] = 0xAB
        images = {
            "/rgb/image": bag.msg("sensor_msgs/msg/Image", header=bag.header(t, "rgb_optical"), height=H, width=W,
                                  encoding="rgb8", is_bigendian=0, step=W * 3 + 4, data=padded.reshape(-1)),
        }
        bgr = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        images["/bgr/image"] = image_message(t, "bgr_optical", bgr, encoding="bgr8", store=s)
        gray = rng.integers(0, 256, (H, W), dtype=np.uint8)
        images["/gray/image"] = image_message(t, "gray_optical", gray, encoding="mono8", store=s)
        gray16 = rng.integers(0, 65536, (H, W), dtype=np.uint16)
        images["/gray16/image"] = bag.msg(  # big-endian
            "sensor_msgs/msg/Image", header=bag.header(t, "gray16_optical"), height=H, width=W, encoding="mono16",
            is_bigendian=1, step=W * 2, data=gray16.astype(">u2").view(np.uint8).reshape(-1))
        ramp = np.linspace(0, 1, W)[None, :, None] * np.linspace(0.5, 1, H)[:, None, None]
        jpeg = (ramp * [180, 120, 60] + 20 * k).astype(np.uint8)  # smooth: JPEG keeps it close
        images["/jpeg/image/compressed"] = compressed_image_message(t, "jpeg_optical", jpeg, "jpeg", store=s)
        png = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        images["/png/image/compressed"] = compressed_image_message(t, "png_optical", png, "png", store=s)
        mm = rng.integers(0, 8000, (H, W), dtype=np.uint16)
        mm[0, :3] = 0
        images["/depth16/depth"] = image_message(t, "depth16_optical", mm, encoding="16UC1", store=s)
        metres = rng.uniform(0.1, 9.0, (H, W)).astype(np.float32)
        metres[0, 0], metres[0, 1], metres[1, 0] = np.inf, np.nan, -np.inf
        images["/depth32/depth"] = depth_message(t, "depth32_optical", metres, store=s)
        for topic, msg in images.items():
            bag.write(topic, msg, t + 1000)  # received 1 us later
            name = topic.split("/")[1]
            bag.write(f"/{name}/camera_info", camera_info_message(t, f"{name}_optical", CAMERAS[name], store=s), t + 1000)
        jpeg_decoded = cv2.imdecode(np.asarray(images["/jpeg/image/compressed"].data), cv2.IMREAD_COLOR)[..., ::-1]
        depth16 = mm.astype(np.float32) / np.float32(1000)
        depth16[mm == 0] = np.nan
        for name, value in (("rgb", rgb), ("bgr", bgr), ("gray", gray), ("gray16", gray16), ("jpeg", jpeg_decoded),
                            ("png", png), ("depth16", depth16), ("depth32", metres)):
            truth["images"][name].append(value)
        truth.setdefault("jpeg_original", []).append(jpeg)

        # an organised 2 x 5 cloud, rows padded by 8 bytes, intensity first, float64 xyz
        cloud = np.zeros(10, LIDAR_DTYPE)
        for f, lo, hi in (("x", -5, 5), ("y", -5, 5), ("z", -1, 1), ("intensity", 0, 255)):
            cloud[f] = rng.uniform(lo, hi, 10)
        cloud["x"][3] = np.nan
        cloud["ring"] = np.repeat([0, 1], 5)
        cloud["t"] = rng.integers(0, 100_000, 10)
        rows = np.zeros((2, 5 * 48 + 8), np.uint8)
        rows[:, : 5 * 48] = cloud.view(np.uint8).reshape(2, -1)
        fields = [bag.msg("sensor_msgs/msg/PointField", name=name, offset=LIDAR_DTYPE.fields[name][1],
                          datatype={"f8": 8, "u2": 4, "u4": 6}[LIDAR_DTYPE[name].str[1:]], count=1)
                  for name in LIDAR_DTYPE.names]
        bag.write("/lidar/points", bag.msg("sensor_msgs/msg/PointCloud2", header=bag.header(t + 2_000_000, "lidar"),
                                           height=2, width=5, fields=fields, is_bigendian=False, point_step=48,
                                           row_step=5 * 48 + 8, data=rows.reshape(-1), is_dense=False),
                  t + 2_001_000)
        truth["lidar"].append(cloud)
        velodyne = np.zeros(7, VELODYNE_DTYPE)
        for f in VELODYNE_DTYPE.names:
            velodyne[f] = rng.uniform(0, 100, 7)
        truth["velodyne"].append(velodyne)
        bag.write("/velodyne_points", points_message(t - 3_000_000, "velodyne", velodyne, store=s), t)
    bag.close()
    truth["stamps"] = np.array(truth["stamps"], np.int64)
    truth["body_to_odom"] = np.array(truth["body_to_odom"])
    truth["twist"] = np.array(truth["twist"])
    return truth


@pytest.fixture(scope="module", params=FORMATS)
def rich(request, tmp_path_factory):
    path = bag_path(tmp_path_factory.mktemp(request.param), request.param)
    return request.param, path, write_rich_bag(path, request.param)


# ---------------------------------------------------------------------------- reading them back


def test_topics_and_defaults(rich):
    fmt, path, _ = rich
    topics = list_topics(path)
    if fmt != "ros1":  # the storage file stands for its bag
        storage_file = next(path.glob("*.mcap" if fmt == "mcap" else "*.db3"))
        assert list_topics(storage_file) == topics
    assert topics["/rgb/image"].msgtype == "sensor_msgs/msg/Image" and topics["/rgb/image"].count == 3
    assert topics["/tf_static"].count == 1 and topics["/jpeg/image/compressed"].msgtype == "sensor_msgs/msg/CompressedImage"
    with RobotLog(path) as log:
        assert sorted(log.cameras) == ["bgr", "gray", "gray16", "jpeg", "png", "rgb"]
        assert sorted(log.depth) == ["depth16", "depth32"]
        assert sorted(log.lidars) == ["lidar", "velodyne_points"]
        assert log.odometry.topic == "/odom"
        assert (log.body_frame, log.odom_frame) == ("body", "odom")
        assert log.cameras["jpeg"].info_topic == "/jpeg/camera_info"
        assert log.cameras["rgb"].encoding == "rgb8" and log.cameras["jpeg"].encoding == "rgb8; jpeg compressed bgr8"


def test_cameras_bit_exact(rich):
    fmt, path, truth = rich
    with RobotLog(path) as log:
        for name, streams in (("rgb", log.cameras), ("bgr", log.cameras), ("gray", log.cameras),
                              ("gray16", log.cameras), ("jpeg", log.cameras), ("png", log.cameras),
                              ("depth16", log.depth), ("depth32", log.depth)):
            stream = streams[name]
            assert stream.camera == CAMERAS[name], name  # every parameter exact, model included
            assert stream.frame_id == f"{name}_optical"
            np.testing.assert_array_equal(stream.stamps_ns, truth["stamps"])
            assert stream.stamps_ns.dtype == np.int64 and stream.stamps_from_bag == 0
            streamed = list(log.images(stream))
            assert [i for i, _ in streamed] == [0, 1, 2]
            for k, want in enumerate(truth["images"][name]):
                for got in (log.image(stream, k), streamed[k][1]):
                    assert got.dtype == want.dtype and got.shape == want.shape, name
                    if want.dtype == np.float32:  # inf, -inf and NaN too
                        np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))
                    else:
                        np.testing.assert_array_equal(got, want)
        for k in range(3):
            assert np.abs(log.image(log.cameras["jpeg"], k).astype(int) - truth["jpeg_original"][k]).max() <= 12
        assert log.depth["depth16"].is_depth and not log.cameras["gray16"].is_depth
        with pytest.raises(IndexError):
            log.image(log.cameras["rgb"], 3)


def test_lidar_any_layout(rich):
    fmt, path, truth = rich
    with RobotLog(path) as log:
        lidar, velodyne = log.lidars["lidar"], log.lidars["velodyne_points"]
        assert lidar.frame_id == "lidar" and lidar.fields == ("intensity", "ring", "x", "y", "z", "t")
        np.testing.assert_array_equal(lidar.stamps_ns, truth["stamps"] + 2_000_000)
        np.testing.assert_array_equal(velodyne.stamps_ns, truth["stamps"] - 3_000_000)
        for k, want in enumerate(truth["lidar"]):
            got = log.cloud(lidar, k)
            np.testing.assert_array_equal(got.xyz_m, np.stack([want["x"], want["y"], want["z"]], 1))
            np.testing.assert_array_equal(got.intensity, want["intensity"])
            np.testing.assert_array_equal(got.ring, want["ring"])
            assert got.time_field == "t" and got.time.dtype == np.float64
            np.testing.assert_array_equal(got.time, want["t"])
            finite = log.cloud(lidar, k, finite_only=True)
            assert len(finite) == 9 and np.array_equal(finite.ring, np.delete(want["ring"], 3))
        for k, got in log.clouds(velodyne):
            want = truth["velodyne"][k]
            np.testing.assert_array_equal(got.xyz_m, np.stack([want["x"], want["y"], want["z"]], 1).astype(np.float64))
            np.testing.assert_array_equal(got.time, want["time"].astype(np.float64))
            np.testing.assert_array_equal(got.ring, want["ring"])
            assert got.time_field == "time"


def test_tf_odometry_and_trajectory(rich):
    fmt, path, truth = rich
    with RobotLog(path) as log:
        for name, pose in truth["frames"].items():
            np.testing.assert_allclose(log.sensor_to_body(log.cameras.get(name, log.depth.get(name)).frame_id), pose,
                                       rtol=0, atol=1e-9)
        np.testing.assert_allclose(log.sensor_to_body("lidar"), truth["lidar_to_body"], rtol=0, atol=1e-9)  # 2 links
        np.testing.assert_allclose(log.sensor_to_body("/velodyne"), truth["velodyne_to_body"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(log.tf.static_transform("body", "lidar"), np.linalg.inv(truth["lidar_to_body"]),
                                   rtol=0, atol=1e-9)
        traj = log.body_trajectory()
        assert traj.source == "tf: odom -> body" and traj.body_to_odom.shape == (3, 4, 4)
        np.testing.assert_array_equal(traj.stamps_ns, truth["stamps"])
        np.testing.assert_allclose(traj.body_to_odom, truth["body_to_odom"], rtol=0, atol=1e-9)
        odom = log.odometry
        assert (odom.frame_id, odom.child_frame_id) == ("odom", "body")
        np.testing.assert_allclose(odom.child_to_parent, truth["body_to_odom"], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(odom.linear_mps, truth["twist"][:, :3])
        np.testing.assert_array_equal(odom.angular_radps, truth["twist"][:, 3:])
        from_odom = log.body_trajectory("odometry")
        assert from_odom.source == "odometry /odom"
        np.testing.assert_allclose(from_odom.body_to_odom, truth["body_to_odom"], rtol=0, atol=1e-9)
        with pytest.raises(InputError, match=r"^tf: no link between 'nowhere' and 'body'"):
            log.sensor_to_body("nowhere")
        with pytest.raises(InputError, match=r"^tf: no link between 'odom' and 'body' \(there is one only through "
                                             r"moving /tf links\)"):
            log.sensor_to_body("odom")


def test_association(rich):
    fmt, path, truth = rich
    with RobotLog(path) as log:
        rgb, lidar, velodyne = log.cameras["rgb"], log.lidars["lidar"], log.lidars["velodyne_points"]
        np.testing.assert_array_equal(associate(rgb.stamps_ns, lidar.stamps_ns, 2_000_000), [[0, 0], [1, 1], [2, 2]])
        assert associate(rgb.stamps_ns, lidar.stamps_ns, 1_999_999).shape == (0, 2)
        np.testing.assert_array_equal(associate(velodyne.stamps_ns, rgb.stamps_ns, 3_000_000), [[0, 0], [1, 1], [2, 2]])


def test_selection(rich, tmp_path):
    fmt, path, truth = rich
    yaml_path = tmp_path / "topics.yaml"
    yaml_path.write_text("cameras:\n  front: {image: /png/image/compressed, info: /png/camera_info}\n"
                         "  eye: bgr/image\ndepth: {}\nlidar: {top: {points: /lidar/points}}\nodometry: /odom\n"
                         "body_frame: body\n")
    with RobotLog(path, load_selection(yaml_path)) as log:
        assert sorted(log.cameras) == ["eye", "front"] and log.depth == {} and list(log.lidars) == ["top"]
        assert log.cameras["eye"].info_topic == "/bgr/camera_info" and log.cameras["eye"].camera == CAMERAS["bgr"]
        np.testing.assert_array_equal(log.image(log.cameras["front"], 2), truth["images"]["png"][2])
    yaml_path.write_text("camera: {}\n")
    with pytest.raises(InputError, match=r"topics.yaml: unknown key 'camera' \(did you mean 'cameras'\?\)$"):
        load_selection(yaml_path)
    with pytest.raises(InputError, match=r"^s.cameras.a: unknown key 'imgae' \(did you mean 'image'\?\)$"):
        Selection.from_data({"cameras": {"a": {"imgae": "/x"}}}, "s")
    with pytest.raises(InputError, match=r"^s.cameras.a.rectified: expected true or false"):
        Selection.from_data({"cameras": {"a": {"image": "/x", "rectified": "yes"}}}, "s")


# ---------------------------------------------------------------------------- BagWriter in all formats


@pytest.fixture(scope="module")
def rig() -> Rig:
    return Rig.from_data({
        "name": "mini",
        "sensors": [
            {"name": "front", "type": "camera", "mount": {"xyz_m": [0.4, 0.0, 0.1], "rpy_deg": [78.0, 30.0, -20.0]},
             "intrinsics": {"model": "OPENCV_FISHEYE", "width": 16, "height": 12, "preset": "spot_fisheye"}, "depth": True},
            {"name": "wide", "type": "camera", "mount": {"xyz_m": [0.1, 0.0, 0.2]},
             "intrinsics": {"model": "FULL_OPENCV", "width": 8, "height": 6, "fx": 5.0,
                            "dist": [0.1, -0.01, 0.001, 0.002, 0.003, 0.2, 0.01, 0.001]}, "color": "gray"},
            {"name": "lidar", "type": "lidar", "mount": {"xyz_m": [0.0, 0.0, 0.3], "rpy_deg": [0.0, 0.0, 10.0]},
             "lidar": {"channels": 4, "vertical_fov_deg": [-15, 15], "azimuth_samples": 10}},
        ],
    })


@pytest.mark.parametrize("fmt", FORMATS)
def test_bag_writer_round_trip(tmp_path, rig, fmt):
    path = bag_path(tmp_path, fmt)
    rng = np.random.default_rng(3)
    ticks = []
    with BagWriter(path, rig, storage=fmt, time_offset_ns=T0) as bag:
        for k in range(3):
            pose = make_se3(Rotation.from_euler("z", 0.1 * k).as_matrix(), np.array([0.2 * k, 0.0, 0.5]))
            lidar = rig["lidar"]
            scan = lidar.scan(rng.uniform(1, 9, lidar.ray_shape), intensity=rng.uniform(0, 1, lidar.ray_shape))
            rgb = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
            gray = rng.integers(0, 256, (6, 8), dtype=np.uint8)
            depth = rng.uniform(0.2, 5.0, (12, 16)).astype(np.float32)
            bag.write_tick(0.1 * k, pose, images={"front": rgb, "wide": gray}, depths={"front": depth},
                           clouds={"lidar": scan})
            ticks.append((pose, rgb, gray, depth, scan))
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary debris
    assert path.is_file() == (fmt == "ros1")
    with RobotLog(path) as log:
        assert sorted(log.cameras) == ["front", "wide"] and list(log.depth) == ["front"]
        assert log.cameras["wide"].camera == rig["wide"].camera and log.cameras["wide"].camera.model == "FULL_OPENCV"
        assert log.cameras["front"].camera == rig["front"].camera
        np.testing.assert_array_equal(log.cameras["front"].stamps_ns, T0 + TICK * np.arange(3))
        for name in ("front", "wide", "lidar"):
            frame = log.lidars[name].frame_id if name == "lidar" else log.cameras[name].frame_id
            np.testing.assert_allclose(log.sensor_to_body(frame), rig[name].sensor_to_body, rtol=0, atol=1e-9)
        traj = log.body_trajectory()
        for k, (pose, rgb, gray, depth, scan) in enumerate(ticks):
            np.testing.assert_allclose(traj.body_to_odom[k], pose, rtol=0, atol=1e-9)
            np.testing.assert_array_equal(log.image(log.cameras["front"], k), rgb)
            np.testing.assert_array_equal(log.image(log.cameras["wide"], k), gray)
            np.testing.assert_array_equal(log.image(log.depth["front"], k), depth)
            np.testing.assert_array_equal(log.cloud(log.lidars["lidar"], k).xyz_m, scan.xyz_m[scan.hit])
            np.testing.assert_array_equal(log.cloud(log.lidars["lidar"], k).ring, scan.ring[scan.hit])
    with pytest.raises(InputError, match=r"ROS 1 bag is one file whose name ends in .bag"):
        BagWriter(tmp_path / "other", rig, storage="ros1")
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


def test_bag_writer_ros1_latches_tf_static(tmp_path, rig):
    from rosbags.rosbag1 import Reader as Reader1

    with BagWriter(tmp_path / "a.bag", rig, storage="ros1") as bag:
        bag.write_tick(0.0, np.eye(4))
    with Reader1(tmp_path / "a.bag") as reader:
        latching = {c.topic: c.ext.latching for c in reader.connections}
        md5 = {c.topic: c.digest for c in reader.connections}
    assert latching["/tf_static"] == 1 and not latching["/tf"]
    assert md5["/tf"] == "94810edda583a504dfda3829e70d7eec"  # tf2_msgs/TFMessage as ROS defines it


# ---------------------------------------------------------------------------- bad input: one line each


def _stream_bag(path: Path, fmt: str, topic_msgs) -> None:
    """A bag of camera 'cam' (CameraInfo at every image) plus the given (topic, t_ns, make(bag)) messages."""
    bag = RawBag(path, fmt)
    for topic, t_ns, make in topic_msgs:
        bag.write(topic, make(bag), t_ns)
    bag.close()


def _image(bag, t, encoding="rgb8", frame="cam_optical"):
    pixels = np.zeros((H, W, 3) if encoding in ("rgb8", "yuv422") else (H, W), np.uint8)
    msg = image_message(t, frame, pixels if encoding != "yuv422" else pixels, encoding="rgb8" if encoding == "yuv422"
                        else encoding, store=bag.store)
    if encoding == "yuv422":
        msg.encoding = "yuv422"
    return msg


def _info(bag, t, camera=CAMERAS["gray"]):
    return camera_info_message(t, "cam_optical", camera, store=bag.store)


def _camera_msgs(n=3, stamps=None, bad=None):
    out = []
    for k in range(n):
        t = T0 + k * TICK
        stamp = stamps[k] if stamps is not None else t
        out.append(("/cam/camera_info", t, lambda b, t=t: _info(b, t)))
        out.append(("/cam/image", t, (lambda b, s=stamp: _image(b, s)) if k != bad else
                    (lambda b, s=stamp: _image(b, s, "yuv422"))))
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_bad_input_names_topic_and_index(tmp_path, fmt):
    # unknown encoding at message 1
    path = bag_path(tmp_path, fmt, "encoding")
    _stream_bag(path, fmt, _camera_msgs(bad=1))
    with pytest.raises(InputError, match=r"^bag .*encoding.*: /cam/image message 1: unknown image encoding 'yuv422' "
                                         r"\(nsim reads rgb8, bgr8"):
        RobotLog(path)

    # stamps that go back at message 2
    path = bag_path(tmp_path, fmt, "stamps")
    _stream_bag(path, fmt, _camera_msgs(stamps=[T0 + 100, T0 + 300, T0 + 200]))
    with pytest.raises(InputError, match=rf"/cam/image message 2: header stamp {T0 + 200} ns is not after the "
                                         rf"previous message's {T0 + 300} ns \(stamps must increase\)$"):
        RobotLog(path)

    # a zero header stamp: the bag time stands in, and is counted
    path = bag_path(tmp_path, fmt, "zero")
    _stream_bag(path, fmt, _camera_msgs(stamps=[T0, 0, T0 + 2 * TICK]))
    with RobotLog(path) as log:
        np.testing.assert_array_equal(log.cameras["cam"].stamps_ns, T0 + TICK * np.arange(3))
        assert log.cameras["cam"].stamps_from_bag == 1

    # no CameraInfo for an image topic; a topic that does not exist
    path = bag_path(tmp_path, fmt, "noinfo")
    _stream_bag(path, fmt, [*_camera_msgs(), ("/debug/image", T0, lambda b: _image(b, T0))])
    with RobotLog(path) as log:
        assert list(log.cameras) == ["cam"]  # the defaults skip it
    with pytest.raises(InputError, match=r"^bag .*: /debug/image: no CameraInfo for this image topic \(no CameraInfo "
                                         r"topics in /debug/; give cameras.dbg.info\)$"):
        RobotLog(path, Selection(cameras={"dbg": CameraTopics("/debug/image")}))
    with pytest.raises(InputError, match=r"^bag .*: /cam/imag: no such topic \(cameras.x\); did you mean /cam/image\? "
                                         r"\(the bag's Image or CompressedImage topics: /cam/image, /debug/image\)$"):
        RobotLog(path, {"cameras": {"x": "/cam/imag"}})
    with pytest.raises(InputError, match=r"^bag .*: /cam/image: is sensor_msgs/msg/Image, odometry needs Odometry$"):
        RobotLog(path, Selection.from_data({"odometry": "/cam/image"}))

    # a compressed image that does not decode (message 1)
    path = bag_path(tmp_path, fmt, "jpeg")

    def jpeg(b, t, ok=True):
        msg = compressed_image_message(t, "cam_optical", np.zeros((H, W, 3), np.uint8), store=b.store)
        if not ok:
            msg.data = np.frombuffer(b"not a jpeg at all", np.uint8).copy()
        return msg

    msgs = [("/cam/camera_info", T0, lambda b: _info(b, T0))]
    msgs += [("/cam/image/compressed", T0 + k * TICK, lambda b, k=k: jpeg(b, T0 + k * TICK, ok=k != 1)) for k in range(3)]
    _stream_bag(path, fmt, msgs)
    with RobotLog(path) as log:
        cam = log.cameras["cam"]
        assert log.image(cam, 0).shape == (H, W, 3)
        with pytest.raises(InputError, match=r"^bag .*: /cam/image/compressed message 1: the compressed image \(format "
                                             r"'rgb8; jpeg compressed bgr8', 17 bytes\) does not decode$"):
            log.image(cam, 1)
        with pytest.raises(InputError, match=r"/cam/image/compressed message 1: the compressed image"):
            list(log.images(cam))

    # a PointCloud2 without z (message 1)
    path = bag_path(tmp_path, fmt, "cloud")
    xyz = np.zeros(4, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    xy = np.zeros(4, np.dtype([("x", "<f4"), ("y", "<f4"), ("intensity", "<f4")]))
    _stream_bag(path, fmt, [("/points", T0 + k * TICK, lambda b, k=k: points_message(T0 + k * TICK, "l", xy if k == 1 else xyz,
                                                                                      store=b.store)) for k in range(3)])
    with pytest.raises(InputError, match=r"^bag .*: /points message 1: PointCloud2 without z \(fields: x, y, intensity\)$"):
        RobotLog(path)

    # an image whose size differs from its CameraInfo
    path = bag_path(tmp_path, fmt, "size")
    _stream_bag(path, fmt, [("/cam/camera_info", T0, lambda b: _info(b, T0, CAMERAS["gray"].scaled(0.5))),
                            ("/cam/image", T0, lambda b: _image(b, T0))])
    with pytest.raises(InputError, match=r"/cam/image message 0: the image is 16x12, its CameraInfo \(/cam/camera_info\) "
                                         r"says 8x6$"):
        RobotLog(path)

    # a zero quaternion on /tf
    path = bag_path(tmp_path, fmt, "quat")

    def tf(b, t, ok):
        msg = b.msg("tf2_msgs/msg/TFMessage", transforms=[b.transform(t, "odom", "body", np.eye(4))])
        if not ok:
            msg.transforms[0].transform.rotation.w = 0.0
        return msg

    _stream_bag(path, fmt, [("/tf", T0 + k * TICK, lambda b, k=k: tf(b, T0 + k * TICK, k != 2)) for k in range(3)])
    with pytest.raises(InputError, match=r"^bag .*: /tf message 2 \(odom -> body\): transform: expected a finite "
                                         r"translation and a non-zero quaternion"):
        RobotLog(path)


def test_bad_bag_paths(tmp_path):
    with pytest.raises(InputError, match=r"^bag .*missing: does not exist$"):
        RobotLog(tmp_path / "missing")
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\nthis is not a bag")
    with pytest.raises(InputError, match=r"^bag .*junk.bag: not a readable ROS bag: "):
        RobotLog(tmp_path / "junk.bag")


def test_tf_repeats_and_ordering(tmp_path):
    path = tmp_path / "tf"
    msgs = [("/tf", T0 + t, lambda b, t=t, x=x: b.msg("tf2_msgs/msg/TFMessage", transforms=[
        b.transform(T0 + t, "odom", "body", make_se3(np.eye(3), np.array([x, 0.0, 0.0])))]))
        for t, x in ((0, 1.0), (5, 2.0), (5, 3.0), (9, 4.0))]
    _stream_bag(path, "sqlite3", msgs)
    with RobotLog(path) as log:
        (link,) = log.tf.moving
        np.testing.assert_array_equal(link.stamps_ns, T0 + np.array([0, 5, 9]))
        np.testing.assert_array_equal(link.child_to_parent[:, 0, 3], [1.0, 2.0, 4.0])  # the first of a repeat is kept
    path = tmp_path / "tf_back"
    _stream_bag(path, "sqlite3", [msgs[0], msgs[3], ("/tf", T0 + 10, msgs[1][2])])
    with pytest.raises(InputError, match=r"/tf message 2 \(odom -> body\): header stamp .* is not after"):
        RobotLog(path)


def test_trajectory_across_moving_links():
    a, b = make_se3(np.eye(3), np.ones(3)), make_se3(np.eye(3), np.zeros(3))
    from nsim.io.tf_tree import MovingLink

    stamps = np.array([1, 2])
    tree = TfTree((StaticLink("body", "cam", a),),
                  (MovingLink("map", "odom", stamps, np.stack([a, b])), MovingLink("odom", "body", stamps, np.stack([b, a]))))
    stamps_ns, body_to_map = tree.trajectory("map", "body")  # equal rates: the stamps of the link nearest the body
    np.testing.assert_array_equal(stamps_ns, stamps)
    np.testing.assert_allclose(body_to_map, np.stack([a @ b, b @ a]), rtol=0, atol=1e-12)
    stamps_ns, body_to_odom = tree.trajectory("odom", "cam")  # "body" is cam here: the static link is composed in
    np.testing.assert_allclose(body_to_odom, np.stack([b @ a, a @ a]))
    with pytest.raises(InputError, match=r"path from 'cam' to 'body' has no moving link"):
        tree.trajectory("cam", "body")
    late = TfTree((), (MovingLink("map", "odom", np.array([5, 6]), np.stack([a, b])),
                       MovingLink("odom", "body", stamps, np.stack([b, a]))))
    with pytest.raises(InputError, match=r"moving links from 'map' to 'body' share no time \(odom -> body 1..2 ns, "
                                         r"map -> odom 5..6 ns\)"):
        late.trajectory("map", "body")


def _yaw_pose(yaw: float, xyz) -> np.ndarray:
    return make_se3(Rotation.from_euler("z", yaw).as_matrix(), np.asarray(xyz, dtype=np.float64))


@pytest.mark.parametrize("fmt", FORMATS)
def test_map_odom_base_link_tree(tmp_path, fmt):
    """REP 105 as nav2 records it (evo's nav2_turtlebot.mcap): odom -> base_link at the odometry's
    rate, map -> odom (amcl) at a lower one and stamped ahead of when it is sent (its
    transform_tolerance), so past the last odometry. Read in map, the trajectory keeps the
    odometry's stamps that lie in map -> odom's span, with map -> odom interpolated at them."""
    path = bag_path(tmp_path, fmt, "rep105")
    ms = 1_000_000
    odom_stamps = T0 + TICK * np.arange(11)  # 0 .. 1 s
    bag_times = [int(t) for t in odom_stamps]
    base_to_odom = [_yaw_pose(0.05 * k, [0.1 * k, 0.02 * k, 0.0]) for k in range(11)]
    map_ms, map_yaw = np.array([250, 750, 1250]), np.array([0.2, 0.6, 0.4])  # amcl: stamped 200 ms after sending
    map_xy = np.array([[1.0, 2.0], [1.4, 2.0], [1.4, 2.4]])
    msgs = [(t, "/tf", lambda b, t=t, k=k: b.msg("tf2_msgs/msg/TFMessage", transforms=[
        b.transform(t, "odom", "base_link", base_to_odom[k])])) for k, t in enumerate(bag_times)]
    msgs += [(t + 1, "/odom", lambda b, t=t, k=k: _odom(b, t, "odom", "base_link", base_to_odom[k]))
             for k, t in enumerate(bag_times)]
    msgs += [(T0 + (int(m) - 200) * ms, "/tf", lambda b, m=m, y=y, xy=xy: b.msg("tf2_msgs/msg/TFMessage", transforms=[
        b.transform(T0 + int(m) * ms, "map", "odom", _yaw_pose(y, [*xy, 0.0]))]))
        for m, y, xy in zip(map_ms, map_yaw, map_xy, strict=True)]
    msgs.append((T0, "/tf_static", lambda b: b.msg("tf2_msgs/msg/TFMessage", transforms=[
        b.transform(T0, "base_link", "base_footprint", _yaw_pose(0.0, [0.0, 0.0, -0.1]))])))
    _stream_bag(path, fmt, [(topic, t, make) for t, topic, make in sorted(msgs, key=lambda m: m[0])])

    keep = odom_stamps >= T0 + 250 * ms  # 0.3 .. 1 s: inside map -> odom's 0.25 .. 1.25 s
    t_ms = (odom_stamps[keep] - T0) / ms
    yaw, x, y = (np.interp(t_ms, map_ms, v) for v in (map_yaw, map_xy[:, 0], map_xy[:, 1]))  # about z: slerp is lerp
    want = np.stack([_yaw_pose(a, [u, v, 0.0]) @ base_to_odom[k]
                     for a, u, v, k in zip(yaw, x, y, np.flatnonzero(keep), strict=True)])
    with RobotLog(path, {"odom_frame": "map"}) as log:
        assert (log.odom_frame, log.body_frame) == ("map", "base_link")
        for source, label in (("auto", "tf: map -> base_link"), ("tf", "tf: map -> base_link"),
                              ("odometry", "odometry /odom")):
            traj = log.body_trajectory(source)
            assert traj.source == label and (traj.odom_frame, traj.body_frame) == ("map", "base_link")
            np.testing.assert_array_equal(traj.stamps_ns, odom_stamps[keep])
            np.testing.assert_allclose(traj.body_to_odom, want, rtol=0, atol=1e-9)
        kept, odom_to_map = log.tf.transforms_at("odom", "map", T0 + np.array([0, 500, 750, 2000]) * ms)
        np.testing.assert_array_equal(kept, [False, True, True, False])
        np.testing.assert_allclose(odom_to_map, [_yaw_pose(0.4, [1.2, 2.0, 0.0]), _yaw_pose(0.6, [1.4, 2.0, 0.0])],
                                   rtol=0, atol=1e-12)
        footprint = log.tf.transforms_at("base_footprint", "map", odom_stamps[keep])[1]  # static + moving + moving
        np.testing.assert_allclose(footprint, want @ _yaw_pose(0.0, [0.0, 0.0, -0.1]), rtol=0, atol=1e-9)
    with RobotLog(path) as log:  # read in odom (the default): every odometry stamp, nothing interpolated
        traj = log.body_trajectory()
        assert traj.source == "tf: odom -> base_link"
        np.testing.assert_array_equal(traj.stamps_ns, odom_stamps)
        np.testing.assert_allclose(traj.body_to_odom, np.stack(base_to_odom), rtol=0, atol=1e-12)
    with RobotLog(path, {"odom_frame": "world"}) as log, pytest.raises(
            InputError, match=r"^tf: no link between 'odom' and 'world' in /tf or /tf_static \(and from tf: tf: no link "
                              r"between 'base_link' and 'world'"):
        log.body_trajectory()


@pytest.mark.parametrize("fmt", ("ros1", "mcap"))
def test_odometry_without_child_frame(tmp_path, fmt, caplog):
    """Stage's base_pose_ground_truth (embag's test.bag) leaves child_frame_id empty: its poses are
    taken as the body's, whatever the body frame is called."""
    poses = [_yaw_pose(0.1 * k, [1.0 + k, 0.5, 0.0]) for k in range(3)]
    odom = [("/base_pose_ground_truth", T0 + k * TICK, lambda b, k=k: _odom(b, T0 + k * TICK, "odom", "", poses[k]))
            for k in range(3)]
    path = bag_path(tmp_path, fmt, "stage")
    _stream_bag(path, fmt, odom)
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path) as log:
        assert (log.odometry.frame_id, log.odometry.child_frame_id) == ("odom", "")
        assert (log.body_frame, log.odom_frame) == (None, "odom")
        traj = log.body_trajectory()
        assert (traj.source, traj.odom_frame, traj.body_frame) == ("odometry /base_pose_ground_truth", "odom", "")
        np.testing.assert_allclose(traj.body_to_odom, np.stack(poses), rtol=0, atol=1e-12)
        with pytest.raises(InputError, match=r"the body frame is unknown \(the Odometry /base_pose_ground_truth has no "
                                             r"child_frame_id, no base_link/body/base_footprint frame in tf\)"):
            log.sensor_to_body("base_laser_link")
    assert "/base_pose_ground_truth: child_frame_id is empty; its poses are taken as the body's (body frame: unnamed)" \
        in caplog.text
    laser_to_base = _yaw_pose(0.0, [0.2, 0.0, 0.15])
    path = bag_path(tmp_path, fmt, "stage_tf")
    _stream_bag(path, fmt, [("/tf_static", T0, lambda b: b.msg("tf2_msgs/msg/TFMessage", transforms=[
        b.transform(T0, "base_link", "base_laser_link", laser_to_base)])), *odom])
    with RobotLog(path) as log:  # the body frame tf names: the poses are base_link's
        assert log.body_frame == "base_link"
        traj = log.body_trajectory()
        assert (traj.source, traj.body_frame) == ("odometry /base_pose_ground_truth", "base_link")
        np.testing.assert_allclose(traj.body_to_odom, np.stack(poses), rtol=0, atol=1e-12)
        np.testing.assert_allclose(log.sensor_to_body("base_laser_link"), laser_to_base, rtol=0, atol=1e-12)


def test_rectified_raw_preferred_and_calibration_change(tmp_path):
    cam = CAMERAS["rgb"]

    def info(b, t, k1=None):  # ROS 2 messages
        msg = camera_info_message(t, "cam_optical", cam, store=b.store)
        msg.p = np.array(msg.p)
        msg.p[0] = 9.0  # the rectified image's own focal length
        if k1 is not None:
            msg.d = np.array(msg.d)
            msg.d[0] = k1
        return msg

    path = tmp_path / "rect"
    _stream_bag(path, "sqlite3", [
        ("/cam/camera_info", T0, lambda b: info(b, T0)),
        ("/cam/image_rect", T0, lambda b: _image(b, T0)),
        ("/cam/image_raw", T0, lambda b: _image(b, T0)),
        ("/cam/image_raw/compressed", T0, lambda b: compressed_image_message(T0, "cam_optical",
                                                                             np.zeros((H, W, 3), np.uint8), store=b.store)),
    ])
    with RobotLog(path) as log:
        assert sorted(log.cameras) == ["cam_image_raw", "cam_image_rect"]  # both named /cam/...: full names
        assert log.cameras["cam_image_raw"].camera == cam
        assert log.cameras["cam_image_rect"].camera == Camera("PINHOLE", W, H, 9.0, cam.fy, cam.cx, cam.cy)
    with RobotLog(path, {"cameras": {"a": {"image": "/cam/image_rect", "rectified": False}}}) as log:
        assert log.cameras["a"].camera == cam
    log.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        log.image(log.cameras["a"], 0)

    path = tmp_path / "changes"
    _stream_bag(path, "sqlite3", [("/cam/camera_info", T0 + k, lambda b, k=k: info(b, T0 + k, k1=0.5 if k == 2 else None))
                                  for k in range(3)] + [("/cam/image", T0, lambda b: _image(b, T0))])
    with pytest.raises(InputError, match=r"/cam/camera_info message 2: the calibration differs from message 0's"):
        RobotLog(path)


def test_logs_skipped_topics(tmp_path, caplog):
    path = tmp_path / "skip"
    _stream_bag(path, "mcap", [*_camera_msgs(1), ("/debug/image", T0, lambda b: _image(b, T0)),
                               ("/o1", T0, lambda b: _odom(b)), ("/o2", T0, lambda b: _odom(b))])
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path) as log:
        assert log.odometry is None
    text = caplog.text
    assert "/debug/image: no CameraInfo topic in /debug/; skipped" in text
    assert "several Odometry topics (/o1, /o2)" in text


def test_named_topics_are_not_warned_about(tmp_path, caplog):
    """Only topics the defaults would take are warned about as skipped: never one the selection names, and a group
    the selection names (cameras) brings no warning about its kind of topic while the other (depth) is defaulted."""
    path = tmp_path / "named"
    _stream_bag(path, "mcap", [*_camera_msgs(1), ("/debug/image", T0, lambda b: _image(b, T0)),
                               ("/calib/info", T0, lambda b: _info(b, T0)),
                               ("/raw/depth", T0, lambda b: depth_message(T0, "cam_optical", np.ones((H, W)),
                                                                          encoding="16UC1", store=b.store))])
    named = {"dbg": {"image": "/debug/image", "info": "/calib/info"}}
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path, {"cameras": named}) as log:
        assert set(log.cameras) == {"dbg"} and log.depth == {}
    assert "/debug/image" not in caplog.text and "/cam/image" not in caplog.text
    assert "/raw/depth: no CameraInfo topic in /raw/; skipped" in caplog.text  # the depth defaults' own
    caplog.clear()
    named = {"d": {"image": "/raw/depth", "info": "/calib/info"}}
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path, {"depth": named}) as log:
        assert set(log.depth) == {"d"} and set(log.cameras) == {"cam"}
    assert "/raw/depth" not in caplog.text and "/debug/image: no CameraInfo topic in /debug/; skipped" in caplog.text


def _odom(b, t_ns=T0, frame="odom", child="body", child_to_frame=None):
    m = np.eye(4) if child_to_frame is None else child_to_frame
    q = Rotation.from_matrix(m[:3, :3]).as_quat()
    pose = b.msg("geometry_msgs/msg/Pose", position=b.msg("geometry_msgs/msg/Point", x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                 orientation=b.msg("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))
    zero = b.msg("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0)
    return b.msg("nav_msgs/msg/Odometry", header=b.header(t_ns, frame), child_frame_id=child,
                 pose=b.msg("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=np.zeros(36)),
                 twist=b.msg("geometry_msgs/msg/TwistWithCovariance",
                             twist=b.msg("geometry_msgs/msg/Twist", linear=zero, angular=zero), covariance=np.zeros(36)))


# ---------------------------------------------------------------------------- message <-> array units


def test_read_image_padding_and_byte_order():
    rng = np.random.default_rng(0)
    for encoding, dtype in (("mono16", ">u2"), ("16UC1", "<u2"), ("32FC1", ">f4"), ("bgr8", "u1"), ("8UC1", "u1")):
        shape = (5, 7, 3) if encoding == "bgr8" else (5, 7)
        values = rng.integers(0, 60000, shape).astype(dtype)
        step = values[0].nbytes + 6
        rows = np.zeros((5, step), np.uint8)
        rows[:, : values[0].nbytes] = np.ascontiguousarray(values).view(np.uint8).reshape(5, -1)
        msg = TYPESTORE.types["sensor_msgs/msg/Image"](
            header=TYPESTORE.types["std_msgs/msg/Header"](
                stamp=TYPESTORE.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
            height=5, width=7, encoding=encoding, is_bigendian=int(dtype.startswith(">")), step=step, data=rows.reshape(-1))
        got = read_image(msg)
        want = values[..., ::-1] if encoding == "bgr8" else values
        assert got.dtype == np.dtype(dtype).newbyteorder("=") and got.dtype.isnative
        np.testing.assert_array_equal(got, want)
    msg.encoding, msg.step = "16UC1", 14 + 6  # reading as depth wants 16-bit; 0 = no measurement
    msg.data = np.zeros(5 * msg.step, np.uint8)
    depth = read_image(msg, depth_m=True)
    assert depth.dtype == np.float32 and np.isnan(depth).all()
    msg.encoding = "mono8"
    with pytest.raises(InputError, match=r"^x: mono8 is not a depth encoding"):
        read_image(msg, depth_m=True, where="x")
    msg.step = 3
    with pytest.raises(InputError, match=r"^image: step 3 is shorter than a row of 7 mono8 pixels \(7 bytes\)$"):
        read_image(msg)


def test_compressed_png_gray16_and_errors():
    gray16 = np.arange(12 * 16, dtype=np.uint16).reshape(12, 16) * 300
    msg = compressed_image_message(0, "f", gray16, "png")
    assert msg.format == "mono16; png compressed mono16"
    out = read_compressed_image(msg)
    assert out.dtype == np.uint16 and np.array_equal(out, gray16)
    msg.format = "16UC1; compressedDepth png"
    with pytest.raises(InputError, match=r"^image: compressedDepth images"):
        read_compressed_image(msg)


@pytest.mark.parametrize("name", list(CAMERAS))
@pytest.mark.parametrize("store", [TYPESTORE, ROS1_TYPESTORE], ids=["ros2", "ros1"])
def test_camera_info_round_trip(name, store):
    msg = camera_info_message(5, "f", CAMERAS[name], store=store)
    assert camera_from_info(msg) == CAMERAS[name]
    assert msg.distortion_model == {"OPENCV": "plumb_bob", "PINHOLE": "plumb_bob", "FULL_OPENCV": "rational_polynomial",
                                    "OPENCV_FISHEYE": "equidistant"}[CAMERAS[name].model]
    rect = camera_from_info(msg, rectified=True)  # P = [K | 0]: the pinhole of K
    assert rect == Camera("PINHOLE", W, H, *(getattr(CAMERAS[name], k) for k in ("fx", "fy", "cx", "cy")))


def test_camera_info_roi_binning_and_errors():
    cam = CAMERAS["rgb"].scaled(4.0)  # 64 x 48
    msg = camera_info_message(0, "f", cam)
    msg.roi.x_offset, msg.roi.y_offset, msg.roi.width, msg.roi.height = 8, 4, 40, 32
    msg.binning_x = msg.binning_y = 2
    small = camera_from_info(msg)
    assert (small.width, small.height) == (20, 16)
    p = np.random.default_rng(1).uniform(-0.3, 0.3, (50, 3)) + [0, 0, 1]
    uv_full, _ = cam.project(p)
    uv_small, _ = small.project(p)
    np.testing.assert_allclose(uv_small, (uv_full - [8, 4] + 0.5) / 2 - 0.5, atol=1e-9)  # pixel centres exact
    msg = camera_info_message(0, "f", CAMERAS["rgb"])
    msg.distortion_model = "kb8"
    with pytest.raises(InputError, match=r"^ci: unknown distortion model 'kb8'"):
        camera_from_info(msg, where="ci")
    msg.distortion_model, msg.k = "plumb_bob", np.zeros(9)
    with pytest.raises(InputError, match=r"uncalibrated camera \(K is all zero\)$"):
        camera_from_info(msg)
    msg = camera_info_message(0, "f", CAMERAS["gray16"])
    msg.d = np.array([0.1, 0.0, 0.0, 0.0, 0.5])
    with pytest.raises(InputError, match=r"equidistant takes 4 coefficients"):
        camera_from_info(msg)
    msg.d = np.zeros(4)  # a fisheye with zero distortion is still a fisheye
    assert camera_from_info(msg).model == "OPENCV_FISHEYE"


def test_pointcloud_layouts():
    cloud = np.zeros(6, LIDAR_DTYPE)
    cloud["x"], cloud["ring"] = np.arange(6), 7
    msg = points_message(0, "l", cloud, height=2)
    assert (msg.height, msg.width, msg.point_step) == (2, 3, 48)
    back = read_pointcloud(msg)
    assert back.dtype.names == LIDAR_DTYPE.names and back.dtype.isnative
    np.testing.assert_array_equal(back["x"], cloud["x"])
    vector = np.zeros(3, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("normal", "<f4", (3,))]))
    vector["normal"] = [[1, 2, 3]] * 3
    back = read_pointcloud(points_message(0, "l", vector))  # count = 3
    np.testing.assert_array_equal(back["normal"], vector["normal"])
    msg = points_message(0, "l", cloud)
    msg.point_step = 40  # "t" at 40 no longer fits
    with pytest.raises(InputError, match=r"^p: field 't' at offset 40 does not fit a point step of 40 bytes$"):
        read_pointcloud(msg, where="p")
    no_xyz = points_message(0, "l", np.zeros(2, np.dtype([("a", "<f4")])))
    with pytest.raises(InputError, match=r"^points: PointCloud2 without x/y/z \(fields: a\)$"):
        lidar_points(no_xyz)


# ---------------------------------------------------------------------------- association


def _associate_twin(a, b, tol):
    """Plain reference: every pair, nearest first, each index once."""
    cands = sorted((abs(int(x) - int(y)), i, j) for i, x in enumerate(a) for j, y in enumerate(b) if abs(int(x) - int(y)) <= tol)
    used_a, used_b, out = set(), set(), []
    for _, i, j in cands:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            out.append((i, j))
    return sorted(out)


def test_associate_hand_cases():
    np.testing.assert_array_equal(associate(np.array([0, 10, 20]), np.array([11, 1, 50]), 2), [[0, 1], [1, 0]])
    # b=10 is nearest for both 9 and 12: 9 (1 away) gets it; 12 takes its second choice 14
    np.testing.assert_array_equal(associate(np.array([9, 12]), np.array([10, 14]), 3), [[0, 0], [1, 1]])
    assert associate(np.array([], np.int64), np.array([1]), 5).shape == (0, 2)
    np.testing.assert_array_equal(associate(np.array([5]), np.array([0, 10]), 5), [[0, 0]])  # tie: smaller j
    with pytest.raises(ValueError, match="integer nanoseconds"):
        associate(np.array([0.5]), np.array([1]), 1)
    with pytest.raises(ValueError, match="tolerance_ns"):
        associate(np.array([0]), np.array([1]), -1)


def test_associate_matches_plain_twin():
    rng = np.random.default_rng(5)
    for _ in range(30):
        a = np.sort(rng.integers(0, 1000, rng.integers(0, 40)))
        b = rng.integers(0, 1000, rng.integers(0, 40))
        tol = int(rng.integers(0, 60))
        got = associate(a, b, tol)
        assert got.dtype == np.int64
        assert [tuple(p) for p in got] == _associate_twin(a, b, tol)
