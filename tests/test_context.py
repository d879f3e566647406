"""The run context is frozen: a different setting is a new context, never a change to a shared one."""

from __future__ import annotations

import dataclasses

import click
import pytest

import nsim.context
from nsim.commands.common import run_context
from nsim.context import RunContext


def test_context_is_frozen_and_replace_leaves_the_original(store):
    ctx = RunContext(store=store, device_spec="cpu", seed=3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ctx.force = True
    forced = dataclasses.replace(ctx, force=True)
    assert forced.force and not ctx.force
    assert (forced.store, forced.device_spec, forced.seed) == (store, "cpu", 3)


def test_device_is_resolved_once_per_context(store, monkeypatch):
    calls = []

    def fake_resolve(spec: str) -> str:
        calls.append(spec)
        return "cpu"

    monkeypatch.setattr(nsim.context, "resolve_device", fake_resolve)
    ctx = RunContext(store=store, device_spec="auto")
    assert calls == []  # CPU-only commands never resolve (and never import torch)
    assert ctx.device == "cpu" and ctx.device == "cpu"
    assert calls == ["auto"]


def test_a_command_forcing_leaves_the_root_context_unforced(tmp_path):
    from nsim.cli import _LazyContext, cli

    root = click.Context(cli, obj=_LazyContext(tmp_path / "ws", "cpu", 7, False))
    forced = run_context(root, force=True)
    shared = root.obj.get()
    assert forced.force and not shared.force
    assert forced.store is shared.store and forced.seed == 7
    assert not run_context(root).force
