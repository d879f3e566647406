"""LiDAR configuration and beam geometry (the paper's direction formula)."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.sensors.lidar import LidarConfig, beam_azimuths_rad, beam_directions, beam_elevations_deg


def test_defaults_are_the_papers_sensor():
    cfg = LidarConfig()
    assert (cfg.channels, cfg.vertical_fov_deg, cfg.azimuth_samples) == (16, (-15.0, 15.0), 1800)
    assert beam_directions(cfg).shape == (16, 1800, 3)


def test_directions_are_unit_and_follow_the_formula():
    cfg = LidarConfig(channels=5, vertical_fov_deg=(-20.0, 10.0), azimuth_samples=12)
    d = beam_directions(cfg)
    assert d.shape == (5, 12, 3) and d.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    theta, phi = np.radians(30.0 * 4), np.radians(90.0 - (-20.0 + 7.5 * 2))  # column 4, channel 2
    np.testing.assert_allclose(d[2, 4], [np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])
    np.testing.assert_allclose(d[0, 0], [np.cos(np.radians(20.0)), 0.0, -np.sin(np.radians(20.0))], atol=1e-12)
    np.testing.assert_allclose(d[0, 3, :2], [0.0, np.cos(np.radians(20.0))], atol=1e-12)  # 90 deg: +y, left


def test_elevations_evenly_spread_over_the_fov():
    cfg = LidarConfig(channels=16)
    elevations = np.degrees(np.arcsin(beam_directions(cfg)[..., 2]))
    np.testing.assert_allclose(elevations, np.broadcast_to(np.linspace(-15, 15, 16)[:, None], (16, 1800)), atol=1e-9)
    np.testing.assert_allclose(np.diff(beam_elevations_deg(cfg)), 2.0)


def test_azimuth_steps_are_two_pi_over_n():
    for n in (1, 7, 1800):
        cfg = LidarConfig(azimuth_samples=n)
        d = beam_directions(cfg)
        theta = np.unwrap(np.arctan2(d[3, :, 1], d[3, :, 0]))
        np.testing.assert_allclose(theta, 2 * np.pi * np.arange(n) / n, atol=1e-9)
        np.testing.assert_allclose(beam_azimuths_rad(cfg), 2 * np.pi * np.arange(n) / n)


def test_single_channel():
    cfg = LidarConfig(channels=1, vertical_fov_deg=(0.0, 0.0), azimuth_samples=4)
    np.testing.assert_allclose(beam_directions(cfg)[0], [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"channels": 0}, "channels"),
        ({"channels": 2.0}, "channels"),
        ({"azimuth_samples": 0}, "azimuth_samples"),
        ({"vertical_fov_deg": (15.0, -15.0)}, "vertical_fov_deg"),
        ({"vertical_fov_deg": (-95.0, 15.0)}, "vertical_fov_deg"),
        ({"vertical_fov_deg": (5.0, 5.0)}, "vertical_fov_deg"),
        ({"channels": 1}, "vertical_fov_deg"),
        ({"vertical_fov_deg": (0.0,)}, "vertical_fov_deg"),
        ({"min_range_m": -1.0}, "min_range_m"),
        ({"max_range_m": 0.05}, "max_range_m"),
        ({"range_noise_std_m": -0.1}, "range_noise_std_m"),
    ],
)
def test_validation(kwargs, field):
    with pytest.raises(ValueError, match=f"LidarConfig.{field}"):
        LidarConfig(**kwargs)


def test_lists_become_tuples():
    cfg = LidarConfig(vertical_fov_deg=[-10, 10])
    assert cfg.vertical_fov_deg == (-10.0, 10.0) and hash(cfg)
