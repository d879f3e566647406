"""`nsim render` culling at micro size: people in view render the same with and without culling;
people out of view of every sensor render as if there were nobody, and with culling the human
NeRF is never called.

The people come from a simulated Spot run in which every person is moved, at every tick, to a
fixed place in the robot's body frame (the trajectory format the stage reads, ``HumanSet``):
in front of the robot (seen by Spot's front cameras and its LiDAR) or 3-4.5 m behind it (out of
the front cameras' view; Spot's 360-degree LiDAR would see them, so it is left out there).
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.config import configs_dir, from_dict, load_config
from nsim.context import RunContext
from nsim.workspace.store import Store
from tests.stages.micro import capture_and_micro_scene

SPOT = configs_dir() / "robots" / "spot.yaml"
FRONT = ("frontleft", "frontright")
BEHIND = ((-3.0, -1.5), (-3.5, -0.5), (-3.0, 0.5), (-4.5, 1.0))  # body frame: x forward, y left (m)
AHEAD = ((2.0, -0.6), (2.5, 0.3), (3.0, -1.2), (2.0, 1.0))
MICRO_HUMAN = ["model.hash_levels=4", "model.hash_log2_table_size=10", "model.hash_max_resolution=64",
               "model.hidden_dim=16", "model.color_hidden_dim=16", "model.samples_per_ray=12", "model.blend_voxel_m=0.08",
               "optim.steps=10", "optim.rays_per_batch=128", "optim.num_threads=1", "output.eval_views=1",
               "output.preview_views=1", "output.preview_width=16", "output.preview_height=24", "output.gait_frames=2"]


def place_people(store: Store, traj: str, offsets, tag: str) -> str:
    """``traj`` with person k at ``offsets[k % len]`` in the robot's body frame at every tick."""
    a = dict(np.load(store.get(traj).file("trajectory.npz"), allow_pickle=False))
    poses = a["robot_pose_se3"]
    n = a["position_m"].shape[1]
    off = np.array([offsets[k % len(offsets)] for k in range(n)], dtype=np.float64)
    a["position_m"] = np.einsum("tij,nj->tni", poses[:, :2, :2], off) + poses[:, None, :2, 3]
    a["heading_rad"] = np.broadcast_to(np.arctan2(poses[:, 1, 0], poses[:, 0, 0])[:, None] + np.pi,
                                       a["heading_rad"].shape).copy()
    key = hashlib.sha256(f"test.render.culling:{traj}:{tag}".encode()).hexdigest()
    with store.publish(kind="trajectory", stage="test_render_culling", version=1, key=key,
                       config={"placement": tag}, inputs={"trajectory": traj}) as out:
        np.savez(out.dir / "trajectory.npz", **a)
    return out.ref


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A capture, a micro scene checkpoint, a micro human checkpoint (train_human on an actor
    capture) and a short Spot run with its people placed ahead of and behind the robot."""
    from nsim.stages import capture, train_human

    root = tmp_path_factory.mktemp("render_culling")
    ws = root / "ws"
    capture_and_micro_scene(root, ws)
    assert main(["--workspace", str(ws), "simulate", "--preset", "tiny", "--set", "max_duration_s=1.0", "--set",
                 "video=false", "--scenario", str(configs_dir() / "scenarios" / "spot_run.json"),
                 "--tag", "trajectory/t"]) == 0
    store = Store(ws)
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    actor = capture.run(capture.Inputs(), load_config(capture.Config, stage="capture", preset="tiny", overrides=[
        "actor=true", "video=false", "width=32", "height=48", "n_frames=8", "supersample=1"]), ctx).capture
    human = train_human.run(train_human.Inputs(capture=actor),
                            load_config(train_human.Config, stage="train_human", preset="tiny", overrides=MICRO_HUMAN),
                            ctx).human
    traj = store.resolve("trajectory/t")
    assert np.load(store.get(traj).file("trajectory.npz"))["position_m"].shape[1] >= 2
    return {"store": store, "ctx": ctx, "human": human, "scene": store.resolve("scene/t"),
            "ahead": place_people(store, traj, AHEAD, "ahead"), "behind": place_people(store, traj, BEHIND, "behind")}


@pytest.fixture
def human_calls(monkeypatch):
    """How many times the human NeRF (``HumanModel.render_samples``) is called."""
    from nsim.human.nerf import HumanModel

    calls = {"n": 0}
    real = HumanModel.render_samples

    def counted(self, *a, **k):
        calls["n"] += 1
        return real(self, *a, **k)

    monkeypatch.setattr(HumanModel, "render_samples", counted)
    return calls


def render_with(world, traj: str, sensors, culling: bool, humans: bool) -> str:
    from nsim.stages import render

    cfg = from_dict(render.Config, {"tick_stride": 10, "max_frames": 2, "shard_frames": 2, "image_scale": 0.05,
                                    "lidar_azimuth_scale": 0.02, "noise": False, "video": False,
                                    "sensors": list(sensors), "culling": culling, "march": {"step_m": 0.05}})
    inputs = render.Inputs(trajectory=traj, scene=world["scene"], rig=SPOT, humans=(world["human"],) if humans else (),
                           people=humans)  # humans False: nobody (--no-people)
    return render.run(inputs, cfg, world["ctx"]).render


def decoded(store: Store, ref: str, with_masks: bool = True) -> dict[str, object]:
    """Every file under the sensors' folders, decoded (PNG, EXR: arrays; PLY, JSON: bytes)."""
    from nsim.io.coco import read_instance_mask
    from nsim.io.exr import read_exr
    from nsim.io.images import read_image

    art = store.get(ref)
    out: dict[str, object] = {}
    for s in json.loads(art.file("render.json").read_text())["sensors"]:
        for p in sorted((art.path / s["name"]).rglob("*")):
            rel = p.relative_to(art.path).as_posix()
            if not p.is_file() or (not with_masks and ("/mask/" in rel or rel.endswith("boxes.json"))):
                continue
            if p.suffix == ".exr":
                out[rel] = read_exr(p)
            elif p.suffix == ".png":
                out[rel] = read_instance_mask(p) if p.parent.name == "mask" else read_image(p)
            else:
                out[rel] = p.read_bytes()
    return out


def same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, bytes):
        return a == b
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def differing(x: dict, y: dict) -> list[str]:
    assert x.keys() == y.keys(), sorted(set(x) ^ set(y))
    return [k for k in x if not same(x[k], y[k])]


def test_people_in_view_render_the_same_with_and_without_culling(world, human_calls):
    store, sensors = world["store"], (*FRONT, "lidar")
    culled = decoded(store, render_with(world, world["ahead"], sensors, culling=True, humans=True))
    assert human_calls["n"] > 0  # the people are in view: culling keeps them
    unculled = decoded(store, render_with(world, world["ahead"], sensors, culling=False, humans=True))
    assert any("/rgb/" in k for k in culled) and any("/scan/" in k for k in culled)
    # not vacuous: the people change what the cameras see and the LiDAR's ranges
    nobody = decoded(store, render_with(world, world["ahead"], sensors, culling=True, humans=False))
    changed = differing({k: v for k, v in culled.items() if k in nobody}, nobody)
    assert any("/rgb/" in k for k in changed)
    assert any(not same(culled[k]["range"], nobody[k]["range"]) for k in nobody if k.endswith(".exr") and "/scan/" in k)
    # the images, depths, masks, boxes and every LiDAR channel but intensity: identical
    scans = [k for k in culled if k.endswith(".exr") and "/scan/" in k]
    intensity = {k: (culled[k].pop("intensity"), unculled[k].pop("intensity")) for k in scans}
    assert differing({k: v for k, v in culled.items() if not k.endswith(".ply")},
                     {k: v for k, v in unculled.items() if not k.endswith(".ply")}) == []
    # intensity (= the ray's accumulated opacity): the unculled stage composites the rays that miss
    # every box too, summing the scene's weights among zero-density human samples -- the same
    # value up to float32 rounding (1 ulp seen), not bit for bit (nor, hence, the .ply files)
    for a, b in intensity.values():
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def test_people_out_of_view_are_skipped_and_change_nothing(world, human_calls):
    store = world["store"]
    culled_ref = render_with(world, world["behind"], FRONT, culling=True, humans=True)
    assert human_calls["n"] == 0  # nobody is visible: the human NeRF is never called
    culled = decoded(store, culled_ref)
    nobody = decoded(store, render_with(world, world["behind"], FRONT, culling=True, humans=False))
    assert any("/rgb/" in k for k in nobody) and any("/depth/" in k for k in nobody)
    assert differing({k: v for k, v in culled.items() if k in nobody}, nobody) == []
    masks = [v for k, v in culled.items() if "/mask/" in k]
    assert masks and not any(m.any() for m in masks)
    # without culling every person's NeRF is called on every ray, and the output is the same
    unculled = decoded(store, render_with(world, world["behind"], FRONT, culling=False, humans=True))
    assert human_calls["n"] > 0
    assert differing(culled, unculled) == []


def test_lidar_culls_people_beyond_its_range(world, human_calls, tmp_path):
    """Spot's 360-degree LiDAR sees the people 3-4.5 m behind the robot; with its range cut to 2 m
    they are beyond it: culled (the human NeRF is never called) and the scans equal a render
    without people, while at the full range the same people are drawn."""
    from nsim.stages import render

    rig = tmp_path / "spot_short_lidar.yaml"
    text = SPOT.read_text()
    assert "max_range_m: 100.0" in text
    rig.write_text(text.replace("max_range_m: 100.0", "max_range_m: 2.0"))

    def scan(humans: bool, rig_file) -> str:
        cfg = from_dict(render.Config, {"tick_stride": 10, "max_frames": 2, "shard_frames": 2, "image_scale": 0.05,
                                        "lidar_azimuth_scale": 0.02, "noise": False, "video": False,
                                        "sensors": ["lidar"], "culling": True})
        inputs = render.Inputs(trajectory=world["behind"], scene=world["scene"], rig=rig_file,
                               humans=(world["human"],) if humans else (), people=humans)
        return render.run(inputs, cfg, world["ctx"]).render

    store = world["store"]
    short = decoded(store, scan(True, rig))
    assert human_calls["n"] == 0
    assert differing(short, decoded(store, scan(False, rig))) == []
    assert any("/scan/" in k for k in short)
    scan(True, SPOT)  # full range: the people behind the robot are within it
    assert human_calls["n"] > 0


def test_render_without_humans_draws_the_scenarios_people(world, caplog, human_calls):
    """No --humans: each person is drawn by the checkpoint its scenario's appearance names (human/ana, tagged
    here), the others with the default look (the test-room mannequin), said in one warning line and recorded;
    the front cameras see the mannequins (instance ids in the masks: the micro checkpoint is too faint to own a
    pixel) and the checkpoint is called; --no-people draws nobody."""
    from nsim.stages import render

    store = world["store"]
    store.set_ref("human/ana", world["human"])  # spot_run.json: humans[0].appearance is human/ana
    cfg = from_dict(render.Config, {"tick_stride": 10, "max_frames": 2, "shard_frames": 2, "image_scale": 0.05,
                                    "noise": False, "video": False, "sensors": list(FRONT),
                                    "march": {"step_m": 0.05}})
    with caplog.at_level("WARNING"):
        ref = render.run(render.Inputs(trajectory=world["ahead"], scene=world["scene"], rig=SPOT), cfg,
                         world["ctx"]).render
    art = store.get(ref)
    n = len(art.manifest["summary"]["people_checkpoints"])
    assert n >= 2
    assert art.manifest["summary"]["people_checkpoints"] == [world["human"]] + ["default look"] * (n - 1)
    assert art.manifest["summary"]["people_from"] == "scenario"
    assert art.manifest["inputs"]["human0"] == world["human"]
    assert f"{n - 1} of {n} people drawn with the default look" in caplog.text
    assert "humans[1] 'human/ben' (not in this workspace)" in caplog.text
    masks = [v for k, v in decoded(store, ref).items() if "/mask/" in k]
    seen = set(np.unique(np.concatenate([m.ravel() for m in masks]))) - {0}
    assert seen and seen <= {2, 3, 4, 5}, seen  # people drawn with the default look (instance id k + 1)
    assert human_calls["n"] > 0  # person 0 by its checkpoint
    nobody = store.get(render.run(render.Inputs(trajectory=world["ahead"], scene=world["scene"], rig=SPOT,
                                                people=False), cfg, world["ctx"]).render)
    assert nobody.id != ref and nobody.manifest["summary"]["people_from"] == "none"
    assert not any(v.any() for k, v in decoded(store, nobody.id).items() if "/mask/" in k)
