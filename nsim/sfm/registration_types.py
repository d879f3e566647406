"""The types of registering a robot's odometry in a scene: its options, results and checked inputs.

Shared by the rigid fit (``nsim.sfm.register``) and the drift refinement
(``nsim.sfm.drift_refinement``), below both: :class:`RegisterOptions` (how to register),
:class:`Registration` (the rigid fit) and :class:`DriftRefinement` (the pose graph's result), both
reporting :class:`ResidualStats` over their inliers, and :func:`check_inputs` (the localised frames
and the odometry trajectory, checked and converted). ``nsim.sfm.register`` uses all of these, so
``from nsim.sfm.register import RegisterOptions, Registration`` keeps working.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nsim.config import param
from nsim.errors import InputError
from nsim.geometry.transforms import is_rotation
from nsim.sfm.align import apply_sim3_to_poses

#: Floors on the residuals' standard deviations, as fractions of the expected ones (exact data).
SIGMA_FLOOR = 1e-3


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


class ResidualStats:
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
class Registration(ResidualStats):
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


@dataclass(frozen=True, eq=False)
class DriftRefinement(ResidualStats):
    """The odometry bent onto the localised frames by :func:`nsim.sfm.drift_refinement.refine_drift`.

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


def check_inputs(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns):
    """The arguments of ``register_trajectory`` / ``refine_drift`` checked and converted.

    Returns ``(cam_to_world (K, 4, 4) float64, stamps_ns (K,) int64, sensor_to_body (K, 4, 4),
    body_to_odom (N, 4, 4) float64, traj_ns (N,) int64)``; ValueError names the first bad one.
    """
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
