"""``nsim capture synth`` and ``nsim capture robot-log``."""

from __future__ import annotations

from pathlib import Path

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.group("capture")
def command():
    """Captures of the built-in test room with exact ground truth: a handheld video, a robot's log."""


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


@command.command("robot-log")
@click.option("--preset", default="default", show_default=True, help="Preset from nsim/configs/robot_log/NAME.yaml.")
@click.option("--config", "config_file", type=click.Path(dir_okay=False), default=None, help="YAML file over the preset.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Override one config value (repeatable).")
@click.argument("trajectory")
@click.option("--rig", "rig_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="The robot's sensors (YAML or URDF rig); default: the presets' robots/spot.yaml.")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="The bag to write (a new directory; a *.bag file with storage=ros1); <out>.truth.json beside it.")
@click.pass_context
def robot_log(click_ctx, preset, config_file, overrides, trajectory, rig_path, out):
    """A realistic robot log of TRAJECTORY (a simulated run in a test room): the rig's sensors rendered by
    the room's oracle with real-world faults (noise, auto-exposure, JPEG, depth holes, LiDAR dropout,
    odometry drift, a camera clock offset, an odometry frame offset), written as a ROS bag."""
    from nsim.config import configs_dir
    from nsim.stages import capture

    cfg = resolve_config(capture.RobotLogConfig, "robot_log", preset, config_file, overrides)
    rig_path = rig_path if rig_path is not None else configs_dir() / "robots" / "spot.yaml"
    ctx = run_context(click_ctx)
    truth = capture.robot_log(trajectory, rig_path, out, cfg, ctx)
    click.echo(f"robot log: {out} ({len(truth['stamps_ns'])} ticks, odometry frame offset and clock offset in "
               f"{out}.truth.json)", err=True)
    click.echo(str(out))
