"""pycolmap SfM on the box room: conversions, accuracy, scale, gravity, determinism, bad input."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pycolmap
import pytest

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import look_at
from nsim.io.images import write_image
from nsim.sfm.align import (
    apply_sim3_to_points,
    fit_sim3,
    gravity_align,
    pose_errors,
    scale_from_camera_height,
)
from nsim.sfm.colmap import (
    camera_from_colmap,
    camera_to_colmap,
    initial_focal_px,
    run_sfm,
    transform_result,
    write_model,
)
from nsim.sfm.options import SfmOptions
from tests.sfm.scene import room_diagonal_m

CAMERAS = [
    Camera("PINHOLE", 160, 120, 110.0, 112.0, 79.0, 60.5),
    Camera("OPENCV", 160, 120, 110.0, 111.0, 80.2, 59.1, (-0.1, 0.02, 0.001, -0.002, 0.0)),
    Camera("OPENCV", 160, 120, 110.0, 111.0, 80.2, 59.1, (-0.1, 0.02, 0.001, -0.002, 0.004)),
    Camera.fisheye_spot_like(160, 120),
    Camera("FULL_OPENCV", 160, 120, 110.0, 111.0, 80.2, 59.1, (0.31, -0.12, 0.001, -0.002, 0.01, 0.62, -0.05, 0.02)),
]


@pytest.mark.parametrize("camera", CAMERAS, ids=["pinhole", "opencv", "opencv_k3", "fisheye", "full_opencv"])
def test_camera_conversion_matches_pycolmap_projection(camera):
    cam = camera_to_colmap(camera)
    assert cam.has_prior_focal_length
    assert camera_from_colmap(cam) == camera
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(0.8, 2.0, 50)])
    uv, valid = camera.project(points)
    uv_colmap = cam.img_from_cam(points)
    np.testing.assert_allclose(uv_colmap[valid], uv[valid] + 0.5, atol=1e-9)  # COLMAP's pixel centres


def test_simple_radial_becomes_opencv():
    cam = pycolmap.Camera.create_from_model_name(1, "SIMPLE_RADIAL", 100.0, 160, 120)
    cam.params = [100.0, 80.5, 60.0, -0.05]
    ours = camera_from_colmap(cam)
    assert ours.model == "OPENCV" and ours.dist == (-0.05, 0.0, 0.0, 0.0, 0.0)
    assert (ours.cx, ours.cy) == (80.0, 59.5)
    points = np.array([[0.3, -0.2, 1.0], [0.0, 0.1, 2.0]])
    np.testing.assert_allclose(cam.img_from_cam(points), ours.project(points)[0] + 0.5, atol=1e-9)


def test_initial_focal_px():
    assert initial_focal_px("PINHOLE", 320, 240, 90.0) == pytest.approx(160.0)
    assert initial_focal_px("OPENCV_FISHEYE", 320, 240, 180.0) == pytest.approx(320 / np.pi)


def _check_accuracy(result, capture, max_rot_deg: float, max_pos_fraction: float) -> None:
    names = result.registered_names
    assert len(names) >= 0.95 * len(capture.names)
    rot, pos = pose_errors(result.poses_se3(names), capture.gt(names))
    assert np.median(rot) < max_rot_deg
    assert np.median(pos) < max_pos_fraction * room_diagonal_m()


def test_reconstructs_the_box_room(pinhole_sfm, pinhole_capture):
    stats = pinhole_sfm.stats
    assert stats.images_given == len(pinhole_capture.names)
    assert 0.0 < stats.mean_reprojection_error_px < 1.0
    assert stats.mean_track_length > 2.0 and stats.num_points3d == len(pinhole_sfm.points_xyz) > 500
    assert set(stats.phase_wall_s) == {"features", "matching", "far_pair_check", "mapping", "bundle_adjustment",
                                       "total"}
    assert stats.far_pairs_checked > 0 and stats.far_pairs_dropped <= 0.1 * stats.far_pairs_checked
    _check_accuracy(pinhole_sfm, pinhole_capture, 0.5, 0.01)
    cam = pinhole_sfm.cameras[pinhole_sfm.registered_names[0]]
    assert cam.model == "OPENCV" and cam.fx == pytest.approx(pinhole_capture.camera.fx, rel=0.03)
    assert pinhole_sfm.points_rgb.dtype == np.uint8 and pinhole_sfm.points_rgb.shape == pinhole_sfm.points_xyz.shape


def test_metric_scale_from_a_noisy_reference(pinhole_sfm, pinhole_capture):
    names = pinhole_sfm.registered_names
    gt = capture_centres = pinhole_capture.gt(names)[:, :3, 3]
    noisy = capture_centres + np.random.default_rng(0).normal(0, 0.01, gt.shape)  # 1 cm noise
    fit = fit_sim3(pinhole_sfm.poses_se3(names)[:, :3, 3], noisy)
    metric = transform_result(pinhole_sfm, fit.s, fit.R, fit.t)
    est = metric.poses_se3(names)[:, :3, 3]
    i, j = np.triu_indices(len(names), 1)
    ratio = np.linalg.norm(est[i] - est[j], axis=1) / np.linalg.norm(gt[i] - gt[j], axis=1)
    assert np.median(ratio) == pytest.approx(1.0, abs=0.02)
    assert fit.rms_m < 0.03
    # the model moved with the poses, and the input result did not
    image = metric.reconstruction.find_image_with_name(names[0])
    np.testing.assert_allclose(image.projection_center(), est[0], atol=1e-9)
    assert not np.allclose(pinhole_sfm.poses_se3(names)[:, :3, 3], est)


def test_gravity_alignment_recovers_z_up(pinhole_sfm, pinhole_capture):
    names = pinhole_sfm.registered_names
    fit = gravity_align(pinhole_sfm.points_xyz, pinhole_sfm.poses_se3(names))
    assert fit.floor_found
    up = transform_result(pinhole_sfm, 1.0, fit.R, fit.t)
    gt = pinhole_capture.gt(names)
    scale = scale_from_camera_height(up.poses_se3(names), float(np.median(gt[:, 2, 3])))
    metric = transform_result(up, scale, np.eye(3), np.zeros(3))
    est = metric.poses_se3(names)
    # heights above the floor are recovered directly; the rest only up to a rotation about z
    np.testing.assert_allclose(est[:, 2, 3], gt[:, 2, 3], atol=0.03)
    sim = fit_sim3(est[:, :3, 3], gt[:, :3, 3])
    tilt_deg = np.degrees(np.arccos(np.clip(sim.R[2, 2], -1.0, 1.0)))
    assert tilt_deg < 1.0 and sim.s == pytest.approx(1.0, abs=0.03)
    floor = apply_sim3_to_points(scale, fit.R, scale * fit.t, pinhole_sfm.points_xyz)
    assert np.quantile(floor[:, 2], 0.02) > -0.05  # nothing far below the floor


def test_write_model_round_trip(pinhole_sfm, tmp_path):
    out = write_model(pinhole_sfm, tmp_path / "sparse")
    assert {p.name for p in out.iterdir()} >= {"cameras.bin", "images.bin", "points3D.bin"}
    rec = pycolmap.Reconstruction(out)
    assert rec.num_reg_images() == pinhole_sfm.stats.images_registered
    assert rec.num_points3D() == pinhole_sfm.stats.num_points3d


def test_known_intrinsics_stay_fixed(pinhole_capture, tmp_path):
    phases = []
    result = run_sfm(pinhole_capture.image_dir, tmp_path / "work", SfmOptions(matcher="exhaustive"),
                     known_camera=pinhole_capture.camera, progress=lambda p, done, total: phases.append(p))
    assert all(cam == pinhole_capture.camera for cam in result.cameras.values())
    _check_accuracy(result, pinhole_capture, 0.5, 0.01)
    assert [p for i, p in enumerate(phases) if p not in phases[:i]] == [
        "features", "matching", "mapping", "bundle_adjustment"]
    assert result.stats.attempts[0]["hfov_guess_deg"] is None


def test_too_few_images(pinhole_capture, tmp_path):
    with pytest.raises(InputError, match="2 images to reconstruct; need at least 3"):
        run_sfm(pinhole_capture.image_dir, tmp_path / "w", image_names=pinhole_capture.names[:2])


def test_mixed_sizes_with_shared_intrinsics(pinhole_capture, tmp_path):
    d = tmp_path / "images"
    shutil.copytree(pinhole_capture.image_dir, d)
    write_image(d / "frame_00003.png", np.zeros((60, 80, 3), np.uint8))
    with pytest.raises(InputError, match="frame_00003.png: image is 80x60 but frame_00000.png is 160x120"):
        run_sfm(d, tmp_path / "w")


def test_known_camera_of_the_wrong_size(pinhole_capture, tmp_path):
    with pytest.raises(InputError, match="is 160x120 but the known camera is 320x240"):
        run_sfm(pinhole_capture.image_dir, tmp_path / "w", known_camera=pinhole_capture.camera.scaled(2.0))


def test_too_few_registered_is_an_input_error(pinhole_capture, tmp_path):
    """5 overlapping views of the room and 9 unrelated noise images: 5 of 14 < 50% register."""
    d = tmp_path / "images"
    d.mkdir()
    for name in pinhole_capture.names[:5]:
        shutil.copy(pinhole_capture.image_dir / name, d / name)
    rng = np.random.default_rng(0)
    for k in range(9):
        write_image(d / f"noise_{k}.png", rng.integers(0, 256, (120, 160, 3), dtype=np.uint8))
    with pytest.raises(InputError, match=r"only \d of 14 frames registered .*more overlap"):
        run_sfm(d, tmp_path / "w", SfmOptions(matcher="exhaustive", hfov_guesses_deg=(75.0,)))


def test_fisheye_with_unknown_intrinsics(fisheye_capture, tmp_path):
    result = run_sfm(fisheye_capture.image_dir, tmp_path / "work", SfmOptions(camera_model="OPENCV_FISHEYE"))
    _check_accuracy(result, fisheye_capture, 0.5, 0.01)
    cam = result.cameras[result.registered_names[0]]
    assert cam.model == "OPENCV_FISHEYE" and cam.fx == pytest.approx(fisheye_capture.camera.fx, rel=0.03)
    assert result.stats.mean_reprojection_error_px < 1.0  # COLMAP's own figure overflows at 90 deg


_SFM_IN_FRESH_PROCESS = """
import sys
from pathlib import Path
import numpy as np
from nsim.sfm.colmap import run_sfm
image_dir, work, names = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3].split(",")
r = run_sfm(image_dir, work, image_names=names)
np.savez(work / "out.npz", names=np.array(r.registered_names), c2w=np.stack([r.cam_to_world[n] for n in names]),
         xyz=r.points_xyz)
"""


def test_same_input_same_poses(pinhole_capture, tmp_path):
    """Two reruns, each in a fresh process (as ``nsim reconstruct`` is rerun), agree bit for bit (matching on
    one thread: see the Determinism paragraph of ``nsim.sfm.colmap``)."""
    import subprocess
    import sys

    names = pinhole_capture.names[:12]
    outs = []
    for k in range(2):
        work = tmp_path / f"w{k}"
        subprocess.run([sys.executable, "-c", _SFM_IN_FRESH_PROCESS, str(pinhole_capture.image_dir), str(work),
                        ",".join(names)], check=True, capture_output=True)
        outs.append(np.load(work / "out.npz"))
    assert outs[0]["names"].tolist() == outs[1]["names"].tolist() == names
    np.testing.assert_array_equal(outs[0]["c2w"], outs[1]["c2w"])
    np.testing.assert_array_equal(outs[0]["xyz"], outs[1]["xyz"])


def test_a_pose_that_jumps_away_from_its_neighbours_is_rejected(pinhole_sfm):
    from nsim.sfm.colmap import _reject_pose_jumps

    names = pinhole_sfm.registered_names
    rec = pycolmap.Reconstruction(pinhole_sfm.reconstruction)
    assert _reject_pose_jumps(rec, names) == []
    frame = rec.frame(rec.find_image_with_name(names[10]).frame_id)
    old = frame.rig_from_world  # a mirrored registration: half a turn about the camera's y axis
    frame.rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([0.0, np.pi, 0.0])) * old.rotation,
                                            old.translation)
    assert _reject_pose_jumps(rec, names) == [names[10]]
    assert not rec.find_image_with_name(names[10]).has_pose
    assert rec.num_reg_images() == len(names) - 1


def test_a_far_pair_that_disagrees_with_the_near_pairs_is_dropped(pinhole_capture, pinhole_sfm, pinhole_sfm_dir,
                                                                   tmp_path):
    """A false loop closure (as repeated textures make) is removed; the true far pairs stay."""
    from nsim.sfm.colmap import _check_far_pairs

    shutil.copyfile(pinhole_sfm_dir / "database.db", tmp_path / "database.db")
    names = pinhole_capture.names
    db = pycolmap.Database.open(tmp_path / "database.db")
    ids = {im.name: im.image_id for im in db.read_all_images()}
    # forge a far pair with many "inliers": frame 0's keypoints matched to arbitrary ones of a far frame
    near = db.read_two_view_geometry(ids[names[0]], ids[names[1]])
    far_name = next(n for n in names[12:] if not db.exists_two_view_geometry(ids[names[0]], ids[n]))
    fake = pycolmap.TwoViewGeometry()
    fake.config = near.config
    matches = np.asarray(near.inlier_matches).copy()
    matches[:, 1] = (matches[:, 1] * 7 + 3) % db.num_keypoints_for_image(ids[far_name])
    fake.inlier_matches = matches
    db.write_two_view_geometry(ids[names[0]], ids[far_name], fake)
    db.close()

    checked, dropped = _check_far_pairs(tmp_path / "database.db", pinhole_capture.image_dir, tmp_path / "near",
                                        names, SfmOptions(), refine_intrinsics=True)
    # the fixture's database lost its own disagreeing pairs already; the rest agree again
    assert checked == pinhole_sfm.stats.far_pairs_checked - pinhole_sfm.stats.far_pairs_dropped + 1
    assert dropped == 1
    db = pycolmap.Database.open(tmp_path / "database.db")
    assert not db.exists_two_view_geometry(ids[names[0]], ids[far_name])
    db.close()


@pytest.mark.skipif(pycolmap.has_cuda, reason="pycolmap has CUDA here: nothing to fall back from")
def test_cuda_without_pycolmap_cuda_falls_back_to_cpu(pinhole_capture, tmp_path, caplog):
    result = run_sfm(pinhole_capture.image_dir, tmp_path / "w", SfmOptions(device="cuda", matcher="exhaustive"),
                     image_names=pinhole_capture.names[:8])
    assert result.stats.device == "cpu" and "without CUDA" in caplog.text


@pytest.mark.gpu
@pytest.mark.skipif(not pycolmap.has_cuda, reason="pycolmap built without CUDA")
def test_cuda_sift(pinhole_capture, tmp_path):
    result = run_sfm(pinhole_capture.image_dir, tmp_path / "w", SfmOptions(device="cuda"))
    assert result.stats.device == "cuda"
    _check_accuracy(result, pinhole_capture, 0.5, 0.01)


def test_known_poses_triangulate_a_camera_turning_in_place(tmp_path):
    """A camera turning about itself (centres within some 10 cm): hardly a pair for SfM to start from; with the poses
    known (motion capture) the features are triangulated there and the poses come back as given."""
    from tests.sfm.scene import ROOM_XYZ_M, render_sequence

    camera = Camera.pinhole_from_fov(160, 120, 75.0)
    rng = np.random.default_rng(1)
    centre = np.array([ROOM_XYZ_M[0] / 2, ROOM_XYZ_M[1] / 2, 1.4])
    poses = []
    for k in range(10):
        a = math.radians(-40 + 8 * k)  # a 72 deg pan towards +x
        eye = centre + rng.normal(0, 0.05, 3)
        poses.append(look_at(eye, eye + np.array([math.cos(a), math.sin(a), -0.3]), np.array([0.0, 0.0, 1.0])))
    poses = np.stack(poses)
    names = render_sequence(tmp_path / "images", camera, poses)
    known = dict(zip(names, poses, strict=True))
    result = run_sfm(tmp_path / "images", tmp_path / "w", SfmOptions(matcher="exhaustive"), known_camera=camera,
                     known_poses=known)
    assert result.stats.images_registered == len(names)
    for name in names:
        np.testing.assert_allclose(result.cam_to_world[name], known[name], atol=1e-9)
    assert result.stats.num_points3d > 50
    # the points lie on the room's walls, floor and boxes: inside the room, away from the camera
    xyz = result.points_xyz
    inside = np.all((xyz > -0.1) & (xyz < np.array(ROOM_XYZ_M) + 0.1), axis=1)
    assert inside.mean() > 0.9
    assert np.median(np.linalg.norm(xyz - centre, axis=1)) > 1.0
    with pytest.raises(InputError, match="known poses need a known camera"):
        run_sfm(tmp_path / "images", tmp_path / "w2", known_poses=known)


def test_a_known_camera_is_not_refused_for_large_distortion():
    """COLMAP drops cameras whose distortion exceeds 1 as diverged; a calibrated fixed camera may (TUM fr1's k3 is
    1.1633): the bound is lifted when the camera is known and kept when it is refined."""
    from nsim.sfm.colmap import _mapper_options

    fixed = _mapper_options(SfmOptions(), refine_intrinsics=False)
    assert min(fixed.max_extra_param, fixed.mapper.max_extra_param, fixed.triangulation.max_extra_param) > 1e6
    refined = _mapper_options(SfmOptions(), refine_intrinsics=True)
    assert refined.max_extra_param == 1.0
