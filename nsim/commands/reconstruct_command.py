"""``nsim reconstruct``."""

from __future__ import annotations

from pathlib import Path

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("reconstruct")
@click.argument("source", required=False)
@stage_options("reconstruct")
@click.option("--import", "import_file", type=click.Path(dir_okay=False), default=None,
              help="Skip SfM: import poses from a nerfstudio/PolyCam/Record3D transforms.json.")
@click.option("--images-root", type=click.Path(file_okay=False), default=None,
              help="With --import: the folder the images must lie in (default: the transforms.json's folder).")
@click.option("--skip-missing", is_flag=True,
              help="With --import: skip frames whose image is missing (and drop missing depth, mask, ply files).")
@click.option("--metric", is_flag=True,
              help="With --import: the poses are in metres (PolyCam, Record3D); without a scale source "
                   "an import's scale is arbitrary.")
@click.option("--reference", type=click.Path(), default=None,
              help="Metric poses (transforms.json, or a TUM trajectory such as odometry) for a Sim(3) fit.")
@click.option("--reference-poses", is_flag=True,
              help="With --reference and --intrinsics: the reference's poses are the cameras' (motion capture): "
                   "no SfM mapping, the features are only triangulated there (a camera turning in place).")
@click.option("--known-distance", type=float, nargs=7, default=None, metavar="X1 Y1 Z1 X2 Y2 Z2 D",
              help="Two points of an unscaled run and their distance in metres.")
@click.option("--camera-height", type=float, default=None, help="Mean camera height above the floor (m).")
@click.option("--intrinsics", type=click.Path(dir_okay=False), default=None,
              help="Known camera: transforms.json, or YAML/JSON with model, width, height, fx, fy, cx, cy, dist.")
@click.option("--frames", type=int, default=None, help="About this many frames from a video (sets frames=).")
@click.option("--camera-model", default=None, help="SIMPLE_RADIAL, OPENCV, OPENCV_FISHEYE or PINHOLE.")
@click.pass_context
def command(click_ctx, source, preset, config_file, overrides, force, tag, import_file, reference, known_distance,
            camera_height, intrinsics, frames, camera_model, images_root, skip_missing, metric, reference_poses):
    """Camera poses from a video, a folder of images or a capture artifact (pycolmap SfM, metric scale)."""
    from nsim.errors import InputError
    from nsim.stages import reconstruct

    extra = ([f"frames={frames}"] if frames is not None else []) + (
        [f"camera_model={camera_model}"] if camera_model else [])
    cfg = resolve_config(reconstruct.Config, "reconstruct", preset, config_file, [*extra, *overrides])
    ctx = run_context(click_ctx, force)
    src_path = capture = None
    if source is not None:
        if Path(source).exists():
            src_path = Path(source)
        else:
            try:
                capture = ctx.store.resolve(source, kind="capture")
            except InputError:
                raise InputError(f"{source}: no such file, folder or capture artifact") from None
    elif import_file is None:
        raise InputError("reconstruct: give a video, an image folder or a capture (or --import transforms.json)")
    inputs = reconstruct.Inputs(
        source=src_path, capture=capture, reference=Path(reference) if reference else None,
        intrinsics=Path(intrinsics) if intrinsics else None, known_distance=tuple(known_distance) if known_distance else None,
        camera_height_m=camera_height, import_transforms=Path(import_file) if import_file else None,
        images_root=Path(images_root) if images_root else None, skip_missing=skip_missing, metric=metric,
        reference_poses=reference_poses,
    )
    out = reconstruct.run(inputs, cfg, ctx)
    frames_line = ctx.store.get(out.poses).manifest.get("summary", {}).get("video_frames")
    if frames_line:  # a video: how many of its frames were sampled, used, blurred, duplicates
        click.echo(frames_line, err=True)
    report_artifact(ctx, out.poses, out.cache_hit, tag)
