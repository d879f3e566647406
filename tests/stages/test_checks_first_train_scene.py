"""``nsim train-scene``: every check that the arguments, the config and the poses' transforms.json decide runs
before any image is read (issue 44: a config that could never train used to fail after loading every image, or
after training). ``SceneData.load`` -- reading and shrinking every image, the first expensive step -- is replaced
by a sentinel: a bad input is one line and exit code 2 without reaching it, and nothing is published."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.workspace.store import Store

# 64x16: a 4:1 image, so that a small data.max_image_side / eval.image_side shrinks it to nothing
CAPTURE = ["width=64", "height=16", "n_frames=6", "supersample=1", "video=false"]


class ReachedLoad(Exception):
    pass


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    ws = tmp_path_factory.mktemp("checks_ts") / "ws"
    args = ["--workspace", str(ws), "capture", "synth"]
    for kv in CAPTURE:
        args += ["--set", kv]
    assert main([*args, "--tag", "capture/t"]) == 0
    return ws


@pytest.fixture
def no_load(monkeypatch):
    """Reading the images replaced by a sentinel: reaching it means every input check passed."""
    from nsim.train.scene_data import SceneData

    calls = []

    def load(*args, **kwargs):
        calls.append(args)
        raise ReachedLoad

    monkeypatch.setattr(SceneData, "load", load)
    return calls


def _kinds(ws) -> list[str]:
    objects = ws / "objects"
    return sorted(json.loads(m.read_text())["kind"] for m in objects.glob("*/*/manifest.json"))


def _train(ws, capsys, *sets: str, extra=()):
    args = ["--workspace", str(ws), "--device", "cpu", "train-scene", "--poses", "capture/t", "--preset", "tiny",
            *extra]
    for kv in sets:
        args += ["--set", kv]
    capsys.readouterr()
    code = main(args)
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("sets, message", [
    (["data.holdout_every=1"], "holding out every 1th frame leaves no training frames"),
    (["data.bounds=fixed"], "data.bounds: 'fixed' needs data.aabb_min_m and data.aabb_max_m"),
    (["data.bounds=fixed", "data.aabb_min_m=[0,0,0]", "data.aabb_max_m=[1,0,1]"], "degenerate scene box"),
    (["data.bounds=points"], "data.bounds is 'points' but there is no sparse point cloud"),
    (["loss.depth_weight=0.1"], "loss.depth_weight > 0 needs a sparse point cloud"),
    (["data.max_image_side=1"], "data.max_image_side: 1 px shrinks the 64x16 images to nothing"),
    (["eval.image_side=2"], "eval.image_side: 2 px shrinks the 64x16 images to nothing"),
    (["field.backend=tcnn"], "field.backend: tcnn (tiny-cuda-nn) runs on CUDA only"),
])
def test_bad_config_fails_before_reading_the_images(workspace, no_load, capsys, sets, message):
    before = _kinds(workspace)
    code, err = _train(workspace, capsys, *sets)
    assert code == 2 and len(err) == 1, err
    assert message in err[0], err
    assert no_load == []
    assert _kinds(workspace) == before  # nothing published


def test_image_depth_loss_needs_a_training_frame_with_depth(workspace, no_load, capsys, tmp_path):
    """A capture has depth for every frame; with every frame's depth_file_path gone, the depth loss has nothing."""
    store = Store(workspace)
    cap = store.get(store.resolve("capture/t"))
    doc = json.loads(cap.file("transforms.json").read_text())
    inputs = {"source": cap.id}
    key = store.action_key("test_no_depth", 1, {}, inputs)
    with store.publish(kind="poses", stage="test_no_depth", version=1, key=key, config={}, inputs=inputs) as out:
        (out.dir / "images").mkdir()
        for f in doc["frames"]:
            f.pop("depth_file_path", None)
            (out.dir / f["file_path"]).write_bytes((cap.path / f["file_path"]).read_bytes())
        (out.dir / "transforms.json").write_text(json.dumps(doc))
    store.set_ref("poses/nodepth", out.ref)
    before = _kinds(workspace)
    capsys.readouterr()
    code = main(["--workspace", str(workspace), "--device", "cpu", "train-scene", "--poses", "poses/nodepth",
                 "--preset", "tiny", "--set", "loss.image_depth_weight=0.1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "loss.image_depth_weight > 0 but no training frame has a depth image" in err[0]
    assert no_load == [] and _kinds(workspace) == before


def test_good_config_reaches_the_images(workspace, no_load):
    with pytest.raises(ReachedLoad):  # the checks pass and reading the images is next
        main(["--workspace", str(workspace), "--device", "cpu", "train-scene", "--poses", "capture/t",
              "--preset", "tiny", "--set", "data.bounds=fixed", "--set", "data.aabb_min_m=[-1,-1,-1]",
              "--set", "data.aabb_max_m=[1,1,1]", "--set", "data.max_image_side=32"])
    assert len(no_load) == 1


def _robot(store: Store, poses: str, streams: dict) -> str:
    """A recording artifact (recording.json with ``streams``) and a registration of it against ``poses`` (a
    two-pose trajectory): what ``--recording`` needs to be resolved and read."""
    from nsim.io.tum import Trajectory, write_tum

    key = store.action_key("test_recording", 1, {}, {"streams": json.dumps(streams)})
    with store.publish(kind="recording", stage="test_recording", version=1, key=key, config={}, inputs={}) as out:
        (out.dir / "recording.json").write_text(json.dumps({"streams": streams}))
    inputs = {"recording": out.ref, "poses": poses}
    key = store.action_key("test_registration", 1, {}, inputs)
    with store.publish(kind="registration", stage="test_registration", version=1, key=key, config={},
                       inputs=inputs) as reg:
        stamps = np.array([1_000_000_000, 2_000_000_000], dtype=np.int64)
        np.save(reg.dir / "trajectory_world_ns.npy", stamps, allow_pickle=False)
        write_tum(reg.dir / "trajectory_world.tum", Trajectory.from_poses(stamps / 1e9, np.stack([np.eye(4)] * 2)))
        (reg.dir / "registration.json").write_text(json.dumps({
            "format": 1, "inputs": inputs, "odom_to_world": np.eye(4).tolist(), "scale": 1.0,
            "clock_offset_s": 0.0}))
    return reg.ref


def test_recording_checks_come_before_the_images(workspace, no_load, capsys):
    store = Store(workspace)
    reg = _robot(store, store.resolve("capture/t"), {})
    before = _kinds(workspace)
    code, err = _train(workspace, capsys, "data.scale=arbitrary", extra=["--recording", reg])
    assert code == 2 and len(err) == 1 and "the poses' scale is arbitrary" in err[0], err
    code, err = _train(workspace, capsys, extra=["--recording", reg, "--recording-camera", "nope"])
    assert code == 2 and len(err) == 1 and "no camera 'nope' in the recording (it has: none)" in err[0], err
    code, err = _train(workspace, capsys, extra=["--recording", reg])  # no camera stream: no robot frame
    assert code == 2 and len(err) == 1 and "no robot frame to train on" in err[0], err
    assert no_load == [] and _kinds(workspace) == before
