"""``nsim train-scene``: the scene NeRF of a room, as a ``scene-checkpoint`` artifact.

Input: a ``poses`` artifact from ``nsim reconstruct`` (its frames, metric poses and sparse
points) or a ``capture`` artifact (ground-truth poses; the bench and tests use it). Frame ``i``
is held out for evaluation when ``i % data.holdout_every == 0``.

Artifact layout (see ``nsim.train.scene.export_scene``)::

    model.pt, scene.json       weights + everything that rebuilds the model (configs, scene box,
                               hash backend, which images trained); ``nsim.rendering.load_model``
    bounds.json                the scene box (world metres, z up; ``"metric": false`` and no metres when
                               the poses' scale is arbitrary), near / far
    occupancy_grid.npy/.json   3D occupancy baked from the density (empty-space skipping)
    obstacles.png/.json        2D obstacle map and polygons in a height band (the simulator's map)
    curves.png, history.json   training loss / PSNR against steps
    eval/frame_NNNNN.png       held-out renders beside ground truth at ``eval.image_side``; eval.json
                               their PSNR / SSIM / LPIPS (mean appearance embedding), the left-half
                               embedding fit's right-half scores, depth AbsRel, the scored resolution

Training runs on copies of the images shrunk to ``data.max_image_side`` (intrinsics scaled
exactly); held-out scoring renders at ``eval.image_side`` (0: as captured), chunk by chunk.
Poses of arbitrary scale (``report.json`` / ``transforms.json`` say so): the config's metre
lengths are scaled to the scene's size (``nsim.train.scene_data.units_per_metre``) and scene.json
and bounds.json say ``"metric": false``.

Resume: checkpoints go to ``<workspace>/tmp/train_scene.<key>.resume/last.pt`` every
``output.checkpoint_every`` steps. A run that is killed and started again with the same
inputs, config, seed and device continues from there and publishes the same artifact as an
uninterrupted run (bit-identical on CPU). The directory is removed once the artifact is
published; ``nsim gc`` removes an abandoned one after 24 hours.

The device is part of the action key: a CUDA run (different kernels, mixed precision) is a
different artifact from a CPU run.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
from typing import Any

from nsim.config import from_dict
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.train.scene import TrainSceneConfig

STAGE = "train_scene"
# 2: scene.json keeps the training images' mean colour (image_mean_rgb, for nsim render's fill);
# 3: shrunk training images, scoring at eval.image_side with LPIPS and the half-image protocol, scale record
# 4: the walkable map from the training rays (hits, carved haze; obstacle_density 1/m), depth/mask supervision keys
VERSION = 5

log = logging.getLogger(__name__)

Config = TrainSceneConfig
ACCEPTED_KINDS = ("poses", "capture")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """``poses``: a poses artifact id (or a capture artifact id: ground-truth poses)."""

    poses: str

    def ids(self) -> dict[str, str]:
        return {"poses": self.poses}


@dataclasses.dataclass(frozen=True)
class Outputs:
    scene: str
    cache_hit: bool = False
    train_seconds: float | None = None
    resumed_from: int | None = None


def device_kind(device: str) -> str:
    """What of the device enters the action key: ``cpu`` or ``cuda`` (not the index)."""
    return "cuda" if str(device).startswith("cuda") else "cpu"


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed,
                                extra={"device": device_kind(ctx.device)})


def resume_dir(ctx: RunContext, key: str):
    return ctx.store.root / "tmp" / f"{STAGE}.{key[:24]}.resume"


def run(inputs: Inputs, cfg: Config, ctx: RunContext, on_log=None) -> Outputs:
    """Train (or resume, or find in the run cache). ``on_log(trainer, stats)``: called every
    ``output.log_every`` steps (benchmarks evaluate there; it must not change the trainer)."""
    from nsim.train.scene import SceneData, train_scene

    store = ctx.store
    src = store.get(store.resolve(inputs.poses))
    if src.kind not in ACCEPTED_KINDS:
        raise InputError(f"--poses {inputs.poses}: a {src.kind} artifact; train-scene needs a poses artifact "
                         "(nsim reconstruct) or a capture artifact")
    inputs = Inputs(poses=src.id)
    key = action_key(inputs, cfg, ctx)
    if not ctx.force and (hit := store.lookup(key)) is not None:
        return Outputs(scene=hit.id, cache_hit=True)

    data = SceneData.load(src.path, max_image_side=cfg.data.max_image_side, scale=cfg.data.scale)
    device = ctx.device
    work = resume_dir(ctx, key)
    result = train_scene(data, cfg, work, device=device, seed=ctx.seed, progress=ctx.show_progress, on_log=on_log)
    scene_id = publish(ctx, key, inputs, cfg, src.kind, data, result)
    shutil.rmtree(work, ignore_errors=True)
    return Outputs(scene=scene_id, train_seconds=result.trainer.train_seconds, resumed_from=result.resumed_from)


def publish(ctx: RunContext, key: str, inputs: Inputs, cfg: Config, source_kind: str, data, result) -> str:
    """Export a finished training (``nsim.train.scene.TrainResult``) as the artifact of ``key``."""
    from nsim.train.scene import export_scene

    with ctx.store.publish(kind="scene-checkpoint", stage=STAGE, version=VERSION, key=key, config=cfg,
                           inputs=inputs.ids(), seed=ctx.seed) as out:
        summary = export_scene(out.dir, result)
        out.summary.update({
            "source_kind": source_kind,
            "frames": data.n_frames,
            "train_frames": int(len(result.trainer.train_ids)),
            "eval_frames": int(len(result.trainer.eval_ids)),
            "image_size": [int(data.full_size_hw[1]), int(data.full_size_hw[0])],
            "train_image_size": [int(result.trainer.data.size_hw[1]), int(result.trainer.data.size_hw[0])],
            "metric": bool(data.metric),
            "device": device_kind(str(result.trainer.device)),
            "hash_backend": result.trainer.backend,
            **summary,
        })
        out.timing["train_seconds"] = round(result.trainer.train_seconds, 2)
        out.timing["post_train_phases_s"] = dict(result.post_train_seconds)
        if result.resumed_from is not None:
            out.timing["resumed_from_step"] = result.resumed_from
    return out.ref


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    cfg = from_dict(Config, manifest["config"])
    ctx.force = True
    return run(Inputs(poses=manifest["inputs"]["poses"]), cfg, ctx).scene
