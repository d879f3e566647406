"""Spinning multi-beam LiDAR: configuration and the one beam pattern.

The LiDAR frame is x forward, y left, z up (FLU); ``lidar_to_world (4, 4)`` maps it to the
world. A scan is a range image ``(channels, azimuth_samples)``: row ``c`` is the beam at
elevation ``BeamPattern.elevations_deg[c]`` (rows in *ascending* elevation, row 0 lowest),
column ``a`` the azimuth ``theta_a = 2 pi a / azimuth_samples`` measured from +x towards +y
(counter-clockwise seen from above). Directions follow the paper's formula

    d = (cos(theta) sin(phi), sin(theta) sin(phi), cos(phi)),   phi = 90 deg - elevation.

:class:`BeamPattern` is the one place beams are made: from a :class:`LidarConfig` (beams spread
evenly over the vertical field of view, ``LidarConfig.beams``) or from explicit elevations
(``BeamPattern.from_angles``, a rig's ``vertical_angles_deg``). A rig's LiDAR
(``nsim.sensors.rig.LidarSensor``), the renderer (``nsim.rendering.renderer.render_lidar``) and
the oracle (``nsim.synth.oracle.RoomOracle.lidar_gt``) all take their beams from it
(:func:`beams_and_config`), so a simulated scan and its ground truth cannot use different beams.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from nsim.config import param


@dataclass(frozen=True)
class BeamPattern:
    """Where a spinning LiDAR's beams point (module docstring).

    elevations_deg: ``(C,)`` beam elevations in degrees, strictly ascending (row ``c`` = ring ``c``,
        row 0 lowest), finite, within [-90, 90], at least one.
    azimuth_samples: columns per revolution, >= 1; column ``a`` at ``2 pi a / azimuth_samples``.
    """

    elevations_deg: tuple[float, ...]
    azimuth_samples: int

    def __post_init__(self) -> None:
        a = self.azimuth_samples
        if isinstance(a, bool) or not isinstance(a, (int, np.integer)) or a < 1:
            raise ValueError(f"BeamPattern.azimuth_samples: expected int >= 1, got {a!r}")
        object.__setattr__(self, "azimuth_samples", int(a))
        el = np.asarray(self.elevations_deg, dtype=np.float64)
        if el.ndim != 1:
            raise ValueError(f"BeamPattern.elevations_deg: expected a list of elevations, got shape {el.shape}")
        if el.size == 0:
            raise ValueError("BeamPattern.elevations_deg: a LiDAR needs at least one beam, got none")
        if not np.all(np.isfinite(el)) or np.any(np.abs(el) > 90.0):
            raise ValueError("BeamPattern.elevations_deg: expected finite elevations within [-90, 90]")
        if np.any(np.diff(el) <= 0.0):
            raise ValueError("BeamPattern.elevations_deg: expected strictly ascending elevations (distinct, row 0 lowest)")
        object.__setattr__(self, "elevations_deg", tuple(el.tolist()))

    @classmethod
    def even(cls, channels: int, vertical_fov_deg: tuple[float, float], azimuth_samples: int) -> BeamPattern:
        """``channels`` beams spread evenly over ``vertical_fov_deg = (lowest, highest)`` (both included)."""
        low, high = vertical_fov_deg
        return cls(tuple(np.linspace(low, high, channels, dtype=np.float64).tolist()), azimuth_samples)

    @classmethod
    def from_angles(cls, elevations_deg, azimuth_samples: int) -> BeamPattern:
        """Beams at explicit elevations ``(C,)`` in any order (sorted ascending into rows; distinct)."""
        el = np.asarray(elevations_deg, dtype=np.float64)
        if el.ndim != 1:
            raise ValueError(f"BeamPattern.elevations_deg: expected a list of elevations, got shape {el.shape}")
        el = np.sort(el)
        if np.any(np.diff(el) == 0.0):
            raise ValueError("BeamPattern.elevations_deg: elevations must be distinct")
        return cls(tuple(el.tolist()), azimuth_samples)

    @property
    def channels(self) -> int:
        return len(self.elevations_deg)

    @property
    def shape(self) -> tuple[int, int]:
        """The range image's shape, ``(channels, azimuth_samples)``."""
        return (len(self.elevations_deg), self.azimuth_samples)

    @property
    def azimuths_rad(self) -> np.ndarray:
        """Azimuth ``theta`` of each column, ``2 pi a / azimuth_samples``: ``(azimuth_samples,)`` float64."""
        return 2.0 * np.pi * np.arange(self.azimuth_samples, dtype=np.float64) / self.azimuth_samples

    def directions(self) -> np.ndarray:
        """Unit beam directions in the LiDAR frame (x fwd, y left, z up): ``(channels, azimuth_samples, 3)``
        float64, ``d = (cos(theta) sin(phi), sin(theta) sin(phi), cos(phi))``, ``phi = 90 deg - elevation``.
        """
        phi = np.radians(90.0 - np.asarray(self.elevations_deg, dtype=np.float64))[:, None]  # (C, 1)
        theta = self.azimuths_rad[None, :]  # (1, A)
        sin_phi = np.sin(phi)
        return np.stack(
            np.broadcast_arrays(np.cos(theta) * sin_phi, np.sin(theta) * sin_phi, np.cos(phi)), axis=-1
        )


@dataclass(frozen=True)
class LidarConfig:
    """A spinning LiDAR with evenly spread beams (defaults: the paper's 16-beam, -15..15 deg sensor).

    channels: number of beams (rows of the range image), >= 1.
    vertical_fov_deg: (lowest, highest) beam elevation in degrees, within [-90, 90];
        lowest < highest when channels > 1, equal when channels == 1.
    azimuth_samples: rays per revolution (columns), >= 1; step 2 pi / azimuth_samples.
    min_range_m, max_range_m: returns outside [min, max] are dropped (range = inf).
    range_noise_std_m: std of additive Gaussian range noise (0: exact ranges).

    These are the only defaults of a LiDAR: a rig's ``lidar`` block (``nsim.sensors.rig.LidarSpec``)
    extends this class.
    """

    channels: int = param(16, ge=1)
    vertical_fov_deg: tuple[float, float] = (-15.0, 15.0)
    azimuth_samples: int = param(1800, ge=1)
    min_range_m: float = param(0.1, ge=0.0)
    max_range_m: float = param(100.0, gt=0.0)
    range_noise_std_m: float = param(0.0, ge=0.0)

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

    @property
    def beams(self) -> BeamPattern:
        """The beam pattern: ``channels`` beams evenly over ``vertical_fov_deg``."""
        return BeamPattern.even(self.channels, self.vertical_fov_deg, self.azimuth_samples)


def beams_and_config(lidar: Any) -> tuple[BeamPattern, LidarConfig]:
    """The beams and range settings of ``lidar``: a :class:`LidarConfig` (its ``beams``) or a rig's
    LiDAR (``nsim.sensors.rig.LidarSensor``: anything with a ``beams`` pattern and a ``config``), whose
    beams may be explicit elevations. What the renderer and the oracle scan with."""
    if isinstance(lidar, LidarConfig):
        return lidar.beams, lidar
    beams, cfg = getattr(lidar, "beams", None), getattr(lidar, "config", None)
    if isinstance(beams, BeamPattern) and isinstance(cfg, LidarConfig):
        return beams, cfg
    raise TypeError(f"expected a LidarConfig or a rig's LidarSensor, got {type(lidar).__name__}")


def beam_elevations_deg(lidar: Any) -> np.ndarray:
    """Elevation of each channel in degrees, ascending: ``(channels,)`` float64 (``BeamPattern.elevations_deg``)."""
    return np.asarray(beams_and_config(lidar)[0].elevations_deg, dtype=np.float64)


def beam_azimuths_rad(lidar: Any) -> np.ndarray:
    """Azimuth ``theta`` of each column, ``2 pi a / azimuth_samples``: ``(azimuth_samples,)`` (``BeamPattern.azimuths_rad``)."""
    return beams_and_config(lidar)[0].azimuths_rad


def beam_directions(lidar: Any) -> np.ndarray:
    """Unit beam directions in the LiDAR frame: ``(channels, azimuth_samples, 3)`` float64 (``BeamPattern.directions``)."""
    return beams_and_config(lidar)[0].directions()
