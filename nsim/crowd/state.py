"""The robot as the crowd sees it: ``RobotState``, shared by ``social_force`` and ``behaviours``."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class RobotState:
    """The robot at one tick, as the humans perceive it: a capsule on the floor.

    position_m: (2,) centre; velocity_mps: (2,); heading_rad: yaw about +z from +x.
    The body is the segment ``position_m +- half_length_m * (cos, sin)(heading_rad)`` grown by
    ``radius_m`` (Spot: about 1.1 x 0.5 m -> half_length_m 0.3, radius_m 0.28).
    """

    position_m: np.ndarray
    velocity_mps: np.ndarray
    heading_rad: float
    radius_m: float
    half_length_m: float = 0.0

    def body_segment_m(self) -> np.ndarray:
        """End points ``(2, 2)`` of the body's axis (a single point when ``half_length_m`` is 0)."""
        u = np.array([math.cos(self.heading_rad), math.sin(self.heading_rad)])
        c = np.asarray(self.position_m, dtype=np.float64)
        return np.stack([c - self.half_length_m * u, c + self.half_length_m * u])

    def advanced(self, dt_s: float) -> RobotState:
        """The robot ``dt_s`` later at constant velocity and heading (its pose at the end of a step)."""
        moved = np.asarray(self.position_m, dtype=np.float64) + dt_s * np.asarray(self.velocity_mps, dtype=np.float64)
        return replace(self, position_m=moved)
