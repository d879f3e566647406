"""``nsim import-log``."""

from __future__ import annotations

from pathlib import Path

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("import-log")
@stage_options("import_log")
@click.argument("log", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--selection", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="YAML choosing a bag's topics (cameras, depth, lidar, odometry, pose, tf, body_frame, odom_frame; a "
                   "camera's distortion model); "
                   "default: by message type. Not for a recording folder.")
@click.option("--trajectory", "trajectory_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="TUM file of the body's poses in the odometry frame, stamps in seconds on the bag's clock: the "
                   "trajectory instead of the bag's tf / odometry / pose topics (a RealSense bag has none).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, log, selection, trajectory_file):
    """Import a robot's recording: LOG is a ROS 2 bag directory (sqlite3 or mcap), ROS 1 .bag file(s),
    or a recording folder (a directory without metadata.yaml: trajectory.tum, rig.yaml or rig.urdf,
    cameras/<name>/ with camera_info.yaml, optional depth/<name>/ and lidar/<name>/; see
    nsim.io.robot_folder). Writes a recording artifact: every camera, depth and LiDAR stream with
    stamps, intrinsics and extrinsics, and the body's trajectory in the odometry frame. A log with a
    trajectory and no sensor streams is a trajectory-only recording (for nsim simulate)."""
    from nsim.stages import import_log

    cfg = resolve_config(import_log.Config, "import_log", preset, config_file, overrides)
    ctx = run_context(click_ctx, force)
    out = import_log.run(import_log.Inputs(log=tuple(log), selection=selection, trajectory=trajectory_file), cfg, ctx)
    report_artifact(ctx, out.recording, out.cache_hit, tag)
