"""`nsim render --recording` at tiny size: a robot log of the test room (nsim.synth.faulty_robot_log: two of
Spot's fisheye cameras with depth, one of them grey, and its LiDAR; a 30 ms camera clock offset and
the odometry frame 30 deg and 1.1 m off the room's), imported, registered with its truth (a
``registration`` artifact published here, as register-log would write it: register-log's SfM is
tested in test_register_log.py), rendered on a micro scene NeRF of the same room; the render
against the log's truth and its recorded readings, the cache, and bad input.

People: a log of an ``nsim simulate`` run of spot_run.json written by ``nsim capture robot-log`` (its
clock: the run's first tick at 1.7e9 s), rendered with the run's people (one of them moved to cross
in front of the robot, the others removed) drawn by a briefly trained human checkpoint; the person
masks against the oracle's actor posed at each frame's true tick, with the default time origin and
with a wrong one."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
import yaml

from nsim.cli import main
from nsim.crowd.paths import yaw_poses_se3
from nsim.geometry.transforms import make_se3
from nsim.io.exr import read_depth_exr, read_exr, read_exr_attributes, read_points_exr
from nsim.io.images import read_image
from nsim.io.tum import Trajectory, write_tum
from nsim.metrics.image import psnr
from nsim.rendering.render_plan import adapt_rig
from nsim.sensors.rig import load_rig
from nsim.stages.capture import RobotLogConfig
from nsim.synth.faulty_robot_log import RobotLogFaults, write_robot_log
from nsim.synth.room import make_room
from nsim.workspace.store import Store
from tests.stages.micro import CAPTURE

TICKS = 4
SENSORS = ("frontleft", "left", "lidar")
# The scene: the tiny preset on a 64 x 48 fisheye capture of the same room, 250 steps with its depth images'
# supervision (loss.image_depth_weight: geometry in seconds), so that walls and floor sit where the room's are.
CAPTURE_FISHEYE = [*CAPTURE, "camera=fisheye"]
# Bounds (measured values in the test's docstring): each fails for the wrong registration on at least one camera
MIN_PSNR_GAIN_DB = 1.0
MAX_DEPTH_ABS_REL = 0.04
MAX_LIDAR_MEDIAN_M = 0.1
SCENE = {"optim": {"steps": 250}, "loss": {"image_depth_weight": 1.0}}


def _rig():
    """Spot's front-left (RGB) and left (grey) fisheyes at 32 x 24 with z-depth, its LiDAR at 16 x 90."""
    rig = adapt_rig(load_rig("nsim/configs/robots/spot.yaml"),
                    RobotLogConfig(sensors=SENSORS, image_scale=0.05, lidar_azimuth_scale=0.05))
    grey = tuple(dataclasses.replace(s, color="gray") if s.name == "left" else s for s in rig.sensors)
    return dataclasses.replace(rig, sensors=grey)


def _registration(store: Store, rec: str, poses: str, stamps_ns, body_to_world, odom_to_world, offset_s: float,
                  tag: str) -> str:
    """A registration artifact (register-log's layout) with the given trajectory and clock offset."""
    key = store.action_key("test_registration", 1, {"tag": tag}, {"recording": rec})
    with store.publish(kind="registration", stage="test_registration", version=1, key=key, config={"tag": tag},
                       inputs={"recording": rec, "poses": poses}) as out:
        np.save(out.dir / "trajectory_world_ns.npy", np.asarray(stamps_ns, dtype=np.int64))
        write_tum(out.dir / "trajectory_world.tum", Trajectory.from_poses(np.asarray(stamps_ns) / 1e9, body_to_world))
        doc = {"format": 1, "inputs": {"recording": rec, "poses": poses}, "odom_to_world": np.asarray(odom_to_world).tolist(),
               "scale": 1.0, "clock_offset_s": offset_s, "clock_offset_meaning": "camera stamp minus odometry time"}
        (out.dir / "registration.json").write_text(json.dumps(doc, indent=1) + "\n")
    store.set_ref(f"registration/{tag}", out.ref)
    return out.ref


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("render_recording")
    ws = root / "ws"
    w = ["--workspace", str(ws)]
    # the scene: a NeRF of the robot lab from a handheld capture
    args = [*w, "capture", "synth"]
    for kv in CAPTURE_FISHEYE:
        args += ["--set", kv]
    assert main([*args, "--tag", "capture/t"]) == 0
    cfg_file = root / "scene.yaml"
    cfg_file.write_text(yaml.safe_dump(SCENE))
    assert main([*w, "--device", "cpu", "train-scene", "--poses", "capture/t", "--preset", "tiny", "--config",
                 str(cfg_file), "--tag", "scene/t"]) == 0
    # the robot's log: a stretch of the room's walk loop
    rig = _rig()
    spec = make_room("robot-lab", seed=0)
    cx, cy, rx, ry = spec.walk_loop_xy_m
    a = np.arange(TICKS) * 0.15 / np.sqrt(rx * ry)
    body = yaw_poses_se3(np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], -1),
                         np.arctan2(ry * np.cos(a), -rx * np.sin(a)), 0.5)
    faults = dataclasses.replace(RobotLogFaults.none(), clock_offset_s=0.03, odom_frame_yaw_deg=30.0,
                                 odom_frame_xyz_m=(1.0, -0.5, 0.0))
    truth = write_robot_log(root / "run", spec, rig, body, np.arange(TICKS) * 0.1 + 100.0, faults, seed=1)
    assert main([*w, "import-log", str(root / "run"), "--tag", "recording/run"]) == 0
    store = Store(ws)
    rec, poses = store.resolve("recording/run"), store.resolve("capture/t")
    stamps = np.array(truth["stamps_ns"], dtype=np.int64)
    body_to_world = np.array(truth["body_to_world"])
    odom = np.array(truth["odom_to_world"])
    _registration(store, rec, poses, stamps, body_to_world, odom, truth["clock_offset_s"], "truth")
    # the same registration with the odometry frame 0.3 m and 8 deg off: a wrong pose for every frame
    wrong = make_se3(yaw_poses_se3(np.zeros((1, 2)), np.radians([8.0]), 0.0)[0, :3, :3], np.array([0.3, -0.1, 0.0]))
    _registration(store, rec, poses, stamps, wrong @ body_to_world, wrong @ odom, truth["clock_offset_s"], "wrong")
    # a trajectory that begins one tick late: each stream's first frame lies outside it
    _registration(store, rec, poses, stamps[1:], body_to_world[1:], odom, truth["clock_offset_s"], "late")
    return store, rig, truth


def render(store: Store, registration: str, *extra: str, tag: str | None = None) -> int:
    args = ["--workspace", str(store.root), "--device", "cpu", "render", "--recording", registration,
            "--scene", "scene/t", "--set", "video=false", *extra]
    return main([*args, "--tag", tag] if tag else args)


@pytest.fixture(scope="module")
def rendered(world):
    store, rig, truth = world
    assert render(store, "registration/truth", tag="render/truth") == 0
    art = store.get(store.resolve("render/truth"))
    return art, json.loads(art.file("render.json").read_text())


@pytest.fixture(scope="module")
def rendered_wrong(world):
    store, _, _ = world
    assert render(store, "registration/wrong", tag="render/wrong") == 0
    return store.get(store.resolve("render/wrong"))


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two images with 8-bit values (uint8, or float in [0, 255])."""
    return psnr(np.asarray(a, np.float64) / 255.0, np.asarray(b, np.float64) / 255.0)


def camera_scores(art, rec, name: str) -> tuple[float, float]:
    """Mean PSNR (dB) of the rendered frames of camera ``name`` against the recorded ones, and of each
    recorded frame's own mean colour (the best constant image) against it."""
    sim, const = [], []
    for i in range(TICKS):
        real = read_image(rec.file(f"camera/{name}/{i:06d}.png"))
        sim.append(_psnr(read_image(art.file(f"camera/{name}/{i:06d}.png")), real))
        flat = real.reshape(-1, *real.shape[2:]).astype(np.float64)
        const.append(_psnr(np.broadcast_to(flat.mean(0), real.shape), real))
    return float(np.mean(sim)), float(np.mean(const))


def depth_abs_rel(art, rec, name: str) -> float:
    """Median |sim - real| / real over the pixels where both depth images are finite, every frame."""
    rel = []
    for i in range(TICKS):
        real = read_depth_exr(rec.file(f"depth/{name}/{i:06d}.exr"))
        sim = read_depth_exr(art.file(f"depth/{name}/{i:06d}.exr"))
        ok = np.isfinite(real) & np.isfinite(sim)
        rel.append(np.abs(sim[ok] - real[ok]) / real[ok])
    return float(np.median(np.concatenate(rel)))


def lidar_median_error_m(art, rec, i: int) -> float:
    sim = read_points_exr(art.file(f"lidar/lidar/{i:06d}.exr"))["range"][0]
    real = np.linalg.norm(np.stack([read_points_exr(rec.file(f"lidar/lidar/{i:06d}.exr"))[c][0] for c in "XYZ"], -1), axis=-1)
    hit = np.isfinite(sim)
    return float(np.median(np.abs(sim[hit] - real[hit])))


def test_render_json_and_poses_are_the_truth(world, rendered):
    store, rig, truth = world
    art, meta = rendered
    assert meta["mode"] == "recording" and meta["scene"] == store.resolve("scene/t")
    assert meta["recording"] == store.resolve("recording/run")
    assert meta["registration"] == store.resolve("registration/truth")
    assert sorted((s["kind"], s["name"]) for s in meta["streams"]) == sorted(
        [("camera", "frontleft"), ("camera", "left"), ("depth", "frontleft"), ("depth", "left"), ("lidar", "lidar")])
    body = np.array(truth["body_to_world"])
    sensors = {s.name: s for s in rig.sensors}
    for st in meta["streams"]:
        assert st["skipped_outside_trajectory"] == 0 and [f["index"] for f in st["frames"]] == list(range(TICKS))
        camera_clock = st["kind"] == "camera"
        for f in st["frames"]:
            i = f["index"]  # the log records every sensor once per tick
            want_stamp = truth["camera_frames"]["stamps_ns"][i] if camera_clock else truth["stamps_ns"][i]
            assert f["stamp_ns"] == want_stamp and f["odom_time_ns"] == truth["stamps_ns"][i]
            np.testing.assert_allclose(np.array(f["sensor_to_world"]), sensors[st["name"]].world_pose(body[i]), atol=1e-6)


def test_images_depth_and_lidar_match_the_recording_and_a_wrong_pose_does_not(world, rendered, rendered_wrong):
    """Measured at this size: PSNR 26.8 / 29.6 dB (front-left RGB / left grey) against 24.9 / 22.6 for the
    best constant image and 25.1 / 27.9 with the odometry frame 0.3 m and 8 deg off; depth AbsRel 0.017 /
    0.008 (off: 0.063 / 0.019); LiDAR median range error 4 cm (off: 37-40 cm)."""
    store, _, _ = world
    art, meta = rendered
    rec = store.get(meta["recording"])
    for name in ("frontleft", "left"):
        psnr, const = camera_scores(art, rec, name)
        wrong, _ = camera_scores(rendered_wrong, rec, name)
        assert psnr > const + MIN_PSNR_GAIN_DB and psnr > wrong + MIN_PSNR_GAIN_DB, (name, psnr, const, wrong)
        rel, rel_wrong = depth_abs_rel(art, rec, name), depth_abs_rel(rendered_wrong, rec, name)
        assert rel < MAX_DEPTH_ABS_REL and rel_wrong > 1.5 * rel, (name, rel, rel_wrong)
    for i in range(TICKS):
        assert lidar_median_error_m(art, rec, i) < MAX_LIDAR_MEDIAN_M < lidar_median_error_m(rendered_wrong, rec, i)


def _files(art_dir, kinds=("camera", "depth", "lidar")) -> list[str]:
    return sorted(str(p.relative_to(art_dir)) for k in kinds for p in (art_dir / k).rglob("*")
                  if p.is_file() and p.name != "stamps_ns.npy")


def test_files_mirror_the_recording(world, rendered):
    store, _, _ = world
    art, meta = rendered
    rec = store.get(meta["recording"])
    assert _files(art.path) == _files(rec.path) and len(_files(art.path)) == 5 * TICKS
    for name, grey in (("frontleft", False), ("left", True)):
        sim, real = (cv2.imread(str(a.file(f"camera/{name}/000003.png")), cv2.IMREAD_UNCHANGED) for a in (art, rec))
        assert sim.shape == real.shape == ((24, 32) if grey else (24, 32, 3)) and sim.dtype == np.uint8
        path = art.file(f"depth/{name}/000003.exr")
        assert set(read_exr(path)) == {"Z"} and read_exr(path)["Z"].dtype == np.float32
        assert read_depth_exr(path).shape == read_depth_exr(rec.file(f"depth/{name}/000003.exr")).shape
        assert "z-depth" in read_exr_attributes(path)["nsim_depth"]
    sim, real = read_points_exr(art.file("lidar/lidar/000003.exr")), read_points_exr(rec.file("lidar/lidar/000003.exr"))
    assert set(sim) == {"X", "Y", "Z", "range"} and all(v.dtype == np.float32 for v in sim.values())
    assert sim["range"].shape == real["X"].shape and sim["range"].shape[0] == 1
    assert art.file("preview/contact_sheet.png").stat().st_size > 1000


def test_lidar_ranges_pair_point_for_point(world, rendered):
    """Every simulated point lies on its recorded point's ray; where the scene returns, at nearly its range."""
    store, _, _ = world
    art, meta = rendered
    rec = store.get(meta["recording"])
    for i in range(TICKS):
        sim = read_points_exr(art.file(f"lidar/lidar/{i:06d}.exr"))
        real = read_points_exr(rec.file(f"lidar/lidar/{i:06d}.exr"))
        xyz_real = np.stack([real[c][0] for c in "XYZ"], -1).astype(np.float64)
        xyz_sim = np.stack([sim[c][0] for c in "XYZ"], -1).astype(np.float64)
        r_real, r_sim = np.linalg.norm(xyz_real, axis=-1), sim["range"][0].astype(np.float64)
        hit = np.isfinite(r_sim)
        assert hit.mean() > 0.9  # a closed room: almost every beam returns
        assert np.isnan(xyz_sim[~hit]).all() and np.isinf(r_sim[~hit]).all()
        np.testing.assert_allclose(xyz_sim[hit] / r_sim[hit, None], xyz_real[hit] / r_real[hit, None], atol=1e-5)
        np.testing.assert_allclose(np.linalg.norm(xyz_sim[hit], axis=-1), r_sim[hit], rtol=1e-5)
        err = np.abs(r_sim[hit] - r_real[hit])
        assert np.median(err) < MAX_LIDAR_MEDIAN_M, np.median(err)


def test_rerun_is_a_cache_hit_with_the_same_id(world, rendered, capsys):
    store, _, _ = world
    art, _ = rendered
    capsys.readouterr()
    assert render(store, "registration/truth") == 0
    out = capsys.readouterr()
    assert out.out.strip() == art.id and "cached" in out.err
    # a forced rerun renders the same bytes: the same artifact id (on one stream and frame, for time)
    ids = []
    for force in ([], ["--force"]):
        assert render(store, "registration/truth", "--set", "sensors=[lidar]", "--set", "max_frames=1", *force) == 0
        ids.append(capsys.readouterr().out.strip())
    assert ids[0] == ids[1] and ids[0] != art.id


def test_frames_outside_the_trajectory_are_skipped_and_counted(world):
    store, _, _ = world
    assert render(store, "registration/late", "--set", "sensors=[lidar,camera/left]", tag="render/late") == 0
    meta = json.loads(store.get(store.resolve("render/late")).file("render.json").read_text())
    assert [(s["kind"], s["name"]) for s in meta["streams"]] == [("camera", "left"), ("lidar", "lidar")]
    for st in meta["streams"]:
        assert st["skipped_outside_trajectory"] == 1 and [f["index"] for f in st["frames"]] == list(range(1, TICKS))
    art = store.get(store.resolve("render/late"))
    assert _files(art.path) == sorted(f"{k}/{i:06d}.{x}" for k, x in (("camera/left", "png"), ("lidar/lidar", "exr"))
                                      for i in range(1, TICKS))


# ---------------------------------------------------------------------------------- bad input
def _not_metric(store: Store) -> str:
    """A scene checkpoint whose scene.json says its world has no metric scale (nothing else is read first)."""
    key = store.action_key("test_scene", 1, {"metric": False}, {})
    with store.publish(kind="scene-checkpoint", stage="test_scene", version=1, key=key, config={}, inputs={}) as out:
        (out.dir / "scene.json").write_text(json.dumps({"format": 1, "metric": False, "units": "arbitrary"}) + "\n")
    return out.ref


@pytest.mark.parametrize("case, args, fragments", [
    ("not a registration", ["--recording", "recording/run"], ["a recording artifact", "needs a registration"]),
    ("no such stream", ["--recording", "registration/truth", "--set", "sensors=[left,back]"],
     ["sensors:", "no stream 'back'", "camera/left"]),
    ("not metric", ["--recording", "registration/truth", "--scene", "NOT_METRIC"], ["scale is arbitrary"]),
    ("scaled", ["--recording", "registration/truth", "--set", "image_scale=0.5"], ["image_scale 0.5", "recorded sizes"]),
    ("lidar scaled", ["--recording", "registration/truth", "--set", "lidar_azimuth_scale=0.5"],
     ["lidar_azimuth_scale 0.5", "set lidar_azimuth_scale to 1"]),
    ("people without a run", ["--recording", "registration/truth", "--humans", "scene/t"],
     ["--humans needs --trajectory"]),
    ("two modes", ["--recording", "registration/truth", "--poses", "capture/t"],
     ["exactly one of --trajectory, --poses or --recording"]),
    ("no scene", ["--recording", "registration/truth", "--scene", None], ["pass --scene"]),
])
def test_bad_input_is_one_line_and_publishes_nothing(world, capsys, case, args, fragments):
    store, _, _ = world
    args = [store.resolve(_not_metric(store)) if a == "NOT_METRIC" else a for a in args]
    if None in args:  # no --scene at all
        args = args[:-2]
    elif "--scene" not in args:
        args += ["--scene", "scene/t"]
    before = set(store.all_ids())
    capsys.readouterr()
    code = main(["--workspace", str(store.root), "--device", "cpu", "render", *args])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("WARNING")]
    assert len(lines) == 1 and "Traceback" not in err, err
    for f in fragments:
        assert f in lines[0], lines[0]
    assert set(store.all_ids()) == before


def test_a_scale_refuses_only_the_streams_it_scales(world):
    """A preset's LiDAR scale is no reason to refuse rendering a recording's cameras (the plan is made, no render)."""
    from nsim.errors import InputError
    from nsim.rendering.render_job import ArtifactDir, RenderSources
    from nsim.rendering.render_plan import RenderConfig, plan_recording

    store, _, _ = world
    reg = store.resolve("registration/truth")
    rec = store.get(reg).manifest["inputs"]["recording"]
    sources = RenderSources(scene=None, trajectory=None, poses=None, registration=ArtifactDir(reg, store.get(reg).path),
                            recording=ArtifactDir(rec, store.get(rec).path), humans=(), baked=None, rig_file=None)
    cfg = dataclasses.replace(RenderConfig(), lidar_azimuth_scale=0.05, sensors=("left",))
    plan = plan_recording(sources, cfg)
    assert plan.frames and not any(f.stream.startswith("lidar/") for f in plan.frames)
    with pytest.raises(InputError, match="lidar_azimuth_scale 0.05"):
        plan_recording(sources, dataclasses.replace(cfg, sensors=("left", "lidar")))


# ---------------------------------------------------------------------------------- the core, analytically
def test_core_clock_poses_and_points():
    from nsim.rendering import recording as core

    # a frame stamped s on the cameras' clock was captured at odometry time s - clock_offset_s
    np.testing.assert_array_equal(core.odometry_time_ns(np.array([1_000_030_000_000]), 0.03, True), [1_000_000_000_000])
    np.testing.assert_array_equal(core.odometry_time_ns(np.array([5]), 0.03, False), [5])
    # halfway between two poses: the mean position and half the turn; outside the span: NaN, not held
    traj = np.array([10**18, 10**18 + 10**9], dtype=np.int64)
    body = yaw_poses_se3(np.array([[0.0, 0.0], [2.0, 0.0]]), np.radians([0.0, 90.0]), 0.5)
    mount = make_se3(np.eye(3), np.array([1.0, 0.0, 0.0]))
    inside, b, w = core.sensor_poses(traj[:1] + np.array([5 * 10**8, -1, 10**9 + 1]), traj, body, mount)
    assert inside.tolist() == [True, False, False] and np.isnan(w[1:]).all()
    np.testing.assert_allclose(b[0], yaw_poses_se3(np.array([[1.0, 0.0]]), np.radians([45.0]), 0.5)[0], atol=1e-12)
    np.testing.assert_allclose(w[0], b[0] @ mount)
    # a recorded point's ray and the simulated point on it
    dirs, valid = core.point_directions(np.array([[3.0, 4.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    assert valid.tolist() == [True, False, False] and np.allclose(dirs[0], [0.6, 0.8, 0.0])
    xyz = core.points_from_ranges(dirs, np.array([10.0, np.inf, np.nan]))
    np.testing.assert_allclose(xyz[0], [6.0, 8.0, 0.0])
    assert np.isnan(xyz[1:]).all()
    # streams by key or by bare name; an unknown one is named
    keys = ["camera/a", "camera/b", "depth/a", "lidar/l"]
    assert core.select_streams(keys, ()) == keys and core.select_streams(keys, ("a", "lidar/l")) == [
        "camera/a", "depth/a", "lidar/l"]
    with pytest.raises(ValueError, match="'c'"):
        core.select_streams(keys, ("b", "c"))
    assert core.select_frames(np.array([0, 2, 4, 6, 8]), 3, 2).tolist() == [2, 4]


# ---------------------------------------------------------------------------------- people
PEOPLE_STRIDE, PEOPLE_TICKS = 5, 4  # the log records ticks 0, 5, 10, 15 of a 1 s run (dt 0.05 s)
CROSS_X_M, CROSS_Y_M = 1.5, (1.0, -1.0)  # person 0's path in the robot's body frame over the run: x ahead, y left
LATE_S = 0.6  # a wrong time origin: ticks 0 and 5 see the people of 0.6 and 0.85 s, ticks 10 and 15 none


def _crossing(store: Store, traj: str) -> str:
    """``traj`` with person 0 crossing in front of the robot (``CROSS_*``, facing its way) and the others gone."""
    a = dict(np.load(store.get(traj).file("trajectory.npz"), allow_pickle=False))
    poses, t = a["robot_pose_se3"], a["time_s"]
    y = np.interp(t, [t[0], t[-1]], CROSS_Y_M)
    a["position_m"] = np.full_like(a["position_m"], np.nan)
    a["position_m"][:, 0] = np.einsum("tij,tj->ti", poses[:, :2, :2], np.stack([np.full_like(y, CROSS_X_M), y], -1)) \
        + poses[:, :2, 3]
    a["heading_rad"] = a["heading_rad"].copy()
    a["heading_rad"][:, 0] = np.arctan2(poses[:, 1, 0], poses[:, 0, 0]) - np.pi / 2
    with store.publish(kind="trajectory", stage="test_render_recording", version=1,
                       key=store.action_key("test_crossing", 1, {}, {"trajectory": traj}), config={},
                       inputs={"trajectory": traj}) as out:
        np.savez(out.dir / "trajectory.npz", **a)
    store.set_ref("trajectory/crossing", out.ref)
    return out.ref


@pytest.fixture(scope="module")
def people(world, tmp_path_factory):
    store, _, _ = world
    root = tmp_path_factory.mktemp("render_recording_people")
    w = ["--workspace", str(store.root)]
    assert main([*w, "simulate", "--scenario", "nsim/configs/scenarios/spot_run.json", "--preset", "tiny", "--set",
                 "max_duration_s=1.0", "--set", "video=false", "--tag", "trajectory/run"]) == 0
    bag = root / "run"
    assert main([*w, "capture", "robot-log", "trajectory/run", "--preset", "tiny", "--set", "sensors=[frontleft]",
                 "--set", f"tick_stride={PEOPLE_STRIDE}", "--set", f"max_ticks={PEOPLE_TICKS}", "--out", str(bag)]) == 0
    assert main([*w, "import-log", str(bag), "--tag", "recording/people"]) == 0
    truth = json.loads((root / "run.truth.json").read_text())
    rec, poses = store.resolve("recording/people"), store.resolve("capture/t")
    _registration(store, rec, poses, truth["stamps_ns"], np.array(truth["body_to_world"]), np.array(truth["odom_to_world"]),
                  truth["clock_offset_s"], "people")
    _crossing(store, store.resolve("trajectory/run"))
    assert main([*w, "capture", "synth", "--preset", "tiny", "--actor", "--set", "n_frames=12", "--set", "supersample=1",
                 "--set", "video=false", "--tag", "capture/actor"]) == 0
    assert main([*w, "--device", "cpu", "train-human", "--capture", "capture/actor", "--preset", "tiny", "--steps", "60",
                 "--tag", "human/t"]) == 0
    people_args = ["--trajectory", "trajectory/crossing", "--humans", "human/t", "--set", "sensors=[camera/frontleft]"]
    assert render(store, "registration/people", *people_args, tag="render/people") == 0
    assert render(store, "registration/people", *people_args, "--set", f"people_time_offset_s={LATE_S}",
                  tag="render/people-late") == 0
    return store, truth, people_args


def _truth_masks(store: Store, truth: dict) -> list[np.ndarray]:
    """Per recorded frame, the oracle's person mask: the actor posed at the frame's tick (trajectory mode's
    ``HumanSet.joint_transforms``), seen by the rig's front-left camera at the log's true body pose."""
    from nsim.rendering.people import HumanSet
    from nsim.synth.actor import Actor
    from nsim.synth.oracle import PlacedActor, RoomOracle

    arrays = dict(np.load(store.get(store.resolve("trajectory/crossing")).file("trajectory.npz"), allow_pickle=False))
    people = HumanSet([], arrays, "cpu")
    cam = adapt_rig(load_rig("nsim/configs/robots/spot.yaml"), RobotLogConfig(sensors=("frontleft",), image_scale=0.1)).sensors[0]
    oracle = RoomOracle(make_room("robot-lab", seed=0))
    masks = []
    for i in range(PEOPLE_TICKS):
        actors = [PlacedActor(Actor(float(arrays["height_m"][k]), seed=0), T, instance_id=k + 1)
                  for k, T in people.joint_transforms(i * PEOPLE_STRIDE)]
        view = oracle.render_gt(cam.camera, cam.world_pose(np.array(truth["body_to_world"][i])), 1, actors=actors)
        masks.append(view.instance_mask)
    return masks


def _masks(store: Store, tag: str) -> list[np.ndarray]:
    from nsim.io.coco import read_instance_mask

    art = store.get(store.resolve(tag))
    return [np.asarray(read_instance_mask(art.file(f"mask/frontleft/{i:06d}.png"))) for i in range(PEOPLE_TICKS)]


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def _centroid(m: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(m)
    return np.array([u.mean(), v.mean()])


def test_people_render_where_the_oracle_sees_them(people):
    """With the default time origin (the run's first tick at the recording's first odometry stamp, as capture
    robot-log records) the person's mask overlaps the oracle's at every frame and follows it across the image;
    with the origin 0.6 s late it does not, and the frames past the run's end have nobody, counted. Measured:
    IoU 0.45-0.57 (the micro human NeRF draws a wider person: 150-220 px against the oracle's 90-125),
    centroids within 1.8 px of the oracle's, which move 25 px over the run; late: IoU 0-0.03."""
    store, truth, _ = people
    art = store.get(store.resolve("render/people"))
    meta = json.loads(art.file("render.json").read_text())
    assert meta["people"]["humans"] == [store.resolve("human/t")]
    assert meta["people"]["trajectory"] == store.resolve("trajectory/crossing")
    assert meta["people"]["people_time_offset_s"] == 0.0 and meta["people"]["people_outside_run"] == 0
    assert meta["people"]["first_odometry_ns"] == truth["stamps_ns"][0]
    (st,) = meta["streams"]
    ticks = np.arange(PEOPLE_TICKS) * PEOPLE_STRIDE
    run_t = np.load(store.get(store.resolve("trajectory/crossing")).file("trajectory.npz"))["time_s"]
    np.testing.assert_allclose([f["people_time_s"] for f in st["frames"]], run_t[ticks], atol=1e-6)  # the log: float64 s
    truth_masks = [m == 1 for m in _truth_masks(store, truth)]
    sim = [m == 1 for m in _masks(store, "render/people")]
    late = [m == 1 for m in _masks(store, "render/people-late")]
    assert all(m.sum() > 20 for m in truth_masks)  # the person is in view of every frame
    ious = [_iou(a, b) for a, b in zip(sim, truth_masks, strict=True)]
    late_ious = [_iou(a, b) for a, b in zip(late[:2], truth_masks[:2], strict=True)]
    assert min(ious) > 0.3 and max(late_ious) < 0.15, (ious, late_ious)
    # the person crosses the view: the mask's centroid moves with the oracle's, a few pixels from it
    c_sim, c_true = np.stack([_centroid(m) for m in sim]), np.stack([_centroid(m) for m in truth_masks])
    assert np.abs(c_true[-1] - c_true[0]).max() > 15
    assert np.linalg.norm(c_sim - c_true, axis=-1).max() < 3.0, (c_sim, c_true)
    # the late origin: ticks 10 and 15 see simulation times past the run's end: nobody, counted
    meta_late = json.loads(store.get(store.resolve("render/people-late")).file("render.json").read_text())
    assert meta_late["people"]["people_outside_run"] == 2 and meta_late["streams"][0]["people_outside_run"] == 2
    assert all(m.sum() > 0 for m in late[:2]) and not any(m.any() for m in late[2:])
    # COCO boxes of the masks, the mirror unchanged beside them
    boxes = json.loads(art.file("boxes/frontleft.json").read_text())
    assert len(boxes["annotations"]) == PEOPLE_TICKS
    assert sorted(im["file_name"] for im in boxes["images"]) == [f"camera/frontleft/{i:06d}.png" for i in range(PEOPLE_TICKS)]
    assert _files(art.path) == [f"camera/frontleft/{i:06d}.png" for i in range(PEOPLE_TICKS)]


@pytest.mark.parametrize("case, args, fragments", [
    ("people and no people", ["--trajectory", "trajectory/crossing", "--humans", "human/t", "--no-people"],
     ["--no-people draws nobody", "give one"]),
    ("no overlap", ["--trajectory", "trajectory/crossing", "--humans", "human/t", "--set", "people_time_offset_s=-5"],
     ["spans simulation time [0, 1] s", "no frame overlaps the run"]),
    ("a rig", ["--trajectory", "trajectory/crossing", "--humans", "human/t", "--rig", "nsim/configs/robots/spot.yaml"],
     ["a recording renders its own recorded sensors"]),
])
def test_bad_people_input_is_one_line_and_publishes_nothing(people, capsys, case, args, fragments):
    store, _, _ = people
    before = set(store.all_ids())
    capsys.readouterr()
    code = main(["--workspace", str(store.root), "--device", "cpu", "render", "--recording", "registration/people",
                 "--scene", "scene/t", *args])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("WARNING")]
    assert len(lines) == 1 and "Traceback" not in err, err
    for f in fragments:
        assert f in lines[0], lines[0]
    assert set(store.all_ids()) == before


def test_core_people_clock_and_states():
    from nsim.rendering import recording as core

    # the run's first tick at the first odometry stamp; the difference taken in integer ns
    t = core.people_time_s(np.array([1_700_000_000_250_000_000, 1_699_999_999_000_000_000]), 1_700_000_000_000_000_000,
                           2.0, 0.5)
    np.testing.assert_allclose(t, [2.75, 1.5], atol=1e-12)
    time_s = np.array([0.0, 1.0, 2.0])
    pos = np.array([[[0.0, 0.0], [5.0, 5.0]], [[2.0, 4.0], [np.nan, np.nan]], [[4.0, 4.0], [7.0, 7.0]]])
    head = np.array([[np.pi - 0.1, 0.0], [-np.pi + 0.1, 0.0], [0.0, 0.0]])
    phase = np.array([[0.9, 0.0], [0.1, 0.0], [0.3, 0.0]])
    # on a tick: that tick, exactly; a person absent there is absent
    present, p, h, g = core.people_states_at(time_s, pos, head, phase, 1.0)
    assert present.tolist() == [True, False] and p[0].tolist() == [2.0, 4.0] and h[0] == head[1, 0] and g[0] == 0.1
    assert np.isnan(p[1]).all() and np.isnan(h[1]) and np.isnan(g[1])
    # a quarter of the way: linear position, the heading across +-pi along the short arc, the phase through 1
    present, p, h, g = core.people_states_at(time_s, pos, head, phase, 0.25)
    assert present.tolist() == [True, False]  # person 1 is missing at tick 1: absent between 0 and 1
    np.testing.assert_allclose(p[0], [0.5, 1.0])
    np.testing.assert_allclose(h[0], np.pi - 0.05)
    np.testing.assert_allclose(g[0], 0.95)
    present, p, _, g = core.people_states_at(time_s, pos, head, phase, 1.75)
    assert present.tolist() == [True, False]
    np.testing.assert_allclose(p[0], [3.5, 4.0])
    np.testing.assert_allclose(g[0], 0.25)
    # outside the run: nobody
    for q in (-0.01, 2.01):
        assert not core.people_states_at(time_s, pos, head, phase, q)[0].any()


def test_people_between_ticks_pose_like_the_ticks(people):
    """``HumanSet.joint_transforms_at`` on a tick's time is ``joint_transforms`` of that tick, bit for bit; half
    way between two ticks the root lies half way between theirs."""
    from nsim.rendering.people import HumanSet

    store, _, _ = people
    arrays = dict(np.load(store.get(store.resolve("trajectory/crossing")).file("trajectory.npz"), allow_pickle=False))
    hs = HumanSet([], arrays, "cpu")
    t = arrays["time_s"]
    for tick in (0, 7, len(t) - 1):
        (k, a), = hs.joint_transforms(tick)
        (k2, b), = hs.joint_transforms_at(float(t[tick]))
        assert k == k2 == 0 and np.array_equal(a, b)
    (_, mid), = hs.joint_transforms_at(float(t[3] + t[4]) / 2)
    (_, a), (_, b) = hs.joint_transforms(3)[0], hs.joint_transforms(4)[0]
    np.testing.assert_allclose(mid[0, :2, 3], (a[0, :2, 3] + b[0, :2, 3]) / 2, atol=0.02)
    assert hs.joint_transforms_at(float(t[-1]) + 0.01) == []
