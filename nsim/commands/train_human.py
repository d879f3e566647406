"""``nsim train-human``."""

from __future__ import annotations

from pathlib import Path

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("train-human")
@stage_options("train_human")
@click.option("--capture", default=None, help="A capture artifact with a person (nsim capture synth --actor).")
@click.option("--data", "folder", type=click.Path(file_okay=False), default=None,
              help="A folder of frames, skeleton poses and masks (docs/human_data.md).")
@click.option("--scene", default=None, help="Scene checkpoint to composite over while training (optional).")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Training steps (sets optim.steps=).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, capture, folder, scene, steps):
    """Train a person's NeRF, driven by its skeleton: a human-checkpoint artifact."""
    from nsim.stages import train_human

    if (capture is None) == (folder is None):
        raise click.UsageError("give exactly one of --capture REF or --data FOLDER")
    extra = [f"optim.steps={steps}"] if steps is not None else []
    cfg = resolve_config(train_human.Config, "train_human", preset, config_file, [*extra, *overrides])
    ctx = run_context(click_ctx, force)
    out = train_human.run(train_human.Inputs(capture=capture, folder=Path(folder) if folder else None, scene=scene),
                          cfg, ctx)
    report_artifact(ctx, out.human, out.cache_hit, tag)
