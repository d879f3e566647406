"""SE(3) and Sim(3) helpers on top of ``scipy.spatial.transform.Rotation``.

Conventions (see ``nsim.geometry.conventions``): poses are ``(..., 4, 4)`` homogeneous
matrices, rotations ``(..., 3, 3)``, translations and points ``(..., 3)``, quaternions
``wxyz`` (scalar first; scipy is ``xyzw`` and is converted here, nowhere else). A Sim(3)
is the triple ``(s, R, t)`` acting as ``x -> s * R @ x + t``.

``make_se3``, ``invert_se3`` and ``apply_sim3`` also accept torch tensors (same device and
dtype out, differentiable); the rest is numpy float64.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nsim.geometry.array_kind import is_tensor

if TYPE_CHECKING:
    import torch

    Array = np.ndarray | torch.Tensor


def _as_float_array(x) -> Array:
    """Tensors pass through; anything else becomes a floating numpy array."""
    if is_tensor(x):
        return x
    x = np.asarray(x)
    return x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float64)


def _check_shape(name: str, x: Array, tail: tuple[int, ...]) -> None:
    if x.ndim < len(tail) or tuple(x.shape[-len(tail):]) != tail:
        want = "(..., " + ", ".join(map(str, tail)) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {tuple(x.shape)}")


def make_se3(R: Array, t: Array) -> Array:
    """Homogeneous pose from rotation ``R (..., 3, 3)`` and translation ``t (..., 3)``.

    Batch dimensions broadcast. Returns ``(..., 4, 4)`` with last row ``[0, 0, 0, 1]``.
    """
    R, t = _as_float_array(R), _as_float_array(t)
    _check_shape("R", R, (3, 3))
    _check_shape("t", t, (3,))
    if is_tensor(R) or is_tensor(t):
        import torch

        like = R if is_tensor(R) else t
        R, t = (torch.as_tensor(v, device=like.device) for v in (R, t))
        dtype = torch.promote_types(R.dtype, t.dtype)
        batch = torch.broadcast_shapes(R.shape[:-2], t.shape[:-1])
        top = torch.cat([R.to(dtype).expand(*batch, 3, 3), t.to(dtype).expand(*batch, 3)[..., None]], dim=-1)
        bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype, device=top.device)
        return torch.cat([top, bottom.expand(*top.shape[:-2], 1, 4)], dim=-2)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4), dtype=np.result_type(R, t))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_se3(T: Array) -> Array:
    """Inverse of rigid poses ``T (..., 4, 4)``: ``[R^T, -R^T t]``. Returns ``(..., 4, 4)``."""
    T = _as_float_array(T)
    _check_shape("T", T, (4, 4))
    R_inv = T[..., :3, :3].swapaxes(-1, -2)
    t_inv = -(R_inv @ T[..., :3, 3:4])[..., 0]
    return make_se3(R_inv, t_inv)


def quat_wxyz_from_matrix(R: Array) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` wxyz with ``w >= 0`` from rotations ``R (..., 3, 3)``."""
    R = np.asarray(R, dtype=np.float64)
    _check_shape("R", R, (3, 3))
    from scipy.spatial.transform import Rotation  # scipy on use: numpy-only callers start fast

    q_xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = q_xyzw[:, [3, 0, 1, 2]]
    q = np.where(q[:, :1] < 0.0, -q, q)  # q and -q are the same rotation; pick w >= 0
    return q.reshape(R.shape[:-2] + (4,))


def matrix_from_quat_wxyz(q_wxyz: Array) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` from quaternions ``(..., 4)`` wxyz (normalised first)."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    _check_shape("q_wxyz", q, (4,))
    norm = np.linalg.norm(q, axis=-1)
    if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
        raise ValueError("q_wxyz: quaternions must be finite and nonzero")
    from scipy.spatial.transform import Rotation  # scipy on use: numpy-only callers start fast

    R = Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix()
    return R.reshape(q.shape[:-1] + (3, 3))


def se3_from_quat_wxyz_t(q_wxyz: Array, t: Array) -> np.ndarray:
    """Poses ``(..., 4, 4)`` from quaternions ``(..., 4)`` wxyz and translations ``(..., 3)``."""
    return make_se3(matrix_from_quat_wxyz(q_wxyz), np.asarray(t, dtype=np.float64))


def umeyama(src_xyz: Array, dst_xyz: Array, with_scale: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama 1991) minimising ``sum ||dst - (s R src + t)||^2``.

    src_xyz, dst_xyz: (N, 3) corresponding points, N >= 3, src not all collinear.
    Returns ``(s, R (3, 3), t (3,))``; ``s == 1.0`` when ``with_scale`` is False.
    """
    src = np.asarray(src_xyz, dtype=np.float64)
    dst = np.asarray(dst_xyz, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise ValueError(f"umeyama: expected src, dst of equal shape (N, 3), got {src.shape} and {dst.shape}")
    if src.shape[0] < 3:
        raise ValueError(f"umeyama: need at least 3 point pairs, got {src.shape[0]}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise ValueError("umeyama: points must be finite")
    mu_src, mu_dst = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - mu_src, dst - mu_dst
    var_src = np.mean(np.sum(src_c**2, axis=1))
    cov = dst_c.T @ src_c / src.shape[0]
    U, D, Vt = np.linalg.svd(cov)
    if var_src < 1e-24 or D[1] < 1e-12 * max(D[0], 1e-300):
        raise ValueError("umeyama: degenerate configuration (points coincide or are collinear)")
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2] = -1.0  # reflection: flip the weakest axis to get a proper rotation
    R = (U * S) @ Vt
    s = float(np.dot(D, S) / var_src) if with_scale else 1.0
    t = mu_dst - s * R @ mu_src
    return s, R, t


def apply_sim3(s: float, R: Array, t: Array, points_xyz: Array) -> Array:
    """``s * R @ p + t`` for points ``(..., 3)``; ``R (3, 3)``, ``t (3,)``. Returns ``(..., 3)``."""
    points_xyz = _as_float_array(points_xyz)
    _check_shape("points_xyz", points_xyz, (3,))
    if is_tensor(points_xyz):
        import torch

        R = torch.as_tensor(R, dtype=points_xyz.dtype, device=points_xyz.device)
        t = torch.as_tensor(t, dtype=points_xyz.dtype, device=points_xyz.device)
    else:
        R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    return s * points_xyz @ R.T + t


def rotation_angle_deg(R_a: Array, R_b: Array) -> np.ndarray:
    """Geodesic angle between rotations, in degrees, in ``[0, 180]``.

    R_a, R_b: (..., 3, 3), batch dimensions broadcast. Returns (...) float64.
    """
    R_a = np.asarray(R_a, dtype=np.float64)
    R_b = np.asarray(R_b, dtype=np.float64)
    _check_shape("R_a", R_a, (3, 3))
    _check_shape("R_b", R_b, (3, 3))
    R_rel = R_a.swapaxes(-1, -2) @ R_b
    from scipy.spatial.transform import Rotation  # scipy on use: numpy-only callers start fast

    angle = Rotation.from_matrix(R_rel.reshape(-1, 3, 3)).magnitude()
    return np.degrees(angle).reshape(R_rel.shape[:-2])


def look_at(eye: Array, target: Array, up: Array = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``cam_to_world (..., 4, 4)`` (OpenCV axes) of a camera at ``eye`` looking at ``target``.

    eye, target, up: (..., 3) world points / direction (batch dimensions broadcast). Camera
    +z points from eye to target, +y points "down" (against ``up``), +x to the right.
    Raises ValueError when eye == target or the view direction is parallel to ``up``.
    """
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    for name, v in (("eye", eye), ("target", target), ("up", up)):
        _check_shape(name, v, (3,))
    z = target - eye
    z_norm = np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, up)
    x_norm = np.linalg.norm(x, axis=-1, keepdims=True)
    if np.any(z_norm < 1e-12):
        raise ValueError("look_at: eye and target coincide")
    if np.any(x_norm < 1e-9 * z_norm * np.linalg.norm(up, axis=-1, keepdims=True)):
        raise ValueError("look_at: view direction is parallel to up")
    z, x = z / z_norm, x / x_norm
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=-1)  # columns are the camera axes in world coordinates
    return make_se3(R, np.broadcast_to(eye, R.shape[:-1]))


def is_rotation(R: Array, tol: float = 1e-6) -> np.ndarray:
    """Whether each ``R (..., 3, 3)`` is orthonormal with det +1 (within ``tol``, finite).

    Returns a bool array of shape (...); a 0-d array for a single matrix (usable in ``if``).
    """
    R = np.asarray(R, dtype=np.float64)
    _check_shape("R", R, (3, 3))
    finite = np.all(np.isfinite(R), axis=(-2, -1))
    R = np.where(finite[..., None, None], R, 0.0)
    ortho_err = np.abs(R.swapaxes(-1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
    det_err = np.abs(np.linalg.det(R) - 1.0)
    return finite & (ortho_err <= tol) & (det_err <= tol)


def interpolate_poses(times_s: np.ndarray, poses_se3: np.ndarray, query_s: np.ndarray) -> np.ndarray:
    """Poses ``(T, 4, 4)`` at ``query_s (T,)`` from timed poses ``(S,)``, ``(S, 4, 4)``.

    Positions are linear, rotations slerped between samples; outside the samples' span the first
    or last pose is held.
    """
    from scipy.spatial.transform import Rotation, Slerp

    t = np.asarray(times_s, dtype=np.float64)
    q = np.clip(np.asarray(query_s, dtype=np.float64), t[0], t[-1])
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for axis in range(3):
        out[:, axis, 3] = np.interp(q, t, poses_se3[:, axis, 3])
    if len(t) == 1:
        out[:, :3, :3] = poses_se3[0, :3, :3]
    else:
        out[:, :3, :3] = Slerp(t, Rotation.from_matrix(poses_se3[:, :3, :3]))(q).as_matrix()
    return out
