"""`nsim train-human --video` end to end at tiny size, with a scripted detector in MediaPipe's place
(what it reports comes from known poses): the human data folder it writes, the checkpoint with the
person's BVH and fit report, and bad input refused in one line with nothing published."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

import nsim.human.landmarks as landmarks
from nsim.cli import main
from nsim.geometry.transforms import look_at
from nsim.human.bvh import read_bvh
from nsim.human.fit import reference_body
from nsim.human.gait import walk_cycle
from nsim.human.landmarks import LANDMARK_NAMES, FrameObservation
from nsim.human.monocular import static_camera
from nsim.human.motion import LocomotionLoop
from nsim.human.skeleton import forward_kinematics
from nsim.io.video import write_mp4
from nsim.workspace.store import Store

FPS, W, H, HFOV = 15.0, 160, 120, 70.0
HIPS = [LANDMARK_NAMES.index("left_hip"), LANDMARK_NAMES.index("right_hip")]


def _landmarks(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame landmarks (n, L, 3) of a walk past a camera 1.5 m up, and their pixels (n, L, 2)."""
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, fps=FPS))
    root, quats = loop.sample(np.arange(n) / FPS)
    body = reference_body(1.75)
    lm = body.landmarks(forward_kinematics(body.skeleton, quats, root + (-1.5, 0.0, 0.0)))
    w2c = np.linalg.inv(look_at((0.3, -4.5, 1.5), (0.0, 0.0, 0.9)))
    lm = lm @ w2c[:3, :3].T + w2c[:3, 3]
    uv, _ = static_camera(W, H, HFOV).project(lm)
    return lm, uv


class _Scripted:
    """Reports the known walk, frame after frame; frames whose pixels are all black show nobody."""

    def __init__(self, n: int, backward: bool = False):
        self.lm, self.uv = _landmarks(n)
        self.k, self.step = (n - 1, -1) if backward else (0, 1)

    def __call__(self, rgb):
        k, self.k = self.k, self.k + self.step
        if rgb.max() < 20:
            return None
        lm, uv = self.lm[k], self.uv[k]
        mask = np.zeros(rgb.shape[:2], np.float32)
        lo, hi = np.floor(uv.min(0)).astype(int), np.ceil(uv.max(0)).astype(int)
        mask[max(lo[1], 0):hi[1] + 1, max(lo[0], 0):hi[0] + 1] = 1.0
        return FrameObservation(uv, lm - lm[HIPS].mean(0), np.ones(33), mask, None)

    def close(self):
        pass


def _video(path, n: int, dark=()) -> str:
    rng = np.random.default_rng(0)
    frames = []
    for k in range(n):
        rgb = rng.integers(60, 200, (H, W, 3), dtype=np.uint8)
        if k in dark:
            rgb[:] = 0
        frames.append(rgb)
    write_mp4(path, frames, FPS)
    return str(path)


@pytest.fixture
def scripted(monkeypatch):
    def make(n: int):
        made = []

        def detector(**kwargs):  # the second one made runs over the frames last to first (PersonVideoConfig.both_directions)
            made.append(_Scripted(n, backward=bool(made)))
            return made[-1]
        monkeypatch.setattr(landmarks, "MediaPipePoseDetector", detector)
    return make


def _artifacts(ws) -> int:
    return len(Store(ws).artifacts()) if (ws / "objects").exists() else 0


def test_video_to_human_checkpoint(tmp_path, scripted, capsys):
    n = 36
    scripted(n)
    video = _video(tmp_path / "walk.mp4", n, dark=range(20, 23))
    ws = tmp_path / "ws"
    args = ["--workspace", str(ws), "--device", "cpu", "train-human", "--video", video, "--fov", str(HFOV),
            "--camera-height", "1.5", "--preset", "tiny", "--steps", "5", "--tag", "human/video"]
    assert main(args) == 0, capsys.readouterr().err
    store = Store(ws)
    art = store.get(store.resolve("human/video"))
    m = json.loads(art.file("manifest.json").read_text())
    assert m["summary"]["frames"] == n - 3 and m["summary"]["source"] == video
    assert m["summary"]["person"]["dropped"] == ["frames 20-22 (1.3-1.5 s, 3 frames): no person"]
    report = json.loads(art.file("person_fit.json").read_text())
    assert report["camera_height_m"] == pytest.approx(1.5) and report["height_m"] == pytest.approx(1.75, abs=0.06)
    assert report["hfov_deg"] == pytest.approx(HFOV)
    clip = read_bvh(art.file("person.bvh"))
    assert clip.num_frames == 20  # frames 0-19, the longest stretch with the person
    assert not list((ws / "tmp").glob("train_human.*"))
    # the same video again: the run cache answers; another mask threshold is another artifact
    assert main(args[:-2]) == 0
    assert "cached" in capsys.readouterr().err
    assert main([*args[:-2], "--mask-threshold", "0.9", "--tag", "human/video-09"]) == 0
    assert store.resolve("human/video-09") != store.resolve("human/video")


@pytest.mark.parametrize("extra, message", [
    (["--video", "walk.mp4", "--mask-threshold", "1.5"], "--mask-threshold"),
    (["--data", "folder", "--mask-threshold", "0.8"], "--mask-threshold go with --video or --images"),
])
def test_mask_threshold_is_checked_before_anything_runs(tmp_path, capsys, extra, message):
    ws = tmp_path / "ws"
    code = main(["--workspace", str(ws), "--device", "cpu", "train-human", *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert _artifacts(ws) == 0


@pytest.mark.parametrize("case, message", [
    ("extra", r"needs MediaPipe: pip install 'nsim\[people\]'"),
    ("short", "is too short"),
    ("nobody", "no person found in any of its 36 frames"),
    ("missing", "no such file"),
])
def test_bad_videos_publish_nothing(tmp_path, scripted, monkeypatch, capsys, case, message):
    n = 36
    scripted(n)
    if case == "extra":
        monkeypatch.undo()
        monkeypatch.setitem(sys.modules, "mediapipe", None)
    video = _video(tmp_path / "walk.mp4", 15 if case == "short" else n, dark=range(n) if case == "nobody" else ())
    if case == "missing":
        video = str(tmp_path / "nope.mp4")
    ws = tmp_path / "ws"
    capsys.readouterr()
    code = main(["--workspace", str(ws), "--device", "cpu", "train-human", "--video", video, "--preset", "tiny",
                 "--steps", "5"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert re.search(message, err), err
    assert _artifacts(ws) == 0
