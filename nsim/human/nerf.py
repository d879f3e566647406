"""The human NeRF: a radiance field in the body's canonical (rest) pose, warped to any skeleton pose.

Spaces. *Posed* space is the world in which a body stands at ``joint_transforms (J, 4, 4)``
(joint-to-world, from ``nsim.human.skeleton.forward_kinematics``). *Canonical* space is the
world frame of the skeleton's rest pose (``Skeleton.rest_transforms()``: a T-pose on the
floor, facing +x); the field lives in its padded box ``canonical_box (2, 3)``. Joint ``j``
moves canonical points rigidly by ``G_j = T_j R_j^-1`` (``R_j`` its rest transform), and bone
``j`` is the segment(s) from joint ``j`` to its children (to its end site for a leaf): the part
of the body that ``G_j`` carries.

Inverse skinning. Skinning weights are a learned, low-resolution volume over the canonical
box: one log-weight channel per joint, ``log w^c_j(y)``, initialised to the log of
``softmax([-d_1(y), ..., -d_J(y), -d_bg] / tau)``: ``d_j`` the distance from ``y`` to bone
``j``, ``d_bg`` (``blend_background_m``) the distance beyond which a point belongs to no bone,
``tau`` (``blend_temperature_m``) the softness. A posed point ``x`` is mapped back by every
joint, ``y_j = G_j^-1 x``, and each joint's weight is read *at its own candidate* (HumanNeRF,
Weng et al. 2022): ``w_j(x) = w^c_j(y_j)``. Since bones move rigidly, the initial ``w_j(x)``
is exactly the softmax of the distances from ``x`` to the *posed* bones: no root finding, one
pass, ``J`` trilinear reads per point. Two ways to use the candidates (``skinning``):

* ``blend`` (classic inverse LBS): ``x_c = sum_j w_j y_j / sum_j w_j`` and
  ``sigma(x) = sigma_c(x_c) min(s, 1)`` with the ownership ``s = sum_j w_j``. Wrong where two
  unrelated parts come close: a hand swinging beside the thigh is claimed both by the wrist
  (its own flesh) and by the hip joint (canonical space 15 cm from the thigh, empty but still
  the thigh's territory), and the average of the two candidates lies in neither.
* ``mixture`` (default): each of the ``skinning_candidates`` best-weighted joints carries a
  rigid copy of the canonical body, masked by its weight:
  ``sigma(x) = sum_k w_k sigma_c(y_k)``, colour the density-weighted mean. This is linear
  blend skinning applied to the density instead of to the point: exact for a part that moves
  with one bone, a smooth blend of the neighbouring bones' copies at a joint, and the hand
  beside the thigh is found by the wrist's copy (the hip's copy there is empty canonical space,
  so it adds nothing). Ghosts are suppressed by the weights: a point between the legs that the
  left hip maps into the canonical *right* leg is not owned by the left hip there (``w^c_left``
  is small inside the right leg), so that copy is masked out.

Hypotheses weighing less than ``min_ownership`` are not evaluated (empty-space skipping). The
weights stay learnable (``lr_blend`` in the trainer), reaching the loss through the field's
input and the masks.

Optional non-rigid offsets (``nonrigid``): ``x_c += tanh(MLP(PE(x_c), pose)) * max_offset``,
the pose being the joints' local rotations (6D, relative to the rest pose); the last layer
starts at zero, so training starts from pure skinning.

Canonical field: a hash grid (``nsim.fields.HashEncoding``) or a positional-encoding MLP over
the canonical box -> density MLP (``trunc_exp``) + geometry feature -> colour MLP. With
``shading`` the colour MLP also sees the posed-to-canonical rotation at the point (the world
axes in canonical coordinates), so light fixed in the world (sun, lamps) can shade a limb
differently as it turns. Density is zero outside the canonical box.

Rendering. ``render_samples`` puts ``samples_per_ray`` stratified samples between each ray's
entry into and exit from the posed body box (world axis-aligned, joints and end sites grown by
``box_padding_m``); rays that miss it get empty intervals (``t_start == t_end``, density 0).
The samples are ``RaySamples`` like the scene model's, so ``render_merged`` volume-renders human
and scene samples along the same rays together, in depth order, with the renderer's compositing
(``nsim.volume.compositing``).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from nsim.config import param
from nsim.fields.hash_encoding import HashEncoding
from nsim.fields.mlp import MLP
from nsim.fields.scene_field import trunc_exp
from nsim.geometry.cameras import dirs_to_world
from nsim.human.skeleton import Skeleton, default_padding_m, pose_aabb
from nsim.volume.compositing import composite_sets, merge_samples, set_weights
from nsim.volume.rays import camera_dirs
from nsim.volume.samples import RaySamples

FIELD_TYPES = ("hash", "mlp")
SKINNING_MODES = ("mixture", "blend")


@dataclass(frozen=True)
class HumanModelConfig:
    """The human NeRF's sizes (see the module docstring).

    Canonical field: ``field`` ``hash`` (multiresolution hash grid from ``hash_base_resolution``
    to ``hash_max_resolution`` cells across the canonical box) or ``mlp`` (``pe_frequencies``
    octaves of positional encoding); density and colour MLPs share the encoding but not their
    hidden layers (a shared trunk let the fast-growing density drive the colour head into
    saturation). Skinning (``mixture`` or ``blend``, see the module docstring): a log-weight volume with cells of about
    ``blend_voxel_m``, initialised from bone distances with ``blend_temperature_m`` and
    ``blend_background_m``. ``box_padding_m``: padding of the canonical and posed boxes around
    joints and end sites (None: 10 % of the body height).

    Where to look: ``sample_bone_radius_m`` (None, as models made before it: the whole posed box) spreads a ray's
    ``samples_per_ray`` over the part of it that passes within that distance of a posed bone (the hull of its
    intersections with capsules of that radius around the bones, inside the posed box), not over the whole box:
    the same samples land closer together where the body can be, and the field is empty beyond that distance
    (a shape prior from the skeleton).
    """

    field: str = param("hash", choices=FIELD_TYPES)
    hash_levels: int = param(8, ge=1, le=16)
    hash_features_per_level: int = param(2, choices=(1, 2, 4, 8))
    hash_log2_table_size: int = param(16, ge=8, le=22)
    hash_base_resolution: int = param(8, ge=2, le=512)
    hash_max_resolution: int = param(256, ge=2, le=8192)
    pe_frequencies: int = param(8, ge=1, le=16, help="positional-encoding octaves (field: mlp)")
    hidden_dim: int = param(64, ge=4, le=512)
    hidden_layers: int = param(1, ge=1, le=8)
    color_hidden_dim: int = param(64, ge=4, le=512)
    color_hidden_layers: int = param(1, ge=0, le=8)
    shading: bool = param(True, help="colour sees the world axes in canonical coordinates (fixed lights)")
    skinning: str = param("mixture", choices=SKINNING_MODES)
    skinning_candidates: int = param(2, ge=1, le=8, help="hypotheses per point (skinning: mixture)")
    blend_voxel_m: float = param(0.04, gt=0.0, le=0.5)
    blend_temperature_m: float = param(0.02, gt=0.0)
    blend_background_m: float = param(0.2, gt=0.0, help="bone distance beyond which a point belongs to no bone")
    box_padding_m: float | None = param(None, ge=0.0)
    nonrigid: bool = param(False, help="pose-dependent non-rigid offset MLP")
    nonrigid_hidden_dim: int = param(64, ge=4, le=512)
    nonrigid_pe_frequencies: int = param(4, ge=1, le=12)
    nonrigid_max_offset_m: float = param(0.05, gt=0.0)
    samples_per_ray: int = param(48, ge=2, le=1024)
    min_ownership: float = param(1e-3, ge=0.0, lt=1.0, help="samples owned less than this by any bone are empty")
    sample_bone_radius_m: float | None = param(
        None, gt=0.0, help="samples only where a ray passes this close to a posed bone (null: the whole posed box)")


# ====================================================================== geometry helpers
def bone_segments(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest-pose bone segments: ``a (B, 3)``, ``b (B, 3)`` (world metres) and ``joint (B,)``.

    Joint ``j`` owns one segment to each child, or to its end site when it is a leaf that has
    one, or a zero-length segment at the joint otherwise.
    """
    T = skeleton.rest_transforms()
    p = T[:, :3, 3]
    a, b, owner = [], [], []
    for j in range(skeleton.num_joints):
        kids = skeleton.children(j)
        ends = [p[c] for c in kids]
        if not kids:
            e = skeleton.end_sites_m[j]
            ends = [p[j] + T[j, :3, :3] @ e] if np.all(np.isfinite(e)) else [p[j]]
        for q in ends:
            a.append(p[j])
            b.append(q)
            owner.append(j)
    return np.asarray(a), np.asarray(b), np.asarray(owner, dtype=np.int64)


def point_segment_distance(x: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Distances ``(N, B)`` from points ``x (N, 3)`` to segments ``a, b (B, 3)``."""
    ab = b - a
    denom = (ab * ab).sum(-1).clamp(min=1e-12)
    u = (((x[:, None, :] - a) * ab).sum(-1) / denom).clamp(0.0, 1.0)
    closest = a + u[..., None] * ab
    return torch.linalg.vector_norm(x[:, None, :] - closest, dim=-1)


def ray_capsule_interval(origins: Tensor, dirs: Tensor, a: Tensor, b: Tensor, radius: float) -> tuple[Tensor, Tensor]:
    """Where rays ``origins, dirs (R, 3)`` (unit dirs) pass within ``radius`` of segments ``a, b (R, B, 3)``:
    entry and exit ``t (R, B)`` (``+inf, -inf`` for a miss). A capsule is convex, so its interval is the hull of
    the intervals of its two end spheres and of its cylinder (the infinite cylinder cut by the slab between the
    ends)."""
    inf = torch.full_like(a[..., 0], float("inf"))
    o, d = origins[:, None, :], dirs[:, None, :]
    r2 = radius * radius

    def sphere(c: Tensor) -> tuple[Tensor, Tensor]:
        oc = o - c
        half_b = (oc * d).sum(-1)
        disc = half_b * half_b - ((oc * oc).sum(-1) - r2)
        root = torch.sqrt(disc.clamp(min=0.0))
        return torch.where(disc >= 0, -half_b - root, inf), torch.where(disc >= 0, -half_b + root, -inf)

    s0, s1 = sphere(a)
    e0, e1 = sphere(b)
    ab = b - a
    length = torch.linalg.vector_norm(ab, dim=-1)
    w = ab / length.clamp(min=1e-12)[..., None]
    oa = o - a
    dw, ow = (d * w).sum(-1), (oa * w).sum(-1)
    d_perp, o_perp = d - dw[..., None] * w, oa - ow[..., None] * w
    qa = (d_perp * d_perp).sum(-1)
    qb = (o_perp * d_perp).sum(-1)
    disc = qb * qb - qa * ((o_perp * o_perp).sum(-1) - r2)
    root = torch.sqrt(disc.clamp(min=0.0))
    ok = (disc >= 0) & (qa > 1e-12) & (length > 1e-9)
    c0 = (-qb - root) / qa.clamp(min=1e-12)
    c1 = (-qb + root) / qa.clamp(min=1e-12)
    # the slab 0 <= (o + t d - a) . w <= length
    safe = torch.where(dw.abs() > 1e-12, dw, torch.full_like(dw, 1e-12))
    p0, p1 = -ow / safe, (length - ow) / safe
    c0 = torch.maximum(c0, torch.minimum(p0, p1))
    c1 = torch.minimum(c1, torch.maximum(p0, p1))
    ok = ok & (c1 >= c0)
    c0, c1 = torch.where(ok, c0, inf), torch.where(ok, c1, -inf)
    return torch.minimum(torch.minimum(s0, e0), c0), torch.maximum(torch.maximum(s1, e1), c1)


def bone_distances(x: Tensor, skeleton: Skeleton) -> Tensor:
    """Distance ``(N, J)`` from rest-pose points ``x (N, 3)`` to each joint's bone (nearest segment)."""
    a, b, owner = bone_segments(skeleton)
    d = point_segment_distance(x, torch.as_tensor(a, dtype=x.dtype), torch.as_tensor(b, dtype=x.dtype))
    out = torch.full((x.shape[0], skeleton.num_joints), float("inf"), dtype=x.dtype)
    return out.scatter_reduce(1, torch.as_tensor(owner)[None].expand_as(d), d, reduce="amin")


def initial_blend_log_weights(points: Tensor, skeleton: Skeleton, temperature_m: float,
                              background_m: float) -> Tensor:
    """``log softmax([-d_1, ..., -d_J, -d_bg] / tau)`` without the background channel: ``(N, J)``."""
    d = bone_distances(points, skeleton)
    logits = torch.cat([-d, torch.full_like(d[:, :1], -background_m)], dim=1) / temperature_m
    return torch.log_softmax(logits, dim=1)[:, :-1]


def local_rotations_6d(joint_transforms: Tensor, parents: Tensor) -> Tensor:
    """The non-root joints' rotations relative to their parents, as the first two columns minus
    the identity's (zero in the rest pose): ``(6 (J - 1),)``."""
    R = joint_transforms[:, :3, :3]
    local = R[parents[1:]].transpose(-1, -2) @ R[1:]
    six = local[..., :, :2] - torch.eye(3, 2, dtype=R.dtype, device=R.device)
    return six.reshape(-1)


def positional_encoding(x: Tensor, frequencies: int) -> Tensor:
    """``[x, sin(2^k pi x), cos(2^k pi x)]`` for ``k < frequencies``: ``(..., D (1 + 2 F))``."""
    scales = (2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device)) * math.pi
    xs = (x[..., None, :] * scales[:, None]).flatten(-2)
    return torch.cat([x, torch.sin(xs), torch.cos(xs)], dim=-1)


# ====================================================================== modules
class CanonicalField(nn.Module):
    """Density and colour in the canonical box ``box (2, 3)`` (see ``HumanModelConfig``)."""

    def __init__(self, cfg: HumanModelConfig, box: Tensor, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        self.register_buffer("box", torch.as_tensor(box, dtype=torch.float32).clone())
        if cfg.field == "hash":
            self.encoding = HashEncoding(cfg.hash_levels, cfg.hash_features_per_level, cfg.hash_log2_table_size,
                                         cfg.hash_base_resolution, cfg.hash_max_resolution, backend="torch",
                                         generator=generator)
            enc_dim = self.encoding.n_output_dims
        else:
            self.encoding = None
            enc_dim = 3 * (1 + 2 * cfg.pe_frequencies)
        self.density_mlp = MLP(enc_dim, cfg.hidden_dim, cfg.hidden_layers, 1, generator)
        self.color_mlp = MLP(enc_dim + (9 if cfg.shading else 0), cfg.color_hidden_dim,
                             cfg.color_hidden_layers, 3, generator)

    def unit(self, x_c: Tensor) -> Tensor:
        return (x_c - self.box[0]) / (self.box[1] - self.box[0])

    def forward(self, x_c: Tensor, rot_pc: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """``x_c (N, 3)`` canonical points, ``rot_pc (N, 3, 3)`` posed-to-canonical rotations ->
        ``sigma (N,)`` (1/m; 0 outside the box) and ``rgb (N, 3)`` in (0, 1)."""
        u = self.unit(x_c)
        inside = ((u >= 0.0) & (u <= 1.0)).all(-1)
        if self.encoding is not None:
            feat = self.encoding(u)
        else:
            feat = positional_encoding(u * 2.0 - 1.0, self.cfg.pe_frequencies)
        sigma = trunc_exp(self.density_mlp(feat)[:, 0] - 1.0) * inside
        if self.cfg.shading:
            if rot_pc is None:
                rot_pc = torch.eye(3, dtype=x_c.dtype, device=x_c.device).expand(x_c.shape[0], 3, 3)
            feat = torch.cat([feat, rot_pc.reshape(-1, 9)], dim=-1)
        return sigma, torch.sigmoid(self.color_mlp(feat))


class NonRigidOffset(nn.Module):
    """``(x_c, pose) -> offset (N, 3)`` with ``|offset| < max_offset_m`` per axis; zero at start."""

    def __init__(self, cfg: HumanModelConfig, n_joints: int, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.frequencies = cfg.nonrigid_pe_frequencies
        self.max_offset_m = cfg.nonrigid_max_offset_m
        in_dim = 3 * (1 + 2 * self.frequencies) + 6 * (n_joints - 1)
        self.mlp = MLP(in_dim, cfg.nonrigid_hidden_dim, 2, 3, generator)
        with torch.no_grad():
            self.mlp.layers[-1].weight.zero_()
            self.mlp.layers[-1].bias.zero_()

    def forward(self, unit_c: Tensor, pose: Tensor) -> Tensor:
        enc = positional_encoding(unit_c * 2.0 - 1.0, self.frequencies)
        h = torch.cat([enc, pose.to(enc.dtype).expand(enc.shape[0], -1)], dim=-1)
        return torch.tanh(self.mlp(h)) * self.max_offset_m


@dataclass
class Warp:
    """Posed points mapped to canonical space: ``K`` hypotheses per point (N points).

    x_c: (N, K, 3) canonical points; weights: (N, K) each hypothesis' skinning weight (its
    share of the canonical density); joint: (N, K) the joint whose transform made it (-1 for a
    blend of several); rot_pc: (N, K, 3, 3) its posed-to-canonical rotation; ownership: (N,)
    ``sum_j w^c_j(y_j)`` over all joints.
    """

    x_c: Tensor
    weights: Tensor
    joint: Tensor
    rot_pc: Tensor
    ownership: Tensor


@dataclass
class MergedRender:
    """Per-ray result of rendering several sample sets together (R rays).

    rgb: (R, 3); accumulation: (R,) total opacity; depth: (R,) expected range (metres along the
    unit ray, ``nsim.volume.quadrature.expected_depth``); alpha: (K, R) each input set's visible
    opacity (its share of the weights), e.g. the person mask of a human set.
    """

    rgb: Tensor
    accumulation: Tensor
    depth: Tensor
    alpha: Tensor


def render_merged(*sets: RaySamples, background_rgb: Tensor | None = None) -> MergedRender:
    """Volume-render sample sets together in depth order, over ``background_rgb`` ((3,) or (R, 3)):
    ``nsim.volume.compositing.composite_sets``, the renderer's compositing, with each set's opacity."""
    out, source = composite_sets(*sets, background_rgb=background_rgb)
    return MergedRender(out.rgb, out.accumulation, out.depth, set_weights(out.weights, source, len(sets)))


def empty_samples(n_rays: int, device: str | torch.device = "cpu") -> RaySamples:
    """A set of zero samples per ray (``(R, 0)``)."""
    z = torch.zeros((n_rays, 0), device=device)
    return RaySamples(z, z.clone(), z.clone(), torch.zeros((n_rays, 0, 3), device=device))


class HumanModel(nn.Module):
    """The human NeRF of one person (``skeleton``); see the module docstring."""

    def __init__(self, cfg: HumanModelConfig, skeleton: Skeleton, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        self.skeleton = skeleton
        J = skeleton.num_joints
        self.padding_m = default_padding_m(skeleton) if cfg.box_padding_m is None else float(cfg.box_padding_m)
        rest = skeleton.rest_transforms()
        lo, hi = pose_aabb(skeleton, rest, self.padding_m)
        box = torch.tensor(np.stack([lo, hi]), dtype=torch.float32)
        self.register_buffer("canonical_box", box)
        self.register_buffer("rest_transforms", torch.as_tensor(rest, dtype=torch.float32))
        self.register_buffer("parents", torch.as_tensor(np.maximum(skeleton.parents, 0)))
        has_end = np.isfinite(skeleton.end_sites_m[:, 0])
        self.register_buffer("end_joints", torch.as_tensor(np.nonzero(has_end)[0]))
        self.register_buffer("end_sites", torch.as_tensor(skeleton.end_sites_m[has_end], dtype=torch.float32))
        seg_a, seg_b, seg_joint = bone_segments(skeleton)  # rest-pose bones (derived: not in the state dict)
        self.register_buffer("bone_start", torch.as_tensor(seg_a, dtype=torch.float32), persistent=False)
        self.register_buffer("bone_end", torch.as_tensor(seg_b, dtype=torch.float32), persistent=False)
        self.register_buffer("bone_joint", torch.as_tensor(seg_joint), persistent=False)
        # the blend-weight volume: (J, 1, Z, Y, X) log-weights on the vertices of a grid over the box
        extent = (hi - lo)
        res = [max(2, int(math.ceil(e / cfg.blend_voxel_m)) + 1) for e in extent]  # x, y, z vertices
        xs = [torch.linspace(float(lo[a]), float(hi[a]), res[a], dtype=torch.float64) for a in range(3)]
        gz, gy, gx = torch.meshgrid(xs[2], xs[1], xs[0], indexing="ij")
        grid = torch.stack([gx, gy, gz], dim=-1).reshape(-1, 3)
        logw = initial_blend_log_weights(grid, skeleton, cfg.blend_temperature_m, cfg.blend_background_m)
        vol = logw.t().reshape(J, 1, res[2], res[1], res[0]).float()
        self.blend_log_weights = nn.Parameter(vol.clamp(min=-60.0).contiguous())
        self.field = CanonicalField(cfg, box, generator)
        self.nonrigid = NonRigidOffset(cfg, J, generator) if cfg.nonrigid else None

    # ------------------------------------------------------------------ poses and boxes
    def as_transforms(self, joint_transforms) -> Tensor:
        """``joint_transforms`` ``(J, 4, 4)`` or ``(P, J, 4, 4)`` (array or tensor) as float32 on the
        model's device, always ``(P, J, 4, 4)``."""
        T = joint_transforms if isinstance(joint_transforms, Tensor) else torch.as_tensor(np.asarray(joint_transforms))
        J = self.skeleton.num_joints
        if T.shape[-3:] != (J, 4, 4) or T.ndim not in (3, 4):
            raise ValueError(f"joint_transforms: expected ({J}, 4, 4) or (P, {J}, 4, 4), got {tuple(T.shape)}")
        return T.to(device=self.canonical_box.device, dtype=torch.float32).reshape(-1, J, 4, 4)

    def posed_box(self, joint_transforms) -> Tensor:
        """World boxes ``(P, 2, 3)`` around the posed joints and end sites, grown by the padding."""
        T = self.as_transforms(joint_transforms)
        Te = T[:, self.end_joints]
        ends = Te[..., :3, 3] + torch.einsum("peij,ej->pei", Te[..., :3, :3], self.end_sites)
        pts = torch.cat([T[..., :3, 3], ends], dim=1)
        return torch.stack([pts.amin(1) - self.padding_m, pts.amax(1) + self.padding_m], dim=1)

    def posed_bones(self, joint_transforms) -> tuple[Tensor, Tensor]:
        """Every pose's bone segments (``bone_segments``), carried by their joints: starts, ends ``(P, B, 3)``."""
        G = self.skinning(joint_transforms)[:, self.bone_joint]  # (P, B, 4, 4)
        R, t = G[..., :3, :3], G[..., :3, 3]
        return (torch.einsum("pbij,bj->pbi", R, self.bone_start) + t,
                torch.einsum("pbij,bj->pbi", R, self.bone_end) + t)

    def skinning(self, joint_transforms) -> Tensor:
        """Canonical-to-posed transforms ``G_j = T_j R_j^-1``: ``(P, J, 4, 4)``."""
        return self.as_transforms(joint_transforms) @ torch.linalg.inv(self.rest_transforms)

    def pose_codes(self, joint_transforms) -> Tensor:
        """The non-rigid MLP's pose input per pose: ``(P, 6 (J - 1))``."""
        T = self.as_transforms(joint_transforms)
        return torch.stack([local_rotations_6d(t, self.parents) for t in T])

    # ------------------------------------------------------------------ blend weights
    def _grid_coords(self, y: Tensor) -> tuple[Tensor, Tensor]:
        """grid_sample coordinates in [-1, 1] of canonical points ``y (..., 3)`` and an inside mask."""
        lo, hi = self.canonical_box[0], self.canonical_box[1]
        g = (y - lo) / (hi - lo) * 2.0 - 1.0
        return g, (g.abs() <= 1.0).all(-1)

    def blend_log_weights_at(self, y: Tensor) -> Tensor:
        """Joint ``j``'s canonical log-weight at its own candidate ``y[:, j] (N, J, 3)``: ``(N, J)``
        (``-1e4`` outside the box)."""
        n, J = y.shape[0], y.shape[1]
        g, inside = self._grid_coords(y)
        grid = g.transpose(0, 1).reshape(J, n, 1, 1, 3)  # batch = joint
        out = torch.nn.functional.grid_sample(self.blend_log_weights, grid, mode="bilinear", padding_mode="border",
                                              align_corners=True)  # (J, 1, n, 1, 1)
        logw = out.reshape(J, n).t()
        return torch.where(inside, logw, torch.full_like(logw, -1e4))

    def blend_log_weights_of(self, y: Tensor, joints: Tensor) -> Tensor:
        """Joint ``joints[n, k]``'s canonical log-weight at its candidate ``y[n, k] (N, K, 3)``: ``(N, K)`` (``-1e4``
        outside the box). What :meth:`blend_log_weights_at` reads for every joint (the same trilinear interpolation
        on the grid's vertices, clamped at its border), for the given ones only."""
        vol = self.blend_log_weights[:, 0]  # (J, Z, Y, X)
        J, Z, Y, X = vol.shape
        g, inside = self._grid_coords(y)
        size = torch.tensor([X - 1, Y - 1, Z - 1], dtype=y.dtype, device=y.device)
        p = torch.minimum(torch.maximum((g + 1.0) * 0.5 * size, torch.zeros_like(size)), size)
        p0 = torch.minimum(torch.floor(p), (size - 1).clamp(min=0)).detach()
        f = p - p0
        i0 = p0.long()
        flat = vol.reshape(-1)
        base = joints * (Z * Y * X)
        out = torch.zeros_like(f[..., 0])
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    row = ((i0[..., 2] + dz).clamp(max=Z - 1) * Y + (i0[..., 1] + dy).clamp(max=Y - 1)) * X
                    w = ((f[..., 0] if dx else 1.0 - f[..., 0]) * (f[..., 1] if dy else 1.0 - f[..., 1])
                         * (f[..., 2] if dz else 1.0 - f[..., 2]))
                    out = out + w * flat[base + row + (i0[..., 0] + dx).clamp(max=X - 1)]
        return torch.where(inside, out, torch.full_like(out, -1e4))

    def canonical_weights(self, x_c: Tensor) -> Tensor:
        """Every joint's canonical weight at canonical points ``x_c (N, 3)``: ``(N, J)`` (not normalised)."""
        g, inside = self._grid_coords(x_c)
        vol = self.blend_log_weights.transpose(0, 1)  # (1, J, Z, Y, X)
        out = torch.nn.functional.grid_sample(vol, g.reshape(1, -1, 1, 1, 3), mode="bilinear", padding_mode="border",
                                              align_corners=True)
        return torch.exp(out.reshape(vol.shape[1], -1).t()) * inside[:, None]

    # ------------------------------------------------------------------ warps
    @staticmethod
    def _index(n: int, pose_index: Tensor | None, device) -> Tensor:
        return torch.zeros(n, dtype=torch.long, device=device) if pose_index is None else pose_index

    def candidates(self, x_p: Tensor, joint_transforms, pose_index: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Every joint's canonical candidate ``y_j = G_j^-1 x_p`` for points ``x_p (N, 3)`` posed
        by ``joint_transforms[pose_index]``: ``y (N, J, 3)``, log-weights ``log w^c_j(y_j) (N, J)``
        and the per-pose inverse rotations ``(P, J, 3, 3)``."""
        G_inv = torch.linalg.inv(self.skinning(joint_transforms))  # (P, J, 4, 4) posed -> canonical per joint
        n, P, J = x_p.shape[0], G_inv.shape[0], G_inv.shape[1]
        idx = self._index(n, pose_index, x_p.device)
        # per pose, y = x_p M + t with M (3, J 3) = every joint's rotation side by side: one matrix product
        M = G_inv[:, :, :3, :3].permute(0, 3, 1, 2).reshape(P, 3, J * 3)
        t = G_inv[:, :, :3, 3].reshape(P, J * 3)
        if P == 1:
            y = torch.addmm(t[0], x_p, M[0])
        else:  # one product per pose over its points (cheaper than gathering a transform per point)
            ordered = n < 2 or bool((idx[1:] >= idx[:-1]).all())  # render_samples sorts its rays by pose
            order = None if ordered else torch.argsort(idx, stable=True)
            counts = torch.bincount(idx, minlength=P).tolist()
            xs = x_p if order is None else x_p[order]
            y = torch.cat([torch.addmm(t[p], part, M[p]) for p, part in enumerate(torch.split(xs, counts)) if counts[p]])
            if order is not None:
                y = torch.empty_like(y).index_put((order,), y)
        y = y.view(n, J, 3)
        return y, self.blend_log_weights_at(y), G_inv[..., :3, :3]

    def warp(self, x_p: Tensor, joint_transforms, pose_index: Tensor | None = None) -> Warp:
        """Posed points ``x_p (N, 3)`` -> canonical hypotheses (see ``HumanModelConfig.skinning``),
        then the non-rigid offset. ``joint_transforms``: one pose ``(J, 4, 4)``, or ``(P, J, 4, 4)``
        with each point's pose in ``pose_index (N,)``."""
        n = x_p.shape[0]
        idx = self._index(n, pose_index, x_p.device)
        if self.cfg.skinning == "blend":
            y, logw, rot_inv = self.candidates(x_p, joint_transforms, idx)
            ownership = torch.exp(torch.logsumexp(logw, dim=1))
            w = torch.softmax(logw, dim=1)
            x_c = torch.einsum("nj,nja->na", w, y)[:, None]
            rot = torch.einsum("nj,njab->nab", w, rot_inv[idx])[:, None]
            weights = ownership.clamp(max=1.0)[:, None]
            joint = torch.full_like(weights, -1, dtype=torch.long)
        else:
            T = self.as_transforms(joint_transforms)
            # Which hypotheses: every joint's candidate weighed, without a graph (the choice is not differentiated,
            # and only the chosen hypotheses reach the loss). Where the warp is differentiated (pose refinement,
            # learned skinning weights) the chosen ones are then formed again, with their gradients: the same
            # numbers, at the cost of K candidates instead of J.
            with torch.no_grad():
                y, logw, rot_inv = self.candidates(x_p, T, idx)
                ownership = torch.exp(torch.logsumexp(logw, dim=1))
                top, joint = torch.topk(logw, min(self.cfg.skinning_candidates, logw.shape[1]), dim=1)
            if torch.is_grad_enabled() and (T.requires_grad or x_p.requires_grad
                                            or self.blend_log_weights.requires_grad):
                G_inv = torch.linalg.inv(self.skinning(T))[idx[:, None], joint]  # (N, K, 4, 4)
                x_c = torch.einsum("nkab,nb->nka", G_inv[..., :3, :3], x_p) + G_inv[..., :3, 3]
                top, rot = self.blend_log_weights_of(x_c, joint), G_inv[..., :3, :3]
            else:
                x_c = torch.gather(y, 1, joint[..., None].expand(-1, -1, 3))
                rot = rot_inv[idx[:, None], joint]
            weights = torch.exp(top)
        if self.nonrigid is not None:
            k = x_c.shape[1]
            code = self.pose_codes(joint_transforms)[idx]
            offset = self.nonrigid(self.field.unit(x_c.reshape(-1, 3)), code.repeat_interleave(k, dim=0))
            x_c = x_c + offset.view(n, k, 3)
        return Warp(x_c, weights, joint, rot, ownership)

    def canonical_to_posed(self, x_c: Tensor, joint_transforms) -> Tensor:
        """Forward LBS of canonical points ``x_c (N, 3)`` to one pose ``(J, 4, 4)`` with the
        canonical weights: ``(N, 3)``. (Skinning only: the non-rigid offset is not inverted.)"""
        G = self.skinning(joint_transforms)[0]
        w = self.canonical_weights(x_c)
        w = w / w.sum(-1, keepdim=True).clamp(min=1e-12)
        y = torch.einsum("jab,nb->nja", G[:, :3, :3], x_c) + G[:, :3, 3]
        return torch.einsum("nj,nja->na", w, y)

    def query(self, x_p: Tensor, joint_transforms, pose_index: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Density ``(N,)``, colour ``(N, 3)`` and ownership ``(N,)`` at posed points ``x_p (N, 3)``.

        ``sigma = sum_k w_k sigma_c(x_c^k)``, colour the density-weighted mean of the
        hypotheses'. Hypotheses weighing less than ``min_ownership`` are not evaluated.
        """
        wp = self.warp(x_p, joint_transforms, pose_index)
        n, k = wp.weights.shape
        flat = torch.nonzero(wp.weights.reshape(-1) > self.cfg.min_ownership)[:, 0]
        sigma_k = x_p.new_zeros(n * k)
        rgb_k = x_p.new_zeros(n * k, 3)
        if flat.numel():
            s, c = self.field(wp.x_c.reshape(-1, 3)[flat], wp.rot_pc.reshape(-1, 3, 3)[flat])
            sigma_k = sigma_k.index_put((flat,), s * wp.weights.reshape(-1)[flat])
            rgb_k = rgb_k.index_put((flat,), c)
        sigma_k = sigma_k.view(n, k)
        sigma = sigma_k.sum(-1)
        if k == 1:
            return sigma, rgb_k, wp.ownership
        share = (sigma_k + 1e-6) / (sigma + k * 1e-6)[:, None]
        return sigma, (share[..., None] * rgb_k.view(n, k, 3)).sum(1), wp.ownership

    # ------------------------------------------------------------------ rendering
    def render_samples(self, origins: Tensor, dirs: Tensor, joint_transforms, near: float | Tensor = 0.0,
                       far: float | Tensor = 1e4, generator: torch.Generator | None = None,
                       pose_index: Tensor | None = None, box_test: bool = True) -> RaySamples:
        """Samples of the posed body along rays ``origins, dirs (R, 3)`` (world, unit dirs).

        ``joint_transforms``: the pose ``(J, 4, 4)``, or several ``(P, J, 4, 4)`` with each
        ray's in ``pose_index (R,)`` (training batches many frames in one call).
        ``samples_per_ray`` intervals split the part of ``[near, far]`` inside the posed box (with
        ``sample_bone_radius_m``: and within that distance of a posed bone, ``ray_capsule_interval``)
        evenly; with ``generator`` each sample's point is jittered inside its interval
        (training), else taken at its middle. Rays that miss the box get empty intervals at
        ``near`` (``t_starts == t_ends``, density 0). Returns ``RaySamples`` ``(R, S)``.

        ``box_test``: query the network only on the rays that meet the box (the ray-box test
        that visibility culling is). ``False`` queries it on every ray's samples, as a renderer
        without culling does, and gives the same samples (a missed ray's intervals are empty,
        so its density is set to 0 after the query): for measuring what culling saves.
        """
        T = self.as_transforms(joint_transforms)
        n, S = origins.shape[0], self.cfg.samples_per_ray
        dev = origins.device
        idx = self._index(n, pose_index, dev)
        boxes = self.posed_box(T.detach())[idx]  # (R, 2, 3); where to sample, not differentiated
        inv = 1.0 / torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
        ta, tb = (boxes[:, 0] - origins) * inv, (boxes[:, 1] - origins) * inv
        t_in, t_out = torch.minimum(ta, tb).amax(-1), torch.maximum(ta, tb).amin(-1)
        if self.cfg.sample_bone_radius_m is not None:  # where the ray passes near a bone (model config)
            a, b = self.posed_bones(T.detach())
            c0, c1 = ray_capsule_interval(origins, dirs, a[idx], b[idx], self.cfg.sample_bone_radius_m)
            t_in, t_out = torch.maximum(t_in, c0.amin(-1)), torch.minimum(t_out, c1.amax(-1))
        near_t = torch.as_tensor(near, dtype=origins.dtype, device=dev).expand(n)
        far_t = torch.as_tensor(far, dtype=origins.dtype, device=dev).expand(n)
        t_in, t_out = torch.maximum(t_in, near_t), torch.minimum(t_out, far_t)
        hit = t_out > t_in
        t_in = torch.where(hit, t_in, near_t)
        t_out = torch.where(hit, t_out, near_t)
        edges = t_in[:, None] + (t_out - t_in)[:, None] * torch.linspace(0.0, 1.0, S + 1, device=dev)
        t0, t1 = edges[:, :-1], edges[:, 1:]
        if generator is not None:
            u = torch.rand((n, S), generator=generator).to(dev)
        else:
            u = torch.full((n, S), 0.5, device=dev)
        t_mid = t0 + (t1 - t0) * u
        sigma = origins.new_zeros(n, S)
        rgb = origins.new_zeros(n, S, 3)
        if not box_test:
            chunk = 4096  # rays per query: bounds the warp's (points, joints) memory
            for a in range(0, n, chunk):
                sl = slice(a, min(n, a + chunk))
                x = origins[sl, None, :] + dirs[sl, None, :] * t_mid[sl, :, None]
                s, c, _ = self.query(x.reshape(-1, 3), T, idx[sl].repeat_interleave(S))
                sigma[sl] = torch.where(hit[sl, None], s.view(-1, S), 0.0)
                rgb[sl] = torch.where(hit[sl, None, None], c.view(-1, S, 3), 0.0)
            return RaySamples(t0, t1, sigma, rgb)
        rows = torch.nonzero(hit)[:, 0]
        if idx.numel() and bool((idx != idx[0]).any()):  # grouped by pose: the warp's one product per pose
            rows = rows[torch.argsort(idx[rows], stable=True)]
        if rows.numel():
            x = origins[rows, None, :] + dirs[rows, None, :] * t_mid[rows, :, None]
            s, c, _ = self.query(x.reshape(-1, 3), T, idx[rows].repeat_interleave(S))
            sigma = sigma.index_put((rows,), s.view(-1, S))
            rgb = rgb.index_put((rows,), c.view(-1, S, 3))
        return RaySamples(t0, t1, sigma, rgb)

    @torch.no_grad()
    def render(self, camera, cam_to_world, joint_transforms, background_rgb=(1.0, 1.0, 1.0),
               chunk: int = 8192) -> dict[str, np.ndarray]:
        """Render the posed person alone with ``camera`` at ``cam_to_world (4, 4)`` (OpenCV axes).

        background_rgb: (3,) colour or (H, W, 3) float image in [0, 1]. Returns ``rgb (H, W, 3)``
        float32, ``alpha (H, W)`` and ``depth (H, W)`` (range along the ray; 0 where empty).
        """
        was_training = self.training
        self.eval()
        dev = self.canonical_box.device
        h, w = camera.height, camera.width
        dirs_cam = camera_dirs(camera, dev).reshape(-1, 3)
        c2w = torch.as_tensor(np.asarray(cam_to_world), dtype=torch.float32, device=dev).expand(h * w, 4, 4)
        origins, dirs = dirs_to_world(dirs_cam, c2w)
        bg = torch.as_tensor(np.asarray(background_rgb, dtype=np.float32), device=dev)
        bg = bg.reshape(-1, 3).expand(h * w, 3) if bg.numel() == 3 else bg.reshape(h * w, 3)
        T = self.as_transforms(joint_transforms)
        rgb, alpha, depth = [], [], []
        for k in range(0, h * w, chunk):
            out = render_merged(self.render_samples(origins[k:k + chunk], dirs[k:k + chunk], T),
                                background_rgb=bg[k:k + chunk])
            rgb.append(out.rgb)
            alpha.append(out.accumulation)
            depth.append(torch.where(out.accumulation > 1e-4, out.depth, torch.zeros_like(out.depth)))
        self.train(was_training)
        return {"rgb": torch.cat(rgb).clamp(0, 1).view(h, w, 3).cpu().numpy(),
                "alpha": torch.cat(alpha).view(h, w).cpu().numpy(),
                "depth": torch.cat(depth).view(h, w).cpu().numpy()}


# ====================================================================== previews
def orbit_cameras(joint_transforms: np.ndarray, skeleton: Skeleton, n_views: int, width: int, height: int,
                  hfov_deg: float = 40.0, elevation_deg: float = 10.0, start_deg: float = 0.0):
    """A pinhole camera and ``n_views`` poses ``(V, 4, 4)`` on a circle around the posed body,
    far enough for the whole body to fit, looking at the centre of its box."""
    from nsim.geometry.cameras import Camera
    from nsim.geometry.transforms import look_at

    lo, hi = pose_aabb(skeleton, joint_transforms, 0.05)
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    cam = Camera.pinhole_from_fov(width, height, hfov_deg)
    vfov = 2.0 * math.atan(height / (2.0 * cam.fy))
    dist = radius / math.sin(0.5 * min(math.radians(hfov_deg), vfov)) * 1.05
    poses = []
    for k in range(n_views):
        az = math.radians(start_deg + 360.0 * k / n_views)
        el = math.radians(elevation_deg)
        eye = centre + dist * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        poses.append(look_at(eye, centre))
    return cam, np.stack(poses)


def turntable(model: HumanModel, joint_transforms: np.ndarray | None = None, n_views: int = 8, width: int = 96,
              height: int = 128, background_rgb=(1.0, 1.0, 1.0)) -> np.ndarray:
    """``n_views`` renders around the body (rest pose by default), side by side: ``(H, V W, 3)`` uint8."""
    from nsim.io.images import to_uint8

    T = model.skeleton.rest_transforms() if joint_transforms is None else np.asarray(joint_transforms)
    cam, poses = orbit_cameras(T, model.skeleton, n_views, width, height)
    return np.concatenate([to_uint8(model.render(cam, p, T, background_rgb)["rgb"]) for p in poses], axis=1)


def gait_cycle_poses(skeleton: Skeleton, n_frames: int = 16, speed_mps: float = 1.3) -> np.ndarray:
    """``n_frames`` joint transforms ``(F, J, 4, 4)`` of one walking cycle of ``skeleton``'s height,
    walking in place (the pelvis kept over the origin)."""
    from nsim.human.gait import walk_cycle
    from nsim.human.motion import LocomotionLoop
    from nsim.human.skeleton import REFERENCE_HEIGHT_M, forward_kinematics, nsim_skeleton

    # the nominal height (floor to top of head) of an nsim body as tall as ``skeleton``
    height = REFERENCE_HEIGHT_M * skeleton.height_m() / nsim_skeleton(REFERENCE_HEIGHT_M).height_m()
    loop = LocomotionLoop.from_clip(walk_cycle(speed_mps, float(np.clip(height, 0.5, 2.5))))
    phase = np.arange(n_frames) / n_frames
    root, quats = loop.pose_at(phase, np.zeros((n_frames, 2)), np.zeros(n_frames))
    return forward_kinematics(skeleton, quats, root)


def gait_frames(model: HumanModel, n_frames: int = 16, width: int = 96, height: int = 128,
                azimuth_deg: float = 60.0, background_rgb=(1.0, 1.0, 1.0)) -> list[np.ndarray]:
    """One walking cycle rendered from a fixed three-quarter view: ``F`` uint8 images ``(H, W, 3)``."""
    from nsim.io.images import to_uint8

    poses = gait_cycle_poses(model.skeleton, n_frames)
    cam, c2w = orbit_cameras(model.skeleton.rest_transforms(), model.skeleton, 1, width, height, start_deg=azimuth_deg)
    return [to_uint8(model.render(cam, c2w[0], T, background_rgb)["rgb"]) for T in poses]


# ====================================================================== saving and loading
MODEL_FILE = "human.pt"
META_FILE = "human.json"


def skeleton_to_dict(skeleton: Skeleton) -> dict:
    return {"joint_names": list(skeleton.joint_names), "parents": skeleton.parents.tolist(),
            "offsets_m": skeleton.offsets_m.tolist(),
            "end_sites_m": [[None if np.isnan(v) else float(v) for v in row] for row in skeleton.end_sites_m]}


def skeleton_from_dict(d: dict) -> Skeleton:
    ends = np.array([[np.nan if v is None else v for v in row] for row in d["end_sites_m"]], dtype=np.float64)
    return Skeleton(tuple(d["joint_names"]), np.asarray(d["parents"]), np.asarray(d["offsets_m"]), ends)


def save_human_model(out_dir: str | os.PathLike, model: HumanModel, extra: dict | None = None) -> None:
    """Write ``human.pt`` (state dict) and ``human.json`` (config, skeleton, canonical box, ``extra``)."""
    from nsim.config import to_dict

    out_dir = Path(out_dir)
    torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, out_dir / MODEL_FILE)
    meta = {
        "format": 1,
        "model": to_dict(model.cfg),
        "skeleton": skeleton_to_dict(model.skeleton),
        "canonical_box_m": model.canonical_box.cpu().tolist(),
        "frames": "canonical: the skeleton's rest pose (T-pose on z = 0, facing +x), world metres, z up",
        **(extra or {}),
    }
    (out_dir / META_FILE).write_text(json.dumps(meta, indent=1) + "\n")


def load_human_model(model_dir: str | os.PathLike, device: str | torch.device = "cpu") -> HumanModel:
    """Rebuild a :class:`HumanModel` written by :func:`save_human_model` (eval mode, on ``device``)."""
    from nsim.config import from_dict
    from nsim.errors import InputError

    model_dir = Path(model_dir)
    try:
        meta = json.loads((model_dir / META_FILE).read_text())
    except (FileNotFoundError, json.JSONDecodeError) as exc:
        raise InputError(f"{model_dir / META_FILE}: cannot read the human model description ({exc.__class__.__name__})") from None
    model = HumanModel(from_dict(HumanModelConfig, meta["model"]), skeleton_from_dict(meta["skeleton"]))
    model.load_state_dict(torch.load(model_dir / MODEL_FILE, map_location="cpu", weights_only=True))
    return model.to(device).eval()


__all__ = [
    "CanonicalField",
    "HumanModel",
    "HumanModelConfig",
    "MergedRender",
    "NonRigidOffset",
    "Warp",
    "bone_distances",
    "bone_segments",
    "empty_samples",
    "gait_cycle_poses",
    "gait_frames",
    "initial_blend_log_weights",
    "load_human_model",
    "local_rotations_6d",
    "merge_samples",
    "orbit_cameras",
    "point_segment_distance",
    "positional_encoding",
    "ray_capsule_interval",
    "render_merged",
    "save_human_model",
    "skeleton_from_dict",
    "skeleton_to_dict",
    "turntable",
]
