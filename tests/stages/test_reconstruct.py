"""`nsim reconstruct` end to end on a small test-room capture, and its bad inputs."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from nsim.io.ply import read_ply
from nsim.io.transforms_json import read_transforms
from nsim.io.tum import Trajectory, read_tum, write_tum
from nsim.sfm.align import fit_sim3, pose_errors
from nsim.synth.room import make_room, room_diagonal_m
from nsim.workspace.store import Store

SMALL = ("--set", "n_frames=100", "--set", "width=160", "--set", "height=120", "--set", "video=false")


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory):
    from nsim.cli import main

    ws = tmp_path_factory.mktemp("rec") / "ws"
    assert main(["--workspace", str(ws), "capture", "synth", "--preset", "tiny", *SMALL, "--tag", "capture/s"]) == 0
    store = Store(ws)
    return store, store.get(store.resolve("capture/s"))


@pytest.mark.slow
def test_reconstruct_capture_with_noisy_reference(small_capture, run_cli, tmp_path):
    store, cap = small_capture
    gt = read_tum(cap.file("gt_trajectory.tum"))
    noisy = gt.positions_xyz + np.random.default_rng(0).normal(0, 0.01, gt.positions_xyz.shape)
    ref = tmp_path / "odometry.tum"
    write_tum(ref, Trajectory(gt.timestamps_s, noisy, gt.orientations_quat_wxyz))
    code, out, err = run_cli("reconstruct", "capture/s", "--preset", "tiny", "--reference", str(ref),
                             "--tag", "poses/s", workspace=store.root)
    assert code == 0, err
    art = store.get(out.strip())
    assert art.manifest["kind"] == "poses" and art.manifest["inputs"] == {"capture": cap.id}
    est = read_transforms(art.file("transforms.json"))
    assert len(est.frames) >= 95
    by_t = {round(t, 6): T for t, T in zip(gt.timestamps_s.tolist(), gt.poses_se3(), strict=True)}
    est_poses = np.stack([f.cam_to_world for f in est.frames])
    gt_poses = np.stack([by_t[round(f.timestamp_s, 6)] for f in est.frames])
    rot, pos = pose_errors(est_poses, gt_poses)
    assert np.median(rot) < 1.0
    assert np.median(pos) < 0.01 * room_diagonal_m(make_room("robot-lab", 0))
    # metric: the output is in the reference's (ground truth's) scale within 2 %
    assert fit_sim3(est_poses[:, :3, 3], gt_poses[:, :3, 3]).s == pytest.approx(1.0, rel=0.02)
    report = json.loads(art.file("report.json").read_text())
    assert report["scale"]["source"] == "reference" and report["images_registered"] == len(est.frames)
    assert report["scale"]["message"].endswith("odometry.tum")  # a file name, never a path
    cloud = read_ply(art.file("sparse_points.ply"))
    assert len(cloud.xyz) == report["num_points3d"] > 100
    assert {"cameras.bin", "images.bin", "points3D.bin"} <= {p.name for p in (art.path / "sparse").iterdir()}
    assert (art.path / "top_down.png").stat().st_size > 1000
    assert "phases_s" in art.manifest["timing"]
    # same inputs, same artifact (the reference is digested by content, not by path)
    moved = tmp_path / "elsewhere.tum"
    moved.write_bytes(ref.read_bytes())
    code, out2, err = run_cli("reconstruct", "capture/s", "--preset", "tiny", "--reference", str(moved),
                              "--force", workspace=store.root)
    assert code == 0 and out2.strip() != ""  # a different file name is recorded in report.json
    # verify --rebuild reruns it from the reference where it was read, while it is unchanged
    assert art.manifest["timing"]["source"] == {"reference": str(ref.resolve())}
    code, out, err = run_cli("verify", "--rebuild", art.id, workspace=store.root)
    assert code == 0 and out.strip() == f"ok      {art.id[:12]} rebuilt identically", (out, err)
    ref.write_text(ref.read_text() + "\n")
    code, out, err = run_cli("verify", "--rebuild", art.id, workspace=store.root)
    assert code == 0 and out.startswith(f"SKIPPED {art.id[:12]} cannot rebuild: {ref.resolve()}: the reference has "
                                        "changed"), out


def test_bad_inputs_exit_2(small_capture, run_cli, tmp_path):
    store, cap = small_capture
    ws = store.root
    before = sorted(store.all_ids())
    # an unreadable video
    bad_video = tmp_path / "broken.mp4"
    bad_video.write_bytes(b"\x00\x01 not a video" * 100)
    cases = [
        (("reconstruct", str(bad_video)), "broken.mp4"),
        (("reconstruct", str(tmp_path / "missing.mp4")), "no such file, folder or capture artifact"),
        (("reconstruct",), "give a video, an image folder or a capture"),
        (("reconstruct", "capture/s", "--camera-height", "1.5", "--known-distance", *["0"] * 6, "1"),
         "at most one of"),
        (("reconstruct", "capture/s", "--camera-height", "-1"), "--camera-height"),
        (("reconstruct", "capture/s", "--camera-model", "FANCY"), "camera_model: 'FANCY' is not one of"),
    ]
    few = tmp_path / "few"
    few.mkdir()
    for i in range(2):
        cv2.imwrite(str(few / f"{i}.png"), np.full((20, 20, 3), 100, np.uint8))
    cases.append((("reconstruct", str(few)), "need at least 3"))
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for i, size in enumerate((20, 20, 30)):
        cv2.imwrite(str(mixed / f"{i}.png"), np.full((size, size, 3), 100, np.uint8))
    cases.append((("reconstruct", str(mixed)), "size"))
    no_match = tmp_path / "late.tum"
    gt = read_tum(cap.file("gt_trajectory.tum"))
    write_tum(no_match, Trajectory(gt.timestamps_s + 1000.0, gt.positions_xyz, gt.orientations_quat_wxyz))
    cases.append((("reconstruct", "capture/s", "--preset", "tiny", "--reference", str(no_match)), "late.tum"))
    cases.append((("reconstruct", "capture/s", "--preset", "tiny", "--set", "frames=40",
                   "--set", "loop_detection=false", "--set", "max_features=256"), "frames registered"))
    for args, message in cases:
        code, out, err = run_cli(*args, workspace=ws)
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 2, (args, err)
        assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], (args, err)
    assert sorted(store.all_ids()) == before  # no partial poses artifact
    assert list((ws / "tmp").iterdir()) == []


@pytest.mark.slow
def test_a_phone_capture_reconstructs_against_its_odometry(run_cli, tmp_path):
    """The phone preset's frames are JPEG (exposure drift, noise, blur, rolling shutter): reconstruct
    matches the capture's TUM trajectory to them by timestamp and registers at least 95 % of them."""
    from nsim.cli import main

    ws = tmp_path / "ws"
    assert main(["--workspace", str(ws), "capture", "synth", "--preset", "phone", *SMALL, "--tag", "capture/p"]) == 0
    store = Store(ws)
    cap = store.get(store.resolve("capture/p"))
    assert all(f.file_path.endswith(".jpg") for f in read_transforms(cap.file("transforms.json")).frames)
    code, out, err = run_cli("reconstruct", "capture/p", "--preset", "tiny", "--frames", "100",
                             "--reference", str(cap.file("gt_trajectory.tum")), workspace=ws)
    assert code == 0, err
    report = json.loads(store.get(out.strip()).file("report.json").read_text())
    assert report["scale"]["source"] == "reference"
    assert report["images_registered"] >= 0.95 * report["images_given"]
