"""``nsim bake``."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("bake")
@stage_options("bake")
@click.argument("scene")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, scene):
    """Bake SCENE (a scene-checkpoint id, prefix or ref) for fast sensors (nsim render --set method=baked --baked
    ID): a sparse voxel grid and, with the default preset, a mesh fitted to the NeRF and textured from the training
    images (one ray cast and one texture lookup a ray): a baked-scene artifact."""
    from nsim.stages import bake

    cfg = resolve_config(bake.Config, "bake", preset, config_file, overrides)
    ctx = run_context(click_ctx, force)
    out = bake.run(bake.Inputs(scene=scene), cfg, ctx)
    if out.parts_reused:
        click.echo(f"resumed: {out.parts_reused} part(s) of the lattice (and of the NeRF's depths on the "
                   "training rays) were already evaluated", err=True)
    report_artifact(ctx, out.baked, out.cache_hit, tag)
