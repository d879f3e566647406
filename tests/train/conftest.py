"""A tiny capture of the test room, made once per test session through the capture stage."""

from __future__ import annotations

import pytest

from nsim.config import from_dict
from nsim.context import RunContext
from nsim.stages import capture
from nsim.workspace.store import Store

TINY_CAPTURE = {"width": 64, "height": 48, "n_frames": 32, "supersample": 2, "video": False}


@pytest.fixture(scope="session")
def tiny_capture_dir(tmp_path_factory):
    store = Store(tmp_path_factory.mktemp("scene") / "ws")
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    out = capture.run(capture.Inputs(), from_dict(capture.Config, TINY_CAPTURE), ctx)
    return store.get(out.capture).path


@pytest.fixture(scope="session")
def tiny_data(tiny_capture_dir):
    from nsim.train.scene import SceneData

    return SceneData.load(tiny_capture_dir)
