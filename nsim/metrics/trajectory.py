"""Trajectory accuracy: absolute trajectory error (ATE) and relative pose error (RPE), as evo computes them.

Trajectories are ``nsim.io.tum.Trajectory`` (body-to-world poses, TUM files via ``read_tum``). Poses
are paired by timestamp with ``nsim.io.tum.associate`` (nearest pairs first, |dt| <= ``max_dt_s``).

ATE (Sturm et al. 2012; evo ``ape``, translation part): the estimate is aligned to the reference by
Umeyama's least-squares fit of the matched positions -- ``"se3"`` (rotation + translation), ``"sim3"``
(plus scale, for monocular estimates) or ``"none"`` -- giving ``p' = s R p + t`` and ``R_i' = R R_i``;
the errors are ``|q_i - p'_i|`` (metres) and the angle of ``R_q_i^T R'_i`` (degrees).

RPE (evo ``rpe``): for index pairs ``(i, j = i + delta)`` of the matched sequence, the error pose is
``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``; the translation error is ``|t(E)|`` (metres), the rotation error
the angle of ``R(E)`` (degrees). ``all_pairs=True`` uses every ``i`` (the TUM benchmark's choice),
``False`` only ``i = 0, delta, 2 delta, ...`` (evo's default). An SE(3) alignment leaves RPE unchanged;
``"sim3"`` corrects the estimate's scale first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nsim.errors import InputError
from nsim.geometry.transforms import rotation_angle_deg, umeyama
from nsim.io.tum import Trajectory, associate

ALIGNMENTS = ("none", "se3", "sim3")
DEFAULT_MAX_DT_S = 0.01  # evo's default association window


@dataclass(frozen=True, eq=False)
class AlignedPair:
    """Matched poses, the estimate aligned: ``x -> scale * rotation @ x + translation_m``.

    timestamps_s: (M,) of the reference; ref_poses_se3, est_poses_se3: (M, 4, 4) body-to-world
    (the estimate's after alignment; with Sim(3) its positions are scaled, rotations stay rotations).
    """

    timestamps_s: np.ndarray
    ref_poses_se3: np.ndarray
    est_poses_se3: np.ndarray
    alignment: str
    scale: float
    rotation: np.ndarray
    translation_m: np.ndarray


def _check_alignment(alignment: str) -> None:
    if alignment not in ALIGNMENTS:
        raise ValueError(f"alignment: expected one of {ALIGNMENTS}, got {alignment!r}")


def align_trajectories(
    reference: Trajectory, estimate: Trajectory, alignment: str = "se3", max_dt_s: float = DEFAULT_MAX_DT_S
) -> AlignedPair:
    """Pair poses by timestamp and align the estimate to the reference (module docstring).

    Raises InputError when no timestamps match, or when "se3"/"sim3" is asked for with fewer than 3
    matched poses or with collinear positions.
    """
    _check_alignment(alignment)
    idx_ref, idx_est = associate(reference, estimate, max_dt_s)
    if len(idx_ref) == 0:
        spans = [
            f"{name} [{t[0]:.6f}, {t[-1]:.6f}]" if len(t) else f"{name} empty"
            for name, t in (("reference", reference.timestamps_s), ("estimate", estimate.timestamps_s))
        ]
        raise InputError(
            f"trajectories have no common timestamps (|dt| <= {max_dt_s} s); time spans: {', '.join(spans)}"
        )
    ref = reference.poses_se3()[idx_ref]
    est = estimate.poses_se3()[idx_est]
    s, R, t = 1.0, np.eye(3), np.zeros(3)
    if alignment != "none":
        try:
            s, R, t = umeyama(est[:, :3, 3], ref[:, :3, 3], with_scale=alignment == "sim3")
        except ValueError as err:
            raise InputError(
                f"cannot align trajectories ({alignment}) on {len(idx_ref)} matched poses: {err}"
            ) from None
        est = est.copy()
        est[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
        est[:, :3, :3] = R @ est[:, :3, :3]
    return AlignedPair(reference.timestamps_s[idx_ref], ref, est, alignment, float(s), R, t)


def _rmse(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


@dataclass(frozen=True, eq=False)
class AteResult:
    """Absolute trajectory error over ``n_matched`` poses after ``alignment`` (see ``AlignedPair``).

    errors_m, rot_errors_deg: (n_matched,) per-pose errors; the rest summarise them.
    """

    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float
    rot_rmse_deg: float
    n_matched: int
    alignment: str
    scale: float
    rotation: np.ndarray
    translation_m: np.ndarray
    errors_m: np.ndarray
    rot_errors_deg: np.ndarray

    def row(self) -> dict[str, float | int | str]:
        return {"ATE RMSE [m]": self.rmse_m, "ATE rot RMSE [deg]": self.rot_rmse_deg,
                "alignment": self.alignment, "poses": self.n_matched}  # fmt: skip


def ate(
    reference: Trajectory, estimate: Trajectory, alignment: str = "se3", max_dt_s: float = DEFAULT_MAX_DT_S
) -> AteResult:
    """Absolute trajectory error of ``estimate`` against ``reference`` (module docstring)."""
    pair = align_trajectories(reference, estimate, alignment, max_dt_s)
    errors = np.linalg.norm(pair.ref_poses_se3[:, :3, 3] - pair.est_poses_se3[:, :3, 3], axis=1)
    rot_errors = rotation_angle_deg(pair.ref_poses_se3[:, :3, :3], pair.est_poses_se3[:, :3, :3])
    return AteResult(
        rmse_m=_rmse(errors),
        mean_m=float(errors.mean()),
        median_m=float(np.median(errors)),
        max_m=float(errors.max()),
        rot_rmse_deg=_rmse(rot_errors),
        n_matched=len(errors),
        alignment=alignment,
        scale=pair.scale,
        rotation=pair.rotation,
        translation_m=pair.translation_m,
        errors_m=errors,
        rot_errors_deg=rot_errors,
    )


@dataclass(frozen=True, eq=False)
class RpeResult:
    """Relative pose error over ``n_pairs`` pose pairs ``delta_frames`` apart.

    trans_errors_m, rot_errors_deg: (n_pairs,) per-pair errors; the rest summarise them.
    """

    delta_frames: int
    trans_rmse_m: float
    trans_mean_m: float
    trans_median_m: float
    trans_max_m: float
    rot_rmse_deg: float
    rot_mean_deg: float
    rot_median_deg: float
    rot_max_deg: float
    n_pairs: int
    all_pairs: bool
    alignment: str
    trans_errors_m: np.ndarray
    rot_errors_deg: np.ndarray

    def row(self) -> dict[str, float | int | str]:
        return {"RPE Δ [frames]": self.delta_frames, "RPE trans RMSE [m]": self.trans_rmse_m,
                "RPE rot RMSE [deg]": self.rot_rmse_deg, "pairs": self.n_pairs}  # fmt: skip


def _inv_mul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 @ B`` for rigid poses A, B: (M, 4, 4)."""
    R_A_T = A[:, :3, :3].transpose(0, 2, 1)
    out = np.tile(np.eye(4), (len(A), 1, 1))
    out[:, :3, :3] = R_A_T @ B[:, :3, :3]
    out[:, :3, 3] = (R_A_T @ (B[:, :3, 3] - A[:, :3, 3])[..., None])[..., 0]
    return out


def rpe(
    reference: Trajectory,
    estimate: Trajectory,
    delta_frames: int = 1,
    all_pairs: bool = True,
    alignment: str = "none",
    max_dt_s: float = DEFAULT_MAX_DT_S,
) -> RpeResult:
    """Relative pose error at ``delta_frames`` (module docstring). Raises InputError when fewer than
    ``delta_frames + 1`` poses match.
    """
    if isinstance(delta_frames, bool) or not isinstance(delta_frames, (int, np.integer)) or delta_frames < 1:
        raise ValueError(f"rpe: delta_frames must be an int >= 1, got {delta_frames!r}")
    pair = align_trajectories(reference, estimate, alignment, max_dt_s)
    n = len(pair.timestamps_s)
    if n <= delta_frames:
        raise InputError(
            f"RPE: a delta of {delta_frames} frames needs more than {delta_frames} matched poses, got {n}"
        )
    i = np.arange(0, n - delta_frames, 1 if all_pairs else delta_frames)
    j = i + delta_frames
    Q, P = pair.ref_poses_se3, pair.est_poses_se3
    E = _inv_mul(_inv_mul(Q[i], Q[j]), _inv_mul(P[i], P[j]))
    trans = np.linalg.norm(E[:, :3, 3], axis=1)
    rot = rotation_angle_deg(np.eye(3), E[:, :3, :3])
    return RpeResult(
        delta_frames=int(delta_frames),
        trans_rmse_m=_rmse(trans),
        trans_mean_m=float(trans.mean()),
        trans_median_m=float(np.median(trans)),
        trans_max_m=float(trans.max()),
        rot_rmse_deg=_rmse(rot),
        rot_mean_deg=float(rot.mean()),
        rot_median_deg=float(np.median(rot)),
        rot_max_deg=float(rot.max()),
        n_pairs=len(i),
        all_pairs=all_pairs,
        alignment=alignment,
        trans_errors_m=trans,
        rot_errors_deg=rot,
    )


def rpe_per_delta(
    reference: Trajectory,
    estimate: Trajectory,
    deltas_frames: Sequence[int] = (1, 10, 30),
    all_pairs: bool = True,
    alignment: str = "none",
    max_dt_s: float = DEFAULT_MAX_DT_S,
) -> tuple[RpeResult, ...]:
    """``rpe`` at each delta; deltas longer than the matched trajectory raise InputError."""
    return tuple(rpe(reference, estimate, d, all_pairs, alignment, max_dt_s) for d in deltas_frames)
