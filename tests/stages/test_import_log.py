"""``nsim import-log`` on a robot log nsim writes (nsim.synth.faulty_robot_log): streams, stamps, intrinsics,
extrinsics and the trajectory against the log's ground truth; bad input exits 2 with nothing published."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from nsim.cli import main
from nsim.crowd.paths import yaw_poses_se3
from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.exr import read_depth_exr, read_points_exr
from nsim.io.recording_output import inside_trajectory, kept_frames
from nsim.io.robot_log import RobotLog
from nsim.io.tum import read_tum
from nsim.rendering.render_plan import adapt_rig
from nsim.sensors.rig import CameraSensor, load_rig, static_transforms
from nsim.stages.capture import RobotLogConfig
from nsim.synth.faulty_robot_log import RobotLogFaults, write_robot_log
from nsim.synth.room import make_room
from nsim.workspace.store import Store


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A 6-tick clean log of Spot (32 x 24 cameras, a 16 x 90 LiDAR) in the robot lab; the odometry
    frame offset from the room's, and drift-free."""
    rig = adapt_rig(load_rig("nsim/configs/robots/spot.yaml"), RobotLogConfig(image_scale=0.05, lidar_azimuth_scale=0.05))
    spec = make_room("robot-lab", seed=0)
    n = 6
    cx, cy, rx, ry = spec.walk_loop_xy_m
    a = np.arange(n) * 0.1 / np.sqrt(rx * ry)
    body = yaw_poses_se3(np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], -1),
                         np.arctan2(ry * np.cos(a), -rx * np.sin(a)), 0.5)
    stamps = np.arange(n) * 0.1 + 100.0
    faults = dataclasses.replace(RobotLogFaults.none(), odom_frame_yaw_deg=30.0, odom_frame_xyz_m=(1.0, -0.5, 0.0))
    root = tmp_path_factory.mktemp("importlog")
    truth = write_robot_log(root / "run", spec, rig, body, stamps, faults, seed=1)
    return root / "run", rig, truth


@pytest.fixture(scope="module")
def imported(bag, tmp_path_factory):
    path, rig, truth = bag
    ws = tmp_path_factory.mktemp("ws")
    assert main(["--workspace", str(ws), "import-log", str(path), "--tag", "recording/run"]) == 0
    store = Store(ws)
    art = store.get(store.resolve("recording/run"))
    return ws, art, rig, truth, path


def test_streams_stamps_intrinsics_and_extrinsics_match_the_log(imported):
    ws, art, rig, truth, path = imported
    doc = json.loads(art.file("recording.json").read_text())
    cams = [s for s in rig.sensors if isinstance(s, CameraSensor)]
    kinds = sorted(k for k in doc["streams"])
    assert [k for k in kinds if k.startswith("camera/")] == sorted(f"camera/{s.name}" for s in cams)
    assert any(k.startswith("lidar/") for k in kinds)
    sensor_to_body = static_transforms(rig)
    with RobotLog(path) as rl:
        for key, entry in doc["streams"].items():
            kind, name = key.split("/")
            stamps = np.load(art.file(f"{kind}/{name}/stamps_ns.npy"))
            stream = {"camera": rl.cameras, "depth": rl.depth, "lidar": rl.lidars}[kind][name]
            np.testing.assert_array_equal(stamps, stream.stamps_ns)
            assert entry["frames"] == list(range(len(stream.stamps_ns)))
            assert entry["inside_trajectory"] == len(stamps)
            if kind == "camera":
                sensor = next(s for s in cams if s.name == name)
                assert Camera.from_dict(entry["camera"]) == sensor.camera
                frame = art.file(f"camera/{name}/{entry['frames'][1]:06d}.png")
                import cv2
                img = cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)
                want = rl.image(stream, 1)
                np.testing.assert_array_equal(img[..., ::-1] if img.ndim == 3 else img, want)
            elif kind == "depth":
                np.testing.assert_array_equal(read_depth_exr(art.file(f"depth/{name}/000002.exr")),
                                              rl.image(stream, 2))
            else:
                pts = read_points_exr(art.file(f"lidar/{name}/000000.exr"))
                cloud = next(iter(rl.clouds(stream)))[1]
                np.testing.assert_allclose(pts["X"][0], cloud.xyz_m[:, 0].astype(np.float32))
            # the extrinsic: the rig's sensor_to_body, through the bag's /tf_static
            np.testing.assert_allclose(np.array(entry["sensor_to_body"]), sensor_to_body[name], atol=1e-9)
    # the trajectory: the truth in the odometry frame (offset, no drift)
    traj = read_tum(art.file("trajectory.tum"))
    odom_to_world = np.array(truth["odom_to_world"])
    body_to_world = np.array(truth["body_to_world"])
    want = np.linalg.inv(odom_to_world) @ body_to_world
    np.testing.assert_allclose(traj.poses_se3(), want, atol=1e-6)
    stamps_ns = np.load(art.file("trajectory_ns.npy"))
    assert stamps_ns.dtype == np.int64 and len(stamps_ns) == len(want)
    assert art.file("preview.png").stat().st_size > 1000


def test_rerun_is_cached(imported, capsys):
    ws, art, _, _, path = imported
    capsys.readouterr()
    assert main(["--workspace", str(ws), "import-log", str(path)]) == 0
    out = capsys.readouterr()
    assert out.out.strip() == art.id and "cached" in out.err


def test_stride_and_max_frames(imported, tmp_path):
    ws, art, _, _, path = imported
    assert kept_frames(10, 3, 0).tolist() == [0, 3, 6, 9]
    assert kept_frames(10, 1, 3).tolist() == [0, 4, 9]
    assert kept_frames(2, 1, 5).tolist() == [0, 1]
    traj = np.array([0, 100, 200, 300], dtype=np.int64)
    assert inside_trajectory(np.array([-1, 0, 150, 300, 301]), traj, 60e-9).tolist() == [False, True, True, True, False]
    assert inside_trajectory(np.array([150]), traj, 40e-9).tolist() == [False]
    assert main(["--workspace", str(ws), "import-log", str(path), "--set", "frame_stride=2", "--tag", "rec/s2"]) == 0
    store = Store(ws)
    doc = json.loads(store.get(store.resolve("rec/s2")).file("recording.json").read_text())
    assert all(e["frames"] == [0, 2, 4] for e in doc["streams"].values())


def test_bad_input_exits_2_with_one_line_and_publishes_nothing(imported, tmp_path, capsys):
    ws, _, _, _, path = imported
    store = Store(ws)
    before = set(store.all_ids())
    sel = tmp_path / "sel.yaml"
    sel.write_text("lidar: {top: /no/such/points}\n")
    typo = tmp_path / "typo.yaml"
    typo.write_text("lidars: {top: /points}\n")
    cases = [
        (["import-log", str(tmp_path / "none.bag")], "no such file"),
        (["import-log", str(path), "--selection", str(sel)], "/no/such/points"),
        (["import-log", str(path), "--selection", str(typo)], "lidars"),
        (["import-log", str(path), "--set", "frame_stride=0"], "frame_stride"),
        (["import-log", str(path), "--tag", "bad ref name/.."], "ref"),
    ]
    for args, words in cases:
        capsys.readouterr()
        assert main(["--workspace", str(ws), *args]) == 2, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, (args, err)
    assert set(Store(ws).all_ids()) == before


def test_capture_robot_log_then_import(tmp_path, capsys):
    """``nsim capture robot-log`` of a simulated run (tiny preset) writes a bag and its truth; import-log reads it;
    bad destinations exit 2 before any rendering."""
    ws = str(tmp_path / "ws")
    assert main(["--workspace", ws, "simulate", "--scenario", "nsim/configs/scenarios/spot_run.json",
                 "--tag", "trajectory/run"]) == 0
    out = tmp_path / "run"
    assert main(["--workspace", ws, "capture", "robot-log", "trajectory/run", "--preset", "tiny", "--out", str(out)]) == 0
    truth = json.loads((tmp_path / "run.truth.json").read_text())
    assert len(truth["stamps_ns"]) == 8 and truth["stamps_ns"][0] == 1_700_000_000 * 10**9
    assert main(["--workspace", ws, "import-log", str(out), "--tag", "recording/run"]) == 0
    store = Store(ws)
    doc = json.loads(store.get(store.resolve("recording/run")).file("recording.json").read_text())
    assert doc["trajectory"]["poses"] == 8 and {v["kind"] for v in doc["streams"].values()} == {"camera", "depth", "lidar"}
    for args, words in (
        (["--out", str(out)], "exists already"),
        (["--out", str(tmp_path / "x" / "run")], "does not exist"),
        (["--out", str(tmp_path / "run2"), "--set", "storage=ros1"], "*.bag"),
        (["--out", str(tmp_path / "run3"), "--set", "faults.jpeg_quality=0"], "faults.jpeg_quality"),
    ):
        capsys.readouterr()
        assert main(["--workspace", ws, "capture", "robot-log", "trajectory/run", "--preset", "tiny", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, (args, err)
    assert not (tmp_path / "run2").exists() and not (tmp_path / "run3").exists()


def test_rebuild_reimports_the_log_from_where_it_was_read(imported, tmp_path):
    """`nsim verify --rebuild` re-imports the recorded log path; the same bag at another path gives the same id;
    a log that changed since is refused, one line."""
    import shutil

    from nsim.context import RunContext
    from nsim.stages import import_log

    ws, art, _, _, path = imported
    store = Store(ws)
    manifest = store.get(art.id).manifest
    assert manifest["timing"]["source"]["log"] == [str(Path(path).resolve())]
    ctx = RunContext(store=store, device_spec="cpu", seed=manifest["seed"] or 0)
    assert import_log.rebuild(manifest, ctx) == art.id
    moved = tmp_path / "elsewhere" / Path(path).name
    shutil.copytree(path, moved) if Path(path).is_dir() else (moved.parent.mkdir(), shutil.copy(path, moved))
    other = Store(tmp_path / "ws2")
    again = import_log.run(import_log.Inputs(log=(moved,)), import_log.Config(), dataclasses.replace(ctx, store=other))
    assert again.recording == art.id
    gone = dict(manifest, timing={**manifest["timing"], "source": {**manifest["timing"]["source"],
                                                                     "log": [str(tmp_path / "gone")]}})
    with pytest.raises(InputError, match="no longer there"):
        import_log.rebuild(gone, ctx)
    changed = dict(manifest, timing={**manifest["timing"], "source": {**manifest["timing"]["source"],
                                                                        "log": [str(moved)]}})
    victim = moved if moved.is_file() else sorted(p for p in moved.rglob("*") if p.is_file())[0]
    victim.write_bytes(victim.read_bytes() + b"\0")
    with pytest.raises(InputError, match="has changed"):
        import_log.rebuild(changed, ctx)
