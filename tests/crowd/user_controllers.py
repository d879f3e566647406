"""User controller classes for the tests and for ``nsim/configs/scenarios/sweeps/spot_run_controllers.yaml``.

``nsim.crowd.controllers`` documents the protocol: ``Class(**params)``, then
``command(observation) -> (vx_mps, vy_mps, yaw_rate_radps)`` in the body frame each tick.
"""

from __future__ import annotations

import math

import numpy as np


class GoalSeeker:
    """Straight to the current goal at ``speed_mps``, slowing down within a metre of a final goal,
    stopping (and only turning) when a person is closer than ``stop_gap_m`` ahead; faces its goal."""

    def __init__(self, speed_mps: float = 1.0, stop_gap_m: float = 0.6):
        self.speed_mps = speed_mps
        self.stop_gap_m = stop_gap_m

    def command(self, obs):
        to_goal = obs.goal_m - obs.position_m
        dist = float(np.hypot(*to_goal))
        speed = self.speed_mps if not obs.final_goal else min(self.speed_mps, dist)
        v = to_goal / max(dist, 1e-9) * speed if dist > 1e-3 else np.zeros(2)
        if len(obs.people_position_m):
            offset = obs.people_position_m - obs.position_m
            gap = np.hypot(offset[:, 0], offset[:, 1]) - obs.people_radius_m - obs.robot_radius_m - obs.robot_half_length_m
            ahead = offset @ v > 0
            if np.any(ahead & (gap < self.stop_gap_m)):
                v = np.zeros(2)
        c, s = math.cos(obs.heading_rad), math.sin(obs.heading_rad)
        turn = math.atan2(to_goal[1], to_goal[0]) - obs.heading_rad if dist > 0.05 else 0.0
        turn = (turn + math.pi) % (2 * math.pi) - math.pi
        return (c * v[0] + s * v[1], -s * v[0] + c * v[1], 2.0 * turn)


class Recorder:
    """Asks for ``command`` every tick and keeps every observation it was given."""

    def __init__(self, command=(0.0, 0.0, 0.0)):
        self.fixed = tuple(command)
        self.seen = []
        RECORDERS.append(self)

    def command(self, obs):
        self.seen.append(obs)
        return self.fixed


RECORDERS: list[Recorder] = []


class NoCommand:
    """A class without ``command``."""

    def act(self, obs):
        return (0.0, 0.0, 0.0)


class WrongShape:
    def command(self, obs):
        return (0.5, 0.0)


class NotFinite:
    def command(self, obs):
        return (float("nan"), 0.0, 0.0) if obs.time_s > 0.2 else (0.0, 0.0, 0.0)


class Looker:
    """Asks for the ``front`` camera whenever a frame is offered, and stands still."""

    def __init__(self):
        self.frames = []
        RECORDERS.append(self)

    def command(self, obs):
        if obs.render_sensor is not None:
            self.frames.append((obs.time_s, obs.render_sensor("front")))
        return (0.2, 0.0, 0.0)
