"""``nsim render``: what the arguments decide is refused before any work (issue 44). ``--poses`` with ``--humans``
used to be refused by the shard renderer, after the scene model was loaded (and, with ``method=baked``, after
baking it); an ``image_scale`` that leaves a camera no pixel was a ValueError traceback. The artifacts here are
stand-ins (nothing is rendered); the work -- planning the frames, loading the model -- is replaced by sentinels."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.workspace.store import Store
from tests.stages.sentinel import ReachedWork, block_work


@pytest.fixture
def world(tmp_path):
    """A poses artifact (two 64x16 frames), a scene-checkpoint and a human-checkpoint stand-in."""
    from nsim.geometry.cameras import Camera
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms

    ws = tmp_path / "ws"
    store = Store(ws)
    refs = {}
    for kind in ("poses", "scene-checkpoint", "human-checkpoint"):
        key = store.action_key(f"test_{kind}", 1, {}, {})
        with store.publish(kind=kind, stage=f"test_{kind}", version=1, key=key, config={}, inputs={}) as out:
            if kind == "poses":
                cam = Camera.pinhole_from_fov(64, 16, 60.0)
                write_transforms(out.dir / "transforms.json", TransformsData(frames=[
                    Frame(file_path=f"images/{i}.png", cam_to_world=np.eye(4), camera=cam) for i in range(2)]))
            else:
                (out.dir / "scene.json").write_text("{}")
        refs[kind] = out.ref
    return ws, refs


@pytest.fixture
def no_work(monkeypatch):
    return block_work(monkeypatch, "nsim.rendering.model.load_model", "nsim.rendering.render_plan.bake_here")


def _kinds(ws) -> list[str]:
    return sorted(json.loads(m.read_text())["kind"] for m in (ws / "objects").glob("*/*/manifest.json"))


def _render(ws, capsys, *args):
    capsys.readouterr()
    code = main(["--workspace", str(ws), "--device", "cpu", "render", *args])
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("method", ["proposal", "baked"])
def test_poses_render_with_humans_fails_before_the_model(world, no_work, capsys, method):
    ws, refs = world
    before = _kinds(ws)
    code, err = _render(ws, capsys, "--poses", refs["poses"], "--scene", refs["scene-checkpoint"], "--humans",
                        refs["human-checkpoint"], "--set", f"method={method}")
    assert code == 2 and len(err) == 1, err
    assert "render --poses: --humans" in err[0] and "render them with --trajectory" in err[0]
    assert no_work == [] and _kinds(ws) == before
    assert not list((ws / "tmp").glob("render.*"))  # no shard folder either


def test_image_scale_to_nothing_is_one_line(world, no_work, capsys):
    ws, refs = world
    code, err = _render(ws, capsys, "--poses", refs["poses"], "--scene", refs["scene-checkpoint"], "--set",
                        "image_scale=0.01")
    assert code == 2 and len(err) == 1, err
    assert "image_scale: 0.01 shrinks frame 0's 64x16 image to nothing" in err[0]
    assert no_work == []


def test_poses_render_without_humans_reaches_the_model(world, no_work):
    ws, refs = world
    with pytest.raises(ReachedWork):  # the checks pass: loading the scene model is next
        main(["--workspace", str(ws), "--device", "cpu", "render", "--poses", refs["poses"], "--scene",
              refs["scene-checkpoint"], "--set", "video=false"])
    assert len(no_work) == 1
