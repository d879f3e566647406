"""Trajectory-only recordings (a real robot's odometry with no sensors) through ``import-log``, refused by
``register-log``, driving ``simulate``; ``import-log --trajectory FILE.tum``; ``simulate --robot-trajectory``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nsim.config import configs_dir
from nsim.crowd.paths import yaw_poses_se3
from nsim.io.robot_folder import read_tum_ns
from nsim.io.rosbag import BagWriter
from nsim.io.tum import Trajectory, write_tum
from nsim.workspace.store import Store

POLYGON_ROOM = configs_dir() / "scenarios" / "polygon_room.yaml"
FAST = ("--preset", "tiny", "--set", "video=false")
T0_NS = 1_700_000_000_000_000_000


def _path(n: int = 41, dt_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A robot driving along y = 1.5 m in the polygon room at 1 m/s, turning a little: stamps_ns, body_to_odom."""
    t = np.arange(n) * dt_s
    xy = np.stack([2.0 + 1.0 * t, 1.5 + 0.2 * np.sin(t)], -1)
    return T0_NS + np.round(t * 1e9).astype(np.int64), yaw_poses_se3(xy, 0.2 * np.cos(t), 0.0)


def _odometry_bag(path: Path, storage: str = "sqlite3") -> tuple[np.ndarray, np.ndarray]:
    stamps, poses = _path()
    with BagWriter(path, storage=storage) as bag:
        for t, pose in zip(stamps, poses, strict=True):
            bag.write_odometry(None, pose, t_ns=int(t))
    return stamps, poses


def _scenario(tmp_path: Path, trajectory: dict) -> Path:
    import yaml

    data = yaml.safe_load(POLYGON_ROOM.read_text())
    data["robot"]["trajectory"] = trajectory
    data["duration_s"] = 3.0
    out = tmp_path / "replay.yaml"
    out.write_text(yaml.safe_dump(data))
    return out


def test_an_odometry_bag_imports_as_a_trajectory_only_recording_and_drives_simulate(run_cli, tmp_path, caplog):
    stamps, poses = _odometry_bag(tmp_path / "nav")
    store = Store(tmp_path / "ws")
    code, out, err = run_cli("import-log", str(tmp_path / "nav"), "--tag", "nav")
    assert code == 0, err
    rec = store.get(out.strip())
    doc = json.loads(rec.file("recording.json").read_text())
    assert doc["trajectory_only"] is True and doc["streams"] == {}
    np.testing.assert_array_equal(np.load(rec.file("trajectory_ns.npy")), stamps)
    got_ns, got = read_tum_ns(rec.file("trajectory.tum"))
    np.testing.assert_allclose(got[:, :3, 3], poses[:, :3, 3], atol=1e-6)

    # register-log: nothing to register, one line
    code, out, err = run_cli("register-log", "nav", "--poses", "nav")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "trajectory-only recording" in err and "nothing to register" in err

    # simulate drives along it: the robot's poses are the recording's, from t = 0
    scenario = _scenario(tmp_path, {"recording": "nav"})
    code, out, err = run_cli("simulate", "--scenario", str(scenario), *FAST)
    assert code == 0, err
    art = store.get(out.strip())
    sc = json.loads(art.file("scenario.json").read_text())
    traj = sc["robot"]["trajectory"]
    assert traj["source"].startswith(f"recording {rec.id} ") and "odometry frame" in traj["source"]
    assert traj["poses"][0]["t_s"] == 0.0 and len(traj["poses"]) == len(stamps)
    sim = np.load(art.file("trajectory.npz"))
    t = sim["time_s"]
    want_x = 2.0 + t[t <= 4.0]  # x = 2 + t along the recorded path
    np.testing.assert_allclose(sim["robot_pose_se3"][: len(want_x), 0, 3], want_x, atol=1e-6)
    np.testing.assert_allclose(sim["robot_pose_se3"][: len(want_x), 1, 3], 1.5 + 0.2 * np.sin(want_x - 2.0),
                               atol=0.02)

    # the same from the command line, and from the TUM file itself: the same poses
    code, out2, err = run_cli("simulate", "--scenario", str(POLYGON_ROOM), "--robot-trajectory", "nav",
                              *FAST, "--set", "max_duration_s=3")
    assert code == 0, err
    sim2 = np.load(store.get(out2.strip()).file("trajectory.npz"))
    np.testing.assert_allclose(sim2["robot_pose_se3"][:20], sim["robot_pose_se3"][:20], atol=1e-9)
    code, out3, err = run_cli("simulate", "--scenario", str(POLYGON_ROOM), "--robot-trajectory",
                              str(rec.file("trajectory.tum")), *FAST, "--set", "max_duration_s=3")
    assert code == 0, err
    sim3 = np.load(store.get(out3.strip()).file("trajectory.npz"))
    np.testing.assert_allclose(sim3["robot_pose_se3"][:20], sim["robot_pose_se3"][:20], atol=1e-6)


def test_a_trajectory_only_folder_imports(run_cli, tmp_path):
    stamps, poses = _path()
    root = tmp_path / "run"
    root.mkdir()
    write_tum(root / "trajectory.tum", Trajectory.from_poses(stamps / 1e9, poses))
    code, out, err = run_cli("import-log", str(root))
    assert code == 0, err
    doc = json.loads(Store(tmp_path / "ws").get(out.strip()).file("recording.json").read_text())
    assert doc["trajectory_only"] is True and doc["trajectory"]["poses"] == len(stamps)
    # a rig without streams is a misnamed folder, not a trajectory-only recording
    (root / "rig.yaml").write_text("sensors: {}\n")
    code, out, err = run_cli("import-log", str(root), "--force")
    assert code == 2 and "rig.yaml but no stream folders" in err and len(err.strip().splitlines()) == 1


def test_bad_trajectory_inputs_are_one_line(run_cli, tmp_path):
    store = Store(tmp_path / "ws")
    # a bag with nothing: no stream and no trajectory
    with BagWriter(tmp_path / "empty", static_transforms={"cam": np.eye(4)}) as bag:
        bag.write_sensors(None, t_ns=T0_NS)
    code, out, err = run_cli("import-log", str(tmp_path / "empty"))
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "no camera, depth or LiDAR stream and no trajectory" in err
    # --trajectory: a file with one pose; a file on another clock than the frames
    _odometry_bag(tmp_path / "nav")
    one = tmp_path / "one.tum"
    one.write_text("1700000000.0 0 0 0 0 0 0 1\n")
    code, out, err = run_cli("import-log", str(tmp_path / "nav"), "--trajectory", str(one))
    assert code == 2 and "1 pose(s); a trajectory needs two" in err and len(err.strip().splitlines()) == 1, err
    # a scenario naming an artifact of another kind, or none
    code, out, err = run_cli("import-log", str(tmp_path / "nav"), "--tag", "nav")
    assert code == 0, err
    for entry, words in (({"recording": "nosuch"}, "no artifact or ref named 'nosuch'"),
                         ({"registration": "nav"}, "robot.trajectory")):
        code, out, err = run_cli("simulate", "--scenario", str(_scenario(tmp_path, entry)), *FAST)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
        assert words in err
    assert len(store.all_ids()) == 1  # nothing else published


@pytest.mark.parametrize("storage", ["ros1"])
def test_trajectory_file_replaces_the_bag_s_and_must_share_its_clock(run_cli, tmp_path, storage):
    """A bag with a camera but no tf or odometry (a RealSense recording): --trajectory gives the body's path."""
    from nsim.geometry.cameras import Camera

    cam = Camera("PINHOLE", 16, 12, 20.0, 20.0, 8.0, 6.0)
    stamps, poses = _path(11)
    bag_path = tmp_path / "cam.bag"
    with BagWriter(bag_path, storage=storage, static_transforms={"cam_optical": np.eye(4)}) as bag:
        for t in stamps:
            bag.write_sensors(None, t_ns=int(t), images={"cam": np.full((12, 16, 3), 90, np.uint8)},
                              infos={"cam": cam})
    tum = tmp_path / "truth.tum"
    write_tum(tum, Trajectory.from_poses(stamps / 1e9, poses))
    code, out, err = run_cli("import-log", str(bag_path), "--trajectory", str(tum))
    assert code == 0, err
    doc = json.loads(Store(tmp_path / "ws").get(out.strip()).file("recording.json").read_text())
    assert doc["trajectory"]["source"] == "file truth.tum" and doc["trajectory_only"] is False
    assert all(e["inside_trajectory"] == len(stamps) for e in doc["streams"].values())
    # the same file 100 s later: not the bag's clock
    write_tum(tum, Trajectory.from_poses(stamps / 1e9 + 100.0, poses))
    code, out, err = run_cli("import-log", str(bag_path), "--trajectory", str(tum))
    assert code == 2 and "not the log's clock" in err and len(err.strip().splitlines()) == 1, err
