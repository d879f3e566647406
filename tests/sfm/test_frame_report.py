"""The account of every video frame: blurred, duplicate, not sampled, kept, and SfM's verdict."""

from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest

from nsim.io.images import read_image
from nsim.sfm.frames import (
    BLURRED,
    DUPLICATE,
    KEPT,
    NOT_REGISTERED,
    NOT_SAMPLED,
    POSE_JUMP,
    USED,
    account_frames,
    choose_frames,
    frame_name,
    frame_summary_line,
    select_video,
    video_frame_report,
)
from nsim.workspace.store import Store
from tests.sfm.test_frames import _panning_frames

FPS = 10.0


def _write_mp4(path, frames: list[np.ndarray], fps: float = FPS) -> None:
    """mp4v in MP4, as a phone would record it (lossy)."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()


def _blur(image: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(image, (0, 0), 3.0)


def _expand(entries: list[dict]) -> list[int]:
    """Every frame index the report's entries cover (a run covers index..last)."""
    return [i for e in entries for i in range(e["index"], e.get("last", e["index"]) + 1)]


def _check_partition(report: dict, n: int) -> None:
    """Every frame index is in exactly one entry, in order; the counts agree with the entries."""
    assert _expand(report["frames"]) == list(range(n))
    assert report["frames_decoded"] == n and sum(report["counts"].values()) == n
    counted: dict[str, int] = {}
    for e in report["frames"]:
        counted[e["status"]] = counted.get(e["status"], 0) + e.get("count", 1)
    assert {s: c for s, c in report["counts"].items() if c} == counted


def test_known_blurred_and_duplicate_frames_are_reported(tmp_path):
    n, blurred, duplicates = 40, {7, 19, 30}, {12, 13, 25}
    frames = _panning_frames(n)
    for i in sorted(duplicates):
        frames[i] = frames[i - 1]  # 12 and 13 repeat 11, 25 repeats 24: a camera standing still
    for i in blurred:
        frames[i] = _blur(frames[i])
    video = tmp_path / "walk.mp4"
    _write_mp4(video, frames)
    selection = select_video(video, n)  # one span per frame: nothing is left unsampled
    account = selection.account
    assert set(np.flatnonzero(account.status == BLURRED)) == blurred
    assert set(np.flatnonzero(account.status == DUPLICATE)) == duplicates
    assert account.counts() == {BLURRED: 3, NOT_SAMPLED: 0, DUPLICATE: 3, KEPT: n - 6}
    assert [f.index for f in selection.frames] == sorted(set(range(n)) - blurred - duplicates)

    report = selection.report({})
    _check_partition(report, n)
    by_index = {e["index"]: e for e in report["frames"]}
    assert report["fps"] == FPS and report["frames_sampled"] == n - 3 and report["windows"] == n
    for i, e in by_index.items():
        assert e["timestamp_s"] == pytest.approx(i / FPS)
        assert e["sharpness"] == pytest.approx(account.sharpness[i])
        if i in blurred:
            assert e["status"] == BLURRED and e["sharpness"] < report["blur_threshold"]
            assert "name" not in e
        elif i in duplicates:
            assert e["status"] == DUPLICATE and e["difference"] < report["dedup_threshold"]
            assert e["compared_with"] == {12: 11, 13: 11, 25: 24}[i]
        else:
            assert e["status"] == KEPT and e["name"] == frame_name(i) and e["sharpness"] >= report["blur_threshold"]
            assert (e["difference"] is None) == (i == 0)
            assert i == 0 or e["difference"] >= report["dedup_threshold"]
    # a kept frame right after a blurred or duplicate one is compared with the last kept frame
    assert (by_index[8]["compared_with"], by_index[14]["compared_with"]) == (6, 11)
    json.dumps(report)  # plain JSON types only


def test_subsampled_video_accounts_for_every_frame_once(tmp_path):
    n, blurred, still = 90, {4, 5, 6, 33, 61}, range(40, 56)
    frames = _panning_frames(n)
    for i in still:
        frames[i] = frames[still[0]]
    for i in blurred:
        frames[i] = _blur(frames[i])
    video = tmp_path / "walk.mp4"
    _write_mp4(video, frames)
    selection = select_video(video, 15)  # spans of 6 frames
    account = selection.account
    report = selection.report({})
    _check_partition(report, n)
    assert report["windows"] == 15 and report["frames_sampled"] == 15
    counts = report["counts"]
    assert frame_summary_line(report) == (
        f"15 of 90 video frames sampled ({counts[KEPT]} kept, {counts[DUPLICATE]} duplicates); 5 blurred, "
        f"{counts[NOT_SAMPLED]} not sampled (a sharper frame of their span was sampled)")
    statuses = {i: e["status"] for e in report["frames"] for i in _expand([e])}
    assert {i for i, s in statuses.items() if s == BLURRED} == blurred
    # a run of not-sampled frames lies in one span, whose pick is the sharpest of its unblurred frames
    runs = [e for e in report["frames"] if e["status"] == NOT_SAMPLED]
    assert runs and all(e["count"] == e["last"] - e["index"] + 1 for e in runs)
    for e in runs:
        span = np.flatnonzero(account.window == account.window[e["index"]])
        assert set(range(e["index"], e["last"] + 1)) <= set(span)
        sharp = [i for i in span if statuses[i] != BLURRED]
        assert e["picked"] == max(sharp, key=lambda i: (account.sharpness[i], -i))
        assert statuses[e["picked"]] in (KEPT, DUPLICATE)
        assert e["timestamp_s"] == pytest.approx(e["index"] / FPS)
        assert e["last_timestamp_s"] == pytest.approx(e["last"] / FPS)
    # the still camera: one frame of it kept, the later picks duplicates of it
    kept_still = [i for i in still if statuses[i] == KEPT]
    dup_still = [i for i in still if statuses[i] == DUPLICATE]
    assert len(kept_still) == 1 and len(dup_still) >= 1 and min(dup_still) > kept_still[0]
    assert {i for i, s in statuses.items() if s == DUPLICATE} == set(dup_still)
    # the kept frames are what choose_frames keeps and what the second decoding pass returned
    assert [f.index for f in selection.frames] == sorted(i for i, s in statuses.items() if s == KEPT)


def test_sfm_fates_join_on_name_and_summary_line():
    n = 30
    sharp = np.ones(n)
    sharp[[3, 17]] = 0.01  # blurred
    thumbs = np.stack([np.full((24, 32), i / n, np.float32) for i in range(n)])
    thumbs[9] = thumbs[8]  # a duplicate
    account = account_frames(sharp, thumbs, n)
    np.testing.assert_array_equal(account.kept, choose_frames(sharp, thumbs, n))
    kept = [frame_name(int(i)) for i in account.kept]
    fates = dict.fromkeys(kept, USED) | {kept[4]: NOT_REGISTERED, kept[5]: POSE_JUMP}
    report = video_frame_report(account, np.arange(n) / FPS, fates, FPS)
    _check_partition(report, n)
    named = {e["name"]: e["status"] for e in report["frames"] if "name" in e}
    assert named == fates  # the statuses report.json's images list uses, under the same names
    assert report["counts"] == {BLURRED: 2, NOT_SAMPLED: 0, DUPLICATE: 1, USED: n - 5, NOT_REGISTERED: 1,
                                POSE_JUMP: 1}
    assert frame_summary_line(report) == (
        f"28 of 30 video frames sampled ({n - 5} used, 1 not registered, 1 dropped for a pose jump, "
        "1 duplicates); 2 blurred, 0 not sampled")


def test_account_of_nothing():
    account = account_frames(np.zeros(0), np.zeros((0, 24, 32)), 10)
    assert account.kept.size == 0 and account.counts() == {BLURRED: 0, NOT_SAMPLED: 0, DUPLICATE: 0, KEPT: 0}
    report = video_frame_report(account, [], {})
    assert report["frames"] == [] and report["frames_sampled"] == 0


@pytest.mark.slow
def test_reconstruct_video_report_accounts_for_every_frame(pinhole_capture, run_cli, tmp_path, caplog):
    """End to end: report.json's video_frames and images lists join on name and agree."""
    frames, blurred, duplicates = [], set(), set()
    for k, name in enumerate(pinhole_capture.names):
        image = read_image(pinhole_capture.image_dir / name)
        if k == 10:
            blurred.add(len(frames))
            frames.append(_blur(image))
        frames.append(image)
        if k == 5:
            duplicates |= {len(frames), len(frames) + 1}
            frames += [image, image]
    video = tmp_path / "room.mp4"
    _write_mp4(video, frames)
    n = len(frames)
    ws = tmp_path / "ws"
    caplog.set_level(logging.INFO, logger="nsim.stages.reconstruct")
    code, out, err = run_cli("reconstruct", str(video), "--preset", "tiny", "--frames", str(n), workspace=ws)
    assert code == 0, err
    art = Store(ws).get(out.strip())
    report = json.loads(art.file("report.json").read_text())
    video_frames = report["video_frames"]
    _check_partition(video_frames, n)
    statuses = {e["index"]: e["status"] for e in video_frames["frames"]}
    assert {i for i, s in statuses.items() if s == BLURRED} == blurred
    assert {i for i, s in statuses.items() if s == DUPLICATE} == duplicates
    images = {im["name"]: im["status"] for im in report["images"]}
    assert images == {e["name"]: e["status"] for e in video_frames["frames"] if "name" in e}
    assert sorted(p.name for p in (art.path / "images").iterdir()) == sorted(images)
    assert video_frames["counts"][USED] == report["images_registered"] > 0.5 * n
    line = art.manifest["summary"]["video_frames"]
    assert line.startswith(f"{n - 1} of {n} video frames sampled (") and "2 duplicates); 1 blurred" in line
    assert line in caplog.text  # logged (shown with nsim -v)
