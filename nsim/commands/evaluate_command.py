"""``nsim evaluate``."""

from __future__ import annotations

from pathlib import Path

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("evaluate")
@stage_options("evaluate")
@click.option("--table", required=True, metavar="NAME",
              help="scenes | spot-rgb | spot-depth | lidar | slam | detection (the paper's tables; lidar: "
                   "recording-mode renders).")
@click.option("--render", "renders", multiple=True, required=True,
              help="A render artifact to score (repeatable: e.g. one poses-mode render per environment for scenes). "
                   "Its mode picks the ground truth: the test room's oracle, or for a recording-mode render "
                   "(nsim render --recording) the robot's recording it renders.")
@click.option("--onnx", type=click.Path(dir_okay=False), default=None,
              help="detection.detector=onnx: a YOLO-style ONNX model's weights.")
@click.option("--coco-sim", type=click.Path(dir_okay=False), default=None,
              help="detection.detector=coco: detections on the simulated frames (COCO JSON).")
@click.option("--coco-real", type=click.Path(dir_okay=False), default=None,
              help="detection.detector=coco: detections on the real frames (COCO JSON).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, table, renders, onnx, coco_sim, coco_real):
    """Score renders against ground truth (the test room's oracle or a robot's recording) and write one of the
    paper's tables (an evaluation artifact)."""
    from nsim.stages import evaluate

    cfg = resolve_config(evaluate.Config, "evaluate", preset, config_file, [*overrides, f"table={table}"])
    ctx = run_context(click_ctx, force)
    inputs = evaluate.Inputs(renders=tuple(renders), onnx=Path(onnx) if onnx else None,
                             coco_sim=Path(coco_sim) if coco_sim else None,
                             coco_real=Path(coco_real) if coco_real else None)
    out = evaluate.run(inputs, cfg, ctx)
    click.echo(evaluate.load_table(ctx, out.evaluation).to_text(), err=True)
    report_artifact(ctx, out.evaluation, out.cache_hit, tag)
