"""Shared fixtures: a fresh workspace per test, and the CLI runner."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from nsim.workspace.store import Store


def pytest_configure(config):
    """Under pytest-xdist (``make test``: one worker per core) each worker's torch gets its share of the cores,
    so that two workers on two cores do not run four threads."""
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if workers:
        import torch

        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        torch.set_num_threads(max(1, cores // max(1, int(workers))))


def pytest_collection_modifyitems(config, items):
    # files holding slow tests first, the whole-pipeline ones (tests/test_*.py: demo, paper) before the rest:
    # pytest-xdist hands out files in this order, so the longest start at once instead of running alone at the end
    slow_files = {item.path for item in items if "slow" in item.keywords}
    root = Path(__file__).resolve().parent
    items.sort(key=lambda item: (item.path not in slow_files, item.path.parent != root))

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
