"""Organised LiDAR EXR and PLY: bit-exact round trips, the documented miss convention, header attributes."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.exr import write_exr
from nsim.io.lidar_exr import (
    elevations_from_attributes,
    lidar_exr_attributes,
    read_lidar_exr,
    read_lidar_ply,
    scan_from_ply,
    write_lidar_exr,
    write_lidar_ply,
)
from nsim.sensors import LidarConfig, LidarSensor


@pytest.fixture
def sensor() -> LidarSensor:
    cfg = LidarConfig(channels=4, vertical_fov_deg=(-15.0, 15.0), azimuth_samples=36)
    return LidarSensor("top", np.eye(4), cfg, np.linspace(-15.0, 15.0, 4))


@pytest.fixture
def scan(sensor):
    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.5, 30.0, size=sensor.ray_shape)
    ranges[rng.random(sensor.ray_shape) < 0.2] = np.inf  # misses
    return sensor.scan(sensor.measure(ranges), intensity=rng.uniform(0.0, 1.0, size=sensor.ray_shape))


def test_exr_round_trip_is_bit_exact(tmp_path, sensor, scan):
    path = write_lidar_exr(tmp_path / "scan.exr", scan, sensor="top", elevations_deg=sensor.elevations_deg)
    back = read_lidar_exr(path)
    for name in ("range_m", "xyz_m", "intensity", "ring"):
        a, b = getattr(scan, name), getattr(back, name)
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8))  # NaN and inf included
    assert back.ring.dtype == np.uint16 and back.xyz_m.shape == (4, 36, 3)


def test_misses_follow_the_documented_convention(tmp_path, scan):
    back = read_lidar_exr(write_lidar_exr(tmp_path / "scan.exr", scan))
    miss = ~back.hit
    assert miss.any() and back.hit.any()
    assert np.all(np.isinf(back.range_m[miss])) and np.all(np.isnan(back.xyz_m[miss]))
    assert np.all(back.intensity[miss] == 0.0)
    np.testing.assert_allclose(np.linalg.norm(back.xyz_m[back.hit], axis=-1), back.range_m[back.hit], rtol=1e-6)
    np.testing.assert_array_equal(back.ring, np.broadcast_to(np.arange(4)[:, None], (4, 36)))


def test_header_explains_the_file(tmp_path, sensor, scan):
    path = write_lidar_exr(tmp_path / "scan.exr", scan, sensor="top", elevations_deg=sensor.elevations_deg)
    attrs = lidar_exr_attributes(path)
    assert attrs["nsim_sensor"] == "top"
    assert "inf" in attrs["nsim_miss"] and "NaN" in attrs["nsim_miss"]
    assert "rows = beams" in attrs["nsim_layout"] and "x forward" in attrs["nsim_frame"]
    np.testing.assert_allclose(elevations_from_attributes(attrs), sensor.elevations_deg)
    assert elevations_from_attributes(lidar_exr_attributes(write_lidar_exr(tmp_path / "b.exr", scan))) is None


def test_write_is_deterministic(tmp_path, scan):
    a = write_lidar_exr(tmp_path / "a.exr", scan, sensor="top").read_bytes()
    b = write_lidar_exr(tmp_path / "b.exr", scan, sensor="top").read_bytes()
    assert a == b


def test_ply_holds_the_returns(tmp_path, scan):
    cloud = read_lidar_ply(write_lidar_ply(tmp_path / "scan.ply", scan))
    assert len(cloud) == int(scan.hit.sum())
    np.testing.assert_array_equal(cloud.xyz, scan.xyz_m[scan.hit])
    np.testing.assert_array_equal(cloud.fields["range"], scan.range_m[scan.hit])
    np.testing.assert_array_equal(cloud.fields["ring"], scan.ring[scan.hit])
    assert cloud.xyz.dtype == np.float32 and cloud.fields["ring"].dtype == np.uint16
    back = scan_from_ply(cloud, scan.range_m.shape)
    for name in ("range_m", "xyz_m", "intensity", "ring"):
        np.testing.assert_array_equal(getattr(back, name).view(np.uint8), getattr(scan, name).view(np.uint8))


def test_reading_the_wrong_file_is_an_input_error(tmp_path):
    path = write_exr(tmp_path / "depth.exr", {"Z": np.ones((2, 3), np.float32)})
    with pytest.raises(InputError, match="not an organised LiDAR EXR"):
        read_lidar_exr(path)
    with pytest.raises(InputError, match="no such file"):
        read_lidar_exr(tmp_path / "none.exr")
    with pytest.raises(InputError, match="no such file"):
        lidar_exr_attributes(tmp_path / "none.exr")
