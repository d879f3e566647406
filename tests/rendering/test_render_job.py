"""The render's data (``nsim.rendering.render_job``): frames, streams and the shard job are plain, picklable
data (they cross to Ray workers as they are); the plan reads folders, not a workspace; render.json's frame
entries and the shard keys are what the dicts they replaced gave."""

from __future__ import annotations

import hashlib
import json
import pickle

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.npz import save_npz_deterministic
from nsim.rendering.render_job import (
    ArtifactDir,
    PoseFrame,
    RecordedFrame,
    RecordedStream,
    RenderSources,
    ShardJob,
    TickFrame,
)
from nsim.rendering.render_plan import RenderConfig, plan_frames, shard_key, shards_of

CAMERA = Camera.pinhole_from_fov(8, 6, 60.0)


def pose(x: float) -> np.ndarray:
    p = np.eye(4)
    p[:3, 3] = (x, 0.5, 1.25)
    return p


def trajectory(tmp_path, n: int = 5) -> ArtifactDir:
    art = ArtifactDir("ab" * 32, tmp_path / "traj")
    art.path.mkdir()
    save_npz_deterministic(art.path / "trajectory.npz", {"robot_pose_se3": np.stack([pose(0.1 * i) for i in range(n)]),
                                                         "time_s": np.arange(n) * 0.1})
    return art


def test_frames_are_read_only_float64_copies():
    source = pose(1.0).astype(np.float32)
    f = TickFrame(index=3, time_s=0.3, body_to_world=source)
    assert f.body_to_world.dtype == np.float64 and not f.body_to_world.flags.writeable
    assert np.array_equal(f.body_to_world, np.asarray(source.tolist(), dtype=np.float64))  # as the JSON lists gave
    source[0, 3] = 9.0
    assert f.body_to_world[0, 3] == 1.0
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        TickFrame(index=0, time_s=0.0, body_to_world=np.eye(3))


def test_render_json_entries_are_the_old_dicts():
    """``to_json`` gives exactly the keys and values render.json listed from the frame dicts."""
    tick = TickFrame(index=2, time_s=0.2, body_to_world=pose(0.0))
    old = {"index": 2, "time_s": 0.2, "body_to_world": pose(0.0).tolist()}
    assert tick.to_json() == {k: old[k] for k in ("index", "time_s", "name") if k in old}
    frame = PoseFrame(index=4, time_s=None, name="0004.png", cam_to_world=pose(1.0), camera=CAMERA)
    assert json.dumps(frame.to_json(), sort_keys=True) == json.dumps({"index": 4, "time_s": None, "name": "0004.png"},
                                                                       sort_keys=True)
    w = pose(2.0) @ pose(0.5)
    rec = RecordedFrame(stream="camera/left", index=7, stamp_ns=10**18 + 1, odom_time_ns=10**18, body_to_world=pose(2.0),
                        sensor_to_world=w)
    assert rec.to_json() == {"index": 7, "stamp_ns": 10**18 + 1, "odom_time_ns": 10**18, "sensor_to_world": w.tolist()}
    with_people = RecordedFrame(stream="camera/left", index=7, stamp_ns=1, odom_time_ns=1, body_to_world=pose(2.0),
                                sensor_to_world=w, people_time_s=0.25)
    assert with_people.to_json()["people_time_s"] == 0.25


def test_shard_keys_are_the_old_ones():
    """The digest covers the same ids as before: the indices, or (stream, index) in recording mode."""
    ticks = [TickFrame(index=i, time_s=0.1 * i, body_to_world=pose(0.0)) for i in (3, 5)]
    digest = hashlib.sha256(f"KEY:{[3, 5]}".encode()).hexdigest()[:16]
    assert shard_key("KEY", ticks) == f"shard_000003_000005_{digest}"
    rec = [RecordedFrame(stream="lidar/top", index=9, stamp_ns=0, odom_time_ns=0, body_to_world=pose(0.0),
                         sensor_to_world=pose(0.0))]
    digest = hashlib.sha256(f"KEY:{[('lidar/top', 9)]}".encode()).hexdigest()[:16]
    assert shard_key("KEY", rec) == f"shard_000009_000009_{digest}"


def test_shard_job_pickles_for_ray_workers(tmp_path):
    frames = (TickFrame(index=0, time_s=0.0, body_to_world=pose(0.0)),
              PoseFrame(index=1, time_s=1.5, name="a.png", cam_to_world=pose(1.0), camera=CAMERA),
              RecordedFrame(stream="camera/left", index=2, stamp_ns=5, odom_time_ns=4, body_to_world=pose(2.0),
                            sensor_to_world=pose(3.0), people_time_s=0.5))
    stream = RecordedStream(key="camera/left", kind="camera", name="left", sensor_to_body=pose(0.1), camera=CAMERA,
                            color="gray", skipped_outside_trajectory=1, people_outside_run=0)
    job = ShardJob(scene_dir=tmp_path / "scene", human_dirs=(tmp_path / "h0",), person_model=(0, 0),
                   trajectory_npz=tmp_path / "t.npz", rig=None, recording_dir=tmp_path / "rec", streams=(stream,),
                   seed=7, device="cpu", shards=(frames[:2], frames[2:]), baked_dir=None)
    back = pickle.loads(pickle.dumps(job))
    assert (back.scene_dir, back.human_dirs, back.person_model, back.seed, back.device) == \
           (job.scene_dir, job.human_dirs, (0, 0), 7, "cpu")
    assert back.streams[0].camera == CAMERA and np.array_equal(back.streams[0].sensor_to_body, pose(0.1))
    for a, b in zip([f for s in job.shards for f in s], [f for s in back.shards for f in s], strict=True):
        assert type(a) is type(b) and a.to_json() == b.to_json()
    assert np.array_equal(back.shards[0][1].cam_to_world, pose(1.0)) and back.shards[0][1].camera == CAMERA


def test_plan_frames_reads_folders_not_a_workspace(tmp_path):
    """Trajectory mode from a bare folder: every ``tick_stride``-th tick from ``start``, at most ``max_frames``,
    cut into shards of ``shard_frames``."""
    sources = RenderSources(scene=ArtifactDir("cd" * 32, tmp_path / "scene"), trajectory=trajectory(tmp_path))
    cfg = RenderConfig(start=1, tick_stride=2, max_frames=None, shard_frames=1)
    frames = plan_frames(sources, cfg)
    assert [f.index for f in frames] == [1, 3] and [f.time_s for f in frames] == [0.1, 0.30000000000000004]
    assert all(isinstance(f, TickFrame) for f in frames) and np.array_equal(frames[1].body_to_world, pose(0.1 * 3))
    assert [[f.index for f in s] for s in shards_of(frames, cfg)] == [[1], [3]]
    missing = RenderSources(scene=sources.scene, trajectory=ArtifactDir("ef" * 32, tmp_path / "nothing"))
    with pytest.raises(InputError, match="artifact efefefefefef: has no file trajectory.npz"):
        plan_frames(missing, cfg)
