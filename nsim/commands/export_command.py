"""``nsim export``."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("export")
@stage_options("export")
@click.argument("scene")
@click.pass_context
def command(click_ctx, preset, config_file, overrides, force, tag, scene):
    """Export SCENE (a scene-checkpoint id, prefix or ref) as a point cloud (PLY), a mesh (PLY, GLB) and a
    preview, in the scene's world frame (metres, z up): an export artifact."""
    from nsim.stages import export

    cfg = resolve_config(export.Config, "export", preset, config_file, overrides)
    ctx = run_context(click_ctx, force)
    out = export.run(export.Inputs(scene=scene), cfg, ctx)
    report_artifact(ctx, out.export, out.cache_hit, tag)
