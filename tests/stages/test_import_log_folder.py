"""``nsim import-log DIR`` on a recording folder: nsim's synthetic robot log (Spot in the robot lab) imported
as a bag, exported as a folder, imported again, gives the same recording (camera models, extrinsics, stamps,
trajectory, pixels, depth, clouds); bad folders exit 2 with one line naming the file and publish nothing."""

from __future__ import annotations

import dataclasses
import json
import shutil

import cv2
import numpy as np
import pytest

from nsim.cli import main
from nsim.crowd.paths import yaw_poses_se3
from nsim.io.exr import read_exr
from nsim.io.robot_log import RobotLog
from nsim.io.tum import read_tum
from nsim.rendering.render_plan import adapt_rig
from nsim.sensors.rig import load_rig
from nsim.stages.capture import RobotLogConfig
from nsim.synth.faulty_robot_log import RobotLogFaults, write_robot_log
from nsim.synth.room import make_room
from nsim.workspace.store import Store
from tests.io.test_robot_folder import export_folder


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A 4-tick clean log of Spot (32 x 24 cameras with depth, a 16 x 90 LiDAR), as a bag and as a folder."""
    rig = adapt_rig(load_rig("nsim/configs/robots/spot.yaml"), RobotLogConfig(image_scale=0.05, lidar_azimuth_scale=0.05))
    spec = make_room("robot-lab", seed=0)
    n = 4
    cx, cy, rx, ry = spec.walk_loop_xy_m
    a = np.arange(n) * 0.1 / np.sqrt(rx * ry)
    body = yaw_poses_se3(np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], -1),
                         np.arctan2(ry * np.cos(a), -rx * np.sin(a)), 0.5)
    faults = dataclasses.replace(RobotLogFaults.none(), odom_frame_yaw_deg=30.0, odom_frame_xyz_m=(1.0, -0.5, 0.0),
                                 clock_offset_s=0.0123456789)
    root = tmp_path_factory.mktemp("importfolder")
    write_robot_log(root / "run", spec, rig, body, np.arange(n) * 0.1 + 1_700_000_000.0, faults, seed=1)
    with RobotLog(root / "run") as rl:
        folder = export_folder(rl, root / "folder")
    return root / "run", folder


@pytest.fixture(scope="module")
def imported(logs, tmp_path_factory):
    bag, folder = logs
    ws = tmp_path_factory.mktemp("ws")
    assert main(["--workspace", str(ws), "import-log", str(bag), "--tag", "recording/bag"]) == 0
    assert main(["--workspace", str(ws), "import-log", str(folder), "--tag", "recording/folder"]) == 0
    store = Store(ws)
    return ws, store.get(store.resolve("recording/bag")), store.get(store.resolve("recording/folder"))


def test_folder_gives_the_recording_the_bag_gives(imported):
    ws, bag, folder = imported
    doc_b, doc_f = (json.loads(a.file("recording.json").read_text()) for a in (bag, folder))
    assert doc_f["folder"] == {"name": "folder"} and "bags" not in doc_f and doc_b["bags"] == [{"name": "run"}]
    assert doc_f["trajectory"]["source"] == "trajectory.tum"
    for key in ("body_frame", "odom_frame"):
        assert doc_f[key] == doc_b[key]
    for key in ("poses", "duration_s"):
        assert doc_f["trajectory"][key] == doc_b["trajectory"][key]
    assert doc_f["trajectory"]["length_m"] == pytest.approx(doc_b["trajectory"]["length_m"], abs=1e-12)
    assert sorted(doc_f["streams"]) == sorted(doc_b["streams"])
    assert {v["kind"] for v in doc_f["streams"].values()} == {"camera", "depth", "lidar"}
    same = ("kind", "camera", "sensor_to_body", "frames", "frames_in_topic", "inside_trajectory", "encoding", "fields",
            "dir", "stamps_from_bag")
    for key, entry in doc_f["streams"].items():
        want = doc_b["streams"][key]
        assert {k: entry.get(k) for k in same} == {k: want.get(k) for k in same}, key
        assert entry["topic"] == key.replace("camera/", "cameras/") and entry["frame_id"] == key.split("/")[1]
    # every file: stamps and trajectory stamps to the nanosecond, pixels, depth and clouds bit for bit
    files_b = {p.relative_to(bag.path).as_posix() for p in bag.path.rglob("*") if p.is_file()}
    files_f = {p.relative_to(folder.path).as_posix() for p in folder.path.rglob("*") if p.is_file()}
    assert files_f == files_b
    checked = 0
    for rel in sorted(files_b):
        fb, ff = bag.path / rel, folder.path / rel
        if rel.endswith(".npy"):
            np.testing.assert_array_equal(np.load(ff), np.load(fb))
        elif rel.endswith(".png") and rel != "preview.png":
            np.testing.assert_array_equal(cv2.imread(str(ff), cv2.IMREAD_UNCHANGED), cv2.imread(str(fb), cv2.IMREAD_UNCHANGED))
        elif rel.endswith(".exr"):
            eb, ef = read_exr(fb), read_exr(ff)
            assert sorted(eb) == sorted(ef)
            for c in eb:
                np.testing.assert_array_equal(ef[c], eb[c])
        else:
            continue
        checked += 1
    assert checked > 30
    np.testing.assert_allclose(read_tum(folder.file("trajectory.tum")).poses_se3(),
                               read_tum(bag.file("trajectory.tum")).poses_se3(), rtol=0, atol=1e-12)
    # the cameras' clock offset survives to the nanosecond
    cam = next(k for k, v in doc_f["streams"].items() if v["kind"] == "camera")
    offset = np.load(folder.file(f"{cam}/stamps_ns.npy")) - np.load(folder.file("trajectory_ns.npy"))
    assert set(offset.tolist()) == {12_345_679}


def test_rerun_is_cached_and_stride_applies(imported, logs, capsys):
    ws, _, folder = imported
    capsys.readouterr()
    assert main(["--workspace", str(ws), "import-log", str(logs[1])]) == 0
    out = capsys.readouterr()
    assert out.out.strip() == folder.id and "cached" in out.err
    assert main(["--workspace", str(ws), "import-log", str(logs[1]), "--set", "frame_stride=3", "--tag", "rec/s3"]) == 0
    store = Store(ws)
    doc = json.loads(store.get(store.resolve("rec/s3")).file("recording.json").read_text())
    assert all(e["frames"] == [0, 3] for e in doc["streams"].values())


def _first_camera(root):
    return sorted((root / "cameras").iterdir())[0]


def _frames(root):
    return sorted(_first_camera(root).glob("*.png"))


def _rewrite(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


BAD = {
    "no trajectory": (lambda r: (r / "trajectory.tum").unlink(), [], "trajectory.tum: no such file"),
    "no camera_info": (lambda r: (_first_camera(r) / "camera_info.yaml").unlink(), [], "camera_info.yaml: no such file"),
    "unknown distortion model": (lambda r: _rewrite(_first_camera(r) / "camera_info.yaml", "distortion_model: ",
                                                    "distortion_model: kb4 #"), [], "unknown distortion model 'kb4'"),
    "sensor missing from the rig": (lambda r: _rewrite(r / "rig.yaml", f"  {_first_camera(r).name}:", "  nobody:"), [],
                                    "rig.yaml: no sensor '"),
    "non-monotonic timestamps": (lambda r: (_first_camera(r) / "timestamps.txt").write_text("3\n1\n2\n4\n"), [],
                                 "timestamps.txt:2: timestamp 1 ns is not after"),
    "timestamp count": (lambda r: (_first_camera(r) / "timestamps.txt").write_text("1\n2\n"), [],
                        "timestamps.txt: 2 timestamps for 4 frames"),
    "a later frame does not decode": (lambda r: _frames(r)[3].write_bytes(b"\x89PNG\r\n"), [], "does not decode"),
    "selection": (lambda r: None, ["--selection", "{root}/rig.yaml"], "chooses a bag's topics"),
    "trajectory from tf": (lambda r: None, ["--set", "trajectory=tf"], "trajectory=tf reads a bag's topics"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_folder_exits_2_with_one_line_and_publishes_nothing(imported, logs, tmp_path, capsys, case):
    ws, _, _ = imported
    before = set(Store(ws).all_ids())
    root = tmp_path / "bad"
    shutil.copytree(logs[1], root)
    edit, args, words = BAD[case]
    edit(root)
    capsys.readouterr()
    assert main(["--workspace", str(ws), "import-log", str(root), *(a.format(root=root) for a in args)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err
    assert str(root) in err, err
    assert set(Store(ws).all_ids()) == before


def test_depth_unit_recorded_and_implausible_depth_warned(logs, imported, tmp_path, caplog):
    """Each depth stream records its unit and median depth; a unit 100x off (millimetres declared as tenths of a
    metre) imports with a warning naming the median."""
    import yaml

    _, bag, folder = imported
    for art, unit in ((bag, None), (folder, 1.0)):
        entry = json.loads(art.file("recording.json").read_text())["streams"]["depth/frontleft"]
        assert entry["depth_unit"] and 0.1 <= entry["median_depth_m"] <= 20.0
        assert unit is None or entry["depth_m_per_unit"] == unit
    bag_path, _ = logs
    with RobotLog(bag_path) as rl:
        wrong = export_folder(rl, tmp_path / "wrong", depth_suffix=".png")
    for info in (wrong / "depth").glob("*/camera_info.yaml"):
        info.write_text(yaml.safe_dump(yaml.safe_load(info.read_text()) | {"depth_m_per_unit": 0.1}))
    ws = tmp_path / "ws"
    with caplog.at_level("WARNING"):
        assert main(["--workspace", str(ws), "import-log", str(wrong), "--tag", "recording/wrong"]) == 0
    warned = [r.getMessage() for r in caplog.records if "median depth" in r.getMessage()]
    assert warned and "outside 0.1-20 m" in warned[0] and "0.1 m per unit" in warned[0], warned
    store = Store(ws)
    entry = json.loads(store.get(store.resolve("recording/wrong")).file("recording.json").read_text())
    entry = entry["streams"]["depth/frontleft"]
    assert entry["depth_m_per_unit"] == 0.1 and entry["depth_unit"] == "depth_m_per_unit in camera_info.yaml"
    assert entry["median_depth_m"] > 20.0
