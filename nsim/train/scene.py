"""Training the scene NeRF: the trainer (``SceneTrainer``: batches, losses, schedules, checkpoints (save / resume),
evaluation) and its loop (``train_scene``). Its configuration: ``nsim.train.scene_config``; the artifact it ends
in: ``nsim.train.scene_export``.

Input: a directory holding ``transforms.json`` (frames with poses and intrinsics, nerfstudio
convention; a capture artifact or a poses artifact) and the images it names; optionally
each frame's ``depth_file_path`` (z-depth: scores held-out depth, and supervises training
depth when ``loss.image_depth_weight`` > 0), its ``mask_path`` (rays are drawn only from the
pixels a mask keeps), and a sparse point cloud ``sparse_points.ply`` (``points3D.ply`` also
accepted) for optional sparse depth supervision (``loss.depth_weight``).

Split: frame ``i`` is held out for evaluation when ``i % holdout_every == 0`` (every 8th).

Determinism and resume: every random draw of step ``k`` (the rays of the batch, the
samplers' jitter) comes from a generator seeded with ``(seed, k)``, learning rates are a
function of ``k``, and a checkpoint holds the step, the weights, the optimiser's moments and
the grad scaler. So a run killed at any point and resumed from its last checkpoint ends with
the same weights, bit for bit on CPU, as a run that was never interrupted.

Data (``nsim.train.scene_data``): uint8 images at the training resolution (``data.max_image_side``),
rays drawn per batch. Held-out scoring (``nsim.train.scene_eval``): chunked renders into compact
arrays at ``eval.image_side``, and for appearance-embedded models the left-half embedding fit.
Scale: for poses of arbitrary scale the trainer's metre lengths become scene units
(:func:`in_scene_units`, ``nsim.train.scene_data.units_per_metre``) and the artifact says
``"metric": false``.

Core API (what ``nsim/stages/train_scene.py`` calls)::

    data = SceneData.load(poses_dir, max_image_side=cfg.data.max_image_side)  # transforms.json + images
    result = train_scene(data, cfg, work_dir, device=ctx.device, seed=ctx.seed,
                         progress=ctx.show_progress)      # resumes from work_dir/last.pt
    summary = export_scene(out.dir, result)               # nsim.train.scene_export: the artifact's files

``work_dir`` must survive the process (so that a killed run can resume) and be unique to the
action key, e.g. ``store.root / "tmp" / f"train_scene.{key[:16]}.resume"``; the stage removes
it after publishing. Later stages load the artifact with ``nsim.rendering.load_model`` and
``OccupancyGrid.load`` and render through ``nsim.rendering.render_camera`` / ``render_lidar``.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nsim.config import config_digest
from nsim.errors import InputError
from nsim.geometry.cameras import dirs_to_world
from nsim.rendering.model import SceneModel
from nsim.train import loop
from nsim.train.loop import ResumableTrainer, StepStats, spread, step_seed
from nsim.train.scene_config import TrainSceneConfig, in_scene_units
from nsim.train.scene_data import (
    POINT_FILES,
    SceneData,
    camera_to_point_median,
    scene_bounds,
    units_per_metre,
)
from nsim.train.scene_eval import (
    ViewRays,
    render_image,
    score_views,
)
from nsim.volume import quadrature
from nsim.volume.rays import PoseRefinement, Rays, camera_dirs, make_rays

log = logging.getLogger(__name__)

DIRS_TABLE_MAX_BYTES = 256 << 20  # per-camera pixel-direction tables above this: directions per batch instead


#: ``field.hash_max_resolution: 0`` (from the data) stays within these: the presets' 2048 at least (a small
#: capture keeps what it always had), and a bound on how fine a 2**19-row table can usefully be.
AUTO_HASH_RESOLUTION = (2048, 16384)


def finest_hash_resolution(data: SceneData, aabb, contract: bool,
                           bounds: tuple[int, int] = AUTO_HASH_RESOLUTION) -> tuple[int, str]:
    """The hash grid's finest resolution for ``data`` (its cameras at the training size) in the scene box
    ``aabb (2, 3)``: the one whose finest cell spans one training pixel's footprint at the capture's typical
    distance, rounded up to a multiple of 64 and kept within ``bounds``; with why, for the log.

    The typical distance is the median camera-to-sparse-point distance (the depth at which the capture saw
    things), else the median camera-to-box-centre distance. The footprint is that distance over the
    training cameras' median focal length (px). With ``contract`` the box fills half the grid's side
    (``nsim.fields.contraction``), else all of it. A 1080p phone capture of a room gets a grid some
    four times finer than a 320 px one: the 2048 of the presets blurs what its pixels resolve.
    """
    aabb = np.asarray(torch.as_tensor(aabb).cpu(), dtype=np.float64)
    centres = np.asarray(data.cam_to_world, np.float64)[:, :3, 3]
    if data.points_xyz is not None and len(data.points_xyz) >= 8:
        distance, source = camera_to_point_median(centres, data.points_xyz), "median camera-to-sparse-point distance"
    else:
        mid = aabb.mean(axis=0)
        distance, source = float(np.median(np.linalg.norm(centres - mid, axis=-1))), "median camera-to-box-centre distance"
    focal = float(np.median([max(c.fx, c.fy) for c in data.cameras]))
    extent = float((aabb[1] - aabb[0]).max())
    lo, hi = bounds
    if not (distance > 0 and math.isfinite(distance) and focal > 0):
        return lo, f"no typical distance to size it by ({source} {distance:.4g}): {lo}"
    footprint = distance / focal
    need = extent / ((0.5 if contract else 1.0) * footprint)
    res = int(min(max(math.ceil(need / 64.0) * 64, lo), hi))
    return res, (f"{res}: one training pixel ({focal:.0f} px focal) at the {source} {distance:.4g} spans "
                 f"{footprint:.4g} units, the box's longest side {extent:.4g} units needs {need:.0f} cells "
                 f"(kept within {lo}..{hi})")


def z_depth_to_range(depth_z: Tensor, dirs_cam_z: Tensor) -> Tensor:
    """Range along the unit ray ``z / d_z`` from z-depth ``(R,)`` and the ray's camera-axes direction's
    z ``(R,)`` (``nsim.volume.rays.camera_dirs``); 0 where there is no depth (``z <= 0``) or the ray
    does not look forward (``d_z <= 1e-6``). The torch twin of ``nsim.sensors.depth_model.z_depth_to_range``."""
    ok = (depth_z > 0) & (dirs_cam_z > 1e-6)
    return torch.where(ok, depth_z / torch.where(ok, dirs_cam_z, 1.0), 0.0)


def image_depth_loss(pred_range: Tensor, target_range: Tensor, n_rays: int) -> Tensor:
    """``sum |pred - target| / target`` over the rays with a target (``target > 0``), divided by ``n_rays``
    (the batch's rays with a target; a part of a batch passes the whole batch's count).

    pred_range: ``(R,)`` the rendered expected range (``RenderOutput.depth``, normalised ``sum w t /
    sum w``); target_range: ``(R,)`` from the depth image (:func:`z_depth_to_range`), 0 for none.
    The expected-depth term of Urban Radiance Fields (Rematas et al., CVPR 2022, sec. 3.2; nerfstudio's
    ``urban_radiance_field_depth_loss``, a depth-nerfacto option), a squared error there, taken here as
    an L1 relative to the target, the form of ``loss.depth_weight``'s sparse-point term and of the
    AbsRel that depth is scored by: a metre off at 10 m weighs what 10 cm off at 1 m does, and the
    weight needs no change between metric and arbitrary-scale scenes. Its gradient is
    ``sign(pred - target) / target / n_rays``.
    """
    has = target_range > 0
    rel = torch.abs(pred_range - target_range) / torch.where(has, target_range, 1.0)
    return torch.where(has, rel, 0.0).sum() / max(1, n_rays)


def _step_seed(seed: int, step: int, purpose: str = "batch") -> int:
    """The scene trainer's seeds (``nsim.train.loop.step_seed`` in its namespace)."""
    return step_seed("nsim.train.scene", seed, step, purpose)


# ====================================================================== the trainer
def _sum_in_order(tensors: list[Tensor]) -> Tensor:
    """``((t0 + t1) + t2) + ...`` into a fresh tensor (the first is not modified)."""
    if len(tensors) == 1:
        return tensors[0]
    out = tensors[0] + tensors[1]  # one pass over memory, not a copy and then an add
    for t in tensors[2:]:
        out += t
    return out


class SceneTrainer(ResumableTrainer):
    """One training run's state: model, optimiser, step; ``train_step`` advances it by one.

    Everything random in step ``k`` is drawn from generators seeded with ``(seed, k)``.

    ``data`` is brought to ``cfg.data.max_image_side`` (read again from its files when it is not
    already there). ``cfg`` is kept as given in ``given_cfg``; ``self.cfg`` is it in scene units
    (:func:`in_scene_units`, ``units_per_m``: 1 for metric poses).
    """

    def __init__(self, data: SceneData, cfg: TrainSceneConfig, device: str = "cpu", seed: int = 0) -> None:
        data = data.with_max_image_side(cfg.data.max_image_side)
        self.given_cfg = cfg
        self.units_per_m, self.units_from = units_per_metre(data)
        cfg = in_scene_units(cfg, self.units_per_m)
        self.data, self.cfg, self.device, self.seed = data, cfg, torch.device(device), int(seed)
        if self.device.type == "cpu":
            from nsim.train.heap import keep_large_blocks_on_heap

            keep_large_blocks_on_heap()  # table-sized gradient buffers every step: no page faults (nsim/train/heap.py)
        self.train_ids, self.eval_ids = data.split(cfg.data.holdout_every)
        self.aabb = torch.as_tensor(scene_bounds(data, cfg.data))
        if cfg.field.hash_max_resolution == 0:
            res, why = finest_hash_resolution(data, self.aabb, cfg.field.contract)
            log.info("field.hash_max_resolution from the data: %s", why)
            cfg = self.cfg = replace(cfg, field=replace(cfg.field, hash_max_resolution=res))
        init = torch.Generator().manual_seed(_step_seed(seed, 0, "init"))
        from nsim.fields.hash_encoding import HashEncoding

        self.backend = HashEncoding.resolve_backend(cfg.field.backend, self.device)
        self.model = SceneModel(cfg.field, cfg.sampler, self.aabb, data.n_frames, backend=self.backend,
                                generator=init).to(self.device)
        mask = torch.zeros(data.n_frames, dtype=torch.bool)
        mask[torch.as_tensor(self.train_ids)] = True
        self.model.train_mask.copy_(mask)
        self.pose_refine = PoseRefinement(data.n_frames).to(self.device) if cfg.optim.pose_refinement else None
        # data on the device: uint8 images, per-camera pixel directions, poses
        self.images = torch.as_tensor(data.images).to(self.device)
        # pixel directions: a (C, H, W, 3) table when the distinct cameras are few, else unprojected per batch
        h, w = data.size_hw
        self.dirs_cam = None
        if len(data.cameras) * h * w * 12 <= DIRS_TABLE_MAX_BYTES:
            self.dirs_cam = torch.stack([camera_dirs(c) for c in data.cameras]).to(self.device)
        self.camera_index = torch.as_tensor(data.camera_index, dtype=torch.long, device=self.device)
        self.cam_to_world = torch.as_tensor(data.cam_to_world, dtype=torch.float32, device=self.device)
        self.train_index = torch.as_tensor(self.train_ids, dtype=torch.long, device=self.device)
        self.depth_points = self._project_points() if cfg.loss.depth_weight > 0 else None
        # masks: one bool a pixel; kept_in_row (T * H,) kept pixels per (training image, row), kept_rows its running sum
        self.masks = self.kept_in_row = self.kept_rows = None
        if data.masks is not None:
            self.masks = torch.as_tensor(data.masks).to(self.device)
            self.kept_in_row = self.masks.sum(-1, dtype=torch.int64)[self.train_index].reshape(-1)
            if int(self.kept_in_row.sum()) == 0:
                raise InputError(f"{data.root}: the masks (mask_path) keep no pixel of any training image")
            self.kept_rows = torch.cumsum(self.kept_in_row, 0)
        # depth images at the training resolution, (N, H, W) float16 z-depth, 0: none
        self.depth_z, self.depth_digest = None, None
        if cfg.loss.image_depth_weight > 0:
            depth_z = data.train_depth_z(self.train_ids)
            if depth_z is None:
                raise InputError(f"{data.root}: loss.image_depth_weight > 0 but no training frame has a depth "
                                 "image (depth_file_path)")
            self.depth_digest = hashlib.sha256(depth_z.tobytes()).hexdigest()
            self.depth_z = torch.as_tensor(depth_z).to(self.device)
        groups = [{"params": list(self.model.field.parameters()), "lr": cfg.optim.lr_field, "name": "field"}]
        if len(self.model.proposals):
            groups.append({"params": list(self.model.proposals.parameters()), "lr": cfg.optim.lr_proposal,
                           "name": "proposal"})
        if self.pose_refine is not None:
            groups.append({"params": list(self.pose_refine.parameters()), "lr": cfg.optim.lr_pose, "name": "pose"})
        self.base_lr = [g["lr"] for g in groups]
        # fused: one kernel over all tensors (4x faster than the default loop on CPU), deterministic
        self.optimizer = torch.optim.Adam(groups, eps=cfg.optim.adam_eps, betas=(0.9, cfg.optim.adam_beta2),
                                          fused=self.device.type in ("cpu", "cuda"))
        self.amp = bool(cfg.optim.mixed_precision and self.device.type == "cuda")
        self.scaler = torch.amp.GradScaler("cuda", enabled=self.amp)
        self.step = 0
        self.train_seconds = 0.0
        self.history: list[dict[str, float]] = []
        self._pool = None  # threads for optim.batch_threads > 1, made on first use
        self._parts_warm = False

    # ------------------------------------------------------------------ schedules
    def anneal(self, step: int) -> float:
        n = self.cfg.optim.proposal_anneal_steps
        if n <= 0:
            return 1.0
        x = min(1.0, step / n)
        bias = 10.0  # mip-NeRF 360 / nerfstudio's annealing curve, from 0.5 ... 1
        return 0.5 + 0.5 * (bias * x / ((bias - 1.0) * x + 1.0))

    def proposal_update(self, step: int) -> bool:
        """Whether step ``step`` trains the proposal fields (nerfstudio's schedule: every step at
        first, then every ``proposal_update_every`` steps by the end of the warm-up)."""
        o = self.cfg.optim
        every = o.proposal_update_every
        if o.proposal_warmup_steps > 0:
            every = int(np.clip(np.interp(step, [0, o.proposal_warmup_steps], [0, every]), 1, every))
        return step % every == 0

    # ------------------------------------------------------------------ batches
    def _project_points(self) -> Tensor | None:
        """For each training image, the sparse points in front of it: rows (image, u, v, range_m)."""
        pts = self.data.points_xyz
        if pts is None or len(pts) == 0:
            raise InputError(f"{self.data.root}: loss.depth_weight > 0 needs a sparse point cloud ({', '.join(POINT_FILES)})")
        rows = []
        for i in self.train_ids:
            c2w = self.data.cam_to_world[i]
            cam = self.data.cameras[self.data.camera_index[i]]
            p_cam = (pts - c2w[:3, 3]) @ c2w[:3, :3]
            uv, valid = cam.project(p_cam)
            rng = np.linalg.norm(p_cam, axis=-1)
            valid &= rng > self.cfg.sampler.near_m
            if valid.any():
                rows.append(np.column_stack([np.full(valid.sum(), i), uv[valid], rng[valid]]))
        if not rows:
            raise InputError(f"{self.data.root}: no sparse point projects into any training image")
        return torch.as_tensor(np.concatenate(rows), dtype=torch.float32)

    def batch(self, step: int) -> tuple[Rays, Tensor, torch.Generator]:
        """The rays and target colours of ``step``: a pure function of ``(seed, step)``."""
        rays, target, _, g = self.batch_with_depth(step)
        return rays, target, g

    def batch_with_depth(self, step: int) -> tuple[Rays, Tensor, Tensor | None, torch.Generator]:
        """``batch(step)`` and each ray's target range ``(R,)`` along its unit direction (0: no depth;
        None unless ``loss.image_depth_weight`` > 0)."""
        img, v, u, g = self.pixels(step)
        target = self.images[img, v, u].float() / 255.0
        dirs_cam = self._pixel_dirs(img, v, u)
        rays = self._rays(dirs_cam, img)
        share = self.cfg.optim.appearance_mean_share
        if share > 0.0:  # appearance dropout: these rays draw with the mean code (image_index -1)
            ga = torch.Generator().manual_seed(_step_seed(self.seed, step, "appearance"))
            dropped = (torch.rand(len(img), generator=ga) < share).to(img.device)
            rays = replace(rays, image_index=torch.where(dropped, -1, rays.image_index))
        depth = None
        if self.depth_z is not None:
            depth = z_depth_to_range(self.depth_z[img, v, u].float(), dirs_cam[:, 2])
            depth = torch.where((depth > rays.near) & (depth < rays.far), depth, 0.0)  # what the ray can render
        return rays, target, depth, g

    def pixels(self, step: int) -> tuple[Tensor, Tensor, Tensor, torch.Generator]:
        """The training pixels of ``step``: image (frame index), row, column ``(R,)`` each, and the step's
        generator; uniform over the training images' pixels, or over the pixels their masks keep."""
        g = torch.Generator().manual_seed(_step_seed(self.seed, step))
        b = self.cfg.optim.rays_per_batch
        h, w = self.data.size_hw
        if self.kept_rows is None:
            pick = torch.randint(0, len(self.train_ids), (b,), generator=g).to(self.device)
            pix = torch.randint(0, h * w, (b,), generator=g).to(self.device)
            return self.train_index[pick], pix // w, pix % w, g
        # the r-th kept pixel: its (image, row) from the running row counts, then its column in that row
        r = torch.randint(0, int(self.kept_rows[-1]), (b,), generator=g).to(self.device)
        row = torch.searchsorted(self.kept_rows, r, right=True)
        k = r - (self.kept_rows[row] - self.kept_in_row[row])  # the k-th kept pixel of its row
        img, v = self.train_index[row // h], row % h
        running = torch.cumsum(self.masks[img, v], -1, dtype=torch.int32)  # (R, W)
        u = torch.searchsorted(running, (k + 1).to(torch.int32)[:, None])[:, 0]
        return img, v, u, g

    def _pixel_dirs(self, img: Tensor, v: Tensor, u: Tensor) -> Tensor:
        """Camera-axes unit directions ``(R, 3)`` through pixels ``(v, u)`` of images ``img`` (as ``camera_dirs``)."""
        cam_idx = self.camera_index[img]
        if self.dirs_cam is not None:
            return self.dirs_cam[cam_idx, v, u]
        out = torch.empty((len(img), 3), dtype=torch.float32)
        uv = torch.stack([u, v], -1).cpu().double().numpy()
        idx = cam_idx.cpu()
        for c in torch.unique(idx).tolist():  # the same float64 arithmetic as the table, pixel by pixel
            rows = torch.nonzero(idx == c, as_tuple=True)[0]
            d = self.data.cameras[c].dirs_through(uv[rows.numpy()], fill_invalid=True)
            out[rows] = torch.as_tensor(np.asarray(d), dtype=torch.float32)
        return out.to(self.device)

    def _rays(self, dirs_cam: Tensor, img: Tensor) -> Rays:
        c2w = self.cam_to_world[img]
        if self.pose_refine is not None:
            c2w = self.pose_refine(c2w, img)
        origins, dirs = dirs_to_world(dirs_cam, c2w)
        s = self.cfg.sampler
        return make_rays(origins, dirs, s.near_m, s.far_m, self.aabb.to(self.device) if s.clip_rays_to_box else None,
                         image_index=img)

    def depth_batch(self, step: int) -> tuple[Rays, Tensor]:
        g = torch.Generator().manual_seed(_step_seed(self.seed, step, "depth"))
        rows = self.depth_points[torch.randint(0, len(self.depth_points), (self.cfg.loss.depth_rays_per_batch,), generator=g)]
        img = rows[:, 0].long()
        dirs = []
        for k, i in enumerate(img.tolist()):
            cam = self.data.cameras[self.data.camera_index[i]]
            dirs.append(np.asarray(cam.unproject(rows[k, 1:3].double().numpy()), dtype=np.float32))
        dirs_cam = torch.as_tensor(np.stack(dirs)).to(self.device)
        return self._rays(dirs_cam, img.to(self.device)), rows[:, 3].to(self.device)

    # ------------------------------------------------------------------ one step
    def train_step(self) -> StepStats:
        t0 = self._begin_step()
        step = self.step
        cfg = self.cfg
        extra = {}
        grid = cfg.sampler.kind == "grid"
        if grid and step > 0 and step % cfg.sampler.grid_update_every == 0:
            g_grid = torch.Generator().manual_seed(_step_seed(self.seed, step, "grid"))
            with torch.autocast(self.device.type, dtype=torch.float16, enabled=self.amp):
                extra["grid_occupied"] = self.model.update_grid(g_grid, all_cells=step < cfg.sampler.grid_warmup_steps)
        rays, target, depth, g = self.batch_with_depth(step)
        depth_rays = 0 if depth is None else int((depth > 0).sum())
        anneal = self.anneal(step)
        update_proposals = self.proposal_update(step) and not grid
        self.optimizer.zero_grad(set_to_none=True)
        parts = self._parts(len(rays))
        if len(parts) == 1:
            loss, mse = self._part_loss(step, rays, target, g, anneal, update_proposals, grid, True, 1.0, extra,
                                        depth, depth_rays)
            self.scaler.scale(loss).backward()
        else:
            params = [q for grp in self.optimizer.param_groups for q in grp["params"] if q.requires_grad]

            def part(k: int, sl: slice):
                g_k = torch.Generator().manual_seed(_step_seed(self.seed, step, f"part{k}"))
                ex: dict = {}
                ls, ms = self._part_loss(step, rays[sl], target[sl], g_k, anneal, update_proposals, grid, k == 0,
                                         (sl.stop - sl.start) / len(rays), ex,
                                         None if depth is None else depth[sl], depth_rays)
                # with pose refinement the parts' rays share the pose nodes: keep them for the other parts
                grads = torch.autograd.grad(self.scaler.scale(ls), params, allow_unused=True,
                                            retain_graph=self.pose_refine is not None)
                return ls.detach(), ms.detach(), ex, grads

            # the parts run on the worker threads (num_threads torch threads each, set once when the pool
            # starts), never on this one: this thread's count is the loop's (loop_threads), set once
            if self._parts_warm:
                results = [f.result() for f in [self._pool.submit(part, k, sl) for k, sl in enumerate(parts)]]
            else:  # this trainer's first split step runs its parts in turn: compiled kernels get built once
                results = [self._pool.submit(part, k, sl).result() for k, sl in enumerate(parts)]
                self._parts_warm = True
            # the parts' gradients summed in part order, whatever order the threads finished in: deterministic.
            # The sum and the optimiser step are element-wise: they run here, on all the parts' cores when the
            # loop holds loop_threads() (a thread count fixed by the config, so reruns repeat bit for bit); at
            # 2^19-row tables they took over a quarter of a step.
            for i, q in enumerate(params):
                gs = [r[3][i] for r in results if r[3][i] is not None]
                q.grad = _sum_in_order(gs) if gs else None
            loss = sum(r[0] for r in results)
            mse = sum(r[1] for r in results)
            for key in results[0][2]:
                extra[key] = sum(r[2].get(key, 0.0) for r in results)
        self.scaler.step(self.optimizer)
        self.scaler.update()
        return self._finish_step(t0, loss, mse, extra)

    def loop_threads(self) -> int:
        """torch's intra-op threads on the training loop's thread (``nsim.train.loop.train_loop`` sets them
        once and restores them after; the post-training bakes and scoring of ``scene_export.export_scene`` use the
        same): on a CPU ``optim.num_threads x optim.batch_threads``, the cores a step uses. A split batch's
        parts run on the worker threads at ``num_threads`` each (set when the pool starts); this thread
        builds the batch (indexing and element-wise work, whatever its thread count), sums the parts'
        gradients and steps Adam on all those cores. Fixed by the config, so reruns repeat bit for bit.
        0 (torch's count left alone) on a GPU or with ``num_threads`` 0. On one thread the fox capture's
        walkable map took 57 s instead of 31 (2 cores)."""
        o = self.cfg.optim
        if self.device.type != "cpu" or o.num_threads <= 0:
            return 0
        return o.num_threads * max(1, o.batch_threads)

    def _parts(self, n: int) -> list[slice]:
        """The batch's parts for ``optim.batch_threads`` (CPU only; one part otherwise)."""
        k = self.cfg.optim.batch_threads if self.device.type == "cpu" else 1
        k = max(1, min(k, n))
        if k > 1:
            self._thread_pool()
        edges = [round(i * n / k) for i in range(k + 1)]
        return [slice(edges[i], edges[i + 1]) for i in range(k)]

    def _thread_pool(self):
        """The ``optim.batch_threads`` worker threads (CPU, more than one; else None), made on first use:
        the parts of a training batch, and the chunks of an evaluation render, run there."""
        k = self.cfg.optim.batch_threads if self.device.type == "cpu" else 1
        if k > 1 and self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            threads = self.cfg.optim.num_threads
            self._pool = ThreadPoolExecutor(k, thread_name_prefix="nsim-part",
                                            initializer=(lambda: torch.set_num_threads(threads)) if threads > 0 else None)
        return self._pool

    def _part_loss(self, step: int, rays: Rays, target: Tensor, g: torch.Generator, anneal: float,
                   update_proposals: bool, grid: bool, first: bool, share: float, extra: dict,
                   depth: Tensor | None = None, depth_rays: int = 0) -> tuple[Tensor, Tensor]:
        """Loss and colour MSE of one part, both scaled by ``share`` (the part's fraction of the batch),
        so that the parts' values add up to the whole batch's. ``depth``: the part's target ranges
        (0: none) and ``depth_rays`` the whole batch's rays with depth, for the depth-image term
        (a sum over the part's rays / depth_rays: the parts' terms add up to the batch's mean)."""
        cfg = self.cfg
        with torch.autocast(self.device.type, dtype=torch.float16, enabled=self.amp):
            out = self.model.render(rays, generator=g, anneal=anneal, proposal_grad=update_proposals,
                                    return_samples=grid and cfg.loss.distortion_weight > 0)
            rgb = out.rgb.float()
            if cfg.loss.random_background and step >= cfg.loss.random_background_start * cfg.optim.steps:
                # the same volume rendering over a random colour per ray: (1 - acc) * bg replaces (1 - acc) * background
                bg = torch.rand((len(rays), 3), generator=g).to(self.device)
                rgb = rgb + (1.0 - out.accumulation.float())[:, None] * (bg - out.background.float())
            mse = torch.mean((rgb - target) ** 2)
            loss = mse
            if cfg.loss.opacity_weight > 0 and step >= cfg.loss.opacity_start * cfg.optim.steps:
                entropy = quadrature.opacity_loss(out.accumulation)
                loss = loss + cfg.loss.opacity_weight * entropy
                extra["opacity"] = share * float(entropy.detach())
            if cfg.loss.interlevel_weight > 0 and update_proposals:
                inter = quadrature.interlevel_loss(out.weights, out.bins, out.proposal_weights, out.proposal_bins)
                loss = loss + cfg.loss.interlevel_weight * inter
                extra["interlevel"] = share * float(inter.detach())
            if cfg.loss.distortion_weight > 0 and out.bins is not None:
                dist = quadrature.distortion_loss(out.weights, out.bins)
                loss = loss + cfg.loss.distortion_weight * dist
                extra["distortion"] = share * float(dist.detach())
            elif cfg.loss.distortion_weight > 0 and out.samples is not None:
                # marching intervals, in the fraction of each ray's [near, far] (as the proposal bins are)
                span = (rays.far - rays.near).clamp(min=1e-6)[:, None]
                s0 = (out.samples.t_starts - rays.near[:, None]) / span
                s1 = (out.samples.t_ends - rays.near[:, None]) / span
                dist = quadrature.distortion_loss_intervals(out.weights, s0, s1)
                loss = loss + cfg.loss.distortion_weight * dist
                extra["distortion"] = share * float(dist.detach())
            if cfg.loss.free_space_weight > 0 and not grid and step >= cfg.loss.free_space_start * cfg.optim.steps:
                free = self.free_space_loss(rays, out, g)
                loss = loss + cfg.loss.free_space_weight * free
                extra["free_space"] = share * float(free.detach())
            loss = loss * share if share != 1.0 else loss
            if depth is not None and depth_rays > 0:
                d_img = image_depth_loss(out.depth.float(), depth, depth_rays)
                loss = loss + cfg.loss.image_depth_weight * d_img
                extra["image_depth"] = float(d_img.detach())
            if first and self.depth_points is not None:  # the sparse-point depth term: whole, in the first part
                d_rays, d_target = self.depth_batch(step)
                g_d = torch.Generator().manual_seed(_step_seed(self.seed, step, "depth-jitter"))
                d_out = self.model.render(d_rays, generator=g_d, anneal=anneal, proposal_grad=False)
                d_loss = torch.mean(torch.abs(d_out.depth - d_target) / d_target)
                loss = loss + cfg.loss.depth_weight * d_loss
                extra["depth"] = float(d_loss.detach())
        return loss, mse * share if share != 1.0 else mse

    def _first_weighted_t(self, rays: Rays, bins: Tensor, weights: Tensor) -> Tensor:
        """Start (metres) of the first bin where the ray's cumulative weight reaches 1e-3: ``(R,)``."""
        from nsim.rendering.samplers import spacing_to_t

        s = self.cfg.sampler
        t = spacing_to_t(bins.detach(), rays.near, rays.far, s.spacing, s.lindisp_break_m)
        cum = torch.cumsum(weights.detach(), dim=-1)
        first = (cum < 1e-3).sum(-1, keepdim=True).clamp(max=cum.shape[-1] - 1)
        return torch.gather(t[:, :-1], -1, first)[:, 0]

    def free_space_loss(self, rays: Rays, out, generator: torch.Generator) -> Tensor:
        """Mean scene-field density at random points in front of each ray's first weighted bin
        (of the last proposal stage or of the final samples, whichever comes first)."""
        lc = self.cfg.loss
        t_free = torch.minimum(self._first_weighted_t(rays, out.proposal_bins[-1], out.proposal_weights[-1]),
                               self._first_weighted_t(rays, out.bins, out.weights)) - lc.free_space_margin_m
        span = (t_free - rays.near).clamp(min=0.0)
        n = len(rays)
        u = torch.rand((n, lc.free_space_samples), generator=generator).to(span.device)
        ts = rays.near[:, None] + u * span[:, None]
        x = rays.origins[:, None, :] + rays.dirs[:, None, :] * ts[..., None]
        sigma, _ = self.model.field.density(x.reshape(-1, 3))
        valid = (span > 1e-3).float()[:, None].expand(-1, lc.free_space_samples)
        return (sigma.view(n, -1) * valid).sum() / valid.sum().clamp(min=1.0)

    # ------------------------------------------------------------------ checkpoints
    def meta(self) -> dict[str, Any]:
        meta = {"config": config_digest(self.cfg), "data": self.data.digest, "seed": self.seed,
                "backend": self.backend, "device": self.device.type}
        if self.depth_digest is not None:  # the depth images train only with loss.image_depth_weight > 0
            meta["image_depth"] = self.depth_digest
        return meta

    def _extra_state(self) -> dict[str, Any]:
        return {
            "pose_refine": None if self.pose_refine is None else self.pose_refine.state_dict(),
            "scaler": self.scaler.state_dict(),
            # all randomness is a function of (seed, step); the global generators are kept for completeness
            "torch_rng": torch.get_rng_state(),
        }

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        if self.pose_refine is not None:
            self.pose_refine.load_state_dict(state["pose_refine"])
        self.scaler.load_state_dict(state["scaler"])
        torch.set_rng_state(state["torch_rng"])

    def history_row(self, stats: StepStats) -> dict[str, Any]:
        """The history's row at a logged step: loss, training PSNR, the step's extras, and the held-out
        scores of ``output.eval_views`` views when an evaluation is due (``output.eval_every``)."""
        out = self.cfg.output
        row = {"step": self.step, "train_seconds": self.train_seconds, "loss": stats.loss, "psnr_train": stats.psnr,
               **stats.extra}
        if out.eval_every and (self.step % out.eval_every == 0 or self.step == self.cfg.optim.steps):
            views = spread(list(self.eval_ids), out.eval_views)
            if views:
                row.update({f"eval_{k}": v for k, v in self.evaluate(views)["mean"].items()})
        return row

    # ------------------------------------------------------------------ rendering and evaluation
    def density_fn(self) -> Callable[[Tensor], Tensor]:
        """The scene field's density ``x (N, 3) -> sigma (N,)`` (eval mode, no gradients) for baking grids.
        On a CPU with ``optim.batch_threads`` > 1 each call's points are split in that many fixed parts
        evaluated on the worker threads at once (the first call runs whole, so that anything compiled
        on first use is built once); the parts depend only on N, so a rerun bakes the same grid."""
        model = self.model.eval()
        pool = self._thread_pool()

        def whole(x: Tensor) -> Tensor:
            with torch.no_grad():  # per thread
                return model.field.density(x)[0]

        if pool is None:
            return whole
        k = self.cfg.optim.batch_threads
        warm = [False]

        def split(x: Tensor) -> Tensor:
            if not warm[0] or len(x) < 2 * k:
                warm[0] = True
                return whole(x)
            edges = [round(i * len(x) / k) for i in range(k + 1)]
            parts = [pool.submit(whole, x[edges[i]:edges[i + 1]]) for i in range(k)]
            return torch.cat([p.result() for p in parts])

        return split

    def view_rays(self, i: int, camera) -> ViewRays:
        """What renders frame ``i`` (its recorded pose) through ``camera`` (any size)."""
        s = self.cfg.sampler
        return ViewRays(camera, self.cam_to_world[i].cpu(), s.near_m, s.far_m,
                        self.aabb.to(self.device) if s.clip_rays_to_box else None)

    @torch.no_grad()
    def render_view(self, i: int, chunk: int | None = None, image_side: int | None = None) -> dict[str, np.ndarray]:
        """Render frame ``i`` (its recorded pose, mean appearance) at ``image_side`` (default ``eval.image_side``):
        rgb (H, W, 3), depth_z and depth_median_z (H, W) z-depth in scene units, accumulation (H, W); float32."""
        side = self.cfg.eval.image_side if image_side is None else image_side
        view = self.view_rays(i, self.data.eval_camera(i, side))
        return render_image(self.model, view, chunk or self.cfg.output.render_chunk_rays, pool=self._thread_pool())

    def evaluate(self, views: list[int] | None = None, final: bool = False, image_dir: Path | None = None) -> dict[str, Any]:
        """Scores of held-out frames (all, or ``views``) at ``eval.image_side``: PSNR / SSIM / depth
        AbsRel with the mean appearance embedding; ``final`` adds LPIPS and the left-half fit's
        ``*_half`` scores (``nsim.train.scene_eval``). ``image_dir``: each render beside its ground
        truth is written there (``frame_NNNNN.png``) as it is scored, so no image is kept.
        Returns ``views`` (one row each), ``mean``, ``resolution`` and ``protocol``."""
        views = list(self.eval_ids) if views is None else views
        out = score_views(self.model, self.data, views, self.cfg.eval, self.cfg.output.render_chunk_rays,
                          lambda i: torch.Generator().manual_seed(_step_seed(self.seed, i, "eval-fit")), final,
                          self._thread_pool(), image_dir)
        h, w = self.data.size_hw
        res = out["resolution"]
        out["resolution"] = {"scored_wh": res["scored_wh"], "trained_wh": [w, h], "captured_wh": res["captured_wh"],
                             "eval.image_side": res["eval.image_side"],
                             "data.max_image_side": self.cfg.data.max_image_side}
        return out


# ====================================================================== the loop
@dataclass
class TrainResult(loop.TrainResult):
    """A scene training (``nsim.train.loop.TrainResult``) and the post-training phases' seconds."""

    post_train_seconds: dict[str, float] = field(default_factory=dict)  # export_scene's phases (not in any file)


def train_scene(
    data: SceneData,
    cfg: TrainSceneConfig,
    work_dir: str | os.PathLike,
    device: str = "cpu",
    seed: int = 0,
    progress: bool = False,
    stop_after: int | None = None,
    on_log: Callable[[SceneTrainer, StepStats], None] | None = None,
) -> TrainResult:
    """Train (or resume) a scene model; checkpoints go to ``work_dir/last.pt``.

    If ``work_dir/last.pt`` exists and belongs to this run (same config, data, seed, backend and
    device), training continues from it; a checkpoint is written every ``output.checkpoint_every``
    steps and at the end. ``stop_after``: return after that many total steps *without* writing a
    checkpoint, as if the process had been killed then (tests). ``on_log`` is called every
    ``output.log_every`` steps (after evaluation, if one is due). The loop is ``nsim.train.loop.resume_and_train``.
    """
    o = cfg.output
    trainer, resumed = loop.resume_and_train(lambda: SceneTrainer(data, cfg, device, seed), work_dir, cfg.optim.steps,
                                             o.log_every, o.checkpoint_every, "training scene", progress, stop_after,
                                             on_log, log)
    return TrainResult(trainer, resumed)


__all__ = ["AUTO_HASH_RESOLUTION", "SceneTrainer", "TrainResult", "finest_hash_resolution", "image_depth_loss",
           "train_scene", "z_depth_to_range"]
