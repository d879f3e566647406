"""The scene-checkpoint artifact of a finished training (``export_scene``: what ``nsim train-scene`` publishes):
the model, the scene box, the occupancy grid and walkable map baked from the trained field, the training curves and
the held-out scores.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nsim.train import loop
from nsim.train.loop import spread
from nsim.train.scene import SceneTrainer, TrainResult, _step_seed
from nsim.train.scene_data import image_mean_rgb
from nsim.train.scene_eval import constant_color_psnr

log = logging.getLogger(__name__)

#: Why a scene of arbitrary scale has no walkable map (scene.json's ``walkable_map``; nsim simulate says it too).
NO_MAP_WITHOUT_SCALE = ("the poses' scale is arbitrary, so a robot's height band and a floor mean nothing in them; "
                        "give nsim reconstruct a scale (--reference, --camera-height or --known-distance; --metric "
                        "for an import whose poses are metric) and train again")


def occupancy_cell(aabb, cell_m: float, max_cells: int) -> float:
    """``cell_m``, or the smallest cell (1 % steps) above it whose grid over ``aabb (2, 3)`` has at most
    ``max_cells`` cells."""
    from nsim.rendering.occupancy import grid_shape

    aabb = np.asarray(torch.as_tensor(aabb).cpu(), dtype=np.float64)
    if math.prod(grid_shape(aabb, cell_m)) <= max_cells:
        return cell_m
    cell = max(cell_m, float(np.prod(aabb[1] - aabb[0]) / max_cells) ** (1.0 / 3.0))
    while math.prod(grid_shape(aabb, cell)) > max_cells:
        cell *= 1.01
    log.warning("occupancy grid: cells of %.4g instead of %.4g (at most %d cells over the box)", cell, cell_m, max_cells)
    return cell


def bake_occupancy(trainer: SceneTrainer):
    """The 3D occupancy grid of the trained scene field (``output.occupancy_*``)."""
    from nsim.rendering.occupancy import OccupancyGrid

    out = trainer.cfg.output
    g = torch.Generator().manual_seed(_step_seed(trainer.seed, 0, "occupancy"))
    cell = occupancy_cell(trainer.aabb, out.occupancy_cell_m, out.occupancy_max_cells)
    return OccupancyGrid.bake(trainer.density_fn(), trainer.aabb, cell, out.occupancy_density,
                              out.occupancy_samples_per_cell, dilate=1, generator=g, device=trainer.device)


@torch.no_grad()
def bake_obstacles(trainer: SceneTrainer, grid=None):
    """The 2D obstacle map at ``output.obstacle_band_m`` (world z, metres), with the cells the training
    views observed (their poses as trained, pose refinement included; unobserved cells are unknown).
    ``grid``: the scene's occupancy grid (:func:`bake_occupancy`): the field is not evaluated in its empty cells."""
    from nsim.rendering.occupancy import CameraViews, obstacle_map

    out = trainer.cfg.output
    model = trainer.model.eval()
    g = torch.Generator().manual_seed(_step_seed(trainer.seed, 0, "obstacles"))
    ids = np.asarray(trainer.train_ids, dtype=np.int64)
    cam_to_world = trainer.data.cam_to_world[ids]
    if trainer.pose_refine is not None:
        idx = torch.as_tensor(ids, device=trainer.device)
        cam_to_world = trainer.pose_refine(trainer.cam_to_world[idx], idx).double().cpu().numpy()
    views = CameraViews(cam_to_world, tuple(trainer.data.cameras), trainer.data.camera_index[ids],
                        trainer.cfg.sampler.near_m, trainer.cfg.sampler.far_m)
    return obstacle_map(lambda x: model.field.density(x)[0], trainer.aabb, out.obstacle_band_m, out.obstacle_cell_m,
                        out.obstacle_density, out.occupancy_samples_per_cell, generator=g, device=trainer.device,
                        views=views, skip=grid)


def plot_curves(path: Path, history: list[dict[str, float]]) -> None:
    """Training loss and PSNR (train batches; held-out views when evaluated) against steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), dpi=90)
    if history:
        steps = [h["step"] for h in history]
        axes[0].semilogy(steps, [h["loss"] for h in history], label="loss")
        for key in ("interlevel", "distortion", "free_space"):
            if all(key in h for h in history):
                axes[0].semilogy(steps, [h[key] for h in history], label=key, alpha=0.7)
        axes[0].set_xlabel("step")
        axes[0].legend()
        axes[1].plot(steps, [h["psnr_train"] for h in history], label="train batch PSNR")
        ev = [(h["step"], h["eval_psnr"]) for h in history if "eval_psnr" in h]
        if ev:
            axes[1].plot(*zip(*ev, strict=True), "o-", label="held-out PSNR")
        axes[1].set_xlabel("step")
        axes[1].set_ylabel("dB")
        axes[1].legend()
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def export_scene(out_dir: str | os.PathLike, result: TrainResult) -> dict[str, Any]:
    """Write everything the stage publishes into ``out_dir``; returns the summary.

    Files: ``model.pt`` + ``scene.json`` (weights and what rebuilds the model: configs, scene
    box, hash backend, training images), ``bounds.json``, ``occupancy_grid.npy`` + ``.json`` (3D grid),
    ``obstacles.png`` + ``obstacles.json`` (2D map and polygons at the height band; only for a metric
    scene: a robot's height band and a floor mean nothing in arbitrary units, see ``NO_MAP_WITHOUT_SCALE``),
    ``curves.png`` + ``history.json`` (against steps), ``eval/<frame>.png`` (render | ground
    truth, at the scored size) and ``eval.json`` (per view: PSNR / SSIM / LPIPS with the mean
    appearance embedding, the left-half fit's right-half ``*_half`` scores, depth AbsRel; which
    resolution was scored; what each score is). ``scene.json`` and ``bounds.json`` say whether the
    scene is metric (``"metric"``; ``"units": "arbitrary"`` otherwise, lengths in the poses' units).
    No file holds a timing, so a rerun on CPU writes the same bytes (the artifact id repeats); the
    training seconds are in ``result.trainer.train_seconds`` for the caller to report.
    """
    from nsim.rendering.model import save_model

    trainer = result.trainer
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = trainer.cfg
    data = trainer.data
    save_model(out_dir, trainer.model, extra={
        "images": data.names,
        "train_images": [int(i) for i in trainer.train_ids],
        "eval_images": [int(i) for i in trainer.eval_ids],
        "steps": trainer.step,
        "image_mean_rgb": image_mean_rgb(data, trainer.train_ids),
        "image_size_trained": [int(data.size_hw[1]), int(data.size_hw[0])],
        **scale_record(trainer),
    })
    aabb = trainer.aabb.tolist()
    if data.metric:
        bounds = {"units": "m", "metric": True, "frame": "world, z up", "aabb_min_m": aabb[0], "aabb_max_m": aabb[1],
                  "near_m": cfg.sampler.near_m, "far_m": cfg.sampler.far_m}
    else:  # no metre anywhere: lengths in the poses' own units
        bounds = {"units": "arbitrary", "metric": False, "frame": "world, z up (as the poses give it)",
                  "aabb_min": aabb[0], "aabb_max": aabb[1], "near": cfg.sampler.near_m, "far": cfg.sampler.far_m,
                  "units_per_m_guess": trainer.units_per_m}
    (out_dir / "bounds.json").write_text(json.dumps(bounds, indent=1) + "\n")
    phases = result.post_train_seconds
    t0 = time.perf_counter()
    with loop.torch_threads(trainer.loop_threads()):  # plain tensor work: on every core training used
        grid = bake_occupancy(trainer)
        grid.save(out_dir / "occupancy_grid.npy")
        if not data.metric:  # the grid's own JSON says metres; its box key stays for OccupancyGrid.load
            meta = json.loads((out_dir / "occupancy_grid.json").read_text())
            meta.update({"units": "arbitrary", "metric": False})
            (out_dir / "occupancy_grid.json").write_text(json.dumps(meta, indent=1) + "\n")
        # obstacles.json = occupancy.json (polygons with holes, read by nsim simulate), obstacles.png,
        # obstacle_cells.npy / .png (free / occupied / unknown) and the nav2 map map.yaml + map.pgm
        phases["occupancy_grid"] = round(time.perf_counter() - t0, 2)
        if data.metric:
            t0 = time.perf_counter()
            bake_obstacles(trainer, grid).save(out_dir)
            phases["walkable_map"] = round(time.perf_counter() - t0, 2)
        else:
            log.warning("no walkable map: %s", NO_MAP_WITHOUT_SCALE)
    history = [{k: v for k, v in h.items() if k != "train_seconds"} for h in trainer.history]
    plot_curves(out_dir / "curves.png", history)
    (out_dir / "history.json").write_text(json.dumps(history, indent=1) + "\n")
    views = spread(list(trainer.eval_ids), cfg.output.final_eval_views)
    summary: dict[str, Any] = {"steps": trainer.step, "occupied_fraction": grid.occupied_fraction}
    if views:
        t0 = time.perf_counter()
        (out_dir / "eval").mkdir(exist_ok=True)
        with loop.torch_threads(trainer.loop_threads()):  # chunks on the part threads, fit and LPIPS here
            ev = trainer.evaluate(views, final=True, image_dir=out_dir / "eval")
        phases["heldout_scores"] = round(time.perf_counter() - t0, 2)
        (out_dir / "eval.json").write_text(json.dumps({
            "resolution": ev["resolution"], "protocol": ev["protocol"], "views": ev["views"], "mean": ev["mean"],
            "constant_color_psnr": constant_color_psnr(data, cfg.data.holdout_every)}, indent=1) + "\n")
        summary.update({f"eval_{k}": round(v, 4) for k, v in ev["mean"].items()})
        summary["eval_image_size"] = ev["resolution"]["scored_wh"]
    result.evaluation = summary
    return summary


def scale_record(trainer: SceneTrainer) -> dict[str, Any]:
    """What scene.json says about the scene's units (``metric``; for arbitrary scale, the guess that sized
    the trainer's lengths: the config's metre values times ``units_per_m``)."""
    data = trainer.data
    return {"metric": bool(data.metric), "units": "m" if data.metric else "arbitrary",
            "scale_source": data.scale_source, "units_per_m": trainer.units_per_m, "units_per_m_from": trainer.units_from,
            "walkable_map": "occupancy.json" if data.metric else None,
            **({} if data.metric else {"walkable_map_why_not": NO_MAP_WITHOUT_SCALE})}


__all__ = ["NO_MAP_WITHOUT_SCALE", "bake_obstacles", "bake_occupancy", "export_scene", "occupancy_cell",
           "plot_curves", "scale_record"]
