"""MP4 videos that browsers play: H.264 (High profile, yuv420p) in MP4, written by the ffmpeg binary
that the ``imageio-ffmpeg`` wheel ships (with libx264). Every MP4 nsim writes goes through
:func:`open_mp4` (OpenCV's ``mp4v`` fourcc is MPEG-4 Part 2, which browsers do not play).

Conventions:

- frames are ``(H, W, 3)`` uint8 **RGB** (nsim's order; OpenCV drawings in BGR flip with ``[..., ::-1]``),
  every frame the size of the first;
- H.264 in 4:2:0 needs an even width and height: an odd size gets one more column / row, a copy of the
  last one (the pixels inside the original size keep their place, so intrinsics stay valid);
- colour: RGB to YUV with the BT.601 matrix in limited range, tagged as such in the stream
  (``smpte170m``, ``tv``), so players and OpenCV's reader convert back with the same matrix;
- quality: x264 ``preset`` :data:`PRESET`, constant quality ``crf`` :data:`CRF` (visually lossless
  for these synthetic frames), ``+faststart`` (the index first, so a browser starts playing at once);
- the file's bytes depend only on the frames, the frame rate and the ffmpeg build, not on the CPU: one
  encoder thread (x264's output depends on its thread count), the RGB to YUV conversion in swscale's
  bit-exact C code (:data:`SWS_FLAGS`: its SIMD code for the CPU at hand rounds otherwise, so an AVX-512
  machine wrote other bytes than an AVX2 one), bit-exact muxing (no creation time, no library version tag);
- written atomically (``nsim.io.atomic_path``): a failed or interrupted write leaves no file.

:func:`probe_video` reads a video's codec, size, frame rate and frame count back (any format ffmpeg reads).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import subprocess
import tempfile
from collections.abc import Iterable, Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.io import atomic_path

CODEC = "h264"
"""The codec of every MP4 nsim writes, as ffmpeg names it."""
PRESET = "medium"
CRF = 18
SWS_FLAGS = "+accurate_rnd+bitexact+full_chroma_int"
"""swscale's flags for the RGB to YUV conversion: the same bytes on every CPU (``-cpuflags 0``'s, tested)."""


def ffmpeg_exe() -> str:
    """Path of the ffmpeg binary (the one in the imageio-ffmpeg wheel; ``IMAGEIO_FFMPEG_EXE`` overrides it)."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise RuntimeError("writing and reading MP4 needs the imageio-ffmpeg package "
                           "(a dependency of nsim: pip install imageio-ffmpeg)") from None
    return imageio_ffmpeg.get_ffmpeg_exe()


def _even(rgb: np.ndarray) -> np.ndarray:
    """``rgb`` grown by one copied last column / row where its width / height is odd."""
    h, w = rgb.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return rgb
    return np.pad(rgb, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def encode_command(width: int, height: int, fps: float, out: str | os.PathLike) -> list[str]:
    """The ffmpeg command that reads raw RGB frames of ``width`` x ``height`` (both even) on stdin
    and writes them to ``out`` as H.264 MP4 at ``fps`` frames per second."""
    rate = Fraction(fps).limit_denominator(1001000)
    return [
        ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y",
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}", "-framerate", f"{rate.numerator}/{rate.denominator}",
        "-i", "pipe:0",
        "-an", "-map_metadata", "-1",
        "-sws_flags", SWS_FLAGS,
        "-c:v", "libx264", "-preset", PRESET, "-crf", str(CRF), "-threads", "1",
        "-pix_fmt", "yuv420p", "-colorspace", "smpte170m", "-color_range", "tv",
        "-flags:v", "+bitexact", "-fflags", "+bitexact", "-movflags", "+faststart",
        "-f", "mp4", str(out),
    ]


class Mp4Writer:
    """Frames in, one H.264 MP4 out; made by :func:`open_mp4`. ``write(rgb)`` appends a frame."""

    def __init__(self, path: Path, tmp: Path, fps: float):
        self.path, self._tmp, self.fps = path, tmp, fps
        self.frames = 0
        self.size_hw: tuple[int, int] | None = None
        self._proc: subprocess.Popen | None = None
        self._log = tempfile.TemporaryFile()

    def write(self, rgb: np.ndarray) -> None:
        """Append one ``(H, W, 3)`` uint8 RGB frame (the size of the first frame)."""
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3 or 0 in rgb.shape:
            raise ValueError(f"{self.path.name}: expected an (H, W, 3) uint8 RGB frame, got {rgb.dtype} {rgb.shape}")
        if self.size_hw is None:
            self.size_hw = rgb.shape[:2]
            h, w = (n + n % 2 for n in self.size_hw)
            self._proc = subprocess.Popen(encode_command(w, h, self.fps, self._tmp), stdin=subprocess.PIPE,
                                          stdout=subprocess.DEVNULL, stderr=self._log)
        elif rgb.shape[:2] != self.size_hw:
            raise ValueError(f"{self.path.name}: frame {self.frames} is {rgb.shape[1]}x{rgb.shape[0]}, "
                             f"the first was {self.size_hw[1]}x{self.size_hw[0]}")
        try:
            self._proc.stdin.write(np.ascontiguousarray(_even(rgb)).tobytes())
        except BrokenPipeError:
            self._fail("ffmpeg stopped reading frames")
        self.frames += 1

    def _fail(self, what: str) -> None:
        proc, self._proc = self._proc, None
        if proc is not None:
            with contextlib.suppress(OSError):
                proc.stdin.close()
            proc.kill()
            proc.wait()
        self._log.seek(0)
        said = self._log.read().decode(errors="replace").strip().splitlines()
        raise RuntimeError(f"{self.path}: {what}" + (f": {said[-1]}" if said else ""))

    def _finish(self) -> None:
        if self._proc is None:
            raise ValueError(f"{self.path}: no frames to write")
        with contextlib.suppress(BrokenPipeError):
            self._proc.stdin.close()
        if self._proc.wait() != 0:
            self._fail(f"ffmpeg failed (exit {self._proc.returncode})")
        self._proc = None

    def _abort(self) -> None:
        if self._proc is not None:
            with contextlib.suppress(OSError):
                self._proc.stdin.close()
            self._proc.kill()
            self._proc.wait()
            self._proc = None


@contextlib.contextmanager
def open_mp4(path: str | os.PathLike, fps: float) -> Iterator[Mp4Writer]:
    """Write an H.264 MP4 at ``fps`` frames per second: ``with open_mp4(p, 10) as video: video.write(rgb)``.

    The file appears at ``path`` when the block ends without an exception (at least one frame
    written); otherwise nothing is left behind. Raises RuntimeError if ffmpeg fails.
    """
    path = Path(path)
    if not (fps > 0 and np.isfinite(fps)):
        raise ValueError(f"{path}: fps must be a positive number, got {fps}")
    with atomic_path(path) as tmp:
        writer = Mp4Writer(path, tmp, float(fps))
        try:
            yield writer
            writer._finish()
        finally:
            writer._abort()
            writer._log.close()


def write_mp4(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float) -> Path:
    """Write ``frames`` (each ``(H, W, 3)`` uint8 RGB) as an H.264 MP4 (:func:`open_mp4`); returns ``path``."""
    with open_mp4(path, fps) as video:
        for rgb in frames:
            video.write(rgb)
    return Path(path)


@dataclasses.dataclass(frozen=True)
class VideoInfo:
    """What ffmpeg reads of a video's first video stream."""

    codec: str
    """ffmpeg's codec name: ``h264``, ``mpeg4`` (OpenCV's mp4v), ``hevc``, ..."""
    width: int
    height: int
    fps: float
    frames: int
    """decoded frames (counted by decoding the whole stream)"""


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Codec, size, frame rate and frame count of a video file; InputError if it is missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    ffmpeg_exe()
    import imageio_ffmpeg

    try:
        reader = imageio_ffmpeg.read_frames(str(path))
        meta = next(reader)
        reader.close()
        frames, _ = imageio_ffmpeg.count_frames_and_secs(str(path))
    except (OSError, RuntimeError, ValueError, IndexError, StopIteration) as err:  # ffmpeg failed, or no video stream
        msg = str(err).strip().splitlines()
        raise InputError(f"{path}: not a readable video" + (f" ({msg[-1]})" if msg else "")) from None
    w, h = meta["size"]
    return VideoInfo(codec=str(meta["codec"]).split()[0], width=int(w), height=int(h), fps=float(meta["fps"]),
                     frames=int(frames))
