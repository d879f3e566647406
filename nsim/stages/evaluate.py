"""``nsim evaluate``: how real the simulation is, as one of the paper's tables (an ``evaluation`` artifact).

``--table`` picks the experiment (``scenes``, ``spot-rgb``, ``spot-depth``, ``lidar``, ``slam``,
``detection``: ``nsim.evaluation.evaluate_tables``); ``--render`` (repeatable) the render artifacts it scores.
The ground truth follows from the renders' mode (``nsim.evaluation.truth``):

* ``poses`` / ``trajectory`` renders of a scene trained on the test room: the room's oracle at the
  rendered poses (``nsim.evaluation.oracle_truth``), or for ``scenes`` the captured frames;
* ``recording`` renders (``nsim render --recording``): the robot's recording they render, frame for
  frame, and its registration into the scene's world (``nsim.evaluation.recording_truth``).

This module resolves the inputs (``evaluation_inputs``: the loaded renders, the workspace as a read-only
``ArtifactReader``, device and seed, for ``nsim.evaluation.inputs.EvaluationInputs``), checks the run cache,
computes the table (every input is read and checked before anything is published) and publishes the artifact
(layout: ``nsim.evaluation.write``).

Bad input is one line (``InputError``): a render of the wrong mode for the table, frames missing
or out of range (frame counts that do not match), images or depth maps of different sizes, NaN
depth at pixels where the ground truth is valid, an empty person mask, a trajectory with no
timestamps in common with the frames, no test-room ground truth where the table needs it, a
recording or registration a recording-mode render names that is not in the workspace, or a
rendered frame its recording does not have.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from nsim.context import RunContext
from nsim.errors import InputError
from nsim.evaluation.evaluate_config import TABLES, Config, DetectionConfig, SlamConfig
from nsim.evaluation.inputs import EvaluationInputs
from nsim.stages.runner import cached, device_kind, rerun

STAGE = "evaluate"
VERSION = 3  # 2: numbers rounded (nsim.io.canonical); 3: spot-depth notes no-return px per camera

__all__ = ["STAGE", "TABLES", "VERSION", "Config", "DetectionConfig", "Inputs", "Outputs", "SlamConfig",
           "action_key", "evaluation_inputs", "load_table", "rebuild", "resolve_inputs", "run"]


@dataclasses.dataclass(frozen=True)
class Inputs:
    """renders: render artifact ids or refs (one per environment for ``scenes``); onnx: a detector's
    weights (``detection.detector: onnx``); coco_sim / coco_real: detections on the simulated and
    real frames, keyed by ``<camera>/rgb/NNNNNN.png`` (``camera/<camera>/NNNNNN.png`` for a
    recording-mode render) (``detection.detector: coco``)."""

    renders: tuple[str, ...]
    onnx: Path | None = None
    coco_sim: Path | None = None
    coco_real: Path | None = None

    def ids(self) -> dict[str, str]:
        return {f"render{k}": r for k, r in enumerate(self.renders)}

    def files(self) -> dict[str, Path]:
        return {n: Path(p) for n in ("onnx", "coco_sim", "coco_real") if (p := getattr(self, n)) is not None}


@dataclasses.dataclass(frozen=True)
class Outputs:
    evaluation: str
    cache_hit: bool = False


def _file_digests(inputs: Inputs) -> dict[str, str]:
    from nsim.workspace.store import sha256_file

    out = {}
    for name, path in inputs.files().items():
        if not path.is_file():
            raise InputError(f"--{name.replace('_', '-')} {path}: no such file")
        out[name] = sha256_file(path)[0]
    return out


def resolve_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    if not inputs.renders:
        raise InputError("evaluate: give at least one --render")
    ids = tuple(ctx.store.resolve(r, kind="render") for r in inputs.renders)
    if len(set(ids)) != len(ids):
        raise InputError("evaluate: the same render is given twice")
    return dataclasses.replace(inputs, renders=ids)


IMAGE_TABLES = ("scenes", "spot-rgb")  # score images: LPIPS, the one computation that runs on a device


def _runs_lpips(cfg: Config) -> bool:
    return cfg.lpips_net != "none" and cfg.table in IMAGE_TABLES


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    extra: dict[str, Any] = {"files": _file_digests(inputs)}
    if _runs_lpips(cfg):
        extra["device"] = device_kind(ctx.device)
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def evaluation_inputs(inputs: Inputs, cfg: Config, ctx: RunContext) -> EvaluationInputs:
    """What the evaluation reads (``inputs`` resolved): the renders loaded, the workspace to read the artifacts
    they name, the device (resolved for the image tables only; else ``cpu``) and the seed."""
    from nsim.evaluation.renders import load_render

    return EvaluationInputs(renders=tuple(load_render(ctx.store, r) for r in inputs.renders), artifacts=ctx.store,
                            device=ctx.device if cfg.table in IMAGE_TABLES else "cpu", seed=ctx.seed, onnx=inputs.onnx,
                            coco_sim=inputs.coco_sim, coco_real=inputs.coco_real)


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    """Compute ``cfg.table`` over the renders (or find it in the run cache)."""
    from nsim.evaluation.evaluate_tables import Evaluation, compute
    from nsim.evaluation.write import write_result

    inputs = resolve_inputs(inputs, ctx)
    if cfg.depth_max_m <= cfg.depth_min_m:
        raise InputError(f"depth_max_m ({cfg.depth_max_m:g}) must be greater than depth_min_m ({cfg.depth_min_m:g})")
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(evaluation=hit, cache_hit=True)
    ev = Evaluation(evaluation_inputs(inputs, cfg, ctx), cfg)
    result = compute(ev)  # every input is read and checked before publishing
    with ctx.store.publish(kind="evaluation", stage=STAGE, version=VERSION, key=key, config=cfg,
                           inputs=inputs.ids(), seed=ctx.seed) as out:
        write_result(out.dir, cfg.table, inputs.renders, ev, result)
        out.summary.update({"table": cfg.table, "rows": len(result.table.rows), "records": len(result.records),
                            "files": {k: str(v) for k, v in inputs.files().items()},
                            "ground_truth": ev.truth.source})
    return Outputs(evaluation=out.ref)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    ids = manifest["inputs"]
    files = manifest.get("summary", {}).get("files", {})
    renders = tuple(ids[f"render{k}"] for k in range(len(ids)))
    inputs = Inputs(renders=renders, **{k: Path(v) for k, v in files.items()})
    return rerun(run, inputs, Config, manifest, ctx).evaluation


def load_table(ctx: RunContext, evaluation: str):
    """The ``nsim.metrics.results_table.Table`` of an evaluation artifact."""
    from nsim.metrics.results_table import Table

    art = ctx.store.get(ctx.store.resolve(evaluation, kind="evaluation"))
    meta = json.loads(art.file("evaluation.json").read_text())
    return Table.from_json(art.file(f"{meta['table']}.json").read_text())
