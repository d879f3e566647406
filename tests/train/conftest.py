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


class _RunsCode:
    """Unpickling this calls ``exec`` of ``code``: what a planted resume checkpoint would do."""

    def __init__(self, code: str):
        self.code = code

    def __reduce__(self):
        import builtins

        return builtins.exec, (self.code,)


BAD_CHECKPOINTS = ("pickle_exec", "torch_save_exec", "truncated", "garbage")


@pytest.fixture
def plant_checkpoint():
    """``plant(path, kind, marker)`` writes a bad checkpoint of ``kind`` (one of ``BAD_CHECKPOINTS``)
    at ``path``; the two ``*_exec`` kinds create the file ``marker`` if they are ever unpickled."""
    import pickle

    import torch

    def plant(path, kind, marker):
        path.parent.mkdir(parents=True, exist_ok=True)
        payload = {"format": 1, "step": 3, "model": _RunsCode(f"open({str(marker)!r}, 'w').write('pwned')")}
        if kind == "pickle_exec":
            path.write_bytes(pickle.dumps(payload))
        elif kind == "torch_save_exec":
            torch.save(payload, path)
        elif kind == "truncated":
            torch.save({"format": 1, "step": 3, "model": {"w": torch.zeros(1000)}}, path)
            path.write_bytes(path.read_bytes()[:300])
        elif kind == "garbage":
            path.write_bytes(b"not a checkpoint\x00" * 10)
        else:
            raise ValueError(kind)
        return path

    return plant
