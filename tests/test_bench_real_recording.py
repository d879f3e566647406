"""bench/real_recording.py's pure parts: the capture/recording split, the overlap of their views, and the recording
folder it writes (read back by nsim's own folder reader, as ``nsim import-log`` reads it)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_real_recording", REPO / "bench" / "real_recording.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_split_is_disjoint_in_time_with_a_gap(bench):
    stamps = 1305031229.5 + np.arange(300) / 30.0  # 10 s at 30 Hz
    capture, recording = bench.split(stamps, 0.6, 40, 8)
    assert len(capture) == 40 and len(recording) == 8
    assert capture[0] == 0 and capture[-1] == 179  # evenly over the first 60 %
    assert stamps[recording[0]] >= stamps[capture[-1]] + bench.GAP_S
    assert recording[-1] == 299 and np.all(np.diff(recording) > 0)
    with pytest.raises(SystemExit, match="capture-fraction"):
        bench.split(stamps, 1.0, 40, 8)
    with pytest.raises(SystemExit, match="too few"):
        bench.split(stamps[:20], 0.95, 40, 8)  # nothing left half a second after the capture


def test_view_overlap_angles_and_distances(bench):
    # identity orientation at t = 0..1, then the same turned 90 deg about x (axis +z -> -y) 1 m away
    q_id, q_x90 = [0, 0, 0, 1], [np.sin(np.pi / 4), 0, 0, np.cos(np.pi / 4)]
    gt = np.array([[0.00, 0, 0, 0, *q_id], [0.01, 0, 0, 0, *q_id], [1.00, 1, 0, 0, *q_x90],
                   [1.01, 1, 0, 0, *q_x90]], dtype=np.float64)
    same = bench.view_overlap(gt, np.array([0.0]), np.array([0.005]))
    assert same["axis_deg_max"] == pytest.approx(0.0, abs=1e-6) and same["centre_m_max"] == 0.0
    turned = bench.view_overlap(gt, np.array([0.0]), np.array([1.0]))
    assert turned["axis_deg_median"] == pytest.approx(90.0) and turned["centre_m_median"] == pytest.approx(1.0)
    assert turned["within_15deg"] == 0.0
    assert bench.view_overlap(gt, np.array([0.0]), np.array([5.0])) == {"matched": 0}  # no pose within 20 ms


def _sequence(root: Path, n: int = 4) -> Path:
    import cv2

    seq = root / "rgbd_dataset_freiburg1_test"
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb, depth, gt = [], [], []
    for i in range(n):
        t = 1305031229.5 + i / 30.0
        cv2.imwrite(str(seq / "rgb" / f"{t:.6f}.png"), np.full((480, 640, 3), 40 * i, np.uint8))
        cv2.imwrite(str(seq / "depth" / f"{t + 0.004:.6f}.png"), np.full((480, 640), 5000, np.uint16))  # 1 m
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png\n")
        depth.append(f"{t + 0.004:.6f} depth/{t + 0.004:.6f}.png\n")
    for k in range(n * 4):
        t = 1305031229.0 + k / 100.0 * 4
        gt.append(f"{t:.4f} {0.01 * k:.4f} 0 1.5 0 0 0 1\n")
    (seq / "rgb.txt").write_text("# color images\n# file: 'rgbd_dataset_freiburg1_test.bag'\n# timestamp filename\n"
                                 + "".join(rgb))
    (seq / "depth.txt").write_text("# depth maps\n# timestamp filename\n" + "".join(depth))
    (seq / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "".join(gt))
    return seq


def test_recording_folder_reads_back(bench, tmp_path):
    from nsim.io.robot_folder import RobotFolder

    seq = _sequence(tmp_path)
    rgb, depth = bench.read_list(seq / "rgb.txt"), bench.read_list(seq / "depth.txt")
    gt = bench.read_groundtruth(seq / "groundtruth.txt")
    assert bench.camera_of(seq, seq / "rgb.txt", None) == "fr1"
    camera = bench.kinect_camera("fr1")
    assert camera.model == "OPENCV" and camera.dist[4] == pytest.approx(1.1633)
    out = tmp_path / "recording"
    n_depth = bench.write_recording(seq, rgb, depth, gt, np.array([1, 3]), out, camera)
    assert n_depth == 2
    with RobotFolder(out) as log:
        stream = log.cameras[bench.CAMERA]
        assert len(stream.stamps_ns) == 2
        assert stream.stamps_ns[0] == 1305031229533333000  # the TUM name read exactly, to the microsecond
        np.testing.assert_array_equal(log.sensor_to_body(stream.frame_id), np.eye(4))
        traj = log.body_trajectory()
        assert traj.stamps_ns[0] <= stream.stamps_ns[0] and traj.stamps_ns[-1] >= stream.stamps_ns[-1]
