"""Ground-truth rendering: shapes, determinism, depth definitions, multi-view consistency."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import look_at
from nsim.synth.oracle import RoomOracle
from nsim.synth.path import handheld_path
from nsim.synth.room import ROOM_PRESETS, make_room
from tests.synth.multiview import reproject
from tests.synth.simple_room import simple_spec

W, H = 96, 72
PINHOLE = Camera.pinhole_from_fov(W, H, 70.0)
FISHEYE = Camera.fisheye_spot_like(W, H)
N_PATH = 48


@pytest.mark.parametrize("name", ROOM_PRESETS)
def test_every_preset_renders(oracles, name):
    oracle = oracles[name]
    pose = handheld_path(oracle.spec, N_PATH, seed=0)[5]
    rgb, depth_z, depth_range = oracle.render_gt(PINHOLE, pose)
    assert rgb.shape == (H, W, 3) and depth_z.shape == depth_range.shape == (H, W)
    assert rgb.dtype == depth_z.dtype == depth_range.dtype == np.float32
    assert 0.0 <= rgb.min() and rgb.max() <= 1.0 and rgb.std() > 0.05
    assert np.all(np.isfinite(depth_z)) and depth_z.min() > 0.5  # a closed room: every pixel hits something
    assert depth_range.max() < np.linalg.norm(oracle.spec.size_xyz_m)
    dirs = PINHOLE.unproject(np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1).astype(float))
    np.testing.assert_allclose(depth_z, depth_range * dirs[..., 2], rtol=1e-6)


def test_bit_identical_across_oracles(oracles):
    spec = make_room("kitchen", seed=0)
    fresh = RoomOracle(spec)
    pose = handheld_path(spec, N_PATH, seed=3)[17]
    a = fresh.render_gt(PINHOLE, pose, supersample=2)
    b = oracles["kitchen"].render_gt(PINHOLE, pose, supersample=2)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a.rgb, RoomOracle(make_room("kitchen", seed=1)).render_gt(PINHOLE, pose).rgb)


def test_render_matches_cast_rays(oracles):
    oracle = oracles["seminar-room"]
    pose = handheld_path(oracle.spec, N_PATH, seed=0)[9]
    view = oracle.render_gt(PINHOLE, pose)
    origins, dirs = PINHOLE.pixel_rays(pose)
    hits = oracle.cast_rays(origins.reshape(-1, 3), dirs.reshape(-1, 3))
    np.testing.assert_allclose(view.depth_range.ravel(), hits.t, rtol=1e-6)
    # colour: the same surface albedo, prefiltered by the pixel footprint in the render
    assert np.median(np.abs(view.rgb.reshape(-1, 3) - hits.rgb)) < 0.08


def test_supersampling_keeps_depth_and_smooths_colour(oracles):
    oracle = oracles["robot-lab"]
    pose = handheld_path(oracle.spec, N_PATH, seed=0)[2]
    one = oracle.render_gt(PINHOLE, pose, supersample=1)
    three = oracle.render_gt(PINHOLE, pose, supersample=3)
    np.testing.assert_array_equal(one.depth_z, three.depth_z)
    np.testing.assert_array_equal(one.depth_range, three.depth_range)
    diff = np.abs(one.rgb - three.rgb)
    assert 0.0 < diff.mean() < 0.05
    with pytest.raises(ValueError, match="supersample"):
        oracle.render_gt(PINHOLE, pose, supersample=0)


def test_hand_checked_depth():
    """Camera at height 1 in the simple room looking straight down: depth 1 everywhere but on the cube."""
    oracle = RoomOracle(simple_spec())
    pose = look_at([4.5, 2.5, 1.0], [4.5, 2.5, 0.0], up=(1.0, 0.0, 0.0))
    view = oracle.render_gt(PINHOLE, pose)
    np.testing.assert_allclose(view.depth_z, 1.0, rtol=1e-6)
    pose = look_at([1.5, 1.5, 2.0], [1.5, 1.5, 0.0], up=(1.0, 0.0, 0.0))  # over the cube (top at z = 1)
    view = oracle.render_gt(Camera.pinhole_from_fov(16, 12, 20.0), pose)
    np.testing.assert_allclose(view.depth_z, 1.0, rtol=1e-6)


def test_fisheye_depth_undefined_beyond_90_degrees(oracles):
    oracle = oracles["living-room"]
    pose = handheld_path(oracle.spec, N_PATH, seed=0)[30]
    view = oracle.render_gt(FISHEYE, pose)
    dirs = FISHEYE.unproject(np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1).astype(float))
    behind = dirs[..., 2] <= 0
    assert behind.any() and (~behind).any()
    assert np.all(np.isnan(view.depth_z[behind])) and np.all(np.isfinite(view.depth_z[~behind]))
    assert np.all(np.isfinite(view.depth_range))  # the range is defined for every ray


def test_rejects_bad_pose(oracles):
    with pytest.raises(ValueError, match="rotation"):
        oracles["kitchen"].render_gt(PINHOLE, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        oracles["kitchen"].render_gt(PINHOLE, np.eye(3))


@pytest.mark.parametrize("camera", [PINHOLE, FISHEYE], ids=["pinhole", "fisheye"])
@pytest.mark.parametrize("name", ROOM_PRESETS)
def test_multi_view_consistency(oracles, name, camera):
    """Reproject frame i into its path neighbours with GT depth: colours agree; a 2 degree pose error shows."""
    oracle = oracles[name]
    poses = handheld_path(oracle.spec, N_PATH, seed=0)
    for i, j in ((4, 5), (33, 34), (14, 16)):  # eye-height loop, low loop, a wider baseline
        vi = oracle.render_gt(camera, poses[i])
        vj = oracle.render_gt(camera, poses[j])
        good = reproject(camera, vi, poses[i], vj, poses[j])
        assert good.fraction_checked > 0.25, (i, j, good)
        assert good.median_abs_rgb < 0.02, (i, j, good)
        assert good.median_rel_range < 1e-3, (i, j, good)
        wrong = poses[j].copy()
        wrong[:3, :3] = wrong[:3, :3] @ Rotation.from_rotvec([0.0, np.radians(2.0), 0.0]).as_matrix()
        bad = reproject(camera, vi, poses[i], vj, wrong, visible_rel_tol=1.0)
        assert bad.median_abs_rgb > 1.5 * good.median_abs_rgb, (i, j, good, bad)


@pytest.mark.parametrize("name", ROOM_PRESETS)
def test_sift_matches_agree_with_ground_truth(oracles, name):
    """What SfM will see: many SIFT matches between path neighbours, and the GT geometry confirms them."""
    cv2 = pytest.importorskip("cv2")
    oracle = oracles[name]
    camera = Camera.pinhole_from_fov(320, 240, 75.0)
    poses = handheld_path(oracle.spec, 100, seed=0)
    i, j = 10, 11
    views = [oracle.render_gt(camera, poses[k]) for k in (i, j)]
    sift = cv2.SIFT_create()
    (kp_i, desc_i), (kp_j, desc_j) = (
        sift.detectAndCompute(cv2.cvtColor(np.rint(v.rgb * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY), None)
        for v in views
    )
    pairs = [m for m, second in cv2.BFMatcher().knnMatch(desc_i, desc_j, k=2) if m.distance < 0.8 * second.distance]
    assert len(pairs) >= 150
    uv_i = np.array([kp_i[m.queryIdx].pt for m in pairs])
    uv_j = np.array([kp_j[m.trainIdx].pt for m in pairs])
    rows, cols = np.rint(uv_i[:, 1]).astype(int), np.rint(uv_i[:, 0]).astype(int)
    p_world = (camera.unproject(uv_i) * views[0].depth_range[rows, cols, None]) @ poses[i][:3, :3].T + poses[i][:3, 3]
    uv_pred, _ = camera.project((p_world - poses[j][:3, 3]) @ poses[j][:3, :3])
    assert np.mean(np.linalg.norm(uv_pred - uv_j, axis=1) < 3.0) > 0.75
