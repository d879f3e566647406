"""``nsim register-log`` end to end at tiny size: a robot log of a simulated run (nsim capture robot-log, its
default faults: drifting odometry, a 30 ms camera clock offset, the odometry frame 35 deg and 1.4 m off the
room's) imported and registered into a scene of the same room; the result against the log's truth.

The scene is a poses artifact made here as ``tests/sfm/test_localize.py`` makes its scene: 40 frames of
the handheld capture path at 200x150, SIFT-matched by ``run_sfm``, then triangulated from the frames'
true poses, so that its world is the room's (metric, z up) and the registration's error is the
registration's own, not the scene's SfM error. The robot's log: Spot's five fisheye cameras at half size
(320x240: SIFT needs the pixels), 20 ticks 0.2 s apart (4 s, 4 m of the walk loop; a 2 s run does not
pin down the clock offset).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from nsim.cli import main
from nsim.geometry.transforms import invert_se3, rotation_angle_deg
from nsim.io.tum import read_tum
from nsim.workspace.store import Store

CAMERAS = "[frontleft,frontright,left,right,back]"
ROBOT_LOG = ["--preset", "tiny", "--set", f"sensors={CAMERAS}", "--set", "image_scale=0.5", "--set", "tick_stride=4",
             "--set", "max_ticks=20"]
# Tolerances at this size. 24 of 30 frames localise (the right and back cameras face walls that the scene's
# inward-facing capture never saw), with residuals of 1.5 cm / 0.17 deg (median) over a 4 m run. The drift
# refinement reports the odometry frame's standard error as 1.7 cm / 0.14 deg (its origin lies 6 m from the
# robot: 0.14 deg there is 1.5 cm) and the clock offset's as 7 ms; measured: 1.2 cm / 0.14 deg and 0.5 ms off
# the truth, the trajectory's ATE 6 mm (the rigid fit alone: 4.7 cm / 0.74 deg and 15 ms, bent by the drift
# of a 4 m run). The bounds are two (position, clock) and three (rotation) standard errors.
MAX_ODOM_FRAME_M = 0.035
MAX_ODOM_FRAME_DEG = 0.4
MAX_CLOCK_ERROR_S = 0.015
MAX_ATE_M = 0.02


def _scene(store: Store, root) -> str:
    """A poses artifact of the robot lab: images/, a metric COLMAP model in sparse/, transforms.json."""
    import cv2  # noqa: F401  (before pycolmap, see nsim.sfm.colmap)
    import pycolmap

    from nsim.geometry.cameras import Camera
    from nsim.io.images import to_uint8, write_image
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms
    from nsim.sfm.colmap import colmap_log_level, run_sfm
    from nsim.sfm.options import SfmOptions
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.path import handheld_path
    from nsim.synth.room import make_room

    camera = Camera.pinhole_from_fov(200, 150, 75.0)
    spec = make_room("robot-lab", 0)
    oracle = RoomOracle(spec)
    poses = handheld_path(spec, 40, seed=0)
    images = root / "scene" / "images"
    images.mkdir(parents=True)
    for i, c2w in enumerate(poses):
        write_image(images / f"frame_{i:05d}.png", to_uint8(oracle.render_gt(camera, c2w, 1).rgb))
    work = root / "sfm"
    rec = run_sfm(images, work, SfmOptions(num_threads=2), known_camera=camera).reconstruction
    for image in rec.images.values():
        if image.has_pose:
            w2c = invert_se3(poses[int(image.name[6:11])])
            rec.frames[image.frame_id].set_cam_from_world(image.camera_id, pycolmap.Rigid3d(w2c[:3, :]))
    sparse = root / "scene" / "sparse"
    sparse.mkdir()
    with colmap_log_level():
        rec = pycolmap.triangulate_points(rec, work / "database.db", images, sparse)
    rec.write(sparse)
    key = store.action_key("test_scene", 1, {"frames": 40}, {})
    with store.publish(kind="poses", stage="test_scene", version=1, key=key, config={}, inputs={}) as out:
        shutil.copytree(images, out.dir / "images")
        shutil.copytree(sparse, out.dir / "sparse")
        write_transforms(out.dir / "transforms.json", TransformsData(
            frames=[Frame(f"images/frame_{i:05d}.png", c2w, camera) for i, c2w in enumerate(poses)],
            extra={"nsim_metric": True, "nsim_z_up": True}))
    return out.ref


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("register_log")
    ws = root / "ws"
    store = Store(ws)
    store.set_ref("poses/scene", _scene(store, root))
    w = ["--workspace", str(ws)]
    assert main([*w, "simulate", "--scenario", "nsim/configs/scenarios/spot_run.json", "--preset", "tiny",
                 "--tag", "trajectory/run"]) == 0
    bag = root / "run"
    assert main([*w, "capture", "robot-log", "trajectory/run", *ROBOT_LOG, "--out", str(bag)]) == 0
    assert main([*w, "import-log", str(bag), "--tag", "recording/run"]) == 0
    assert main([*w, "register-log", "recording/run", "--poses", "poses/scene", "--preset", "tiny",
                 "--tag", "registration/run"]) == 0
    truth = json.loads((root / "run.truth.json").read_text())
    return ws, store, truth


def test_recovers_the_odometry_frame_and_the_clock_offset(world):
    ws, store, truth = world
    art = store.get(store.resolve("registration/run"))
    assert art.manifest["kind"] == "registration"
    doc = json.loads(art.file("registration.json").read_text())
    assert doc["inputs"] == {"recording": store.resolve("recording/run"), "poses": store.resolve("poses/scene")}
    # the odometry frame and the clock against the log's truth
    want = np.array(truth["odom_to_world"])
    got = np.array(doc["odom_to_world"])
    pos_err = float(np.linalg.norm(got[:3, 3] - want[:3, 3]))
    rot_err = float(rotation_angle_deg(got[:3, :3], want[:3, :3]))
    assert pos_err < MAX_ODOM_FRAME_M and rot_err < MAX_ODOM_FRAME_DEG, (pos_err, rot_err)
    assert abs(doc["clock_offset_s"] - truth["clock_offset_s"]) < MAX_CLOCK_ERROR_S, doc["clock_offset_s"]
    assert doc["scale"] == 1.0 and doc["refined"]["nodes"] >= 2 and doc["rigid"]["odom_to_world"] != doc["odom_to_world"]
    # the frames: most localised, each record complete; the statistics are the inliers'
    loc = doc["localised"]
    assert loc["tried"] == 30 and loc["localised"] >= 20 and set(loc["per_camera"]) == {"frontleft", "frontright", "left",
                                                                                      "right", "back"}
    localised = [f for f in doc["frames"] if f["localised"]]
    assert len(localised) == loc["localised"]
    for f in localised:
        assert {"camera", "index", "stamp_ns", "inliers", "reprojection_error_px", "cam_to_world", "rigid", "refined"} <= set(f)
    refined = np.array([f["refined"]["residual_m"] for f in localised if f["refined"]["inlier"]])
    assert doc["residual"]["inliers"] == len(refined) >= 15
    assert doc["residual"]["median_m"] == pytest.approx(float(np.median(refined))) and doc["residual"]["median_m"] < 0.03
    # the body's trajectory in the world, at the recording's odometry stamps, against the true run
    rec = store.get(store.resolve("recording/run"))
    stamps = np.load(art.file("trajectory_world_ns.npy"))
    np.testing.assert_array_equal(stamps, np.load(rec.file("trajectory_ns.npy")))
    np.testing.assert_array_equal(stamps, np.array(truth["stamps_ns"]))
    body = read_tum(art.file("trajectory_world.tum")).poses_se3()
    truth_body = np.array(truth["body_to_world"])
    ate = float(np.sqrt(np.mean(np.sum((body[:, :3, 3] - truth_body[:, :3, 3]) ** 2, axis=-1))))
    assert ate < MAX_ATE_M, ate
    np.testing.assert_allclose(body[0], got @ read_tum(rec.file("trajectory.tum")).poses_se3()[0], atol=1e-9)
    assert art.file("preview.png").stat().st_size > 10_000


def test_rerun_is_cached_and_a_forced_rerun_is_identical(world, capsys):
    ws, store, _ = world
    capsys.readouterr()
    assert main(["--workspace", str(ws), "register-log", "recording/run", "--poses", "poses/scene",
                 "--preset", "tiny"]) == 0
    out = capsys.readouterr()
    assert out.out.strip() == store.resolve("registration/run") and "cached" in out.err
    # determinism, on a smaller action (one camera, three frames, the clock offset given): same artifact id
    small = ["--set", "cameras=[left]", "--set", "frames_per_camera=3", "--set", "register.clock_offset_s=0.03"]
    ids = []
    for force in ([], ["--force"]):
        assert main(["--workspace", str(ws), "register-log", "recording/run", "--poses", "poses/scene",
                     "--preset", "tiny", *small, *force]) == 0
        out = capsys.readouterr()
        assert "published" in out.err
        ids.append(out.out.strip())
    assert ids[0] == ids[1]
    doc = json.loads(store.get(ids[0]).file("registration.json").read_text())
    assert doc["clock_offset_s"] == 0.03 and doc["clock_offset_std_s"] is None and doc["localised"]["tried"] == 3


def test_bad_input_exits_2_with_one_line_and_publishes_nothing(world, tmp_path, capsys):
    ws, store, _ = world
    scene = store.get(store.resolve("poses/scene"))
    # a poses artifact without a sparse model (an --import), and one whose scale is arbitrary
    for tag, keep_sparse, metric in (("poses/nosparse", False, True), ("poses/arbitrary", True, False)):
        key = store.action_key("test_scene", 1, {"variant": tag}, {})
        with store.publish(kind="poses", stage="test_scene", version=1, key=key, config={}, inputs={}) as out:
            shutil.copytree(scene.path / "images", out.dir / "images")
            if keep_sparse:
                shutil.copytree(scene.path / "sparse", out.dir / "sparse")
            doc = json.loads(scene.file("transforms.json").read_text())
            (out.dir / "transforms.json").write_text(json.dumps(doc | {"nsim_metric": metric}))
        store.set_ref(tag, out.ref)
    before = set(store.all_ids())
    cases = [
        (["poses/scene", "--poses", "poses/scene"], "a poses artifact; expected a recording"),
        (["recording/run", "--poses", "recording/run"], "a recording artifact; expected a poses"),
        (["recording/run", "--poses", "trajectory/run"], "a trajectory artifact; expected a poses"),
        (["recording/run", "--poses", "poses/nosparse"], "no COLMAP model in sparse/"),
        (["recording/run", "--poses", "poses/arbitrary"], "scale is arbitrary"),
        (["recording/run", "--poses", "poses/scene", "--set", "cameras=[left,nosuch]"], "no camera named 'nosuch'"),
        (["recording/run", "--poses", "poses/scene", "--set", "register.max_gap_s=-1"], "register.max_gap_s"),
        (["recording/run", "--poses", "poses/scene", "--set", "drift.node_spacing_m=0"], "drift.node_spacing_m"),
        (["nosuch", "--poses", "poses/scene"], "no artifact or ref named 'nosuch'"),
        # too few frames to register: one line saying so (two frames localised, three needed)
        (["recording/run", "--poses", "poses/scene", "--set", "cameras=[left]", "--set", "frames_per_camera=2"],
         "only 2 of 2 frames localised"),
    ]
    for args, words in cases:
        capsys.readouterr()
        assert main(["--workspace", str(ws), "register-log", *args, "--preset", "tiny"]) == 2, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, (args, err)
    assert set(Store(ws).all_ids()) == before
