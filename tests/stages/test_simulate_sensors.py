"""``robot.sensors``: a user controller steering by rendered depth frames of a micro scene checkpoint,
through ``nsim simulate``; the frames equal a direct render; bad scenarios fail in one line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.config import configs_dir
from nsim.workspace.store import Store
from tests.stages import sensor_controllers
from tests.stages.micro import capture_and_micro_scene

SPOT_RUN = configs_dir() / "scenarios" / "spot_run.json"
FAST = ["--preset", "tiny", "--set", "video=false", "--set", "max_duration_s=2.0"]  # dt_s 0.05: ticks 0..40


def scenario(scene, **sensors) -> dict:
    d = json.loads(SPOT_RUN.read_text())
    d["scene"] = scene
    d["humans"] = []
    d["robot"]["trajectory"] = {"waypoints_m": [[1.5, 1.6], [6.0, 1.6], [6.0, 4.9], [1.5, 4.9]], "loop": True}
    d["robot"]["controller"] = {"python": "tests.stages.sensor_controllers:DepthStopper",
                                "params": sensors.pop("params", {})}
    d["robot"]["sensors"] = {"rate_hz": 2.0, "rig": "pinhole-rgbd", "names": ["rgbd"], "image_scale": 0.1, **sensors}
    return d


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A workspace with a micro scene checkpoint ``scene/t``."""
    root = tmp_path_factory.mktemp("sim-sensors")
    capture_and_micro_scene(root, root / "ws")
    return Store(root / "ws")


def simulate(world, data, tmp_path, name="sc.json", *extra):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    sensor_controllers.FRAMES.clear()
    return main(["--workspace", str(world.root), "--device", "cpu", "simulate", *FAST, "--scenario", str(path), *extra])


def test_controller_gets_frames_at_the_rate_equal_to_a_direct_render(world, tmp_path):
    from nsim.rendering.model import load_model
    from nsim.rendering.occupancy import OccupancyGrid
    from nsim.rendering.renderer import render_camera
    from nsim.sensors.rig import Rig
    from nsim.stages.render import Config as RenderConfig
    from nsim.stages.simulate import scenario_from_data

    assert simulate(world, scenario({"checkpoint": "scene/t"}), tmp_path, "sc.json", "--tag", "trajectory/s") == 0
    frames = list(sensor_controllers.FRAMES)
    art = world.get(world.resolve("trajectory/s"))
    traj = np.load(art.file("trajectory.npz"))
    dt = float(traj["time_s"][1] - traj["time_s"][0])
    # 2 Hz at 0.05 s: ticks 0, 10, 20, 30 (tick 40 is the last state, no command)
    assert [round(f["time_s"] / dt) for f in frames] == [0, 10, 20, 30]
    metrics = json.loads(art.file("metrics.json").read_text())
    assert metrics["run"]["sensor_frames"] == {"rgbd": 4}
    assert not any("rgbd" in p.name for p in art.path.rglob("*"))  # the frames are not saved
    stored = json.loads(art.file("scenario.json").read_text())  # the rig stored resolved, read back unchanged
    assert stored["robot"]["sensors"]["rig"]["name"] == "pinhole-rgbd"
    assert scenario_from_data(stored, source="stored", store=world).digest == art.manifest["summary"]["scenario_digest"]
    for f in frames:
        assert f["frame"]["rgb"].shape == (48, 64, 3) and f["frame"]["rgb"].dtype == np.float32
        assert f["frame"]["depth"].shape == (48, 64) and f["frame"]["depth"].dtype == np.float32
        assert np.isfinite(f["frame"]["depth"]).any()

    # steered by it: moving until a frame shows the wall ahead 2 cm closer than the first one, stopped from then on
    cmd = traj["robot_command_body"]
    near = [round(f["time_s"] / dt) for f in frames if f["mean_depth_m"] < frames[0]["mean_depth_m"] - 0.02]
    assert near and 0 < near[0] < len(cmd), [f["mean_depth_m"] for f in frames]
    assert np.all(cmd[: near[0], 0] == 0.5) and np.all(cmd[near[0] :] == 0.0)
    assert traj["robot_pose_se3"][near[0], 0, 3] > traj["robot_pose_se3"][0, 0, 3] + 0.2

    # equal to rendering the rig's sensor directly at the robot's pose of that tick
    scene = world.get(world.resolve("scene/t")).path
    model, grid, cfg = load_model(scene).eval(), OccupancyGrid.load(scene / "occupancy_grid.npy"), RenderConfig()
    s = Rig.load(configs_dir() / "robots" / "pinhole-rgbd.yaml")["rgbd"]
    s = dataclasses.replace(s, camera=s.camera.scaled(0.1))
    for f in frames[:2]:
        k = round(f["time_s"] / dt)
        pose = traj["robot_pose_se3"][k]
        np.testing.assert_allclose(pose[:2, 3], f["position_m"])
        view = render_camera(model, s.camera, s.world_pose(pose), cfg.method, grid, cfg.march, cfg.chunk_rays)
        np.testing.assert_array_equal(f["frame"]["rgb"], view.rgb)
        z = np.where(view.accumulation >= cfg.min_accumulation, view.depth_median_z, np.inf)
        z = np.where(z > s.depth.max_m, np.inf, np.where(z < s.depth.min_m, np.nan, z)).astype(np.float32)
        np.testing.assert_array_equal(f["frame"]["depth"], z)


def test_rig_settings_enter_the_artifact_id(world, tmp_path, capsys):
    capsys.readouterr()
    assert simulate(world, scenario({"checkpoint": "scene/t"}), tmp_path) == 0
    a = capsys.readouterr().out.strip().splitlines()[-1]
    assert simulate(world, scenario({"checkpoint": "scene/t"}), tmp_path) == 0  # cached: the same id, no frames
    assert capsys.readouterr().out.strip().splitlines()[-1] == a and sensor_controllers.FRAMES == []
    assert simulate(world, scenario({"checkpoint": "scene/t"}, image_scale=0.05), tmp_path) == 0
    b = capsys.readouterr().out.strip().splitlines()[-1]
    assert b != a and sensor_controllers.FRAMES[0]["frame"]["rgb"].shape == (24, 32, 3)


@pytest.mark.parametrize("case", ["room scene", "unknown name", "asked for another sensor", "no such rig"])
def test_bad_sensors_fail_in_one_line_and_publish_nothing(world, tmp_path, capsys, case):
    data = {
        "room scene": scenario({"room": "robot-lab", "room_seed": 0}),
        "unknown name": scenario({"checkpoint": "scene/t"}, names=["rgbd", "nope"]),
        "asked for another sensor": scenario({"checkpoint": "scene/t"}, names=["rgbd"],
                                             params={"sensor": "frontleft"}),
        "no such rig": scenario({"checkpoint": "scene/t"}, rig="robots/none.yaml"),
    }[case]
    before = sorted(p.name for p in (world.root / "objects").rglob("*") if p.parent.parent.name == "objects")
    capsys.readouterr()
    assert simulate(world, data, tmp_path, "bad.json") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.json" in err and "robot.sensors" in err, err
    expect = {"room scene": "scene checkpoint", "unknown name": "'nope'", "asked for another sensor": "'frontleft'",
              "no such rig": "neither a rig preset"}
    assert expect[case] in err
    after = sorted(p.name for p in (world.root / "objects").rglob("*") if p.parent.parent.name == "objects")
    assert after == before


def test_spot_rig_by_default_fisheye_and_lidar_equal_direct_renders(world):
    """The core (``nsim.crowd.sensors.SceneSensors``) on Spot's rig as nsim ships it: a fisheye camera with
    depth and the LiDAR, each equal to ``render_camera`` / ``render_lidar`` at the same pose; counts kept."""
    from nsim.crowd.scenario import parse_scenario
    from nsim.crowd.sensors import SceneSensors, SensorsSpec
    from nsim.errors import InputError
    from nsim.rendering.renderer import render_camera, render_lidar
    from nsim.sensors.rig import Rig
    from nsim.stages.render import Config as RenderConfig

    data = scenario({"checkpoint": world.resolve("scene/t")}, names=["frontleft", "lidar"], image_scale=0.05,
                    lidar_azimuth_scale=0.05)
    del data["robot"]["sensors"]["rig"]  # default: spot
    spec = parse_scenario(data, source="spot.json").data["robot"]["sensors"]
    assert spec["rig"] == Rig.load(configs_dir() / "robots" / "spot.yaml").to_dict()  # stored resolved
    cam = SceneSensors(world.get(world.resolve("scene/t")).path, SensorsSpec.from_data(spec), RenderConfig())
    body = np.eye(4)
    body[:3, 3] = [2.0, 2.5, 0.5]
    fl, lidar = cam("frontleft", body), cam("lidar", body, 0.5)
    rig = Rig.load(configs_dir() / "robots" / "spot.yaml")
    s = dataclasses.replace(rig["frontleft"], camera=rig["frontleft"].camera.scaled(0.05))
    assert fl["rgb"].shape == (24, 32, 3) and fl["depth"].shape == (24, 32) and set(fl) == {"rgb", "depth"}
    cfg = RenderConfig()
    view = render_camera(cam.model, s.camera, s.world_pose(body), cfg.method, cam.grid, cfg.march, cfg.chunk_rays)
    np.testing.assert_array_equal(fl["rgb"], view.rgb)
    lid = rig["lidar"]
    a = max(1, round(lid.config.azimuth_samples * 0.05))
    lid = dataclasses.replace(lid, config=dataclasses.replace(lid.config, azimuth_samples=a))
    assert set(lidar) == {"ranges"} and lidar["ranges"].shape == (lid.config.channels, a)
    assert lidar["ranges"].dtype == np.float32 and np.isfinite(lidar["ranges"]).any()
    direct = render_lidar(cam.model, lid.world_pose(body), lid, cfg.method, cam.grid, cfg.march, cfg.chunk_rays,
                          cfg.min_accumulation)
    np.testing.assert_array_equal(lidar["ranges"], direct)
    assert cam.frames_rendered == {"frontleft": 1, "lidar": 1}
    with pytest.raises(InputError, match="'back', not one of names"):
        cam("back", body)
