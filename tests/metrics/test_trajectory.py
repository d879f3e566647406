"""ATE and RPE: analytic cases, bad input, and the numbers evo computes on the same TUM files."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry.transforms import make_se3
from nsim.io.tum import Trajectory, read_tum, write_tum
from nsim.metrics.trajectory import align_trajectories, ate, rpe, rpe_per_delta


def wavy_path(n: int = 60, seed: int = 0, dt_s: float = 0.1) -> Trajectory:
    """A smooth 3-D path with a turning, pitching body (not collinear, so alignment is well posed)."""
    t = np.arange(n) * dt_s + 100.0
    s = np.linspace(0.0, 2.0 * np.pi, n)
    xyz = np.column_stack([3.0 * np.cos(s), 2.0 * np.sin(s), 0.3 * np.sin(3 * s)])
    rng = np.random.default_rng(seed)
    rotvec = np.column_stack([0.1 * np.sin(2 * s), 0.05 * rng.standard_normal(n), s])
    return Trajectory.from_poses(t, make_se3(Rotation.from_rotvec(rotvec).as_matrix(), xyz))


def transformed(traj: Trajectory, scale: float, R: np.ndarray, t: np.ndarray) -> Trajectory:
    """Every pose mapped by the similarity x -> scale R x + t (orientations rotated by R)."""
    poses = traj.poses_se3()
    poses[:, :3, 3] = scale * poses[:, :3, 3] @ R.T + t
    poses[:, :3, :3] = R @ poses[:, :3, :3]
    return Trajectory.from_poses(traj.timestamps_s, poses)


def perturbed(traj: Trajectory, seed: int, sigma_m: float = 0.05, sigma_rad: float = 0.02) -> Trajectory:
    rng = np.random.default_rng(seed)
    poses = traj.poses_se3()
    poses[:, :3, 3] += rng.normal(0.0, sigma_m, (len(traj), 3))
    noise = Rotation.from_rotvec(rng.normal(0.0, sigma_rad, (len(traj), 3))).as_matrix()
    poses[:, :3, :3] = poses[:, :3, :3] @ noise
    return Trajectory.from_poses(traj.timestamps_s, poses)


R_OFFSET = Rotation.from_euler("zyx", [40.0, -10.0, 5.0], degrees=True).as_matrix()
T_OFFSET = np.array([1.5, -2.0, 0.3])


def test_ate_is_zero_after_alignment_of_a_rigid_offset():
    ref = wavy_path()
    est = transformed(ref, 1.0, R_OFFSET, T_OFFSET)
    result = ate(ref, est, "se3")
    assert result.rmse_m == pytest.approx(0.0, abs=1e-9)
    assert result.rot_rmse_deg == pytest.approx(0.0, abs=1e-6)
    assert result.n_matched == len(ref) and result.scale == 1.0
    np.testing.assert_allclose(result.rotation, R_OFFSET.T, atol=1e-9)  # maps the estimate back
    unaligned = ate(ref, est, "none")
    assert unaligned.rmse_m > 1.0


def test_ate_sim3_recovers_scale():
    ref = wavy_path()
    est = transformed(ref, 0.4, R_OFFSET, T_OFFSET)
    assert ate(ref, est, "se3").rmse_m > 0.1
    result = ate(ref, est, "sim3")
    assert result.rmse_m == pytest.approx(0.0, abs=1e-9)
    assert result.scale == pytest.approx(1 / 0.4)


def test_ate_known_translation_error_without_alignment():
    ref = wavy_path()
    est = transformed(ref, 1.0, np.eye(3), np.array([0.0, 0.0, 0.25]))
    result = ate(ref, est, "none")
    assert result.rmse_m == pytest.approx(0.25) and result.max_m == pytest.approx(0.25)
    np.testing.assert_allclose(result.errors_m, 0.25)


def test_rpe_of_a_constant_offset():
    """A constant world-frame offset leaves every relative pose, hence RPE, at zero; a constant
    body-frame error on every relative motion gives exactly that error at delta 1."""
    ref = wavy_path()
    est = transformed(ref, 1.0, R_OFFSET, T_OFFSET)
    result = rpe(ref, est, delta_frames=1)
    assert result.trans_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert result.rot_max_deg == pytest.approx(0.0, abs=1e-5)
    assert result.n_pairs == len(ref) - 1
    # Estimate built from the reference's relative motions, each followed by an extra body-frame step
    # of 0.1 m along x and 2 degrees about z.
    ref_poses = ref.poses_se3()
    extra = make_se3(Rotation.from_euler("z", 2.0, degrees=True).as_matrix(), np.array([0.1, 0.0, 0.0]))
    est_poses = [ref_poses[0]]
    for k in range(1, len(ref)):
        est_poses.append(est_poses[-1] @ np.linalg.inv(ref_poses[k - 1]) @ ref_poses[k] @ extra)
    est = Trajectory.from_poses(ref.timestamps_s, np.array(est_poses))
    result = rpe(ref, est, delta_frames=1)
    np.testing.assert_allclose(result.trans_errors_m, 0.1, atol=1e-9)
    np.testing.assert_allclose(result.rot_errors_deg, 2.0, atol=1e-7)


def test_rpe_pairs_and_deltas():
    ref = wavy_path(n=31)
    est = perturbed(ref, seed=1)
    assert rpe(ref, est, 10, all_pairs=True).n_pairs == 21
    assert rpe(ref, est, 10, all_pairs=False).n_pairs == 3  # (0, 10), (10, 20), (20, 30)
    results = rpe_per_delta(ref, est, (1, 5))
    assert [r.delta_frames for r in results] == [1, 5]
    with pytest.raises(InputError, match="delta of 40 frames"):
        rpe(ref, est, 40)
    with pytest.raises(ValueError, match="delta_frames"):
        rpe(ref, est, 0)


def test_association_by_timestamp():
    ref = wavy_path(n=40)
    est = perturbed(ref, seed=2)
    # the estimate runs at half the rate, with 2 ms of clock jitter
    est = Trajectory.from_poses(est.timestamps_s[::2] + 0.002, est.poses_se3()[::2])
    result = ate(ref, est, "se3", max_dt_s=0.01)
    assert result.n_matched == 20
    pair = align_trajectories(ref, est, "none", max_dt_s=0.01)
    np.testing.assert_array_equal(pair.timestamps_s, ref.timestamps_s[::2])


def test_bad_input():
    ref = wavy_path(n=10)
    later = Trajectory.from_poses(ref.timestamps_s + 1000.0, ref.poses_se3())
    with pytest.raises(InputError, match="no common timestamps"):
        ate(ref, later)
    two = Trajectory.from_poses(ref.timestamps_s[:2], ref.poses_se3()[:2])
    with pytest.raises(InputError, match="cannot align"):
        ate(ref, two, "se3")
    assert ate(ref, two, "none").n_matched == 2
    line = ref.poses_se3()
    line[:, :3, 3] = np.outer(np.arange(10), [1.0, 0.0, 0.0])
    collinear = Trajectory.from_poses(ref.timestamps_s, line)
    with pytest.raises(InputError, match="collinear"):
        ate(collinear, collinear, "sim3")
    with pytest.raises(ValueError, match="alignment"):
        ate(ref, ref, "SE3")


# ------------------------------------------------------------------------------------------------
# evo on the same TUM files


def evo_pair(ref_path, est_path):
    """Fresh evo trajectories, associated as evo does (its ape/rpe change their inputs in place)."""
    from evo.core import sync
    from evo.tools import file_interface

    return sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(ref_path), file_interface.read_tum_trajectory_file(est_path)
    )


@pytest.fixture
def tum_files(tmp_path):
    ref = wavy_path(n=80)
    est = transformed(perturbed(ref, seed=4), 0.7, R_OFFSET, T_OFFSET)
    # a few ms of clock jitter, inside evo's and nsim's 10 ms window
    jitter = np.random.default_rng(5).uniform(-0.003, 0.003, len(est))
    est = Trajectory.from_poses(est.timestamps_s + jitter, est.poses_se3())
    return write_tum(tmp_path / "ref.tum", ref), write_tum(tmp_path / "est.tum", est)


@pytest.mark.parametrize("alignment", ["se3", "sim3"])
def test_ate_matches_evo(tum_files, alignment):
    pytest.importorskip("evo")
    from evo.core import metrics
    from evo.main_ape import ape

    ref_path, est_path = tum_files
    ours = ate(read_tum(ref_path), read_tum(est_path), alignment)
    options = dict(align=True, correct_scale=alignment == "sim3")
    trans = ape(*evo_pair(ref_path, est_path), metrics.PoseRelation.translation_part, **options)
    rot = ape(*evo_pair(ref_path, est_path), metrics.PoseRelation.rotation_angle_deg, **options)
    assert ours.n_matched == len(trans.np_arrays["error_array"]) == 80
    assert ours.rmse_m == pytest.approx(trans.stats["rmse"], rel=1e-9)
    assert ours.mean_m == pytest.approx(trans.stats["mean"], rel=1e-9)
    assert ours.max_m == pytest.approx(trans.stats["max"], rel=1e-9)
    np.testing.assert_allclose(ours.errors_m, trans.np_arrays["error_array"], rtol=1e-9)
    assert ours.rot_rmse_deg == pytest.approx(rot.stats["rmse"], rel=1e-7)


@pytest.mark.parametrize(
    ("delta", "all_pairs", "alignment"), [(1, False, "none"), (5, True, "none"), (10, True, "sim3")]
)
def test_rpe_matches_evo(tum_files, delta, all_pairs, alignment):
    pytest.importorskip("evo")
    from evo.core import metrics
    from evo.main_rpe import rpe as evo_rpe

    ref_path, est_path = tum_files
    ours = rpe(read_tum(ref_path), read_tum(est_path), delta, all_pairs=all_pairs, alignment=alignment)
    options = dict(
        delta=delta, delta_unit=metrics.Unit.frames, all_pairs=all_pairs,
        align=alignment != "none", correct_scale=alignment == "sim3",
    )  # fmt: skip
    trans = evo_rpe(*evo_pair(ref_path, est_path), metrics.PoseRelation.translation_part, **options)
    rot = evo_rpe(*evo_pair(ref_path, est_path), metrics.PoseRelation.rotation_angle_deg, **options)
    assert ours.n_pairs == len(trans.np_arrays["error_array"])
    np.testing.assert_allclose(ours.trans_errors_m, trans.np_arrays["error_array"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ours.rot_errors_deg, rot.np_arrays["error_array"], rtol=1e-7, atol=1e-9)
    assert ours.trans_rmse_m == pytest.approx(trans.stats["rmse"], rel=1e-9)
    assert ours.rot_mean_deg == pytest.approx(rot.stats["mean"], rel=1e-7)
