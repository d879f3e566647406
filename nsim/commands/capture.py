"""``nsim capture synth``."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.group("capture")
def command():
    """Captures: the built-in test room with exact ground truth."""


@command.command("synth")
@stage_options("capture")
@click.option("--room", default=None, help="Room preset (robot-lab, common-room, kitchen, living-room, seminar-room).")
@click.option("--camera", default=None, help="Camera: pinhole or fisheye.")
@click.option("--actor", is_flag=True, default=False,
              help="A person walks through the room, filmed by a camera that follows it (masks/, poses.json).")
@click.pass_context
def synth(click_ctx, preset, config_file, overrides, force, tag, room, camera, actor):
    """Generate a handheld capture of the test room with exact ground truth."""
    from nsim.stages import capture

    extra = ([f"room={room}"] if room else []) + ([f"camera={camera}"] if camera else []) + (["actor=true"] if actor else [])
    cfg = resolve_config(capture.Config, "capture", preset, config_file, [*extra, *overrides])
    ctx = run_context(click_ctx, force)
    out = capture.run(capture.Inputs(), cfg, ctx)
    report_artifact(ctx, out.capture, out.cache_hit, tag)
