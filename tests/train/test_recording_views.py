"""A robot's recorded frames as training views, the core: fitting a camera to the capture's size, the share
and the hold-out rule, SceneData with recorded frames (no stage, no recording artifact: see
``tests/stages/test_train_scene_recording.py`` for the end to end run)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nsim.geometry.cameras import Camera
from nsim.io.images import write_image
from nsim.train.scene_data import (
    RecordedFrame,
    RecordedFrames,
    RecordingConfig,
    SceneData,
    fit_camera,
    fit_geometry,
    fit_image,
    split_recorded_frames,
)

FISHEYE = Camera.fisheye_spot_like(160, 120)
PINHOLE = Camera("OPENCV", 90, 40, 70.0, 72.0, 44.2, 19.1, (0.05, -0.01, 0.001, 0.0005, 0.0))


@pytest.mark.parametrize("camera", [FISHEYE, PINHOLE], ids=["fisheye", "opencv"])
@pytest.mark.parametrize("size", [(64, 48), (64, 36), (200, 150), (160, 120)], ids=["shrink", "crop", "enlarge", "same"])
def test_fit_camera_keeps_every_pixel_ray(camera, size):
    """A fitted pixel looks along the ray of the recorded image point it was resampled from."""
    fitted = fit_camera(camera, *size)
    assert (fitted.width, fitted.height) == size and fitted.model == camera.model and fitted.dist == camera.dist
    scaled, x0, y0 = fit_geometry(camera, *size)
    sx, sy = scaled.width / camera.width, scaled.height / camera.height
    uv = np.array([[0.0, 0.0], [size[0] - 1.0, size[1] - 1.0], [size[0] / 2 - 0.3, size[1] / 3 + 0.7]])
    # fitted pixel (u, v) = scaled pixel (u + x0, v + y0) = recorded point ((u + x0 + 0.5) / sx - 0.5, ...)
    recorded = np.column_stack([(uv[:, 0] + x0 + 0.5) / sx - 0.5, (uv[:, 1] + y0 + 0.5) / sy - 0.5])
    np.testing.assert_allclose(fitted.unproject(uv), camera.unproject(recorded), atol=1e-12)
    assert abs(sx - sy) < 0.02  # uniform, up to whole pixels


def test_fit_image_matches_its_camera():
    """The fitted image of a smooth pattern holds, at each pixel, the pattern at the recorded point of that pixel."""
    camera = Camera("PINHOLE", 160, 120, 100.0, 100.0, 79.5, 59.5)
    v, u = np.mgrid[0:120, 0:160].astype(np.float64)
    ramp = np.stack([u, v, u * 0 + 60], -1).astype(np.uint8)  # value = pixel coordinate
    for size in ((64, 36), (320, 240)):
        fitted = fit_camera(camera, *size)
        out = fit_image(ramp, camera, fitted)
        assert out.shape == (size[1], size[0], 3)
        scaled, x0, y0 = fit_geometry(camera, *size)
        s = scaled.width / camera.width
        centre = (size[1] // 2, size[0] // 2)
        want_u = (centre[1] + x0 + 0.5) / s - 0.5
        want_v = (centre[0] + y0 + 0.5) / s - 0.5
        assert abs(float(out[centre][0]) - want_u) <= 1.0 and abs(float(out[centre][1]) - want_v) <= 1.0


def _frames(per_camera: dict[str, int], outside: dict[str, int] | None = None) -> RecordedFrames:
    frames = []
    for name, n in per_camera.items():
        for j in range(n):
            frames.append(RecordedFrame(name, j, 10 + j, 1_000 + j, FISHEYE, np.eye(4), Path(f"{name}/{j}.png"),
                                        f"recording:camera/{name}/{10 + j:06d}.png"))
    outside = outside or {}
    return RecordedFrames(tuple(frames), {c: n + outside.get(c, 0) for c, n in per_camera.items()},
                          {c: outside.get(c, 0) for c in per_camera})


def test_share_selects_the_documented_number_of_frames():
    rec = _frames({"back": 40, "frontleft": 40, "left": 20})
    for share, capture_train in ((0.25, 21), (0.5, 30), (0.1, 90), (0.75, 20)):
        split = split_recorded_frames(rec, capture_train, RecordingConfig(share=share))
        n = round(share / (1 - share) * capture_train)
        assert split.wanted == n and len(split.train) == min(n, 100 - len(split.held_out))
        assert len(split.train) / (capture_train + len(split.train)) == pytest.approx(share, abs=0.5 / capture_train)
    # 0.75 of 20 asks for 60, more than the 100 - 13 held out? no: 60 of 87 candidates; 0.9 of 90 asks for 810: all
    split = split_recorded_frames(rec, 90, RecordingConfig(share=0.9))
    assert split.wanted == 810 and len(split.train) == 100 - len(split.held_out)


def test_held_out_frames_are_fixed_and_never_train():
    rec = _frames({"back": 17, "frontleft": 9})
    helds = set()
    for share in (0.05, 0.25, 0.5, 0.95):
        split = split_recorded_frames(rec, 20, RecordingConfig(share=share, holdout_every=4))
        assert not set(split.train) & set(split.held_out)
        helds.add(split.held_out)
    assert len(helds) == 1  # the same frames whatever the share
    (held,) = helds
    assert [(rec.frames[k].camera_name, rec.frames[k].position) for k in held] == \
        [("back", j) for j in (0, 4, 8, 12, 16)] + [("frontleft", j) for j in (0, 4, 8)]


def test_frames_are_shared_by_camera_and_evenly_spaced():
    rec = _frames({"a": 30, "b": 10})
    split = split_recorded_frames(rec, 30, RecordingConfig(share=0.25, holdout_every=1000))
    assert split.wanted == 10
    picked = {c: [rec.frames[k].position for k in split.train if rec.frames[k].camera_name == c] for c in ("a", "b")}
    # candidates: a 1..29 (29), b 1..9 (9): quotas 7.63 and 2.37 -> 8 and 2
    assert len(picked["a"]) == 8 and len(picked["b"]) == 2
    gaps = np.diff(picked["a"])
    assert gaps.max() - gaps.min() <= 1  # evenly spaced
    assert picked["b"] == [3, 7]  # centred: candidates 1..9, the 0.25 and 0.75 points
    assert split == split_recorded_frames(rec, 30, RecordingConfig(share=0.25, holdout_every=1000))


def _scene_data(root: Path, size=(64, 36), n=6) -> SceneData:
    cam = Camera.pinhole_from_fov(*size, 70.0)
    rng = np.random.default_rng(0)
    images = rng.integers(0, 255, (n, size[1], size[0], 3), dtype=np.uint8)
    paths = []
    for i in range(n):
        paths.append(write_image(root / f"c{i}.png", images[i]))
    c2w = np.tile(np.eye(4), (n, 1, 1))
    c2w[:, 0, 3] = np.arange(n)
    return SceneData(root, [f"c{i}.png" for i in range(n)], images, c2w, [cam], np.zeros(n, int), [None] * n,
                     digest="capture", full_cameras=[cam], image_paths=paths)


def test_scene_data_with_recorded_frames(tmp_path):
    data = _scene_data(tmp_path)
    rng = np.random.default_rng(1)
    wide = Camera("OPENCV_FISHEYE", 160, 120, 40.0, 40.0, 79.5, 59.5, (-0.05, 0.0, 0.0, 0.0))  # corners past its reach
    frames = []
    for k, cam in enumerate([FISHEYE, PINHOLE, FISHEYE, wide]):
        img = rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8)
        path = write_image(tmp_path / f"r{k}.png", img)
        pose = np.eye(4)
        pose[:3, 3] = [k, 1.0, 2.0]
        frames.append(RecordedFrame("c", k, k, k, cam, pose, path, f"recording:r{k}.png"))
    out = data.with_recorded_frames(frames)
    assert out.n_frames == 10 and out.n_capture == 6 and out.size_hw == (36, 64)
    assert out.full_cameras == [data.cameras[0], FISHEYE, PINHOLE, wide]  # as recorded
    assert out.cameras[1:] == [fit_camera(c, 64, 36) for c in (FISHEYE, PINHOLE, wide)]
    assert out.camera_index.tolist() == [0] * 6 + [1, 2, 1, 3]
    np.testing.assert_array_equal(out.cam_to_world[6:], np.stack([f.cam_to_world for f in frames]))
    np.testing.assert_array_equal(out.images[:6], data.images)
    # the capture's hold-out rule is the capture's; recorded frames always train
    train, held = out.split(4)
    assert held.tolist() == [0, 4] and train.tolist() == [1, 2, 3, 5, 6, 7, 8, 9]
    # the too-wide fisheye's unprojectable corners are masked, every other pixel kept
    assert out.masks is not None and out.masks[:9].all() and 0 < out.masks[9].mean() < 1
    assert out.digest != data.digest
    assert out.with_max_image_side(0) is out  # the trainer's call changes nothing
    small = out.with_max_image_side(32)
    assert small.size_hw == (18, 32) and small.cameras[1] == fit_camera(FISHEYE, 32, 18)
    assert small.masks is not None and not small.masks[9].all() and small.masks[6].all()
    # scoring a recorded frame at its own fitted camera gives its training copy, at another its file again
    np.testing.assert_array_equal(out.eval_image(6, out.cameras[1]), out.images[6])
    assert out.eval_image(6, FISHEYE).shape == (120, 160, 3)
    assert math.isclose(out.eval_camera(6, 0).fx, FISHEYE.fx)
