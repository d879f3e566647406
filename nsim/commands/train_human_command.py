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
@click.option("--video", type=click.Path(dir_okay=False), default=None,
              help="A video of one person (static or handheld camera): masks and poses are found "
                   "automatically (needs nsim[people]).")
@click.option("--images", type=click.Path(file_okay=False), default=None,
              help="A folder of frames (jpg/png, in name order) of one person, as --video.")
@click.option("--fov", "fov_deg", type=click.FloatRange(10.0, 170.0), default=None,
              help="--video/--images: the camera's horizontal field of view in degrees (default 65).")
@click.option("--camera-height", "camera_height_m", type=click.FloatRange(0.1, 20.0), default=None,
              help="--video/--images: the camera's height above the floor in metres (sets the scale).")
@click.option("--person-height", "person_height_m", type=click.FloatRange(0.5, 2.5), default=None,
              help="--video/--images: the person's height in metres (sets the scale instead).")
@click.option("--camera", "camera_mode", type=click.Choice(["auto", "static", "moving"]), default="auto",
              show_default=True, help="--video/--images: the camera; auto: moving when the background moves or "
                                      "the person walks on the spot in the image (a camera following them); its "
                                      "path by SfM with the person masked out.")
@click.option("--fps", "images_fps", type=click.FloatRange(0.1, 240.0, min_open=False), default=30.0,
              show_default=True, help="--images: the frames' rate.")
@click.option("--mask-threshold", type=click.FloatRange(0.0, 1.0, min_open=True, max_open=True), default=None,
              help="--video/--images: the person's mask probability at which a pixel is trained as the person "
                   "(default 0.7; nsim.human.landmarks.TRAINING_MASK_THRESHOLD).")
@click.option("--scene", default=None, help="Scene checkpoint to composite over while training (optional).")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Training steps (sets optim.steps=).")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, capture, folder, video, images, fov_deg,
            camera_height_m, person_height_m, camera_mode, images_fps, mask_threshold, scene, steps):
    """Train a person's NeRF, driven by its skeleton: a human-checkpoint artifact."""
    from nsim.human.person_video import PersonVideoConfig
    from nsim.stages import train_human
    from nsim.train.human_data_video import PersonSource

    if sum(x is not None for x in (capture, folder, video, images)) != 1:
        raise click.UsageError("give exactly one of --capture REF, --data FOLDER, --video FILE or --images FOLDER")
    if camera_height_m is not None and person_height_m is not None:
        raise click.UsageError("give --camera-height or --person-height, not both")
    person = None
    if video is not None or images is not None:
        cfg_person = PersonVideoConfig(hfov_deg=fov_deg, camera_height_m=camera_height_m,
                                       body_height_m=person_height_m, camera=camera_mode,
                                       **({} if mask_threshold is None else {"mask_threshold": mask_threshold}))
        person = PersonSource(Path(video or images), kind="video" if video else "images", images_fps=images_fps,
                              person=cfg_person)
    elif any(x is not None for x in (fov_deg, camera_height_m, person_height_m, mask_threshold)):
        raise click.UsageError("--fov, --camera-height, --person-height and --mask-threshold go with --video or "
                               "--images")
    extra = [f"optim.steps={steps}"] if steps is not None else []
    cfg = resolve_config(train_human.Config, "train_human", preset, config_file, [*extra, *overrides])
    ctx = run_context(click_ctx, force)
    out = train_human.run(train_human.Inputs(capture=capture, folder=Path(folder) if folder else None, scene=scene,
                                             person=person), cfg, ctx)
    report_artifact(ctx, out.human, out.cache_hit, tag)
