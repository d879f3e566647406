"""Robot rigs: the shipped Spot and pinhole RGB-D rigs, mounts and rays, depth and LiDAR models, errors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from nsim.errors import ConfigError, NsimError
from nsim.geometry import Camera, is_rotation, make_se3
from nsim.sensors import CameraSensor, DepthConfig, LidarConfig, LidarSensor, Rig, beam_directions
from nsim.sensors.depth_model import apply_depth_model, range_to_z_depth, z_depth_to_range
from nsim.sensors.rig import LINK_TO_OPTICAL

ROBOTS = Path(__file__).resolve().parents[2] / "nsim" / "configs" / "robots"
BODY_HEIGHT_M = 0.5  # nsim/configs/robots/spot.yaml: the body frame origin above the ground when standing


@pytest.fixture(scope="module")
def spot() -> Rig:
    return Rig.load(ROBOTS / "spot.yaml")


def _rig(tmp_path: Path, sensors: list, **top) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"name": "test", **top, "sensors": sensors}, sort_keys=False))
    return path


PINHOLE = {"model": "PINHOLE", "width": 32, "height": 24, "hfov_deg": 60.0}


# ------------------------------------------------------------------ the shipped rigs


def test_spot_rig(spot):
    assert spot.names == ("frontleft", "frontright", "left", "right", "back", "lidar")
    for cam in spot.cameras:
        assert cam.type == "camera" and cam.emits_image and cam.emits_depth
        assert cam.camera.model == "OPENCV_FISHEYE" and cam.ray_shape == (480, 640)
        assert cam.camera == Camera.fisheye_spot_like(640, 480)
        assert 0.5 <= BODY_HEIGHT_M + cam.sensor_to_body[2, 3] <= 0.6
        assert is_rotation(cam.sensor_to_body[:3, :3])
    (lidar,) = spot.lidars
    assert lidar.type == "lidar" and lidar.ray_shape == (16, 1800)
    assert lidar.config.vertical_fov_deg == (-15.0, 15.0) and lidar.evenly_spaced
    assert lidar.sensor_to_body[2, 3] > max(c.sensor_to_body[2, 3] for c in spot.cameras)  # on top


def test_spot_cameras_look_where_the_real_ones_do(spot):
    axis = {c.name: c.sensor_to_body[:3, 2] for c in spot.cameras}  # optical axis in the body frame
    for name in ("frontleft", "frontright"):
        assert axis[name][0] > 0.5 and axis[name][2] < -0.2  # forward and down
    assert axis["frontleft"][1] < 0 < axis["frontright"][1]  # crossed, as on Spot
    assert axis["left"][1] > 0.9 and axis["right"][1] < -0.9 and axis["back"][0] < -0.9
    down = {c.name: c.sensor_to_body[:3, 1] for c in spot.cameras}  # image +v in the body frame
    assert down["left"][2] < -0.9 and down["right"][2] > 0.9  # the right camera is upside down


def test_spot_yaml_matches_spot_like_urdf(spot, tmp_path):
    links = {"frontleft": "frontleft_fisheye", "frontright": "frontright_fisheye", "left": "left_fisheye",
             "right": "right_fisheye", "back": "back_fisheye"}
    sensors = [{"name": n, "type": "camera", "mount": {"link": link}, "intrinsics": PINHOLE} for n, link in links.items()]
    sensors.append({"name": "lidar", "type": "lidar", "mount": {"link": "lidar"}, "lidar": {}})
    rig = Rig.load(_rig(tmp_path, sensors, urdf=str(ROBOTS / "spot_like.urdf")))
    for name in spot.names:
        np.testing.assert_allclose(rig[name].sensor_to_body, spot[name].sensor_to_body, atol=1e-8)


def test_to_dict_is_plain_data(spot):
    import json

    d = spot.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert [s["name"] for s in d["sensors"]] == list(spot.names)
    assert d["sensors"][0]["camera"]["model"] == "OPENCV_FISHEYE" and d["sensors"][0]["depth"]["max_m"] == 10.0
    assert d["sensors"][5]["lidar"]["channels"] == 16 and len(d["sensors"][5]["elevations_deg"]) == 16
    assert Rig.load(ROBOTS / "spot.yaml").to_dict() == d


def test_pinhole_rgbd_rig():
    rig = Rig.load(ROBOTS / "pinhole-rgbd.yaml")
    (cam,) = rig.sensors
    assert isinstance(cam, CameraSensor) and cam.emits_image and cam.emits_depth
    assert cam.camera.model == "PINHOLE" and cam.ray_shape == (480, 640)
    assert cam.depth == DepthConfig(kind="z", min_m=0.1, max_m=10.0)
    np.testing.assert_allclose(cam.sensor_to_body[:3, :3], LINK_TO_OPTICAL)  # level, looking along body +x
    assert abs(cam.camera.fov_deg[0] - 69.0) < 1e-9


# ------------------------------------------------------------------ mounts, poses and rays


def test_mount_rotations_agree(tmp_path):
    c, s = float(np.cos(np.pi / 4)), float(np.sin(np.pi / 4))
    q = [float(np.cos(np.pi / 8)), 0.0, 0.0, float(np.sin(np.pi / 8))]  # yaw 45 deg
    R = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    sensors = [
        {"name": "a", "type": "lidar", "mount": {"xyz_m": [1, 2, 3], "rpy_deg": [0, 0, 45]}, "lidar": {}},
        {"name": "b", "type": "lidar", "mount": {"xyz_m": [1, 2, 3], "quat_wxyz": q}, "lidar": {}},
        {"name": "c", "type": "lidar", "mount": {"xyz_m": [1, 2, 3], "rotation_matrix": R}, "lidar": {}},
    ]
    rig = Rig.load(_rig(tmp_path, sensors))
    for s in rig:
        np.testing.assert_allclose(s.sensor_to_body, make_se3(np.array(R), np.array([1.0, 2.0, 3.0])), atol=1e-12)


def test_optical_axes_mount(tmp_path):
    sensors = [
        {"name": "link", "type": "camera", "mount": {"rpy_deg": [0, 0, 90]}, "intrinsics": PINHOLE},
        {"name": "opt", "type": "camera", "mount": {"axes": "optical", "rotation_matrix": [[1, 0, 0], [0, 0, 1], [0, -1, 0]]},
         "intrinsics": PINHOLE},
    ]
    rig = Rig.load(_rig(tmp_path, sensors))
    np.testing.assert_allclose(rig["link"].sensor_to_body[:3, 2], [0, 1, 0], atol=1e-12)  # looks left
    np.testing.assert_allclose(rig["opt"].sensor_to_body[:3, 2], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rig["link"].sensor_to_body, rig["opt"].sensor_to_body, atol=1e-12)


def test_world_pose_and_camera_rays(spot):
    cam = spot["frontleft"]
    body_to_world = make_se3(np.eye(3)[[1, 0, 2]] * [[1], [-1], [1]], np.array([2.0, -1.0, 0.5]))  # yaw 90
    pose = cam.world_pose(body_to_world)
    np.testing.assert_allclose(pose, body_to_world @ cam.sensor_to_body)
    origins, dirs = cam.rays(body_to_world)
    assert origins.shape == dirs.shape == (480 * 640, 3)
    np.testing.assert_allclose(origins, np.broadcast_to(pose[:3, 3], origins.shape))
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    ref_origins, ref_dirs = cam.camera.pixel_rays(pose)  # (H, W, 3): rows are v, so index v * W + u
    np.testing.assert_allclose(dirs, ref_dirs.reshape(-1, 3), atol=1e-12)
    np.testing.assert_allclose(cam.world_pose(np.stack([body_to_world, np.eye(4)]))[0], pose)


def test_lidar_rays_follow_the_papers_formula(spot):
    lidar = spot["lidar"]
    body_to_world = make_se3(np.eye(3), np.array([1.0, 0.0, 0.5]))
    origins, dirs = lidar.rays(body_to_world)
    assert dirs.shape == (16 * 1800, 3)
    np.testing.assert_allclose(dirs.reshape(16, 1800, 3), beam_directions(lidar.config))  # level mount
    np.testing.assert_allclose(origins[0], [0.95, 0.0, 0.72])
    theta, phi = 2 * np.pi * 7 / 1800, np.radians(90.0 - (-15.0 + 2.0 * 3))  # ring 3, column 7
    np.testing.assert_allclose(dirs[3 * 1800 + 7], [np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])


def test_explicit_beam_angles(tmp_path):
    angles = [-25.0, 2.0, -15.0, 5.0, -10.0, 15.0, -5.0, 0.0, -2.0]  # denser near the horizon, any order
    sensors = [{"name": "l", "type": "lidar", "mount": {}, "lidar": {"vertical_angles_deg": angles, "azimuth_samples": 8}}]
    lidar = Rig.load(_rig(tmp_path, sensors))["l"]
    assert isinstance(lidar, LidarSensor) and lidar.ray_shape == (9, 8) and not lidar.evenly_spaced
    np.testing.assert_allclose(lidar.elevations_deg, sorted(angles))  # rows ascending: ring 0 lowest
    elevation = np.degrees(np.arcsin(lidar.dirs_sensor[..., 2]))
    np.testing.assert_allclose(elevation, np.broadcast_to(np.sort(angles)[:, None], (9, 8)), atol=1e-9)
    azimuth = np.arctan2(lidar.dirs_sensor[..., 1], lidar.dirs_sensor[..., 0]) % (2 * np.pi)
    np.testing.assert_allclose(azimuth, np.broadcast_to(2 * np.pi * np.arange(8) / 8, (9, 8)), atol=1e-9)


# ------------------------------------------------------------------ depth and LiDAR measurement models


def test_depth_kinds_on_a_plane(tmp_path):
    sensors = [{"name": "d", "type": "depth", "mount": {}, "intrinsics": PINHOLE, "depth": {"kind": "z"}},
               {"name": "r", "type": "depth", "mount": {}, "intrinsics": PINHOLE, "depth": {"kind": "range"}}]
    rig = Rig.load(_rig(tmp_path, sensors))
    d, r = rig["d"], rig["r"]
    assert not d.emits_image and d.emits_depth
    ranges = 2.0 / d.dirs_sensor[..., 2]  # a wall 2 m in front of the camera
    np.testing.assert_allclose(d.depth_from_range(ranges), 2.0, atol=1e-12)
    np.testing.assert_allclose(r.depth_from_range(ranges), ranges)
    np.testing.assert_allclose(z_depth_to_range(np.full((24, 32), 2.0), d.dirs_sensor[..., 2]), ranges)


def test_fisheye_z_depth_undefined_beyond_90_degrees():
    dz = np.array([0.5, 0.0, -0.3])
    z = range_to_z_depth(np.array([2.0, 2.0, 2.0]), dz)
    assert z[0] == 1.0 and np.isnan(z[1]) and np.isnan(z[2])
    assert range_to_z_depth(np.array([np.inf]), np.array([0.5]))[0] == np.inf


def test_depth_model_noise_quantisation_and_range():
    depth = np.array([[0.05, 1.0, 1.23456, 20.0, np.inf, np.nan]])
    cfg = DepthConfig(min_m=0.1, max_m=10.0, quantization_m=0.01)
    out = apply_depth_model(depth, cfg)
    assert out.dtype == np.float32
    assert np.isnan(out[0, 0]) and out[0, 3] == np.inf and out[0, 4] == np.inf and np.isnan(out[0, 5])
    np.testing.assert_allclose(out[0, 1:3], [1.0, 1.23], atol=1e-6)
    noisy = DepthConfig(noise_abs_std_m=0.01, noise_rel_std=0.02)
    flat = np.full((200, 200), 2.0)
    a = apply_depth_model(flat, noisy, np.random.default_rng(3))
    b = apply_depth_model(flat, noisy, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)  # seeded: deterministic
    assert abs(float(np.std(a)) - (0.01 + 0.02 * 2.0)) < 0.003 and abs(float(np.mean(a)) - 2.0) < 0.003
    with pytest.raises(ValueError, match="rng"):
        apply_depth_model(flat, noisy)


def test_lidar_measure_noise_dropout_and_gate(spot):
    lidar = spot["lidar"]
    exact = np.full(lidar.ray_shape, 5.0)
    exact[0, :3] = [0.1, 200.0, np.inf]  # nearer than min, beyond max, no hit
    out = lidar.measure(exact)
    assert out.dtype == np.float32 and np.all(np.isinf(out[0, :3])) and np.all(out[0, 3:] == 5.0)
    cfg = LidarConfig(range_noise_std_m=0.03)
    noisy = LidarSensor("l", np.eye(4), cfg, np.linspace(-15, 15, 16), dropout_prob=0.25)
    r1 = noisy.measure(np.full(noisy.ray_shape, 5.0), np.random.default_rng(1))
    r2 = noisy.measure(np.full(noisy.ray_shape, 5.0), np.random.default_rng(1))
    np.testing.assert_array_equal(r1, r2)
    hit = np.isfinite(r1)
    assert abs(1.0 - hit.mean() - 0.25) < 0.01 and abs(float(np.std(r1[hit])) - 0.03) < 0.002
    with pytest.raises(ValueError, match="rng"):
        noisy.measure(np.full(noisy.ray_shape, 5.0))


def test_lidar_scan_points(spot):
    lidar = spot["lidar"]
    r = np.full(lidar.ray_shape, 4.0)
    r[2, 5] = np.inf
    scan = lidar.scan(r)
    assert scan.xyz_m.shape == (16, 1800, 3) and scan.ring.dtype == np.uint16
    assert np.all(np.isnan(scan.xyz_m[2, 5])) and scan.intensity[2, 5] == 0 and scan.range_m[2, 5] == np.inf
    np.testing.assert_allclose(np.linalg.norm(scan.xyz_m[scan.hit], axis=1), 4.0, rtol=1e-6)
    np.testing.assert_array_equal(scan.ring[:, 0], np.arange(16))


def test_exposure_and_gray(tmp_path):
    sensors = [{"name": "c", "type": "camera", "mount": {}, "intrinsics": PINHOLE, "exposure_ev": 1.0},
               {"name": "g", "type": "camera", "mount": {}, "intrinsics": PINHOLE, "color": "gray"},
               {"name": "p", "type": "camera", "mount": {}, "intrinsics": PINHOLE}]
    rig = Rig.load(_rig(tmp_path, sensors))
    rgb = np.random.default_rng(0).uniform(0.0, 0.6, size=(4, 5, 3)).astype(np.float32)
    assert rig["p"].expose(rgb) is not None and np.array_equal(rig["p"].expose(rgb), rgb)
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    brighter = rig["c"].expose(rgb)
    lin_b = np.where(brighter <= 0.04045, brighter / 12.92, ((brighter + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(lin_b, np.clip(2 * lin, 0, 1), atol=1e-5)
    assert rig["g"].expose(rgb).shape == (4, 5)


# ------------------------------------------------------------------ errors: one line, file, line, sensor


def _expect_error(tmp_path, sensors, fragment, sensor=None, line=True, **top):
    path = _rig(tmp_path, sensors, **top)
    with pytest.raises(ConfigError) as info:
        Rig.load(path)
    msg = str(info.value)
    assert isinstance(info.value, NsimError) and "\n" not in msg
    assert str(path) in msg and fragment in msg, msg
    if line:
        assert re.search(re.escape(str(path)) + r":\d+:", msg), msg
    if sensor:
        assert f"sensor '{sensor}'" in msg, msg
    return msg


LIDAR = {"name": "top", "type": "lidar", "mount": {}, "lidar": {}}


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"type": "radar"}, "unknown sensor type 'radar'"),
        ({"mount": {"quat_wxyz": [1.0, 0.2, 0.0, 0.0]}}, "mount.quat_wxyz: norm 1.0198"),
        ({"mount": {"rotation_matrix": [[1, 0, 0], [0, 1, 0.1], [0, 0, 1]]}}, "mount.rotation_matrix: not a rotation"),
        ({"mount": {"rotation_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}}, "det = -1"),
        ({"mount": {"rpy_deg": [0, 0, 1], "quat_wxyz": [1, 0, 0, 0]}}, "give one rotation"),
        ({"mount": {"xyz_m": [0, 0]}}, "mount.xyz_m: expected a list of 3 items"),
        ({"mount": {"xyz": [0, 0, 0]}}, "mount.xyz: unknown key"),
        ({"lidar": {"channels": 0}}, "lidar.channels: expected int >= 1, got 0"),
        ({"lidar": {"azimuth_samples": 0}}, "lidar.azimuth_samples: expected int >= 1, got 0"),
        ({"lidar": {"vertical_angles_deg": []}}, "at least one beam"),
        ({"lidar": {"vertical_angles_deg": [-1, 1], "channels": 16}}, "16 channels but 2 vertical_angles_deg"),
        ({"lidar": {"vertical_fov_deg": [15, -15]}}, "vertical_fov_deg"),
        ({"lidar": {"dropout_prob": 1.0}}, "lidar.dropout_prob"),
        ({"lidar": None, "intrinsics": PINHOLE}, "unknown key for a lidar sensor"),
        ({"mount": {"link": "lidar"}}, "a link needs a URDF"),
    ],
)
def test_bad_lidar_sensor(tmp_path, change, fragment):
    sensor = {**LIDAR, **change}
    sensor = {k: v for k, v in sensor.items() if v is not None or k != "lidar"}
    _expect_error(tmp_path, [sensor], fragment, sensor="top")


@pytest.mark.parametrize(
    ("sensor", "fragment"),
    [
        ({"name": "c", "type": "camera", "mount": {}}, "intrinsics: required key is missing"),
        ({"name": "c", "type": "camera", "intrinsics": PINHOLE}, "mount: required key is missing"),
        ({"name": "c", "mount": {}, "intrinsics": PINHOLE}, "type: required key is missing"),
        ({"name": "c", "type": "camera", "mount": {}, "intrinsics": {**PINHOLE, "fx": 100.0}}, "exactly one of preset, hfov_deg or fx"),
        ({"name": "c", "type": "camera", "mount": {}, "intrinsics": {"model": "PINHOLE", "width": 0, "height": 4, "fx": 5.0}},
         "intrinsics.width: expected int >= 1"),
        ({"name": "c", "type": "camera", "mount": {}, "intrinsics": {"model": "OPENCV", "width": 8, "height": 8, "fx": 5.0,
                                                                      "dist": [0.1]}}, "OPENCV takes"),
        ({"name": "c", "type": "camera", "mount": {}, "intrinsics": PINHOLE, "depth": {"min_m": 5.0, "max_m": 1.0}},
         "depth.max_m"),
        ({"name": "c", "type": "camera", "mount": {}, "intrinsics": PINHOLE, "depth": {"kind": "disparity"}},
         "depth.kind: 'disparity' is not one of z, range"),
        ({"name": "c", "type": "camera", "mount": {}, "intrinsics": PINHOLE, "color": "bgr"}, "color: 'bgr'"),
        ({"name": "c", "type": "depth", "mount": {}, "intrinsics": PINHOLE, "color": "rgb"}, "unknown key for a depth sensor"),
        ({"name": "c", "type": "camera", "mount": {"axes": "optical"}, "intrinsics": PINHOLE, "exposure_ev": "x"},
         "exposure_ev"),
    ],
)
def test_bad_camera_sensor(tmp_path, sensor, fragment):
    _expect_error(tmp_path, [sensor], fragment, sensor="c")


def test_duplicate_names(tmp_path):
    msg = _expect_error(tmp_path, [LIDAR, {**LIDAR}], "duplicate sensor name 'top'")
    assert "sensors[1].name" in msg


def test_unknown_urdf_link(tmp_path):
    sensors = [{**LIDAR, "mount": {"urdf": str(ROBOTS / "spot_like.urdf"), "link": "tail"}}]
    _expect_error(tmp_path, sensors, "no link named 'tail'", sensor="top")


def test_error_names_the_line(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text("name: t\nsensors:\n  - name: top\n    type: lidar\n    mount: {}\n    lidar:\n      channels: 0\n")
    with pytest.raises(ConfigError, match=re.escape(f"{path}:7: sensor 'top': lidar.channels")):
        Rig.load(path)
    path.write_text("sensors:\n  - name: [\n")
    with pytest.raises(ConfigError, match=re.escape(f"{path}:") + r".*malformed YAML"):
        Rig.load(path)
    with pytest.raises(ConfigError, match="rig file not found"):
        Rig.load(tmp_path / "none.yaml")
    _expect_error(tmp_path, [], "expected a non-empty list of sensors")
    _expect_error(tmp_path, [LIDAR], "robot: unknown key", robot="x")
