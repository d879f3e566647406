"""The robot log of the test room: each fault against its configured size, and the bag read back with RobotLog."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from nsim.crowd.paths import yaw_poses_se3
from nsim.errors import ConfigError, InputError
from nsim.io.images import to_uint8
from nsim.io.robot_log import RobotLog
from nsim.io.rosbag import stamp_ns
from nsim.rendering.render_plan import adapt_rig
from nsim.sensors.rig import Rig, _linear_to_srgb, _srgb_to_linear, load_rig
from nsim.stages.capture import RobotLogConfig
from nsim.synth.faulty_robot_log import (
    CAMERA_TAG,
    RobotLogFaults,
    camera_faults,
    depth_faults,
    depth_holes,
    exposure_gains,
    jpeg_bytes,
    jpeg_round_trip,
    lidar_faults,
    log_stamps_ns,
    odom_to_world,
    odometry_from_truth,
    truth_path,
    write_robot_log,
)
from nsim.synth.oracle import RoomOracle
from nsim.synth.room import make_room

NONE = RobotLogFaults.none()


def _faults(**kwargs) -> RobotLogFaults:
    """No fault but the ones named."""
    return dataclasses.replace(NONE, **kwargs)


@pytest.fixture(scope="module")
def room():
    spec = make_room("robot-lab", seed=0)
    return spec, RoomOracle(spec)


@pytest.fixture(scope="module")
def rig() -> Rig:
    """Spot's rig with 32x24 cameras and a 16 x 90 LiDAR."""
    return adapt_rig(load_rig("nsim/configs/robots/spot.yaml"), RobotLogConfig(image_scale=0.05, lidar_azimuth_scale=0.05))


@pytest.fixture(scope="module")
def small_rig() -> Rig:
    """A pinhole RGB-D camera, a gray camera and a LiDAR: for the per-sensor fault functions."""
    return Rig.from_data({"name": "small", "sensors": [
        {"name": "rgbd", "type": "camera", "mount": {}, "intrinsics": {"model": "PINHOLE", "width": 120, "height": 100, "hfov_deg": 60},
         "depth": {"kind": "z", "min_m": 0.1, "max_m": 10.0}},
        {"name": "gray", "type": "camera", "mount": {}, "color": "gray",
         "intrinsics": {"model": "PINHOLE", "width": 40, "height": 30, "hfov_deg": 60}},
        {"name": "lidar", "type": "lidar", "mount": {}, "lidar": {"channels": 16, "azimuth_samples": 1800, "min_range_m": 0.3}},
    ]})


def _arc(spec, n: int, dt_s: float = 0.1, speed_mps: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Spot walking the room's walk loop at ``speed_mps``: body_to_world (n, 4, 4), stamps (n,)."""
    cx, cy, rx, ry = spec.walk_loop_xy_m
    a = np.arange(n) * speed_mps * dt_s / np.sqrt(rx * ry)
    xy = np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], axis=-1)
    yaw = np.arctan2(ry * np.cos(a), -rx * np.sin(a))  # along the tangent
    return yaw_poses_se3(xy, yaw, 0.5), np.arange(n) * dt_s + 12.5


def _line(n: int, step_m: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    xy = np.stack([np.arange(n) * step_m, np.zeros(n)], axis=-1)
    return yaw_poses_se3(xy, np.zeros(n), 0.5), np.arange(n) * 0.1


# ---------------------------------------------------------------------------------- odometry
def test_odometry_tick0_is_the_frame_offset(room):
    body, stamps = _arc(room[0], 30)
    faults = RobotLogFaults()
    odom = odometry_from_truth(body, stamps, faults, np.random.default_rng(0))
    np.testing.assert_allclose(odom_to_world(faults) @ odom[0], body[0], atol=1e-12)
    assert np.abs(odom_to_world(faults) @ odom[-1] - body[-1]).max() > 1e-4  # drifted by the end
    # the offset alone: every tick is the truth in the odom frame
    offset_only = _faults(odom_frame_yaw_deg=-120.0, odom_frame_xyz_m=(3.0, 1.0, -0.2))
    odom = odometry_from_truth(body, stamps, offset_only, np.random.default_rng(0))
    np.testing.assert_allclose(odom_to_world(offset_only) @ odom, body, atol=1e-12)
    T = odom_to_world(offset_only)
    assert np.degrees(np.arctan2(T[1, 0], T[0, 0])) == pytest.approx(-120.0)
    np.testing.assert_array_equal(T[:3, 3], [3.0, 1.0, -0.2])


def test_odometry_scale_and_heading_bias_on_a_straight_line():
    body, stamps = _line(51)  # 5 m along x
    odom = odometry_from_truth(body, stamps, _faults(odom_scale_error_percent=2.0), np.random.default_rng(0))
    np.testing.assert_allclose(odom[:, 0, 3], 1.02 * body[:, 0, 3], atol=1e-12)
    np.testing.assert_allclose(odom[:, :3, :3], body[:, :3, :3], atol=1e-12)
    odom = odometry_from_truth(body, stamps, _faults(odom_yaw_drift_deg_per_m=1.0), np.random.default_rng(0))
    heading_deg = np.degrees(np.arctan2(odom[:, 1, 0], odom[:, 0, 0]))
    np.testing.assert_allclose(heading_deg, body[:, 0, 3] * 1.0, atol=1e-9)  # 1 deg per metre walked


def test_odometry_standing_still_drifts_only_with_the_gyro_bias():
    body = np.repeat(_line(1)[0], 20, axis=0)
    stamps = np.arange(20) * 0.5
    faults = dataclasses.replace(RobotLogFaults(), odom_yaw_rate_bias_deg_per_s=0.1)
    odom = odometry_from_truth(body, stamps, faults, np.random.default_rng(3))
    world = odom_to_world(faults) @ odom
    np.testing.assert_allclose(world[:, :3, 3], body[:, :3, 3], atol=1e-12)  # no distance, no position drift
    heading_deg = np.degrees(np.arctan2(world[:, 1, 0], world[:, 0, 0]))
    np.testing.assert_allclose(heading_deg, 0.1 * (stamps - stamps[0]), atol=1e-9)


def test_odometry_drift_grows_with_path_length(room):
    body, stamps = _arc(room[0], 301)  # 30 m
    walked = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(body[:, :3, 3], axis=0), axis=-1))]
    faults = RobotLogFaults()
    errors = []
    for seed in range(16):
        odom = odometry_from_truth(body, stamps, faults, np.random.default_rng(seed))
        errors.append(np.linalg.norm((odom_to_world(faults) @ odom)[:, :3, 3] - body[:, :3, 3], axis=-1))
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    at = [np.searchsorted(walked, d) for d in (2.0, 5.0, 10.0, 20.0, 29.0)]
    assert rms[0] == 0.0
    assert np.all(np.diff(rms[at]) > 0.0), rms[at]
    assert 0.002 < rms[at[0]] < 0.2 and rms[at[-1]] > 3.0 * rms[at[0]]  # about 1 % of the distance and more


def test_odometry_is_seeded_and_leaves_its_inputs_alone(room):
    body, stamps = _arc(room[0], 10)
    before = body.copy()
    a = odometry_from_truth(body, stamps, RobotLogFaults(), np.random.default_rng(7))
    b = odometry_from_truth(body, stamps, RobotLogFaults(), np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(body, before)
    with pytest.raises(ValueError, match="stamps_s"):
        odometry_from_truth(body, stamps[::-1], RobotLogFaults(), np.random.default_rng(7))


def test_camera_stamps_are_exactly_the_clock_offset_ahead():
    stamps = np.arange(50) * 0.1 + 12.5  # seconds that do not round trip through ns in float arithmetic
    for offset_s in (0.03, -0.05, 0.0, 0.123456789):
        odometry_ns, camera_ns = log_stamps_ns(stamps, _faults(clock_offset_s=offset_s))
        assert odometry_ns.dtype == camera_ns.dtype == np.int64
        assert odometry_ns.tolist() == [round(t * 1e9) for t in stamps]
        assert (camera_ns - odometry_ns).tolist() == [round(offset_s * 1e9)] * 50


# ---------------------------------------------------------------------------------- cameras
def test_camera_without_faults_is_the_clean_image(room, small_rig):
    spec, oracle = room
    view = oracle.render_gt(small_rig["rgbd"].camera, _look(spec))
    out = camera_faults(view.rgb, 1.0, small_rig["rgbd"], NONE, np.random.default_rng(0))
    np.testing.assert_array_equal(out, to_uint8(view.rgb))
    gray = small_rig["gray"]
    rgb = oracle.render_gt(gray.camera, _look(spec)).rgb
    np.testing.assert_array_equal(camera_faults(rgb, 1.0, gray, NONE, np.random.default_rng(0)),
                                  to_uint8(gray.expose(rgb)))


def _look(spec) -> np.ndarray:
    """A camera (OpenCV axes) at the walk loop's centre, 1 m up, looking along +x."""
    cx, cy, _, _ = spec.walk_loop_xy_m
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    pose[:3, 3] = [cx, cy, 1.0]
    return pose


def test_camera_read_noise_has_the_configured_std(small_rig):
    level = 0.18  # linear
    rgb = np.full((100, 120, 3), _linear_to_srgb(np.float32(level)), dtype=np.float32)
    out = camera_faults(rgb, 1.0, small_rig["rgbd"], _faults(camera_read_noise_std=0.02), np.random.default_rng(1))
    linear = _srgb_to_linear(out.astype(np.float64) / 255.0)
    assert linear.mean() == pytest.approx(level, abs=0.002)
    assert linear.std() == pytest.approx(0.02, rel=0.08)


def test_camera_exposure_gain_scales_linear_light(small_rig):
    rgb = np.full((20, 20, 3), _linear_to_srgb(np.float32(0.2)), dtype=np.float32)
    out = camera_faults(rgb, 1.5, small_rig["rgbd"], NONE, np.random.default_rng(0))
    assert _srgb_to_linear(out.astype(np.float64) / 255.0).mean() == pytest.approx(0.3, rel=0.01)


def test_exposure_gains_drift_smoothly_with_the_configured_std():
    times = np.arange(4000) * 0.1
    faults = _faults(exposure_drift_std_stops=0.25, exposure_drift_timescale_s=1.0)
    stops = np.log2(exposure_gains(times, faults, np.random.default_rng(2)))
    assert stops.std() == pytest.approx(0.25, rel=0.15)
    assert abs(stops.mean()) < 0.05
    assert np.corrcoef(stops[:-1], stops[1:])[0, 1] > 0.9  # smooth from frame to frame
    np.testing.assert_array_equal(exposure_gains(times, NONE, np.random.default_rng(2)), 1.0)


def test_jpeg_frames_differ_from_clean_by_a_bounded_amount(room, small_rig):
    spec, oracle = room
    rgb = oracle.render_gt(small_rig["rgbd"].camera, _look(spec)).rgb
    clean = to_uint8(rgb).astype(np.float64)
    out = camera_faults(rgb, 1.0, small_rig["rgbd"], _faults(jpeg_quality=85), np.random.default_rng(0))
    assert out.shape == clean.shape and out.dtype == np.uint8
    err = np.abs(out - clean)
    assert err.mean() > 0.1  # compressed
    psnr = 10.0 * np.log10(255.0**2 / np.mean(err**2))
    assert psnr > 30.0 and err.mean() < 4.0, (psnr, err.mean())
    gray = camera_faults(rgb[:30, :40], 1.0, small_rig["gray"], _faults(jpeg_quality=85), np.random.default_rng(0))
    assert gray.shape == (30, 40) and gray.dtype == np.uint8
    # the frame is the decoded JPEG of the image before it, whose bytes the log holds
    before = camera_faults(rgb, 1.0, small_rig["rgbd"], _faults(jpeg_quality=85), np.random.default_rng(0), jpeg=False)
    np.testing.assert_array_equal(before, clean.astype(np.uint8))
    np.testing.assert_array_equal(out, jpeg_round_trip(before, 85))
    data = jpeg_bytes(before, 85)
    assert data[:2] == b"\xff\xd8"
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(decoded, out)
    gray_bytes = cv2.imdecode(np.frombuffer(jpeg_bytes(before[..., 0], 85), np.uint8), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(gray_bytes[..., 0], gray_bytes[..., 1])  # a gray JPEG holds equal R, G, B
    np.testing.assert_array_equal(gray_bytes[..., 0], jpeg_round_trip(before[..., 0], 85))


# ---------------------------------------------------------------------------------- depth
def test_depth_below_min_range_is_invalid(small_rig):
    s = small_rig["rgbd"]
    r = np.full(s.ray_shape, 2.0)
    r[:, :60] = 0.2  # the rig's own minimum is 0.1
    r[0, -1], r[1, -1] = np.inf, np.nan
    out = depth_faults(r, s, _faults(depth_min_range_m=0.3), np.random.default_rng(0))
    assert np.isnan(out[:, :60]).all()
    z = 2.0 * s.dirs_sensor[..., 2]
    np.testing.assert_allclose(out[2:, 60:], z[2:, 60:], rtol=1e-6)
    assert np.isposinf(out[0, -1]) and np.isnan(out[1, -1])
    clean = depth_faults(r, s, NONE, np.random.default_rng(0))  # the rig's 0.1 m minimum only
    np.testing.assert_allclose(clean[:, :60], 0.2 * s.dirs_sensor[:, :60, 2], rtol=1e-6)


def test_depth_noise_has_the_configured_std(small_rig):
    s = small_rig["rgbd"]
    r = np.full(s.ray_shape, 2.0)
    clean = depth_faults(r, s, NONE, np.random.default_rng(0))
    noisy = depth_faults(r, s, _faults(depth_noise_abs_std_m=0.01, depth_noise_rel_std=0.005), np.random.default_rng(4))
    expected = 0.01 + 0.005 * clean  # nsim.sensors.depth_model: std = abs + rel * depth
    z = (noisy - clean) / expected
    assert z.std() == pytest.approx(1.0, rel=0.05)
    assert abs(z.mean()) < 0.05


def test_depth_holes_have_the_configured_fraction_in_blobs(small_rig):
    s = small_rig["rgbd"]
    r = np.full(s.ray_shape, 2.0)
    out = depth_faults(r, s, _faults(depth_hole_fraction=0.05, depth_hole_size_px=2.0), np.random.default_rng(5))
    holes = np.isnan(out)
    assert holes.sum() == round(0.05 * holes.size)
    right_of_hole = holes[:, 1:][holes[:, :-1]]
    assert right_of_hole.mean() > 0.5  # blobs, not salt and pepper (0.05 for independent pixels)
    mask = depth_holes((50, 60), 0.1, 0.0, np.random.default_rng(0))
    assert mask.sum() == 300
    assert not depth_holes((50, 60), 0.0, 2.0, np.random.default_rng(0)).any()


# ---------------------------------------------------------------------------------- LiDAR
def test_lidar_dropout_and_noise_match_the_configuration(small_rig):
    s = small_rig["lidar"]
    r = np.full(s.ray_shape, 5.0)
    out = lidar_faults(r, s, _faults(lidar_dropout_fraction=0.1, lidar_range_noise_std_m=0.03), np.random.default_rng(6))
    lost = np.isinf(out)
    n = lost.size
    assert abs(lost.mean() - 0.1) < 4.0 * np.sqrt(0.1 * 0.9 / n)
    assert (out[~lost] - 5.0).std() == pytest.approx(0.03, rel=0.05)
    r[0, 0], r[0, 1], r[0, 2] = np.inf, np.nan, 0.2  # no hit, undefined, nearer than the 0.3 m minimum
    clean = lidar_faults(r, s, NONE, np.random.default_rng(6))
    assert np.isinf(clean[0, :3]).all() and np.all(clean.reshape(-1)[3:] == np.float32(5.0))


# ---------------------------------------------------------------------------------- the bag
def _messages(path) -> dict[str, list]:
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    return out


def _bag_name(storage: str) -> str:
    return "run.bag" if storage == "ros1" else "run"


STORAGES = ["sqlite3", "mcap", "ros1"]


@pytest.mark.parametrize("storage", STORAGES)
def test_bag_has_every_topic_stamp_and_the_truth(tmp_path, room, rig, storage):
    spec, oracle = room
    body, stamps = _arc(spec, 5)
    faults = RobotLogFaults()  # camera clock 30 ms ahead, JPEG at quality 85
    name = _bag_name(storage)
    truth = write_robot_log(tmp_path / name, spec, rig, body, stamps, faults, seed=3, storage=storage, oracle=oracle)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name, name + ".truth.json"]
    assert json.loads(truth_path(tmp_path / name).read_text()) == truth
    msgs = _messages(tmp_path / name)
    cameras = [s.name for s in rig.cameras]
    expected = {"/tf": 5, "/tf_static": 1, "/odom": 5, "/lidar/points": 5}
    for c in cameras:  # every tick has its frames; CameraInfo with the colour and with the depth
        expected |= {f"/{c}/image/compressed": 5, f"/{c}/depth": 5, f"/{c}/camera_info": 10}
    assert {k: len(v) for k, v in msgs.items()} == expected
    for topic, ms in msgs.items():  # bag time = header stamp
        header = [m.transforms[0].header if topic.startswith("/tf") else m.header for _, m in ms]
        assert [t for t, _ in ms] == [stamp_ns(h) for h in header], topic
    odometry_ns = [round(t * 1e9) for t in stamps]
    assert truth["stamps_ns"] == odometry_ns and truth["stamps_s"] == stamps.tolist()
    assert truth["camera_frames"]["stamps_ns"] == [t + 30_000_000 for t in odometry_ns]
    assert truth["camera_frames"]["capture_times_s"] == stamps.tolist()
    assert truth["clock_offset_s"] == 0.03 and truth["faults"]["odom_scale_error_percent"] == 1.0
    np.testing.assert_allclose(truth["body_to_world"], body, atol=0)
    T = np.asarray(truth["odom_to_world"])
    np.testing.assert_allclose(T, odom_to_world(faults), atol=1e-15)

    with RobotLog(tmp_path / name) as log:
        assert sorted(log.cameras) == sorted(log.depth) == sorted(cameras) and list(log.lidars) == ["lidar"]
        assert log.odometry.stamps_ns.tolist() == odometry_ns
        assert log.lidars["lidar"].stamps_ns.tolist() == odometry_ns
        for c in cameras:
            stream = log.cameras[c]
            assert stream.msgtype == "sensor_msgs/msg/CompressedImage" and stream.encoding == "rgb8; jpeg compressed bgr8"
            assert (stream.stamps_ns - log.odometry.stamps_ns).tolist() == [30_000_000] * 5  # exactly the offset
            assert log.depth[c].stamps_ns.tolist() == odometry_ns
            assert log.image(stream, 0).shape == (24, 32, 3)
        # the odometry: the truth in the odom frame at tick 0, then drifting; /tf carries the same
        trajectory = log.body_trajectory()
        assert trajectory.source == "tf: odom -> body" and trajectory.stamps_ns.tolist() == odometry_ns
        np.testing.assert_allclose(trajectory.body_to_odom, log.odometry.child_to_parent, atol=1e-12)
        np.testing.assert_allclose(T @ trajectory.body_to_odom[0], body[0], atol=1e-9)
        assert np.abs(T @ trajectory.body_to_odom[-1] - body[-1]).max() > 1e-5
        # the JPEG frames: encode_jpeg's very bytes of the camera at the true pose of its tick
        front = rig["frontleft"]
        k = [s.name for s in rig.sensors].index("frontleft")
        for i in range(5):
            view = oracle.render_gt(front.camera, front.world_pose(body[i]))
            gain = truth["camera_frames"]["exposure_gains"]["frontleft"][i]
            image = camera_faults(view.rgb, gain, front, faults, np.random.default_rng([3, CAMERA_TAG, i, k]), jpeg=False)
            assert bytes(msgs["/frontleft/image/compressed"][i][1].data) == jpeg_bytes(image, 85)
            np.testing.assert_array_equal(log.image(log.cameras["frontleft"], i), jpeg_round_trip(image, 85))
        # depth holes and the 0.3 m minimum are in the depth images
        depth = np.stack([d for _, d in log.images(log.depth["frontleft"])])
    assert np.isnan(depth).mean() >= 0.03 and np.nanmin(depth) >= 0.3 - 4 * 0.005


@pytest.mark.parametrize(("storage", "offset_s"), [("sqlite3", 0.05), ("mcap", -0.15), ("ros1", 0.0)])
def test_clean_log_holds_the_oracle_readings_and_the_clock_offset(tmp_path, room, rig, storage, offset_s):
    """No fault but the clock offset: every reading is the oracle's at the true pose of its tick.
    -0.15 s puts camera frames more than a tick (0.1 s) before their odometry."""
    spec, oracle = room
    body, stamps = _arc(spec, 4)
    faults = _faults(clock_offset_s=offset_s)
    name = _bag_name(storage)
    truth = write_robot_log(tmp_path / name, spec, rig, body, stamps, faults, seed=0, storage=storage, oracle=oracle)
    assert truth["camera_frames"]["topic"] == "/<camera>/image"
    with RobotLog(tmp_path / name) as log:
        odometry_ns = log.odometry.stamps_ns
        assert odometry_ns.tolist() == [round(t * 1e9) for t in stamps]
        trajectory = log.body_trajectory()
        np.testing.assert_allclose(trajectory.body_to_odom, body, atol=1e-12)  # no drift, odom = world
        np.testing.assert_allclose(log.odometry.child_to_parent, body, atol=1e-12)
        for s in rig.cameras:
            stream = log.cameras[s.name]
            assert stream.msgtype == "sensor_msgs/msg/Image" and stream.encoding == "rgb8"
            assert (stream.stamps_ns - odometry_ns).tolist() == [round(offset_s * 1e9)] * 4
            assert log.depth[s.name].stamps_ns.tolist() == odometry_ns.tolist()
            assert stream.camera == s.camera
            np.testing.assert_allclose(log.sensor_to_body(stream.frame_id), s.sensor_to_body, atol=1e-12)
            for i, image in log.images(stream):
                view = oracle.render_gt(s.camera, s.world_pose(body[i]))
                np.testing.assert_array_equal(image, to_uint8(view.rgb))
                r = view.depth_range
                clean = np.where(np.isnan(r), np.nan, s.measure_depth(np.nan_to_num(r, nan=np.inf)))
                np.testing.assert_array_equal(log.image(log.depth[s.name], i), clean.astype(np.float32))
        lidar = rig["lidar"]
        assert log.lidars["lidar"].stamps_ns.tolist() == odometry_ns.tolist()
        for i, points in log.clouds(log.lidars["lidar"]):
            exact = oracle.cast_rays(*lidar.rays(body[i])).t.reshape(lidar.ray_shape)
            scan = lidar.scan(lidar.measure(exact))
            np.testing.assert_allclose(points.xyz_m, scan.xyz_m[scan.hit], atol=1e-6)
            np.testing.assert_array_equal(points.intensity, 1.0)


def test_seeded_runs_write_identical_truth(tmp_path, room, rig):
    spec, oracle = room
    body, stamps = _arc(spec, 3)
    for k in range(2):
        (tmp_path / str(k)).mkdir()
        write_robot_log(tmp_path / str(k) / "run", spec, rig, body, stamps, RobotLogFaults(), seed=11, oracle=oracle)
    a, b = ((tmp_path / str(k) / "run.truth.json").read_bytes() for k in range(2))
    assert a == b
    img = [_messages(tmp_path / str(k) / "run")["/back/image/compressed"][-1][1].data for k in range(2)]
    np.testing.assert_array_equal(img[0], img[1])


def test_bad_destination_fails_before_rendering(tmp_path, room, rig, monkeypatch):
    spec, _ = room
    body, stamps = _arc(spec, 3)

    def no_rendering(*args, **kwargs):
        raise AssertionError("rendered before checking the destination")

    monkeypatch.setattr("nsim.synth.oracle.RoomOracle", no_rendering)
    (tmp_path / "run").mkdir()
    with pytest.raises(InputError, match="exists already"):
        write_robot_log(tmp_path / "run", spec, rig, body, stamps)
    assert list((tmp_path / "run").iterdir()) == []
    truth_path(tmp_path / "other").write_text("{}")
    with pytest.raises(InputError, match="exists already"):
        write_robot_log(tmp_path / "other", spec, rig, body, stamps)
    with pytest.raises(InputError, match="does not exist"):
        write_robot_log(tmp_path / "missing" / "run", spec, rig, body, stamps)
    with pytest.raises(ConfigError, match="depth_hole_fraction"):
        write_robot_log(tmp_path / "new", spec, rig, body, stamps, _faults(depth_hole_fraction=2.0))
    line, from_zero = _line(3)
    with pytest.raises(ValueError, match="before time 0"):  # the camera clock 50 ms behind a run that starts at 0
        write_robot_log(tmp_path / "new", spec, rig, line, from_zero, _faults(clock_offset_s=-0.05))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.truth.json", "run"]


def test_a_gray_camera_writes_a_one_component_jpeg():
    from nsim.io.rosbag import jpeg_components
    from nsim.synth.faulty_robot_log import jpeg_bytes, jpeg_round_trip

    gray = (np.arange(48 * 64) % 251).astype(np.uint8).reshape(48, 64)
    assert jpeg_components(jpeg_bytes(gray, 90)) == 1
    back = jpeg_round_trip(gray, 90)
    assert back.shape == gray.shape and back.dtype == np.uint8
    assert np.abs(back.astype(int) - gray).mean() < 8
    assert jpeg_components(jpeg_bytes(np.stack([gray] * 3, -1), 90)) == 3


def test_depth_noise_alone_stays_below_the_agreement_floor(room, rig):
    """paper.AGREEMENT_TOLERANCE's depth floor is the AbsRel the log's default depth noise adds by itself: a perfect
    render (the oracle's exact depth) scored against the noisy recording, over Spot's depth views of the walk loop."""
    from nsim.metrics.depth import abs_rel
    from tests.test_paper_recording import load_paper

    paper = load_paper()
    spec, oracle = room
    body, _ = _arc(spec, 40)
    faults = _faults(depth_noise_abs_std_m=RobotLogFaults().depth_noise_abs_std_m,
                     depth_noise_rel_std=RobotLogFaults().depth_noise_rel_std)
    per_view = []
    for i in range(0, 40, 4):
        for s in rig.cameras:
            if s.emits_depth:
                r = oracle.render_gt(s.camera, s.world_pose(body[i])).depth_range
                exact = s.depth_from_range(np.nan_to_num(r, nan=np.inf))  # before the sensor's range limits
                per_view.append(abs_rel(exact, depth_faults(r, s, faults, np.random.default_rng(i))))
    assert len(per_view) == 50
    # the noise's own AbsRel: about E|n| / d = sqrt(2 / pi) (5 mm / d + 1 %), 0.014 at these depths (about 0.9 m)
    assert 0.01 < np.mean(per_view) < 0.017 and max(per_view) < paper.DEPTH_NOISE_ABSREL_FLOOR
    assert paper.AGREEMENT_TOLERANCE[("spot-depth", "AbsRel")] == ("rel+abs", 0.25, paper.DEPTH_NOISE_ABSREL_FLOOR)
