"""A TUM RGB-D sequence as downloaded (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt) read by
``nsim.io.robot_folder.RobotFolder`` and imported by ``nsim import-log``: metric depth from TUM's 1/5000 m,
the frames' stamps from the lists, the ground truth as the body's trajectory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.images import write_image, write_png16
from nsim.io.robot_folder import RobotFolder, camera_info_yaml
from nsim.workspace.store import Store

CAMERA = Camera("OPENCV", 8, 6, 7.0, 7.0, 4.0, 3.0, (0.26, -0.95, -0.005, 0.0026, 1.16))
HEADER = "# color images\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n"


def tum_sequence(root: Path, depth_m: tuple[float, ...] = (1.175, 1.2, 0.9)) -> Path:
    """Three colour frames 30 ms apart, three depth frames 5 ms after each (TUM's 16-bit PNG, 5000 per metre),
    and a 100 Hz ground truth moving 1 cm per pose along x."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_rows, depth_rows = [HEADER], [HEADER.replace("color", "depth")]
    for k, d in enumerate(depth_m):
        t = f"1305031102.{175304 + 30000 * k:06d}"
        td = f"1305031102.{180304 + 30000 * k:06d}"
        write_image(root / "rgb" / f"{t}.png", np.full((6, 8, 3), 40 * (k + 1), np.uint8))
        write_png16(root / "depth" / f"{td}.png", np.full((6, 8), round(d * 5000), np.uint16))
        rgb_rows.append(f"{t} rgb/{t}.png\n")
        depth_rows.append(f"{td} depth/{td}.png\n")
    (root / "rgb.txt").write_text("".join(rgb_rows))
    (root / "depth.txt").write_text("".join(depth_rows))
    truth = ["# ground truth trajectory\n# file: 'x.bag'\n# timestamp tx ty tz qx qy qz qw\n"]
    for k in range(12):
        truth.append(f"1305031102.{170000 + 10000 * k:06d} {0.01 * k:.4f} 0.5000 1.4000 0.0000 0.0000 0.0000 1.0000\n")
    (root / "groundtruth.txt").write_text("".join(truth))
    (root / "camera_info.yaml").write_text(yaml.safe_dump(camera_info_yaml(CAMERA, "rgb")))
    return root


def test_a_tum_sequence_reads_as_is_with_metric_depth(tmp_path):
    root = tum_sequence(tmp_path / "rgbd_dataset_freiburg1_xyz")
    with RobotFolder(root) as rf:
        assert sorted(rf.cameras) == ["rgb"] and sorted(rf.depth) == ["rgb"] and rf.lidars == {}
        cam, depth = rf.cameras["rgb"], rf.depth["rgb"]
        assert cam.camera == CAMERA and depth.camera == CAMERA
        assert cam.stamps_ns.tolist() == [1305031102175304000, 1305031102205304000, 1305031102235304000]
        assert depth.stamps_ns[0] == 1305031102180304000
        np.testing.assert_allclose(rf.image(depth, 0), 1.175, atol=1e-6)  # 5875 / 5000, not 5.875 (millimetres)
        assert depth.depth_unit.m_per_unit == pytest.approx(1 / 5000)
        np.testing.assert_array_equal(rf.image(cam, 1), np.full((6, 8, 3), 80, np.uint8))
        np.testing.assert_array_equal(rf.sensor_to_body(cam.frame_id), np.eye(4))
        traj = rf.body_trajectory()
        assert traj.source == "groundtruth.txt" and len(traj.stamps_ns) == 12 and traj.body_frame == "rgb"
        np.testing.assert_allclose(traj.body_to_odom[3, :3, 3], [0.03, 0.5, 1.4])


def test_import_log_takes_the_sequence_folder(run_cli, tmp_path):
    root = tum_sequence(tmp_path / "seq")
    code, out, err = run_cli("import-log", str(root))
    assert code == 0, err
    doc = json.loads(Store(tmp_path / "ws").get(out.strip()).file("recording.json").read_text())
    assert sorted(doc["streams"]) == ["camera/rgb", "depth/rgb"]
    entry = doc["streams"]["depth/rgb"]
    assert entry["depth_m_per_unit"] == pytest.approx(2e-4) and "TUM" in entry["depth_unit"]
    assert entry["median_depth_m"] == pytest.approx(1.175, abs=1e-6)
    assert doc["trajectory"]["source"] == "groundtruth.txt"
    assert all(e["inside_trajectory"] == 3 for e in doc["streams"].values())


@pytest.mark.parametrize("case,words", [
    ("no calibration", "camera_info.yaml: no such file; write the colour camera's calibration"),
    ("no ground truth", "groundtruth.txt: no such file"),
    ("8-bit depth", "expected a single-channel 16-bit depth PNG, got uint8"),
    ("unlisted frame", "rgb.txt: 1 frame(s) not listed"),
])
def test_bad_sequences_are_one_line(tmp_path, case, words):
    root = tum_sequence(tmp_path / "seq")
    if case == "no calibration":
        (root / "camera_info.yaml").unlink()
    elif case == "no ground truth":
        (root / "groundtruth.txt").unlink()
    elif case == "8-bit depth":
        first = sorted((root / "depth").glob("*.png"))[0]
        write_image(first, np.full((6, 8), 200, np.uint8))
    else:
        write_image(root / "rgb" / "1305031103.000000.png", np.zeros((6, 8, 3), np.uint8))
    with pytest.raises(InputError) as err:
        with RobotFolder(root) as rf:
            for _ in rf.images(rf.depth["rgb"]):
                pass
    assert words in str(err.value) and "\n" not in str(err.value), str(err.value)
