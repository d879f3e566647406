"""Human reactions to the robot: HuNavSim's six behaviours, in two profiles.

Each human has one behaviour (``Behaviour``, codes as HuNavSim's ``hunav_msgs/AgentBehavior``)
and a small state machine (``behaviour_state``: ``NAVIGATING`` 0, ``REACTING`` 1, ``DONE`` 2) with
a clock (``behaviour_timer_s``). ``BehaviourParams.profile`` picks the rules below and the
default of every number (``PROFILES``; the table in the README lists both):

``hunavsim`` (the default) — HuNavSim's agent manager as its source defines it
(robotics-upo/hunav_sim, MIT: ``hunav_agent_manager/behavior_trees/BT*Nav.xml``,
``src/agent_manager.cpp``, ``src/time_expired_condition.cpp``; the force constants of
robotics-upo/lightsfm ``include/lightsfm/sfm.hpp``, which it uses):

* Every distance is from the human's centre to the robot's *centre*.
* Seeing the robot (``IsRobotVisible``): within the behaviour's detection distance (surprised
  4 m, scared 3 m, curious 10 m, threatening 4 m) and within ``pi/2 + 0.17`` rad of the heading
  (``lineOfSight``: a 199.5 deg field of view). Regular and impassive humans have no such
  condition: they never react (``regular_detection_distance_m`` 0).
* A human reacts on every tick it sees the robot, and only then (the trees re-check visibility
  each tick). Its clock counts the time it has reacted over the whole run (the
  ``TimeExpiredCondition`` accumulates only on ticks it is evaluated): surprised 30 s, curious
  30 s and threatening 40 s once per run (``only_once``: then ``DONE`` for good); scared 40 s,
  then one tick off and the clock starts again (``only_once="False"``).
* Surprised, scared, curious and threatening humans leave the robot out of their social force
  at all times, reacting or not (``computeForces``: only regular humans see it as an agent,
  impassive ones as an obstacle); the hard constraint of ``social_force.step`` still keeps the
  bodies apart.
* surprised (``lookAtTheRobot``): stands still (HuNavSim skips the position update) and turns
  towards the robot.
* scared (``avoidRobot``): desired speed 0.6 m/s (``scared_max_speed_mps``; also its speed cap,
  as lightsfm caps the speed at the desired one) and an extra repulsion ``A B / d`` from the
  robot's centre, ``d`` the centre distance less the human's radius (HuNavSim's
  ``20 * forceSigmaObstacle / d`` with lightsfm's ``forceSigmaObstacle = 0.2``: ``4 / d``).
* curious (``approximateRobot``): walks to the robot's centre at ``1.8 d / 10`` m/s (``d`` the
  centre distance, 10 m HuNavSim's ``max_dist_view_``); within 1.5 m stands still and faces it.
* threatening (``blockRobot``): walks at 2 m/s to a point 1.1 m ahead of the robot's centre;
  within 1.2 m of the robot it faces it. HuNavSim writes that point as ``(x + 1.1 sin h,
  y + 1.1 cos h)``, which lies *beside* the robot (h = 0 gives a point to its left); nsim keeps
  the point its code means, ahead along the heading ``(cos h, sin h)``.
* Not modelled: HuNavSim checks no walls between human and robot (``lineOfSight`` leaves the
  ray-trace as a TODO); both profiles hide the robot behind walls unless ``line_of_sight`` is
  false. Its heading snaps (curious, threatening) or turns at pi rad per 0.01 s tick
  (surprised); nsim turns at ``ForceParams.max_turn_rate_dps``.

``nsim`` — nsim's earlier tuning, kept as it was:

* Every distance is from the human's centre to the robot's body *surface* (its capsule).
* Detection within 4 m for every behaviour (regular and impassive humans too, which only mark
  it: ``behaviour_state`` 1, no change of motion), 200 deg field of view. Once reacting, the
  reaction lasts while the robot stays within the detection distance (the human knows where it
  is: no field of view needed); surprised 3 s, curious and threatening 10 s, scared untimed.
  Then ``DONE``, re-armed once the robot leaves the detection distance; the clock is the time in
  the current state.
* The robot is an agent in everyone's social force (impassive: an obstacle); curious and
  threatening humans, who mean to get close, see it as an obstacle while reacting.
* surprised: desired speed 0 (slows down) and looks at the robot. scared: desired velocity x0.6
  and an extra ``A exp(-d / B)`` from the robot's nearest body point (``d`` to its surface).
  curious: 0.6 m/s towards the robot's nearest body point, stopping 1.0 m from its surface.
  threatening: 1.6 m/s to a point 0.8 m ahead of its body's front; faces the robot within
  0.5 m of that point.

``PROFILES`` holds both tables; any number set in the config overrides its profile's value
(``null``: the profile's). The profile chooses rules as well as numbers, so it lives in code,
not as preset files.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from nsim.config import check_params, param
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
ROBOT_IGNORED = 2

HUNAVSIM_MAX_VIEW_M = 10.0
"""HuNavSim's ``max_dist_view_``: a curious human approaches at ``curious_speed_mps * d / 10``."""

SCARED_MIN_DISTANCE_M = 0.1
"""The hunavsim scared repulsion ``A B / d`` uses ``max(d, this)``: bounded (and never reversed)
where HuNavSim's would blow up, i.e. only when bodies already overlap."""

PROFILES: dict[str, dict[str, float]] = {
    "hunavsim": {
        "field_of_view_deg": 2.0 * (90.0 + math.degrees(0.17)),
        "regular_detection_distance_m": 0.0,
        "surprised_detection_distance_m": 4.0,
        "scared_detection_distance_m": 3.0,
        "curious_detection_distance_m": 10.0,
        "threatening_detection_distance_m": 4.0,
        "surprised_duration_s": 30.0,
        "scared_duration_s": 40.0,
        "curious_duration_s": 30.0,
        "threatening_duration_s": 40.0,
        "scared_strength_mps2": 20.0,
        "scared_range_m": 0.2,
        "scared_speed_factor": 1.0,
        "scared_max_speed_mps": 0.6,
        "curious_speed_mps": 1.8,
        "curious_stop_distance_m": 1.5,
        "threatening_speed_mps": 2.0,
        "threatening_front_distance_m": 1.1,
        "threatening_look_distance_m": 1.2,
    },
    "nsim": {
        "field_of_view_deg": 200.0,
        "regular_detection_distance_m": 4.0,
        "surprised_detection_distance_m": 4.0,
        "scared_detection_distance_m": 4.0,
        "curious_detection_distance_m": 4.0,
        "threatening_detection_distance_m": 4.0,
        "surprised_duration_s": 3.0,
        "scared_duration_s": math.inf,
        "curious_duration_s": 10.0,
        "threatening_duration_s": 10.0,
        "scared_strength_mps2": 6.0,
        "scared_range_m": 1.5,
        "scared_speed_factor": 0.6,
        "scared_max_speed_mps": math.inf,
        "curious_speed_mps": 0.6,
        "curious_stop_distance_m": 1.0,
        "threatening_speed_mps": 1.6,
        "threatening_front_distance_m": 0.8,
        "threatening_look_distance_m": 0.5,
    },
}
"""Each profile's value of every number of ``BehaviourParams`` (see the module docstring)."""


def behaviour_codes(names: Sequence[str]) -> np.ndarray:
    """Behaviour names (``"regular"``, ...) -> codes ``(N,)`` int8; ``ValueError`` names the bad one."""
    out = np.empty(len(names), dtype=np.int8)
    for k, name in enumerate(names):
        try:
            out[k] = Behaviour[str(name).upper()]
        except KeyError:
            raise ValueError(f"behaviour {name!r} is not one of {', '.join(BEHAVIOUR_NAMES)}") from None
    return out


_PROFILE_VALUE = " (null: the profile's)"


@dataclass(frozen=True)
class BehaviourParams:
    """How humans perceive and react to the robot (see the module docstring).

    ``profile`` picks the rules and the default of every number; a number left ``None`` takes the
    profile's value (``resolved()`` fills them in). Distances are to the robot's centre under
    ``hunavsim`` and to its body's surface under ``nsim``.
    """

    profile: str = param(
        "hunavsim", choices=tuple(PROFILES), help="hunavsim: HuNavSim's rules and numbers; nsim: nsim's tuning"
    )
    field_of_view_deg: float | None = param(
        None, gt=0, le=360, help="full angle, about the heading, in which the robot is seen" + _PROFILE_VALUE
    )
    line_of_sight: bool = param(True, help="walls hide the robot (segment test against the map)")
    regular_detection_distance_m: float | None = param(
        None, ge=0, help="regular and impassive humans mark the robot (state 1, no change of motion) "
        "within this; 0: never" + _PROFILE_VALUE
    )
    surprised_detection_distance_m: float | None = param(
        None, gt=0, help="a surprised human sees the robot within this" + _PROFILE_VALUE
    )
    scared_detection_distance_m: float | None = param(
        None, gt=0, help="a scared human sees the robot within this" + _PROFILE_VALUE
    )
    curious_detection_distance_m: float | None = param(
        None, gt=0, help="a curious human sees the robot within this" + _PROFILE_VALUE
    )
    threatening_detection_distance_m: float | None = param(
        None, gt=0, help="a threatening human sees the robot within this" + _PROFILE_VALUE
    )
    surprised_duration_s: float | None = param(
        None, ge=0, help="how long a surprised human stands and looks" + _PROFILE_VALUE
    )
    scared_duration_s: float | None = param(
        None, gt=0, help="scared reaction time before a one-tick pause (hunavsim) / untimed: inf (nsim)"
        + _PROFILE_VALUE
    )
    curious_duration_s: float | None = param(
        None, ge=0, help="how long a curious human keeps approaching / looking" + _PROFILE_VALUE
    )
    threatening_duration_s: float | None = param(
        None, ge=0, help="how long a threatening human keeps blocking" + _PROFILE_VALUE
    )
    scared_strength_mps2: float | None = param(
        None, ge=0, help="A of the extra robot repulsion of a scared human" + _PROFILE_VALUE
    )
    scared_range_m: float | None = param(
        None, gt=0, help="B of the extra repulsion: A B / d (hunavsim), A exp(-d / B) (nsim)" + _PROFILE_VALUE
    )
    scared_speed_factor: float | None = param(
        None, gt=0, help="desired-velocity multiplier while scared" + _PROFILE_VALUE
    )
    scared_max_speed_mps: float | None = param(
        None, gt=0, help="desired speed and speed cap of a scared human at most this" + _PROFILE_VALUE
    )
    curious_speed_mps: float | None = param(
        None, gt=0, help="a curious human's approach speed (hunavsim: at 10 m, proportional to the distance)"
        + _PROFILE_VALUE
    )
    curious_stop_distance_m: float | None = param(
        None, gt=0, help="curious humans stop this far from the robot" + _PROFILE_VALUE
    )
    threatening_speed_mps: float | None = param(
        None, gt=0, help="speed of a threatening human going to block the robot" + _PROFILE_VALUE
    )
    threatening_front_distance_m: float | None = param(
        None, gt=0, help="blocking point, ahead of the robot's centre (hunavsim) / front (nsim)" + _PROFILE_VALUE
    )
    threatening_look_distance_m: float | None = param(
        None, gt=0, help="a threatening human faces the robot within this of it (hunavsim) / of the "
        "blocking point (nsim)" + _PROFILE_VALUE
    )

    def __post_init__(self) -> None:
        check_params(self)  # the loader checks loaded values; this, values set from Python

    @property
    def hunavsim(self) -> bool:
        """Whether the HuNavSim rules apply."""
        return self.profile == "hunavsim"

    def resolved(self) -> BehaviourParams:
        """These parameters with every ``None`` replaced by the profile's value (``self`` if none is)."""
        return _resolve(self)


@functools.lru_cache(maxsize=64)
def _resolve(params: BehaviourParams) -> BehaviourParams:
    """``BehaviourParams.resolved``, cached: ``step`` asks for it every tick."""
    missing = {k: v for k, v in PROFILES[params.profile].items() if getattr(params, k) is None}
    return dataclasses.replace(params, **missing) if missing else params


class RobotView(NamedTuple):
    """The robot as each human sees it (all ``(N,)`` unless noted).

    closest_m: (N, 2) nearest point of the robot's body axis; surface_distance_m: from the
    human's centre to the robot's surface (body segment grown by the robot's radius), negative
    when the centre is inside the robot; centre_m: (2,) the robot's centre; centre_distance_m:
    from the human's centre to the robot's centre.
    """

    closest_m: np.ndarray
    surface_distance_m: np.ndarray
    centre_m: np.ndarray
    centre_distance_m: np.ndarray


def robot_distance_m(view: RobotView, params: BehaviourParams) -> np.ndarray:
    """The distance the profile's rules use: to the robot's centre (hunavsim) or surface (nsim)."""
    return view.centre_distance_m if params.hunavsim else view.surface_distance_m


def robot_aim_m(view: RobotView, params: BehaviourParams) -> np.ndarray:
    """Where each human looks for the robot ``(N, 2)``: its centre (hunavsim) or nearest body point (nsim)."""
    if params.hunavsim:
        return np.broadcast_to(np.asarray(view.centre_m, dtype=np.float64), view.closest_m.shape)
    return view.closest_m


class Reaction(NamedTuple):
    """What the behaviours change this tick, per human (all ``(N,)`` unless noted).

    override: the human follows ``target_m (N, 2)`` at ``target_speed_mps``, stopping
    ``stop_distance_m`` short of it (slowing down over the arrival distance), instead of its goals.
    speed_factor: multiplies the desired velocity; speed_limit_mps: then caps the desired speed,
    and the speed (``inf``: no limit). hold: stands still this tick (no motion of its own).
    look_at_robot: turn the head (heading) towards ``look_at_m (N, 2)``.
    robot_law: ROBOT_AS_AGENT, ROBOT_AS_OBSTACLE or ROBOT_IGNORED in the social force.
    scared: add ``scared_repulsion``.
    """

    override: np.ndarray
    target_m: np.ndarray
    target_speed_mps: np.ndarray
    stop_distance_m: np.ndarray
    speed_factor: np.ndarray
    speed_limit_mps: np.ndarray
    hold: np.ndarray
    look_at_robot: np.ndarray
    look_at_m: np.ndarray
    robot_law: np.ndarray
    scared: np.ndarray


def detection_distance_m(behaviour: np.ndarray, params: BehaviourParams) -> np.ndarray:
    """Each human's detection distance ``(N,)`` from its behaviour (0: never detects)."""
    p = params.resolved()
    table = np.zeros(len(Behaviour) + 1)
    table[Behaviour.REGULAR] = table[Behaviour.IMPASSIVE] = p.regular_detection_distance_m
    table[Behaviour.SURPRISED] = p.surprised_detection_distance_m
    table[Behaviour.SCARED] = p.scared_detection_distance_m
    table[Behaviour.CURIOUS] = p.curious_detection_distance_m
    table[Behaviour.THREATENING] = p.threatening_detection_distance_m
    return table[behaviour]


def _in_range(behaviour: np.ndarray, view: RobotView | None, params: BehaviourParams) -> np.ndarray:
    if view is None:
        return np.zeros(len(behaviour), bool)
    limit = detection_distance_m(behaviour, params)
    return (robot_distance_m(view, params) <= limit) & (limit > 0.0)


def robot_detected(
    behaviour: np.ndarray,
    position_m: np.ndarray,
    heading_rad: np.ndarray,
    view: RobotView,
    segments_m: np.ndarray,
    params: BehaviourParams,
) -> np.ndarray:
    """Whether each human sees the robot now: ``(N,)`` bool.

    Within its behaviour's detection distance, in the field of view, and (with ``line_of_sight``)
    not hidden by a wall segment; bearing and sight line to ``robot_aim_m``.
    """
    p = params.resolved()
    aim = robot_aim_m(view, p)
    to_robot = aim - position_m
    bearing = np.arctan2(to_robot[:, 1], to_robot[:, 0]) - heading_rad
    bearing = (bearing + np.pi) % (2.0 * np.pi) - np.pi
    seen = _in_range(behaviour, view, p) & (np.abs(bearing) <= np.deg2rad(p.field_of_view_deg) / 2.0)
    if p.line_of_sight and len(segments_m) and np.any(seen):
        k = np.flatnonzero(seen)
        blocked = segments_intersect(position_m[k], aim[k], segments_m).any(axis=1)
        seen = seen.copy()
        seen[k[blocked]] = False
    return seen


def duration_s(behaviour: np.ndarray, params: BehaviourParams) -> np.ndarray:
    """Reaction duration per human ``(N,)``: ``inf`` for the untimed behaviours."""
    p = params.resolved()
    table = np.full(len(Behaviour) + 1, np.inf)
    table[Behaviour.SURPRISED] = p.surprised_duration_s
    table[Behaviour.SCARED] = p.scared_duration_s
    table[Behaviour.CURIOUS] = p.curious_duration_s
    table[Behaviour.THREATENING] = p.threatening_duration_s
    return table[behaviour]


def update_behaviour_states(
    behaviour: np.ndarray,
    state: np.ndarray,
    timer_s: np.ndarray,
    detected: np.ndarray,
    view: RobotView | None,
    params: BehaviourParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One tick of the state machine: new ``(behaviour_state (N,) int8, behaviour_timer_s (N,))``.

    detected: ``robot_detected`` now. view: None when there is no robot (out of range, unseen).
    hunavsim: the timer is the time spent reacting over the run; nsim: the time in the current
    state (restarting at 0 on every transition).
    """
    p = params.resolved()
    limit = duration_s(behaviour, p)
    if p.hunavsim:
        # HuNavSim's TimeExpiredCondition: ticked (clock += dt) only on ticks the robot is seen;
        # the reaction runs while the clock is short of the period. Scared re-arms: at expiry its
        # clock restarts and it skips that one tick; the others are done for the run.
        rearms = behaviour == Behaviour.SCARED
        finished = (state == DONE) & ~rearms
        seen = detected & ~finished
        clock = np.where(seen, timer_s + dt_s, timer_s)
        expired = seen & (clock >= limit)
        new = np.where(finished | expired, DONE, np.where(seen, REACTING, NAVIGATING)).astype(np.int8)
        return new, np.where(expired & rearms, 0.0, clock)
    in_range = _in_range(behaviour, view, p)
    expired = timer_s + dt_s >= limit
    new = np.where(
        state == NAVIGATING,
        np.where(detected, REACTING, NAVIGATING),
        np.where(~in_range, NAVIGATING, np.where((state == REACTING) & expired, DONE, state)),
    ).astype(np.int8)
    timer = np.where(new == state, timer_s + dt_s, 0.0)
    return new, timer


def _no_reaction(behaviour: np.ndarray, position_m: np.ndarray, robot_law: np.ndarray) -> Reaction:
    n = len(behaviour)
    zeros, no = np.zeros(n), np.zeros(n, bool)
    return Reaction(
        no, np.zeros((n, 2)), zeros, zeros, np.ones(n), np.full(n, np.inf), no, no, position_m, robot_law, no
    )


def behaviour_reactions(
    behaviour: np.ndarray,
    state: np.ndarray,
    position_m: np.ndarray,
    robot: RobotState | None,
    view: RobotView | None,
    params: BehaviourParams,
) -> Reaction:
    """Translate behaviours and states into this tick's ``Reaction`` (no robot: no reaction)."""
    p = params.resolved()
    reacting = state == REACTING
    if p.hunavsim:  # only regular humans see the robot as an agent, impassive ones as an obstacle
        robot_law = np.select(
            [behaviour == Behaviour.REGULAR, behaviour == Behaviour.IMPASSIVE],
            [ROBOT_AS_AGENT, ROBOT_AS_OBSTACLE],
            ROBOT_IGNORED,
        ).astype(np.int8)
    else:
        robot_law = np.where(behaviour == Behaviour.IMPASSIVE, ROBOT_AS_OBSTACLE, ROBOT_AS_AGENT).astype(np.int8)
    if robot is None or view is None or not np.any(reacting):
        return _no_reaction(behaviour, position_m, robot_law)
    surprised = reacting & (behaviour == Behaviour.SURPRISED)
    curious = reacting & (behaviour == Behaviour.CURIOUS)
    threatening = reacting & (behaviour == Behaviour.THREATENING)
    scared = reacting & (behaviour == Behaviour.SCARED)

    aim = robot_aim_m(view, p)
    distance = robot_distance_m(view, p)
    forward = np.array([np.cos(robot.heading_rad), np.sin(robot.heading_rad)])
    # HuNavSim's blockRobot puts the point at (sin h, cos h): beside the robot; ahead is (cos h, sin h)
    reach_m = p.threatening_front_distance_m + (0.0 if p.hunavsim else robot.half_length_m + robot.radius_m)
    block_point = np.asarray(robot.position_m, dtype=np.float64) + reach_m * forward
    to_block = block_point - position_m
    block_distance = np.hypot(to_block[:, 0], to_block[:, 1])
    target = np.where(curious[:, None], aim, np.where(threatening[:, None], block_point, position_m))
    if p.hunavsim:
        curious_speed = p.curious_speed_mps * distance / HUNAVSIM_MAX_VIEW_M
        near_robot = curious & (distance <= p.curious_stop_distance_m)  # stands and looks
        hold = surprised | near_robot
        stop = np.where(curious, p.curious_stop_distance_m, 0.0)
        near_block = threatening & (distance <= p.threatening_look_distance_m)
    else:
        curious_speed = np.full(len(behaviour), p.curious_speed_mps)
        # curious humans aim at the nearest body point and stop short of the robot's *surface*
        stop = np.where(curious, p.curious_stop_distance_m + robot.radius_m, 0.0)
        near_robot = curious & (distance <= p.curious_stop_distance_m + 0.25)
        hold = np.zeros(len(behaviour), bool)
        near_block = threatening & (block_distance < p.threatening_look_distance_m)
        # humans who mean to get close keep only the physical (wall-law) avoidance of the robot
        robot_law = np.where(curious | threatening, ROBOT_AS_OBSTACLE, robot_law).astype(np.int8)
    speed = np.select([curious, threatening], [curious_speed, np.full(len(behaviour), p.threatening_speed_mps)], 0.0)
    return Reaction(
        override=surprised | curious | threatening,
        target_m=target,
        target_speed_mps=speed,
        stop_distance_m=stop,
        speed_factor=np.where(scared, p.scared_speed_factor, 1.0),
        speed_limit_mps=np.where(scared, p.scared_max_speed_mps, np.inf),
        hold=hold,
        look_at_robot=surprised | near_robot | near_block,
        look_at_m=np.array(aim, dtype=np.float64),
        robot_law=robot_law,
        scared=scared,
    )


def scared_repulsion(
    position_m: np.ndarray,
    radius_m: np.ndarray,
    view: RobotView,
    scared: np.ndarray,
    params: BehaviourParams,
) -> np.ndarray:
    """Extra repulsion of scared humans from the robot: ``(N, 2)`` m/s², zero where not ``scared``.

    hunavsim: ``A B / max(d, SCARED_MIN_DISTANCE_M)`` away from the robot's centre, ``d`` the
    centre distance less the human's radius (HuNavSim's ``avoidRobot``, ``4 / d`` by default).
    nsim: ``A exp(-d / B)`` away from the robot's nearest body point, ``d`` the distance to its
    surface clamped at 0 (bounded at contact).
    """
    p = params.resolved()
    if p.hunavsim:
        away = position_m - np.asarray(view.centre_m, dtype=np.float64)
        d = np.maximum(view.centre_distance_m - radius_m, SCARED_MIN_DISTANCE_M)
        mag = p.scared_strength_mps2 * p.scared_range_m / d
    else:
        away = position_m - view.closest_m
        mag = p.scared_strength_mps2 * np.exp(-np.maximum(view.surface_distance_m, 0.0) / p.scared_range_m)
    dist = np.hypot(away[:, 0], away[:, 1])
    unit = away / np.maximum(dist, 1e-9)[:, None]
    return np.where(scared[:, None], mag[:, None] * unit, 0.0)


def fastest_speed_mps(behaviour: np.ndarray, desired_speed_mps: np.ndarray, params: BehaviourParams) -> float:
    """The highest speed any of these humans may aim for: its own, or a reaction's it can have."""
    p = params.resolved()
    present = set(np.unique(behaviour).tolist())
    speeds = [float(np.max(desired_speed_mps, initial=0.0))]
    if Behaviour.CURIOUS in present:
        top = p.curious_speed_mps
        if p.hunavsim:
            top *= p.curious_detection_distance_m / HUNAVSIM_MAX_VIEW_M
        speeds.append(top)
    if Behaviour.THREATENING in present:
        speeds.append(p.threatening_speed_mps)
    return max(speeds)
