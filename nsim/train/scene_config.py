"""The scene trainer's configuration (``nsim train-scene``; presets: ``train_scene/*.yaml`` among nsim's configs):
steps, batch and learning rates (``OptimConfig``), loss weights (``LossConfig``), logging, checkpoints and the baked
grids (``OutputConfig``), with the field's, sampler's, data's and evaluation's own sections (``TrainSceneConfig``);
and :func:`in_scene_units`, the metre lengths of a config in a scene of arbitrary scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from nsim.config import param
from nsim.fields.scene_field import SceneFieldConfig
from nsim.rendering.model import SamplerConfig
from nsim.train.scene_data import DataConfig
from nsim.train.scene_eval import EvalConfig


@dataclass(frozen=True)
class OptimConfig:
    """Steps, batch and Adam with an exponentially decaying learning rate.

    Each group's learning rate goes from ``lr_*`` (after a linear warm-up) to
    ``lr_* * lr_final_factor`` at the last step. ``num_threads``: torch CPU threads (0 leaves
    torch's default), per batch part; the training loop holds them and restores the count after
    (``SceneTrainer.loop_threads``). ``mixed_precision``: fp16 autocast with a grad scaler, CUDA only.
    ``batch_threads``: with ``k > 1`` parts, part ``j`` draws its jitter from ``(seed, step, j)``
    and its loss is scaled by its share of the batch; each part's gradients come back from
    ``torch.autograd.grad`` and are summed in part order, so the step is the whole batch's and
    deterministic whichever thread finishes first.
    """

    steps: int = param(5000, ge=1)
    rays_per_batch: int = param(4096, ge=1)
    lr_field: float = param(1e-2, gt=0.0)
    lr_proposal: float = param(1e-2, gt=0.0)
    lr_pose: float = param(1e-4, gt=0.0)
    lr_final_factor: float = param(0.03, gt=0.0, le=1.0)
    warmup_steps: int = param(0, ge=0)
    adam_eps: float = param(1e-15, gt=0.0)
    adam_beta2: float = param(0.999, gt=0.0, lt=1.0, help="Adam's second-moment decay (instant-NGP uses 0.99)")
    proposal_anneal_steps: int = param(1000, ge=0, help="steps over which proposal weights go from ^0.5 to ^1")
    proposal_update_every: int = param(5, ge=1, help="train the proposal fields every N steps (after the warm-up)")
    proposal_warmup_steps: int = param(1000, ge=0, help="steps over which the update interval grows from 1 to N")
    pose_refinement: bool = param(False, help="optimise a per-image SE(3) correction (NeRF--)")
    appearance_mean_share: float = param(0.0, ge=0.0, lt=1.0, help="fraction of each batch's rays rendered with "
                                         "the training images' mean appearance code instead of their own "
                                         "(appearance dropout): the colour MLP then learns what the mean code "
                                         "draws, the images' average look, which is how a held-out view is "
                                         "rendered and scored (the mean-embedding protocol)")
    mixed_precision: bool = True
    num_threads: int = param(2, ge=0, le=256)
    batch_threads: int = param(1, ge=1, le=64, help="split each batch into this many parts whose forward and "
                               "backward run on concurrent threads (CPU; each with num_threads torch threads): "
                               "a 512-ray step at 1 torch thread runs 1.4x faster as 2 parts on 2 cores than "
                               "as one on 2 torch threads")


@dataclass(frozen=True)
class LossConfig:
    """Loss weights. ``free_space_*``: the proposal sampler only ever queries the scene field near
    surfaces, so its density elsewhere is whatever initialisation left ("fog" that a marching
    renderer, which queries everywhere, would see). This term draws ``free_space_samples`` points
    per ray uniformly between ``near`` and ``free_space_margin_m`` before the first bin that
    carries weight (of the last proposal stage or of the final samples, whichever is nearer: the
    ray is transparent there), and penalises the field's density there (mean, 1/m), so
    that marching, the occupancy grid and the obstacle map see the same scene as the training
    renderer. It starts after ``free_space_start`` of the steps: applied while the geometry is
    still wrong, it would hold surfaces back from moving towards the cameras."""

    interlevel_weight: float = param(1.0, ge=0.0)
    distortion_weight: float = param(0.002, ge=0.0)
    free_space_weight: float = param(0.0, ge=0.0, help="density penalty in front of the visible surface (see below)")
    free_space_samples: int = param(2, ge=1, le=64, help="free-space points per ray")
    free_space_margin_m: float = param(0.2, ge=0.0)
    free_space_start: float = param(0.5, ge=0.0, le=1.0, help="fraction of the steps before the free-space term starts")
    random_background: bool = param(False, help="composite each training ray over a random colour instead of the "
                                    "model's background, so that a surface seen in the images has to be opaque "
                                    "(instant-NGP's trick for object captures; on the closed test room, applied from "
                                    "step 0, it collapsed the geometry: 19.9 dB, AbsRel 0.90 at 1400 steps vs 24.7 dB)")
    random_background_start: float = param(0.0, ge=0.0, le=1.0,
                                           help="fraction of the steps before the random background starts")
    opacity_weight: float = param(0.0, ge=0.0, help="binary entropy of each ray's accumulation: a ray should "
                                  "either hit something or nothing, not see through a half-transparent wall")
    opacity_start: float = param(0.0, ge=0.0, le=1.0, help="fraction of the steps before the opacity term starts")
    depth_weight: float = param(0.0, ge=0.0, help="sparse-point depth supervision (needs sparse_points.ply)")
    depth_rays_per_batch: int = param(256, ge=1)
    image_depth_weight: float = param(0.0, ge=0.0, help="depth-image supervision (needs the frames' "
                                      "depth_file_path): on every batch ray with depth, |expected range - "
                                      "depth range| / depth range (image_depth_loss)")


@dataclass(frozen=True)
class OutputConfig:
    """Logging, checkpoints, evaluation and the baked occupancy grid / obstacle map."""

    log_every: int = param(50, ge=1)
    checkpoint_every: int = param(1000, ge=1)
    eval_every: int = param(0, ge=0, help="steps between evaluations during training (0: only at the end)")
    eval_views: int = param(4, ge=0, help="held-out views scored during training (0: all)")
    final_eval_views: int = param(0, ge=0, help="held-out views scored and rendered at the end (0: all)")
    occupancy_cell_m: float = param(0.04, gt=0.0, help="3D occupancy grid cell size")
    occupancy_density: float = param(1.0, gt=0.0, help="density (1/m) above which a cell of the rendering grid is "
                                     "occupied; low, because the grid must not change the image: a NeRF's haze of "
                                     "0.01/m over 5 m of free space is 5 % of a pixel")
    occupancy_samples_per_cell: int = param(2, ge=1, le=64)
    obstacle_band_m: tuple[float, float] = (0.1, 1.0)
    obstacle_cell_m: float = param(0.05, gt=0.0)
    obstacle_density: float = param(1.0, gt=0.0, help="density (1/m) above which a cell of the 2D obstacle map "
                                    "is an obstacle unless training rays went through it (haze is carved away); "
                                    "cells where training rays stop are obstacles whatever the density")
    render_chunk_rays: int = param(8192, ge=1)
    occupancy_max_cells: int = param(1 << 23, ge=1, help="the 3D grid's cells at most (its cells grow to fit): "
                                     "bounds the bake's memory (~60 B a cell) and time for a large box")


@dataclass(frozen=True)
class TrainSceneConfig:
    field: SceneFieldConfig = SceneFieldConfig()
    sampler: SamplerConfig = SamplerConfig()
    optim: OptimConfig = OptimConfig()
    loss: LossConfig = LossConfig()
    data: DataConfig = DataConfig()
    output: OutputConfig = OutputConfig()
    eval: EvalConfig = EvalConfig()


def in_scene_units(cfg: TrainSceneConfig, units_per_m: float) -> TrainSceneConfig:
    """``cfg`` with every length in metres multiplied by ``units_per_m`` and every density (1/m)
    divided by it, so that a scene of arbitrary scale gets the near plane, box margin, cells and
    bands a metric one would (the initial density too: ``field.density_bias`` shifts by ``-ln s``).
    A fixed box (``data.aabb_*_m``) is taken to be in the poses' own units already. ``cfg`` itself
    when ``units_per_m`` is 1."""
    s = float(units_per_m)
    if s == 1.0:
        return cfg
    sm, lo, out = cfg.sampler, cfg.loss, cfg.output
    return replace(
        cfg,
        field=replace(cfg.field, density_bias=cfg.field.density_bias - math.log(s)),
        sampler=replace(sm, near_m=sm.near_m * s, far_m=sm.far_m * s, lindisp_break_m=sm.lindisp_break_m * s,
                        grid_cell_m=sm.grid_cell_m * s, grid_step_m=sm.grid_step_m * s,
                        grid_density_threshold=sm.grid_density_threshold / s),
        loss=replace(lo, free_space_margin_m=lo.free_space_margin_m * s),
        data=replace(cfg.data, bounds_margin_m=cfg.data.bounds_margin_m * s),
        output=replace(out, occupancy_cell_m=out.occupancy_cell_m * s, occupancy_density=out.occupancy_density / s,
                       obstacle_band_m=(out.obstacle_band_m[0] * s, out.obstacle_band_m[1] * s),
                       obstacle_cell_m=out.obstacle_cell_m * s, obstacle_density=out.obstacle_density / s),
    )


__all__ = ["LossConfig", "OptimConfig", "OutputConfig", "TrainSceneConfig", "in_scene_units"]
