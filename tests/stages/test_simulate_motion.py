"""Motion that drives people (issue 45): a scenario person driven by a BVH file (CMU, cgspeed's 3dsMax-friendly
names, in CMU's unit) and one driven by a human checkpoint's fitted motion (its ``person.bvh``) walk at their
clip's speed in ``nsim simulate``, their gait phase advancing by the clip's own stride; the clips travel in the
run so render poses them without the files; the canonical scenario does not depend on where the file was; bad
motions are one line (exit 2) before any simulation work."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from nsim.human.bvh import write_bvh
from nsim.human.gait import IDLE_PERIOD_S, walk_cycle
from nsim.human.motion import LocomotionLoop, MotionClip
from nsim.human.person_motion import clip_at_height, clip_from_data, person_loop
from nsim.human.skeleton import (
    JOINT_NAMES,
    Skeleton,
    forward_kinematics,
    quat_about_z_wxyz,
    quat_mul_wxyz,
    rot_z,
)
from nsim.stages.simulate import load_scenario
from nsim.workspace.store import Store
from tests.human.namings import renamed
from tests.stages.sentinel import block_work

FAST = ("--preset", "tiny", "--set", "video=false", "--set", "max_duration_s=5")
BVH_SPEED_MPS = 1.0  # the BVH person's clip: nsim's walk at 1.0 m/s on the 1.75 m body (the reference)
VIDEO_SPEED_MPS, VIDEO_HEIGHT_M = 1.6, 1.65  # the video's person: 1.65 m tall, walking at 1.6 m/s
WARMUP_S = 1.0  # people start standing: the mean speed is taken after they reached their walking speed


def _room(humans: list[dict]) -> dict:
    """A 12 x 8 m room with nothing in it; the robot stands in a corner, far from the people's lanes."""
    return {
        "name": "motion_room", "duration_s": 5.0, "seed": 0,
        "scene": {"polygons": [[[-0.2, -0.2], [12.2, -0.2], [12.2, 8.2], [-0.2, 8.2], [-0.2, -0.2]]],
                  "holes": [[[[0.0, 0.0], [12.0, 0.0], [12.0, 8.0], [0.0, 8.0], [0.0, 0.0]]]]},
        "robot": {"trajectory": {"waypoints_m": [[6.0, 7.4]], "speed_mps": 1.0}},
        "humans": humans,
    }


def _lane(human_id: str, y: float, motion, **extra) -> dict:
    return {"id": human_id, "start_m": [0.8, y], "waypoints_m": [[11.5, y]], "motion": motion, **extra}


def _write_scenario(folder: Path, humans: list[dict]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "scenario.yaml"
    path.write_text(yaml.safe_dump(_room(humans)))
    return path


def _cmu_walk_bvh(path: Path) -> Path:
    """nsim's walk at ``BVH_SPEED_MPS``, two strides, its joints named as cgspeed's 3dsMax-friendly CMU release
    names them (LeftHip, LeftKnee, LeftAnkle, Chest ...), written in CMU's unit (1/0.45 inch)."""
    one = walk_cycle(BVH_SPEED_MPS)
    stride = one.root_positions_m[-1] - one.root_positions_m[0]
    root = np.concatenate([one.root_positions_m, one.root_positions_m[1:] + stride])
    quats = np.concatenate([one.local_rotations_wxyz, one.local_rotations_wxyz[1:]])
    two = MotionClip(one.skeleton, one.fps, root, quats)
    return write_bvh(path, renamed(two, "biped"), unit="cmu")


def _video_person_clip() -> MotionClip:
    """What ``train-human --video`` fits: a person of ``VIDEO_HEIGHT_M`` on its own skeleton (nsim's names),
    walking at ``VIDEO_SPEED_MPS`` across the camera's world (heading 40 degrees, from (2, -1))."""
    walk = walk_cycle(VIDEO_SPEED_MPS, VIDEO_HEIGHT_M)
    yaw = np.radians(40.0)
    root = walk.root_positions_m @ rot_z(yaw).T + np.array([2.0, -1.0, 0.0])
    quats = np.array(walk.local_rotations_wxyz)
    quats[:, 0] = quat_mul_wxyz(quat_about_z_wxyz(np.full(len(quats), yaw)), quats[:, 0])
    return MotionClip(walk.skeleton, walk.fps, root, quats, name="person")


def _human_checkpoint(store: Store, with_bvh: bool = True) -> str:
    """A human-checkpoint artifact as ``train-human --video`` leaves it (its ``person.bvh``, in centimetres)."""
    key = store.action_key("test_train_human", 1, {}, {"with_bvh": with_bvh})
    with store.publish(kind="human-checkpoint", stage="test_train_human", version=1, key=key, config={},
                       inputs={}) as out:
        (out.dir / "human.json").write_text("{}")
        if with_bvh:
            write_bvh(out.dir / "person.bvh", _video_person_clip())
    return out.ref


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One simulate run: ``bvh`` driven by the CMU file, ``video`` by the checkpoint's motion, ``still`` idle."""
    from nsim.cli import main

    root = tmp_path_factory.mktemp("motion")
    ws = root / "ws"
    store = Store(ws)
    checkpoint = _human_checkpoint(store)
    folder = root / "scenarios"
    folder.mkdir()
    _cmu_walk_bvh(folder / "cmu_walk.bvh")
    path = _write_scenario(folder, [_lane("bvh", 1.5, {"bvh": "cmu_walk.bvh"}),
                                    _lane("video", 4.0, {"from": checkpoint}, height_m=1.6),
                                    _lane("still", 6.0, "idle")])
    assert main(["--workspace", str(ws), "simulate", "--scenario", str(path), *FAST, "--tag", "trajectory/m"]) == 0
    art = store.get(store.resolve("trajectory/m"))
    with np.load(art.path / "trajectory.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    scenario = json.loads((art.path / "scenario.json").read_text())
    return {"store": store, "art": art, "arrays": arrays, "scenario": scenario, "path": path, "checkpoint": checkpoint}


def _clip_of(scenario: dict, k: int) -> MotionClip:
    sha = scenario["humans"][k]["motion"]["clip"]
    entry = next(c for c in scenario["motion_clips"] if c["sha256"] == sha)
    return clip_from_data(entry)


def _mean_speed(arrays: dict, k: int) -> float:
    t, xy = arrays["time_s"], arrays["position_m"][:, k]
    keep = t >= WARMUP_S
    step = np.linalg.norm(np.diff(xy[keep], axis=0), axis=1)
    return float(step.sum() / (t[keep][-1] - t[keep][0]))


def test_people_walk_at_their_clip_s_speed(run):
    sc, arrays = run["scenario"], run["arrays"]
    bvh_clip, video_clip = _clip_of(sc, 0), _clip_of(sc, 1)
    # the clips' own speeds on the nsim body: the BVH's as written; the video's scaled by the legs (1.75 / 1.65)
    bvh_speed = LocomotionLoop.from_clip(bvh_clip).speed_mps
    video_speed = LocomotionLoop.from_clip(video_clip).speed_mps
    assert bvh_speed == pytest.approx(BVH_SPEED_MPS, rel=1e-3)
    assert video_speed == pytest.approx(VIDEO_SPEED_MPS * 1.75 / VIDEO_HEIGHT_M, rel=1e-3)
    # the scenario gives no speed: each person's desired speed is its clip's, and it walks at it
    assert sc["humans"][0]["speed_mps"] == pytest.approx(bvh_speed, abs=1e-6)
    assert sc["humans"][1]["speed_mps"] == pytest.approx(video_speed, abs=1e-6)
    assert _mean_speed(arrays, 0) == pytest.approx(bvh_speed, rel=0.10)
    assert _mean_speed(arrays, 1) == pytest.approx(video_speed, rel=0.10)
    # the idle stands where it started
    assert sc["humans"][2]["speed_mps"] == 0.0
    np.testing.assert_allclose(arrays["position_m"][:, 2], np.tile([0.8, 6.0], (len(arrays["time_s"]), 1)), atol=1e-9)


def test_the_gait_phase_advances_by_the_clip_s_own_stride(run):
    """The feet do not slide: a cycle of the clip is played per stride the clip takes (at the person's height),
    whatever the crowd's speed; the idle's phase runs with time."""
    sc, arrays = run["scenario"], run["arrays"]
    dt = float(arrays["time_s"][1] - arrays["time_s"][0])
    for k, height in ((0, 1.75), (1, 1.6)):
        stride = LocomotionLoop.from_clip(clip_at_height(_clip_of(sc, k), height)).stride_m
        walked = np.linalg.norm(np.diff(arrays["position_m"][:, k], axis=0), axis=1)
        advance = np.mod(np.diff(arrays["gait_phase"][:, k]), 1.0)
        np.testing.assert_allclose(advance * stride, walked, atol=1e-7)
    assert _clip_of(sc, 1).num_frames >= 3 and 1.6 / 1.75 * LocomotionLoop.from_clip(_clip_of(sc, 1)).stride_m == \
        pytest.approx(LocomotionLoop.from_clip(clip_at_height(_clip_of(sc, 1), 1.6)).stride_m, rel=1e-9)
    np.testing.assert_allclose(np.mod(np.diff(arrays["gait_phase"][:, 2]), 1.0), dt / IDLE_PERIOD_S, atol=1e-9)


def test_the_motions_are_stored_in_the_run(run):
    """The canonical scenario holds the clips (by SHA-256) and where they came from; trajectory.npz holds what render
    poses them with, and HumanSet poses each person as its clip at its height (no file needed)."""
    from nsim.rendering.people import HumanSet

    sc, arrays = run["scenario"], run["arrays"]
    bvh, video = sc["humans"][0]["motion"], sc["humans"][1]["motion"]
    assert bvh["source"].startswith("bvh file sha256 ") and "unit measured: unit cmu" in bvh["source"]
    assert "biped joint names, 24 of 24 body joints mapped" in bvh["source"] and "cmu_walk" not in bvh["source"]
    assert video["source"].startswith(f"human-checkpoint {run['checkpoint']} person.bvh (unit cm")
    assert [c["sha256"] for c in sc["motion_clips"]] == [bvh["clip"], video["clip"]]
    assert list(arrays["motion"]) == [f"clip {bvh['clip'][:12]}", f"clip {video['clip'][:12]}", "idle"]
    assert list(arrays["motion_clip"]) == [0, 1, -1]
    people = HumanSet([], arrays, "cpu")
    tick = 60
    posed = dict(people.joint_transforms(tick))
    for k, height in ((0, 1.75), (1, 1.6)):
        loop = person_loop("", _clip_of(sc, k), height)
        root, q = loop.pose_at(arrays["gait_phase"][tick, k:k + 1], arrays["position_m"][tick, k:k + 1],
                               arrays["heading_rad"][tick, k:k + 1])
        np.testing.assert_allclose(posed[k], forward_kinematics(loop.skeleton, q[0], root[0]), atol=1e-6)
    # the posed BVH walker's planted foot stays where it is from tick to tick while the body walks on
    foot = [JOINT_NAMES.index("left_foot"), JOINT_NAMES.index("right_foot")]
    feet = np.array([dict(people.joint_transforms(i))[0][foot, :3, 3] for i in range(40, 100)])  # (T, 2, 3)
    low = np.argmin(feet[:, :, 2], axis=1)
    planted = [np.linalg.norm(feet[i + 1, low[i], :2] - feet[i, low[i], :2]) for i in range(len(low) - 1)
               if low[i + 1] == low[i]]
    body = np.linalg.norm(np.diff(arrays["position_m"][40:100, 0], axis=0), axis=1)
    assert np.median(planted) < 0.2 * np.median(body)


def test_a_speed_given_wins_and_is_logged(tmp_path, caplog):
    folder = tmp_path / "a"
    folder.mkdir()
    _cmu_walk_bvh(folder / "cmu_walk.bvh")
    path = _write_scenario(folder, [_lane("bvh", 1.5, {"bvh": "cmu_walk.bvh", "unit": "cmu"}, speed_mps=1.4)])
    with caplog.at_level(logging.INFO, logger="nsim"):
        sc = load_scenario(path)
    assert sc.humans[0].speed_mps == 1.4
    lines = [r.getMessage() for r in caplog.records if "another speed than its own" in r.getMessage()]
    assert len(lines) == 1 and "humans[0] (bvh) 1.4 m/s, its clip's 1 m/s" in lines[0]
    assert not any("m per unit (unit: auto" in r.getMessage() for r in caplog.records)  # the unit was given


def test_the_canonical_scenario_does_not_depend_on_where_the_file_is(tmp_path, caplog):
    a = tmp_path / "a"
    a.mkdir()
    _cmu_walk_bvh(a / "cmu_walk.bvh")
    first = _write_scenario(a, [_lane("bvh", 1.5, {"bvh": "cmu_walk.bvh"})])
    b = tmp_path / "elsewhere" / "deeper"
    b.mkdir(parents=True)
    shutil.copy(a / "cmu_walk.bvh", b / "cmu_walk.bvh")
    moved = _write_scenario(b, [_lane("bvh", 1.5, {"bvh": "cmu_walk.bvh"})])
    with caplog.at_level(logging.INFO, logger="nsim"):
        digest = load_scenario(first).digest
    guessed = [r.getMessage() for r in caplog.records if "m per unit (unit: auto" in r.getMessage()]
    assert len(guessed) == 1 and "unit cmu" in guessed[0] and "0.0564444 m per unit" in guessed[0]
    assert load_scenario(moved).digest == digest
    # the canonical content reads back as it is (no file needed)
    from nsim.stages.simulate import scenario_from_data

    sc = load_scenario(moved)
    assert scenario_from_data(sc.data, source="stored").digest == digest


def _cli_error(run_cli, tmp_path, monkeypatch, humans: list[dict], files: dict[str, object] | None = None,
               store_setup=None) -> str:
    """Run simulate on a scenario that must be refused before any simulation work: its one stderr line."""
    folder = tmp_path / "sc"
    for name, make in (files or {}).items():
        folder.mkdir(parents=True, exist_ok=True)
        make(folder / name)
    path = _write_scenario(folder, humans)
    calls = block_work(monkeypatch, "nsim.stages.simulate.simulate")
    code, out, err = run_cli("simulate", "--scenario", str(path), *FAST)
    assert code == 2 and out == "" and not calls, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _few_joints_bvh(path: Path) -> Path:
    """Legs and a head only, CMU's names: 8 of the body's 24 joints."""
    walk = walk_cycle(1.0)
    sk = walk.skeleton
    keep = ["pelvis", "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle", "head"]
    names = {"pelvis": "Hips", "left_hip": "LeftUpLeg", "left_knee": "LeftLeg", "left_ankle": "LeftFoot",
             "right_hip": "RightUpLeg", "right_knee": "RightLeg", "right_ankle": "RightFoot", "head": "Head"}
    idx = [sk.index(n) for n in keep]
    parents = [-1, 0, 1, 2, 0, 4, 5, 0]
    offsets = [sk.offsets_m[i] for i in idx]
    offsets[-1] = sk.rest_positions_m()[sk.index("head")] - sk.rest_positions_m()[0]
    body = Skeleton(tuple(names[n] for n in keep), parents, offsets, sk.end_sites_m[idx])
    clip = MotionClip(body, walk.fps, walk.root_positions_m, walk.local_rotations_wxyz[:, idx])
    return write_bvh(path, clip)


@pytest.mark.parametrize(("motion", "files", "expected"), [
    ("moonwalk", None, "humans[0].motion: 'moonwalk' is not one of walk, walk_slow, walk_fast, idle"),
    ({"bvh": "walk.bvh", "speed": 1.0}, None, "humans[0].motion.speed: unknown key"),
    ({"bvh": "walk.bvh", "from": "human/x"}, None, "humans[0].motion: expected one of walk, walk_slow"),
    ({"bvh": "nope.bvh"}, None, "humans[0].motion.bvh: no such file "),
    ({"bvh": "few.bvh"}, {"few.bvh": _few_joints_bvh}, "humans[0].motion: "),
])
def test_bad_motions_are_one_line_before_any_work(run_cli, tmp_path, monkeypatch, motion, files, expected):
    line = _cli_error(run_cli, tmp_path, monkeypatch, [_lane("p", 1.5, motion)], files)
    assert expected in line, line
    if motion == {"bvh": "nope.bvh"}:
        assert str(tmp_path / "sc" / "nope.bvh") in line
    if files:  # the too-few-joints file: named, with the count
        assert f"{tmp_path / 'sc' / 'few.bvh'}: only 8 of 24 body joints map" in line, line


def test_a_checkpoint_without_a_fitted_motion_is_one_line(run_cli, tmp_path, monkeypatch):
    store = Store(tmp_path / "ws")
    plain = _human_checkpoint(store, with_bvh=False)
    line = _cli_error(run_cli, tmp_path, monkeypatch, [_lane("p", 1.5, {"from": plain})])
    assert f"humans[0].motion.from: human checkpoint {plain[:12]}" in line and "has no person.bvh" in line, line
    line = _cli_error(run_cli, tmp_path, monkeypatch, [_lane("p", 1.5, {"from": "human/nobody"})])
    assert "humans[0].motion.from: no artifact or ref named 'human/nobody'" in line, line


def test_an_unsteady_clip_is_one_warning_for_everyone_it_drives(tmp_path, caplog):
    """A clip that starts standing plays as one cycle, so the body drifts about the person: one warning line,
    naming the people, for the file read once."""
    walk = walk_cycle(1.0)
    root = np.concatenate([np.repeat(walk.root_positions_m[:1], 30, 0), walk.root_positions_m])
    quats = np.concatenate([np.repeat(walk.local_rotations_wxyz[:1], 30, 0), walk.local_rotations_wxyz])
    folder = tmp_path / "u"
    folder.mkdir()
    write_bvh(folder / "start_walk.bvh", renamed(MotionClip(walk.skeleton, walk.fps, root, quats), "cmu"), unit="cmu")
    motion = {"bvh": "start_walk.bvh", "unit": "cmu"}
    path = _write_scenario(folder, [_lane("a", 1.5, motion), _lane("b", 3.5, motion)])
    with caplog.at_level(logging.WARNING, logger="nsim"):
        sc = load_scenario(path)
    lines = [r.getMessage() for r in caplog.records if "strays up to" in r.getMessage()]
    assert len(lines) == 1 and "humans[0], humans[1]: the clip's root strays up to" in lines[0], lines
    assert sc.humans[0].clip_id == sc.humans[1].clip_id and len(sc.data["motion_clips"]) == 1
