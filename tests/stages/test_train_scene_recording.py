"""``nsim train-scene --recording`` end to end at micro size: a robot log of a simulated run (nsim capture
robot-log: two of Spot's fisheye cameras at 160x120, 8 ticks) imported, and a registration published here
from the log's truth (its true trajectory and clock offset: registering by SfM is slow and is tested in
``tests/stages/test_register_log.py``), then trained for two steps with a 64x36 capture of the same room
(a 16:9 pinhole beside 4:3 fisheyes: each fisheye frame is shrunk and cropped to 64x36).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from nsim.cli import main
from nsim.config import load_config
from nsim.context import RunContext
from nsim.geometry.cameras import Camera
from nsim.stages import train_scene
from nsim.train.scene_data import RecordingConfig, fit_camera, read_recorded_frames, split_recorded_frames
from nsim.workspace.store import Store
from tests.stages.micro import micro_scene

CAPTURE = ["width=64", "height=36", "n_frames=24", "supersample=1", "video=false"]
ROBOT_LOG = ["--preset", "tiny", "--set", "sensors=[frontleft,back]", "--set", "image_scale=0.25"]


def _registration(store: Store, recording: str, poses: str, truth: dict) -> str:
    """A registration artifact of ``recording`` against ``poses`` holding the log's truth, its trajectory
    without the last pose (so that the last tick's frames lie outside it)."""
    from nsim.io.tum import Trajectory, write_tum

    inputs = {"recording": recording, "poses": poses}
    key = store.action_key("test_registration", 1, {}, inputs)
    with store.publish(kind="registration", stage="test_registration", version=1, key=key, config={},
                       inputs=inputs) as out:
        stamps = np.array(truth["stamps_ns"][:-1], dtype=np.int64)
        np.save(out.dir / "trajectory_world_ns.npy", stamps, allow_pickle=False)
        write_tum(out.dir / "trajectory_world.tum",
                  Trajectory.from_poses(stamps / 1e9, np.array(truth["body_to_world"][:-1])))
        (out.dir / "registration.json").write_text(json.dumps({
            "format": 1, "inputs": inputs, "odom_to_world": truth["odom_to_world"], "scale": 1.0,
            "clock_offset_s": truth["clock_offset_s"]}))
    return out.ref


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("train_rec")
    ws = root / "ws"
    w = ["--workspace", str(ws)]
    assert main([*w, "simulate", "--scenario", "nsim/configs/scenarios/spot_run.json", "--preset", "tiny", "--set",
                 "video=false", "--tag", "trajectory/run"]) == 0
    bag = root / "run"
    assert main([*w, "capture", "robot-log", "trajectory/run", *ROBOT_LOG, "--out", str(bag)]) == 0
    assert main([*w, "import-log", str(bag), "--tag", "recording/run"]) == 0
    cap = [*w, "capture", "synth", "--room", "robot-lab"]
    for kv in CAPTURE:
        cap += ["--set", kv]
    assert main([*cap, "--tag", "capture/t"]) == 0
    store = Store(ws)
    truth = json.loads((root / "run.truth.json").read_text())
    rec, poses = store.resolve("recording/run"), store.resolve("capture/t")
    store.set_ref("registration/run", _registration(store, rec, poses, truth))
    cfg = root / "micro.yaml"
    cfg.write_text(yaml.safe_dump(micro_scene(optim={"steps": 2}, output={"final_eval_views": 0})))
    train = [*w, "--device", "cpu", "train-scene", "--poses", "capture/t", "--preset", "tiny", "--config", str(cfg)]
    return ws, store, truth, train


def test_recorded_frames_sit_at_the_true_poses_with_their_recorded_cameras(world):
    ws, store, truth, _ = world
    reg, rec = store.get(store.resolve("registration/run")), store.get(store.resolve("recording/run"))
    recorded = read_recorded_frames(reg.path, rec.path)
    doc = json.loads(rec.file("recording.json").read_text())["streams"]
    body = np.array(truth["body_to_world"])
    cam_stamps = np.array(truth["camera_frames"]["stamps_ns"], dtype=np.int64)
    assert set(recorded.recorded) == {"back", "frontleft"}
    for f in recorded.frames:
        entry = doc[f"camera/{f.camera_name}"]
        assert f.camera == Camera.from_dict(entry["camera"]) and (f.camera.width, f.camera.height) == (160, 120)
        tick = int(np.flatnonzero(cam_stamps == f.stamp_ns)[0])
        np.testing.assert_allclose(f.cam_to_world, body[tick] @ np.array(entry["sensor_to_body"]), atol=1e-6)
    # frames captured after the registered trajectory's last pose are dropped and counted
    last = truth["stamps_ns"][-2]
    for name, n in recorded.recorded.items():
        stamps = np.load(rec.file(f"camera/{name}/stamps_ns.npy"))
        late = int(np.sum(stamps - round(truth["clock_offset_s"] * 1e9) > last))
        assert recorded.outside[name] == late == 1 and n == len(stamps) == 8
        assert sum(f.camera_name == name for f in recorded.frames) == n - late


def test_train_with_a_share_of_robot_frames(world):
    ws, store, truth, train = world
    assert main([*train, "--recording", "registration/run", "--recording-share", "0.25", "--tag", "scene/rec"]) == 0
    art = store.get(store.resolve("scene/rec"))
    reg = store.resolve("registration/run")
    assert art.manifest["inputs"] == {"poses": store.resolve("capture/t"), "registration": reg}
    scene = json.loads(art.file("scene.json").read_text())
    r = scene["recording"]
    assert r["registration"] == reg and r["recording"] == store.resolve("recording/run")
    assert r["options"] == {"share": 0.25, "holdout_every": 8, "cameras": []}
    # 21 capture frames train (every 8th of 24 held out): 0.25 / 0.75 * 21 = 7 robot frames
    assert r["capture_train_frames"] == 21 and r["robot_train_frames"] == 7 == len(r["train"])
    assert r["share_trained"] == pytest.approx(0.25)
    assert [t["image"] for t in r["train"]] == list(range(24, 31))
    assert scene["train_images"][-7:] == list(range(24, 31)) and max(scene["eval_images"]) < 24
    assert scene["n_images"] == 31 and scene["images"][24].startswith("recording:camera/")
    trained = {(t["camera"], t["index"]) for t in r["train"]}
    held = {(h["camera"], h["index"]) for h in r["held_out"]}
    assert held == {("back", 0), ("frontleft", 0)} and not trained & held  # position 0 of each camera
    assert set(r["cameras"]) == {"back", "frontleft"}
    for c in r["cameras"].values():
        assert c["recorded"] == 8 and c["outside_trajectory"] == 1 and c["held_out"] == 1
        assert c["train"] in (3, 4)
    s = art.manifest["summary"]
    assert s["frames"] == 31 and s["train_frames"] == 28 and s["eval_frames"] == 3 and s["robot_train_frames"] == 7
    assert s["train_image_size"] == [64, 36]


def test_the_trainer_sees_the_fitted_recorded_cameras(world):
    """What the stage trains on, without training: the recorded frames after the capture's, fitted to 64x36."""
    ws, store, truth, _ = world
    from nsim.train.scene import SceneData, SceneTrainer

    cfg = load_config(train_scene.Config, stage="train_scene", preset="tiny",
                      overrides=[f"{k}={v}" for k, v in (("optim.steps", 2), ("optim.rays_per_batch", 64))])
    reg, rec = store.get(store.resolve("registration/run")), store.get(store.resolve("recording/run"))
    data = SceneData.load(store.get(store.resolve("capture/t")).path)
    data2, record = train_scene.add_recorded_frames(data, reg, rec, RecordingConfig(share=0.25), cfg)
    recorded = read_recorded_frames(reg.path, rec.path)
    split = split_recorded_frames(recorded, 21, RecordingConfig(share=0.25))
    assert data2.n_frames == 31 and data2.images.shape == (31, 36, 64, 3)
    for j, k in enumerate(split.train):
        f = recorded.frames[k]
        c = int(data2.camera_index[24 + j])
        assert data2.full_cameras[c] == f.camera and data2.cameras[c] == fit_camera(f.camera, 64, 36)
        np.testing.assert_array_equal(data2.cam_to_world[24 + j], f.cam_to_world)
    trainer = SceneTrainer(data2, cfg, "cpu", 0)
    assert set(range(24, 31)) <= set(trainer.train_ids.tolist()) and max(trainer.eval_ids) < 24
    rays, target, _ = trainer.batch(0)
    assert torch_finite(rays.dirs) and rays.origins.shape == (64, 3)


def torch_finite(t) -> bool:
    import torch

    return bool(torch.isfinite(t).all())


def test_no_recording_keeps_the_key_it_had(world):
    ws, store, _, _ = world
    ctx = RunContext(store=store, device_spec="cpu", seed=0)
    cfg = load_config(train_scene.Config, stage="train_scene", preset="tiny")
    poses = store.resolve("capture/t")
    before = store.action_key("train_scene", train_scene.VERSION, cfg, {"poses": poses}, seed=0, extra={"device": "cpu"})
    assert train_scene.action_key(train_scene.Inputs(poses=poses), cfg, ctx) == before
    with_rec = train_scene.Inputs(poses=poses, registration=store.resolve("registration/run"))
    other = train_scene.action_key(with_rec, cfg, ctx)
    assert other != before
    assert train_scene.action_key(train_scene.Inputs(poses=poses, registration=with_rec.registration,
                                                     recording=RecordingConfig(share=0.5)), cfg, ctx) != other


def _one_line_exit_2(capsys, args) -> str:
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_bad_input_exits_2_with_one_line(world, capsys, tmp_path):
    ws, store, truth, train = world
    n_before = len(store.artifacts())
    err = _one_line_exit_2(capsys, [*train, "--recording", "recording/run"])
    assert "a recording artifact" in err and "register" in err
    err = _one_line_exit_2(capsys, [*train, "--recording", "registration/run", "--recording-share", "1.5"])
    assert "--recording-share" in err
    err = _one_line_exit_2(capsys, [*train, "--recording-share", "0.5"])
    assert "needs --recording" in err
    err = _one_line_exit_2(capsys, [*train, "--recording", "registration/run", "--recording-camera", "left"])
    assert "no camera 'left'" in err
    # a registration made against another scene: its world is not the one trained
    other = _registration(store, store.resolve("recording/run"), store.resolve("trajectory/run"), truth)
    err = _one_line_exit_2(capsys, [*train, "--recording", other])
    assert "world of poses" in err
    assert len(store.artifacts()) == n_before + 1  # the registration made here, no scene
