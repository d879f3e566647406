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
