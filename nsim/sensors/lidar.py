"""Spinning multi-beam LiDAR: configuration and beam geometry.

The LiDAR frame is x forward, y left, z up (FLU); ``lidar_to_world (4, 4)`` maps it to the
world. A scan is a range image ``(channels, azimuth_samples)``: row ``c`` is the beam at
elevation ``beam_elevations_deg(cfg)[c]`` (rows in *ascending* elevation, row 0 lowest),
column ``a`` the azimuth ``theta_a = 2 pi a / azimuth_samples`` measured from +x towards +y
(counter-clockwise seen from above). Directions follow the paper's formula

    d = (cos(theta) sin(phi), sin(theta) sin(phi), cos(phi)),   phi = 90 deg - elevation,

with the beams spread evenly over the vertical field of view.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LidarConfig:
    """A spinning LiDAR (defaults: the paper's 16-beam, -15..15 deg sensor).

    channels: number of beams (rows of the range image), >= 1.
    vertical_fov_deg: (lowest, highest) beam elevation in degrees, within [-90, 90];
        lowest < highest when channels > 1, equal when channels == 1.
    azimuth_samples: rays per revolution (columns), >= 1; step 2 pi / azimuth_samples.
    min_range_m, max_range_m: returns outside [min, max] are dropped (range = inf).
    range_noise_std_m: std of additive Gaussian range noise (0: exact ranges).
    """

    channels: int = 16
    vertical_fov_deg: tuple[float, float] = (-15.0, 15.0)
    azimuth_samples: int = 1800
    min_range_m: float = 0.1
    max_range_m: float = 100.0
    range_noise_std_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("channels", "azimuth_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"LidarConfig.{name}: expected int >= 1, got {value!r}")
        fov = tuple(self.vertical_fov_deg)
        if len(fov) != 2 or not all(isinstance(v, numbers.Real) and math.isfinite(v) for v in fov):
            raise ValueError(f"LidarConfig.vertical_fov_deg: expected (low, high) finite degrees, got {fov!r}")
        low, high = float(fov[0]), float(fov[1])
        if not (-90.0 <= low <= high <= 90.0):
            raise ValueError(f"LidarConfig.vertical_fov_deg: expected -90 <= low <= high <= 90, got {fov!r}")
        if self.channels > 1 and low == high:
            raise ValueError(f"LidarConfig.vertical_fov_deg: {self.channels} channels need low < high, got {fov!r}")
        if self.channels == 1 and low != high:
            raise ValueError(f"LidarConfig.vertical_fov_deg: a single channel needs low == high, got {fov!r}")
        object.__setattr__(self, "vertical_fov_deg", (low, high))
        if not (math.isfinite(self.min_range_m) and self.min_range_m >= 0.0):
            raise ValueError(f"LidarConfig.min_range_m: expected finite float >= 0, got {self.min_range_m!r}")
        if not (self.max_range_m > self.min_range_m):  # inf allowed: no range limit
            raise ValueError(
                f"LidarConfig.max_range_m: expected > min_range_m ({self.min_range_m}), got {self.max_range_m!r}"
            )
        if not (math.isfinite(self.range_noise_std_m) and self.range_noise_std_m >= 0.0):
            raise ValueError(f"LidarConfig.range_noise_std_m: expected finite float >= 0, got {self.range_noise_std_m!r}")


def beam_elevations_deg(cfg: LidarConfig) -> np.ndarray:
    """Elevation of each channel in degrees, ascending: ``(channels,)`` float64."""
    low, high = cfg.vertical_fov_deg
    return np.linspace(low, high, cfg.channels, dtype=np.float64)


def beam_azimuths_rad(cfg: LidarConfig) -> np.ndarray:
    """Azimuth ``theta`` of each column, ``2 pi a / azimuth_samples``: ``(azimuth_samples,)``."""
    return 2.0 * np.pi * np.arange(cfg.azimuth_samples, dtype=np.float64) / cfg.azimuth_samples


def beam_directions(cfg: LidarConfig) -> np.ndarray:
    """Unit beam directions in the LiDAR frame (x fwd, y left, z up): ``(channels, azimuth_samples, 3)``.

    ``d = (cos(theta) sin(phi), sin(theta) sin(phi), cos(phi))`` with polar angle
    ``phi = 90 deg - elevation``. float64.
    """
    phi = np.radians(90.0 - beam_elevations_deg(cfg))[:, None]  # (C, 1)
    theta = beam_azimuths_rad(cfg)[None, :]  # (1, A)
    sin_phi = np.sin(phi)
    return np.stack(
        np.broadcast_arrays(np.cos(theta) * sin_phi, np.sin(theta) * sin_phi, np.cos(phi)), axis=-1
    )
