"""Priors on the canonical body where the video never looked: the shape of its cross-sections, its left/right
mirror symmetry and the colour of its unseen sides.

A video that films a person from one side constrains the human NeRF's canonical field (``nsim.human.nerf``) only
in what that side projects to: the body's width is seen, its depth along the camera's rays is not, and nothing
behind the body reaches the loss. Left alone the field smears the body along the rays (half-transparent from the
side, a ghost limb where the smear of one leg crosses the other) and paints the back with the front. These priors
say what a body is like there; each is a loss on canonical points drawn near the bones, added to training with a
weight (``nsim.train.human.HumanLossConfig``).

Canonical frame: the skeleton's rest pose (``Skeleton.rest_transforms()``: a T-pose facing +x, left +y, z up).
Bones are the rest pose's segments (``nsim.human.nerf.bone_segments``). Each bone ``b`` gets a cross-section frame
(:func:`bone_frames`): its unit ``axis``, ``depth`` the body's forward direction (+x) made perpendicular to the
axis, and ``lateral = axis x depth``; a point ``p`` has coordinates ``(u, l, d)`` along them from the bone's start.

* **Cross-sections** (:func:`turn_cross_section`): limbs, neck and head are about round in cross-section, the
  trunk an ellipse ``aspect`` (depth / width, about 0.65 for adults) as deep as it is wide. The field should not
  change when a point turns about its bone in the scaled cross-section ``(l, d / aspect)``: the width the video
  sees then says how deep the body is where it did not look. Bones nearly parallel to the forward direction (the
  feet) have no hidden depth in their cross-section; their pairs weigh ``1 - (axis . x)^2``.
* **Left/right symmetry** (:func:`mirror_left_right`): the body's shape is its mirror image across the sagittal
  plane through the root (``y -> 2 y_root - y``), colour less so (a print, a bag).
* **Unseen colour** (:func:`seen_fraction`): a point whose outward direction (away from its bone's axis) faced no
  training camera has a colour no image constrained; it is pulled towards the mean colour its bone shows where it
  was seen (the least-squares guess), not left to whatever the field extrapolates from the other side.

Points are drawn around a bone (:func:`sample_near_bones`) and used in pairs only while both lie nearest to that
bone (:func:`nearest_bone`), so a turn never compares a thigh with the other thigh. Everything here is a pure
function of tensors (no state, no randomness but the ``generator`` given).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nsim.human.nerf import bone_segments, point_segment_distance
from nsim.human.skeleton import Skeleton


@dataclass(frozen=True)
class BoneFrames:
    """Rest-pose bone segments with their cross-section frames (B segments; canonical metres).

    start: (B, 3) the segment's start (its joint); axis, lateral, depth: (B, 3) orthonormal (``axis`` any unit
    vector for a zero-length segment); length_m: (B,); aspect: (B,) depth / width of the cross-section; weight:
    (B,) ``1 - (axis . x)^2``, how much of the forward direction lies in the cross-section; joint: (B,) the joint
    that carries it.
    """

    start: Tensor
    axis: Tensor
    lateral: Tensor
    depth: Tensor
    length_m: Tensor
    aspect: Tensor
    weight: Tensor
    joint: Tensor

    @property
    def end(self) -> Tensor:
        return self.start + self.axis * self.length_m[:, None]


def trunk_joints(skeleton: Skeleton) -> np.ndarray:
    """Joints whose subtree holds three or more leaves (the pelvis and spine of a humanoid: the legs, the arms and
    the head branch off them): ``(J,)`` bool."""
    leaves = np.array([0 if skeleton.children(j) else 1 for j in range(skeleton.num_joints)])
    for j in range(skeleton.num_joints - 1, 0, -1):  # parents come before children
        leaves[skeleton.parents[j]] += leaves[j]
    return leaves >= 3


def bone_frames(skeleton: Skeleton, trunk_aspect: float = 0.65) -> BoneFrames:
    """The cross-section frames of ``skeleton``'s rest-pose bones (``nsim.human.nerf.bone_segments``); segments
    carried by a trunk joint (:func:`trunk_joints`) get ``aspect = trunk_aspect``, the others 1."""
    a, b, joint = bone_segments(skeleton)
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    axis = np.where(length[:, None] > 1e-9, ab / np.maximum(length, 1e-12)[:, None], [0.0, 0.0, 1.0])
    forward = np.array([1.0, 0.0, 0.0])
    along = axis @ forward
    depth = forward - along[:, None] * axis
    norm = np.linalg.norm(depth, axis=1)
    up = np.array([0.0, 0.0, 1.0])  # a bone along +x: any perpendicular (its weight is 0)
    fallback = up - (axis @ up)[:, None] * axis
    fallback /= np.maximum(np.linalg.norm(fallback, axis=1), 1e-12)[:, None]
    depth = np.where(norm[:, None] > 1e-6, depth / np.maximum(norm, 1e-12)[:, None], fallback)
    lateral = np.cross(axis, depth)
    aspect = np.where(trunk_joints(skeleton)[joint], trunk_aspect, 1.0)

    def t(x: np.ndarray) -> Tensor:
        return torch.as_tensor(np.asarray(x, dtype=np.float32))

    return BoneFrames(t(a), t(axis), t(lateral), t(depth), t(length), t(aspect), t(1.0 - along**2),
                      torch.as_tensor(joint, dtype=torch.long))


def nearest_bone(points: Tensor, frames: BoneFrames) -> tuple[Tensor, Tensor]:
    """The nearest segment to each of ``points (N, 3)`` and the distance to it: ``(N,)`` long, ``(N,)``."""
    d = point_segment_distance(points, frames.start.to(points), frames.end.to(points))
    dist, bone = d.min(dim=1)
    return bone, dist


def cross_section(points: Tensor, bone: Tensor, frames: BoneFrames) -> tuple[Tensor, Tensor, Tensor]:
    """Coordinates ``(u, l, d)``, each ``(N,)``, of ``points (N, 3)`` along bone ``bone (N,)``'s axis, lateral and
    depth directions from its start."""
    rel = points - frames.start.to(points)[bone]
    return ((rel * frames.axis.to(points)[bone]).sum(-1), (rel * frames.lateral.to(points)[bone]).sum(-1),
            (rel * frames.depth.to(points)[bone]).sum(-1))


def from_cross_section(u: Tensor, lat: Tensor, dep: Tensor, bone: Tensor, frames: BoneFrames) -> Tensor:
    """Points ``(N, 3)`` at cross-section coordinates ``(u, l, d)`` of bones ``bone (N,)``."""
    f = frames
    return (f.start.to(u)[bone] + u[:, None] * f.axis.to(u)[bone] + lat[:, None] * f.lateral.to(u)[bone]
            + dep[:, None] * f.depth.to(u)[bone])


def sample_near_bones(frames: BoneFrames, n: int, radius_m: float, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """``n`` canonical points ``(n, 3)`` around the bones and the bone each was drawn for ``(n,)``.

    A bone is drawn in proportion to its length plus ``radius_m`` (so a short bone still gets points), a position
    uniformly along it, and an offset uniformly in the disc of radius ``radius_m`` of its scaled cross-section
    (``l = r cos(phi)``, ``d = aspect r sin(phi)``)."""
    f = frames
    p = (f.length_m + radius_m) / (f.length_m + radius_m).sum()
    bone = torch.multinomial(p, n, replacement=True, generator=generator)
    u = torch.rand(n, generator=generator) * f.length_m[bone]
    r = radius_m * torch.sqrt(torch.rand(n, generator=generator))
    phi = 2.0 * torch.pi * torch.rand(n, generator=generator)
    return from_cross_section(u, r * torch.cos(phi), f.aspect[bone] * r * torch.sin(phi), bone, f), bone


def turn_cross_section(points: Tensor, bone: Tensor, frames: BoneFrames, angle_rad: Tensor) -> Tensor:
    """``points (N, 3)`` turned by ``angle_rad (N,)`` about their bone's axis in its scaled cross-section
    ``(l, d / aspect)``: a point on an elliptic cross-section of that aspect stays on it."""
    u, lat, dep = cross_section(points, bone, frames)
    k = frames.aspect.to(points)[bone]
    c, s = torch.cos(angle_rad), torch.sin(angle_rad)
    scaled = dep / k
    return from_cross_section(u, c * lat - s * scaled, k * (s * lat + c * scaled), bone, frames)


def mirror_left_right(points: Tensor, skeleton: Skeleton) -> Tensor:
    """``points (N, 3)`` mirrored across the rest pose's sagittal plane through the root: ``y -> 2 y_root - y``."""
    y0 = float(skeleton.rest_transforms()[0, 1, 3])
    return torch.stack([points[:, 0], 2.0 * y0 - points[:, 1], points[:, 2]], dim=-1)


def outward(points: Tensor, bone: Tensor, frames: BoneFrames) -> Tensor:
    """Unit directions ``(N, 3)`` from each point's bone axis out to it (in the cross-section; the depth
    direction for a point on the axis)."""
    u, lat, dep = cross_section(points, bone, frames)
    n = lat[:, None] * frames.lateral.to(points)[bone] + dep[:, None] * frames.depth.to(points)[bone]
    norm = torch.linalg.vector_norm(n, dim=-1, keepdim=True)
    return torch.where(norm > 1e-9, n / norm.clamp(min=1e-12), frames.depth.to(points)[bone])


def seen_fraction(points: Tensor, normals: Tensor, joint: Tensor, cameras_c: Tensor, min_cos: float = 0.2) -> Tensor:
    """The share of training frames in which each canonical point ``points (N, 3)``, facing ``normals (N, 3)`` and
    carried by ``joint (N,)``, faced the camera: ``(N,)`` in [0, 1].

    cameras_c: ``(F, J, 3)`` each frame's camera centre carried back into the canonical frame by each joint
    (``G_fj^-1 c_f``), so the test needs no pose: the point faces the camera when the cosine between its normal and
    the direction to the camera exceeds ``min_cos``. Occlusion by other parts is not considered."""
    to_cam = cameras_c[:, joint] - points[None]  # (F, N, 3)
    cos = (to_cam * normals[None]).sum(-1) / torch.linalg.vector_norm(to_cam, dim=-1).clamp(min=1e-9)
    return (cos > min_cos).float().mean(0)


def cameras_in_canonical(joint_transforms: Tensor, rest_transforms: Tensor, cam_to_world: Tensor) -> Tensor:
    """Each frame's camera centre carried into the canonical frame by each joint: ``(F, J, 3)``.

    joint_transforms: (F, J, 4, 4) the frames' poses; rest_transforms: (J, 4, 4); cam_to_world: (F, 4, 4).
    Joint ``j`` carries canonical points to frame ``f`` by ``G_fj = T_fj R_j^-1``, so the camera is at
    ``G_fj^-1 c_f = R_j T_fj^-1 c_f`` in its canonical frame."""
    G_inv = rest_transforms[None] @ torch.linalg.inv(joint_transforms)  # (F, J, 4, 4)
    c = cam_to_world[:, :3, 3]
    return torch.einsum("fjab,fb->fja", G_inv[..., :3, :3], c) + G_inv[..., :3, 3]


__all__ = [
    "BoneFrames",
    "bone_frames",
    "cameras_in_canonical",
    "cross_section",
    "from_cross_section",
    "mirror_left_right",
    "nearest_bone",
    "outward",
    "sample_near_bones",
    "seen_fraction",
    "trunk_joints",
    "turn_cross_section",
]
