"""Shared fixtures: a fresh workspace per test, and the CLI runner."""

from __future__ import annotations

import pytest

from nsim.workspace.store import Store


def pytest_collection_modifyitems(config, items):
    import torch

    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device")
    for item in items:
        if "gpu" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def store(tmp_path) -> Store:
    return Store(tmp_path / "ws")


@pytest.fixture
def run_cli(tmp_path, capsys):
    """Run the nsim CLI in-process; returns (exit_code, stdout, stderr)."""
    from nsim.cli import main

    def _run(*args: str, workspace=None):
        ws = str(workspace if workspace is not None else tmp_path / "ws")
        capsys.readouterr()
        code = main(["--workspace", ws, *args])
        out, err = capsys.readouterr()
        return code, out, err

    return _run
