"""H.264 MP4 writing (nsim.io.video): the codec read back, frame count and size, determinism, bad input."""

import cv2
import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.video import CODEC, open_mp4, probe_video, write_mp4


def _frames(n: int, h: int, w: int) -> list[np.ndarray]:
    """Smooth gradients with a bright square moving right: easy to compress, easy to compare."""
    y, x = np.mgrid[0:h, 0:w]
    base = np.stack([x * 255 // max(w - 1, 1), y * 255 // max(h - 1, 1), np.full_like(x, 96)], -1).astype(np.uint8)
    frames = []
    for k in range(n):
        f = base.copy()
        f[h // 4: h // 4 + 8, 2 * k: 2 * k + 8] = 255
        frames.append(f)
    return frames


def _read_opencv(path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(bgr[..., ::-1])
    cap.release()
    return frames


def test_writes_h264_with_the_frames(tmp_path):
    frames = _frames(7, 48, 64)
    path = write_mp4(tmp_path / "clip.mp4", frames, fps=10.0)
    assert path == tmp_path / "clip.mp4" and [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]
    info = probe_video(path)
    assert CODEC == "h264"
    assert (info.codec, info.width, info.height, info.frames) == ("h264", 64, 48, 7)
    assert info.fps == pytest.approx(10.0)
    # what nsim reconstruct's reader (OpenCV) gets back: every frame, nearly unchanged
    back = _read_opencv(path)
    assert len(back) == 7 and back[0].shape == (48, 64, 3)
    err = np.abs(np.stack(back).astype(int) - np.stack(frames).astype(int))
    assert err.mean() < 3.0  # 8-bit limited-range 4:2:0 and back: about 2 levels
    for k, f in enumerate(back):  # in order: the square has moved 2 px per frame
        assert f[12:20, 2 * k + 1:2 * k + 7].min() > 200 and f[12:20, 2 * k + 10:].max(axis=-1).min() < 200


def test_odd_size_is_padded_to_even(tmp_path):
    frames = _frames(3, 25, 33)
    info = probe_video(write_mp4(tmp_path / "odd.mp4", frames, fps=5))
    assert (info.codec, info.width, info.height, info.frames) == ("h264", 34, 26, 3)
    back = _read_opencv(tmp_path / "odd.mp4")
    assert back[1].shape == (26, 34, 3)
    # the picture keeps its place (not scaled): the square in frame 1 at rows 6-13, columns 2-9
    assert back[1][7:13, 3:9].min() > 200 and back[1][7:13, 12:].max(axis=-1).min() < 200
    assert np.abs(back[1][:25, :33].astype(int) - frames[1].astype(int)).mean() < 5.0  # steep gradients here


def test_same_frames_same_bytes(tmp_path):
    frames = _frames(5, 32, 32)
    a = write_mp4(tmp_path / "a.mp4", frames, fps=20).read_bytes()
    b = write_mp4(tmp_path / "b.mp4", frames, fps=20).read_bytes()
    assert a == b and a[4:8] == b"ftyp"


def test_same_bytes_on_any_cpu(tmp_path):
    """The bytes do not depend on the CPU's SIMD: nsim's command gives what ffmpeg with every CPU feature off
    (``-cpuflags 0``, its plain C code) gives. Without ``SWS_FLAGS`` an AVX-512 machine wrote other bytes (swscale's
    SIMD RGB to YUV conversion rounds otherwise), so the tiny demo's artifact ids differed between machines."""
    import subprocess

    from nsim.io.video import encode_command

    rng = np.random.default_rng(0)
    frames = (rng.random((6, 120, 160, 3)) * 255).astype(np.uint8)
    frames[:, :60] = np.linspace(0, 255, 160).astype(np.uint8)[None, None, :, None]
    raw = frames.tobytes()
    out = []
    for extra in ([], ["-cpuflags", "0"]):
        cmd = encode_command(160, 120, 10.0, tmp_path / f"v{len(extra)}.mp4")
        subprocess.run([cmd[0], *extra, *cmd[1:]], input=raw, check=True, capture_output=True)
        out.append((tmp_path / f"v{len(extra)}.mp4").read_bytes())
    assert out[0] == out[1] and len(out[0]) > 1000


def test_streamed_writer(tmp_path):
    with open_mp4(tmp_path / "s.mp4", fps=2.5) as video:
        for f in _frames(4, 16, 24):
            video.write(f)
        assert video.frames == 4 and not (tmp_path / "s.mp4").exists()  # appears when the block ends
    info = probe_video(tmp_path / "s.mp4")
    assert (info.frames, info.width, info.height) == (4, 24, 16) and info.fps == pytest.approx(2.5)


def test_bad_frames_leave_no_file(tmp_path):
    frames = _frames(2, 16, 16)
    with pytest.raises(ValueError, match="uint8"):
        write_mp4(tmp_path / "f.mp4", [frames[0].astype(np.float32)], fps=10)
    with pytest.raises(ValueError, match="the first was 16x16"):
        write_mp4(tmp_path / "s.mp4", [frames[0], np.zeros((16, 18, 3), np.uint8)], fps=10)
    with pytest.raises(ValueError, match="no frames"):
        write_mp4(tmp_path / "e.mp4", [], fps=10)
    with pytest.raises(ValueError, match="fps"):
        write_mp4(tmp_path / "r.mp4", frames, fps=0)
    with pytest.raises(KeyError), open_mp4(tmp_path / "k.mp4", fps=10) as video:
        video.write(frames[0])
        raise KeyError("the caller failed midway")
    assert list(tmp_path.iterdir()) == []


def test_probe_reads_opencv_mp4v_as_mpeg4(tmp_path):
    """The old previews' codec (OpenCV's mp4v: MPEG-4 Part 2, which browsers do not play) is told apart."""
    path = tmp_path / "old.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (32, 32))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write mp4v")
    for f in _frames(3, 32, 32):
        writer.write(f)
    writer.release()
    assert probe_video(path).codec == "mpeg4"


def test_probe_bad_input_is_one_line(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        probe_video(tmp_path / "missing.mp4")
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00\x01 not a video" * 50)
    with pytest.raises(InputError, match="junk.mp4: not a readable video") as err:
        probe_video(junk)
    assert "\n" not in str(err.value)
