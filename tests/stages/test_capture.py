"""`nsim capture synth` end to end at tiny size: files, ground truth, determinism, the cache."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from nsim.io.exr import read_depth_exr
from nsim.io.images import read_image
from nsim.io.transforms_json import read_transforms
from nsim.io.tum import read_tum
from nsim.workspace.store import Store


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    from nsim.cli import main

    ws = tmp_path_factory.mktemp("cap") / "ws"
    assert main(["--workspace", str(ws), "capture", "synth", "--preset", "tiny", "--tag", "capture/t"]) == 0
    store = Store(ws)
    return store, store.get(store.resolve("capture/t"))


def test_capture_files_and_ground_truth(tiny_capture):
    from nsim.stages.capture import Config, make_camera
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.room import RoomSpec

    store, art = tiny_capture
    m = art.manifest
    assert m["kind"] == "capture" and m["summary"]["frames"] == 40
    data = read_transforms(art.path / "transforms.json")
    assert len(data.frames) == 40
    cfg = Config(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in m["config"].items()})
    camera = make_camera(cfg)
    assert data.frames[0].camera == camera
    room = json.loads((art.path / "room.json").read_text())
    oracle = RoomOracle(RoomSpec.from_dict(room["spec"]))
    for k in (0, 17, 39):
        f = data.frames[k]
        rgb = read_image(art.path / f.file_path)
        assert rgb.shape == (72, 96, 3)
        depth = read_depth_exr(art.path / f.depth_file_path)
        gt_rgb, gt_depth, _ = oracle.render_gt(camera, f.cam_to_world, supersample=cfg.supersample)
        np.testing.assert_array_equal(depth, gt_depth.astype(np.float32))
        assert np.abs(rgb.astype(float) / 255 - gt_rgb).max() <= 0.5 / 255 + 1e-6
    traj = read_tum(art.path / "gt_trajectory.tum")
    np.testing.assert_allclose(traj.poses_se3(), np.stack([f.cam_to_world for f in data.frames]), atol=1e-9)
    occ = json.loads((art.path / "occupancy.json").read_text())
    assert occ["units"] == "m" and len(occ["polygons"]) >= 4
    video = cv2.VideoCapture(str(art.path / "video.mp4"))
    n = 0
    while video.read()[0]:
        n += 1
    assert n == 40
    assert (art.path / "preview.png").stat().st_size > 1000


def test_capture_is_cached_and_reproducible(tiny_capture, tmp_path, run_cli):
    store, art = tiny_capture
    code, out, err = run_cli("capture", "synth", "--preset", "tiny", workspace=store.root)
    assert code == 0 and out.strip() == art.id and "cached" in err
    # a second workspace computes the same artifact id from scratch
    code, out, _ = run_cli("capture", "synth", "--preset", "tiny", workspace=tmp_path / "other")
    assert code == 0 and out.strip() == art.id
    code, out, _ = run_cli("verify", "--rebuild", art.id[:10], workspace=store.root)
    assert code == 0 and "rebuilt identically" in out


def test_seed_and_room_change_the_artifact(run_cli, tmp_path):
    args = ("capture", "synth", "--preset", "tiny", "--set", "n_frames=3", "--set", "video=false")
    ids = set()
    for extra in ((), ("--seed", "1"), ("--room", "kitchen"), ("--camera", "fisheye")):
        if extra and extra[0] == "--seed":
            code, out, _ = run_cli(*extra, *args)
        else:
            code, out, _ = run_cli(*args, *extra)
        assert code == 0
        ids.add(out.strip())
    assert len(ids) == 4


ROOMS = ("robot-lab", "common-room", "kitchen", "living-room", "seminar-room")


@pytest.mark.parametrize("camera", ["pinhole", "fisheye"])
@pytest.mark.parametrize("room", ROOMS)
def test_every_room_and_camera_publishes(run_cli, tmp_path, room, camera):
    code, out, err = run_cli(
        "capture", "synth", "--preset", "tiny", "--room", room, "--camera", camera,
        "--set", "n_frames=3", "--set", "video=false", "--set", "supersample=1",
    )
    assert code == 0, err
    store = Store(tmp_path / "ws")
    art = store.get(out.strip())
    assert art.manifest["summary"]["room"] == room
    data = read_transforms(art.path / "transforms.json")
    assert data.frames[0].camera.model == ("PINHOLE" if camera == "pinhole" else "OPENCV_FISHEYE")
    depth = read_depth_exr(art.path / data.frames[0].depth_file_path)
    finite = np.isfinite(depth)
    assert finite.mean() > 0.6 and (depth[finite] > 0).all() and depth[finite].max() < 20.0


def test_default_capture_has_a_low_pass(tiny_capture):
    """Both presets film a loop at eye height and one at about 0.6 m (Spot's camera height)."""
    from nsim.config import load_config
    from nsim.stages.capture import Config, path_config

    for preset in ("default", "tiny"):
        assert load_config(Config, stage="capture", preset=preset).low_pass_height_m == pytest.approx(0.6)
    _, art = tiny_capture
    heights = read_tum(art.path / "gt_trajectory.tum").positions_xyz[:, 2]
    assert heights.min() < 0.65 and heights.max() > 1.45
    flat = path_config(Config(low_pass_height_m=None))
    assert flat.low_height_m == flat.eye_height_m and flat.low_pitch_down_deg == flat.eye_pitch_down_deg
    assert path_config(Config(low_pass_height_m=0.7)).low_height_m == 0.7
