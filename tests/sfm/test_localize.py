"""Localising single images in a scene's sparse model: the test room, held-out views, other cameras.

The scene is a small poses artifact folder (``images/`` + ``sparse/``) of nsim's test room: 60
frames of the handheld capture path at 200x150, SIFT-matched by ``run_sfm`` and then
triangulated from the frames' true poses (``pycolmap.triangulate_points``), so that the model is
metric, z up and in the oracle's world, and a localised pose can be compared with the truth
without the scene's own SfM error in between (that error is reconstruct's to test).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2  # noqa: F401  (before pycolmap, see nsim.sfm.colmap)
import numpy as np
import pycolmap
import pytest

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import invert_se3, rotation_angle_deg
from nsim.io.images import to_uint8, write_image
from nsim.sfm.colmap import colmap_log_level, run_sfm
from nsim.sfm.localize import SceneIndex, build_scene_index, localize, retrieve
from nsim.sfm.options import SfmOptions
from nsim.synth.oracle import RoomOracle
from nsim.synth.path import handheld_path, handheld_path_at
from nsim.synth.room import make_room

N_FRAMES = 60
SCENE_CAMERA = Camera.pinhole_from_fov(200, 150, 75.0)
#: Held-out views: half-way between capture frames 12|13 (eye height) and 47|48 (the low loop, 0.6 m).
HELD_OUT_FRACTIONS = ((12 + 0.5) / N_FRAMES, (47 + 0.5) / N_FRAMES)
FISHEYE = Camera.fisheye_spot_like(320, 240)
# a wider lens than the scene's, with barrel distortion (OpenCV radial-tangential)
_PIN = Camera.pinhole_from_fov(200, 150, 90.0)
DISTORTED = Camera("OPENCV", 200, 150, _PIN.fx, _PIN.fy, _PIN.cx, _PIN.cy, (-0.08, 0.01, 0.0, 0.0, 0.0))
# A pixel of the scene's 200 px, 75 deg images spans 0.4 deg, 1.5-3 cm on walls 2-4 m away; with
# 30-100 inliers a pose lands within about that (measured: at most 2.9 cm and 0.28 deg over 24
# held-out views of both cameras), so 5 cm and 1 deg leave room without hiding a wrong match.
MAX_POSITION_ERROR_M = 0.05
MAX_ROTATION_ERROR_DEG = 1.0


@dataclass(frozen=True)
class Scene:
    root: Path
    oracle: RoomOracle
    cam_to_world: np.ndarray  # (N, 4, 4) the capture's true poses
    index: SceneIndex


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Scene:
    spec = make_room("robot-lab", 0)
    oracle = RoomOracle(spec)
    root = tmp_path_factory.mktemp("poses")
    poses = handheld_path(spec, N_FRAMES, seed=0)
    (root / "images").mkdir()
    for i, c2w in enumerate(poses):
        write_image(root / "images" / f"frame_{i:05d}.png", to_uint8(oracle.render_gt(SCENE_CAMERA, c2w, 2).rgb))
    work = tmp_path_factory.mktemp("sfm")
    result = run_sfm(root / "images", work, SfmOptions(num_threads=2), known_camera=SCENE_CAMERA)
    rec = result.reconstruction
    for image in rec.images.values():
        if image.has_pose:
            world_to_cam = invert_se3(poses[int(image.name[6:11])])
            rec.frames[image.frame_id].set_cam_from_world(image.camera_id, pycolmap.Rigid3d(world_to_cam[:3, :]))
    (root / "sparse").mkdir()
    with colmap_log_level():
        rec = pycolmap.triangulate_points(rec, work / "database.db", root / "images", root / "sparse")
    rec.write(root / "sparse")
    return Scene(root, oracle, poses, build_scene_index(root))


def _view(scene: Scene, camera: Camera, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    c2w = handheld_path_at(scene.oracle.spec, np.array([fraction]), seed=0)[0]
    return to_uint8(scene.oracle.render_gt(camera, c2w, 2).rgb), c2w


def test_index_holds_the_model_points_in_opencv_pixels(scene):
    index = scene.index
    assert len(index.images) >= 55 and index.num_points > 800
    errors = []
    for im in index.images[::10]:
        assert im.xy.shape == (len(im.descriptors), 2) and im.descriptors.shape[1] == 128
        np.testing.assert_allclose(np.linalg.norm(im.descriptors, axis=1), 1.0, atol=1e-5)
        # each keypoint's 3D point projects onto it through the true pose (OpenCV pixel centres)
        w2c = invert_se3(scene.cam_to_world[int(im.name[6:11])])
        uv, ok = SCENE_CAMERA.project(im.xyz_world @ w2c[:3, :3].T + w2c[:3, 3])
        assert ok.all()
        errors.append(np.linalg.norm(uv - im.xy, axis=1))
    errors = np.concatenate(errors)
    assert np.median(errors) < 0.35, np.median(errors)  # a +-0.5 px convention slip would show here


@pytest.mark.parametrize("camera", [FISHEYE, DISTORTED], ids=["fisheye", "opencv"])
def test_localizes_held_out_views_with_other_cameras(scene, camera):
    for fraction in HELD_OUT_FRACTIONS:
        image, truth = _view(scene, camera, fraction)
        loc = localize(image, camera, scene.index)
        assert loc is not None, fraction
        pos_err = float(np.linalg.norm(loc.cam_to_world[:3, 3] - truth[:3, 3]))
        rot_err = float(rotation_angle_deg(loc.cam_to_world[:3, :3], truth[:3, :3]))
        assert pos_err < MAX_POSITION_ERROR_M and rot_err < MAX_ROTATION_ERROR_DEG, (fraction, pos_err, rot_err)
        assert loc.num_inliers >= 20 and loc.median_error_px < 1.0
        assert loc.inlier_xy.shape == (loc.num_inliers, 2) and loc.inlier_xyz_world.shape == (loc.num_inliers, 3)
        # retrieval found the capture frames around the view
        nearest = {f"frame_{int(fraction * N_FRAMES) + d:05d}.png" for d in (-1, 0, 1, 2)}
        assert nearest & set(loc.scene_images), loc.scene_images


def test_localize_is_deterministic_and_retrieval_ranks_the_neighbours(scene):
    image, _ = _view(scene, DISTORTED, HELD_OUT_FRACTIONS[0])
    a = localize(image, DISTORTED, scene.index, seed=3)
    b = localize(image, DISTORTED, scene.index, seed=3)
    assert a is not None and b is not None
    np.testing.assert_array_equal(a.cam_to_world, b.cam_to_world)
    assert a.num_inliers == b.num_inliers and a.scene_images == b.scene_images
    from nsim.sfm.localize import extract_sift

    _, desc = extract_sift(image)
    order, counts = retrieve(scene.index, desc, top_k=3)
    assert len(order) == 3 and np.all(np.diff(counts) <= 0)
    assert any(abs(int(scene.index.images[i].name[6:11]) - 12.5) < 3 for i in order)


def test_blank_walls_and_noise_are_not_localised(scene):
    rng = np.random.default_rng(0)
    blank = np.full((240, 320, 3), 128, np.uint8)
    noise = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    smooth = np.repeat(np.linspace(0, 255, 320, dtype=np.uint8)[None, :, None], 240, axis=0).repeat(3, axis=2)
    for image in (blank, noise, smooth):
        assert localize(image, FISHEYE, scene.index) is None


def test_bad_inputs(scene, tmp_path):
    with pytest.raises(ValueError, match="camera is 320x240"):
        localize(np.zeros((150, 200, 3), np.uint8), FISHEYE, scene.index)
    with pytest.raises(ValueError, match="cannot be used"):
        localize(np.zeros((100, 200, 3), np.uint8), Camera.equirect(200, 100), scene.index)
    with pytest.raises(InputError, match="no COLMAP model in sparse/"):
        build_scene_index(tmp_path)
