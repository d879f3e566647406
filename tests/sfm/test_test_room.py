"""SfM on the real test room (nsim.synth), small: the reconstruct stage's acceptance in miniature.

The full-size check (320x240, 150 frames, pinhole and fisheye) takes minutes and lives in
bench/; here the room is rendered at 160x120 with 100 frames of the capture's two-loop path.
"""

from __future__ import annotations

import numpy as np
import pytest

from nsim.geometry.cameras import Camera
from nsim.io.images import to_uint8, write_image
from nsim.sfm.align import fit_sim3, gravity_align, pose_errors
from nsim.sfm.colmap import run_sfm
from nsim.sfm.options import SfmOptions
from nsim.synth import oracle as synth_oracle
from nsim.synth import path as synth_path
from nsim.synth import room as synth_room

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("kind", ["pinhole", "fisheye"])
def test_test_room_small(tmp_path, kind):
    spec = synth_room.make_room("robot-lab", 0)
    n, w, h = 100, 160, 120
    camera = Camera.pinhole_from_fov(w, h, 75.0) if kind == "pinhole" else Camera.fisheye_spot_like(w, h)
    poses = synth_path.handheld_path(spec, n, seed=0)
    oracle = synth_oracle.RoomOracle(spec)
    names = []
    (tmp_path / "images").mkdir()
    for i, c2w in enumerate(poses):
        names.append(f"frame_{i:05d}.png")
        write_image(tmp_path / "images" / names[-1], to_uint8(oracle.render_gt(camera, c2w, supersample=2).rgb))
    model = "SIMPLE_RADIAL" if kind == "pinhole" else "OPENCV_FISHEYE"
    result = run_sfm(tmp_path / "images", tmp_path / "work", SfmOptions(camera_model=model))

    reg = result.registered_names
    assert len(reg) >= 0.95 * n
    gt = poses[[names.index(r) for r in reg]]
    rot, pos = pose_errors(result.poses_se3(reg), gt)
    assert np.median(rot) < 0.5
    assert np.median(pos) < 0.01 * synth_room.room_diagonal_m(spec)
    noisy = gt[:, :3, 3] + np.random.default_rng(0).normal(0, 0.01, (len(gt), 3))
    assert fit_sim3(result.poses_se3(reg)[:, :3, 3], noisy).s == pytest.approx(
        fit_sim3(result.poses_se3(reg)[:, :3, 3], gt[:, :3, 3]).s, rel=0.02)
    up = gravity_align(result.points_xyz, result.poses_se3(reg))
    R_gt_from_est = fit_sim3(result.poses_se3(reg)[:, :3, 3], gt[:, :3, 3]).R
    assert up.floor_found and (R_gt_from_est @ up.up_old)[2] > np.cos(np.radians(1.0))
