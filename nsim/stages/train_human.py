"""``nsim train-human``: a person's NeRF from frames, skeleton poses and masks, as a ``human-checkpoint``.

Input: a capture artifact made with ``nsim capture synth --actor`` (the test room with a walking
person), or a folder in the documented human data format (docs/human_data.md: transforms.json +
images, ``poses.json`` or ``poses.bvh`` aligned to the frames, ``masks/``) so a lab can bring its
own pose estimator; a folder's files are digested into the action key. Or a video (``--video``) or a
folder of frames (``--images``) of one person, filmed by a static or a handheld camera (told apart by
the background's motion; a moving camera's path by nsim's SfM with the person masked out,
``nsim.human.moving_camera``): masks, a metric camera per frame and
per-frame skeleton poses are found automatically and offline (``nsim.train.human_data_video``, which
needs the ``nsim[people]`` extra), written as that format under ``tmp/``, then trained on as above;
the artifact then also holds ``person.bvh`` (the person's own motion) and ``person_fit.json``
(camera height, bone lengths, frames dropped). Optionally a scene
checkpoint: then training composites the person over the scene NeRF's samples along the same
rays (as the paper, the scene is trained first); otherwise over the capture's background images
(``background/``) when present, else the frames themselves outside the mask.

Artifact layout (``nsim.train.human.export_human``)::

    human.pt, human.json      weights; config, skeleton, canonical box (``nsim.human.nerf.load_human_model``)
    turntable.png             the rest pose from several directions
    gait.gif                  one walking cycle
    history.json, eval.json   training curve; per held-out view PSNR in the person's box, mask IoU
    eval/*.png                held-out renders beside ground truth
    poses_refined.json        with pose refinement (refine.lr) or the held-out fit (refine.held_out_steps):
    pose_refinement.json        every frame's pose as refined / fitted, and how far from the given ones
    held_out_fit.json         with the held-out fit: how far it moved the held-out poses (eval.json then
                                scores the fitted poses, and the given ones as ``*_given_poses``)

Resume: checkpoints in ``<workspace>/tmp/train_human.<key>.resume/`` (as train-scene).
"""

from __future__ import annotations

import dataclasses
import hashlib
import shutil
from pathlib import Path
from typing import Any

from nsim.context import RunContext
from nsim.errors import InputError
from nsim.stages.runner import cached, device_kind, rerun
from nsim.train.human import TrainHumanConfig
from nsim.train.human_data_video import PERSON_BVH_FILE, PERSON_FIT_FILE, PersonSource, prepare_person_data

STAGE = "train_human"
VERSION = 5  # 2: held-out comparisons under a label strip (render | ground truth); 3: frames named after their
#   images in eval.json, pose refinement (refine.*: poses_refined.json, pose_refinement.json)
# 4: poses, trajectories and metrics written rounded (nsim.io.canonical: the same bytes on any CPU)
# 5: --video: a following camera told moving by the person's steps, SfM on keyframes, new person_fit.json keys
Config = TrainHumanConfig


@dataclasses.dataclass(frozen=True)
class Inputs:
    """capture: a capture artifact with a person; folder: human data on disk; person: a video or a
    folder of frames of a person (``nsim.train.human_data_video.PersonSource``: masks and poses are
    found automatically); exactly one of the three. scene: an optional scene-checkpoint for the background."""

    capture: str | None = None
    folder: Path | None = None
    scene: str | None = None
    person: PersonSource | None = None

    def ids(self) -> dict[str, str]:
        out = {}
        if self.capture:
            out["capture"] = self.capture
        if self.scene:
            out["scene"] = self.scene
        return out


@dataclasses.dataclass(frozen=True)
class Outputs:
    human: str
    cache_hit: bool = False
    resumed_from: int | None = None


def _digest_dir(path: Path) -> str:
    from nsim.workspace.store import sha256_file

    h = hashlib.sha256()
    for p in sorted(path.rglob("*")):
        if p.is_file():
            h.update(p.relative_to(path).as_posix().encode() + b"\0" + sha256_file(p)[0].encode())
    return h.hexdigest()


def resolve(inputs: Inputs, ctx: RunContext) -> tuple[Inputs, Path]:
    store = ctx.store
    if sum(x is not None for x in (inputs.capture, inputs.folder, inputs.person)) != 1:
        raise InputError("train-human: give exactly one of --capture (an artifact), --data (a folder), "
                         "--video or --images (a person)")
    if inputs.person is not None:
        root, capture = inputs.person.path, None
        if not (root.is_file() if inputs.person.kind == "video" else root.is_dir()):
            what = "file" if inputs.person.kind == "video" else "folder"
            raise InputError(f"--{inputs.person.kind} {root}: no such {what}")
    elif inputs.capture is not None:
        art = store.get(store.resolve(inputs.capture, kind="capture"))
        if not (art.path / "poses.json").is_file():
            raise InputError(f"--capture {inputs.capture}: capture {art.short} has no person (poses.json); "
                             "make one with nsim capture synth --actor")
        root, capture = art.path, art.id
    else:
        root = Path(inputs.folder)
        if not root.is_dir():
            raise InputError(f"--data {root}: no such folder")
        capture = None
    scene = store.resolve(inputs.scene, kind="scene-checkpoint") if inputs.scene else None
    return Inputs(capture=capture, folder=inputs.folder, scene=scene, person=inputs.person), root


def action_key(inputs: Inputs, root: Path, cfg: Config, ctx: RunContext) -> str:
    from nsim.workspace.store import sha256_file

    extra: dict[str, Any] = {"device": device_kind(ctx.device)}
    if inputs.folder is not None:
        extra["data_digest"] = _digest_dir(root)
    if inputs.person is not None:
        p = inputs.person
        extra["person_digest"] = sha256_file(root)[0] if p.kind == "video" else _digest_dir(root)
        extra["person"] = {k: v for k, v in dataclasses.asdict(p).items() if k != "path"}
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def check_data(root: Path, cfg: Config):
    """The human data folder at ``root`` read and checked without reading an image (``HumanData.load``: files,
    poses, sizes from the headers), with what ``cfg`` needs of it: two frames, one camera, a training frame
    left by the hold-out. Returns the ``HumanData``."""
    from nsim.human.data import HumanData
    from nsim.train.human import holdout_split

    hd = HumanData.load(root)
    if hd.num_frames < 2:
        raise InputError(f"human data: need at least 2 frames, got {hd.num_frames}")
    hd.camera()
    holdout_split(hd.num_frames, cfg.data)
    return hd


def load_data(root: Path, hd=None):
    """``HumanTrainData`` from a human data folder (``nsim.human.data.HumanData``; ``hd``: it already loaded)."""
    import numpy as np

    from nsim.human.data import HumanData
    from nsim.train.human import HumanTrainData

    hd = HumanData.load(root) if hd is None else hd
    images, masks, backgrounds = hd.read_all()
    return HumanTrainData(images=images, cam_to_world=hd.cam_to_world(), camera=hd.camera(),
                          joint_transforms=hd.joint_transforms(), masks=np.asarray(masks, dtype=bool),
                          skeleton=hd.skeleton, background=backgrounds, height_m=hd.poses.height_m,
                          names=[Path(f).stem for f in hd.image_paths])


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    from nsim.train.human import export_human, train_human

    store = ctx.store
    inputs, root = resolve(inputs, ctx)
    key = action_key(inputs, root, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(human=hit, cache_hit=True)
    person_report = None
    if inputs.person is not None:  # masks and poses found in the frames, written as a human data folder
        if cfg.data.holdout_every == 1:  # whatever the frames found: checked before finding them
            raise InputError("human data: the hold-out settings leave no training frames (data.holdout_every 1 "
                             "holds out every frame)")
        root = store.root / "tmp" / f"{STAGE}.{key[:24]}.person"
        shutil.rmtree(root, ignore_errors=True)
        person_report = prepare_person_data(inputs.person, root)
    data = load_data(root, check_data(root, cfg))  # checked before any image is read or the scene loaded
    background_model = None
    if inputs.scene is not None:
        from nsim.rendering import load_model

        background_model = load_model(store.get(inputs.scene).path, device=ctx.device).eval()
    work = store.root / "tmp" / f"{STAGE}.{key[:24]}.resume"
    result = train_human(data, cfg, work, device=ctx.device, seed=ctx.seed, background_model=background_model,
                         progress=ctx.show_progress)
    with store.publish(kind="human-checkpoint", stage=STAGE, version=VERSION, key=key, config=cfg,
                       inputs=inputs.ids(), seed=ctx.seed) as out:
        summary = export_human(out.dir, result)
        if person_report is not None:
            shutil.copy2(root / PERSON_BVH_FILE, out.dir / PERSON_BVH_FILE)
            shutil.copy2(root / PERSON_FIT_FILE, out.dir / PERSON_FIT_FILE)
            out.summary["person"] = {k: person_report[k] for k in ("frames_kept", "camera_height_m", "height_m",
                                                                   "dropped")}
        source = "capture" if inputs.capture else str(inputs.person.path if inputs.person else root)
        out.summary.update({"frames": int(data.n_frames), "source": source,
                            "background": "scene" if inputs.scene else ("images" if data.background is not None
                                                                        else "frames"),
                            **summary})
        if getattr(result, "resumed_from", None) is not None:
            out.timing["resumed_from_step"] = result.resumed_from
    shutil.rmtree(work, ignore_errors=True)
    if inputs.person is not None:
        shutil.rmtree(root, ignore_errors=True)
    return Outputs(human=out.ref, resumed_from=getattr(result, "resumed_from", None))


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    ids = manifest["inputs"]
    if "capture" not in ids:
        raise InputError("this human checkpoint was trained from a folder, which the workspace does not hold: "
                         "rerun nsim train-human --data on it with --force to compare")
    return rerun(run, Inputs(capture=ids["capture"], scene=ids.get("scene")), Config, manifest, ctx).human
