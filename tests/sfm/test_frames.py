"""Frame selection from videos and image folders."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.images import read_image, write_image
from nsim.sfm.frames import (
    choose_frames,
    list_image_files,
    load_image_folder,
    select_video_frames,
    sharpness,
    write_frames,
)

FPS = 10.0


def _textured(rng: np.random.Generator, h: int = 96, w: int = 128) -> np.ndarray:
    noise = rng.uniform(0, 1, (h // 4, w // 4, 3)).astype(np.float32)
    return np.rint(cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1) * 255).astype(np.uint8)


def _panning_frames(n: int, seed: int = 0) -> list[np.ndarray]:
    """n frames panning over a big random texture, 3 px per frame."""
    big = _textured(np.random.default_rng(seed), 96, 128 + 3 * n)
    return [np.ascontiguousarray(big[:, 3 * i: 3 * i + 128]) for i in range(n)]


def _write_video(path, frames: list[np.ndarray]) -> None:
    """MJPG in AVI: the codec every OpenCV build has (lossy, like a phone video)."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (w, h))
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()


def test_sharpness_drops_with_blur():
    image = _textured(np.random.default_rng(0))
    blurred = cv2.GaussianBlur(image, (0, 0), 2.0)
    assert sharpness(blurred) < 0.5 * sharpness(image)
    assert sharpness(np.zeros((20, 20, 3), np.uint8)) == 0.0


def test_choose_frames_spreads_and_skips_blur_and_duplicates():
    n = 100
    sharp = np.ones(n)
    sharp[::7] = 0.05  # blurred frames
    thumbs = np.stack([np.full((24, 32), i / n, np.float32) for i in range(n)])
    keep = choose_frames(sharp, thumbs, 10)
    assert len(keep) == 10
    assert not np.any(keep % 7 == 0)
    assert np.all(np.diff(keep) >= 5)  # one per span of 10
    # a camera standing still: identical thumbnails after frame 50
    thumbs[50:] = thumbs[50]
    keep = choose_frames(sharp, thumbs, 10)
    assert keep.max() < 60 and len(keep) == 6


def test_choose_frames_takes_every_frame_when_asked_for_more():
    keep = choose_frames(np.ones(5), np.random.default_rng(0).uniform(size=(5, 24, 32)), 50)
    np.testing.assert_array_equal(keep, np.arange(5))


def test_select_video_frames(tmp_path):
    frames = _panning_frames(60)
    for i in range(0, 60, 4):
        frames[i] = cv2.GaussianBlur(frames[i], (0, 0), 2.5)  # motion-blurred frames
    video = tmp_path / "walk.avi"
    _write_video(video, frames)
    progress = []
    selected = select_video_frames(video, 12, progress=lambda *a: progress.append(a))
    assert 10 <= len(selected) <= 12
    indices = [f.index for f in selected]
    assert indices == sorted(indices) and indices[-1] >= 50
    assert all(i % 4 != 0 for i in indices)
    for f in selected:
        assert f.image.shape == (96, 128, 3) and f.image.dtype == np.uint8
        assert f.timestamp_s == pytest.approx(f.index / FPS)
        assert f.name == f"frame_{f.index:05d}.png"
        # the second decoding pass returned the right frame (MJPG is lossy: closer than the next frame)
        other = f.index + 1 if f.index < 59 else f.index - 1
        err = [np.abs(f.image.astype(float) - frames[k]).mean() for k in (f.index, other)]
        assert err[0] < 0.7 * err[1]
    assert progress[-1][0] == "frames" and progress[-1][1] == 60
    paths = write_frames(selected, tmp_path / "out")
    np.testing.assert_array_equal(read_image(paths[0]), selected[0].image)


def test_select_video_frames_drops_a_still_camera(tmp_path):
    frames = _panning_frames(20) + [_panning_frames(20)[-1]] * 40
    video = tmp_path / "still.avi"
    _write_video(video, frames)
    selected = select_video_frames(video, 30)
    assert max(f.index for f in selected) < 25  # the 40 still frames add at most one


@pytest.mark.parametrize("content, expected", [(b"", "cannot open"), (b"not a video at all" * 100, "cannot open")])
def test_unreadable_video_is_an_input_error(tmp_path, content, expected):
    video = tmp_path / "broken.mp4"
    video.write_bytes(content)
    with pytest.raises(InputError, match=f"broken.mp4: .*({expected}|no frames)"):
        select_video_frames(video, 10)


def test_missing_video_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="nope.mp4: no such file"):
        select_video_frames(tmp_path / "nope.mp4", 10)


def test_too_few_usable_frames(tmp_path):
    video = tmp_path / "short.avi"
    _write_video(video, _panning_frames(2))
    with pytest.raises(InputError, match="short.avi: only 2 usable frames"):
        select_video_frames(video, 10)


def test_load_image_folder_in_name_order(tmp_path, caplog):
    rng = np.random.default_rng(1)
    for name in ("img10.png", "img2.jpg", "img1.PNG", "notes.txt"):
        if name.endswith("txt"):
            (tmp_path / name).write_text("x")
        else:
            write_image(tmp_path / name, _textured(rng))
    frames = load_image_folder(tmp_path)
    # text order, as COLMAP's sequential matcher sees it, with a warning about the missing padding
    assert [f.name for f in frames] == ["img1.png", "img10.png", "img2.png"]
    assert [f.index for f in frames] == [0, 1, 2]
    assert all(f.timestamp_s is None for f in frames)
    assert [p.name for p in list_image_files(tmp_path)] == ["img1.PNG", "img10.png", "img2.jpg"]
    assert "zero-padded" in caplog.text


def test_load_image_folder_too_few(tmp_path):
    write_image(tmp_path / "a.png", _textured(np.random.default_rng(0)))
    with pytest.raises(InputError, match="found 1 images .*need at least 3"):
        load_image_folder(tmp_path)


def test_load_image_folder_mixed_sizes(tmp_path):
    rng = np.random.default_rng(0)
    write_image(tmp_path / "a.png", _textured(rng))
    write_image(tmp_path / "b.png", _textured(rng))
    write_image(tmp_path / "c.png", _textured(rng, 64, 64))
    with pytest.raises(InputError, match="c.png: image is 64x64 but a.png is 128x96; shared intrinsics"):
        load_image_folder(tmp_path)
    assert len(load_image_folder(tmp_path, shared_intrinsics=False)) == 3


def test_load_image_folder_clashing_stems(tmp_path):
    rng = np.random.default_rng(0)
    for name in ("a.png", "a.jpg", "b.png"):
        write_image(tmp_path / name, _textured(rng))
    with pytest.raises(InputError, match="same name as"):
        load_image_folder(tmp_path)
