"""``nsim export``: what the scene checkpoint's files decide is checked before the model loads or any ray is cast
(issue 44): ``mesh.region=occupied`` over an occupancy grid with no occupied cell used to be refused after the
training views were rendered; a scene without its occupancy grid, after the model was loaded. The scene is a
stand-in; loading the model and casting the views are replaced by sentinels."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.workspace.store import Store
from tests.stages.sentinel import ReachedWork, block_work


@pytest.fixture
def no_work(monkeypatch):
    return block_work(monkeypatch, "nsim.rendering.load_model", "nsim.export.extract.cast_views")


def _scene(store: Store, name: str, occupied: bool | None) -> str:
    """A scene stand-in trained on a two-frame poses artifact; its occupancy grid all ``occupied`` (None: none)."""
    from nsim.geometry.cameras import Camera
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms

    cam = Camera.pinhole_from_fov(16, 12, 60.0)
    key = store.action_key("test_poses", 1, {}, {})
    with store.publish(kind="poses", stage="test_poses", version=1, key=key, config={}, inputs={}) as poses:
        write_transforms(poses.dir / "transforms.json", TransformsData(frames=[
            Frame(file_path=f"images/{i}.png", cam_to_world=np.eye(4), camera=cam) for i in range(2)]))
    inputs = {"poses": poses.ref}
    key = store.action_key(f"test_{name}", 1, {}, inputs)
    with store.publish(kind="scene-checkpoint", stage="test_scene", version=1, key=key, config={},
                       inputs=inputs) as out:
        (out.dir / "scene.json").write_text(json.dumps({"train_images": [0, 1]}))
        if occupied is not None:
            np.save(out.dir / "occupancy_grid.npy", np.full((2, 2, 2), occupied))
            (out.dir / "occupancy_grid.json").write_text(json.dumps({"aabb_m": [[0, 0, 0], [1, 1, 1]],
                                                                     "density_threshold": 1.0}))
    return out.ref


def _export(store: Store, capsys, scene: str, *sets: str):
    args = ["--workspace", str(store.root), "--device", "cpu", "export", scene]
    for kv in sets:
        args += ["--set", kv]
    capsys.readouterr()
    code = main(args)
    return code, capsys.readouterr().err.strip().splitlines()


def _kinds(store: Store) -> list[str]:
    return sorted(json.loads(m.read_text())["kind"] for m in (store.root / "objects").glob("*/*/manifest.json"))


def test_occupied_region_of_an_empty_grid_fails_before_any_work(tmp_path, no_work, capsys):
    store = Store(tmp_path / "ws")
    scene = _scene(store, "empty", occupied=False)
    before = _kinds(store)
    code, err = _export(store, capsys, scene, "mesh.region=occupied")
    assert code == 2 and len(err) == 1, err
    assert "mesh: the scene's occupancy grid has no occupied cell" in err[0]
    assert no_work == [] and _kinds(store) == before


def test_scene_without_occupancy_grid_fails_before_the_model(tmp_path, no_work, capsys):
    store = Store(tmp_path / "ws")
    scene = _scene(store, "no_grid", occupied=None)
    code, err = _export(store, capsys, scene)
    assert code == 2 and len(err) == 1, err
    assert "has no occupancy_grid.npy to export over" in err[0]
    assert no_work == []


@pytest.mark.parametrize("occupied, region", [(True, "occupied"), (False, "seen")])
def test_good_scene_reaches_the_model(tmp_path, no_work, occupied, region):
    store = Store(tmp_path / "ws")
    scene = _scene(store, f"good_{region}", occupied=occupied)
    with pytest.raises(ReachedWork):
        main(["--workspace", str(store.root), "--device", "cpu", "export", scene, "--set", f"mesh.region={region}"])
    assert len(no_work) == 1
