"""``render``'s ``noise: false``: the rig's own measurement with its noise terms zeroed (``nsim.rendering.shard``).

The shard renderer measures through the rig (``CameraSensor.measure_depth``, ``LidarSensor.measure``);
with ``noise: false`` it uses ``_without_noise(rig)``. These tests hold that rig to what ``noise: false``
promises (no Gaussian noise, no dropout; quantisation and the valid ranges stay) and check it against
a plain twin of the measurement written out here.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from nsim.config import configs_dir
from nsim.sensors.depth_model import apply_depth_model
from nsim.sensors.rig import CameraSensor, LidarSensor, load_rig


def _noisy_spot():
    """Spot with depth noise on every camera and range noise and dropout on its LiDAR."""
    rig = load_rig(configs_dir() / "robots" / "spot.yaml")
    sensors = []
    for s in rig.sensors:
        if isinstance(s, CameraSensor):
            s = dataclasses.replace(s, camera=s.camera.scaled(0.05),
                                    depth=dataclasses.replace(s.depth, noise_abs_std_m=0.01, noise_rel_std=0.02))
        else:
            s = dataclasses.replace(s, config=dataclasses.replace(s.config, range_noise_std_m=0.03, azimuth_samples=64),
                                    dropout_prob=0.2)
        sensors.append(s)
    return dataclasses.replace(rig, sensors=tuple(sensors))


def test_without_noise_zeroes_only_the_noise():
    from nsim.rendering.shard import _without_noise

    noisy = _noisy_spot()
    clean = _without_noise(noisy)
    assert [s.name for s in clean.sensors] == [s.name for s in noisy.sensors]
    for a, b in zip(noisy.sensors, clean.sensors, strict=True):
        assert np.array_equal(a.sensor_to_body, b.sensor_to_body) and a.ray_shape == b.ray_shape
        if isinstance(a, CameraSensor):
            assert (b.depth.noise_abs_std_m, b.depth.noise_rel_std) == (0.0, 0.0) and not b.depth.noisy
            assert dataclasses.replace(b.depth, noise_abs_std_m=0.01, noise_rel_std=0.02) == a.depth
            assert b.camera == a.camera
        else:
            assert isinstance(b, LidarSensor) and (b.config.range_noise_std_m, b.dropout_prob) == (0.0, 0.0)
            assert dataclasses.replace(b.config, range_noise_std_m=0.03) == a.config
            assert np.array_equal(a.elevations_deg, b.elevations_deg)
    assert noisy.sensors[0].depth.noisy  # the input is not changed


def test_noise_off_measurement_matches_a_plain_twin():
    from nsim.rendering.shard import _without_noise

    noisy = _noisy_spot()
    clean = _without_noise(noisy)
    rng = np.random.default_rng(0)
    cam, cam_noisy = clean.sensors[0], noisy.sensors[0]
    h, w = cam.ray_shape
    r = rng.uniform(0.0, 12.0, (h, w)).astype(np.float32)
    r[0, :3] = np.inf
    depth = cam.measure_depth(r)  # no generator needed
    twin = apply_depth_model(cam.depth_from_range(r),
                             dataclasses.replace(cam_noisy.depth, noise_abs_std_m=0.0, noise_rel_std=0.0))
    assert np.array_equal(depth, twin, equal_nan=True)
    finite = np.isfinite(depth)
    assert np.allclose(depth[finite] / 0.001, np.round(depth[finite] / 0.001), atol=1e-3)  # millimetre steps stay
    assert np.isnan(depth).any() and np.isinf(depth).any()  # the valid range stays: < 0.2 m NaN, > 10 m inf

    lidar = clean.sensors[-1]
    c, a = lidar.ray_shape
    exact = rng.uniform(0.0, 120.0, (c, a)).astype(np.float32)
    exact[0, :5] = np.inf
    ranges = lidar.measure(exact)
    lo, hi = lidar.config.min_range_m, lidar.config.max_range_m
    gate = np.isfinite(exact) & (exact >= lo) & (exact <= hi)
    assert ranges.dtype == np.float32 and np.array_equal(ranges, np.where(gate, exact, np.inf).astype(np.float32))
    assert gate.sum() < gate.size  # some returns gated away
