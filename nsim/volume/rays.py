"""Rays: world-frame origins and unit directions, their [near, far] range, and pose refinement.

Conventions (``nsim.geometry.conventions``): metres, world z up, ``cam_to_world (..., 4, 4)``
in OpenCV camera axes. Directions are unit length, so ``t`` along a ray is a distance in
metres (a depth map rendered from ``t`` is a *range* map; ``depth_z = t * dir_cam_z``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass
class Rays:
    """A batch of rays. origins, dirs: (R, 3) (dirs unit); near, far: (R,) metres;
    image_index: (R,) int64, the training image a ray comes from (appearance, pose refinement), or None."""

    origins: Tensor
    dirs: Tensor
    near: Tensor
    far: Tensor
    image_index: Tensor | None = None

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, sl) -> Rays:
        return Rays(self.origins[sl], self.dirs[sl], self.near[sl], self.far[sl],
                    None if self.image_index is None else self.image_index[sl])

    def to(self, device) -> Rays:
        return Rays(self.origins.to(device), self.dirs.to(device), self.near.to(device), self.far.to(device),
                    None if self.image_index is None else self.image_index.to(device))


def intersect_aabb(origins: Tensor, dirs: Tensor, aabb: Tensor) -> tuple[Tensor, Tensor]:
    """Entry and exit distances ``(R,)`` of rays through the box ``aabb (2, 3)`` (slab method).

    Rays that miss the box get ``t_exit < t_entry``; a ray starting inside has ``t_entry < 0``.
    """
    inv = 1.0 / torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    t0 = (aabb[0] - origins) * inv
    t1 = (aabb[1] - origins) * inv
    return torch.minimum(t0, t1).amax(-1), torch.maximum(t0, t1).amin(-1)


def make_rays(origins: Tensor, dirs: Tensor, near_m: float, far_m: float, aabb: Tensor | None = None,
              image_index: Tensor | None = None) -> Rays:
    """Rays with ``[near_m, far_m]``, clipped to the scene box ``aabb (2, 3)`` when given.

    A ray that misses the box (or leaves it before ``near_m``) gets ``far = near + 1e-4``:
    an empty ray that renders as background.
    """
    n = origins.shape[0]
    near = torch.full((n,), near_m, dtype=origins.dtype, device=origins.device)
    far = torch.full((n,), far_m, dtype=origins.dtype, device=origins.device)
    if aabb is not None:
        t_in, t_out = intersect_aabb(origins, dirs, aabb)
        near = torch.maximum(near, t_in)
        far = torch.minimum(far, t_out)
        far = torch.where(far > near + 1e-4, far, near + 1e-4)
    return Rays(origins, dirs, near, far, image_index)


def camera_dirs(camera, device: str | torch.device = "cpu") -> Tensor:
    """Unit directions through every pixel centre in camera axes: ``(H, W, 3)`` float32.

    ``Camera.pixel_dirs_cam`` (float64) in float32; pixels a model cannot unproject get
    ``FORWARD_DIR`` ``(0, 0, 1)`` and should be masked by the caller.
    """
    return torch.as_tensor(camera.pixel_dirs_cam(fill_invalid=True), dtype=torch.float32).to(device)


def _skew(v: Tensor) -> Tensor:
    zero = torch.zeros_like(v[..., 0])
    return torch.stack([
        torch.stack([zero, -v[..., 2], v[..., 1]], -1),
        torch.stack([v[..., 2], zero, -v[..., 0]], -1),
        torch.stack([-v[..., 1], v[..., 0], zero], -1),
    ], -2)


def se3_exp(xi: Tensor) -> Tensor:
    """Exponential map of twists ``xi (..., 6) = (rho, omega)`` (translation, rotation) -> ``(..., 4, 4)``.

    ``R = exp([omega]x)`` (Rodrigues), ``t = V rho``; Taylor expansions near ``omega = 0`` keep
    it and its gradient exact at the identity.
    """
    rho, omega = xi[..., :3], xi[..., 3:]
    theta2 = (omega * omega).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    theta = torch.sqrt(theta2.clamp(min=1e-12))
    small = theta2 < 1e-8
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp(min=1e-12))
    c = torch.where(small, 1.0 / 6.0 - theta2 / 120.0, (theta - torch.sin(theta)) / (theta2 * theta).clamp(min=1e-12))
    k = _skew(omega)
    k2 = k @ k
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand_as(k)
    rot = eye + a * k + b * k2
    v = eye + b * k + c * k2
    t = (v @ rho[..., None])[..., 0]
    out = torch.zeros((*xi.shape[:-1], 4, 4), dtype=xi.dtype, device=xi.device)
    out[..., :3, :3] = rot
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


class PoseRefinement(nn.Module):
    """Per-image SE(3) corrections (NeRF--): ``cam_to_world' = cam_to_world @ exp(xi_i)``.

    The correction acts in the camera frame (``rho`` in metres along the camera axes); the
    twists start at zero, so an untrained refinement is the identity.
    """

    def __init__(self, n_images: int) -> None:
        super().__init__()
        self.twists = nn.Parameter(torch.zeros(n_images, 6))

    def forward(self, cam_to_world: Tensor, image_index: Tensor) -> Tensor:
        """cam_to_world: (R, 4, 4); image_index: (R,) -> corrected (R, 4, 4)."""
        return cam_to_world @ se3_exp(self.twists[image_index])
