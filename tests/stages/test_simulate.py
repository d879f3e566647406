"""`nsim simulate` end to end at tiny size: files, poses, determinism, the cache, bad scenarios, sweeps."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import yaml

from nsim.config import configs_dir
from nsim.crowd import CrowdTrajectory
from nsim.io.tum import read_tum
from nsim.stages.simulate import load_scenario, scenario_from_data
from nsim.workspace.store import Store

SPOT_RUN = configs_dir() / "scenarios" / "spot_run.json"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from nsim.cli import main

    ws = tmp_path_factory.mktemp("sim") / "ws"
    args = [
        "--workspace",
        str(ws),
        "simulate",
        "--scenario",
        str(SPOT_RUN),
        "--preset",
        "tiny",
        "--tag",
        "trajectory/t",
    ]
    assert main(args) == 0
    store = Store(ws)
    return store, store.get(store.resolve("trajectory/t"))


def test_trajectory_files(tiny_run):
    store, art = tiny_run
    m = art.manifest
    assert m["kind"] == "trajectory" and m["stage"] == "simulate"
    sc = load_scenario(SPOT_RUN)
    assert m["summary"]["scenario"] == "spot_run" and m["summary"]["scenario_digest"] == sc.digest
    t_count = 81  # 4 s at 0.05 s, the initial tick included
    with np.load(art.path / "trajectory.npz", allow_pickle=False) as npz:
        crowd = CrowdTrajectory.from_arrays(npz)
        pose = npz["robot_pose_se3"]
        assert list(npz["human_ids"]) == ["ana", "ben", "cleo", "dev", "eve"]
        np.testing.assert_allclose(npz["height_m"], [1.68, 1.82, 1.64, 1.76, 1.71])
        assert list(npz["motion"]) == ["walk"] * 5 and npz["appearance"][0] == "human/ana"
    assert crowd.position_m.shape == (t_count, 5, 2) and crowd.gait_phase.shape == (t_count, 5)
    assert pose.shape == (t_count, 4, 4) and np.allclose(crowd.time_s, np.arange(t_count) * 0.05)
    # the robot's body: z up, 0.5 m above the floor, x forward along its motion at ~1 m/s
    assert np.allclose(pose[:, :3, 2], [0, 0, 1]) and np.allclose(pose[:, 2, 3], 0.5)
    vel = np.diff(pose[:, :2, 3], axis=0) / 0.05
    assert np.allclose(np.linalg.norm(vel, axis=1), 1.0, atol=0.02)
    cos = np.sum(vel / np.linalg.norm(vel, axis=1, keepdims=True) * pose[:-1, :2, 0], axis=1)
    assert cos.min() > math.cos(math.radians(6))
    np.testing.assert_allclose(crowd.robot_position_m, pose[:, :2, 3])
    # TUM files: the robot at every tick, each human's root on the floor along its heading
    robot_tum = read_tum(art.path / "robot.tum")
    np.testing.assert_allclose(robot_tum.poses_se3(), pose, atol=1e-9)
    ana = read_tum(art.path / "humans" / "ana.tum")
    np.testing.assert_allclose(ana.positions_xyz[:, :2], crowd.position_m[:, 0])
    assert np.all(ana.positions_xyz[:, 2] == 0.0)
    heading = ana.poses_se3()[:, :2, 0]
    np.testing.assert_allclose(np.arctan2(heading[:, 1], heading[:, 0]), crowd.heading_rad[:, 0], atol=1e-9)
    metrics = json.loads((art.path / "metrics.json").read_text())
    assert metrics["run"]["ticks"] == t_count and metrics["hunav"]["time_to_reach_goal_s"] is None
    assert metrics["hunav"]["path_length_m"] == pytest.approx(4.0, abs=0.05)
    assert 0 < metrics["hunav"]["minimum_distance_to_people_m"] < 10
    stored = json.loads((art.path / "scenario.json").read_text())
    assert scenario_from_data(stored, source="stored").digest == sc.digest
    occ = json.loads((art.path / "occupancy.json").read_text())
    assert len(occ["polygons"]) == len(sc.obstacles_m)
    video = cv2.VideoCapture(str(art.path / "run.mp4"))
    frames = 0
    while video.read()[0]:
        frames += 1
    assert frames == 21  # 5 fps over 4 s: every 4th tick
    assert (art.path / "topdown.png").stat().st_size > 5000


def test_same_scenario_and_seed_give_the_same_artifact(tiny_run, tmp_path, run_cli):
    store, art = tiny_run
    code, out, err = run_cli(
        "simulate", "--scenario", str(SPOT_RUN), "--preset", "tiny", workspace=store.root
    )
    assert code == 0 and out.strip() == art.id and "cached" in err
    # from scratch in another workspace: the same id, so byte-identical files (run.mp4 included)
    code, out, _ = run_cli(
        "simulate", "--scenario", str(SPOT_RUN), "--preset", "tiny", workspace=tmp_path / "other"
    )
    assert code == 0 and out.strip() == art.id
    other = Store(tmp_path / "other").get(art.id)
    assert (other.path / "run.mp4").read_bytes() == (art.path / "run.mp4").read_bytes()
    # the same scenario as YAML in another directory: the same content, the same artifact
    y = tmp_path / "copy" / "spot_run.yaml"
    y.parent.mkdir()
    y.write_text(yaml.safe_dump(json.loads(SPOT_RUN.read_text())))
    code, out, err = run_cli("simulate", "--scenario", str(y), "--preset", "tiny", workspace=store.root)
    assert code == 0 and out.strip() == art.id and "cached" in err
    code, out, _ = run_cli("verify", "--rebuild", art.id[:10], workspace=store.root)
    assert code == 0 and "rebuilt identically" in out


def test_seed_scenario_and_config_change_the_artifact(tiny_run, tmp_path, run_cli):
    store, art = tiny_run
    fast = ("--preset", "tiny", "--set", "video=false", "--set", "max_duration_s=1")
    ids = set()
    code, out, _ = run_cli("simulate", "--scenario", str(SPOT_RUN), *fast)
    ids.add(out.strip())
    code, out, _ = run_cli("--seed", "1", "simulate", "--scenario", str(SPOT_RUN), *fast)
    ids.add(out.strip())
    d = json.loads(SPOT_RUN.read_text())
    d["seed"] = 7
    p = tmp_path / "seed7.json"
    p.write_text(json.dumps(d))
    code, out, _ = run_cli("simulate", "--scenario", str(p), *fast)
    ids.add(out.strip())
    code, out, _ = run_cli(
        "simulate", "--scenario", str(SPOT_RUN), *fast, "--set", "forces.agent_strength_mps2=3"
    )
    ids.add(out.strip())
    assert code == 0 and len(ids) == 4 and art.id not in ids


def _bad_files(tmp_path):
    """(file, text the one-line error must contain) for each kind of bad scenario."""
    base = json.loads(SPOT_RUN.read_text())

    def variant(name, fn):
        d = json.loads(json.dumps(base))
        fn(d)
        p = tmp_path / name
        p.write_text(yaml.safe_dump(d) if name.endswith(".yaml") else json.dumps(d))
        return p

    malformed_json = tmp_path / "malformed.json"
    malformed_json.write_text('{"duration_s": 30,\n "humans": [\n')
    malformed_yaml = tmp_path / "malformed.yaml"
    malformed_yaml.write_text("duration_s: 30\nhumans: [1,\n")
    nan = tmp_path / "nan.json"
    nan.write_text(SPOT_RUN.read_text().replace('"start_m": [1.0, 2.3]', '"start_m": [1.0, NaN]'))
    return [
        (malformed_json, "line 3 column 1: malformed JSON"),
        (malformed_yaml, "line 3: malformed YAML"),
        (
            variant("behaviour.json", lambda d: d["humans"][2].update(behaviour="angry")),
            "humans[2].behaviour: 'angry' is not one of regular, impassive, surprised, scared, curious, threatening",
        ),
        (
            variant("tum.yaml", lambda d: d["robot"].update(trajectory={"tum": "runs/spot.tum"})),
            "robot.trajectory.tum: no such file",
        ),
        (
            variant("inside.json", lambda d: d["humans"][3].update(start_m=[3.0, 0.3])),
            "humans[3].start_m: (3, 0.3) is inside an obstacle of robot-lab",
        ),
        (
            variant("dt.json", lambda d: d.update(dt_s=-0.01)),
            "dt_s: expected a number > 0 and <= 0.5, got -0.01",
        ),
        (nan, "humans[1].start_m[1]: expected a finite number, got nan"),
        (variant("keys.yaml", lambda d: d["robot"].update(colour="yellow")), "robot.colour: unknown key"),
        (variant("top.json", lambda d: d.update(humams=[])), "humams: unknown key (did you mean 'humans'?)"),
    ]


def test_bad_scenarios_exit_2_with_one_line_naming_file_and_field(run_cli, tmp_path):
    for path, message in _bad_files(tmp_path):
        code, out, err = run_cli("simulate", "--scenario", str(path), "--preset", "tiny")
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 2 and len(lines) == 1, (path.name, err)
        assert lines[0].startswith(f"error: {path}: ") and message in lines[0], lines[0]
        assert out == "" and "Traceback" not in err
    for args, message in (
        ((), "give exactly one of --scenario FILE or --sweep FILE"),
        (("--scenario", str(SPOT_RUN), "--workers", "2"), "apply to --sweep only"),
        (("--scenario", str(tmp_path / "none.json")), "none.json: scenario file not found"),
        (("--scenario", str(SPOT_RUN), "--set", "dt_s=0"), "--set dt_s: expected float > 0"),
        (("--sweep", str(tmp_path / "none.yaml")), "none.yaml: sweep file not found"),
    ):
        code, _, err = run_cli("simulate", *args)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_sweep_grid_summary_and_engines(run_cli, tmp_path):
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        yaml.safe_dump(
            {
                "scenario": str(SPOT_RUN),
                "seeds": [0, 1],
                "crowd_sizes": [0, 6],
                "behaviours": ["scared", ["curious", "threatening"]],
            }
        )
    )
    fast = ("--preset", "tiny", "--set", "video=false", "--set", "max_duration_s=1")
    summary = tmp_path / "summary.json"
    code, out, err = run_cli("simulate", "--sweep", str(sweep), *fast, "--summary", str(summary))
    assert code == 0, err
    rows = json.loads(summary.read_text())["rows"]
    assert len(rows) == 8 and [r["grid"]["seed"] for r in rows] == [0] * 4 + [1] * 4
    assert [r["humans"] for r in rows] == [5, 5, 11, 11] * 2
    ids = [r["trajectory"] for r in rows]
    # size 0 ignores the behaviour set: those two cells are the same scenario
    assert ids[0] == ids[1] and len(set(ids)) == 6
    store = Store(tmp_path / "ws")
    extra = json.loads(store.get(ids[3]).file("scenario.json").read_text())["humans"][5:]
    assert {h["behaviour"] for h in extra} <= {"curious", "threatening"} and len(extra) == 6
    assert out.count("\n") == 10 and ids[2][:12] in out and "| seed |" in out
    # again: all cached; through a process pool in a fresh workspace: identical rows
    code, out2, err = run_cli("simulate", "--sweep", str(sweep), *fast)
    assert code == 0 and "(8 cached)" in err and out2 == out
    code, out3, err = run_cli(
        "simulate", "--sweep", str(sweep), *fast, "--workers", "2", workspace=tmp_path / "pool"
    )
    assert code == 0 and out3 == out, err
    md = tmp_path / "summary.md"
    code, _, _ = run_cli("simulate", "--sweep", str(sweep), *fast, "--summary", str(md))
    assert md.read_text().endswith(out)


def test_bad_sweep_files(run_cli, tmp_path):
    cases = {
        "behaviour.yaml": (
            {"scenario": str(SPOT_RUN), "behaviours": ["angry"]},
            "behaviours[0]: 'angry' is not one of",
        ),
        "size.yaml": (
            {"scenario": str(SPOT_RUN), "crowd_sizes": [-2]},
            "crowd_sizes[0]: expected int >= 0, got -2",
        ),
        "key.yaml": ({"scenario": str(SPOT_RUN), "seed": [1]}, "seed: unknown key (did you mean 'seeds'?)"),
        "missing.yaml": ({"seeds": [1]}, "scenario: required key is missing"),
        "scenario.yaml": ({"scenario": "nowhere.json"}, "nowhere.json: scenario file not found"),
        "crowded.yaml": ({"scenario": str(SPOT_RUN), "crowd_sizes": [500]}, "could place only"),
    }
    for name, (data, message) in cases.items():
        (tmp_path / name).write_text(yaml.safe_dump(data))
        code, _, err = run_cli("simulate", "--sweep", str(tmp_path / name), "--preset", "tiny")
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, (name, err)
    code, _, err = run_cli(
        "simulate", "--sweep", str(tmp_path / "size.yaml"), "--engine", "ray", "--address", "x"
    )
    assert code == 2


def test_checkpoint_scene_is_an_input_of_the_trajectory(store, tmp_path):
    from nsim.context import RunContext
    from nsim.stages import simulate
    from nsim.synth.room import make_room, occupancy_polygons

    occ = {"units": "m", "polygons": [p.tolist() for p in occupancy_polygons(make_room("robot-lab", 0))]}
    key = store.action_key("fake-scene", 1, {})
    with store.publish(
        kind="scene-checkpoint", stage="fake-scene", version=1, key=key, config={}, ref="scene/lab"
    ) as out:
        (out.dir / "occupancy.json").write_text(json.dumps(occ))
    d = json.loads(SPOT_RUN.read_text())
    d["scene"] = {"checkpoint": "scene/lab"}
    d["robot"]["trajectory"] = {"waypoints_m": [[1.5, 1.6], [6.0, 1.6], [6.0, 4.9], [1.5, 4.9]], "loop": True}
    p = tmp_path / "ckpt.json"
    p.write_text(json.dumps(d))
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    sc = load_scenario(p, store=store)
    cfg = simulate.Config(max_duration_s=0.5, video=False)
    res = simulate.run(simulate.Inputs(sc), cfg, ctx)
    m = store.get(res.trajectory).manifest
    assert m["inputs"] == {"scene": out.ref}
    assert store.lineage(res.trajectory)["inputs"]["scene"]["kind"] == "scene-checkpoint"
