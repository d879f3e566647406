"""What every stage command shares: the config options, the run context, the result line."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import click

from nsim.config import load_config
from nsim.context import RunContext


def run_context(click_ctx: click.Context, force: bool = False) -> RunContext:
    """The root command's run context (workspace opened on first use), with this command's --force."""
    return dataclasses.replace(click_ctx.find_root().obj.get(), force=force)


def _check_tag(click_ctx: click.Context, _param: click.Parameter, value: str | None) -> str | None:
    """--tag is checked against the workspace before any work starts (not after the stage ran)."""
    if value is not None:
        click_ctx.find_root().obj.get().store.check_ref_destination(value)
    return value


def stage_options(stage: str):
    """The options every stage command shares: --preset, --config, --set, --force, --tag."""

    def deco(f):
        f = click.option("--tag", "tag", default=None, callback=_check_tag,
                         help="Also point this ref (e.g. capture/lab) at the result.")(f)
        f = click.option("--force", is_flag=True, help="Recompute even if the run cache has this action.")(f)
        f = click.option(
            "--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Override one config value (repeatable)."
        )(f)
        f = click.option(
            "--config", "config_file", type=click.Path(dir_okay=False), default=None, help="YAML file over the preset."
        )(f)
        f = click.option(
            "--preset", default="default", show_default=True, help=f"Preset from nsim/configs/{stage}/NAME.yaml."
        )(f)
        return f

    return deco


def resolve_config(cls: type, stage: str, preset: str, config_file: str | None, overrides: Sequence[str]) -> Any:
    return load_config(cls, stage=stage, preset=preset, config_file=config_file, overrides=overrides)


def report_artifact(ctx: RunContext, art_id: str, hit: bool, tag: str | None) -> None:
    """Tag the result if asked; the id goes to stdout (for scripts), a status line to stderr."""
    if tag:
        ctx.store.set_ref(tag, art_id)
    art = ctx.store.get(art_id)
    status = "cached" if hit else "published"
    click.echo(f"{art.kind} {art_id} ({status})", err=True)
    click.echo(art_id)
