"""The actor capture: a walk in free space, a camera that keeps the person in view, files that load as human data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.human.data import HumanData
from nsim.io.exr import read_depth_exr
from nsim.io.images import read_image
from nsim.synth.actor_capture import (
    CAMERA_CLEARANCE_M,
    ActorCaptureConfig,
    actor_motion,
    follow_camera,
    plan_walk_path,
    render_actor_capture,
)
from nsim.synth.room import ROOM_PRESETS, RoomSpec, clearance_xy_m, make_room

TINY = ActorCaptureConfig(width=64, height=48, n_frames=12, fps=10.0, supersample=2, video=True)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("actor") / "capture"
    return render_actor_capture(out, TINY, seed=4)


@pytest.mark.parametrize("name", ROOM_PRESETS)
def test_walk_stays_in_free_space(name):
    spec = make_room(name, seed=0)
    path = plan_walk_path(spec, 12.0, seed=1)
    length = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert length.sum() >= 12.0
    assert length.max() < 0.06  # dense points, no jumps
    assert clearance_xy_m(spec, path).min() >= 0.65 - 0.2
    np.testing.assert_array_equal(path, plan_walk_path(spec, 12.0, seed=1))
    assert not np.array_equal(path[:50], plan_walk_path(spec, 12.0, seed=2)[:50])


def test_camera_follows_at_distance_and_keeps_clear():
    spec: RoomSpec = make_room("kitchen", seed=0)
    cfg = ActorCaptureConfig(n_frames=80)
    clip, _ = actor_motion(spec, cfg, seed=2)
    assert clip.num_frames == 80
    T = clip.joint_transforms()
    pelvis = T[:, 0, :3, 3]
    heading = np.unwrap(np.arctan2(T[:, 0, 1, 0], T[:, 0, 0, 0]))
    c2w = follow_camera(spec, pelvis, heading, cfg.fps, seed=2, cfg=cfg)
    eye = c2w[:, :3, 3]
    dist = np.linalg.norm(eye[:, :2] - pelvis[:, :2], axis=1)
    lo, hi = cfg.follow_distance_m
    assert dist.min() > lo - 0.15 and dist.max() < hi + 0.15
    assert clearance_xy_m(spec, eye[:, :2]).min() >= CAMERA_CLEARANCE_M - 0.05
    # the pelvis stays near the image centre: within 12 degrees of the optical axis
    to_pelvis = pelvis - eye
    cos = np.einsum("ni,ni->n", to_pelvis / np.linalg.norm(to_pelvis, axis=1, keepdims=True), c2w[:, :3, 2])
    assert np.degrees(np.arccos(cos)).max() < 12.0
    # handheld, not teleporting: under 2.5 m/s
    assert (np.linalg.norm(np.diff(eye, axis=0), axis=1) * cfg.fps).max() < 2.5


@pytest.mark.parametrize("view_deg", [0.0, 90.0, 180.0])
def test_camera_keeps_the_side_it_is_given(view_deg):
    """view_deg with no orbit: the camera stays in front of (0), at the left of (90) or behind (180) the walker."""
    spec = make_room("robot-lab", seed=0)
    cfg = ActorCaptureConfig(n_frames=60, orbit_deg_s=0.0, view_deg=view_deg)
    clip, _ = actor_motion(spec, cfg, seed=3)
    T = clip.joint_transforms()
    pelvis = T[:, 0, :3, 3]
    heading = np.unwrap(np.arctan2(T[:, 0, 1, 0], T[:, 0, 0, 0]))
    eye = follow_camera(spec, pelvis, heading, cfg.fps, seed=3, cfg=cfg)[:, :3, 3]
    rel = np.arctan2(eye[:, 1] - pelvis[:, 1], eye[:, 0] - pelvis[:, 0]) - heading
    off = np.degrees(np.abs(np.angle(np.exp(1j * (rel - np.radians(view_deg))))))
    assert np.median(off) < 30.0, off


def test_files_and_masks(capture):
    out = capture.out_dir
    n = TINY.n_frames
    for name in ("transforms.json", "poses.json", "room.json", "occupancy.json", "gt_trajectory.tum",
                 "video.mp4", "preview.png"):
        assert (out / name).is_file(), name
    for sub, ext in (("images", "png"), ("depth", "exr"), ("masks", "png"), ("background", "png")):
        assert len(list((out / sub).glob(f"*.{ext}"))) == n
    assert (capture.mask_fraction > 0.005).mean() >= 0.8  # the person is in (nearly) every frame
    room = json.loads((out / "room.json").read_text())
    assert room["preset"] == TINY.room and room["spec"]["name"] == TINY.room
    mask = read_image(out / "masks" / "frame_00003.png")[..., 0]
    assert set(np.unique(mask)) <= {0, 255} and mask.shape == (TINY.height, TINY.width)
    depth = read_depth_exr(out / "depth" / "frame_00003.exr")
    c2w = capture.cam_to_world[3]
    pelvis = capture.joint_transforms[3, 0, :3, 3]
    person_depth = np.median(depth[mask > 0])
    assert person_depth == pytest.approx(float((pelvis - c2w[:3, 3]) @ c2w[:3, 2]), abs=0.35)
    assert np.median(depth[mask == 0]) > person_depth  # the room behind the person


def test_poses_round_trip_through_human_data(capture):
    data = HumanData.load(capture.out_dir)
    assert data.num_frames == TINY.n_frames
    # poses.json holds the poses to 1e-9 (nsim.io.canonical); composed down the skeleton, a few 1e-9
    np.testing.assert_allclose(data.joint_transforms(), capture.joint_transforms, atol=2e-8)
    np.testing.assert_allclose(data.cam_to_world(), capture.cam_to_world, atol=1e-9)
    np.testing.assert_allclose(data.poses.timestamps_s, np.arange(TINY.n_frames) / TINY.fps)
    assert data.poses.height_m == TINY.actor_height_m and data.poses.meta["actor_seed"] == 4
    m = data.mask(5)
    assert m.dtype == bool and m.mean() == pytest.approx(capture.mask_fraction[5])
    assert data.image(5).shape == (TINY.height, TINY.width, 3)
    images, masks, backgrounds = data.read_all()
    assert images.shape == backgrounds.shape == (TINY.n_frames, TINY.height, TINY.width, 3) and masks.any()
    assert data.camera().width == TINY.width
    # the background is the room alone: the same pixels away from the person (anti-aliased edges and
    # sub-pixel hands aside)
    far = ~np.stack([np.pad(m, 1)[:-2, 1:-1] | np.pad(m, 1)[2:, 1:-1] | np.pad(m, 1)[1:-1, :-2]
                     | np.pad(m, 1)[1:-1, 2:] | m for m in masks])
    assert (images[far] == backgrounds[far]).all(axis=-1).mean() > 0.995
    assert np.abs(images[masks].astype(int) - backgrounds[masks]).mean() > 10  # the person is not in it


def test_same_arguments_same_bytes(capture, tmp_path):
    again = render_actor_capture(tmp_path / "again", TINY, seed=4)
    files = sorted(p.relative_to(capture.out_dir) for p in capture.out_dir.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again.out_dir) for p in again.out_dir.rglob("*") if p.is_file())
    for f in files:
        assert (capture.out_dir / f).read_bytes() == (again.out_dir / f).read_bytes(), f
    with pytest.raises(FileExistsError):
        render_actor_capture(again.out_dir, TINY, seed=4)


def test_config_is_checked():
    with pytest.raises(ValueError, match="follow_distance_m"):
        ActorCaptureConfig(follow_distance_m=(3.0, 2.0))
    with pytest.raises(ValueError, match="camera"):
        ActorCaptureConfig(camera="lidar")
