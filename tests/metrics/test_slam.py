"""SLAM on simulated vs real frames: pycolmap on a small test-room capture, external TUM files,
hand-computed ATE differences, evo on the written trajectories, and bad input.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.images import to_uint8, write_image
from nsim.io.tum import Trajectory, read_tum, write_tum
from nsim.metrics.slam import compare_slam, evaluate_slam, median_ate, run_colmap_slam

N_FRAMES, WIDTH, HEIGHT, FPS = 40, 160, 120, 10.0


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The robot-lab test room's first (eye-height) loop in 40 frames at 160x120: the "real" frames,
    a blurred and noisy copy as the "simulated" ones (as a NeRF renders them), and the ground truth.
    """
    from nsim.synth.oracle import RoomOracle
    from nsim.synth.path import handheld_path, timestamps_s
    from nsim.synth.room import make_room, room_diagonal_m

    spec = make_room("robot-lab", 0)
    poses = handheld_path(spec, 2 * N_FRAMES, seed=0)[:N_FRAMES]  # one loop: enough overlap for 40 frames
    camera = Camera.pinhole_from_fov(WIDTH, HEIGHT, 75.0)
    oracle = RoomOracle(spec)
    real = [to_uint8(oracle.render_gt(camera, c2w).rgb) for c2w in poses]
    rng = np.random.default_rng(0)
    sim = [np.clip(ndimage.gaussian_filter(im.astype(float), (1.0, 1.0, 0)) + rng.normal(0, 4, im.shape), 0, 255)
           .astype(np.uint8) for im in real]
    times = timestamps_s(N_FRAMES, FPS) + 100.0
    real_dir = tmp_path_factory.mktemp("real_frames")
    for k, im in enumerate(real):
        write_image(real_dir / f"frame_{k:05d}.png", im)
    return {"real_dir": real_dir, "sim": sim, "times": times, "gt": Trajectory.from_poses(times, poses),
            "diagonal_m": room_diagonal_m(spec)}


def test_colmap_slam_real_vs_sim(capture, tmp_path):
    names = [f"frame_{k:05d}.png" for k in range(N_FRAMES)]
    real = run_colmap_slam(capture["real_dir"], dict(zip(names, capture["times"], strict=True)), tmp_path / "real")
    sim = run_colmap_slam(capture["sim"], capture["times"], tmp_path / "sim")
    for run in (real, sim):
        assert run.n_frames == N_FRAMES and run.registered_fraction >= 0.95
        back = read_tum(run.tum_path)
        np.testing.assert_array_equal(back.timestamps_s, run.trajectory.timestamps_s)
        np.testing.assert_allclose(back.positions_xyz, run.trajectory.positions_xyz, rtol=0, atol=1e-9)  # TUM: 1e-9
        assert set(run.trajectory.timestamps_s) <= set(capture["times"])
    assert sorted(p.name for p in (tmp_path / "sim" / "images").iterdir()) == names

    result = compare_slam(capture["gt"], real, sim.tum_path)  # a run or its TUM file
    assert result.real.alignment == "sim3" and result.real.n_matched == real.n_registered
    for ate in (result.real, result.sim):
        assert ate.rmse_m < 0.01 * capture["diagonal_m"]
    assert result.difference_m == result.sim.rmse_m - result.real.rmse_m
    assert result.registered_real == real.registered_fraction and result.registered_sim is None
    record = result.record("front")
    assert record["ate_real_m"] == result.real.rmse_m and record["ate_sim_m"] == result.sim.rmse_m

    # the reference library on the written files
    pytest.importorskip("evo")
    from evo.core import metrics, sync
    from evo.main_ape import ape
    from evo.tools import file_interface

    gt_path = write_tum(tmp_path / "gt.tum", capture["gt"])
    ref, est = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt_path)),
                                           file_interface.read_tum_trajectory_file(str(real.tum_path)))
    evo_result = ape(ref, est, metrics.PoseRelation.translation_part, align=True, correct_scale=True)
    assert result.real.rmse_m == pytest.approx(evo_result.stats["rmse"], rel=1e-6)


def offset(traj: Trajectory, xyz_m, dt_s: float = 0.0) -> Trajectory:
    return Trajectory(traj.timestamps_s + dt_s, traj.positions_xyz + np.asarray(xyz_m), traj.orientations_quat_wxyz)


def circle(n: int = 30) -> Trajectory:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, 3] = np.column_stack([np.cos(a), np.sin(a), 0.1 * np.sin(3 * a)])
    return Trajectory.from_poses(np.arange(n) / 10.0, poses)


def test_external_tum_files_hand_computed(tmp_path):
    gt = circle()
    gt_path = write_tum(tmp_path / "gt.tum", gt)
    real_path = write_tum(tmp_path / "orbslam_real.tum", offset(gt, [0.0, 0.0, 0.0]))
    sim_path = write_tum(tmp_path / "orbslam_sim.tum", offset(gt, [0.06, 0.0, 0.08]))  # 0.1 m off everywhere
    result = compare_slam(gt_path, real_path, sim_path, alignment="none")
    assert result.real.rmse_m == 0.0
    assert result.sim.rmse_m == pytest.approx(0.1)
    assert result.difference_m == pytest.approx(0.1)
    # an SE(3) alignment removes a constant offset
    assert compare_slam(gt, gt, offset(gt, [0.06, 0.0, 0.08]), alignment="se3").sim.rmse_m == pytest.approx(0, abs=1e-9)
    # the paper's summary: medians over the cameras
    runs = [compare_slam(gt, offset(gt, [d, 0, 0]), offset(gt, [2 * d + 0.1, 0, 0]), alignment="none")
            for d in (0.1, 0.3, 0.2)]
    assert median_ate(runs) == pytest.approx((0.2, 0.5, 0.3))


def test_bad_input(tmp_path):
    gt = circle()
    with pytest.raises(InputError, match="SLAM on simulated frames vs ground truth: trajectories have no common"):
        compare_slam(gt, gt, offset(gt, [0, 0, 0], dt_s=1000.0))
    frames = [np.zeros((HEIGHT, WIDTH, 3), np.uint8)] * 3
    with pytest.raises(InputError, match="3 frames but 2 timestamps"):
        run_colmap_slam(frames, [0.0, 0.1], tmp_path / "a")
    with pytest.raises(InputError, match=r"frame frame_00002\.png \(0\.1\) is not after"):
        run_colmap_slam(frames, [0.0, 0.1, 0.1], tmp_path / "b")
    with pytest.raises(InputError, match="frame frame_00001.png has no timestamp"):
        run_colmap_slam(frames, {"frame_00000.png": 0.0}, tmp_path / "c")
    with pytest.raises(InputError, match=r"frame 0: expected an \(H, W, 3\) uint8"):
        run_colmap_slam([np.zeros((HEIGHT, WIDTH))], [0.0], tmp_path / "d")
    with pytest.raises(InputError, match="3 real frames but 2 simulated frames"):
        evaluate_slam(gt, frames, frames[:2], [0.0, 0.1, 0.2], tmp_path / "e")
    with pytest.raises(InputError, match="no such file"):
        compare_slam(gt, tmp_path / "missing.tum", gt)
    with pytest.raises(InputError, match="no sequences"):
        median_ate([])
