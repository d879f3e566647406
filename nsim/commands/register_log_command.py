"""``nsim register-log``."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("register-log")
@stage_options("register_log")
@click.argument("recording")
@click.option("--poses", required=True, help="The scene: a poses artifact with a sparse model (nsim reconstruct).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, recording, poses):
    """Place RECORDING (nsim import-log) in the scene of --poses: localise its camera frames in the
    scene's sparse model, register the odometry to them (odometry frame, clock offset, drift) and
    write a registration artifact with the body's trajectory in the scene's world."""
    from nsim.stages import register_log

    cfg = resolve_config(register_log.Config, "register_log", preset, config_file, overrides)
    ctx = run_context(click_ctx, force)
    out = register_log.run(register_log.Inputs(recording=recording, poses=poses), cfg, ctx)
    report_artifact(ctx, out.registration, out.cache_hit, tag)
