"""LiDAR ground truth from the oracle: ranges are cast distances, hand-checkable floor hits, noise, gating."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.geometry.transforms import make_se3
from nsim.sensors.lidar import LidarConfig, beam_directions, beam_elevations_deg
from nsim.synth.oracle import RoomOracle
from nsim.synth.raycast import cast
from tests.synth.simple_room import simple_spec

CFG = LidarConfig(channels=8, azimuth_samples=90, min_range_m=0.0)


def _pose(xyz, yaw_deg=0.0):
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return make_se3(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), np.asarray(xyz, dtype=float))


def test_ranges_equal_cast_distances(oracles):
    oracle = oracles["living-room"]
    cx, cy, rx, _ = oracle.spec.walk_loop_xy_m
    pose = _pose([cx + rx, cy, 0.7], yaw_deg=33.0)  # on the walk loop
    scan = oracle.lidar_gt(pose, CFG)
    assert scan.ranges_m.shape == (8, 90) and scan.ranges_m.dtype == np.float32
    dirs_world = beam_directions(CFG).reshape(-1, 3) @ pose[:3, :3].T
    hits = cast(oracle.spec, np.tile(pose[:3, 3], (len(dirs_world), 1)), dirs_world)
    np.testing.assert_allclose(scan.ranges_m.ravel(), hits.t, rtol=1e-6)
    np.testing.assert_array_equal(scan.surface_id.ravel(), hits.surface_id)
    world = scan.points_lidar_m.reshape(-1, 3).astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
    np.testing.assert_allclose(world, hits.point, atol=1e-5)
    assert (scan.surface_id >= 6).any()  # it sees furniture


def test_floor_beam_hits_at_height_over_sine_of_elevation():
    oracle = RoomOracle(simple_spec())
    cfg = LidarConfig(channels=16, azimuth_samples=360)
    h = 0.5
    scan = oracle.lidar_gt(_pose([4.0, 2.0, h], yaw_deg=10.0), cfg)
    lowest = beam_elevations_deg(cfg)[0]  # -15 deg: reaches the floor 1.87 m away, inside the room
    np.testing.assert_allclose(scan.ranges_m[0], h / np.sin(np.radians(-lowest)), rtol=1e-6)
    assert np.all(scan.surface_id[0] == 0)
    np.testing.assert_allclose(scan.points_lidar_m[0, :, 2], -h, atol=1e-6)


def test_range_gating():
    oracle = RoomOracle(simple_spec())
    exact = oracle.lidar_gt(_pose([4.0, 2.0, 1.2]), LidarConfig(channels=4, azimuth_samples=36))
    values = np.unique(exact.ranges_m.astype(np.float64))
    k, m = len(values) // 3, 2 * len(values) // 3
    lo, hi = (values[k] + values[k + 1]) / 2, (values[m] + values[m + 1]) / 2  # between returns: no ties
    cfg = LidarConfig(channels=4, azimuth_samples=36, min_range_m=float(lo), max_range_m=float(hi))
    scan = oracle.lidar_gt(_pose([4.0, 2.0, 1.2]), cfg)
    inside = (exact.ranges_m >= lo) & (exact.ranges_m <= hi)
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(scan.ranges_m[inside], exact.ranges_m[inside])
    assert np.all(np.isinf(scan.ranges_m[~inside])) and np.all(np.isnan(scan.points_lidar_m[~inside]))
    assert np.all(scan.surface_id[~inside] == -1)


def test_noise_is_seeded_and_has_the_configured_std():
    oracle = RoomOracle(simple_spec())
    noisy = LidarConfig(channels=16, azimuth_samples=720, range_noise_std_m=0.02)
    pose = _pose([4.0, 2.0, 1.2])
    exact = oracle.lidar_gt(pose, LidarConfig(channels=16, azimuth_samples=720))
    a = oracle.lidar_gt(pose, noisy, rng=np.random.default_rng(7))
    b = oracle.lidar_gt(pose, noisy, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a.ranges_m, b.ranges_m)
    err = (a.ranges_m - exact.ranges_m).ravel()
    assert abs(err.std() - 0.02) < 0.002 and abs(err.mean()) < 0.002
    with pytest.raises(ValueError, match="rng"):
        oracle.lidar_gt(pose, noisy)
