"""``nsim evaluate``: every render's input checks run before the first frame is scored (issue 44). The tables score
render after render; a second render's bad input (a camera it lacks, a missing frame file, no LiDAR, no slam
camera, a frame the capture does not have) used to fail after the first render's ground truth was rendered and
scored (slam: after its SfM). The renders here are stand-ins whose files are never read: the ground truth's
rendering, SfM and the image metrics are replaced by sentinels."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.config import configs_dir
from nsim.workspace.store import Store
from tests.stages.sentinel import ReachedWork, block_work

FRAMES = (0, 1, 2)


@pytest.fixture
def no_work(monkeypatch):
    return block_work(
        monkeypatch,
        "nsim.evaluation.oracle_truth.OracleTruth.oracle",
        "nsim.evaluation.oracle_truth.OracleTruth.oracle_view",
        "nsim.metrics.slam.run_colmap_slam",
        "nsim.metrics.paper_tables.image_records",
        "nsim.io.lidar_exr.read_lidar_exr",
        "nsim.evaluation.oracle_truth.read_rgb",
    )


def _publish(store: Store, kind: str, name: str, inputs: dict, files: dict) -> str:
    """An artifact of ``kind`` holding ``files`` (relative path -> bytes, str or a writer ``f(path)``)."""
    key = store.action_key(f"test_{name}", 1, {}, inputs)
    with store.publish(kind=kind, stage=f"test_{kind}", version=1, key=key, config={}, inputs=inputs) as out:
        for rel, content in files.items():
            path = out.dir / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            if callable(content):
                content(path)
            else:
                path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return out.ref


@pytest.fixture
def world(tmp_path):
    """A capture (two 16x12 frames; room.json), a scene trained on it, and a trajectory-render builder."""
    from nsim.geometry.cameras import Camera
    from nsim.io.images import write_image
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms

    store = Store(tmp_path / "ws")
    cam = Camera.pinhole_from_fov(16, 12, 60.0)
    image = np.zeros((12, 16, 3), np.uint8)
    capture = _publish(store, "capture", "capture", {}, {
        "room.json": json.dumps({"preset": "robot-lab"}),
        "transforms.json": lambda p: write_transforms(p, TransformsData(frames=[
            Frame(file_path=f"images/{i}.png", cam_to_world=np.eye(4), camera=cam) for i in range(2)])),
        **{f"images/{i}.png": (lambda p: write_image(p, image)) for i in range(2)},
    })
    scene = _publish(store, "scene-checkpoint", "scene", {"poses": capture}, {"scene.json": "{}"})
    return store, capture, scene


def _trajectory_render(store: Store, scene: str, name: str, sensors=("left", "frontleft", "lidar"),
                       missing: tuple[str, ...] = (), masks: bool = True) -> str:
    """A trajectory-mode render stand-in of ``sensors`` of Spot's rig: render.json, rig.json, robot.tum,
    cameras/<camera>.json and a (never read) file per frame (person masks too with ``masks``), but those in
    ``missing``."""
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms
    from nsim.sensors.rig import CameraSensor, Rig

    rig = Rig.load(configs_dir() / "robots" / "spot.yaml")
    rig = dataclasses.replace(rig, sensors=tuple(s for s in rig.sensors if s.name in sensors))
    files = {
        "render.json": json.dumps({"mode": "trajectory", "frames": [{"index": i, "time_s": 0.1 * i} for i in FRAMES]}),
        "rig.json": json.dumps(rig.to_dict(), default=str),
        "robot.tum": "".join(f"{0.1 * i} {0.1 * i} 0 0 0 0 0 1\n" for i in FRAMES),
    }
    for s in rig.sensors:
        if isinstance(s, CameraSensor):
            files[f"cameras/{s.name}.json"] = (lambda p, s=s: write_transforms(p, TransformsData(frames=[
                Frame(file_path=f"{s.name}/rgb/{i:06d}.png", cam_to_world=np.eye(4), camera=s.camera,
                      timestamp_s=0.1 * i) for i in FRAMES])))
            files.update({f"{s.name}/rgb/{i:06d}.png": b"-" for i in FRAMES})
            files.update({f"{s.name}/depth/{i:06d}.exr": b"-" for i in FRAMES})
            files.update({f"{s.name}/mask/{i:06d}.png": b"-" for i in FRAMES if masks})
        else:
            files.update({f"{s.name}/scan/{i:06d}.exr": b"-" for i in FRAMES})
    for rel in missing:
        del files[rel]
    return _publish(store, "render", name, {"scene": scene, "trajectory": "0" * 64}, files)


def _kinds(store: Store) -> list[str]:
    return sorted(json.loads(m.read_text())["kind"] for m in (store.root / "objects").glob("*/*/manifest.json"))


def _evaluate(store: Store, capsys, table: str, *renders: str, sets=()):
    args = ["--workspace", str(store.root), "--device", "cpu", "evaluate", "--preset", "tiny", "--table", table,
            "--set", "lpips_net=none"]
    for r in renders:
        args += ["--render", r]
    for kv in sets:
        args += ["--set", kv]
    capsys.readouterr()
    code = main(args)
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("table, second, sets, message", [
    ("spot-rgb", {"missing": ("left/rgb/000002.png",)}, (), "has no file left/rgb/000002.png"),
    ("spot-rgb", {"sensors": ("frontleft", "lidar")}, ("cameras=[left]",), "has no image camera left"),
    ("spot-depth", {"missing": ("frontleft/depth/000001.exr",)}, (), "has no file frontleft/depth/000001.exr"),
    ("spot-rgb", {"masks": False}, ("region=people",), "region=people: render"),
    ("lidar", {"sensors": ("left", "frontleft")}, (), "its rig has no LiDAR to score"),
    ("lidar", {"missing": ("lidar/scan/000001.exr",)}, (), "has no file lidar/scan/000001.exr"),
    ("slam", {"sensors": ("frontleft", "lidar")}, (), "slam.camera: render"),
    ("slam", {"missing": ("left/rgb/000000.png",)}, (), "has no file left/rgb/000000.png"),
])
def test_the_second_render_is_checked_before_the_first_is_scored(world, no_work, capsys, table, second, sets,
                                                                  message):
    store, _, scene = world
    first = _trajectory_render(store, scene, "first")
    bad = _trajectory_render(store, scene, "second", **second)
    before = _kinds(store)
    code, err = _evaluate(store, capsys, table, first, bad, sets=sets)
    assert code == 2 and len(err) == 1, err
    assert message in err[0] and bad[:12] in err[0], err
    assert no_work == []  # no ground truth rendered, no SfM, nothing scored
    assert _kinds(store) == before  # nothing published


@pytest.mark.parametrize("table", ["spot-rgb", "spot-depth", "lidar", "slam"])
def test_good_renders_reach_the_work(world, no_work, capsys, table):
    store, _, scene = world
    renders = [_trajectory_render(store, scene, name) for name in ("first", "second")]
    with pytest.raises(ReachedWork):
        _evaluate(store, capsys, table, *renders)
    assert len(no_work) == 1


def _poses_render(store: Store, capture: str, scene: str, name: str, frames) -> str:
    from nsim.io.exr import write_depth_exr
    from nsim.io.images import write_image

    files = {"render.json": json.dumps({"mode": "poses", "frames": [{"index": i, "time_s": 0.0} for i in frames]})}
    for i in frames:
        files[f"frames/rgb/{i:06d}.png"] = lambda p: write_image(p, np.zeros((12, 16, 3), np.uint8))
        files[f"frames/depth/{i:06d}.exr"] = lambda p: write_depth_exr(p, np.ones((12, 16), np.float32))
    return _publish(store, "render", name, {"poses": capture, "scene": scene}, files)


def test_scenes_checks_every_render_before_scoring(world, no_work, capsys):
    store, capture, scene = world
    good = _poses_render(store, capture, scene, "good", [0, 1])
    bad = _poses_render(store, capture, scene, "bad", [1, 7])
    code, err = _evaluate(store, capsys, "scenes", good, bad)
    assert code == 2 and len(err) == 1, err
    assert f"render {bad[:12]}: frame 7 of render.json is not among the 2 frames" in err[0]
    assert no_work == []
    with pytest.raises(ReachedWork):  # both good: scoring is next
        _evaluate(store, capsys, "scenes", good, _poses_render(store, capture, scene, "good2", [1]))
