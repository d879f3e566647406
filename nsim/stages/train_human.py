"""``nsim train-human``: a person's NeRF from frames, skeleton poses and masks, as a ``human-checkpoint``.

Input: a capture artifact made with ``nsim capture synth --actor`` (the test room with a walking
person), or a folder in the documented human data format (docs/human_data.md: transforms.json +
images, ``poses.json`` or ``poses.bvh`` aligned to the frames, ``masks/``) so a lab can bring its
own pose estimator; a folder's files are digested into the action key. Optionally a scene
checkpoint: then training composites the person over the scene NeRF's samples along the same
rays (as the paper, the scene is trained first); otherwise over the capture's background images
(``background/``) when present, else the frames themselves outside the mask.

Artifact layout (``nsim.train.human.export_human``)::

    human.pt, human.json      weights; config, skeleton, canonical box (``nsim.human.nerf.load_human_model``)
    turntable.png             the rest pose from several directions
    gait.gif                  one walking cycle
    history.json, eval.json   training curve; per held-out view PSNR in the person's box, mask IoU
    eval/*.png                held-out renders beside ground truth

Resume: checkpoints in ``<workspace>/tmp/train_human.<key>.resume/`` (as train-scene).
"""

from __future__ import annotations

import dataclasses
import hashlib
import shutil
from pathlib import Path
from typing import Any

from nsim.config import from_dict
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.train.human import TrainHumanConfig

STAGE = "train_human"
VERSION = 2  # 2: held-out comparisons under a label strip (render | ground truth)
Config = TrainHumanConfig


@dataclasses.dataclass(frozen=True)
class Inputs:
    """capture: a capture artifact with a person; folder: human data on disk (one of the two);
    scene: an optional scene-checkpoint for the background."""

    capture: str | None = None
    folder: Path | None = None
    scene: str | None = None

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
    if (inputs.capture is None) == (inputs.folder is None):
        raise InputError("train-human: give exactly one of --capture (an artifact) or --data (a folder)")
    if inputs.capture is not None:
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
    return Inputs(capture=capture, folder=inputs.folder, scene=scene), root


def action_key(inputs: Inputs, root: Path, cfg: Config, ctx: RunContext) -> str:
    extra: dict[str, Any] = {"device": "cuda" if str(ctx.device).startswith("cuda") else "cpu"}
    if inputs.folder is not None:
        extra["data_digest"] = _digest_dir(root)
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def load_data(root: Path):
    """``HumanTrainData`` from a human data folder (``nsim.human.data.HumanData``)."""
    import numpy as np

    from nsim.human.data import HumanData
    from nsim.train.human import HumanTrainData

    hd = HumanData.load(root)
    images, masks, backgrounds = hd.read_all()
    return HumanTrainData(images=images, cam_to_world=hd.cam_to_world(), camera=hd.camera(),
                          joint_transforms=hd.joint_transforms(), masks=np.asarray(masks, dtype=bool),
                          skeleton=hd.skeleton, background=backgrounds)


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    from nsim.train.human import export_human, train_human

    store = ctx.store
    inputs, root = resolve(inputs, ctx)
    key = action_key(inputs, root, cfg, ctx)
    if not ctx.force and (hit := store.lookup(key)) is not None:
        return Outputs(human=hit.id, cache_hit=True)
    data = load_data(root)
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
        out.summary.update({"frames": int(data.n_frames), "source": "capture" if inputs.capture else str(root),
                            "background": "scene" if inputs.scene else ("images" if data.background is not None
                                                                        else "frames"),
                            **summary})
        if getattr(result, "resumed_from", None) is not None:
            out.timing["resumed_from_step"] = result.resumed_from
    shutil.rmtree(work, ignore_errors=True)
    return Outputs(human=out.ref, resumed_from=getattr(result, "resumed_from", None))


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    ids = manifest["inputs"]
    if "capture" not in ids:
        raise InputError("this human checkpoint was trained from a folder, which the workspace does not hold: "
                         "rerun nsim train-human --data on it with --force to compare")
    cfg = from_dict(Config, manifest["config"])
    ctx = dataclasses.replace(ctx, force=True)
    return run(Inputs(capture=ids["capture"], scene=ids.get("scene")), cfg, ctx).human
