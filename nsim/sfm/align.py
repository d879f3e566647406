"""From SfM's arbitrary frame to a metric, z-up world; and pose errors against ground truth.

Every transform here is a similarity ``x -> s * R @ x + t`` written ``(s, R, t)``; a rigid one
has ``s == 1``. Poses are ``cam_to_world (N, 4, 4)`` with OpenCV camera axes (+y down).

* :func:`gravity_align` finds the floor among the sparse points (the largest roughly
  horizontal plane below the cameras; "up" first comes from the cameras, whose mean -y axis
  points up for a hand-held capture) and returns the rigid motion putting the floor at
  ``z = 0`` with ``+z`` up.
* Metric scale then comes from one of: a reference trajectory (:func:`fit_sim3` between
  associated camera centres: :func:`associate_by_name`, :func:`associate_by_time`), a known
  distance between two reconstructed points (:func:`scale_from_known_distance`), or the
  camera height above the floor (:func:`scale_from_camera_height`).
* :func:`pose_errors` compares poses with ground truth after a Sim(3) fit of the centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import PurePosixPath

import numpy as np

from nsim.errors import InputError
from nsim.geometry.transforms import rotation_angle_deg, umeyama

#: Pairs whose residual exceeds this many robust standard deviations are dropped from a Sim(3) fit.
SIM3_OUTLIER_SIGMAS = 4.0


# --------------------------------------------------------------------------------------
# Sim(3)
# --------------------------------------------------------------------------------------


def umeyama_sim3(src_xyz: np.ndarray, dst_xyz: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity with ``dst ~ s R src + t`` for (N, 3) points, N >= 3.

    Thin wrapper over :func:`nsim.geometry.transforms.umeyama` (``with_scale=True``).
    """
    return umeyama(src_xyz, dst_xyz, with_scale=True)


def sim3_matrix(s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) matrix ``[[s R, t], [0, 1]]`` acting on homogeneous points."""
    T = np.eye(4)
    T[:3, :3] = s * np.asarray(R, dtype=np.float64)
    T[:3, 3] = t
    return T


def apply_sim3_to_points(s: float, R: np.ndarray, t: np.ndarray, points_xyz: np.ndarray) -> np.ndarray:
    """``s R p + t`` for (..., 3) points."""
    return s * np.asarray(points_xyz, dtype=np.float64) @ np.asarray(R).T + np.asarray(t)


def apply_sim3_to_poses(s: float, R: np.ndarray, t: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """cam_to_world (..., 4, 4) in the new world: rotation ``R R_c``, centre ``s R c + t`` (stays rigid)."""
    c2w = np.array(cam_to_world, dtype=np.float64)
    out = c2w.copy()
    out[..., :3, :3] = np.asarray(R) @ c2w[..., :3, :3]
    out[..., :3, 3] = apply_sim3_to_points(s, R, t, c2w[..., :3, 3])
    return out


@dataclass(frozen=True)
class Sim3Fit:
    """A Sim(3) from estimated to reference centres.

    residuals_m: (N,) distance of each pair after the fit (reference units, metres);
    inliers: (N,) bool, the pairs used in the final fit.
    """

    s: float
    R: np.ndarray
    t: np.ndarray
    residuals_m: np.ndarray
    inliers: np.ndarray

    @property
    def rms_m(self) -> float:
        """RMS residual over the inlier pairs."""
        return float(np.sqrt(np.mean(self.residuals_m[self.inliers] ** 2)))

    @property
    def median_m(self) -> float:
        return float(np.median(self.residuals_m[self.inliers]))


def fit_sim3(src_xyz: np.ndarray, dst_xyz: np.ndarray, robust: bool = True, max_rounds: int = 5) -> Sim3Fit:
    """Sim(3) mapping ``src`` (N, 3) onto ``dst`` (N, 3), N >= 3.

    With ``robust``, pairs whose residual exceeds ``SIM3_OUTLIER_SIGMAS`` robust standard
    deviations (1.4826 * median) are dropped and the fit repeated, keeping at least half the
    pairs (a mis-registered frame or a wrong association should not bend the whole fit).
    """
    src = np.asarray(src_xyz, dtype=np.float64)
    dst = np.asarray(dst_xyz, dtype=np.float64)
    inliers = np.ones(len(src), dtype=bool)
    s, R, t = umeyama_sim3(src, dst)
    for _ in range(max_rounds if robust else 0):
        res = np.linalg.norm(apply_sim3_to_points(s, R, t, src) - dst, axis=1)
        sigma = 1.4826 * float(np.median(res))
        keep = res <= max(SIM3_OUTLIER_SIGMAS * sigma, 1e-12)
        if keep.sum() < max(3, len(src) // 2) or np.array_equal(keep, inliers):
            break
        inliers = keep
        s, R, t = umeyama_sim3(src[inliers], dst[inliers])
    res = np.linalg.norm(apply_sim3_to_points(s, R, t, src) - dst, axis=1)
    return Sim3Fit(float(s), R, t, res, inliers)


# --------------------------------------------------------------------------------------
# Associating estimated frames with a reference
# --------------------------------------------------------------------------------------


def _stem(name: str) -> str:
    return PurePosixPath(name.replace("\\", "/")).stem


def associate_by_name(est_names: list[str], ref_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of frames with the same file stem (``images/frame_00012.png`` ~ ``frame_00012.png``).

    Returns (idx_est, idx_ref): (M,) int64, sorted by idx_est. A stem that appears twice in the
    reference is ambiguous and matches nothing.
    """
    ref_index: dict[str, int] = {}
    dup: set[str] = set()
    for j, name in enumerate(ref_names):
        stem = _stem(name)
        if stem in ref_index:
            dup.add(stem)
        ref_index[stem] = j
    pairs = [(i, ref_index[_stem(n)]) for i, n in enumerate(est_names) if _stem(n) in ref_index and _stem(n) not in dup]
    arr = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def associate_by_time(est_times_s: np.ndarray, ref_times_s: np.ndarray, max_dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of frames whose timestamps differ by at most ``max_dt_s`` (TUM ``associate``: greedy, nearest first).

    Returns (idx_est, idx_ref): (M,) int64, sorted by idx_est.
    """
    from nsim.io.tum import Trajectory, associate

    def traj(times: np.ndarray) -> Trajectory:
        times = np.asarray(times, dtype=np.float64)
        quat = np.tile([1.0, 0.0, 0.0, 0.0], (len(times), 1))
        return Trajectory(times, np.zeros((len(times), 3)), quat)

    return associate(traj(est_times_s), traj(ref_times_s), max_dt_s)


def require_matches(n_matched: int, n_frames: int, source: str, how: str, minimum: int = 3) -> None:
    """InputError when fewer than ``minimum`` frames matched the reference ``source``."""
    if n_matched < minimum:
        raise InputError(
            f"{source}: only {n_matched} of {n_frames} registered frames match a reference pose {how}; "
            f"need at least {minimum} (check that the reference belongs to this video)")


# --------------------------------------------------------------------------------------
# Gravity: floor plane, z up
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GravityFit:
    """A rigid motion (``s == 1``) putting the floor at z = 0 with +z up.

    T: (4, 4) world_new_from_world_old; up_old: (3,) the up direction in the old frame;
    floor_found: whether a floor plane was found (otherwise up comes from the cameras and
    z = 0 is the 2nd percentile of point heights); floor_inliers: points on the floor plane.
    """

    T: np.ndarray
    up_old: np.ndarray
    floor_found: bool
    floor_inliers: int

    @property
    def R(self) -> np.ndarray:
        return self.T[:3, :3]

    @property
    def t(self) -> np.ndarray:
        return self.T[:3, 3]


def _rotation_to_z(n: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``n`` to +z."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, z)
    c = float(np.dot(n, z))
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1.0 / (1.0 + c))


def _fit_plane(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    n = vt[-1]
    n = n if np.dot(n, up) >= 0 else -n
    return n, float(np.dot(n, centre))


def _ransac_plane(pts: np.ndarray, up: np.ndarray, max_height: float, tol: float, cos_max: float,
                  iterations: int, min_points: int, rng: np.random.Generator) -> tuple[np.ndarray, float] | None:
    """Plane ``n . x = d`` with the most inliers among those with ``n . up >= cos_max`` and ``d < max_height``.

    The winner is refined by least squares on its inliers (three rounds); None when it has
    fewer than ``min_points`` inliers.
    """
    if len(pts) < max(min_points, 3):
        return None
    samples = rng.integers(0, len(pts), size=(iterations, 3))
    a, b, c = pts[samples[:, 0]], pts[samples[:, 1]], pts[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    normals[ok] /= norms[ok, None]
    normals *= np.where(normals @ up >= 0.0, 1.0, -1.0)[:, None]
    offsets = np.einsum("ij,ij->i", normals, a)
    ok &= (normals @ up >= cos_max) & (offsets < max_height)
    best, best_count = None, 0
    for k in np.flatnonzero(ok):
        count = int(np.count_nonzero(np.abs(pts @ normals[k] - offsets[k]) < tol))
        if count > best_count:
            best, best_count = k, count
    if best is None or best_count < min_points:
        return None
    n, d = normals[best], float(offsets[best])
    for _ in range(3):
        inl = np.abs(pts @ n - d) < tol
        if inl.sum() < 3:
            return None
        n, d = _fit_plane(pts[inl], up)
    if np.count_nonzero(np.abs(pts @ n - d) < tol) < min_points or n @ up < cos_max:
        return None
    return n, d


def gravity_align(
    points_xyz: np.ndarray,
    cam_to_world: np.ndarray,
    max_tilt_deg: float = 30.0,
    iterations: int = 1000,
    min_floor_points: int = 30,
    seed: int = 0,
) -> GravityFit:
    """Rigid motion making +z up and the floor z = 0.

    points_xyz: (P, 3) sparse points; cam_to_world: (N, 4, 4) OpenCV axes. "Up" is first the
    mean of the cameras' -y axes. RANSAC finds the plane with the most inliers among those
    whose normal is within ``max_tilt_deg`` of it and that lie below the lowest 10% of the
    cameras. If another such plane lies clearly below it (10 tolerances) with at least 30% as
    many inliers, that one is the floor (a textured table top over a plainer floor). The
    inlier tolerance is 1% of the points' median distance from their median; planes are
    refined by least squares, and the floor's normal becomes +z.
    """
    pts = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    c2w = np.asarray(cam_to_world, dtype=np.float64)
    up0 = -c2w[:, :3, 1].mean(axis=0)
    if np.linalg.norm(up0) < 1e-6:
        raise InputError("gravity alignment: the cameras' up directions cancel out; cannot tell which way is up")
    up0 /= np.linalg.norm(up0)
    centres = c2w[:, :3, 3]
    rng = np.random.default_rng(seed)
    cos_max = math.cos(math.radians(max_tilt_deg))
    plane = None
    if len(pts) >= max(min_floor_points, 3):
        scale = float(np.median(np.linalg.norm(pts - np.median(pts, axis=0), axis=1)))
        tol = 0.01 * max(scale, 1e-12)
        max_height = float(np.quantile(centres @ up0, 0.1)) - tol
        plane = _ransac_plane(pts, up0, max_height, tol, cos_max, iterations, min_floor_points, rng)
        if plane is not None:
            n, d = plane
            count = int(np.count_nonzero(np.abs(pts @ n - d) < tol))
            below = pts[pts @ n < d - 10.0 * tol]
            lower = _ransac_plane(below, up0, max_height, tol, cos_max, iterations,
                                  max(min_floor_points, int(np.ceil(0.3 * count))), rng)
            plane = lower if lower is not None else plane
    if plane is not None:
        normal, offset = plane
        n_inliers = int(np.count_nonzero(np.abs(pts @ normal - offset) < tol))
    else:
        heights = pts @ up0 if len(pts) else centres @ up0
        normal, offset, n_inliers = up0, float(np.quantile(heights, 0.02)), 0
    R = _rotation_to_z(normal)
    T = np.eye(4)
    T[:3, :3] = R
    T[2, 3] = -offset
    return GravityFit(T, normal, plane is not None, n_inliers)


# --------------------------------------------------------------------------------------
# Metric scale without a reference
# --------------------------------------------------------------------------------------


def scale_from_known_distance(point_a_xyz: np.ndarray, point_b_xyz: np.ndarray, distance_m: float) -> float:
    """Scale making the reconstructed points ``a`` and ``b`` (each (3,)) ``distance_m`` apart."""
    if not (math.isfinite(distance_m) and distance_m > 0.0):
        raise InputError(f"known distance: expected a distance > 0 m, got {distance_m}")
    d = float(np.linalg.norm(np.asarray(point_a_xyz, dtype=np.float64) - np.asarray(point_b_xyz, dtype=np.float64)))
    if not d > 0.0:
        raise InputError("known distance: the two points coincide; pick two distinct points")
    return distance_m / d


def scale_from_camera_height(cam_to_world_zup: np.ndarray, height_m: float) -> float:
    """Scale making the median camera height above the floor ``height_m``.

    cam_to_world_zup: (N, 4, 4) already gravity-aligned (floor at z = 0, +z up).
    """
    if not (math.isfinite(height_m) and height_m > 0.0):
        raise InputError(f"camera height: expected a height > 0 m, got {height_m}")
    z = float(np.median(np.asarray(cam_to_world_zup)[:, 2, 3]))
    if not z > 0.0:
        raise InputError("camera height: the cameras are not above the detected floor; "
                         "use --known-distance or --reference instead")
    return height_m / z


# --------------------------------------------------------------------------------------
# Errors against ground truth
# --------------------------------------------------------------------------------------


def pose_errors(est_cam_to_world: np.ndarray, gt_cam_to_world: np.ndarray,
                robust: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose rotation error (deg) and position error (GT units) after a Sim(3) fit of the centres.

    est_cam_to_world, gt_cam_to_world: (N, 4, 4) corresponding poses, N >= 3. The fit is plain
    least squares (evo's APE convention), so one wildly wrong pose also shifts the others'
    errors; ``robust`` fits on the inliers of :func:`fit_sim3` instead (every pose is still
    scored). Returns (N,), (N,).
    """
    est = np.asarray(est_cam_to_world, dtype=np.float64)
    gt = np.asarray(gt_cam_to_world, dtype=np.float64)
    fit = fit_sim3(est[:, :3, 3], gt[:, :3, 3], robust=robust)
    aligned = apply_sim3_to_poses(fit.s, fit.R, fit.t, est)
    rot_err_deg = rotation_angle_deg(aligned[:, :3, :3], gt[:, :3, :3])
    pos_err = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    return rot_err_deg, pos_err
