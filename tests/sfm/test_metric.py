"""Metric scale and frame for a reconstruction: reference (transforms.json / TUM), distance, height."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.tum import Trajectory, write_tum
from nsim.sfm.metric import Reference, load_reference, to_metric

FPS = 10.0


def _pairwise_ratio(est: np.ndarray, gt: np.ndarray) -> float:
    i, j = np.triu_indices(len(est), 1)
    return float(np.median(np.linalg.norm(est[i] - est[j], axis=1) / np.linalg.norm(gt[i] - gt[j], axis=1)))


def _times(capture) -> dict[str, float]:
    return {n: i / FPS for i, n in enumerate(capture.names)}


def test_reference_by_name_with_noise(pinhole_sfm, pinhole_capture):
    noisy = pinhole_capture.cam_to_world.copy()
    noisy[:, :3, 3] += np.random.default_rng(0).normal(0, 0.01, noisy[:, :3, 3].shape)
    ref = Reference("gt.json", noisy, tuple(f"images/{n}" for n in pinhole_capture.names))
    metric, report = to_metric(pinhole_sfm, reference=ref)
    names = metric.registered_names
    assert report.source == "reference" and report.associated_by == "name"
    assert report.matched == report.associated == len(names)
    assert report.residual_rms_m < 0.03
    est, gt = metric.poses_se3(names)[:, :3, 3], pinhole_capture.gt(names)[:, :3, 3]
    assert _pairwise_ratio(est, gt) == pytest.approx(1.0, abs=0.02)
    assert np.median(np.linalg.norm(est - gt, axis=1)) < 0.02  # the reference's world, in metres


def test_reference_from_a_tum_file(pinhole_sfm, pinhole_capture, tmp_path):
    path = tmp_path / "gt.tum"
    times = np.arange(len(pinhole_capture.names)) / FPS
    write_tum(path, Trajectory.from_poses(times, pinhole_capture.cam_to_world))
    ref = load_reference(path)
    assert ref.names is None and len(ref.timestamps_s) == len(pinhole_capture.names)
    metric, report = to_metric(pinhole_sfm, timestamps_s=_times(pinhole_capture), reference=ref)
    assert report.associated_by == "timestamp"
    names = metric.registered_names
    np.testing.assert_allclose(metric.poses_se3(names)[:, :3, 3], pinhole_capture.gt(names)[:, :3, 3], atol=0.03)


def test_reference_with_no_matching_timestamps(pinhole_sfm, pinhole_capture, tmp_path):
    path = tmp_path / "other.tum"
    times = 1000.0 + np.arange(len(pinhole_capture.names)) / FPS
    write_tum(path, Trajectory.from_poses(times, pinhole_capture.cam_to_world))
    with pytest.raises(InputError, match=r"other.tum: only 0 of \d+ registered frames match a reference pose by timestamp"):
        to_metric(pinhole_sfm, timestamps_s=_times(pinhole_capture), reference=load_reference(path))
    with pytest.raises(InputError, match="the input frames have none"):
        to_metric(pinhole_sfm, timestamps_s=None, reference=load_reference(path))


def test_camera_height_and_known_distance(pinhole_sfm, pinhole_capture):
    names = pinhole_sfm.registered_names
    gt = pinhole_capture.gt(names)
    arbitrary, report = to_metric(pinhole_sfm)
    assert report.source == "arbitrary" and "scale is arbitrary" in report.message and report.floor_found
    by_height, report = to_metric(pinhole_sfm, camera_height_m=float(np.median(gt[:, 2, 3])))
    assert report.source == "camera_height"
    np.testing.assert_allclose(by_height.poses_se3(names)[:, 2, 3], gt[:, 2, 3], atol=0.03)
    # two points picked in the arbitrary-scale output (here: two camera centres 0 and 15)
    a, b = arbitrary.poses_se3(names)[[0, 15], :3, 3]
    true_d = float(np.linalg.norm(gt[0, :3, 3] - gt[15, :3, 3]))
    by_distance, report = to_metric(pinhole_sfm, known_distance=(a, b, true_d))
    assert report.source == "known_distance"
    assert _pairwise_ratio(by_distance.poses_se3(names)[:, :3, 3], gt[:, :3, 3]) == pytest.approx(1.0, abs=0.02)
    with pytest.raises(ValueError, match="at most one"):
        to_metric(pinhole_sfm, camera_height_m=1.0, known_distance=(a, b, 1.0))


def test_top_down_png(pinhole_sfm, pinhole_capture, tmp_path):
    from nsim.io.images import read_image
    from nsim.sfm.plot import write_top_down_png

    metric, _ = to_metric(pinhole_sfm, camera_height_m=1.4)
    path = write_top_down_png(tmp_path / "top_down.png", metric.poses_se3(), metric.points_xyz,
                              title="test", reference_xyz=pinhole_capture.cam_to_world[:, :3, 3])
    image = read_image(path)
    assert image.shape == (600, 600, 3) and image.std() > 10


def _z_up_scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Cameras 1.2-1.6 m above a floor at z = 0, looking level-ish; floor points. Metric, z up."""
    from nsim.geometry.transforms import look_at

    rng = np.random.default_rng(seed)
    a = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    eye = np.stack([np.cos(a), np.sin(a), rng.uniform(1.2, 1.6, len(a))], axis=1)
    c2w = look_at(eye, np.stack([3 * np.cos(a + 1), 3 * np.sin(a + 1), np.ones(len(a))], axis=1))
    return c2w, np.c_[rng.uniform(-3, 3, (300, 2)), np.zeros(300)]


def _moved(c2w, pts, s=2.5, rotvec=(0.3, -1.1, 0.7), t=(1.0, 2.0, -3.0)):
    from scipy.spatial.transform import Rotation

    from nsim.sfm.align import apply_sim3_to_points, apply_sim3_to_poses

    R = Rotation.from_rotvec(rotvec).as_matrix()
    return apply_sim3_to_poses(s, R, np.asarray(t), c2w), apply_sim3_to_points(s, R, np.asarray(t), pts)


def test_metric_frame_sources_on_arrays():
    from nsim.sfm.align import apply_sim3_to_poses
    from nsim.sfm.metric import metric_frame

    c2w, pts = _z_up_scene()
    moved, moved_pts = _moved(c2w, pts)
    names = [f"{i}.png" for i in range(len(c2w))]
    height = float(np.median(c2w[:, 2, 3]))
    sim, report = metric_frame(moved, moved_pts, names, camera_height_m=height)
    out = apply_sim3_to_poses(sim.s, sim.R, sim.t, moved)
    assert (report.source, report.frame, report.floor_found) == ("camera_height", "gravity", True)
    assert sim.s == pytest.approx(1 / 2.5, rel=1e-6)
    np.testing.assert_allclose(out[:, 2, :], c2w[:, 2, :], atol=1e-6)  # heights and tilts: z up, floor at 0
    ref = Reference("gt.json", c2w, tuple(names))
    sim, report = metric_frame(moved, moved_pts, names, reference=ref, declared_metric="--metric")
    assert (report.source, report.frame, report.associated_by) == ("reference", "reference", "name")
    np.testing.assert_allclose(apply_sim3_to_poses(sim.s, sim.R, sim.t, moved), c2w, atol=1e-9)
    sim, report = metric_frame(moved, moved_pts, names, declared_metric="--metric")  # scale 1, z up
    assert (report.source, report.scale, sim.s) == ("metric", 1.0, 1.0) and "--metric" in report.message
    sim, report = metric_frame(moved, moved_pts, names)
    assert report.source == "arbitrary" and sim.s == 1.0
    sim, report = metric_frame(c2w, pts, names, declared_metric="an nsim capture", declared_z_up=True)
    assert (report.source, report.frame, report.floor_found) == ("metric", "as_given", None)
    np.testing.assert_array_equal(sim.matrix(), np.eye(4))


def test_metric_frame_camera_height_needs_a_floor():
    from nsim.sfm.metric import metric_frame

    c2w, _ = _z_up_scene()
    names = [f"{i}.png" for i in range(len(c2w))]
    with pytest.raises(InputError, match="no sparse points to find the floor among"):
        metric_frame(c2w, np.zeros((0, 3)), names, camera_height_m=1.4)
    sim, report = metric_frame(c2w, np.zeros((0, 3)), names, camera_height_m=2.8, declared_z_up=True)
    assert sim.s == pytest.approx(2.8 / np.median(c2w[:, 2, 3]))  # a z-up input has its floor at 0
