"""``nsim render``."""

from __future__ import annotations

from pathlib import Path

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("render")
@stage_options("render")
@click.option("--trajectory", default=None, help="A trajectory artifact (nsim simulate): render the robot's sensors per tick "
                                                 "(with --recording: only the people drawn by --humans).")
@click.option("--poses", default=None, help="A poses or capture artifact: render its frames' cameras (for evaluation).")
@click.option("--recording", default=None,
              help="A registration artifact (nsim register-log): render exactly its recording's sensors, frame for frame.")
@click.option("--scene", default=None, help="Scene checkpoint (default: the one the trajectory's scenario names; "
                                            "required with --poses and --recording).")
@click.option("--baked", default=None, help="A baked-scene artifact of the scene (nsim bake), with --set method=baked "
                                            "(without it, method=baked bakes the scene here).")
@click.option("--rig", type=click.Path(dir_okay=False), default=None,
              help="Robot rig file (trajectory mode), e.g. nsim/configs/robots/spot.yaml.")
@click.option("--humans", multiple=True, help="Human checkpoint(s) that draw the trajectory's people (repeatable; with "
                                               "--recording, their clock: people_time_offset_s). Default: the "
                                               "checkpoints the scenario's appearances name, else the default look.")
@click.option("--no-people", is_flag=True, help="Draw none of the trajectory's people (the robot alone in the scene).")
@click.option("--engine", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="Who renders the shards (never changes the result).")
@click.option("--address", default=None, help="--engine ray: a cluster to join (else $RAY_ADDRESS, else a local instance).")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True, help="Ray render workers.")
@click.option("--gpus-per-worker", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="GPUs per Ray worker (0.5 packs two workers on a GPU).")
@click.option("--cpus-per-worker", type=click.FloatRange(min=0.0, min_open=True), default=1.0, show_default=True,
              help="CPUs per Ray worker.")
@click.option("--max-restarts", type=click.IntRange(min=0), default=2, show_default=True,
              help="Ray: times a lost worker is replaced (it reloads the models); its shard is redone.")
@click.option("--rosbag", "rosbag_path", type=click.Path(file_okay=False), default=None,
              help="--trajectory: also export the render as a ROS 2 bag, a new directory (its parent must exist).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, trajectory, poses, recording, scene, baked, rig, humans,
            no_people, engine, address, workers, gpus_per_worker, cpus_per_worker, max_restarts, rosbag_path):
    """Render RGB, depth and LiDAR of a rig along a trajectory (or a poses artifact's cameras, or exactly the
    sensors of a registered robot recording)."""
    from nsim.distributed import check_ray
    from nsim.errors import InputError
    from nsim.rendering.engine import EngineConfig
    from nsim.stages import render

    if sum(x is not None for x in (trajectory if recording is None else None, poses, recording)) != 1:
        raise click.UsageError("give exactly one of --trajectory, --poses or --recording (with --recording, "
                               "--trajectory only supplies the people)")
    # every destination is checked before any work: nothing is rendered or published for a run that cannot finish
    if rosbag_path and (trajectory is None or recording is not None):
        raise click.UsageError(f"--rosbag {rosbag_path}: only a --trajectory render (a robot's run) exports to "
                               f"a ROS 2 bag, not a {'--poses' if poses is not None else '--recording'} render")
    if rosbag_path:
        from nsim.io.rosbag import check_bag_destination

        check_bag_destination(rosbag_path, "--rosbag")
    if rig is not None and not Path(rig).is_file():
        raise InputError(f"--rig {rig}: no such file")
    if engine == "ray":
        check_ray(address)
    cfg = resolve_config(render.Config, "render", preset, config_file, overrides)
    ctx = run_context(click_ctx, force)
    eng = EngineConfig(engine=engine, address=address, workers=workers, num_gpus_per_worker=gpus_per_worker,
                       num_cpus_per_worker=cpus_per_worker, max_restarts=max_restarts)
    inputs = render.Inputs(trajectory=trajectory, poses=poses, scene=scene, rig=Path(rig) if rig else None,
                           humans=tuple(humans), registration=recording, baked=baked,
                           people=not no_people)
    out = render.run(inputs, cfg, ctx, engine=eng)
    if out.shards_reused:
        click.echo(f"resumed: {out.shards_reused} shard(s) were already rendered", err=True)
    report_artifact(ctx, out.render, out.cache_hit, tag)
    if rosbag_path:
        from nsim.rendering.render_output import export_rosbag

        bag = export_rosbag(ctx.store.get(out.render).path, Path(rosbag_path))
        click.echo(f"ROS 2 bag: {bag}", err=True)
