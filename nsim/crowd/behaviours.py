"""Human reactions to the robot, as HuNavSim defines them.

Each human has one behaviour (``Behaviour``, codes as HuNavSim's ``hunav_msgs/AgentBehavior``)
and a small state machine (``behaviour_state``):

``NAVIGATING`` (0)
    Walking its goals. The robot becomes *detected* when its body is within
    ``detection_distance_m`` (human centre to robot surface), inside the human's field of view
    (``field_of_view_deg`` about the heading, HuNavSim's ``lineOfSight``) and, with
    ``line_of_sight``, not hidden behind a wall. Detection moves the human to ``REACTING``.
``REACTING`` (1)
    The behaviour's change of forces or goals applies (below). It lasts while the robot stays
    within the detection distance (field of view no longer needed: the human knows where it is);
    the timed behaviours (surprised, curious, threatening) end after their duration, -> ``DONE``.
    Robot out of range -> ``NAVIGATING``.
``DONE`` (2)
    Back to the goals; re-armed (-> ``NAVIGATING``) once the robot leaves the detection distance.

What ``REACTING`` changes, per behaviour (robot force = the force the robot exerts on the human):

* regular: nothing; the robot is "another human" all along (agent force law).
* impassive: nothing; the robot is a static obstacle all along (obstacle force law).
* surprised: stops (desired speed 0) and turns to look at the robot for ``surprised_duration_s``.
* scared: an extra, longer-range repulsion from the robot (``scared_repulsion``) and the desired
  velocity times ``scared_speed_factor`` (HuNavSim's ``avoidRobot`` lowers the desired speed);
  a human standing at its goal then also holds its spot less firmly and backs away further.
* curious: leaves its goal and walks at ``curious_speed_mps`` towards the robot, stopping
  ``curious_stop_distance_m`` from its body and looking at it, for ``curious_duration_s``
  (HuNavSim's ``approximateRobot``).
* threatening: walks at ``threatening_speed_mps`` to a point ``threatening_front_distance_m``
  in front of the robot's body to block its way, facing it, for ``threatening_duration_s``
  (HuNavSim's ``blockRobot``).

Curious and threatening humans mean to get close: while reacting, the robot repels them with the
short-range wall law (physical avoidance) instead of the agent law (personal space).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from nsim.config import param
from nsim.crowd.neighbours import segments_intersect
from nsim.crowd.state import RobotState


class Behaviour(enum.IntEnum):
    """Behaviour codes, numbered as HuNavSim's ``AgentBehavior.BEH_*``."""

    REGULAR = 1
    IMPASSIVE = 2
    SURPRISED = 3
    SCARED = 4
    CURIOUS = 5
    THREATENING = 6


BEHAVIOUR_NAMES = tuple(b.name.lower() for b in Behaviour)

NAVIGATING = 0
REACTING = 1
DONE = 2

ROBOT_AS_AGENT = 0
ROBOT_AS_OBSTACLE = 1


def behaviour_codes(names: Sequence[str]) -> np.ndarray:
    """Behaviour names (``"regular"``, ...) -> codes ``(N,)`` int8; ``ValueError`` names the bad one."""
    out = np.empty(len(names), dtype=np.int8)
    for k, name in enumerate(names):
        try:
            out[k] = Behaviour[str(name).upper()]
        except KeyError:
            raise ValueError(f"behaviour {name!r} is not one of {', '.join(BEHAVIOUR_NAMES)}") from None
    return out


@dataclass(frozen=True)
class BehaviourParams:
    """How humans perceive and react to the robot (see the module docstring)."""

    detection_distance_m: float = param(
        4.0, gt=0, help="robot body within this distance of a human's centre is detected"
    )
    field_of_view_deg: float = param(
        200.0, gt=0, le=360, help="full angle, about the heading, in which the robot is seen"
    )
    line_of_sight: bool = param(True, help="walls hide the robot (segment test against the map)")
    surprised_duration_s: float = param(3.0, ge=0, help="how long a surprised human stands and looks")
    scared_strength_mps2: float = param(6.0, ge=0, help="extra robot repulsion of a scared human at contact")
    scared_range_m: float = param(1.5, gt=0, help="decay length of the extra repulsion")
    scared_speed_factor: float = param(
        0.6, gt=0, help="desired-velocity multiplier while scared (walking and holding a spot)"
    )
    curious_speed_mps: float = param(0.6, gt=0, help="speed of a curious human's approach")
    curious_stop_distance_m: float = param(
        1.0, gt=0, help="curious humans stop this far from the robot's body"
    )
    curious_duration_s: float = param(10.0, ge=0, help="how long a curious human keeps approaching / looking")
    threatening_speed_mps: float = param(
        1.6, gt=0, help="speed of a threatening human going to block the robot"
    )
    threatening_front_distance_m: float = param(0.8, gt=0, help="blocking point, ahead of the robot's body")
    threatening_duration_s: float = param(10.0, ge=0, help="how long a threatening human keeps blocking")


class RobotView(NamedTuple):
    """The robot as each human sees it: nearest point of its body ``(N, 2)`` and distances ``(N,)``.

    surface_distance_m is from the human's centre to the robot's surface (body segment grown by
    the robot's radius); negative when the centre is inside the robot.
    """

    closest_m: np.ndarray
    surface_distance_m: np.ndarray


class Reaction(NamedTuple):
    """What the behaviours change this tick, per human (all ``(N,)`` unless noted).

    override: the human follows ``target_m (N, 2)`` at ``target_speed_mps``, stopping
    ``stop_distance_m`` short of it (slowing down over the arrival distance), instead of its goals.
    speed_factor: multiplies the desired velocity.
    look_at_robot: turn the head (heading) towards the robot.
    robot_law: ROBOT_AS_AGENT or ROBOT_AS_OBSTACLE. scared: add ``scared_repulsion``.
    """

    override: np.ndarray
    target_m: np.ndarray
    target_speed_mps: np.ndarray
    stop_distance_m: np.ndarray
    speed_factor: np.ndarray
    look_at_robot: np.ndarray
    robot_law: np.ndarray
    scared: np.ndarray


def robot_detected(
    position_m: np.ndarray,
    heading_rad: np.ndarray,
    view: RobotView,
    segments_m: np.ndarray,
    params: BehaviourParams,
) -> np.ndarray:
    """Whether each human detects the robot now: ``(N,)`` bool.

    In range, in the field of view, and (with ``line_of_sight``) not hidden by a wall segment.
    """
    to_robot = view.closest_m - position_m
    bearing = np.arctan2(to_robot[:, 1], to_robot[:, 0]) - heading_rad
    bearing = (bearing + np.pi) % (2.0 * np.pi) - np.pi
    seen = (view.surface_distance_m <= params.detection_distance_m) & (
        np.abs(bearing) <= np.deg2rad(params.field_of_view_deg) / 2.0
    )
    if params.line_of_sight and len(segments_m) and np.any(seen):
        k = np.flatnonzero(seen)
        blocked = segments_intersect(position_m[k], view.closest_m[k], segments_m).any(axis=1)
        seen = seen.copy()
        seen[k[blocked]] = False
    return seen


def _duration_s(behaviour: np.ndarray, params: BehaviourParams) -> np.ndarray:
    """Reaction duration per human: ``inf`` for the untimed behaviours."""
    table = np.full(len(Behaviour) + 1, np.inf)
    table[Behaviour.SURPRISED] = params.surprised_duration_s
    table[Behaviour.CURIOUS] = params.curious_duration_s
    table[Behaviour.THREATENING] = params.threatening_duration_s
    return table[behaviour]


def update_behaviour_states(
    behaviour: np.ndarray,
    state: np.ndarray,
    timer_s: np.ndarray,
    detected: np.ndarray,
    view: RobotView,
    params: BehaviourParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One tick of the state machine: new ``(behaviour_state (N,) int8, behaviour_timer_s (N,))``.

    timer_s is the time spent in the current state; it restarts at 0 on every transition.
    """
    in_range = view.surface_distance_m <= params.detection_distance_m
    expired = timer_s + dt_s >= _duration_s(behaviour, params)
    new = np.where(
        state == NAVIGATING,
        np.where(detected, REACTING, NAVIGATING),
        np.where(~in_range, NAVIGATING, np.where((state == REACTING) & expired, DONE, state)),
    ).astype(np.int8)
    timer = np.where(new == state, timer_s + dt_s, 0.0)
    return new, timer


def behaviour_reactions(
    behaviour: np.ndarray,
    state: np.ndarray,
    position_m: np.ndarray,
    robot: RobotState | None,
    view: RobotView | None,
    params: BehaviourParams,
) -> Reaction:
    """Translate behaviours and states into this tick's ``Reaction`` (no robot: no reaction)."""
    n = len(behaviour)
    reacting = state == REACTING
    robot_law = np.where(behaviour == Behaviour.IMPASSIVE, ROBOT_AS_OBSTACLE, ROBOT_AS_AGENT).astype(np.int8)
    zeros = np.zeros(n)
    if robot is None or view is None or not np.any(reacting):
        return Reaction(
            np.zeros(n, bool),
            np.zeros((n, 2)),
            zeros,
            zeros,
            np.ones(n),
            np.zeros(n, bool),
            robot_law,
            np.zeros(n, bool),
        )
    surprised = reacting & (behaviour == Behaviour.SURPRISED)
    curious = reacting & (behaviour == Behaviour.CURIOUS)
    threatening = reacting & (behaviour == Behaviour.THREATENING)
    scared = reacting & (behaviour == Behaviour.SCARED)
    # humans who mean to get close keep only the physical (wall-law) avoidance of the robot
    robot_law = np.where(curious | threatening, ROBOT_AS_OBSTACLE, robot_law).astype(np.int8)

    forward = np.array([np.cos(robot.heading_rad), np.sin(robot.heading_rad)])
    reach_m = robot.half_length_m + robot.radius_m + params.threatening_front_distance_m
    block_point = np.asarray(robot.position_m, dtype=np.float64) + reach_m * forward
    target = np.where(
        curious[:, None], view.closest_m, np.where(threatening[:, None], block_point, position_m)
    )
    speed = np.select([curious, threatening], [params.curious_speed_mps, params.threatening_speed_mps], 0.0)
    # curious humans aim at the nearest body point and stop short of the robot's *surface*
    stop = np.where(curious, params.curious_stop_distance_m + robot.radius_m, 0.0)
    to_block = block_point - position_m
    near_block = threatening & (np.hypot(to_block[:, 0], to_block[:, 1]) < 0.5)
    near_robot = curious & (view.surface_distance_m <= params.curious_stop_distance_m + 0.25)
    return Reaction(
        override=surprised | curious | threatening,
        target_m=target,
        target_speed_mps=speed,
        stop_distance_m=stop,
        speed_factor=np.where(scared, params.scared_speed_factor, 1.0),
        look_at_robot=surprised | near_robot | near_block,
        robot_law=robot_law,
        scared=scared,
    )


def scared_repulsion(
    position_m: np.ndarray, view: RobotView, scared: np.ndarray, params: BehaviourParams
) -> np.ndarray:
    """Extra repulsion of scared humans from the robot: ``(N, 2)`` m/s².

    ``scared_strength_mps2 * exp(-d / scared_range_m)`` along the direction away from the robot's
    nearest body point, ``d`` the distance to its surface (clamped at 0). HuNavSim's ``avoidRobot``
    uses ``factor * sigma / d``; an exponential keeps the force bounded at contact.
    """
    away = position_m - view.closest_m
    dist = np.hypot(away[:, 0], away[:, 1])
    unit = away / np.maximum(dist, 1e-9)[:, None]
    mag = params.scared_strength_mps2 * np.exp(
        -np.maximum(view.surface_distance_m, 0.0) / params.scared_range_m
    )
    return np.where(scared[:, None], mag[:, None] * unit, 0.0)
