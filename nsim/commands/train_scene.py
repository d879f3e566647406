"""``nsim train-scene``."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("train-scene")
@stage_options("train_scene")
@click.option("--poses", "poses", default="poses/latest", show_default=True,
              help="A poses artifact (nsim reconstruct) or a capture artifact (ground-truth poses): id, prefix or ref.")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Training steps (sets optim.steps=).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, poses, steps):
    """Train the scene NeRF on a poses artifact: a scene-checkpoint artifact (resumes if interrupted)."""
    from nsim.stages import train_scene

    extra = [f"optim.steps={steps}"] if steps is not None else []
    cfg = resolve_config(train_scene.Config, "train_scene", preset, config_file, [*extra, *overrides])
    ctx = run_context(click_ctx, force)
    out = train_scene.run(train_scene.Inputs(poses=poses), cfg, ctx)
    if out.resumed_from is not None:
        click.echo(f"resumed from the checkpoint of step {out.resumed_from}", err=True)
    report_artifact(ctx, out.scene, out.cache_hit, tag)
