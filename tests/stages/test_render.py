"""`nsim render` at tiny size: a micro scene checkpoint, a simulated Spot run, the rig's files,
poses-mode rendering against the capture, resume after a failed shard, errors, the ROS 2 bag."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from nsim.cli import main
from nsim.config import configs_dir, from_dict
from nsim.context import RunContext
from nsim.workspace.store import Store
from tests.stages.micro import capture_and_micro_scene

SPOT = configs_dir() / "robots" / "spot.yaml"
RGBD = configs_dir() / "robots" / "pinhole-rgbd.yaml"


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A workspace with a capture, a micro scene checkpoint and a short Spot run in that scene."""
    root = tmp_path_factory.mktemp("render")
    ws = root / "ws"
    capture_and_micro_scene(root, ws)
    sc_args = ["--workspace", str(ws), "simulate", "--preset", "tiny", "--set", "max_duration_s=2.0"]
    assert main([*sc_args, "--scenario", str(configs_dir() / "scenarios" / "spot_run.json"), "--tag", "trajectory/t"]) == 0
    store = Store(ws)
    # a run *in* the scene checkpoint (its obstacle map): the robot's loop from the canonical scenario, no people
    sc = json.loads(store.get(store.resolve("trajectory/t")).file("scenario.json").read_text())
    sc["scene"] = {"checkpoint": store.resolve("scene/t")}
    sc["humans"] = []
    sc_file = root / "in_scene.json"
    sc_file.write_text(json.dumps(sc))
    assert main([*sc_args, "--scenario", str(sc_file), "--tag", "trajectory/in-scene"]) == 0
    return store


@pytest.fixture(scope="module")
def spot_render(world):
    assert main(["--workspace", str(world.root), "--device", "cpu", "render", "--trajectory", "trajectory/t",
                 "--scene", "scene/t", "--rig", str(SPOT), "--preset", "tiny", "--tag", "render/spot"]) == 0
    return world.get(world.resolve("render/spot"))


def test_spot_render_files(spot_render, world):
    art = spot_render
    meta = json.loads(art.file("render.json").read_text())
    assert meta["mode"] == "trajectory" and len(meta["frames"]) == 3
    names = [s["name"] for s in meta["sensors"]]
    assert names == ["frontleft", "frontright", "left", "right", "back", "lidar"] or set(names) >= {"frontleft", "back"}
    from nsim.io.exr import read_depth_exr, read_exr_attributes
    from nsim.io.images import read_image
    from nsim.io.lidar_exr import read_lidar_exr, read_lidar_ply
    from nsim.sensors.rig import Rig

    rig = Rig.from_resolved(json.loads(art.file("rig.json").read_text()))
    for f in meta["frames"]:
        i = f["index"]
        for s in rig.sensors:
            if s.type == "lidar":
                scan = read_lidar_exr(art.file(f"{s.name}/scan/{i:06d}.exr"))
                assert scan.range_m.shape == s.ray_shape
                assert scan.hit.any()
                hits = scan.xyz_m[scan.hit]
                assert np.allclose(np.linalg.norm(hits, axis=-1), scan.range_m[scan.hit], atol=1e-4)
                cloud = read_lidar_ply(art.file(f"{s.name}/scan/{i:06d}.ply"))
                assert len(cloud.xyz) == int(scan.hit.sum())
            else:
                img = read_image(art.file(f"{s.name}/rgb/{i:06d}.png"))
                assert img.shape[:2] == s.ray_shape and img.dtype == np.uint8
                depth_path = art.file(f"{s.name}/depth/{i:06d}.exr")
                depth = read_depth_exr(depth_path)
                assert depth.shape == s.ray_shape
                assert "z-depth" in read_exr_attributes(depth_path)["nsim_depth"]
                finite = depth[np.isfinite(depth)]
                assert finite.size and (finite > 0).all()
    for name in ("robot.tum", "cameras/frontleft.json", "preview/contact_sheet.png"):
        assert art.file(name).is_file(), name
    from nsim.io.tum import read_tum

    robot = read_tum(art.file("robot.tum"))
    traj = np.load(world.get(world.resolve("trajectory/t")).file("trajectory.npz"))
    assert np.allclose(robot.poses_se3()[1], traj["robot_pose_se3"][meta["frames"][1]["index"]], atol=1e-6)


def test_fill_paints_only_the_pixels_without_a_return(spot_render, world):
    """``fill: image_mean`` (the default) against ``none``: every pixel with a surface (finite depth) is
    the same; pixels without one take their remaining light over the training images'
    mean colour instead of black, so they only get brighter, and some do."""
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_image
    from nsim.rendering import load_model
    from nsim.sensors.rig import Rig

    assert load_model(world.get(world.resolve("scene/t")).path).image_mean_rgb is not None
    assert main(["--workspace", str(world.root), "--device", "cpu", "render", "--trajectory", "trajectory/t",
                 "--scene", "scene/t", "--rig", str(SPOT), "--preset", "tiny", "--set", "fill=none",
                 "--tag", "render/spot-nofill"]) == 0
    plain = world.get(world.resolve("render/spot-nofill"))
    rig = Rig.from_resolved(json.loads(spot_render.file("rig.json").read_text()))
    changed = 0
    for f in json.loads(spot_render.file("render.json").read_text())["frames"]:
        for s in (s for s in rig.sensors if s.type != "lidar"):
            name = f"{s.name}/rgb/{f['index']:06d}.png"
            a, b = read_image(spot_render.file(name)).astype(int), read_image(plain.file(name)).astype(int)
            # no surface: depth inf, or NaN where a fisheye ray beyond 90 degrees has no z-depth (or outside the circle)
            none = ~np.isfinite(read_depth_exr(spot_render.file(f"{s.name}/depth/{f['index']:06d}.exr")))
            assert np.array_equal(a[~none], b[~none])
            assert (a[none] >= b[none] - 1).all()
            changed += int((a != b).any(-1).sum())
    assert changed > 0


def test_cached_rerun_and_other_rig(spot_render, world, capsys, caplog):
    capsys.readouterr()
    assert main(["--workspace", str(world.root), "--device", "cpu", "render", "--trajectory", "trajectory/t",
                 "--scene", "scene/t", "--rig", str(SPOT), "--preset", "tiny"]) == 0
    err = capsys.readouterr().err
    assert "cached" in err
    # without --humans the run's five people are drawn with the default look (their scenario's appearances are
    # not in this workspace), said in one line naming them, and recorded
    assert "5 of 5 people drawn with the default look" in caplog.text
    assert "humans[0] 'human/ana' (not in this workspace)" in caplog.text
    summary = spot_render.manifest["summary"]
    assert summary["people_checkpoints"] == ["default look"] * 5 and summary["people_from"] == "scenario"
    assert summary["default_look"]["seed"] == 0 and len(summary["default_look"]["people"]) == 5
    assert main(["--workspace", str(world.root), "--device", "cpu", "render", "--trajectory", "trajectory/in-scene",
                 "--rig", str(RGBD), "--preset", "tiny", "--tag", "render/rgbd"]) == 0
    rgbd = world.get(world.resolve("render/rgbd"))
    assert rgbd.id != spot_render.id and rgbd.file("rgbd/rgb/000000.png").is_file()


def test_poses_mode_renders_the_frames_cameras(world):
    """Poses mode renders each capture frame's own camera and pose: the same image and median depth
    as rendering that camera directly with the model (and depth of the right scale)."""
    from nsim.io.exr import read_depth_exr
    from nsim.io.images import read_image, to_uint8
    from nsim.io.transforms_json import read_transforms
    from nsim.rendering import load_model
    from nsim.rendering.occupancy import OccupancyGrid
    from nsim.rendering.renderer import MarchConfig, render_camera

    assert main(["--workspace", str(world.root), "--device", "cpu", "render", "--poses", "capture/t", "--scene", "scene/t",
                 "--preset", "tiny", "--set", "max_frames=2", "--set", "image_scale=1.0", "--set", "method=march",
                 "--tag", "render/poses"]) == 0
    art = world.get(world.resolve("render/poses"))
    cap = world.get(world.resolve("capture/t"))
    scene = world.get(world.resolve("scene/t"))
    meta = json.loads(art.file("render.json").read_text())
    assert [f["index"] for f in meta["frames"]] == [0, 10]
    frame = read_transforms(cap.file("transforms.json")).frames[10]
    model = load_model(scene.path)
    grid = OccupancyGrid.load(scene.path / "occupancy_grid.npy")
    cfg = json.loads(art.file("manifest.json").read_text())["config"]
    view = render_camera(model, frame.camera, frame.cam_to_world, method=cfg["method"], grid=grid,
                         march_cfg=MarchConfig(**cfg["march"]))
    assert np.array_equal(read_image(art.file("frames/rgb/000010.png")), to_uint8(view.rgb))
    pred = read_depth_exr(art.file("frames/depth/000010.exr"))
    ok = np.isfinite(pred)
    assert ok.mean() > 0.5
    assert np.allclose(pred[ok], view.depth_median_z[ok], rtol=1e-4, atol=1e-4)
    gt = read_depth_exr(sorted((cap.path / "depth").iterdir())[10])
    assert pred.shape == gt.shape == (48, 64)
    assert 0.2 < np.median(pred[ok]) / np.median(gt[ok]) < 5.0
    # background=last_sample: the stage switches the loaded model to it (the tiny scene keeps light to spare)
    assert main(["--workspace", str(world.root), "--device", "cpu", "render", "--poses", "capture/t", "--scene", "scene/t",
                 "--preset", "tiny", "--set", "max_frames=2", "--set", "image_scale=1.0", "--set", "method=march",
                 "--set", "background=last_sample", "--tag", "render/poses-last"]) == 0
    last = read_image(world.get(world.resolve("render/poses-last")).file("frames/rgb/000010.png"))
    model.sampler_cfg = dataclasses.replace(model.sampler_cfg, background="last_sample")
    view_last = render_camera(model, frame.camera, frame.cam_to_world, method=cfg["method"], grid=grid,
                              march_cfg=MarchConfig(**cfg["march"]))
    assert np.array_equal(last, to_uint8(view_last.rgb)) and not np.array_equal(last, to_uint8(view.rgb))


def test_failed_shard_resumes_and_matches_a_clean_run(world, tmp_path, monkeypatch):
    from nsim.config import to_dict
    from nsim.rendering.engine import EngineConfig
    from nsim.rendering.shard import ShardRenderer
    from nsim.stages import render

    cfg = from_dict(render.Config, {"tick_stride": 7, "max_frames": 4, "shard_frames": 2, "image_scale": 0.05,
                                    "lidar_azimuth_scale": 0.02, "march": {"step_m": 0.05}, "video": False})
    inputs = render.Inputs(trajectory="trajectory/in-scene", rig=RGBD)
    ctx = RunContext(store=world, device_spec="cpu", seed=0, progress=False)
    real = ShardRenderer.render_shard

    def flaky(self, shard, out_dir):
        if shard == 1:
            raise RuntimeError("worker lost")
        return real(self, shard, out_dir)

    monkeypatch.setattr(ShardRenderer, "render_shard", flaky)
    with pytest.raises(Exception, match="worker lost"):
        render.run(inputs, cfg, ctx, engine=EngineConfig())
    assert not any(a.kind == "render" and a.manifest["config"] == json.loads(json.dumps(to_dict(cfg)))
                   for a in world.artifacts())
    monkeypatch.setattr(ShardRenderer, "render_shard", real)
    out = render.run(inputs, cfg, ctx, engine=EngineConfig())
    assert out.shards_reused == 1 and out.shards_rendered == 1
    ctx = dataclasses.replace(ctx, force=True)
    again = render.run(inputs, cfg, ctx, engine=EngineConfig())
    assert again.render == out.render and again.shards_reused == 0


def test_bad_inputs_exit_2(world, tmp_path, capsys):
    ws = str(world.root)
    bad_rig = tmp_path / "bad.yaml"
    bad_rig.write_text("sensors:\n  - name: x\n    type: radar\n    mount: {xyz_m: [0, 0, 0]}\n")
    assert main(["--workspace", ws, "render", "--trajectory", "trajectory/t", "--scene", "scene/t", "--rig", str(bad_rig)]) == 2
    assert "radar" in capsys.readouterr().err
    zero = tmp_path / "zero.yaml"
    zero.write_text("sensors:\n  - name: l\n    type: lidar\n    mount: {xyz_m: [0, 0, 0]}\n    lidar: {channels: 0}\n")
    assert main(["--workspace", ws, "render", "--trajectory", "trajectory/t", "--scene", "scene/t", "--rig", str(zero)]) == 2
    skew = tmp_path / "skew.yaml"
    skew.write_text("sensors:\n  - name: c\n    type: camera\n    mount: {xyz_m: [0, 0, 0], rotation_matrix: "
                    "[[1, 0.3, 0], [0, 1, 0], [0, 0, 1]]}\n    intrinsics: {model: PINHOLE, width: 8, height: 6, hfov_deg: 60}\n")
    assert main(["--workspace", ws, "render", "--trajectory", "trajectory/t", "--scene", "scene/t", "--rig", str(skew)]) == 2
    assert main(["--workspace", ws, "render", "--trajectory", "trajectory/t", "--scene", "scene/t"]) == 2  # no rig
    assert "rig" in capsys.readouterr().err
    # a trajectory whose scene checkpoint is not in this workspace
    other = Store(tmp_path / "other")
    src = world.get(world.resolve("trajectory/in-scene"))
    import shutil

    dst = other.root / "objects" / src.id[:2] / src.id
    dst.parent.mkdir(parents=True)
    shutil.copytree(src.path, dst)
    other.set_ref("trajectory/t", src.id)
    capsys.readouterr()
    assert main(["--workspace", str(other.root), "render", "--trajectory", "trajectory/t", "--rig", str(SPOT)]) == 2
    err = capsys.readouterr().err
    assert "missing from the workspace" in err and err.count("\n") == 1


def test_rosbag_export_reads_back(spot_render, tmp_path):
    from rosbags.rosbag2 import Reader

    from nsim.rendering.render_output import export_rosbag

    bag = export_rosbag(spot_render.path, tmp_path / "bag")
    with Reader(bag) as reader:
        topics = {c.topic: c.msgcount for c in reader.connections}
    assert topics["/frontleft/image"] == 3 and topics["/lidar/points"] == 3 and topics["/tf"] == 3
    assert "/tf_static" in topics and "/odom" in topics
