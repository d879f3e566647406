"""Per-frame corrections of a person's skeleton poses, learned while the human NeRF trains.

A pose estimator's errors (a forearm a few degrees off, a foot planted a few centimetres wrong) show
in a human NeRF as blur and ghost limbs: the canonical body cannot agree with every frame at once.
NeuMan (Jiang et al. 2022) and HumanNeRF (Weng et al. 2022) therefore refine the given poses by the
same photometric and silhouette losses that train the NeRF. Here each frame ``i`` gets

* a small rotation per joint ``r_ij`` (axis-angle, radians), applied in joint ``j``'s own frame
  after its given rotation relative to its parent, and
* a translation of the root ``t_i`` (metres, world),

and the refined pose is forward kinematics over the given local transforms (so bone lengths never
change): ``T'_i0 = (T_i0 + t_i) exp(r_i0)``, ``T'_ij = T'_i,parent L_ij exp(r_ij)`` with
``L_ij = T_i,parent^-1 T_ij``. With every correction zero the given poses come back (to float32
rounding). The corrections are taken relative to their mean over the frames
(:meth:`BodyPoseRefinement.corrections`): a correction shared by every frame is the canonical body's to
absorb, and left free it lets body and poses drift together. A test-time fit of frames against a frozen
body (``nsim.train.human``'s held-out fit) turns that off (``subtract_mean=False``): there each frame's
correction is its own, and the body has nothing to absorb.

:func:`regulariser` keeps the corrections small (a Gaussian prior) and smooth in frame order (a
first-difference penalty over *all* frames). The smoothness term is what gives held-out frames, which
no image loss touches, the corrections of their neighbours: they are moved only by the frames around
them, never by their own pixels.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from nsim.volume.rays import se3_exp


def axis_angle_to_matrix(v: Tensor) -> Tensor:
    """Rotation matrices ``(..., 3, 3)`` of axis-angle vectors ``(..., 3)`` (radians), exact with its gradient
    at 0: the rotation part of ``nsim.volume.rays.se3_exp`` (one Rodrigues formula in nsim)."""
    return se3_exp(torch.cat([torch.zeros_like(v), v], dim=-1))[..., :3, :3]


class BodyPoseRefinement(nn.Module):
    """Learnable corrections of ``N`` given poses ``joint_transforms (N, J, 4, 4)`` of a skeleton with
    ``parents (J,)`` (the root's ``-1``; every parent before its child). ``forward()`` gives the refined
    ``(N, J, 4, 4)``; the parameters are ``rotation (N, J, 3)`` and ``translation (N, 3)``.
    ``subtract_mean``: apply the corrections less their mean over the frames (see :meth:`corrections`);
    False applies each frame's own (a per-frame fit with the body frozen)."""

    def __init__(self, joint_transforms: Tensor, parents: np.ndarray, subtract_mean: bool = True) -> None:
        super().__init__()
        T = torch.as_tensor(joint_transforms, dtype=torch.float32)
        parents = np.asarray(parents)
        n, J = T.shape[0], T.shape[1]
        if T.shape[-2:] != (4, 4) or T.ndim != 4 or parents.shape != (J,):
            raise ValueError(f"BodyPoseRefinement: expected joint_transforms (N, J, 4, 4) and parents (J,), got "
                             f"{tuple(T.shape)} and {parents.shape}")
        if parents[0] >= 0 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, J)):
            raise ValueError("BodyPoseRefinement: joint 0 must be the root and every parent must come before its child")
        local = T.clone()
        p = torch.tensor(parents[1:].tolist(), dtype=torch.long)
        local[:, 1:] = torch.linalg.inv(T[:, p].double()).float() @ T[:, 1:]
        self.register_buffer("given", T)
        self.register_buffer("local", local)  # (N, J, 4, 4): joint-to-parent (the root's: to world)
        self.parents = [int(q) for q in parents]
        self.subtract_mean = bool(subtract_mean)
        self.rotation = nn.Parameter(torch.zeros(n, J, 3))
        self.translation = nn.Parameter(torch.zeros(n, 3))

    @property
    def num_frames(self) -> int:
        return self.local.shape[0]

    def corrections(self) -> tuple[Tensor, Tensor]:
        """The corrections applied: ``rotation (N, J, 3)`` and ``translation (N, 3)`` less their means over the
        frames. A correction every frame shares (a joint turned the same way in every pose, the whole body
        shifted) changes no image that the canonical body cannot change as well, so it is not the poses'
        to learn: the fitter's errors are taken to average out over the frames. With ``subtract_mean`` False:
        the parameters themselves."""
        if not self.subtract_mean:
            return self.rotation, self.translation
        return (self.rotation - self.rotation.mean(0, keepdim=True),
                self.translation - self.translation.mean(0, keepdim=True))

    def forward(self) -> Tensor:
        """The refined joint-to-world transforms ``(N, J, 4, 4)``."""
        n, J = self.local.shape[:2]
        rotation, translation = self.corrections()
        R = axis_angle_to_matrix(rotation)  # (N, J, 3, 3)
        rot = self.local[..., :3, :3] @ R
        shift = torch.zeros(n, J, 3, device=self.local.device, dtype=self.local.dtype)
        shift = torch.cat([translation[:, None], shift[:, 1:]], dim=1)
        bottom = self.local[..., 3:, :]
        local = torch.cat([torch.cat([rot, (self.local[..., :3, 3] + shift)[..., None]], dim=-1), bottom], dim=-2)
        out = [local[:, 0]]
        for j in range(1, J):
            out.append(out[self.parents[j]] @ local[:, j])
        return torch.stack(out, dim=1)

    def regulariser(self, rotation_weight: float, translation_weight: float, smooth_weight: float) -> Tensor:
        """``rotation_weight * mean(r^2) + translation_weight * mean(t^2) + smooth_weight * (mean((r_i+1 - r_i)^2)
        + mean((t_i+1 - t_i)^2))``, the differences over consecutive frames (radians and metres)."""
        r, t = self.corrections()
        loss = rotation_weight * r.pow(2).mean() + translation_weight * t.pow(2).mean()
        if smooth_weight > 0 and r.shape[0] > 1:
            loss = loss + smooth_weight * ((r[1:] - r[:-1]).pow(2).mean() + (t[1:] - t[:-1]).pow(2).mean())
        return loss


def pose_change(given: np.ndarray, refined: np.ndarray) -> dict[str, float]:
    """How far refinement moved poses ``(N, J, 4, 4)``: joint positions (mean, 95th percentile and
    maximum over frames and joints, cm) and joint orientations (mean and maximum angle, degrees)."""
    given, refined = np.asarray(given, dtype=np.float64), np.asarray(refined, dtype=np.float64)
    if given.shape != refined.shape or given.ndim != 4 or given.shape[-2:] != (4, 4):
        raise ValueError(f"pose_change: expected two (N, J, 4, 4) arrays, got {given.shape} and {refined.shape}")
    shift = 100.0 * np.linalg.norm(refined[..., :3, 3] - given[..., :3, 3], axis=-1)
    rel = np.swapaxes(given[..., :3, :3], -1, -2) @ refined[..., :3, :3]
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))
    return {"frames": int(given.shape[0]), "joint_shift_cm_mean": float(shift.mean()),
            "joint_shift_cm_p95": float(np.percentile(shift, 95)), "joint_shift_cm_max": float(shift.max()),
            "rotation_deg_mean": float(angle.mean()), "rotation_deg_max": float(angle.max())}


__all__ = ["BodyPoseRefinement", "axis_angle_to_matrix", "pose_change"]
