"""Social force crowd model: humans walk their goals, avoid each other, the walls and the robot.

The model (accelerations, m/s², per unit mass), one function per term, each ``(N, 2)``:

* ``desired_force``: relaxation to the desired velocity, ``(v0 e - v) / tau`` (Helbing & Molnár 1995).
* ``agent_repulsion``: anisotropic repulsion between humans, the gradient of Helbing & Molnár's
  elliptical potential ``A B exp((r_i + r_j - b) / B)`` whose semi-minor axis ``b`` shrinks along
  the relative motion over ``agent_lookahead_s`` (elliptical specification II, Johansson, Helbing
  & Shukla 2007; see ``pair_repulsion``), weighted by ``w = lambda + (1 - lambda)(1 + cos phi) / 2``
  with ``phi`` the angle between i's heading and the direction to j: people react less to what is
  behind them. Without relative motion it is the circular ``A exp((r_i + r_j - d) / B) n w``
  (Helbing, Farkas & Vicsek 2000). Anticipation is what lets two people walking head-on step
  aside in time; the circular form alone lets them bump.
* ``obstacle_repulsion``: ``A_w exp((r_i - d_iw) / B_w) n_iw`` from the nearest point of every wall
  segment within ``obstacle_cutoff_m`` (a corner shared by two segments counts once).
* ``robot_repulsion``: the robot (a capsule: body segment along its heading, grown by its radius)
  seen as another human (agent law), as an obstacle (wall law), or not at all, by each human's
  behaviour (``behaviours.Reaction.robot_law``).
* ``group_coherence``, ``group_repulsion``, ``group_gaze``: the walking-group forces of Moussaïd
  et al. 2010 (attraction to the group's centre beyond ``(n - 1) / 2`` metres, repulsion between
  members closer than ``r_i + r_j + group_personal_distance_m``, and a braking force ``-beta alpha v``
  when the head must turn ``alpha`` beyond the vision half-angle to see the group's centre).
* ``fluctuation``: a small seeded random acceleration that breaks exact symmetries (only for
  humans who want to move: standing ones do not fidget).
* ``behaviours.scared_repulsion``: the extra robot repulsion of scared humans.

Navigation: each human walks to its current waypoint at its desired speed; before a final goal
(or a behaviour's stop point) it brakes at ``arrival_deceleration_mps2`` (``desired_velocity``).

Integration is semi-implicit Euler at a fixed step: ``v += a dt`` (speed capped at
``max_speed_factor`` times the desired speed), a displacement of at most half the radius, then
hard constraints on the new positions (``separate_bodies``): a few projection passes push apart
every two humans closer than the sum of their radii (half each), push humans out of the robot's
body where the robot *ends* the step (it follows its trajectory regardless, so the saved tick
has no one inside it), and project humans out of the walls last (walls win). The velocity
reported is the displacement over ``dt``.

``step`` is pure (new state, inputs untouched) and deterministic for a given generator state;
``nsim.crowd.rollout.rollout`` runs it over a replayed robot trajectory and returns per-tick arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from nsim.config import param
from nsim.crowd import behaviours as beh
from nsim.crowd.behaviours import Behaviour, BehaviourParams, Reaction, RobotView
from nsim.crowd.neighbours import SegmentGrid, closest_points_on_segments, neighbour_pairs
from nsim.crowd.state import RobotState
from nsim.human.gait_phase import advance_person_phase

STAND_TOLERANCE_M = 0.05
"""Humans stop this close to a final goal (exactly 0 desired speed within it: no creeping)."""

# --------------------------------------------------------------------------------------------
# Parameters and state
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ForceParams:
    """Social force model parameters (accelerations per unit mass)."""

    relaxation_time_s: float = param(0.5, gt=0, help="tau: time to relax to the desired velocity")
    agent_strength_mps2: float = param(2.0, ge=0, help="A: human-human repulsion at contact")
    agent_range_m: float = param(0.5, gt=0, help="B: decay length of the human-human repulsion")
    anisotropy: float = param(0.3, ge=0, le=1, help="lambda: weight of what is behind (1 = isotropic)")
    agent_lookahead_s: float = param(
        1.0, ge=0, help="humans anticipate relative motion over this time (0 = circular)"
    )
    obstacle_strength_mps2: float = param(10.0, ge=0, help="A_w: wall repulsion at contact")
    obstacle_range_m: float = param(0.2, gt=0, help="B_w: decay length of the wall repulsion")
    group_coherence_mps2: float = param(2.0, ge=0, help="beta_2: pull towards the group's centre")
    group_repulsion_mps2: float = param(1.0, ge=0, help="beta_3: push between members too close")
    group_gaze_per_s: float = param(3.0, ge=0, help="beta_1: braking per radian the head must turn")
    group_personal_distance_m: float = param(0.2, ge=0, help="members repel below r_i + r_j + this")
    group_vision_half_angle_deg: float = param(
        90.0, gt=0, le=180, help="half field of view for the gaze force"
    )
    max_speed_factor: float = param(1.3, ge=1, help="speed cap as a multiple of the desired speed")
    agent_cutoff_m: float = param(
        3.0, gt=0, help="humans (and the robot) farther apart than this ignore each other"
    )
    obstacle_cutoff_m: float = param(1.0, gt=0, help="wall segments farther than this are ignored")
    fluctuation_mps2: float = param(0.1, ge=0, help="std of the random acceleration (symmetry breaking)")
    goal_radius_m: float = param(0.3, gt=0, help="a goal closer than this is reached")
    arrival_deceleration_mps2: float = param(1.0, gt=0, help="braking before a final goal or a stop point")
    max_turn_rate_dps: float = param(360.0, gt=0, help="heading turn rate limit")
    push_out_of_robot: bool = param(True, help="humans overlapping the robot's body are pushed out")
    separation_passes: int = param(
        16, ge=0, help="projection passes a step may take to keep bodies apart (0: people may overlap)"
    )


@dataclass(frozen=True)
class CrowdState:
    """The crowd at one tick. Every per-human array has the same leading length ``N``.

    Kinematics
        time_s: float, simulation time of this tick.
        position_m: (N, 2) float64, root position on the floor (world x, y; z up).
        velocity_mps: (N, 2) float64, displacement over the last tick divided by ``dt_s``.
        heading_rad: (N,) float64, facing direction (yaw about +z from +x); follows the velocity,
            or the robot when looking at it, turning at most ``max_turn_rate_dps``.
    Goals
        goals_m: (N, K, 2) float64, each human's waypoints, padded to a common ``K``.
        n_goals: (N,) int64 in [1, K], how many of ``goals_m[i]`` are real.
        goal_index: (N,) int64, the waypoint being walked to.
        loop_goals: (N,) bool, start again at waypoint 0 after the last; otherwise the human
            stops at its last waypoint and ``arrived`` becomes True.
        arrived: (N,) bool.
    Body
        desired_speed_mps: (N,) float64, v0 (0: stands, e.g. an idle clip's person). radius_m: (N,) float64, body radius.
        height_m: (N,) float64, scales the stride length. group_id: (N,) int64, -1 = walks alone.
    Behaviour (``nsim.crowd.behaviours``)
        behaviour: (N,) int8 ``Behaviour`` codes. behaviour_state: (N,) int8 (0 navigating,
        1 reacting, 2 done). behaviour_timer_s: (N,) float64, the reaction clock: time spent
        reacting over the run (profile hunavsim) or time in the current state (nsim).
    Gait (``nsim.human.gait_phase.advance_person_phase``)
        distance_walked_m: (N,) float64. gait_phase: (N,) float64 in [0, 1). gait_stride_m: (N,) float64,
        the person's clip's own stride (> 0), or 0: the stride formula of nsim's procedural walks.
        gait_period_s: (N,) float64, > 0 for a clip that does not travel (the phase advances with
        time over it), else 0.
    """

    time_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    heading_rad: np.ndarray
    goals_m: np.ndarray
    n_goals: np.ndarray
    goal_index: np.ndarray
    loop_goals: np.ndarray
    arrived: np.ndarray
    desired_speed_mps: np.ndarray
    radius_m: np.ndarray
    height_m: np.ndarray
    group_id: np.ndarray
    behaviour: np.ndarray
    behaviour_state: np.ndarray
    behaviour_timer_s: np.ndarray
    distance_walked_m: np.ndarray
    gait_phase: np.ndarray
    gait_stride_m: np.ndarray
    gait_period_s: np.ndarray

    @property
    def n(self) -> int:
        return len(self.position_m)

    @staticmethod
    def create(
        position_m,
        goals_m,
        *,
        n_goals=None,
        loop_goals=False,
        velocity_mps=None,
        heading_rad=None,
        desired_speed_mps=1.3,
        radius_m=0.25,
        height_m=1.75,
        group_id=-1,
        behaviour=Behaviour.REGULAR,
        gait_stride_m=0.0,
        gait_period_s=0.0,
    ) -> CrowdState:
        """A validated initial state; scalars broadcast to every human.

        position_m: (N, 2). goals_m: (N, 2) one goal each, or (N, K, 2) waypoints (``n_goals``
        (N,) says how many are real, default K). The heading defaults to the first goal's
        direction, the velocity to zero. Raises ``ValueError`` naming the bad field.
        """
        pos = _array("position_m", position_m, np.float64)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise ValueError(f"position_m: expected shape (N, 2), got {pos.shape}")
        n = len(pos)
        goals = _array("goals_m", goals_m, np.float64)
        if goals.ndim == 2:
            goals = goals[:, None, :]
        if goals.ndim != 3 or goals.shape[0] != n or goals.shape[2] != 2 or goals.shape[1] < 1:
            raise ValueError(f"goals_m: expected shape ({n}, 2) or ({n}, K, 2), got {goals.shape}")
        k = goals.shape[1]
        count = _per_agent("n_goals", k if n_goals is None else n_goals, n, np.int64)
        if np.any((count < 1) | (count > k)):
            raise ValueError(f"n_goals: expected values in [1, {k}]")
        if heading_rad is None:
            d = goals[:, 0] - pos
            heading_rad = np.arctan2(d[:, 1], d[:, 0])
        vel = np.zeros((n, 2)) if velocity_mps is None else _array("velocity_mps", velocity_mps, np.float64)
        if vel.shape != (n, 2):
            raise ValueError(f"velocity_mps: expected shape ({n}, 2), got {vel.shape}")
        codes = _per_agent("behaviour", behaviour, n, np.int8)
        if not np.all(np.isin(codes, [b.value for b in Behaviour])):
            raise ValueError(f"behaviour: codes must be in {[int(b) for b in Behaviour]}")
        state = CrowdState(
            time_s=0.0,
            position_m=pos,
            velocity_mps=vel,
            heading_rad=_per_agent("heading_rad", heading_rad, n, np.float64),
            goals_m=goals,
            n_goals=count,
            goal_index=np.zeros(n, np.int64),
            loop_goals=_per_agent("loop_goals", loop_goals, n, bool),
            arrived=np.zeros(n, bool),
            desired_speed_mps=_per_agent("desired_speed_mps", desired_speed_mps, n, np.float64),
            radius_m=_per_agent("radius_m", radius_m, n, np.float64),
            height_m=_per_agent("height_m", height_m, n, np.float64),
            group_id=_per_agent("group_id", group_id, n, np.int64),
            behaviour=codes,
            behaviour_state=np.zeros(n, np.int8),
            behaviour_timer_s=np.zeros(n),
            distance_walked_m=np.zeros(n),
            gait_phase=np.zeros(n),
            gait_stride_m=_per_agent("gait_stride_m", gait_stride_m, n, np.float64),
            gait_period_s=_per_agent("gait_period_s", gait_period_s, n, np.float64),
        )
        for name in ("radius_m", "height_m"):
            if np.any(getattr(state, name) <= 0):
                raise ValueError(f"{name}: expected values > 0")
        for name in ("desired_speed_mps", "gait_stride_m", "gait_period_s"):
            if np.any(getattr(state, name) < 0):
                raise ValueError(f"{name}: expected values >= 0")
        for f in fields(state):
            v = getattr(state, f.name)
            if isinstance(v, np.ndarray) and v.dtype.kind == "f" and not np.all(np.isfinite(v)):
                raise ValueError(f"{f.name}: expected finite values")
        return state


def _array(name: str, value, dtype) -> np.ndarray:
    try:
        return np.array(value, dtype=dtype)  # a copy: the state never aliases the caller's arrays
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers, got {type(value).__name__}") from None


def _per_agent(name: str, value, n: int, dtype) -> np.ndarray:
    a = _array(name, value, dtype)
    if a.ndim == 0:
        return np.full(n, a, dtype=dtype)
    if a.shape != (n,):
        raise ValueError(f"{name}: expected a scalar or shape ({n},), got {a.shape}")
    return a


# --------------------------------------------------------------------------------------------
# Forces: one function per term, each returning (N, 2) accelerations in m/s².
# --------------------------------------------------------------------------------------------


def _norm(v: np.ndarray) -> np.ndarray:
    """Length of 2D vectors ``(..., 2)`` -> ``(...)`` (cheaper than ``np.linalg.norm`` on small arrays)."""
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1])


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = _norm(v)
    return v / np.maximum(norm, 1e-12)[..., None], norm


def _heading_unit(heading_rad: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(heading_rad), np.sin(heading_rad)], axis=-1)


def _scatter(index: np.ndarray, vectors: np.ndarray, n: int) -> np.ndarray:
    """Sum ``vectors (Q, 2)`` into ``(n, 2)`` rows ``index (Q,)`` (deterministic order)."""
    return np.stack(
        [
            np.bincount(index, weights=vectors[:, 0], minlength=n),
            np.bincount(index, weights=vectors[:, 1], minlength=n),
        ],
        axis=-1,
    )


def desired_velocity(
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    target_m: np.ndarray,
    speed_mps: np.ndarray,
    stop_distance_m: np.ndarray,
    slow_down: np.ndarray,
    params: ForceParams,
) -> np.ndarray:
    """Desired velocity ``(N, 2)``: towards ``target_m`` at ``speed_mps``.

    Where ``slow_down``, the speed is capped at ``sqrt(2 a s)`` (braking at the constant
    ``arrival_deceleration_mps2`` = a) so the human stops ``stop_distance_m`` short of the target;
    ``s`` is the distance left from where the human will be after the relaxation lag
    (``tau * velocity`` further along): without that look-ahead the relaxation overshoots the stop
    point and the human steps back.
    """
    e, dist = _unit(target_m - position_m)
    closing = np.einsum("ni,ni->n", velocity_mps, e)
    remaining = np.maximum(dist - stop_distance_m - params.relaxation_time_s * closing, 0.0)
    braking = np.sqrt(2.0 * params.arrival_deceleration_mps2 * remaining)
    return e * np.where(slow_down, np.minimum(speed_mps, braking), speed_mps)[:, None]


def desired_force(
    velocity_mps: np.ndarray, desired_velocity_mps: np.ndarray, relaxation_time_s: float
) -> np.ndarray:
    """Relaxation towards the desired velocity: ``(v_desired - v) / tau``, ``(N, 2)``."""
    return (desired_velocity_mps - velocity_mps) / relaxation_time_s


def anisotropy_weight(
    heading_unit: np.ndarray, direction_to_other: np.ndarray, anisotropy: float
) -> np.ndarray:
    """``lambda + (1 - lambda)(1 + cos phi) / 2``: 1 ahead, ``lambda`` behind. ``(Q,)``.

    heading_unit, direction_to_other: (Q, 2) unit vectors.
    """
    cos_phi = np.einsum("qi,qi->q", heading_unit, direction_to_other)
    return anisotropy + (1.0 - anisotropy) * 0.5 * (1.0 + cos_phi)


def _elliptical_force(
    offset_m: np.ndarray, relative_step_m: np.ndarray, radius_sum_m: np.ndarray, params: ForceParams
) -> tuple[np.ndarray, np.ndarray]:
    """``pair_repulsion`` before the anisotropy weight, and the unit vectors ``d/|d|``: ``(Q, 2)`` each.

    Odd in ``(d, y)``: swapping the two humans negates it (only the anisotropy differs).
    """
    n_ij, dist = _unit(offset_m)
    u, dist_y = _unit(offset_m - relative_step_m)
    step_len = _norm(relative_step_m)
    b = 0.5 * np.sqrt(np.maximum((dist + dist_y) ** 2 - step_len**2, 0.0))
    mag = params.agent_strength_mps2 * np.exp((radius_sum_m - b) / params.agent_range_m)
    scale = mag * (dist + dist_y) / (4.0 * np.maximum(b, 1e-9))  # mag * (|d| + |d - y|) / (2b) / 2
    grad = n_ij + u
    # on the focal segment (on a collision course within the look-ahead) the gradient vanishes:
    # fall back to the circular direction there
    degenerate = _norm(grad) < 1e-9
    if np.any(degenerate):
        grad = np.where(degenerate[:, None], n_ij, grad)
        scale = np.where(degenerate, mag, scale)
    return scale[:, None] * grad, n_ij


def pair_repulsion(
    offset_m: np.ndarray,
    relative_step_m: np.ndarray,
    radius_sum_m: np.ndarray,
    heading_unit: np.ndarray,
    params: ForceParams,
) -> np.ndarray:
    """Repulsion on a human from another, row-wise for Q pairs: ``(Q, 2)``.

    offset_m: (Q, 2) ``d = x_i - x_j``; relative_step_m: (Q, 2) ``y = (v_j - v_i) * lookahead``;
    radius_sum_m: (Q,) ``r_i + r_j``; heading_unit: (Q, 2) human i's facing direction.

    ``-grad_d V`` of the potential ``V = A B exp((r_i + r_j - b) / B)`` (y held fixed), with ``b``
    the semi-minor axis of the ellipse through ``d`` with foci ``0`` and ``y``,
    ``2b = sqrt((|d| + |d - y|)^2 - |y|^2)`` (elliptical specification II, Johansson, Helbing &
    Shukla 2007), times the anisotropy ``w(phi)``::

        f = A exp((r_i + r_j - b) / B) (|d| + |d - y|) / (2b) * (d/|d| + (d - y)/|d - y|) / 2 * w

    With ``y = 0`` (same velocities, or ``agent_lookahead_s = 0``) this is the circular
    ``A exp((r_i + r_j - |d|) / B) d/|d| w``.
    """
    f, n_ij = _elliptical_force(offset_m, relative_step_m, radius_sum_m, params)
    return anisotropy_weight(heading_unit, -n_ij, params.anisotropy)[:, None] * f


def agent_repulsion(
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    heading_rad: np.ndarray,
    radius_m: np.ndarray,
    pairs: np.ndarray,
    params: ForceParams,
) -> np.ndarray:
    """Anisotropic, velocity-aware human-human repulsion summed over ``pairs (P, 2)``: ``(N, 2)``.

    pairs: unordered ``i < j`` (``neighbours.neighbour_pairs``); each gives the force on i from j
    and on j from i (``pair_repulsion``; opposite but for the anisotropy weights, so the shared
    part is computed once per pair).
    """
    n = len(position_m)
    if len(pairs) == 0:
        return np.zeros((n, 2))
    i, j = pairs[:, 0], pairs[:, 1]
    f, n_ij = _elliptical_force(
        position_m[i] - position_m[j],
        (velocity_mps[j] - velocity_mps[i]) * params.agent_lookahead_s,
        radius_m[i] + radius_m[j],
        params,
    )
    facing = _heading_unit(heading_rad)
    w_i = anisotropy_weight(facing[i], -n_ij, params.anisotropy)
    w_j = anisotropy_weight(facing[j], n_ij, params.anisotropy)
    return _scatter(np.concatenate([i, j]), np.concatenate([w_i[:, None] * f, -w_j[:, None] * f]), n)


@dataclass(frozen=True)
class WallContacts:
    """Wall segments near each human, one row per distinct nearest point (Q rows).

    agent: (Q,) int64; closest_m: (Q, 2); distance_m: (Q,) centre to the nearest point;
    normal: (Q, 2) unit vector from the wall point to the centre.
    """

    agent: np.ndarray
    closest_m: np.ndarray
    distance_m: np.ndarray
    normal: np.ndarray


def wall_contacts(position_m: np.ndarray, walls: SegmentGrid, within_m: np.ndarray | float) -> WallContacts:
    """Nearest points of the wall segments within ``within_m`` ((N,) or scalar) of each human.

    Segments meeting at a corner share their nearest point there; it is kept once, so a corner
    pushes like one wall, not two.
    """
    agent, seg = walls.candidates(position_m)
    if len(agent):
        q = closest_points_on_segments(position_m[agent], walls.segments_m[seg])
        diff = position_m[agent] - q
        dist = _norm(diff)
        keep = dist < np.broadcast_to(within_m, (len(position_m),))[agent]
        agent, q, diff, dist = agent[keep], q[keep], diff[keep], dist[keep]
        if len(agent) > 1:
            key = np.round(q * 1e7).astype(np.int64)
            order = np.lexsort((key[:, 1], key[:, 0], agent))
            agent, q, diff, dist, key = agent[order], q[order], diff[order], dist[order], key[order]
            dup = np.zeros(len(agent), bool)
            dup[1:] = (agent[1:] == agent[:-1]) & np.all(key[1:] == key[:-1], axis=1)
            agent, q, diff, dist = agent[~dup], q[~dup], diff[~dup], dist[~dup]
        normal = diff / np.maximum(dist, 1e-12)[:, None]
        return WallContacts(agent, q, dist, normal)
    return WallContacts(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)))


def obstacle_repulsion(
    position_m: np.ndarray, radius_m: np.ndarray, walls: SegmentGrid, params: ForceParams
) -> np.ndarray:
    """Wall repulsion ``A_w exp((r_i - d_iw) / B_w) n_iw`` summed over nearby segments: ``(N, 2)``."""
    c = wall_contacts(position_m, walls, params.obstacle_cutoff_m)
    mag = params.obstacle_strength_mps2 * np.exp((radius_m[c.agent] - c.distance_m) / params.obstacle_range_m)
    return _scatter(c.agent, mag[:, None] * c.normal, len(position_m))


def robot_view(position_m: np.ndarray, robot: RobotState) -> RobotView:
    """The robot from each human: nearest point of its body axis, distances to its surface and centre."""
    seg = robot.body_segment_m()
    q = closest_points_on_segments(position_m, np.broadcast_to(seg, (len(position_m), 2, 2)))
    centre = np.array(robot.position_m, dtype=np.float64)
    return RobotView(q, _norm(position_m - q) - robot.radius_m, centre, _norm(position_m - centre))


def robot_repulsion(
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    heading_rad: np.ndarray,
    radius_m: np.ndarray,
    robot: RobotState,
    view: RobotView,
    robot_law: np.ndarray,
    params: ForceParams,
) -> np.ndarray:
    """Repulsion of the robot on each human, ``(N, 2)``, by ``robot_law (N,)``.

    ``ROBOT_AS_AGENT``: ``pair_repulsion`` with the robot's nearest body point as the other human
    (radius ``robot.radius_m``, velocity ``robot.velocity_mps``); ``ROBOT_AS_OBSTACLE``: the wall
    law from the robot's surface, blind to its motion; ``ROBOT_IGNORED``: zero. Zero beyond
    ``agent_cutoff_m``.
    """
    offset = position_m - view.closest_m
    n_ir, d = _unit(offset)
    as_agent = pair_repulsion(
        offset,
        (np.asarray(robot.velocity_mps)[None, :] - velocity_mps) * params.agent_lookahead_s,
        radius_m + robot.radius_m,
        _heading_unit(heading_rad),
        params,
    )
    wall_mag = params.obstacle_strength_mps2 * np.exp(
        (radius_m + robot.radius_m - d) / params.obstacle_range_m
    )
    f = np.where((robot_law == beh.ROBOT_AS_OBSTACLE)[:, None], wall_mag[:, None] * n_ir, as_agent)
    return np.where(((d < params.agent_cutoff_m) & (robot_law != beh.ROBOT_IGNORED))[:, None], f, 0.0)


def _group_centres(position_m: np.ndarray, group_id: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per human: its group's centre of mass ``(N, 2)``, size ``(N,)``, and a mask of grouped humans."""
    grouped = group_id >= 0
    n = len(position_m)
    centre = np.zeros((n, 2))
    size = np.ones(n)
    if np.any(grouped):
        _, inv = np.unique(group_id[grouped], return_inverse=True)
        count = np.bincount(inv).astype(np.float64)
        sums = _scatter(inv, position_m[grouped], len(count))
        centre[grouped] = (sums / count[:, None])[inv]
        size[grouped] = count[inv]
    return centre, size, grouped & (size > 1)


def group_coherence(position_m: np.ndarray, group_id: np.ndarray, params: ForceParams) -> np.ndarray:
    """Attraction ``beta_2 U_i`` to the group's centre when farther than ``(n - 1) / 2`` m: ``(N, 2)``."""
    centre, size, grouped = _group_centres(position_m, group_id)
    u, dist = _unit(centre - position_m)
    on = grouped & (dist > (size - 1.0) / 2.0)
    return np.where(on[:, None], params.group_coherence_mps2 * u, 0.0)


def group_repulsion(
    position_m: np.ndarray, radius_m: np.ndarray, group_id: np.ndarray, pairs: np.ndarray, params: ForceParams
) -> np.ndarray:
    """Repulsion ``beta_3 W_ik`` between group members closer than ``r_i + r_k + d_personal``: ``(N, 2)``."""
    n = len(position_m)
    if len(pairs) == 0:
        return np.zeros((n, 2))
    i, k = pairs[:, 0], pairs[:, 1]
    same = (group_id[i] >= 0) & (group_id[i] == group_id[k])
    i, k = i[same], k[same]
    w, d = _unit(position_m[i] - position_m[k])  # from k to i
    on = d < radius_m[i] + radius_m[k] + params.group_personal_distance_m
    f = params.group_repulsion_mps2 * w[on]
    return _scatter(np.concatenate([i[on], k[on]]), np.concatenate([f, -f]), n)


def group_gaze(
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    heading_rad: np.ndarray,
    group_id: np.ndarray,
    params: ForceParams,
) -> np.ndarray:
    """Braking ``-beta_1 alpha v_i`` when the head must turn ``alpha`` (rad) past the vision
    half-angle to see the group's centre (Moussaïd et al. 2010): ``(N, 2)``."""
    centre, _, grouped = _group_centres(position_m, group_id)
    u, dist = _unit(centre - position_m)
    cos_a = np.clip(np.einsum("ni,ni->n", _heading_unit(heading_rad), u), -1.0, 1.0)
    alpha = np.maximum(np.arccos(cos_a) - np.deg2rad(params.group_vision_half_angle_deg), 0.0)
    on = grouped & (dist > 1e-9)
    return np.where(on[:, None], -params.group_gaze_per_s * alpha[:, None] * velocity_mps, 0.0)


def fluctuation(rng: np.random.Generator, n: int, params: ForceParams) -> np.ndarray:
    """Random acceleration ``N(0, fluctuation_mps2²)`` per axis: ``(N, 2)`` (drawn even when 0, so
    the generator advances identically whatever the setting)."""
    return params.fluctuation_mps2 * rng.standard_normal((n, 2))


# --------------------------------------------------------------------------------------------
# Constraints
# --------------------------------------------------------------------------------------------


SEPARATION_TOLERANCE_M = 1e-7
"""``separate_bodies`` leaves overlaps up to this alone (and stops once none is deeper)."""

SEPARATION_OVERRELAXATION = 1.4
"""``separate_bodies`` moves two overlapping humans apart by this times their overlap (0.7 each).

Exact halves (1.0) creep through a jam, each pass undoing part of the last: on 1,000 people at
2.5 per m² crossing a 20 m room, 8 passes left overlaps of 1.2 mm at 1.0 and none at 1.4. The
surplus leaves a gap of 0.4 times the overlap, never an overlap (the constraint is one-sided)."""


def push_out_of_robot(position_m: np.ndarray, radius_m: np.ndarray, robot: RobotState) -> np.ndarray:
    """Displacement ``(N, 2)`` that moves each human's body out of the robot's body.

    Along the line from the nearest point of the robot's body axis; a centre exactly on the axis
    goes to the robot's left.
    """
    view = robot_view(position_m, robot)
    n_ir, d = _unit(position_m - view.closest_m)
    on_axis = d < 1e-12
    if np.any(on_axis):
        left = np.array([-np.sin(robot.heading_rad), np.cos(robot.heading_rad)])
        n_ir = np.where(on_axis[:, None], left, n_ir)
    depth = np.maximum(radius_m + robot.radius_m - d, 0.0)
    return depth[:, None] * n_ir


def pair_overlaps(
    position_m: np.ndarray, radius_m: np.ndarray, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For unordered pairs ``(P, 2)``: depth ``r_i + r_j - |x_i - x_j|`` ``(P,)`` (> 0: the bodies
    overlap) and the unit vector from j to i ``(P, 2)`` (``(1, 0)`` for coincident centres)."""
    i, j = pairs[:, 0], pairs[:, 1]
    u, dist = _unit(position_m[i] - position_m[j])
    coincident = dist < 1e-12
    if np.any(coincident):
        u = np.where(coincident[:, None], np.array([1.0, 0.0]), u)
    return radius_m[i] + radius_m[j] - dist, u


def separate_bodies(
    start_m: np.ndarray,
    position_m: np.ndarray,
    radius_m: np.ndarray,
    walls: SegmentGrid,
    *,
    robot: RobotState | None = None,
    candidates: np.ndarray | None = None,
    passes: int = 16,
) -> np.ndarray:
    """Project humans so that no bodies overlap: new positions ``(N, 2)`` (inputs untouched).

    start_m: (N, 2) positions at the start of the step, clear of the walls; position_m: (N, 2)
    where the humans would go. The walls project the humans first (``keep_out_of_walls``); then
    each pass (i) moves every two humans closer than ``r_i + r_j`` apart along the line of their
    centres, each by ``SEPARATION_OVERRELAXATION / 2`` times the overlap (all pairs at once, summed), (ii) pushes humans out of
    ``robot``'s body by the full depth (the robot does not yield; overlaps up to
    ``SEPARATION_TOLERANCE_M`` are left, as between humans), (iii) caps each human's
    movement from ``start_m`` at 0.9 of its radius (so (iv) cannot carry anyone through a wall)
    and (iv) projects out of the walls again: walls win. Passes stop once no overlap is deeper
    than ``SEPARATION_TOLERANCE_M``; a jam ``passes`` cannot resolve (someone pressed between the
    robot and a wall) keeps what is left.

    candidates: unordered pairs ``(P, 2)`` that may touch, a superset of those closer than
    ``r_i + r_j + 2 max(r)`` at ``position_m`` (e.g. the step's force pairs, when their cutoff is
    large enough); by default ``neighbour_pairs`` finds them. Cost: linear in N and P per pass.
    """
    x = keep_out_of_walls(position_m, radius_m, walls)
    n = len(x)
    if n == 0 or passes == 0:
        return x
    r_max = float(radius_m.max())
    if candidates is None:
        candidates = neighbour_pairs(x, 4.0 * r_max)
    if len(candidates):
        i, j = candidates[:, 0], candidates[:, 1]
        near = _norm(x[i] - x[j]) < radius_m[i] + radius_m[j] + 2.0 * r_max
        pairs = candidates[near]
    else:
        pairs = np.zeros((0, 2), np.int64)
    limit = 0.9 * radius_m
    # after the first pass only what moved can overlap anew: the pairs and robot checks that
    # follow are those of the humans moved in the pass before (same result, less work)
    check_pairs, moved_before = pairs, np.ones(n, bool)
    for _ in range(passes):
        changed = np.zeros(n, bool)
        if len(check_pairs):
            depth, u = pair_overlaps(x, radius_m, check_pairs)
            hit = depth > SEPARATION_TOLERANCE_M
            if np.any(hit):
                touching = check_pairs[hit]
                half = 0.5 * SEPARATION_OVERRELAXATION * depth[hit, None] * u[hit]
                x = x + _scatter(touching.T.ravel(), np.concatenate([half, -half]), n)
                changed[touching.ravel()] = True
        if robot is not None:
            rows = np.flatnonzero(changed | moved_before)
            out = push_out_of_robot(x[rows], radius_m[rows], robot)
            inside = _norm(out) > SEPARATION_TOLERANCE_M
            x[rows[inside]] += out[inside]
            changed[rows[inside]] = True
        if not np.any(changed):
            break
        # the cap, then the walls, for the humans moved in this pass (the others are clear of them)
        k = np.flatnonzero(changed)
        u, length = _unit(x[k] - start_m[k])
        capped = np.where((length > limit[k])[:, None], start_m[k] + u * limit[k, None], x[k])
        x[k] = keep_out_of_walls(capped, radius_m[k], walls)
        check_pairs = pairs[changed[pairs[:, 0]] | changed[pairs[:, 1]]]
        moved_before = changed
    return x


def keep_out_of_walls(
    position_m: np.ndarray, radius_m: np.ndarray, walls: SegmentGrid, iterations: int = 4
) -> np.ndarray:
    """Project humans out of the walls so no body overlaps a segment: new ``(N, 2)`` positions.

    Each iteration pushes every overlapping human along the normals of its contacts by the
    overlap depths (summed, corners counted once). Correct when humans started the tick
    clear of the walls and moved less than their radius (``step`` guarantees both).
    """
    pos = position_m.copy()
    active = np.arange(len(pos))
    for _ in range(iterations):
        if len(active) == 0:
            break
        c = wall_contacts(pos[active], walls, radius_m[active])
        if len(c.agent) == 0:
            break
        depth = radius_m[active][c.agent] - c.distance_m
        push = _scatter(c.agent, depth[:, None] * c.normal, len(active))
        pos[active] += push
        active = active[np.unique(c.agent)]
    return pos


# --------------------------------------------------------------------------------------------
# Step
# --------------------------------------------------------------------------------------------


def _turn_towards(heading_rad: np.ndarray, target_rad: np.ndarray, max_step_rad: float) -> np.ndarray:
    delta = (target_rad - heading_rad + np.pi) % (2.0 * np.pi) - np.pi
    return (heading_rad + np.clip(delta, -max_step_rad, max_step_rad) + np.pi) % (2.0 * np.pi) - np.pi


def step(
    state: CrowdState,
    robot: RobotState | None,
    walls: SegmentGrid | np.ndarray,
    forces: ForceParams,
    behaviours: BehaviourParams,
    dt_s: float,
    rng: np.random.Generator,
    *,
    robot_next: RobotState | None = None,
) -> CrowdState:
    """Advance the crowd by ``dt_s``: a new ``CrowdState`` (``state`` is not modified).

    robot: the robot at this tick, or None; the humans perceive and react to it. robot_next: the
    robot at the end of the step, which the humans' bodies are kept out of (so the new state and
    the robot at the new tick do not overlap); by default ``robot`` moved on at its velocity.
    walls: a ``SegmentGrid`` (build it once with ``make_walls``) or raw segments ``(M, 2, 2)``.
    rng: the only source of randomness.
    """
    if not dt_s > 0:
        raise ValueError(f"dt_s: expected > 0, got {dt_s!r}")
    if not isinstance(walls, SegmentGrid):
        walls = make_walls(walls, forces, state.radius_m)
    elif walls.reach_m < max(forces.obstacle_cutoff_m, float(state.radius_m.max(initial=0.0))):
        raise ValueError(
            f"walls: indexed for {walls.reach_m} m, less than the force cutoff or a body radius "
            "(use make_walls)"
        )
    n = state.n
    pos, vel, heading = state.position_m, state.velocity_mps, state.heading_rad
    rows = np.arange(n)
    behaviours = behaviours.resolved()

    # --- behaviours: perception, state machine, reactions
    view = robot_view(pos, robot) if robot is not None else None
    if view is not None:
        detected = beh.robot_detected(state.behaviour, pos, heading, view, walls.segments_m, behaviours)
    else:
        detected = np.zeros(n, bool)
    b_state, b_timer = beh.update_behaviour_states(
        state.behaviour, state.behaviour_state, state.behaviour_timer_s, detected, view, behaviours, dt_s
    )
    react: Reaction = beh.behaviour_reactions(state.behaviour, b_state, pos, robot, view, behaviours)

    # --- navigation target and desired velocity
    goal = state.goals_m[rows, state.goal_index]
    final = ~state.loop_goals & (state.goal_index == state.n_goals - 1)
    v_desired = desired_velocity(  # arrived humans keep to their last goal
        pos,
        vel,
        np.where(react.override[:, None], react.target_m, goal),
        np.where(react.override, react.target_speed_mps, state.desired_speed_mps),
        np.where(react.override, react.stop_distance_m, STAND_TOLERANCE_M),
        react.override | final,
        forces,
    )
    v_desired = v_desired * react.speed_factor[:, None]
    v_desired = v_desired * np.minimum(1.0, react.speed_limit_mps / np.maximum(_norm(v_desired), 1e-12))[:, None]

    # --- forces
    pairs = neighbour_pairs(pos, forces.agent_cutoff_m)
    acc = desired_force(vel, v_desired, forces.relaxation_time_s)
    acc = acc + agent_repulsion(pos, vel, heading, state.radius_m, pairs, forces)
    acc = acc + obstacle_repulsion(pos, state.radius_m, walls, forces)
    if robot is not None:
        acc = acc + robot_repulsion(pos, vel, heading, state.radius_m, robot, view, react.robot_law, forces)
        acc = acc + beh.scared_repulsion(pos, state.radius_m, view, react.scared, behaviours)
    if np.any(state.group_id >= 0):
        acc = acc + group_coherence(pos, state.group_id, forces)
        acc = acc + group_repulsion(pos, state.radius_m, state.group_id, pairs, forces)
        acc = acc + group_gaze(pos, vel, heading, state.group_id, forces)
    walking = _norm(v_desired) > 0.0  # standing humans do not fidget
    acc = acc + np.where(walking[:, None], fluctuation(rng, n, forces), 0.0)

    # --- integrate (semi-implicit Euler), speed cap, hard constraints
    v_new = vel + acc * dt_s
    v_cap = forces.max_speed_factor * np.maximum(
        state.desired_speed_mps, np.where(react.override, react.target_speed_mps, 0.0)
    )
    v_cap = np.minimum(v_cap, react.speed_limit_mps)
    u, speed = _unit(v_new)
    v_new = u * np.minimum(speed, v_cap)[:, None]
    v_new = np.where(react.hold[:, None], 0.0, v_new)
    disp = v_new * dt_s
    u, length = _unit(disp)
    disp = u * np.minimum(length, 0.5 * state.radius_m)[:, None]
    body_of_robot = None
    if robot is not None and forces.push_out_of_robot:
        body_of_robot = robot_next if robot_next is not None else robot.advanced(dt_s)
    r_max = float(state.radius_m.max(initial=0.0))
    new_pos = separate_bodies(
        pos,
        pos + disp,
        state.radius_m,
        walls,
        robot=body_of_robot,
        # the force pairs hold every pair separate_bodies needs (within 4 max radii once each has
        # moved up to a radius) when their cutoff reaches 6 max radii
        candidates=pairs if forces.agent_cutoff_m >= 6.0 * r_max else None,
        passes=forces.separation_passes,
    )
    moved = new_pos - pos
    new_vel = moved / dt_s

    # --- heading: towards the robot when looking at it, else along the walking direction
    walked = _norm(moved)
    new_speed = walked / dt_s
    target_heading = np.where(new_speed > 0.1, np.arctan2(new_vel[:, 1], new_vel[:, 0]), heading)
    if view is not None:
        to_robot = react.look_at_m - pos
        target_heading = np.where(
            react.look_at_robot, np.arctan2(to_robot[:, 1], to_robot[:, 0]), target_heading
        )
    new_heading = _turn_towards(heading, target_heading, np.deg2rad(forces.max_turn_rate_dps) * dt_s)

    # --- goals: next waypoint, loop, or arrive
    reached = ~state.arrived & (_norm(new_pos - goal) <= forces.goal_radius_m)
    last = state.goal_index == state.n_goals - 1
    goal_index = np.where(reached & ~last, state.goal_index + 1, state.goal_index)
    goal_index = np.where(reached & last & state.loop_goals, 0, goal_index)
    arrived = state.arrived | (reached & last & ~state.loop_goals)

    # --- gait: phase advances with the distance walked over the clip's stride (or with time: idle)
    return replace(
        state,
        time_s=state.time_s + dt_s,
        position_m=new_pos,
        velocity_mps=new_vel,
        heading_rad=new_heading,
        goal_index=goal_index,
        arrived=arrived,
        behaviour_state=b_state,
        behaviour_timer_s=b_timer,
        distance_walked_m=state.distance_walked_m + walked,
        gait_phase=advance_person_phase(state.gait_phase, walked, dt_s, new_speed, state.height_m,
                                        state.gait_stride_m, state.gait_period_s),
    )


def make_walls(
    segments_m: np.ndarray, forces: ForceParams, radius_m: np.ndarray | float = 0.25
) -> SegmentGrid:
    """Index wall segments ``(M, 2, 2)`` for ``step``: reach covers the force cutoff and the bodies."""
    reach = max(forces.obstacle_cutoff_m, float(np.max(radius_m, initial=0.0)) * 1.5)
    return SegmentGrid.build(np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2), reach)
