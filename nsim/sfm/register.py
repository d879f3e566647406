"""Register a robot's odometry frame in a scene's world from its localised camera frames.

A robot's recording gives its body's trajectory ``body_to_odom (N, 4, 4)`` at ``traj_ns (N,)``
in its own odometry frame, and camera frames stamped on the cameras' clock. Localised in the
scene (``nsim.sfm.localize``), K of those frames have poses ``cam_to_world (K, 4, 4)`` in the
scene's world. This module finds what ties the two together:

* ``odom_to_world``: the odometry frame's pose in the world, a rigid motion (``with_scale``: a
  similarity, for odometry whose scale is not trusted);
* ``clock_offset_s``: the cameras' clock minus the odometry's, so that a frame stamped ``s`` was
  captured at odometry time ``s - clock_offset_s`` (the convention of
  ``nsim.synth.faulty_robot_log``); searched or given.

The model. A frame k from a camera mounted at ``sensor_to_body_k`` has, in the odometry frame,
``cam_to_odom_k = B(t_k - clock_offset_s) @ sensor_to_body_k`` (``B`` interpolated between
trajectory poses by :func:`nsim.geometry.transforms.interpolate_poses`: positions linearly,
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

Drift. One rigid motion cannot absorb odometry that drifts: ``register_trajectory(...,
drift=DriftModel())`` then refines the rigid fit with the pose graph of
``nsim.sfm.drift_refinement`` (:func:`~nsim.sfm.drift_refinement.refine_drift`), and the residual
limits apply to the refined residuals, not the rigid fit's.

The options, the results and the input checks shared with the drift refinement live in
``nsim.sfm.registration_types``.

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

from nsim.sfm.align import SIM3_OUTLIER_SIGMAS, sim3_matrix
from nsim.sfm.drift_refinement import DriftModel, refine_drift
from nsim.sfm.registration_types import (
    SIGMA_FLOOR,
    DriftRefinement,
    RegisterOptions,
    Registration,
    check_inputs,
)

log = logging.getLogger(__name__)

#: At most this many frames propose a motion in the robust start (evenly spaced in time).
MAX_HYPOTHESES = 200
#: Times this close count as equal (float seconds from nanosecond stamps round): a frame whose
#: odometry time is the trajectory's last stamp lies inside it.
_TIME_TOLERANCE_S = 1e-6


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
    current inliers (at least the expected error x ``SIGMA_FLOOR``), so that a fit agreed on by
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
        sm = max(1.4826 * float(np.median(p_res[inliers])), SIGMA_FLOOR * sigma_m)
        sr = max(1.4826 * float(np.median(r_res[inliers])), SIGMA_FLOOR * sigma_rad)
        keep = (p_res <= SIM3_OUTLIER_SIGMAS * sm) & (r_res <= SIM3_OUTLIER_SIGMAS * sr)
        if not keep.any() or np.array_equal(keep, inliers):
            break
        inliers = keep
    s, R, t = fit_pose_pairs(pairs[inliers], with_scale, sm, sr)
    p_res, r_res = pose_residuals(s, R, t, pairs)
    spread_m = max(float(np.sqrt(np.mean(p_res[inliers] ** 2))), SIGMA_FLOOR * sigma_m)
    spread_rad = max(float(np.sqrt(np.mean(r_res[inliers] ** 2))), SIGMA_FLOOR * sigma_rad)
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


# --------------------------------------------------------------------------------------
# Registration
# --------------------------------------------------------------------------------------


def register_trajectory(
    cam_to_world: np.ndarray,
    stamps_ns: np.ndarray,
    sensor_to_body: np.ndarray,
    body_to_odom: np.ndarray,
    traj_ns: np.ndarray,
    options: RegisterOptions = RegisterOptions(),  # noqa: B008  (frozen: immutable)
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
    c2w, stamps, s2b, body, traj = check_inputs(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns)
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
