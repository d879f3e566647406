"""The stages' shared plumbing (nsim.stages.runner): the run cache, the device in the key, rerun, the scene input."""

from __future__ import annotations

import dataclasses

import pytest

from nsim.config import param
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.stages.runner import SceneInputs, cached, device_kind, rerun, resolve_scene


@dataclasses.dataclass(frozen=True)
class Cfg:
    n: int = param(1, ge=0)


def _publish(store, kind: str, files: dict[str, bytes], key: str | None = None, ref: str | None = None) -> str:
    key = key or store.action_key("toy", 1, Cfg(), {}, seed=0, extra={"kind": kind, "files": sorted(files)})
    with store.publish(kind=kind, stage="toy", version=1, key=key, config=Cfg(), seed=0, ref=ref) as out:
        for name, data in files.items():
            (out.dir / name).write_bytes(data)
    return out.artifact.id


def test_cached_finds_the_key_unless_forced(store):
    ctx = RunContext(store=store)
    key = store.action_key("toy", 1, Cfg(), {}, seed=0)
    assert cached(ctx, key) is None
    art_id = _publish(store, "capture", {"a.txt": b"x"}, key=key)
    assert cached(ctx, key) == art_id
    assert cached(dataclasses.replace(ctx, force=True), key) is None


@pytest.mark.parametrize(("device", "kind"), [("cpu", "cpu"), ("cuda", "cuda"), ("cuda:1", "cuda"), ("mps", "cpu")])
def test_device_kind(device, kind):
    assert device_kind(device) == kind


def test_rerun_forces_and_reads_the_manifests_config(store):
    seen = []

    def run(inputs, cfg, ctx):
        seen.append((inputs, cfg, ctx.force))
        return "out"

    ctx = RunContext(store=store)
    assert rerun(run, SceneInputs("s"), Cfg, {"config": {"n": 7}}, ctx) == "out"
    assert seen == [(SceneInputs("s"), Cfg(n=7), True)]
    assert not ctx.force  # the caller's context is not changed
    with pytest.raises(Exception, match="n"):
        rerun(run, SceneInputs("s"), Cfg, {"config": {"n": -1}}, ctx)


def test_resolve_scene_checks_kind_and_files(store):
    ctx = RunContext(store=store)
    scene = _publish(store, "scene-checkpoint", {"occupancy_grid.npy": b"g"}, ref="scene/a")
    bare = _publish(store, "scene-checkpoint", {"model.pt": b"m"}, ref="scene/b")
    other = _publish(store, "capture", {"a.txt": b"x"}, ref="capture/c")
    assert resolve_scene("scene/a", ctx, "bake", files=("occupancy_grid.npy",)) == scene
    assert resolve_scene(scene[:12], ctx, "export") == scene
    assert resolve_scene("scene/b", ctx, "export") == bare
    with pytest.raises(InputError, match=r"bake scene/b: scene \w+ has no occupancy_grid.npy to bake over"):
        resolve_scene("scene/b", ctx, "bake", files=("occupancy_grid.npy",))
    with pytest.raises(InputError, match="export capture/c: a capture artifact; export needs a scene-checkpoint"):
        resolve_scene("capture/c", ctx, "export")
    assert other and SceneInputs(scene).ids() == {"scene": scene}
