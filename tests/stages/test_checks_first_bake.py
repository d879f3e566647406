"""``nsim bake``: what scene.json and the poses artifact decide is checked before the scene model loads (issue 44:
a scene that names no training cameras, which the default preset's surface needs, used to be refused after
``load_model``). The scene here is a stand-in; loading the model is replaced by a sentinel."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.workspace.store import Store


class ReachedModel(Exception):
    pass


@pytest.fixture
def no_model(monkeypatch):
    calls = []

    def load_model(*args, **kwargs):
        calls.append(args)
        raise ReachedModel

    monkeypatch.setattr("nsim.rendering.load_model", load_model)
    return calls


def _scene(store: Store, name: str, scene_json: dict, poses: str | None = None) -> str:
    inputs = {"poses": poses} if poses else {}
    key = store.action_key(f"test_{name}", 1, {}, inputs)
    with store.publish(kind="scene-checkpoint", stage="test_scene", version=1, key=key, config={},
                       inputs=inputs) as out:
        (out.dir / "scene.json").write_text(json.dumps(scene_json))
        np.save(out.dir / "occupancy_grid.npy", np.ones((2, 2, 2), bool))
        (out.dir / "occupancy_grid.json").write_text(json.dumps({"aabb_m": [[0, 0, 0], [1, 1, 1]],
                                                                 "density_threshold": 1.0}))
    return out.ref


def _poses(store: Store, n: int) -> str:
    from nsim.geometry.cameras import Camera
    from nsim.io.images import write_image
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms

    cam = Camera.pinhole_from_fov(16, 12, 60.0)
    key = store.action_key("test_poses", 1, {}, {})
    with store.publish(kind="poses", stage="test_poses", version=1, key=key, config={}, inputs={}) as out:
        (out.dir / "images").mkdir()
        for i in range(n):
            write_image(out.dir / "images" / f"{i}.png", np.zeros((12, 16, 3), np.uint8))
        write_transforms(out.dir / "transforms.json", TransformsData(frames=[
            Frame(file_path=f"images/{i}.png", cam_to_world=np.eye(4), camera=cam) for i in range(n)]))
    return out.ref


def _bake(store: Store, capsys, scene: str, *args: str):
    capsys.readouterr()
    code = main(["--workspace", str(store.root), "--device", "cpu", "bake", scene, *args])
    return code, capsys.readouterr().err.strip().splitlines()


def _kinds(store: Store) -> list[str]:
    return sorted(json.loads(m.read_text())["kind"] for m in (store.root / "objects").glob("*/*/manifest.json"))


def test_surface_without_training_cameras_fails_before_the_model(tmp_path, no_model, capsys):
    store = Store(tmp_path / "ws")
    scene = _scene(store, "no_cameras", {})
    before = _kinds(store)
    code, err = _bake(store, capsys, scene)  # the default preset bakes a surface: it needs the training cameras
    assert code == 2 and len(err) == 1, err
    assert "surface needs the training cameras" in err[0]
    assert no_model == [] and _kinds(store) == before


def test_training_images_out_of_range_fail_before_the_model(tmp_path, no_model, capsys):
    store = Store(tmp_path / "ws")
    scene = _scene(store, "out_of_range", {"train_images": [0, 5]}, poses=_poses(store, 2))
    code, err = _bake(store, capsys, scene)
    assert code == 2 and len(err) == 1, err
    assert "scene.json: train_images: expected frame indices of poses" in err[0] and "(2 frames)" in err[0]
    assert no_model == []


def test_good_scene_reaches_the_model(tmp_path, no_model):
    store = Store(tmp_path / "ws")
    scene = _scene(store, "good", {"train_images": [0, 1]}, poses=_poses(store, 2))
    with pytest.raises(ReachedModel):  # cameras and images read: loading the model is next
        main(["--workspace", str(store.root), "--device", "cpu", "bake", scene])
    assert len(no_model) == 1
