"""``nsim train-scene``."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("train-scene")
@stage_options("train_scene")
@click.option("--poses", "poses", default="poses/latest", show_default=True,
              help="A poses artifact (nsim reconstruct) or a capture artifact (ground-truth poses): id, prefix or ref.")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Training steps (sets optim.steps=).")
@click.option("--recording", default=None,
              help="A registration artifact (nsim register-log, against --poses): its recording's colour camera "
                   "frames also train, with their camera models, at their registered poses.")
@click.option("--recording-share", "share", type=float, default=None,
              help="With --recording: the fraction of the training views that are robot frames.")
@click.option("--recording-holdout-every", "holdout_every", type=int, default=None,
              help="With --recording: robot frame j of each camera never trains when j % K == 0.")
@click.option("--recording-camera", "cameras", multiple=True,
              help="With --recording: a camera whose frames may train (repeatable; none: all). Unset options: "
                   "nsim.train.scene_data.RecordingConfig's defaults.")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, poses, steps, recording, share, holdout_every,
            cameras):
    """Train the scene NeRF on a poses artifact: a scene-checkpoint artifact (resumes if interrupted)."""
    from nsim.config import from_dict
    from nsim.errors import ConfigError
    from nsim.stages import train_scene
    from nsim.train.scene_data import RecordingConfig

    given = {k: v for k, v in (("share", share), ("holdout_every", holdout_every), ("cameras", list(cameras)))
             if v not in (None, [])}
    if given and recording is None:
        raise click.UsageError(f"--recording-{next(iter(given)).replace('_', '-')} needs --recording")
    try:
        options = from_dict(RecordingConfig, given)
    except ConfigError as e:  # "share: expected ..." -> "--recording-share: expected ..."
        field, why = str(e).split(":", 1)
        raise ConfigError(f"--recording-{field.replace('_', '-')}:{why}") from None
    extra = [f"optim.steps={steps}"] if steps is not None else []
    cfg = resolve_config(train_scene.Config, "train_scene", preset, config_file, [*extra, *overrides])
    ctx = run_context(click_ctx, force)
    out = train_scene.run(train_scene.Inputs(poses=poses, registration=recording, recording=options), cfg, ctx)
    if out.resumed_from is not None:
        click.echo(f"resumed from the checkpoint of step {out.resumed_from}", err=True)
    report_artifact(ctx, out.scene, out.cache_hit, tag)
