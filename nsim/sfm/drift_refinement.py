"""Drift refinement: a pose graph that bends rigidly registered odometry onto the localised frames.

One rigid motion cannot absorb odometry that drifts: on a 16 m run of the robot-log
generator's default faults it leaves the odometry frame 4.5 cm and 1.7 deg off, and the clock
offset 4 ms. :func:`refine_drift` (``nsim.sfm.register.register_trajectory(...,
drift=DriftModel())``) starts from the rigid fit (its inliers, clock offset and
``odom_to_world``) and solves a pose graph over the odometry with ``scipy.optimize.least_squares``
(soft_l1 loss, ``DRIFT_ROBUST_SIGMAS``):

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
``B_0 @ inv(O_0)``; its standard error comes from the solve's Jacobian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nsim.config import param
from nsim.sfm.align import SIM3_OUTLIER_SIGMAS, apply_sim3_to_poses, sim3_matrix
from nsim.sfm.registration_types import (
    SIGMA_FLOOR,
    DriftRefinement,
    RegisterOptions,
    Registration,
    check_inputs,
)

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
                 body_to_odom: np.ndarray, traj_ns: np.ndarray,
                 options: RegisterOptions = RegisterOptions(),  # noqa: B008  (frozen: immutable)
                 model: DriftModel = DriftModel()) -> DriftRefinement:
    """Bend the rigidly registered odometry onto the localised frames (the pose graph of the module docstring).

    reg: the rigid registration of these very inputs (:func:`register_trajectory`, its inliers,
    clock offset and ``odom_to_world`` are the start); the other arguments as there. Needs at least
    two trajectory poses. Deterministic: a function of its inputs.
    """
    from scipy.optimize import least_squares

    c2w, stamps, s2b, body, traj = check_inputs(cam_to_world, stamps_ns, sensor_to_body, body_to_odom, traj_ns)
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
    floor_m, floor_rad = SIGMA_FLOOR * sigma_m, SIGMA_FLOOR * sigma_rad
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
