"""``nsim train-scene``: the scene NeRF of a room, as a ``scene-checkpoint`` artifact.

Input: a ``poses`` artifact from ``nsim reconstruct`` (its frames, metric poses and sparse
points) or a ``capture`` artifact (ground-truth poses; the bench and tests use it). Frame ``i``
is held out for evaluation when ``i % data.holdout_every == 0``.

A robot's own frames (``--recording``, a ``registration`` artifact of ``nsim register-log`` made
against the same poses artifact): its recording's colour camera frames become extra training
views, with their recorded camera models, at their registered world poses
(``nsim.train.scene_data``: ``read_recorded_frames``, ``split_recorded_frames``,
``SceneData.with_recorded_frames``). ``Inputs.recording`` (``RecordingConfig``) says which: a
``share`` of the training views, and a fixed hold-out (every ``holdout_every``-th frame of each
camera) that never trains. ``scene.json``'s ``recording`` key records the rule, the counts (frames
outside the registered trajectory dropped), the frames that trained (their ``image`` index in
``images``: after the capture's) and the held-out frames for scoring. The registration and the
options enter the action key only when given: without them the key, and the artifact, are what
they were.

Artifact layout (see ``nsim.train.scene_export.export_scene``)::

    model.pt, scene.json       weights + everything that rebuilds the model (configs, scene box,
                               hash backend, which images trained); ``nsim.rendering.load_model``
    bounds.json                the scene box (world metres, z up; ``"metric": false`` and no metres when
                               the poses' scale is arbitrary), near / far
    occupancy_grid.npy/.json   3D occupancy baked from the density (empty-space skipping)
    obstacles.png/.json        2D obstacle map and polygons in a height band (the simulator's map; with
                               occupancy.json, obstacle_cells.*, map.yaml/.pgm: metric scenes only)
    curves.png, history.json   training loss / PSNR against steps
    eval/frame_NNNNN.png       held-out renders beside ground truth at ``eval.image_side``; eval.json
                               their PSNR / SSIM / LPIPS (mean appearance embedding), the left-half
                               embedding fit's right-half scores, depth AbsRel, the scored resolution

Training runs on copies of the images shrunk to ``data.max_image_side`` (intrinsics scaled
exactly); held-out scoring renders at ``eval.image_side`` (0: as captured), chunk by chunk.
Poses of arbitrary scale (``report.json`` / ``transforms.json`` say so): the config's metre
lengths are scaled to the scene's size (``nsim.train.scene_data.units_per_metre``), scene.json
and bounds.json say ``"metric": false``, and no walkable map is made (scene.json's
``walkable_map_why_not`` says why and how to give a scale; ``nsim simulate`` repeats it).

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
import json
import logging
import shutil
from typing import Any

from nsim.config import from_dict, to_dict
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.stages.runner import cached, device_kind, rerun
from nsim.train.scene_config import TrainSceneConfig
from nsim.train.scene_data import RecordingConfig
from nsim.workspace.store import is_id

STAGE = "train_scene"
# 2: scene.json keeps the training images' mean colour (image_mean_rgb, for nsim render's fill);
# 3: shrunk training images, scoring at eval.image_side with LPIPS and the half-image protocol, scale record
# 4: the walkable map from the training rays (hits, carved haze; obstacle_density 1/m), depth/mask supervision keys
# 6: the walkable map's rays followed only near the band, depth maps sized by pixel count (portrait photos)
# 7: held-out appearance codes fitted together (the same fits, one batch), the walkable map skips the
#    occupancy grid's empty cells (the same map), a scene of arbitrary scale gets no walkable map, and
#    the held-out comparisons carry a label strip (render | ground truth)
# 8: eval.json's depth AbsRel is nsim.metrics.depth's (ground truth within its bounds, predictions clamped)
VERSION = 8

log = logging.getLogger(__name__)

Config = TrainSceneConfig
ACCEPTED_KINDS = ("poses", "capture")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """``poses``: a poses artifact id (or a capture artifact id: ground-truth poses). ``registration``: a
    registration artifact (``nsim register-log`` against ``poses``) whose recording's frames also train,
    as ``recording`` says (ignored without a registration)."""

    poses: str
    registration: str | None = None
    recording: RecordingConfig = RecordingConfig()

    def ids(self) -> dict[str, str]:
        return {"poses": self.poses} if self.registration is None else {"poses": self.poses,
                                                                         "registration": self.registration}


@dataclasses.dataclass(frozen=True)
class Outputs:
    scene: str
    cache_hit: bool = False
    train_seconds: float | None = None
    resumed_from: int | None = None


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    extra: dict[str, Any] = {"device": device_kind(ctx.device)}
    if inputs.registration is not None:
        extra["recording"] = to_dict(inputs.recording)
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def resolve_registration(spec: str, poses_id: str, ctx: RunContext):
    """The registration artifact ``spec`` and its recording, checked: the kinds, and a scene world that is the
    poses artifact's (the registration was made against ``poses_id``)."""
    store = ctx.store
    reg = store.get(store.resolve(spec))
    if reg.kind != "registration":
        how = "; register it first (nsim register-log)" if reg.kind == "recording" else ""
        raise InputError(f"--recording {spec}: a {reg.kind} artifact; train-scene needs a registration artifact "
                         f"(nsim register-log){how}")
    made_on = reg.manifest.get("inputs", {})
    if made_on.get("poses") != poses_id:
        raise InputError(f"--recording {spec}: registration {reg.id[:12]} places the robot in the world of poses "
                         f"{str(made_on.get('poses'))[:12]}, not of --poses {poses_id[:12]}; register the recording "
                         "against the poses you train on")
    rec_id = made_on.get("recording")
    if not isinstance(rec_id, str) or not is_id(rec_id):
        raise InputError(f"--recording {spec}: registration {reg.id[:12]} names no recording artifact")
    return reg, store.get(rec_id)  # WorkspaceError (one line) when it is not in the workspace


def resume_dir(ctx: RunContext, key: str):
    return ctx.store.root / "tmp" / f"{STAGE}.{key[:24]}.resume"


def run(inputs: Inputs, cfg: Config, ctx: RunContext, on_log=None) -> Outputs:
    """Train (or resume, or find in the run cache). ``on_log(trainer, stats)``: called every
    ``output.log_every`` steps (benchmarks evaluate there; it must not change the trainer)."""
    from nsim.train.scene import SceneData, train_scene
    from nsim.train.scene_data import check_training_inputs

    store = ctx.store
    src = store.get(store.resolve(inputs.poses))
    if src.kind not in ACCEPTED_KINDS:
        raise InputError(f"--poses {inputs.poses}: a {src.kind} artifact; train-scene needs a poses artifact "
                         "(nsim reconstruct) or a capture artifact")
    reg = rec = None
    if inputs.registration is not None:
        reg, rec = resolve_registration(inputs.registration, src.id, ctx)
    inputs = dataclasses.replace(inputs, poses=src.id, registration=reg.id if reg is not None else None)
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(scene=hit, cache_hit=True)

    # every check the inputs decide, before any image is read or any training (issue 44)
    transforms = check_training_inputs(src.path, cfg, device_kind(ctx.device))
    robot = plan_recorded_frames(src.path, transforms, reg, rec, inputs.recording, cfg) if reg is not None else None
    data = SceneData.load(src.path, max_image_side=cfg.data.max_image_side, scale=cfg.data.scale)
    record = None
    if robot is not None:
        data, record = add_recorded_frames(data, reg, rec, inputs.recording, cfg, robot)
    device = ctx.device
    work = resume_dir(ctx, key)
    result = train_scene(data, cfg, work, device=device, seed=ctx.seed, progress=ctx.show_progress, on_log=on_log)
    scene_id = publish(ctx, key, inputs, cfg, src.kind, data, result, record)
    shutil.rmtree(work, ignore_errors=True)
    return Outputs(scene=scene_id, train_seconds=result.trainer.train_seconds, resumed_from=result.resumed_from)


def plan_recorded_frames(root, transforms, reg, rec, opts: RecordingConfig, cfg: Config):
    """The registered recording's frames and which of them train (``(recorded, split, capture_train)``), checked
    before any image is read: a metric scene, the cameras, at least one robot frame to train on, and each
    recorded camera fitting the capture's training size (``transforms``: the poses' transforms.json)."""
    from nsim.train.scene_data import (
        camera_at,
        fit_camera,
        holdout_mask,
        poses_scale,
        read_recorded_frames,
        split_recorded_frames,
    )

    label = f"--recording {reg.id[:12]}"
    metric = poses_scale(root, transforms.extra)[1] if cfg.data.scale == "auto" else cfg.data.scale == "metric"
    if not metric:
        raise InputError(f"{label}: the poses' scale is arbitrary (data.scale); a robot's metric frames need a "
                         "metric scene")
    recorded = read_recorded_frames(reg.path, rec.path, opts.cameras, label)
    capture_train = int((~holdout_mask(root, len(transforms.frames), cfg.data.holdout_every)).sum())
    split = split_recorded_frames(recorded, capture_train, opts)
    dropped = sum(recorded.outside.values())
    if dropped:
        log.warning("%s: %d of %d recorded frames lie outside the registered trajectory; dropped", label, dropped,
                    sum(recorded.recorded.values()))
    if not split.train:
        raise InputError(f"{label}: no robot frame to train on (share {opts.share:g} of {capture_train} capture "
                         f"training frames asks for {split.wanted}; {len(recorded.frames)} frames inside the "
                         f"trajectory, {len(split.held_out)} of them held out)")
    if len(split.train) < split.wanted:
        log.warning("%s: share %g asks for %d robot frames, the recording has %d to train on: using them all",
                    label, opts.share, split.wanted, len(split.train))
    size = camera_at(transforms.frames[0].camera, cfg.data.max_image_side)
    for camera in {recorded.frames[k].camera_name: recorded.frames[k].camera for k in split.train}.values():
        fit_camera(camera, size.width, size.height)  # InputError: a camera that cannot be fitted
    return recorded, split, capture_train


def add_recorded_frames(data, reg, rec, opts: RecordingConfig, cfg: Config, robot=None):
    """``data`` with the registered recording's training frames appended, and scene.json's ``recording`` record.
    ``robot``: :func:`plan_recorded_frames`'s answer (None: planned here, from ``data``'s transforms.json)."""
    from nsim.train.scene_data import recording_record

    if robot is None:
        from nsim.io.transforms_json import read_transforms

        robot = plan_recorded_frames(data.root, read_transforms(data.root / "transforms.json"), reg, rec, opts, cfg)
    recorded, split, capture_train = robot
    record = recording_record(recorded, split, opts, capture_train, data.n_frames, reg.id, rec.id)
    return data.with_recorded_frames([recorded.frames[k] for k in split.train]), record


def publish(ctx: RunContext, key: str, inputs: Inputs, cfg: Config, source_kind: str, data, result,
            record: dict[str, Any] | None = None) -> str:
    """Export a finished training (``nsim.train.scene.TrainResult``) as the artifact of ``key``; ``record``:
    scene.json's ``recording`` key (robot frames trained)."""
    from nsim.train.scene_export import export_scene

    with ctx.store.publish(kind="scene-checkpoint", stage=STAGE, version=VERSION, key=key, config=cfg,
                           inputs=inputs.ids(), seed=ctx.seed) as out:
        summary = export_scene(out.dir, result)
        if record is not None:
            scene_json = out.dir / "scene.json"
            scene_json.write_text(json.dumps({**json.loads(scene_json.read_text()), "recording": record}, indent=1)
                                  + "\n")
            summary = {**summary, "robot_train_frames": record["robot_train_frames"],
                       "robot_held_out_frames": len(record["held_out"]),
                       "robot_share_trained": round(record["share_trained"], 4)}
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
    inputs = Inputs(poses=manifest["inputs"]["poses"], registration=manifest["inputs"].get("registration"))
    if inputs.registration is not None:  # the options are scene.json's record
        rec = json.loads(ctx.store.get(manifest["id"]).file("scene.json").read_text())["recording"]
        inputs = dataclasses.replace(inputs, recording=from_dict(RecordingConfig, rec["options"]))
    return rerun(run, inputs, Config, manifest, ctx).scene
