"""Register a robot's odometry frame in a scene's world from its localised camera frames.

A robot's recording gives its body's trajectory ``body_to_odom (N, 4, 4)`` at ``traj_ns (N,)``
in its own odometry frame, and camera frames stamped on the cameras' clock. Localised in the
scene (``nsim.sfm.localize``), K of those frames have poses ``cam_to_world (K, 4, 4)`` in the
scene's world. This module finds what ties the two together:

* ``odom_to_world``: the odometry frame's pose in the world, a rigid motion (``with_scale``: a
  similarity, for odometry whose scale is not trusted);
* ``clock_offset_s``: the cameras' clock minus the odometry's, so that a frame stamped ``s`` was
  captured at odometry time ``s - clock_offset_s`` (the convention of
  ``nsim.synth.robot_log``); searched or given.

The model. A frame k from a camera mounted at ``sensor_to_body_k`` has, in the odometry frame,
``cam_to_odom_k = B(t_k - clock_offset_s) @ sensor_to_body_k`` (``B`` interpolated between
trajectory poses by :func:`nsim.crowd.scenario.interpolate_poses`: positions linearly,
rotations by slerp), and should satisfy ``cam_to_world_k = odom_to_world . cam_to_odom_k``.
Several cameras enter one fit through their own ``sensor_to_body``. A similarity
(``with_scale``) scales the odometry's positions, not the metric camera mounts: the body pose
``B`` maps to centre ``s R b + t`` and rotation ``R R_B`` (``nsim.sfm.align.apply_sim3_to_poses``),
and the camera stays at ``sensor_to_body`` from it.

The fit uses both the camera centres and the camera rotations: minimising
``sum_k |c'_k - c_k|^2 / sigma_p^2 + |R R^odom_k - R^world_k|_F^2 / (2 sigma_r^2)`` (``c'`` the
registered centre; ``|dR|_F^2 ~ 2 angle^2``) has a closed form like Umeyama's
(:func:`fit_pose_pairs`), and the rotations make it well posed where centres alone are not (a
robot driving a straight line). It is robust: every frame proposes the whole motion (one localised camera pose fixes a rigid one),
the proposal that most frames agree with wins (a truncated, MSAC cost), and the fit is then
refined on the frames agreeing with it, dropping those whose position or rotation residual
exceeds ``nsim.sfm.align.SIM3_OUTLIER_SIGMAS`` robust standard deviations (as
:func:`nsim.sfm.align.fit_sim3` does with centres). No random draws: the result is a function
of the inputs.

The clock offset is searched on a grid over ``+-max_clock_offset_s`` (the truncated cost of a
robust fit at each step), then refined by a bounded scalar search with the inliers held fixed,
where the cost (the fit's chi-square with the residuals' own standard deviations) is smooth. Its
curvature gives ``clock_offset_std_s``; an offset that the motion does not pin down (a robot
standing still or driving straight at constant speed) is an error, unless it is given.

Drift. One rigid motion cannot absorb odometry that drifts: on a 16 m run of the robot-log
generator's default faults it leaves the odometry frame 4.5 cm and 1.7 deg off, and the clock
offset 4 ms. :func:`refine_drift` (``register_trajectory(..., drift=DriftModel())``) starts from
the rigid fit (its inliers, clock offset and ``odom_to_world``) and solves a pose graph over the
odometry with ``scipy.optimize.least_squares`` (soft_l1 loss, ``DRIFT_ROBUST_SIGMAS``):

* nodes: odometry poses every ``node_spacing_m`` metres or ``node_spacing_deg`` degrees
  (:func:`drift_nodes`); each node's body pose in the world, ``B_i = (exp(omega_i) R_i, p_i +
  v_i)`` with ``(R_i, p_i)`` the rigid fit's, ``omega_i`` and ``v_i`` interpolated linearly in
  time between nodes (so the refined trajectory exists at every odometry stamp);
* odometry factors between consecutive nodes: ``inv(B_i) B_j`` against the odometry's own
  relative motion ``inv(O_i) O_j``, its translation divided by ``1 + e`` and its rotation turned
  back by ``b`` times the metres walked about body z (``e``: the odometry's scale error, ``b``:
  its heading bias per metre, both estimated under Gaussian priors); residuals per body axis,
  weighed by a random walk in the distance and angle (:class:`DriftModel`);
* frame factors: each inlier frame's camera, ``B(t_k - clock_offset_s) @ sensor_to_body_k``,
  against its localised ``cam_to_world`` (centre and rotation vector, per component), weighed by
  ``position_sigma_m`` and ``rotation_sigma_deg`` first, then by the residuals' own spread; the
  clock offset is a parameter too (``refine_clock_offset``, when it was searched).

After each solve the inliers are chosen anew among the frames used, against the refined
trajectory (``SIM3_OUTLIER_SIGMAS`` robust standard deviations), until they settle or
``max_rounds``. The drift is zero at the first pose, so the odometry frame's pose is
``B_0 @ inv(O_0)``; its standard error comes from the solve's Jacobian. With drift, the residual
limits apply to the refined residuals, not the rigid fit's.

Failures are one-line :class:`nsim.errors.InputError` (``check=False`` returns them in
``Registration.why`` instead): fewer than ``min_frames`` localised frames inside the
trajectory, frames that all lie in one place, too few frames agreeing on one motion, an
unobservable clock offset, or a residual above the limits.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from nsim.config import param
from nsim.errors import InputError
from nsim.geometry.transforms import is_rotation
from nsim.sfm.align import SIM3_OUTLIER_SIGMAS, apply_sim3_to_poses, sim3_matrix

log = logging.getLogger(__name__)

#: At most this many frames propose a motion in the robust start (evenly spaced in time).
MAX_HYPOTHESES = 200
#: Floors on the residuals' standard deviations, as fractions of the expected ones (exact data).
_SIGMA_FLOOR = 1e-3
#: Times this close count as equal (float seconds from nanosecond stamps round): a frame whose
#: odometry time is the trajectory's last stamp lies inside it.
_TIME_TOLERANCE_S = 1e-6


@dataclass(frozen=True)
class RegisterOptions:
    """How to register.

    with_scale: fit a similarity (odometry of unknown scale) instead of a rigid motion.
    clock_offset_s: the cameras' clock minus the odometry's when known; None searches it within
        ``+-max_clock_offset_s`` on a grid of ``clock_step_s`` (keep it below the time in which
        the cameras move by ``position_sigma_m`` or turn by ``rotation_sigma_deg``), refined to
        ``clock_tolerance_s``. A searched offset less certain than ``max_clock_offset_std_s`` is
        an error.
    position_sigma_m, rotation_sigma_deg: the expected error of a localised pose (RMS of the
        centre's distance and of the rotation angle); they weigh and score the robust start and
        the grid search. The refinement uses the residuals' own spread.
    max_median_residual_m, max_median_residual_deg: a larger median residual of the inliers is
        an error. min_frames: fewer localised frames inside the trajectory is an error.
    min_inlier_fraction: fewer frames agreeing with the fit is an error.
    min_extent_m: some camera's inlier centres must reach at least this far from their mean (the
        largest distance, per camera mount); otherwise the robot stood still.
    max_gap_s: a frame whose time falls between trajectory poses further apart than this is not used.
    """

    with_scale: bool = param(False, help="a similarity (odometry of unknown scale) instead of a rigid motion")
    clock_offset_s: float | None = param(None, ge=-60.0, le=60.0, help="camera clock minus odometry clock when "
                                                                        "known (null: searched)")
    max_clock_offset_s: float = param(0.5, ge=0.0, le=60.0, help="search the clock offset within +-this")
    clock_step_s: float = param(0.01, gt=0.0, help="the clock offset search's grid step")
    clock_tolerance_s: float = param(1e-4, gt=0.0, help="the searched clock offset's final tolerance")
    max_clock_offset_std_s: float = param(0.01, gt=0.0, help="a searched offset less certain than this is an error")
    position_sigma_m: float = param(0.02, gt=0.0, help="expected error of a localised camera centre (RMS distance)")
    rotation_sigma_deg: float = param(0.5, gt=0.0, help="expected error of a localised camera rotation (RMS angle)")
    max_median_residual_m: float = param(0.05, gt=0.0, help="a larger median residual is an error")
    max_median_residual_deg: float = param(1.0, gt=0.0, help="a larger median residual is an error")
    min_frames: int = param(3, ge=3, help="fewer localised frames inside the trajectory is an error")
    min_inlier_fraction: float = param(0.5, gt=0.0, le=1.0, help="fewer frames agreeing on the fit is an error")
    min_extent_m: float = param(0.1, ge=0.0, help="some camera's registered frames must spread this far")
    max_gap_s: float = param(0.25, gt=0.0, help="frames between trajectory poses further apart are not used")

    def __post_init__(self) -> None:
        positive = ("clock_step_s", "clock_tolerance_s", "max_clock_offset_std_s", "position_sigma_m",
                    "rotation_sigma_deg", "max_median_residual_m", "max_median_residual_deg", "max_gap_s")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name}: expected a finite value > 0, got {value}")
        if not (math.isfinite(self.max_clock_offset_s) and self.max_clock_offset_s >= 0.0):
            raise ValueError(f"max_clock_offset_s: expected >= 0, got {self.max_clock_offset_s}")
        if self.clock_offset_s is not None and not math.isfinite(self.clock_offset_s):
            raise ValueError(f"clock_offset_s: expected a finite value or None, got {self.clock_offset_s}")
        if self.min_frames < 3:
            raise ValueError(f"min_frames: expected >= 3, got {self.min_frames}")
        if not 0.0 < self.min_inlier_fraction <= 1.0:
            raise ValueError(f"min_inlier_fraction: expected (0, 1], got {self.min_inlier_fraction}")
        if not (math.isfinite(self.min_extent_m) and self.min_extent_m >= 0.0):
            raise ValueError(f"min_extent_m: expected >= 0, got {self.min_extent_m}")


class _Residuals:
    """Residual statistics over the inliers of a fit with ``residual_m``, ``residual_deg`` and ``inliers`` (K,)."""

    residual_m: np.ndarray
    residual_deg: np.ndarray
    inliers: np.ndarray

    @property
    def num_inliers(self) -> int:
        return int(self.inliers.sum())

    def _stat(self, values: np.ndarray, rms: bool) -> float:
        v = values[self.inliers]
        if not len(v):
            return math.nan
        return float(np.sqrt(np.mean(v ** 2))) if rms else float(np.median(v))

    @property
    def median_m(self) -> float:
        return self._stat(self.residual_m, rms=False)

    @property
    def rms_m(self) -> float:
        return self._stat(self.residual_m, rms=True)

    @property
    def median_deg(self) -> float:
        return self._stat(self.residual_deg, rms=False)

    @property
    def rms_deg(self) -> float:
        return self._stat(self.residual_deg, rms=True)


@dataclass(frozen=True, eq=False)
class Registration(_Residuals):
    """The odometry frame in the scene's world, and how well the frames agree with it.

    odom_to_world: (4, 4) ``[[s R, t], [0, 1]]`` mapping odometry points to world points (rigid
    unless ``with_scale``; body poses map with :meth:`to_world`, cameras then by their mounts).
    scale: ``s``.
    clock_offset_s: cameras' clock minus odometry clock; clock_offset_std_s: its standard error
    from the fit (NaN when given, inf when the motion does not constrain it).
    residual_m, residual_deg: (K,) per localised frame, the camera centre's distance and the
    rotation angle between the localised pose and the registered odometry (NaN where not used).
    used: (K,) bool, frames inside the trajectory; inliers: (K,) bool, frames in the final fit.
    why: None when registered, else the one-line reason it could not be (the arrays then hold
    what was computed, NaN otherwise).
    refined: the drift refinement (:class:`DriftRefinement`) when one was asked for and the rigid
    fit passed its checks; every field above stays the rigid fit's.
    """

    odom_to_world: np.ndarray
    scale: float
    clock_offset_s: float
    clock_offset_std_s: float
    residual_m: np.ndarray
    residual_deg: np.ndarray
    used: np.ndarray
    inliers: np.ndarray
    why: str | None = None
    refined: DriftRefinement | None = None

    @property
    def ok(self) -> bool:
        return self.why is None

    def to_world(self, poses_odom: np.ndarray) -> np.ndarray:
        """Poses ``(..., 4, 4)`` in the odometry frame -> the world (rotations stay rotations)."""
        R = self.odom_to_world[:3, :3] / self.scale
        return apply_sim3_to_poses(self.scale, R, self.odom_to_world[:3, 3], poses_odom)

    def summary(self) -> str:
        """One line: the residual, the inliers and the clock offset."""
        return (f"{self.num_inliers}/{int(self.used.sum())} frames, residual median {self.median_m * 100:.2f} cm / "
                f"{self.median_deg:.3f} deg (RMS {self.rms_m * 100:.2f} cm / {self.rms_deg:.3f} deg), "
                f"clock offset {self.clock_offset_s * 1000:.1f} ms, scale {self.scale:.4f}")

    def require(self) -> Registration:
        """This registration, or InputError with :attr:`why`."""
        if self.why is not None:
            raise InputError(self.why)
        return self


# --------------------------------------------------------------------------------------
# The fit of one motion to pose pairs
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PosePairs:
    """K localised frames as pose pairs.

    cam_to_odom: (K, 4, 4) each camera in the odometry frame (body pose at its time x mount);
    cam_to_world: (K, 4, 4) the same camera localised in the world; body_xyz: (K, 3) the body's
    position in the odometry frame at that time. A similarity scales the odometry's positions,
    not the metric camera mounts: the camera centre ``p = b + l`` maps to ``R (s b + l) + t``.
    """

    cam_to_odom: np.ndarray
    cam_to_world: np.ndarray
    body_xyz: np.ndarray

    def __len__(self) -> int:
        return len(self.cam_to_odom)

    def __getitem__(self, idx) -> PosePairs:
        return PosePairs(self.cam_to_odom[idx], self.cam_to_world[idx], self.body_xyz[idx])


def pose_residuals(s, R: np.ndarray, t: np.ndarray, pairs: PosePairs) -> tuple[np.ndarray, np.ndarray]:
    """Centre distances (m) and rotation angles (rad) between ``(s, R, t) . cam_to_odom`` and ``cam_to_world``.

    ``s ()``, ``R (3, 3)``, ``t (3,)`` give ``(K,)``, ``(K,)``; a stack of motions ``s (H,)``,
    ``R (H, 3, 3)``, ``t (H, 3)`` gives ``(H, K)``, ``(H, K)``.
    """
    s, R, t = np.asarray(s, dtype=np.float64), np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    b, c = pairs.body_xyz, pairs.cam_to_world[:, :3, 3]
    lever = pairs.cam_to_odom[:, :3, 3] - b
    scaled = s[..., None, None] * b + lever  # (..., K, 3)
    moved = np.einsum("...ab,...kb->...ka", R, scaled) + t[..., None, :]
    pos = np.linalg.norm(moved - c, axis=-1)
    # angle of (R Ro_k)^T Rc_k: trace(Ro_k^T R^T Rc_k) = sum_ab R_ab (Rc_k Ro_k^T)_ab
    M = pairs.cam_to_world[:, :3, :3] @ pairs.cam_to_odom[:, :3, :3].swapaxes(-1, -2)
    trace = np.einsum("...ab,kab->...k", R, M)
    rot = np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))
    return pos, rot


def fit_pose_pairs(pairs: PosePairs, with_scale: bool, sigma_m: float, sigma_rad: float,
                   rounds: int = 20) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares ``(s, R, t)`` taking ``pairs.cam_to_odom`` onto ``pairs.cam_to_world``.

    Minimises ``sum |R q + t - c|^2 / sigma_m^2 + |R Ro - Rc|_F^2 / (2 sigma_rad^2)`` over the
    centres (``q = s b + l``, see :class:`PosePairs`) and rotations ``Ro, Rc``. For a given ``s``,
    R maximises ``tr(R^T H)`` with ``H = 2 / sigma_m^2 sum (c - c_mean)(q - q_mean)^T +
    1 / sigma_rad^2 sum Rc Ro^T`` (an SVD, as in Umeyama's method) and ``t = c_mean - R q_mean``;
    with scale, ``s`` (closed form for a given R) and R alternate for up to ``rounds``. One pair
    fixes a rigid motion; a scale needs body positions that are not all one.
    """
    b, c = pairs.body_xyz, pairs.cam_to_world[:, :3, 3]
    lever = pairs.cam_to_odom[:, :3, 3] - b
    bc, lc, cc = b - b.mean(axis=0), lever - lever.mean(axis=0), c - c.mean(axis=0)
    rot_sum = np.einsum("kab,kcb->ac", pairs.cam_to_world[:, :3, :3], pairs.cam_to_odom[:, :3, :3])  # sum Rc Ro^T
    var_b = float(np.sum(bc ** 2))
    s = 1.0
    for _ in range(rounds if with_scale else 1):
        H = 2.0 / sigma_m ** 2 * cc.T @ (s * bc + lc) + rot_sum / sigma_rad ** 2
        U, _, Vt = np.linalg.svd(H)
        R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0]) @ Vt
        if not with_scale or var_b <= 1e-24:
            break
        s_new = float(np.sum((bc @ R.T) * (cc - lc @ R.T)) / var_b)  # argmin_s sum |s R b' + R l' - c'|^2
        done = abs(s_new - s) <= 1e-12 * max(abs(s), 1.0)
        s = s_new if s_new > 0.0 else s
        if done:
            break
    q_mean = s * b.mean(axis=0) + lever.mean(axis=0)
    return s, R, c.mean(axis=0) - R @ q_mean


def _hypotheses(pairs: PosePairs, with_scale: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One motion per frame (evenly spaced, at most MAX_HYPOTHESES): (s (H,), R (H, 3, 3), t (H, 3)).

    A frame's rotation and centre fix a rigid motion; with scale, its scale is the median ratio
    of the frame's distances to every other frame, in the world and in the odometry frame.
    """
    K = len(pairs)
    pick = np.unique(np.linspace(0, K - 1, min(K, MAX_HYPOTHESES)).round().astype(np.int64))
    Rh = pairs.cam_to_world[pick, :3, :3] @ pairs.cam_to_odom[pick, :3, :3].swapaxes(-1, -2)
    b, c = pairs.body_xyz, pairs.cam_to_world[:, :3, 3]
    lever = pairs.cam_to_odom[:, :3, 3] - b
    s = np.ones(len(pick))
    if with_scale:
        d_odom = np.linalg.norm(b[pick, None] - b[None], axis=-1)
        d_world = np.linalg.norm(c[pick, None] - c[None], axis=-1)
        ok = d_odom > 1e-9 * max(float(d_odom.max()), 1e-300)
        ratio = np.where(ok, d_world / np.where(ok, d_odom, 1.0), np.nan)
        with np.errstate(all="ignore"):
            s = np.nanmedian(np.where(ok.any(axis=1, keepdims=True), ratio, 1.0), axis=1)
        s = np.where(np.isfinite(s) & (s > 0.0), s, 1.0)
    t = c[pick] - np.einsum("hab,hb->ha", Rh, s[:, None] * b[pick] + lever[pick])
    return s, Rh, t


def _truncated_cost(pos_m: np.ndarray, rot_rad: np.ndarray, sigma_m: float, sigma_rad: float) -> np.ndarray:
    """MSAC cost over the last axis: each residual's squared z-score, capped at SIM3_OUTLIER_SIGMAS^2."""
    cap = SIM3_OUTLIER_SIGMAS ** 2
    return (np.minimum((pos_m / sigma_m) ** 2, cap) + np.minimum((rot_rad / sigma_rad) ** 2, cap)).sum(axis=-1)


@dataclass(frozen=True)
class _Fit:
    s: float
    R: np.ndarray
    t: np.ndarray
    pos_m: np.ndarray  # (K,)
    rot_rad: np.ndarray  # (K,)
    inliers: np.ndarray  # (K,) bool
    sigma_m: float  # the residuals' spread (RMS over the inliers)
    sigma_rad: float


def robust_fit(pairs: PosePairs, with_scale: bool, sigma_m: float, sigma_rad: float, max_rounds: int = 10) -> _Fit:
    """The motion most pairs agree with, refined on them (see the module docstring).

    sigma_m, sigma_rad: expected errors of the pairs (RMS distance and angle) for the start.
    Inliers: position and rotation residuals both within SIM3_OUTLIER_SIGMAS robust standard
    deviations, as in :func:`nsim.sfm.align.fit_sim3`, but here 1.4826 x the median over the
    current inliers (at least the expected error x ``_SIGMA_FLOOR``), so that a fit agreed on by
    fewer than half of the pairs is found as such (the caller decides whether that is enough).
    """
    s_h, R_h, t_h = _hypotheses(pairs, with_scale)
    pos, rot = pose_residuals(s_h, R_h, t_h, pairs)
    best = int(np.argmin(_truncated_cost(pos, rot, sigma_m, sigma_rad)))
    inliers = (pos[best] <= SIM3_OUTLIER_SIGMAS * sigma_m) & (rot[best] <= SIM3_OUTLIER_SIGMAS * sigma_rad)
    if inliers.sum() < 1:
        inliers[np.argmin(pos[best] / sigma_m + rot[best] / sigma_rad)] = True
    sm, sr = sigma_m, sigma_rad
    for _ in range(max_rounds):
        s, R, t = fit_pose_pairs(pairs[inliers], with_scale, sm, sr)
        p_res, r_res = pose_residuals(s, R, t, pairs)
        sm = max(1.4826 * float(np.median(p_res[inliers])), _SIGMA_FLOOR * sigma_m)
        sr = max(1.4826 * float(np.median(r_res[inliers])), _SIGMA_FLOOR * sigma_rad)
        keep = (p_res <= SIM3_OUTLIER_SIGMAS * sm) & (r_res <= SIM3_OUTLIER_SIGMAS * sr)
        if not keep.any() or np.array_equal(keep, inliers):
            break
        inliers = keep
    s, R, t = fit_pose_pairs(pairs[inliers], with_scale, sm, sr)
    p_res, r_res = pose_residuals(s, R, t, pairs)
    spread_m = max(float(np.sqrt(np.mean(p_res[inliers] ** 2))), _SIGMA_FLOOR * sigma_m)
    spread_rad = max(float(np.sqrt(np.mean(r_res[inliers] ** 2))), _SIGMA_FLOOR * sigma_rad)
    return _Fit(s, R, t, p_res, r_res, inliers, spread_m, spread_rad)


# --------------------------------------------------------------------------------------
# Frames on the odometry clock
# --------------------------------------------------------------------------------------


def _usable(frame_s: np.ndarray, traj_s: np.ndarray, lo_s: float, hi_s: float, max_gap_s: float) -> np.ndarray:
    """(K,) whether each frame's odometry time ``frame_s - offset`` lies inside the trajectory, with
    no gap wider than ``max_gap_s`` around it, for every offset in ``[lo_s, hi_s]``."""
    first, last = frame_s - hi_s, frame_s - lo_s
    inside = (first >= traj_s[0] - _TIME_TOLERANCE_S) & (last <= traj_s[-1] + _TIME_TOLERANCE_S)
    gaps = np.diff(traj_s)
    a = np.clip(np.searchsorted(traj_s, first, side="right") - 1, 0, max(len(gaps) - 1, 0))
    b = np.clip(np.searchsorted(traj_s, last, side="left"), 1, len(traj_s) - 1)
    ok = inside.copy()
    if len(gaps):
        for k in np.flatnonzero(inside):
            ok[k] = gaps[a[k]:max(b[k], a[k] + 1)].max() <= max_gap_s + _TIME_TOLERANCE_S
    return ok


def _pairs(traj_s: np.ndarray, body_to_odom: np.ndarray, frame_s: np.ndarray, sensor_to_body: np.ndarray,
           cam_to_world: np.ndarray, offset_s: float) -> PosePairs:
    """The frames at odometry times ``frame_s - offset_s`` as pose pairs (body poses interpolated)."""
    from nsim.geometry.transforms import interpolate_poses

    body = interpolate_poses(traj_s, body_to_odom, frame_s - offset_s)
    return PosePairs(body @ sensor_to_body, cam_to_world, body[:, :3, 3])


def _check_inputs(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns):
    c2w = np.asarray(cam_to_world, dtype=np.float64)
    stamps = np.asarray(stamps_ns)
    body = np.asarray(body_to_odom, dtype=np.float64)
    traj = np.asarray(traj_ns)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise ValueError(f"cam_to_world: expected (K, 4, 4), got {c2w.shape}")
    if stamps.shape != (len(c2w),) or stamps.dtype.kind not in "iu":
        raise ValueError(f"stamps_ns: expected ({len(c2w)},) integers, got {stamps.dtype} {stamps.shape}")
    if body.ndim != 3 or body.shape[1:] != (4, 4) or len(body) < 1:
        raise ValueError(f"body_to_odom: expected (N, 4, 4) with N >= 1, got {body.shape}")
    if traj.shape != (len(body),) or traj.dtype.kind not in "iu":
        raise ValueError(f"traj_ns: expected ({len(body)},) integers, got {traj.dtype} {traj.shape}")
    if np.any(np.diff(traj) <= 0):
        raise ValueError("traj_ns: expected strictly increasing stamps")
    s2b = np.asarray(sensor_to_body, dtype=np.float64)
    if s2b.shape == (4, 4):
        s2b = np.broadcast_to(s2b, c2w.shape)
    if s2b.shape != c2w.shape:
        raise ValueError(f"sensor_to_body: expected (4, 4) or ({len(c2w)}, 4, 4), got {s2b.shape}")
    for name, poses in (("cam_to_world", c2w), ("body_to_odom", body), ("sensor_to_body", s2b)):
        if len(poses) and not (np.all(np.isfinite(poses)) and np.all(is_rotation(poses[:, :3, :3], tol=1e-5))):
            raise ValueError(f"{name}: expected finite rigid poses")
    return c2w, stamps.astype(np.int64), s2b, body, traj.astype(np.int64)


# --------------------------------------------------------------------------------------
# Registration
# --------------------------------------------------------------------------------------


def register_trajectory(
    cam_to_world: np.ndarray,
    stamps_ns: np.ndarray,
    sensor_to_body: np.ndarray,
    body_to_odom: np.ndarray,
    traj_ns: np.ndarray,
    options: RegisterOptions = RegisterOptions(),
    *,
    drift: DriftModel | None = None,
    check: bool = True,
) -> Registration:
    """The odometry frame's pose in the scene (and the cameras' clock offset) from localised frames.

    cam_to_world: (K, 4, 4) localised camera poses (OpenCV axes, the scene's world), stamped
    ``stamps_ns (K,)`` int64 on the cameras' clock; sensor_to_body: (4, 4) for one camera or
    (K, 4, 4), each frame's camera mount (several cameras in one fit); body_to_odom: (N, 4, 4)
    the body's trajectory at ``traj_ns (N,)`` int64, strictly increasing, on the odometry clock.

    drift: refine the rigid fit for the odometry's drift with this model (:func:`refine_drift`;
    the result in ``Registration.refined``, the residual limits then apply to it).

    Returns a :class:`Registration`. The failures listed in the module docstring raise a
    one-line InputError, or with ``check=False`` come back in ``Registration.why``.
    """
    c2w, stamps, s2b, body, traj = _check_inputs(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns)
    o = options
    K = len(c2w)
    t0 = traj[0]
    traj_s = (traj - t0) / 1e9
    frame_s = (stamps - t0) / 1e9
    sigma_m, sigma_rad = o.position_sigma_m, math.radians(o.rotation_sigma_deg)
    search = o.clock_offset_s is None
    lo, hi = (-o.max_clock_offset_s, o.max_clock_offset_s) if search else (o.clock_offset_s, o.clock_offset_s)

    def failed(why: str, **kwargs) -> Registration:
        reg = _registration(K, why=why, **kwargs)
        return reg.require() if check else reg

    frames = np.flatnonzero(_usable(frame_s, traj_s, lo, hi, o.max_gap_s))
    if len(frames) < o.min_frames:
        where = f" for every clock offset within +-{o.max_clock_offset_s:g} s" if search else ""
        return failed(f"only {len(frames)} of {K} localised frames lie inside the odometry trajectory{where}; "
                      f"need at least {o.min_frames}")

    def fit_at(offset: float, idx: np.ndarray) -> _Fit:
        return robust_fit(_pairs(traj_s, body, frame_s[idx], s2b[idx], c2w[idx], offset), o.with_scale,
                          sigma_m, sigma_rad)

    offset_std = math.nan
    if search:
        # coarse: a robust fit per grid step, scored by its truncated cost with the expected errors
        n_steps = int(math.ceil(2 * o.max_clock_offset_s / o.clock_step_s))
        grid = np.linspace(lo, hi, n_steps + 1) if n_steps > 0 else np.array([0.0])
        costs = []
        for offset in grid:
            fit = fit_at(float(offset), frames)
            costs.append(float(_truncated_cost(fit.pos_m, fit.rot_rad, sigma_m, sigma_rad)))
        offset = float(grid[int(np.argmin(costs))])
        # fine: the inliers held, the chi-square with the residuals' own spread (smooth in the offset)
        for _ in range(2):
            fit = fit_at(offset, frames)
            idx = frames[fit.inliers]

            def chi2(x: float, idx=idx, sm=fit.sigma_m, sr=fit.sigma_rad) -> float:
                pairs = _pairs(traj_s, body, frame_s[idx], s2b[idx], c2w[idx], x)
                p, r = pose_residuals(*fit_pose_pairs(pairs, o.with_scale, sm, sr), pairs)
                return float(3.0 * np.sum((p / sm) ** 2) + 3.0 * np.sum((r / sr) ** 2))

            a, b = max(lo, offset - o.clock_step_s), min(hi, offset + o.clock_step_s)
            found = minimize_scalar(chi2, bounds=(a, b), method="bounded", options={"xatol": o.clock_tolerance_s})
            offset = float(found.x)
        h = max(10.0 * o.clock_tolerance_s, 1e-3)
        curvature = (chi2(offset + h) - 2.0 * chi2(offset) + chi2(offset - h)) / h ** 2
        offset_std = math.sqrt(2.0 / curvature) if curvature > 0.0 else math.inf
    else:
        offset = float(o.clock_offset_s)

    # the final fit at the offset, on every frame usable there
    frames = np.flatnonzero(_usable(frame_s, traj_s, offset, offset, o.max_gap_s))
    fit = fit_at(offset, frames)
    n_in, n_used = int(fit.inliers.sum()), len(frames)
    extent = _extent_m(c2w[frames[fit.inliers], :3, 3], s2b[frames[fit.inliers]])
    med_m = float(np.median(fit.pos_m[fit.inliers]))
    med_deg = float(np.degrees(np.median(fit.rot_rad[fit.inliers])))
    args = dict(offset=offset, fit=fit, frames=frames, offset_std=offset_std)
    if n_in < max(o.min_frames, o.min_inlier_fraction * n_used):
        return failed(f"only {n_in} of {n_used} localised frames agree on one odometry frame (need "
                      f"{max(o.min_frames, math.ceil(o.min_inlier_fraction * n_used))}): wrong localisations or "
                      "odometry that does not belong to these images", **args)
    if extent < o.min_extent_m:
        return failed(f"the {n_in} registered frames of each camera lie within {extent:.3f} m of one place (need "
                      f"{o.min_extent_m:g} m): the robot must move while its cameras see the scene", **args)
    if search and abs(offset) > o.max_clock_offset_s - o.clock_step_s / 2:
        return failed(f"the clock offset {offset:+.3f} s lies at the edge of the search range +-"
                      f"{o.max_clock_offset_s:g} s: widen max_clock_offset_s or give clock_offset_s", **args)
    if search and not offset_std <= o.max_clock_offset_std_s:
        return failed(f"the clock offset is not determined by this motion ({offset:+.4f} +- {offset_std:.3g} s, "
                      f"need +-{o.max_clock_offset_std_s:g} s): the robot must turn or change speed in view of "
                      "the scene, or give clock_offset_s", **args)
    what = "registration"
    if drift is not None:
        rigid = _registration(K, **args)
        log.info("registered (rigid): %s", rigid.summary())
        args["refined"] = refined = refine_drift(rigid, c2w, stamps, s2b, body, traj, o, drift)
        med_m, med_deg, n_in, what = refined.median_m, refined.median_deg, refined.num_inliers, "refined registration"
        log.info("refined for drift: %s", refined.summary())
    if med_m > o.max_median_residual_m or med_deg > o.max_median_residual_deg:
        return failed(f"{what} residual median {med_m * 100:.1f} cm / {med_deg:.2f} deg over {n_in} frames "
                      f"exceeds {o.max_median_residual_m * 100:g} cm / {o.max_median_residual_deg:g} deg", **args)
    reg = _registration(K, **args)
    if drift is None:
        log.info("registered: %s", reg.summary())
    return reg


def _extent_m(centres_xyz: np.ndarray, sensor_to_body: np.ndarray) -> float:
    """How far the frames of one camera reach from their mean, the largest over cameras (told apart by mount).

    centres_xyz: (K, 3); sensor_to_body: (K, 4, 4).
    """
    _, camera = np.unique(sensor_to_body.reshape(len(sensor_to_body), 16), axis=0, return_inverse=True)
    extent = 0.0
    for k in np.unique(camera):
        c = centres_xyz[camera.reshape(-1) == k]
        extent = max(extent, float(np.linalg.norm(c - c.mean(axis=0), axis=1).max()))
    return extent


def _registration(K: int, offset: float = math.nan, fit: _Fit | None = None, frames: np.ndarray | None = None,
                  offset_std: float = math.nan, why: str | None = None,
                  refined: DriftRefinement | None = None) -> Registration:
    """A Registration of K frames from the fit over ``frames`` (NaN and nothing used without one)."""
    res_m, res_deg = np.full(K, np.nan), np.full(K, np.nan)
    used, inliers = np.zeros(K, dtype=bool), np.zeros(K, dtype=bool)
    T, s = np.full((4, 4), np.nan), math.nan
    if frames is not None:
        used[frames] = True
    if fit is not None:
        res_m[frames], res_deg[frames], inliers[frames] = fit.pos_m, np.degrees(fit.rot_rad), fit.inliers
        T, s = sim3_matrix(fit.s, fit.R, fit.t), fit.s
    return Registration(T, s, offset, offset_std, res_m, res_deg, used, inliers, why, refined)


# --------------------------------------------------------------------------------------
# Drift: a pose graph over the odometry
# --------------------------------------------------------------------------------------

#: Floors on a segment's odometry standard deviations (numerical only: a robot standing still).
_DRIFT_FLOOR_M = 1e-4
_DRIFT_FLOOR_RAD = math.radians(1e-3)
#: soft_l1's scale, in standard deviations: a factor's residual well inside it counts as its
#: square, beyond it about linearly.
DRIFT_ROBUST_SIGMAS = 2.0


@dataclass(frozen=True)
class DriftModel:
    """How the odometry drifts, for :func:`refine_drift` (the graph is in the module docstring).

    Between two graph nodes the odometry travelled ``d`` metres (after the rigid fit's scale) and
    turned ``phi`` radians (the sum of its steps' rotation angles). Its error over that segment is
    taken as zero-mean, independent of every other segment's, with standard deviations that grow
    like a random walk's, per body axis (x forward, y left, z up):

    * x and y: ``xy_walk_m_per_sqrt_m * sqrt(d)``; z: ``z_walk_m_per_sqrt_m * sqrt(d)``;
    * yaw: ``sqrt(yaw_walk_deg_per_sqrt_m^2 d + yaw_walk_deg_per_sqrt_rad^2 phi)``; roll and
      pitch: ``tilt_walk_deg_per_sqrt_m * sqrt(d)``.

    Two systematic errors, the ones that make leg and wheel odometry drift the most, are
    estimated with the poses, each with a zero-mean Gaussian prior: the odometry's scale error
    ``e`` (it reports ``1 + e`` times the distance the rigid fit gives it; prior std
    ``scale_error_sigma``) and a heading bias per metre walked (prior std
    ``yaw_bias_sigma_deg_per_m``).

    refine_clock_offset: also refine the cameras' clock offset in the graph (only when it was
    searched, not given). node_spacing_m, node_spacing_deg: nodes at the first and the last
    odometry pose and wherever the robot has moved this far or turned this much since the last
    node; between nodes the correction is interpolated linearly in time. max_rounds: solves, each
    after choosing the inliers and the localised frames' spread anew from the previous one.
    """

    xy_walk_m_per_sqrt_m: float = param(0.01, gt=0.0, help="odometry x/y error std after 1 m (random walk)")
    z_walk_m_per_sqrt_m: float = param(0.003, gt=0.0, help="odometry z error std after 1 m (random walk)")
    yaw_walk_deg_per_sqrt_m: float = param(0.2, gt=0.0, help="odometry heading error std after 1 m walked")
    yaw_walk_deg_per_sqrt_rad: float = param(0.2, gt=0.0, help="odometry heading error std after 1 rad turned")
    tilt_walk_deg_per_sqrt_m: float = param(0.02, gt=0.0, help="odometry roll/pitch error std after 1 m (an IMU's "
                                                                 "gravity keeps it small)")
    scale_error_sigma: float = param(0.05, gt=0.0, lt=1.0, help="prior std of the odometry's scale error "
                                                               "(fraction of the distance)")
    yaw_bias_sigma_deg_per_m: float = param(1.0, gt=0.0, help="prior std of the odometry's heading bias per metre")
    refine_clock_offset: bool = param(True, help="refine a searched clock offset in the pose graph")
    node_spacing_m: float = param(0.1, gt=0.0, help="a graph node each time the robot moved this far")
    node_spacing_deg: float = param(5.0, gt=0.0, help="... or turned this much")
    max_rounds: int = param(3, ge=1, le=20, help="solves, re-choosing inliers and the frames' spread between them")

    def __post_init__(self) -> None:
        positive = ("xy_walk_m_per_sqrt_m", "z_walk_m_per_sqrt_m", "yaw_walk_deg_per_sqrt_m",
                    "yaw_walk_deg_per_sqrt_rad", "tilt_walk_deg_per_sqrt_m", "scale_error_sigma",
                    "yaw_bias_sigma_deg_per_m", "node_spacing_m", "node_spacing_deg")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name}: expected a finite value > 0, got {value}")
        if self.max_rounds < 1:
            raise ValueError(f"max_rounds: expected >= 1, got {self.max_rounds}")


@dataclass(frozen=True, eq=False)
class DriftRefinement(_Residuals):
    """The odometry bent onto the localised frames by :func:`refine_drift`.

    body_to_world: (N, 4, 4) the body's poses in the world at the trajectory's stamps (rigid).
    odom_to_world: (4, 4) the odometry frame's pose, ``body_to_world[0] @ inv(body_to_odom[0])``
    (with the rigid fit's scale when it has one): the drift is zero at the first pose, so this is
    where the odometry frame lies. odom_to_world_std_m, odom_to_world_std_deg: its standard error
    (RMS distance, angle) from the solve's Jacobian, given the frames' spread.
    clock_offset_s, clock_offset_std_s: refined in the graph (or the rigid fit's, unrefined).
    scale_error: the odometry reports ``1 + scale_error`` times the distance the rigid fit gives
    it; yaw_bias_deg_per_m: its heading bias.
    residual_m, residual_deg: (K,) per localised frame against ``body_to_world`` (NaN where not
    used); used, inliers: (K,) bool, frames inside the trajectory / in the final solve.
    nodes: (M,) int64 the graph's nodes, indices into the trajectory.
    drift_m, drift_deg: (N,) how far each refined pose lies from the rigid fit's (position, angle).
    rounds: solves run; cost: the last solve's robust cost (0.5 sum rho).
    """

    body_to_world: np.ndarray
    odom_to_world: np.ndarray
    odom_to_world_std_m: float
    odom_to_world_std_deg: float
    clock_offset_s: float
    clock_offset_std_s: float
    scale_error: float
    yaw_bias_deg_per_m: float
    residual_m: np.ndarray
    residual_deg: np.ndarray
    used: np.ndarray
    inliers: np.ndarray
    nodes: np.ndarray
    drift_m: np.ndarray
    drift_deg: np.ndarray
    rounds: int
    cost: float

    def summary(self) -> str:
        """One line: the residual, the inliers, the clock offset and the drift taken up."""
        return (f"{self.num_inliers}/{int(self.used.sum())} frames, residual median {self.median_m * 100:.2f} cm / "
                f"{self.median_deg:.3f} deg (RMS {self.rms_m * 100:.2f} cm / {self.rms_deg:.3f} deg), clock offset "
                f"{self.clock_offset_s * 1000:.1f} ms, drift up to {float(self.drift_m.max()) * 100:.1f} cm / "
                f"{float(self.drift_deg.max()):.2f} deg, scale error {self.scale_error * 100:+.2f} %, yaw bias "
                f"{self.yaw_bias_deg_per_m:+.3f} deg/m")


def drift_nodes(body_to_odom: np.ndarray, scale: float, spacing_m: float,
                spacing_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pose graph's nodes along ``body_to_odom (N, 4, 4)``: ``(nodes (M,) int64, path_m (N,), turn_rad (N,))``.

    path_m, turn_rad: the distance travelled (odometry positions times ``scale``) and the angle
    turned (the sum of the steps' rotation angles) from the first pose. A node at pose 0, then at
    every pose at least ``spacing_m`` further along or ``spacing_rad`` further turned than the last
    node, and at the last pose.
    """
    from scipy.spatial.transform import Rotation

    step_m = scale * np.linalg.norm(np.diff(body_to_odom[:, :3, 3], axis=0), axis=-1)
    rel = body_to_odom[:-1, :3, :3].swapaxes(-1, -2) @ body_to_odom[1:, :3, :3]
    step_rad = Rotation.from_matrix(rel).magnitude() if len(rel) else np.zeros(0)
    path_m = np.concatenate([[0.0], np.cumsum(step_m)])
    turn_rad = np.concatenate([[0.0], np.cumsum(step_rad)])
    nodes = [0]
    for i in range(1, len(body_to_odom)):
        if path_m[i] - path_m[nodes[-1]] >= spacing_m or turn_rad[i] - turn_rad[nodes[-1]] >= spacing_rad:
            nodes.append(i)
    if nodes[-1] != len(body_to_odom) - 1:
        nodes.append(len(body_to_odom) - 1)
    return np.asarray(nodes, dtype=np.int64), path_m, turn_rad


def _segment_sigmas(d_m: np.ndarray, phi_rad: np.ndarray, model: DriftModel) -> tuple[np.ndarray, np.ndarray]:
    """Odometry error std per segment: translation (S, 3) along body x y z (m), rotation (S, 3) about them (rad)."""
    xy = np.sqrt(model.xy_walk_m_per_sqrt_m ** 2 * d_m + _DRIFT_FLOOR_M ** 2)
    z = np.sqrt(model.z_walk_m_per_sqrt_m ** 2 * d_m + _DRIFT_FLOOR_M ** 2)
    yaw = np.sqrt(math.radians(model.yaw_walk_deg_per_sqrt_m) ** 2 * d_m
                  + math.radians(model.yaw_walk_deg_per_sqrt_rad) ** 2 * phi_rad + _DRIFT_FLOOR_RAD ** 2)
    tilt = np.sqrt(math.radians(model.tilt_walk_deg_per_sqrt_m) ** 2 * d_m + _DRIFT_FLOOR_RAD ** 2)
    return np.stack([xy, xy, z], axis=-1), np.stack([tilt, tilt, yaw], axis=-1)


def _rz(angle_rad: np.ndarray) -> np.ndarray:
    """Rotations (S, 3, 3) about +z by ``angle_rad (S,)``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    R = np.zeros((len(c), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


class _DriftGraph:
    """The pose graph of :func:`refine_drift`: parameters, residuals and the Jacobian's sparsity.

    Parameters ``x``: per node a world-frame rotation ``omega (M, 3)`` (rotation vector, applied on
    the left of the rigid fit's body rotation) and translation ``v (M, 3)`` added to its position;
    then the scale error ``e``, the yaw bias ``b`` (rad/m) and, when refined, the clock offset's
    change ``dt`` (s). Between nodes, ``omega`` and ``v`` are interpolated linearly in time.
    """

    def __init__(self, base: np.ndarray, traj_s: np.ndarray, nodes: np.ndarray, path_m: np.ndarray,
                 turn_rad: np.ndarray, body_to_odom: np.ndarray, scale: float, model: DriftModel, refine_clock: bool):
        from scipy.spatial.transform import Rotation, Slerp

        self.base, self.traj_s, self.nodes, self.scale, self.model = base, traj_s, nodes, scale, model
        self.node_s = traj_s[nodes]
        self.M = len(nodes)
        self.n_params = 6 * self.M + 2 + int(refine_clock)
        self.refine_clock = refine_clock
        self.base_rot = Rotation.from_matrix(base[:, :3, :3])
        self.slerp = Slerp(traj_s, self.base_rot)
        rel = np.linalg.inv(body_to_odom[nodes[:-1]]) @ body_to_odom[nodes[1:]]  # odometry between nodes
        self.z_R = rel[:, :3, :3]
        self.z_p = scale * rel[:, :3, 3]
        self.d_m = np.diff(path_m[nodes])
        self.sigma_p, self.sigma_r = _segment_sigmas(self.d_m, np.diff(turn_rad[nodes]), model)
        self.frames: tuple | None = None

    def set_frames(self, frame_s: np.ndarray, offset_s: float, cam_to_world: np.ndarray, sensor_to_body: np.ndarray,
                   sigma_m: float, sigma_rad: float) -> None:
        """The absolute factors: frames at camera times ``frame_s (F,)``, per-component stds."""
        self.frames = (frame_s, offset_s, cam_to_world, sensor_to_body, sigma_m, sigma_rad)

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float, float]:
        M = self.M
        dt = float(x[6 * M + 2]) if self.refine_clock else 0.0
        return x[:3 * M].reshape(M, 3), x[3 * M:6 * M].reshape(M, 3), float(x[6 * M]), float(x[6 * M + 1]), dt

    def _bracket(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per time, the node before it (j, clipped to [0, M - 2]) and the weight of node j + 1."""
        j = np.clip(np.searchsorted(self.node_s, t_s, side="right") - 1, 0, self.M - 2)
        w = np.clip((t_s - self.node_s[j]) / (self.node_s[j + 1] - self.node_s[j]), 0.0, 1.0)
        return j, w

    def poses_at(self, x: np.ndarray, t_s: np.ndarray, base_rot=None, base_p=None) -> tuple[np.ndarray, np.ndarray]:
        """Refined body rotations (T, 3, 3) and positions (T, 3) at odometry times ``t_s (T,)``."""
        from scipy.spatial.transform import Rotation

        omega, v, *_ = self.split(x)
        if base_rot is None:
            base_rot = self.slerp(np.clip(t_s, self.traj_s[0], self.traj_s[-1]))
            base_p = np.stack([np.interp(t_s, self.traj_s, self.base[:, a, 3]) for a in range(3)], axis=-1)
        j, w = self._bracket(t_s)
        om = (1.0 - w)[:, None] * omega[j] + w[:, None] * omega[j + 1]
        dv = (1.0 - w)[:, None] * v[j] + w[:, None] * v[j + 1]
        return (Rotation.from_rotvec(om) * base_rot).as_matrix(), base_p + dv

    def frame_residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera centre differences (F, 3) and rotation vectors (F, 3) of the frames against the graph."""
        from scipy.spatial.transform import Rotation

        frame_s, offset, c2w, s2b, _, _ = self.frames
        *_, dt = self.split(x)
        R, p = self.poses_at(x, frame_s - (offset + dt))
        cam_R = R @ s2b[:, :3, :3]
        cam_p = p + np.einsum("kab,kb->ka", R, s2b[:, :3, 3])
        rot = Rotation.from_matrix(c2w[:, :3, :3].swapaxes(-1, -2) @ cam_R).as_rotvec()
        return cam_p - c2w[:, :3, 3], rot

    def residuals(self, x: np.ndarray) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        m = self.model
        omega, v, e, b, _ = self.split(x)
        node_R = (Rotation.from_rotvec(omega) * self.base_rot[self.nodes]).as_matrix()
        node_p = self.base[self.nodes, :3, 3] + v
        Ra = node_R[:-1]
        est_R = Ra.swapaxes(-1, -2) @ node_R[1:]
        est_p = np.einsum("sba,sb->sa", Ra, node_p[1:] - node_p[:-1])
        z_R = _rz(-b * self.d_m) @ self.z_R  # the heading bias taken out (it turns the body about its z)
        rel_rot = Rotation.from_matrix(z_R.swapaxes(-1, -2) @ est_R).as_rotvec() / self.sigma_r
        rel_pos = (est_p - self.z_p / (1.0 + e)) / self.sigma_p
        dp, dr = self.frame_residuals(x)
        *_, sigma_m, sigma_rad = self.frames
        priors = [e / m.scale_error_sigma, b / math.radians(m.yaw_bias_sigma_deg_per_m)]
        return np.concatenate([rel_rot.ravel(), rel_pos.ravel(), (dr / sigma_rad).ravel(), (dp / sigma_m).ravel(),
                               priors])

    def sparsity(self):
        """The Jacobian's nonzero pattern (rows as in :meth:`residuals`), a scipy.sparse matrix."""
        from scipy.sparse import coo_matrix

        M, S = self.M, self.M - 1
        frame_s, offset, *_ = self.frames
        F = len(frame_s)
        rows, cols = [], []

        def node_cols(j: np.ndarray) -> np.ndarray:  # (n,) nodes -> (n, 6) their columns
            return np.concatenate([3 * j[:, None] + np.arange(3), 3 * M + 3 * j[:, None] + np.arange(3)], axis=1)

        seg = np.arange(S)
        for block in range(2):  # rotation rows, then translation rows: 3 per segment
            r = block * 3 * S + 3 * seg[:, None] + np.arange(3)  # (S, 3)
            c = np.concatenate([node_cols(seg), node_cols(seg + 1), np.full((S, 2), 6 * M), np.full((S, 1), 6 * M + 1)],
                               axis=1)
            rows.append(np.repeat(r, c.shape[1], axis=1).ravel())
            cols.append(np.tile(c, (1, 3)).ravel())
        j, _ = self._bracket(frame_s - offset)
        near = np.stack([np.clip(j + d, 0, M - 1) for d in (-1, 0, 1, 2)], axis=1)  # room for the clock to move
        c = np.concatenate([node_cols(near[:, k]) for k in range(4)] + (
            [np.full((F, 1), 6 * M + 2)] if self.refine_clock else []), axis=1)
        for block in range(2):
            r = 6 * S + block * 3 * F + 3 * np.arange(F)[:, None] + np.arange(3)
            rows.append(np.repeat(r, c.shape[1], axis=1).ravel())
            cols.append(np.tile(c, (1, 3)).ravel())
        rows.append(np.array([6 * S + 6 * F, 6 * S + 6 * F + 1]))
        cols.append(np.array([6 * M, 6 * M + 1]))
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        return coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(6 * S + 6 * F + 2, self.n_params)).tocsr()


def refine_drift(reg: Registration, cam_to_world: np.ndarray, stamps_ns: np.ndarray, sensor_to_body: np.ndarray,
                 body_to_odom: np.ndarray, traj_ns: np.ndarray, options: RegisterOptions = RegisterOptions(),
                 model: DriftModel = DriftModel()) -> DriftRefinement:
    """Bend the rigidly registered odometry onto the localised frames (the pose graph of the module docstring).

    reg: the rigid registration of these very inputs (:func:`register_trajectory`, its inliers,
    clock offset and ``odom_to_world`` are the start); the other arguments as there. Needs at least
    two trajectory poses. Deterministic: a function of its inputs.
    """
    from scipy.optimize import least_squares

    c2w, stamps, s2b, body, traj = _check_inputs(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns)
    if len(body) < 2:
        raise ValueError("body_to_odom: a pose graph needs at least two trajectory poses")
    if not np.all(np.isfinite(reg.odom_to_world)) or reg.used.shape != (len(c2w),):
        raise ValueError("reg: expected a registration of these frames with an odom_to_world")
    t0 = traj[0]
    traj_s = (traj - t0) / 1e9
    frame_s = (stamps - t0) / 1e9
    s = float(reg.scale)
    R0, t_w = reg.odom_to_world[:3, :3] / s, reg.odom_to_world[:3, 3]
    base = apply_sim3_to_poses(s, R0, t_w, body)
    nodes, path_m, turn_rad = drift_nodes(body, s, model.node_spacing_m, math.radians(model.node_spacing_deg))
    refine_clock = model.refine_clock_offset and options.clock_offset_s is None
    graph = _DriftGraph(base, traj_s, nodes, path_m, turn_rad, body, s, model, refine_clock)
    used = reg.used.copy()
    inliers = reg.inliers & used
    # the localised frames' expected error (RMS distance and angle) -> per component
    sigma_m, sigma_rad = options.position_sigma_m, math.radians(options.rotation_sigma_deg)
    floor_m, floor_rad = _SIGMA_FLOOR * sigma_m, _SIGMA_FLOOR * sigma_rad
    x = np.zeros(graph.n_params)
    idx = np.flatnonzero(used)
    rounds, result = 0, None
    for rounds in range(1, model.max_rounds + 1):
        k = np.flatnonzero(inliers)
        graph.set_frames(frame_s[k], reg.clock_offset_s, c2w[k], s2b[k], sigma_m / math.sqrt(3.0),
                         sigma_rad / math.sqrt(3.0))
        result = least_squares(graph.residuals, x, jac_sparsity=graph.sparsity(), method="trf", loss="soft_l1",
                               f_scale=DRIFT_ROBUST_SIGMAS, x_scale="jac")
        x = result.x
        graph.set_frames(frame_s[idx], reg.clock_offset_s, c2w[idx], s2b[idx], 1.0, 1.0)
        dp, dr = graph.frame_residuals(x)
        pos, rot = np.linalg.norm(dp, axis=1), np.linalg.norm(dr, axis=1)
        if rounds == model.max_rounds:
            break
        was = inliers[idx]
        spread_m = max(1.4826 * float(np.median(pos[was])), floor_m)
        spread_rad = max(1.4826 * float(np.median(rot[was])), floor_rad)
        keep = (pos <= SIM3_OUTLIER_SIGMAS * spread_m) & (rot <= SIM3_OUTLIER_SIGMAS * spread_rad)
        if keep.sum() < 3:
            break
        new_m = max(float(np.sqrt(np.mean(pos[keep] ** 2))), floor_m)
        new_rad = max(float(np.sqrt(np.mean(rot[keep] ** 2))), floor_rad)
        if np.array_equal(keep, was) and abs(new_m / sigma_m - 1.0) < 0.1 and abs(new_rad / sigma_rad - 1.0) < 0.1:
            break
        inliers = np.zeros_like(used)
        inliers[idx[keep]] = True
        sigma_m, sigma_rad = new_m, new_rad
    _, _, e, b, dt = graph.split(x)
    R, p = graph.poses_at(x, traj_s, graph.base_rot, base[:, :3, 3])
    refined = np.tile(np.eye(4), (len(traj_s), 1, 1))
    refined[:, :3, :3], refined[:, :3, 3] = R, p
    odom_R = R[0] @ body[0, :3, :3].T
    odom_to_world = sim3_matrix(s, odom_R, p[0] - s * odom_R @ body[0, :3, 3])
    std_m, std_deg, offset_std = _drift_std(result, graph, lever=s * odom_R @ body[0, :3, 3])
    res_m, res_deg = np.full(len(c2w), np.nan), np.full(len(c2w), np.nan)
    res_m[idx], res_deg[idx] = pos, np.degrees(rot)
    drift_deg = np.degrees(np.linalg.norm(np.stack([np.interp(traj_s, graph.node_s, x[a:3 * graph.M:3])
                                                    for a in range(3)], axis=-1), axis=-1))
    return DriftRefinement(
        body_to_world=refined, odom_to_world=odom_to_world, odom_to_world_std_m=std_m, odom_to_world_std_deg=std_deg,
        clock_offset_s=reg.clock_offset_s + dt,
        clock_offset_std_s=offset_std if refine_clock else reg.clock_offset_std_s,
        scale_error=e, yaw_bias_deg_per_m=math.degrees(b), residual_m=res_m, residual_deg=res_deg, used=used,
        inliers=inliers, nodes=nodes, drift_m=np.linalg.norm(p - base[:, :3, 3], axis=1), drift_deg=drift_deg,
        rounds=rounds, cost=float(result.cost))


def _drift_std(result, graph: _DriftGraph, lever: np.ndarray) -> tuple[float, float, float]:
    """Standard errors from the solve's Gauss-Newton Hessian ``J^T J``: of the odometry frame (RMS
    distance, angle in degrees) and of the clock offset (NaN when not refined, inf when singular).

    The odometry frame moves with node 0: its rotation by ``omega_0`` and its origin by ``v_0 +
    omega_0 x (-lever)`` (``lever``: the first body position from the odometry origin, world axes).
    """
    from scipy.sparse import csc_matrix
    from scipy.sparse.linalg import splu

    M = graph.M
    cols = [0, 1, 2, 3 * M, 3 * M + 1, 3 * M + 2] + ([6 * M + 2] if graph.refine_clock else [])
    J = csc_matrix(result.jac)
    H = (J.T @ J).tocsc()
    try:
        lu = splu(H)
        E = np.zeros((graph.n_params, len(cols)))
        E[cols, np.arange(len(cols))] = 1.0
        C = lu.solve(E)[cols]
    except RuntimeError:  # singular: something the frames do not pin down
        return math.inf, math.inf, math.inf if graph.refine_clock else math.nan
    skew = np.array([[0.0, -lever[2], lever[1]], [lever[2], 0.0, -lever[0]], [-lever[1], lever[0], 0.0]])
    A = np.concatenate([skew, np.eye(3)], axis=1)  # origin = v_0 - omega_0 x lever = v_0 + [lever]x omega_0
    cov_t = A @ C[:6, :6] @ A.T
    std_m = math.sqrt(max(float(np.trace(cov_t)), 0.0))
    std_deg = math.degrees(math.sqrt(max(float(np.trace(C[:3, :3])), 0.0)))
    offset_std = math.sqrt(max(float(C[6, 6]), 0.0)) if graph.refine_clock else math.nan
    return std_m, std_deg, offset_std
