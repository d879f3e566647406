"""Training the human NeRF: data, ray sampling, compositing over the background, checkpoints, evaluation.

Input: a :class:`HumanTrainData` in memory — frames of one person with their camera poses,
the person's skeleton pose in every frame (``joint_transforms``, from
``nsim.human.skeleton.forward_kinematics``) and person masks — filled by the human-capture
loader or, in tests, by ray casting ``nsim.synth.actor.Actor``.

Background. The person is composited over what is behind them, in this order of preference:
the trained scene NeRF (``background_model``, a ``SceneModel``: its samples along each ray
are merged with the person's in depth order, so furniture in front of the person occludes
them), the frames' known background (``HumanTrainData.background``: a colour or images), or,
without either, the frame itself (exact outside the person; inside, the mask loss drives the
person opaque, so the background there is hidden).

Rays: each batch draws ``data.inside_fraction`` of its rays from pixels inside the person's
dilated mask and the rest from pixels inside the posed body box but outside the dilated mask
(rays outside the box carry no human samples and teach nothing). Loss: mean squared error of
the composite + ``mask_weight`` times the mean squared error of the person's visible opacity
against the mask.

Split: frame ``i`` is held out when ``i % holdout_every == holdout_every // 2`` or when it is
in the last ``holdout_last_fraction`` of the frames (a held-out part of the motion: poses the
model never saw). Evaluation on held-out frames: PSNR inside the person's 2D box (the ground
truth mask's bounding box grown by ``output.box_margin_px``) and mask IoU (opacity > 0.5 vs
the mask), against two trivial predictions: the box filled with the mean person colour of the
training frames (``psnr_box_baseline``) and the background alone (``psnr_box_background``, where the
frames' background is known).
With ``refine.held_out_steps > 0`` each held-out frame's pose is first fitted to its own image and mask
with the model frozen (the protocol of Anim-NeRF, InstantAvatar and Vid2Avatar for novel poses whose
estimates are off; :meth:`HumanTrainer.fit_held_out`), and the views are scored at the fitted poses and at
the given ones (``*_given_poses``).

Determinism and resume are the scene trainer's (``nsim.train.scene``): every random draw of
step ``k`` comes from generators seeded with ``(seed, k)``, learning rates are functions of
``k``, and a checkpoint (``work_dir/last.pt``) holds the step, weights and Adam moments, so a
killed run resumed from its last checkpoint ends bit-identical (CPU) to an uninterrupted one.

Core API (what a ``train_human`` stage calls)::

    data = HumanTrainData(images, cam_to_world, camera, joint_transforms, masks, skeleton)
    result = train_human(data, cfg, work_dir, device=ctx.device, seed=ctx.seed,
                         background_model=scene_model_or_None)
    summary = export_human(out.dir, result)   # weights, skeleton, box, previews, eval.json
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nsim.config import config_digest, param, to_dict
from nsim.errors import InputError
from nsim.geometry.cameras import dirs_to_world
from nsim.human.nerf import HumanModel, HumanModelConfig, render_merged
from nsim.human.refine import BodyPoseRefinement, pose_change
from nsim.human.shape_prior import (
    bone_frames,
    cameras_in_canonical,
    mirror_left_right,
    nearest_bone,
    outward,
    sample_near_bones,
    seen_fraction,
    turn_cross_section,
)
from nsim.human.skeleton import Skeleton, pose_aabb
from nsim.io import atomic_path
from nsim.metrics.image import psnr
from nsim.train import loop
from nsim.train.loop import ResumableTrainer, StepStats, spread, step_seed
from nsim.volume.rays import camera_dirs, make_rays
from nsim.volume.samples import RaySamples

log = logging.getLogger(__name__)



# ====================================================================== configuration
@dataclass(frozen=True)
class HumanOptimConfig:
    """Steps, batch and Adam with an exponentially decaying learning rate (from ``lr_*`` to
    ``lr_* * lr_final_factor``). ``lr_blend = 0`` freezes the skinning weights (cheaper).
    ``num_threads``: torch CPU threads (0 leaves torch's default) while the training loop runs and
    while :func:`export_human` renders; the count is restored after each (``HumanTrainer.loop_threads``)."""

    steps: int = param(3000, ge=1)
    rays_per_batch: int = param(1024, ge=1)
    lr_field: float = param(1e-2, gt=0.0, help="the canonical field's encoding (hash table)")
    lr_mlp: float = param(1e-2, gt=0.0, help="the canonical field's MLPs")
    lr_blend: float = param(1e-3, ge=0.0)
    lr_nonrigid: float = param(1e-3, ge=0.0)
    lr_final_factor: float = param(0.1, gt=0.0, le=1.0)
    warmup_steps: int = param(0, ge=0)
    adam_eps: float = param(1e-15, gt=0.0)
    num_threads: int = param(2, ge=0, le=256)


@dataclass(frozen=True)
class HumanLossConfig:
    """Loss weights: ``mask_weight`` (opacity vs mask, MSE), ``blend_weight`` (keeps the learned
    skinning log-weights near their bone-distance initialisation, mean squared difference).

    The canonical body's priors where the video never looked (``nsim.human.shape_prior``; each 0: off), on
    ``prior_points`` canonical points a step drawn within ``prior_radius_m`` of the bones, their density taken as
    the opacity of a ``prior_step_m`` step (``1 - exp(-sigma step)``): ``cross_section_weight`` (the opacity
    unchanged by a turn about the point's bone in its cross-section, the trunk's ``trunk_aspect`` deep as wide;
    mean squared difference), ``symmetry_weight`` and ``symmetry_colour_weight`` (opacity and, weighted by it,
    colour unchanged by the left/right mirror), ``unseen_colour_weight`` (the colour of surface points that faced no
    training camera pulled towards the mean colour of their bone's seen surface points; a point's surface weight is
    its opacity times the transparency a ``prior_step_m`` further out from its bone). And
    ``opacity_entropy_weight``: the mean binary entropy (nats) of the batch rays' person opacity, against
    half-transparent people and floaters."""

    mask_weight: float = param(0.5, ge=0.0)
    blend_weight: float = param(1e-3, ge=0.0)
    cross_section_weight: float = param(0.0, ge=0.0, help="cross-sections turned about their bone (shape prior)")
    trunk_aspect: float = param(0.65, gt=0.0, le=2.0, help="the trunk's depth / width (cross_section_weight)")
    symmetry_weight: float = param(0.0, ge=0.0, help="left/right mirror symmetry of the opacity")
    symmetry_colour_weight: float = param(0.0, ge=0.0, help="left/right mirror symmetry of the colour")
    unseen_colour_weight: float = param(0.0, ge=0.0, help="unseen colour pulled to its bone's seen colour")
    opacity_entropy_weight: float = param(0.0, ge=0.0, help="binary entropy of the rays' person opacity (0 or 1)")
    prior_points: int = param(2048, ge=1, help="canonical points a step for the priors above")
    prior_radius_m: float = param(0.2, gt=0.0, help="the priors' points lie this close to a bone")
    prior_step_m: float = param(0.02, gt=0.0, help="opacity of density sigma: 1 - exp(-sigma prior_step_m)")
    seen_min_fraction: float = param(0.02, ge=0.0, lt=1.0,
                                     help="a point is unseen when it faced fewer of the training cameras")

    @property
    def priors(self) -> bool:
        """Whether any canonical prior is on."""
        return (self.cross_section_weight > 0 or self.symmetry_weight > 0 or self.symmetry_colour_weight > 0
                or self.unseen_colour_weight > 0)


@dataclass(frozen=True)
class HumanDataConfig:
    """Split and ray sampling (see the module docstring)."""

    holdout_every: int = param(8, ge=0, help="hold out frame i when i % holdout_every == holdout_every // 2 (0: none)")
    holdout_last_fraction: float = param(0.0, ge=0.0, lt=1.0, help="also hold out this last part of the frames")
    inside_fraction: float = param(0.8, ge=0.0, le=1.0, help="share of rays drawn inside the dilated mask")
    mask_dilation_px: int = param(2, ge=0, le=64)
    near_m: float = param(0.05, ge=0.0)


@dataclass(frozen=True)
class HumanOutputConfig:
    """Logging, checkpoints, evaluation and previews."""

    log_every: int = param(100, ge=1)
    checkpoint_every: int = param(500, ge=1)
    eval_views: int = param(0, ge=0, help="held-out views scored at the end (0: all)")
    box_margin_px: int = param(2, ge=0)
    render_chunk_rays: int = param(8192, ge=1)
    preview_views: int = param(8, ge=1, le=64, help="turntable views")
    preview_width: int = param(96, ge=8)
    preview_height: int = param(128, ge=8)
    gait_frames: int = param(16, ge=2, le=256)
    gait_fps: float = param(12.0, gt=0.0)


@dataclass(frozen=True)
class HumanRefineConfig:
    """Pose refinement (``nsim.human.refine``, as NeuMan and HumanNeRF): per-frame joint rotations and a
    root translation learned with the NeRF by the same losses, from ``start_fraction`` of the steps on,
    at Adam's rate ``lr`` (decaying with the others; 0: the poses are used as given), on every ``every``-th step
    from there (a step that refines costs about twice one that does not: the gradient reaches the poses through
    the canonical field's encoding; on the others the poses are used as refined so far). The regulariser
    (weights ``*_weight``, added to the loss) keeps the corrections small and smooth in frame order, which
    also carries the neighbours' corrections to held-out frames (see ``nsim.human.refine``).

    Held-out fit (``held_out_steps > 0``; the test-time pose fit of Anim-NeRF, InstantAvatar and Vid2Avatar for
    novel-pose scores with estimated poses): after training, with the model frozen, each held-out frame's pose
    (as the model sees it then: refined when refinement is on) is fitted to its own image and mask by the
    training losses through the same corrections, each frame's own (no mean over frames taken, no smoothness
    term), under the prior ``held_out_*_weight``; the held-out views are then scored at the fitted poses (see
    :meth:`HumanTrainer.fit_held_out`). 0: the poses as they are, the scores of before."""

    lr: float = param(0.0, ge=0.0, help="Adam's rate for the corrections (radians, metres); 0: off")
    start_fraction: float = param(0.25, ge=0.0, lt=1.0, help="refine from this share of the steps on")
    every: int = param(1, ge=1, help="refine on every this-many-th step from the start (between, the poses as refined)")
    rotation_weight: float = param(1e-3, ge=0.0, help="prior on the joint corrections, per rad^2")
    translation_weight: float = param(1e-1, ge=0.0, help="prior on the root translation, per m^2")
    smooth_weight: float = param(1e-1, ge=0.0, help="first differences between consecutive frames' corrections")
    held_out_steps: int = param(0, ge=0, help="Adam steps of the held-out frames' pose fit after training; 0: off")
    held_out_lr: float = param(1e-3, gt=0.0, help="the held-out fit's Adam rate, decaying to a tenth over its steps")
    held_out_rotation_weight: float = param(1.0, ge=0.0, help="the held-out fit's prior on joint corrections, per rad^2")
    held_out_translation_weight: float = param(1.0, ge=0.0, help="the held-out fit's prior on the root shift, per m^2")


@dataclass(frozen=True)
class TrainHumanConfig:
    model: HumanModelConfig = HumanModelConfig()
    optim: HumanOptimConfig = HumanOptimConfig()
    loss: HumanLossConfig = HumanLossConfig()
    data: HumanDataConfig = HumanDataConfig()
    output: HumanOutputConfig = HumanOutputConfig()
    refine: HumanRefineConfig = HumanRefineConfig()


# ====================================================================== data
def holdout_split(n: int, cfg: HumanDataConfig) -> tuple[np.ndarray, np.ndarray]:
    """(train indices, held-out indices) of ``n`` frames (module docstring); InputError when none trains. A
    function of ``n`` and ``cfg`` alone: ``nsim train-human`` checks it before reading any image."""
    idx = np.arange(n)
    held = np.zeros(n, dtype=bool)
    if cfg.holdout_every > 0:
        held |= idx % cfg.holdout_every == cfg.holdout_every // 2
    if cfg.holdout_last_fraction > 0:
        held |= idx >= n - int(round(cfg.holdout_last_fraction * n))
    if held.all():
        raise InputError("human data: the hold-out settings leave no training frames")
    return idx[~held], idx[held]


@dataclass(eq=False)
class HumanTrainData:
    """Frames of one person, in memory.

    images: (N, H, W, 3) uint8; cam_to_world: (N, 4, 4) OpenCV axes; camera: the intrinsics
    (``nsim.geometry.cameras.Camera``, W x H); joint_transforms: (N, J, 4, 4) joint-to-world of
    ``skeleton`` in each frame; masks: (N, H, W) bool, the person's pixels; background: None,
    an RGB colour (3,) in [0, 1], or (N, H, W, 3) uint8 images of what is behind the person;
    names: per-frame labels (default ``frame_00000`` ...). ``digest`` (of all of it) is
    computed on construction when not given. ``height_m``: the person's height (floor to top of head)
    as the poses' source gives it, written with refined poses (None: the skeleton's rest extent).
    """

    images: np.ndarray
    cam_to_world: np.ndarray
    camera: Any
    joint_transforms: np.ndarray
    masks: np.ndarray
    skeleton: Skeleton
    background: np.ndarray | None = None
    names: list[str] | None = None
    digest: str = ""
    height_m: float | None = None

    def __post_init__(self) -> None:
        self.images = np.asarray(self.images)
        self.cam_to_world = np.asarray(self.cam_to_world, dtype=np.float64)
        self.joint_transforms = np.asarray(self.joint_transforms, dtype=np.float64)
        self.masks = np.asarray(self.masks, dtype=bool)
        n = self.images.shape[0]
        h, w = self.camera.height, self.camera.width
        J = self.skeleton.num_joints
        if self.images.dtype != np.uint8 or self.images.shape != (n, h, w, 3):
            raise InputError(f"human data: images: expected ({n}, {h}, {w}, 3) uint8 (the camera is {w}x{h}), "
                             f"got {self.images.shape} {self.images.dtype}")
        for name, arr, shape in (("cam_to_world", self.cam_to_world, (n, 4, 4)),
                                 ("joint_transforms", self.joint_transforms, (n, J, 4, 4)),
                                 ("masks", self.masks, (n, h, w))):
            if arr.shape != shape:
                raise InputError(f"human data: {name}: expected {shape} for {n} frames, got {arr.shape}")
        if n < 2:
            raise InputError(f"human data: need at least 2 frames, got {n}")
        if self.background is not None:
            bg = np.asarray(self.background)
            if bg.shape == (3,):
                bg = bg.astype(np.float32)
                if not np.all((bg >= 0) & (bg <= 1)):
                    raise InputError(f"human data: background colour must be in [0, 1], got {bg.tolist()}")
            elif bg.shape != (n, h, w, 3) or bg.dtype != np.uint8:
                raise InputError(f"human data: background: expected (3,) colour or ({n}, {h}, {w}, 3) uint8, got "
                                 f"{bg.shape} {bg.dtype}")
            self.background = bg
        if self.names is None:
            self.names = [f"frame_{i:05d}" for i in range(n)]
        if not self.digest:
            hsh = hashlib.sha256()
            for arr in (self.images, self.cam_to_world, self.joint_transforms, self.masks,
                        self.skeleton.offsets_m, self.skeleton.parents):
                hsh.update(np.ascontiguousarray(arr).tobytes())
            hsh.update(json.dumps(self.camera.to_dict(), sort_keys=True).encode())
            if self.background is not None:
                hsh.update(np.ascontiguousarray(self.background).tobytes())
            self.digest = hsh.hexdigest()

    @property
    def n_frames(self) -> int:
        return self.images.shape[0]

    @property
    def size_hw(self) -> tuple[int, int]:
        return self.images.shape[1], self.images.shape[2]

    def split(self, cfg: HumanDataConfig) -> tuple[np.ndarray, np.ndarray]:
        """(train indices, held-out indices); see the module docstring."""
        return holdout_split(self.n_frames, cfg)

    def background_pixels(self, frames: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray | None:
        """Known background colours ``(n, 3)`` float32 at pixels (frames, v, u), or None."""
        if self.background is None:
            return None
        if self.background.shape == (3,):
            return np.broadcast_to(self.background, (len(frames), 3)).astype(np.float32)
        return self.background[frames, v, u].astype(np.float32) / 255.0


def _dilate(mask: np.ndarray, px: int) -> np.ndarray:
    if px <= 0:
        return mask.copy()
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel) > 0


def _step_seed(seed: int, step: int, purpose: str = "batch") -> int:
    """The human trainer's seeds (``nsim.train.loop.step_seed`` in its namespace)."""
    return step_seed("nsim.train.human", seed, step, purpose)


def _module_digest(module: torch.nn.Module | None) -> str:
    if module is None:
        return ""
    h = hashlib.sha256()
    for k, v in module.state_dict().items():
        h.update(k.encode())
        h.update(v.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


# ====================================================================== the trainer
class HumanTrainer(ResumableTrainer):
    """One training run's state: model, optimiser, step; ``train_step`` advances it by one."""

    def __init__(self, data: HumanTrainData, cfg: TrainHumanConfig, device: str = "cpu", seed: int = 0,
                 background_model=None) -> None:
        self.data, self.cfg, self.device, self.seed = data, cfg, torch.device(device), int(seed)
        self.train_ids, self.eval_ids = data.split(cfg.data)
        init = torch.Generator().manual_seed(_step_seed(seed, 0, "init"))
        self.model = HumanModel(cfg.model, data.skeleton, generator=init).to(self.device)
        self.blend_init = self.model.blend_log_weights.detach().clone()
        self.background_model = background_model.to(self.device).eval() if background_model is not None else None
        if self.background_model is not None:
            for p in self.background_model.parameters():
                p.requires_grad_(False)
        self.images = torch.as_tensor(data.images).to(self.device)
        self.masks = torch.as_tensor(data.masks).to(self.device)
        self.dirs_cam = camera_dirs(data.camera, self.device)  # (H, W, 3)
        self.cam_to_world = torch.as_tensor(data.cam_to_world, dtype=torch.float32, device=self.device)
        self.joint_transforms = torch.as_tensor(data.joint_transforms, dtype=torch.float32, device=self.device)
        self.bg_images = None
        self.bg_colour = None
        if data.background is not None and data.background.shape == (3,):
            self.bg_colour = torch.as_tensor(data.background, dtype=torch.float32, device=self.device)
        elif data.background is not None:
            self.bg_images = torch.as_tensor(data.background).to(self.device)
        self._build_pools()
        self.bones = bone_frames(data.skeleton, cfg.loss.trunk_aspect) if cfg.loss.priors else None
        self.cameras_c = None
        if cfg.loss.unseen_colour_weight > 0:
            ids = torch.as_tensor(self.train_ids, device=self.device)
            self.cameras_c = cameras_in_canonical(self.joint_transforms[ids], self.model.rest_transforms,
                                                  self.cam_to_world[ids])
        o = cfg.optim
        f = self.model.field
        encoding = list(f.encoding.parameters()) if f.encoding is not None else []
        groups = [{"params": list(f.density_mlp.parameters()) + list(f.color_mlp.parameters()), "lr": o.lr_mlp,
                   "name": "mlp"}]
        if encoding:
            groups.append({"params": encoding, "lr": o.lr_field, "name": "encoding"})
        if o.lr_blend > 0:
            groups.append({"params": [self.model.blend_log_weights], "lr": o.lr_blend, "name": "blend"})
        else:
            self.model.blend_log_weights.requires_grad_(False)
        if self.model.nonrigid is not None:
            if o.lr_nonrigid > 0:
                groups.append({"params": list(self.model.nonrigid.parameters()), "lr": o.lr_nonrigid, "name": "nonrigid"})
            else:
                self.model.nonrigid.requires_grad_(False)
        self.refine = None
        if cfg.refine.lr > 0:
            self.refine = BodyPoseRefinement(self.joint_transforms, data.skeleton.parents).to(self.device)
            groups.append({"params": list(self.refine.parameters()), "lr": cfg.refine.lr, "name": "pose"})
        self.refine_start = int(round(cfg.refine.start_fraction * o.steps))
        self.base_lr = [g["lr"] for g in groups]
        self.optimizer = torch.optim.Adam(groups, eps=o.adam_eps, fused=self.device.type in ("cpu", "cuda"))
        self.step = 0
        self.train_seconds = 0.0
        self.history: list[dict[str, float]] = []
        self.held_out_fit: dict[str, Any] | None = None  # fit_held_out's result, once run

    # ------------------------------------------------------------------ ray pools
    def _build_pools(self) -> None:
        """The training frames' ray pools (:meth:`_pools` at the given poses)."""
        self.pools = self._pools(self.train_ids, self.joint_transforms[torch.as_tensor(self.train_ids)])

    def _pools(self, frame_ids: np.ndarray, poses: Tensor) -> list[tuple[Tensor, Tensor, Tensor]]:
        """Per frame of ``frame_ids`` (posed by ``poses (len(frame_ids), J, 4, 4)``), the flat pixel indices
        inside the dilated mask and those inside the posed box but outside the dilated mask (the box's own
        pixels if that is empty), packed (:meth:`_pack`): ``[inside, outside]``."""
        h, w = self.data.size_hw
        inside, outside = [], []
        dirs_cam = self.dirs_cam.reshape(-1, 3)
        for row, i in enumerate(frame_ids):
            dil = torch.as_tensor(_dilate(self.data.masks[i], self.cfg.data.mask_dilation_px)).reshape(-1)
            origins, dirs = dirs_to_world(dirs_cam, self.cam_to_world[i].expand(h * w, 4, 4))
            box = self.model.posed_box(poses[row])[0]
            rays = make_rays(origins, dirs, self.cfg.data.near_m, 1e4, box)
            in_box = (rays.far > rays.near + 2e-4).cpu()
            pin = torch.nonzero(dil)[:, 0]
            pout = torch.nonzero(in_box & ~dil)[:, 0]
            if pin.numel() == 0:
                pin = torch.nonzero(in_box)[:, 0] if in_box.any() else torch.arange(h * w)
            if pout.numel() == 0:
                pout = pin
            inside.append(pin)
            outside.append(pout)
        return [self._pack(inside), self._pack(outside)]

    @staticmethod
    def _pack(lists: list[Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        counts = torch.tensor([len(x) for x in lists])
        offsets = torch.cumsum(counts, 0) - counts
        return torch.cat(lists), offsets, counts

    # ------------------------------------------------------------------ batches
    def batch(self, step: int) -> tuple[Tensor, Tensor, Tensor, torch.Generator]:
        """Frame index ``(B,)`` (into the data), pixel rows ``v`` and columns ``u`` of ``step``'s
        rays: a pure function of ``(seed, step)``; and the step's generator."""
        g = torch.Generator().manual_seed(_step_seed(self.seed, step))
        frames, v, u = self._draw(g, self.pools, self.train_ids)
        return frames, v, u, g

    def _draw(self, g: torch.Generator, pools: list[tuple[Tensor, Tensor, Tensor]],
              frame_ids: np.ndarray) -> tuple[Tensor, Tensor, Tensor]:
        """``optim.rays_per_batch`` rays from ``pools`` (:meth:`_pools` of ``frame_ids``), ``data.inside_fraction``
        of them inside the dilated masks, drawn by ``g``: frame index ``(B,)`` (into the data), rows, columns."""
        b = self.cfg.optim.rays_per_batch
        n_in = int(round(self.cfg.data.inside_fraction * b))
        picks = []
        for pool, count in ((pools[0], n_in), (pools[1], b - n_in)):
            flat, offsets, counts = pool
            k = torch.randint(0, len(frame_ids), (count,), generator=g)
            r = torch.rand(count, generator=g, dtype=torch.float64)
            j = offsets[k] + (r * counts[k]).long().clamp(max=counts[k] - 1)
            picks.append((k, flat[j]))
        k = torch.cat([p[0] for p in picks])
        pix = torch.cat([p[1] for p in picks])
        w = self.data.size_hw[1]
        frames = torch.as_tensor(frame_ids)[k]
        return frames.to(self.device), (pix // w).to(self.device), (pix % w).to(self.device)

    # ------------------------------------------------------------------ rendering
    def _background(self, frames: Tensor, v: Tensor, u: Tensor) -> Tensor:
        """Per-ray background colour ``(B, 3)`` when there is no scene model."""
        if self.bg_colour is not None:
            return self.bg_colour.expand(frames.shape[0], 3)
        if self.bg_images is not None:
            return self.bg_images[frames, v, u].float() / 255.0
        return self.images[frames, v, u].float() / 255.0

    def _scene_samples(self, origins: Tensor, dirs: Tensor) -> tuple[RaySamples, Tensor]:
        """The scene model's samples on these rays and its per-ray background ``(B, 3)``."""
        s = self.background_model.sampler_cfg
        rays = make_rays(origins, dirs, s.near_m, s.far_m, self.background_model.aabb if s.clip_rays_to_box else None)
        with torch.no_grad():
            out = self.background_model.render(rays, return_samples=True)
        return out.samples, out.background

    def refining(self) -> bool:
        """Whether the poses are being refined at the current step."""
        return self.refine is not None and self.step >= self.refine_start

    def poses(self) -> Tensor:
        """Every frame's joint transforms ``(N, J, 4, 4)`` as the model sees them now: the given poses,
        or the refined ones once refinement has started (differentiable while gradients are on)."""
        return self.refine() if self.refining() else self.joint_transforms

    def render_rays(self, frames: Tensor, v: Tensor, u: Tensor, generator: torch.Generator | None = None,
                    poses: Tensor | None = None):
        """Composite of the person over the background for pixels ``(frames, v, u)``: a
        ``MergedRender`` whose ``alpha[0]`` is the person's visible opacity. ``poses``: the frames'
        joint transforms ``(N, J, 4, 4)`` (default :meth:`poses`)."""
        c2w = self.cam_to_world[frames]
        origins, dirs = dirs_to_world(self.dirs_cam[v, u], c2w)
        poses = self.poses() if poses is None else poses
        human = self.model.render_samples(origins, dirs, poses, near=self.cfg.data.near_m,
                                          generator=generator, pose_index=frames)
        if self.background_model is not None:
            scene, scene_bg = self._scene_samples(origins, dirs)
            return render_merged(human, scene, background_rgb=scene_bg)
        return render_merged(human, background_rgb=self._background(frames, v, u))

    # ------------------------------------------------------------------ one step
    def train_step(self) -> StepStats:
        t0 = self._begin_step()
        step = self.step
        cfg = self.cfg
        frames, v, u, g = self.batch(step)
        pose_step = self.refining() and (step - self.refine_start) % cfg.refine.every == 0
        if self.refining() and not pose_step:  # the refined poses as they are: no gradient for them this step
            with torch.no_grad():
                poses = self.poses()
        else:
            poses = self.poses()
        out = self.render_rays(frames, v, u, generator=g, poses=poses)
        loss, mse, mask_loss = self.image_loss(out, frames, v, u)
        extra = {"mask": float(mask_loss.detach())}
        if cfg.loss.opacity_entropy_weight > 0:
            a = out.alpha[0].clamp(1e-4, 1.0 - 1e-4)
            entropy = -torch.mean(a * torch.log(a) + (1.0 - a) * torch.log(1.0 - a))
            loss = loss + cfg.loss.opacity_entropy_weight * entropy
            extra["opacity_entropy"] = float(entropy.detach())
        if cfg.loss.blend_weight > 0 and self.model.blend_log_weights.requires_grad:
            reg = torch.mean((self.model.blend_log_weights - self.blend_init) ** 2)
            loss = loss + cfg.loss.blend_weight * reg
            extra["blend"] = float(reg.detach())
        if self.bones is not None:
            prior, terms = self.prior_loss(step)
            loss = loss + prior
            extra.update(terms)
        if pose_step:
            r = cfg.refine
            reg = self.refine.regulariser(r.rotation_weight, r.translation_weight, r.smooth_weight)
            loss = loss + reg
            extra["pose_reg"] = float(reg.detach())
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return self._finish_step(t0, loss, mse, extra)

    def prior_loss(self, step: int) -> tuple[Tensor, dict[str, float]]:
        """The canonical priors' weighted sum at ``step`` (``HumanLossConfig``, ``nsim.human.shape_prior``) and each
        term unweighted. Its points are drawn by a generator seeded with ``(seed, step)``."""
        c = self.cfg.loss
        bones = self.bones
        g = torch.Generator().manual_seed(_step_seed(self.seed, step, "prior"))
        pts, bone = sample_near_bones(bones, c.prior_points, c.prior_radius_m, g)
        n = pts.shape[0]
        sets = [pts]
        normals = outward(pts, bone, bones)
        if c.unseen_colour_weight > 0:  # a prior_step_m further out: the surface is where the body ends
            sets.append(pts + c.prior_step_m * normals)
        if c.cross_section_weight > 0:
            sets.append(turn_cross_section(pts, bone, bones, 2.0 * torch.pi * torch.rand(n, generator=g)))
        if c.symmetry_weight > 0 or c.symmetry_colour_weight > 0:
            sets.append(mirror_left_right(pts, self.data.skeleton))
        sigma, rgb = self.model.field(torch.cat(sets).to(self.device))
        alpha = 1.0 - torch.exp(-sigma * c.prior_step_m)
        a0, c0 = alpha[:n], rgb[:n]
        bone = bone.to(self.device)
        loss, terms, k = sigma.new_zeros(()), {}, 1
        if c.unseen_colour_weight > 0:
            surface = (a0 * (1.0 - alpha[n:2 * n])).detach()  # opaque here, clear just outside
            seen = seen_fraction(pts.to(self.device), normals.to(self.device), bones.joint.to(self.device)[bone],
                                 self.cameras_c)
            w_seen = surface * (seen >= c.seen_min_fraction)
            nb = bones.start.shape[0]
            total = torch.zeros(nb, device=self.device).index_add(0, bone, w_seen)
            mean = torch.zeros(nb, 3, device=self.device).index_add(0, bone, w_seen[:, None] * c0.detach())
            mean = mean / total.clamp(min=1e-6)[:, None]
            w = surface * (seen < c.seen_min_fraction) * (total[bone] > 1e-3)
            term = (w[:, None] * (c0 - mean[bone]) ** 2).sum() / w.sum().clamp(min=1e-6)
            loss, terms["unseen_colour"], k = loss + c.unseen_colour_weight * term, float(term.detach()), k + 1
        if c.cross_section_weight > 0:
            turned = sets[k].to(self.device)
            same = (nearest_bone(pts.to(self.device), bones)[0] == bone) & (nearest_bone(turned, bones)[0] == bone)
            w = bones.weight.to(self.device)[bone] * same
            term = (w * (a0 - alpha[k * n:(k + 1) * n]) ** 2).sum() / w.sum().clamp(min=1e-6)
            loss, terms["cross_section"], k = loss + c.cross_section_weight * term, float(term.detach()), k + 1
        if c.symmetry_weight > 0 or c.symmetry_colour_weight > 0:
            am, cm = alpha[k * n:(k + 1) * n], rgb[k * n:(k + 1) * n]
            term = torch.mean((a0 - am) ** 2)
            colour = torch.mean((a0 * am).detach()[:, None] * (c0 - cm) ** 2)
            loss = loss + c.symmetry_weight * term + c.symmetry_colour_weight * colour
            terms.update(symmetry=float(term.detach()), symmetry_colour=float(colour.detach()))
        return loss, terms

    def image_loss(self, out, frames: Tensor, v: Tensor, u: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(loss, mse, mask_loss)`` of a render ``out`` (``render_rays``) of pixels ``(frames, v, u)``: the
        composite's mean squared error + ``loss.mask_weight`` x that of the person's opacity against the mask."""
        target = self.images[frames, v, u].float() / 255.0
        mask = self.masks[frames, v, u].float()
        mse = torch.mean((out.rgb - target) ** 2)
        mask_loss = torch.mean((out.alpha[0] - mask) ** 2)
        return mse + self.cfg.loss.mask_weight * mask_loss, mse, mask_loss

    def loop_threads(self) -> int:
        """torch's intra-op threads while the training loop (and :func:`export_human`) runs: ``optim.num_threads``
        on a CPU; 0 (torch's count left alone) on a GPU or with ``num_threads`` 0."""
        threads = self.cfg.optim.num_threads
        return threads if self.device.type == "cpu" and threads > 0 else 0

    # ------------------------------------------------------------------ checkpoints
    def meta(self) -> dict[str, Any]:
        return {"config": config_digest(self.cfg), "data": self.data.digest, "seed": self.seed,
                "device": self.device.type, "background_model": _module_digest(self.background_model)}

    def _extra_state(self) -> dict[str, Any]:
        return {"pose_refinement": self.refine.state_dict()} if self.refine is not None else {}

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        if self.refine is not None:
            self.refine.load_state_dict(state["pose_refinement"])

    def refined_poses(self) -> np.ndarray | None:
        """The refined joint transforms ``(N, J, 4, 4)`` float64 of every frame: the trained frames refined
        (as given without refinement), the held-out ones fitted to their own images with the held-out fit
        (:meth:`fit_held_out`, run here if it has not been), else moved by their neighbours only; None with
        neither refinement nor the held-out fit."""
        if self.refine is None and self.cfg.refine.held_out_steps == 0:
            return None
        with torch.no_grad():
            return self.scoring_poses().double().cpu().numpy()

    # ------------------------------------------------------------------ the held-out fit
    def scoring_poses(self) -> Tensor:
        """Every frame's joint transforms ``(N, J, 4, 4)`` as the held-out views are scored: :meth:`poses`
        with the held-out frames' replaced by their fitted ones when the held-out fit is on."""
        fit = self.fit_held_out()
        return self.poses().detach() if fit is None else fit["poses"]

    def fit_held_out(self) -> dict[str, Any] | None:
        """Fit the held-out frames' poses to their own images and masks with the model frozen; None when
        ``refine.held_out_steps`` is 0 or nothing is held out. Run once, the result kept
        (``self.held_out_fit``).

        Each held-out frame's pose, as the model sees it now (:meth:`poses`), gets its own corrections
        (``BodyPoseRefinement(subtract_mean=False)``: joint rotations and a root translation), learned for
        ``held_out_steps`` Adam steps at ``held_out_lr`` (decaying to a tenth) by the training losses —
        composite MSE + ``loss.mask_weight`` x mask MSE on ``optim.rays_per_batch`` rays drawn from the held-out
        frames' pools as training draws from the training frames' (inside the dilated mask / inside the
        posed box), with generators seeded by ``(seed, k)`` for the fit's purpose — plus the prior
        ``held_out_rotation_weight * mean(r^2) + held_out_translation_weight * mean(t^2)``. No weight of the model
        changes (its parameters are frozen for the fit and their ``requires_grad`` restored after).

        Returns ``{"poses": (N, J, 4, 4) every frame (the held-out ones fitted, float32, on the device),
        "start": the same before the fit, "moved": how far the fit moved the held-out joints
        (``nsim.human.refine.pose_change``), "loss_first", "loss_last": the fit's loss at its first and last
        step, "seconds": its wall time}``.
        """
        r = self.cfg.refine
        if self.held_out_fit is not None or r.held_out_steps == 0 or len(self.eval_ids) == 0:
            return self.held_out_fit
        t0 = time.perf_counter()
        with torch.no_grad():
            start = self.poses().detach().clone()
        ids = torch.as_tensor(self.eval_ids, device=self.device)
        pools = self._pools(self.eval_ids, start[ids])
        fit = BodyPoseRefinement(start[ids], self.data.skeleton.parents, subtract_mean=False).to(self.device)
        opt = torch.optim.Adam(fit.parameters(), lr=r.held_out_lr)
        params = list(self.model.parameters())
        was = [p.requires_grad for p in params]
        for p in params:
            p.requires_grad_(False)
        losses = []
        try:
            for k in range(r.held_out_steps):
                for group in opt.param_groups:
                    group["lr"] = r.held_out_lr * 0.1 ** (k / r.held_out_steps)
                g = torch.Generator().manual_seed(_step_seed(self.seed, k, "held_out_fit"))
                frames, v, u = self._draw(g, pools, self.eval_ids)
                poses = start.index_put((ids,), fit())
                out = self.render_rays(frames, v, u, generator=g, poses=poses)
                loss = (self.image_loss(out, frames, v, u)[0]
                        + fit.regulariser(r.held_out_rotation_weight, r.held_out_translation_weight, 0.0))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                losses.append(float(loss.detach()))
        finally:
            for p, flag in zip(params, was, strict=True):
                p.requires_grad_(flag)
        with torch.no_grad():
            poses = start.index_put((ids,), fit())
        moved = pose_change(start[ids].double().cpu().numpy(), poses[ids].double().cpu().numpy())
        self.held_out_fit = {"poses": poses, "start": start, "moved": moved, "loss_first": losses[0],
                             "loss_last": losses[-1], "seconds": time.perf_counter() - t0}
        log.info("held-out pose fit: %d frames, %d steps, loss %.5f -> %.5f, joints moved %.2f cm on average, in %.1f s",
                 len(self.eval_ids), r.held_out_steps, losses[0], losses[-1], moved["joint_shift_cm_mean"],
                 self.held_out_fit["seconds"], extra={"held_out_fit_s": self.held_out_fit["seconds"]})
        return self.held_out_fit

    def history_row(self, stats: StepStats) -> dict[str, Any]:
        """The history's row at a logged step: loss, training PSNR and the step's extras."""
        return {"step": self.step, "loss": stats.loss, "psnr_train": stats.psnr, **stats.extra}

    # ------------------------------------------------------------------ evaluation
    @torch.no_grad()
    def render_view(self, i: int, poses: Tensor | None = None) -> dict[str, np.ndarray]:
        """Frame ``i`` rendered at its camera and pose over its background: rgb (H, W, 3), alpha (H, W).
        ``poses``: every frame's joint transforms ``(N, J, 4, 4)`` (default :meth:`poses`)."""
        self.model.eval()
        poses = self.poses() if poses is None else poses
        h, w = self.data.size_hw
        vv, uu = torch.meshgrid(torch.arange(h, device=self.device), torch.arange(w, device=self.device), indexing="ij")
        v, u = vv.reshape(-1), uu.reshape(-1)
        frames = torch.full_like(v, int(i))
        chunk = self.cfg.output.render_chunk_rays
        rgb, alpha = [], []
        for k in range(0, h * w, chunk):
            out = self.render_rays(frames[k:k + chunk], v[k:k + chunk], u[k:k + chunk], poses=poses)
            rgb.append(out.rgb)
            alpha.append(out.alpha[0])
        return {"rgb": torch.cat(rgb).clamp(0, 1).view(h, w, 3).cpu().numpy(),
                "alpha": torch.cat(alpha).view(h, w).cpu().numpy()}

    def mean_person_colour(self) -> np.ndarray:
        """Mean colour (3,) of the person's pixels over the training frames."""
        m = self.data.masks[self.train_ids]
        if not m.any():
            return np.full(3, 0.5)
        return self.data.images[self.train_ids][m].astype(np.float64).mean(0) / 255.0

    def evaluate(self, views: list[int] | None = None, keep_images: bool = False) -> dict[str, Any]:
        """PSNR in the person's box, mask IoU and the constant-colour baseline on held-out frames. With the
        held-out fit (``refine.held_out_steps > 0``, :meth:`fit_held_out`, run here if it has not been)
        ``psnr_box`` and ``mask_iou`` are the scores at the fitted poses and ``psnr_box_given_poses``,
        ``mask_iou_given_poses`` those at the poses as given (:meth:`poses`); the images kept are the former."""
        views = list(self.eval_ids) if views is None else list(views)
        mean_colour = self.mean_person_colour()
        fit = self.fit_held_out()
        rows, images = [], {}
        for i in views:
            pred = self.render_view(i, poses=None if fit is None else fit["poses"])
            gt = self.data.images[i].astype(np.float32) / 255.0
            mask = self.data.masks[i]
            box = mask_box(mask, self.cfg.output.box_margin_px)
            baseline = self.baseline_image(i, mean_colour)
            empty = self.baseline_image(i, None)
            row = {"frame": int(i), "name": self.data.names[i], "mask_iou": mask_iou(pred["alpha"] > 0.5, mask)}
            if box is not None:
                sl = (slice(box[0], box[1]), slice(box[2], box[3]))
                row["psnr_box"] = psnr(pred["rgb"][sl], gt[sl])
                row["psnr_box_baseline"] = psnr(baseline[sl], gt[sl])
                if self.data.background is not None:
                    # (without it the baseline's background is the frame itself: "nobody drawn" would score infinity,
                    # which JSON cannot hold)
                    row["psnr_box_background"] = psnr(empty[sl], gt[sl])
            if fit is not None:
                given = self.render_view(i)
                row["mask_iou_given_poses"] = mask_iou(given["alpha"] > 0.5, mask)
                if box is not None:
                    row["psnr_box_given_poses"] = psnr(given["rgb"][sl], gt[sl])
            rows.append(row)
            if keep_images:
                images[int(i)] = pred
        keys = [k for k in ("mask_iou", "psnr_box", "psnr_box_baseline", "psnr_box_background", "mask_iou_given_poses",
                            "psnr_box_given_poses") if any(k in r for r in rows)]
        summary = {k: float(np.mean([r[k] for r in rows if k in r])) for k in keys}
        return {"views": rows, "mean": summary, "images": images}

    def baseline_image(self, i: int, mean_colour: np.ndarray | None) -> np.ndarray:
        """The trivial prediction: the background, with the mask's box filled with ``mean_colour``
        (None: the background alone, as if no person were rendered)."""
        h, w = self.data.size_hw
        if self.bg_colour is not None:
            img = np.broadcast_to(self.data.background, (h, w, 3)).astype(np.float32).copy()
        elif self.data.background is not None:
            img = self.data.background[i].astype(np.float32) / 255.0
        else:
            img = self.data.images[i].astype(np.float32) / 255.0
        box = mask_box(self.data.masks[i], self.cfg.output.box_margin_px)
        if box is not None and mean_colour is not None:
            img = img.copy()
            img[box[0]:box[1], box[2]:box[3]] = mean_colour
        return img


def score_model(model: HumanModel, data: HumanTrainData, cfg: TrainHumanConfig, device: str = "cpu",
                views: list[int] | None = None, keep_images: bool = False) -> dict[str, Any]:
    """A trained ``model`` scored on frames of other ``data`` at their given poses, as :meth:`HumanTrainer.evaluate`
    scores held-out views (PSNR in the person's box, mask IoU, the baselines): every frame, or ``views``. E.g. another
    capture of the same walk filmed from a side the training never saw (``bench/human_sides.py``). ``cfg``: the
    training's (its output, data and thread settings; the model's own config replaces ``cfg.model``); no frame of
    ``data`` is trained on, so its mean-colour baseline is the mean person colour of ``data``'s own frames, and
    neither pose refinement nor the held-out fit runs."""
    every = dataclasses.replace(cfg.data, holdout_every=0, holdout_last_fraction=0.0)
    scoring = dataclasses.replace(cfg, model=model.cfg, data=every, refine=HumanRefineConfig())
    trainer = HumanTrainer(data, scoring, device)
    trainer.model.load_state_dict(model.state_dict())
    trainer.eval_ids = np.arange(data.n_frames)
    with loop.torch_threads(trainer.loop_threads()):
        return trainer.evaluate(views, keep_images)


# ====================================================================== metrics
def mask_iou(pred: np.ndarray, gt: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1 when both are empty)."""
    union = np.logical_or(pred, gt).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred, gt).sum() / union)


def mask_box(mask: np.ndarray, margin_px: int = 0) -> tuple[int, int, int, int] | None:
    """Bounding box ``(v0, v1, u0, u1)`` (end-exclusive) of a boolean mask grown by ``margin_px``, None if empty."""
    rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    if rows.size == 0:
        return None
    h, w = mask.shape
    return (max(0, rows[0] - margin_px), min(h, rows[-1] + 1 + margin_px),
            max(0, cols[0] - margin_px), min(w, cols[-1] + 1 + margin_px))


# ====================================================================== the loop
@dataclass
class HumanTrainResult(loop.TrainResult):
    """A human training (``nsim.train.loop.TrainResult``)."""


def train_human(
    data: HumanTrainData,
    cfg: TrainHumanConfig,
    work_dir: str | os.PathLike,
    device: str = "cpu",
    seed: int = 0,
    background_model=None,
    progress: bool = False,
    stop_after: int | None = None,
    on_log: Callable[[HumanTrainer, StepStats], None] | None = None,
) -> HumanTrainResult:
    """Train (or resume) a human model; checkpoints go to ``work_dir/last.pt``.

    ``background_model``: the trained scene (``SceneModel``) to composite over, or None (see
    the module docstring). A checkpoint of this run (same config, data, seed, device and
    background model) in ``work_dir`` is resumed; one is written every
    ``output.checkpoint_every`` steps and at the end. ``stop_after``: return after that many
    total steps without writing a checkpoint, as if killed (tests). The loop is ``nsim.train.loop.resume_and_train``.
    A finished training then fits the held-out frames' poses when ``refine.held_out_steps > 0``
    (:meth:`HumanTrainer.fit_held_out`; not checkpointed: a resumed run fits them again, to the same result).
    """
    o = cfg.output
    trainer, resumed = loop.resume_and_train(lambda: HumanTrainer(data, cfg, device, seed, background_model), work_dir,
                                             cfg.optim.steps, o.log_every, o.checkpoint_every, "training human",
                                             progress, stop_after, on_log, log)
    if cfg.refine.held_out_steps > 0 and trainer.step >= cfg.optim.steps:
        with loop.torch_threads(trainer.loop_threads()):
            trainer.fit_held_out()
    return HumanTrainResult(trainer, resumed)


def write_gif(path: str | os.PathLike, frames: list[np.ndarray], fps: float) -> Path:
    """An endlessly looping GIF of uint8 ``(H, W, 3)`` frames (Pillow), written atomically."""
    from PIL import Image

    path = Path(path)
    images = [Image.fromarray(np.ascontiguousarray(f)) for f in frames]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(round(1000.0 / fps)), loop=0, optimize=False)
    return path


def export_human(out_dir: str | os.PathLike, result: HumanTrainResult) -> dict[str, Any]:
    """Write the human-checkpoint files into ``out_dir``; returns the summary.

    Files: ``human.pt`` + ``human.json`` (weights; config, skeleton, canonical box — what
    ``nsim.human.nerf.load_human_model`` rebuilds the model from), ``turntable.png`` (the rest
    pose from ``output.preview_views`` directions), ``gait.gif`` (one walking cycle),
    ``history.json``, ``eval/<frame>.png`` (render | ground truth) and ``eval.json`` (per
    held-out view: PSNR in the person's box, mask IoU, the constant-colour baseline); with pose
    refinement (``refine.lr > 0``) or the held-out fit (``refine.held_out_steps > 0``) also
    ``poses_refined.json`` (every frame's pose, the ``poses.json`` format, file paths naming the frames:
    :meth:`HumanTrainer.refined_poses` — the trained frames refined, or as given when refinement is off; the
    held-out frames fitted to their own images with the held-out fit, else moved by their neighbours) and
    ``pose_refinement.json`` (how far those poses are from the given ones, trained and held-out frames apart,
    ``nsim.human.refine.pose_change``). With the held-out fit, eval.json scores the held-out views at the fitted
    poses (``psnr_box``, ``mask_iou``) and at the poses as given (``psnr_box_given_poses``,
    ``mask_iou_given_poses``), per view and on average, and ``held_out_fit.json`` says how far the fit moved the
    held-out poses from where it started (``moved``) and its loss at its first and last step. No file holds a
    timing, so a rerun on CPU writes the same bytes.
    """
    from nsim.human.nerf import gait_frames, save_human_model, turntable
    from nsim.io.images import to_uint8, write_image
    from nsim.io.labels import add_label

    trainer = result.trainer
    cfg = trainer.cfg
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model = trainer.model.eval()
    lo, hi = pose_aabb(trainer.data.skeleton, trainer.data.skeleton.rest_transforms(), model.padding_m)
    save_human_model(out_dir, model, extra={
        "frames_trained": [int(i) for i in trainer.train_ids],
        "frames_held_out": [int(i) for i in trainer.eval_ids],
        "steps": trainer.step,
        "config": to_dict(cfg),
    })
    o = cfg.output
    with loop.torch_threads(trainer.loop_threads()):  # the previews and scores at the training's thread count
        turntable_rgb = turntable(model, None, o.preview_views, o.preview_width, o.preview_height)
        gait = gait_frames(model, o.gait_frames, o.preview_width, o.preview_height)
        views = spread(list(trainer.eval_ids), o.eval_views)
        ev = trainer.evaluate(views, keep_images=True) if views else None
    write_image(out_dir / "turntable.png", turntable_rgb)
    write_gif(out_dir / "gait.gif", gait, o.gait_fps)
    (out_dir / "history.json").write_text(json.dumps(trainer.history, indent=1) + "\n")
    summary: dict[str, Any] = {"steps": trainer.step, "canonical_box_m": [lo.tolist(), hi.tolist()]}
    if ev is not None:
        (out_dir / "eval").mkdir(exist_ok=True)
        for i, pred in ev["images"].items():
            write_image(out_dir / "eval" / f"frame_{i:05d}.png",
                        add_label(np.concatenate([to_uint8(pred["rgb"]), trainer.data.images[i]], axis=1),
                                  [f"frame {i} render", "ground truth"]))
        (out_dir / "eval.json").write_text(json.dumps({"views": ev["views"], "mean": ev["mean"]}, indent=1) + "\n")
        summary.update({f"eval_{k}": round(v, 4) for k, v in ev["mean"].items()})
    fit = trainer.fit_held_out()
    if fit is not None:
        fitted = {"steps": cfg.refine.held_out_steps, "frames": [int(i) for i in trainer.eval_ids],
                  "moved": fit["moved"], "loss_first": fit["loss_first"], "loss_last": fit["loss_last"]}
        (out_dir / "held_out_fit.json").write_text(json.dumps(fitted, indent=1) + "\n")
        summary["held_out_fit"] = {m: round(x, 3) for m, x in fitted["moved"].items()}
    refined = trainer.refined_poses()
    if refined is not None:
        from nsim.human.data import POSES_REFINED_FILE, poses_from_joint_transforms, write_poses

        given = trainer.data.joint_transforms
        moved = {"trained": pose_change(given[trainer.train_ids], refined[trainer.train_ids])}
        if len(trainer.eval_ids):
            moved["held_out"] = pose_change(given[trainer.eval_ids], refined[trainer.eval_ids])
        names = tuple(trainer.data.names)
        skeleton = trainer.data.skeleton
        height = trainer.data.height_m if trainer.data.height_m is not None else skeleton.height_m()
        source = "nsim human NeRF pose refinement" if trainer.refine is not None else "nsim human NeRF (poses as given)"
        if fit is not None:
            source += ", held-out frames fitted to their own images"
        write_poses(out_dir / POSES_REFINED_FILE, poses_from_joint_transforms(
            skeleton, height, refined, file_paths=names, meta={"source": source, "moved": moved}))
        (out_dir / "pose_refinement.json").write_text(json.dumps(moved, indent=1) + "\n")
        summary["pose_refinement"] = {k: {m: round(x, 3) for m, x in v.items()} for k, v in moved.items()}
    result.evaluation = summary
    return summary


__all__ = [
    "HumanDataConfig",
    "HumanLossConfig",
    "HumanOptimConfig",
    "HumanOutputConfig",
    "HumanRefineConfig",
    "HumanTrainData",
    "HumanTrainResult",
    "HumanTrainer",
    "TrainHumanConfig",
    "export_human",
    "holdout_split",
    "mask_box",
    "mask_iou",
    "psnr",
    "score_model",
    "train_human",
    "write_gif",
]
