"""A user controller that steers by a rendered depth camera, for ``tests/stages/test_simulate_sensors.py``.

``DepthStopper`` drives forward at ``speed_mps`` and stops for good once the mean valid depth of the
middle third of ``sensor``'s depth image ("ahead") is ``closer_by_m`` less than it was in the first
frame (it has come that much closer to what it faces); it keeps every frame it was given in
``FRAMES`` (the test reads them back).
"""

from __future__ import annotations

import numpy as np

FRAMES: list[dict] = []
"""One entry per rendered frame: ``time_s``, ``position_m``, ``heading_rad``, ``frame``, ``mean_depth_m``."""


class DepthStopper:
    def __init__(self, sensor: str = "rgbd", closer_by_m: float = 0.02, speed_mps: float = 0.5):
        self.sensor = sensor
        self.closer_by_m = closer_by_m
        self.first_depth_m: float | None = None
        self.speed_mps = speed_mps
        self.stopped = False

    def command(self, obs):
        if obs.render_sensor is not None:
            frame = obs.render_sensor(self.sensor)
            h, w = frame["depth"].shape
            ahead = frame["depth"][h // 3 : 2 * h // 3, w // 3 : 2 * w // 3]
            ahead = ahead[np.isfinite(ahead)]
            mean = float(ahead.mean()) if ahead.size else float("inf")
            FRAMES.append({"time_s": obs.time_s, "position_m": np.array(obs.position_m),
                           "heading_rad": obs.heading_rad, "frame": frame, "mean_depth_m": mean})
            self.first_depth_m = mean if self.first_depth_m is None else self.first_depth_m
            self.stopped = self.stopped or mean < self.first_depth_m - self.closer_by_m
        return (0.0 if self.stopped else self.speed_mps, 0.0, 0.0)
