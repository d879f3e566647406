"""Human training data: poses.json / BVH round trips and one clear error per kind of bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import look_at
from nsim.human.bvh import write_bvh
from nsim.human.data import HumanData, HumanPoses, read_mask, read_poses, write_poses
from nsim.human.gait import walk_cycle
from nsim.human.motion import MotionClip
from nsim.human.skeleton import JOINT_NAMES
from nsim.io.images import write_image
from nsim.io.transforms_json import Frame, TransformsData, write_transforms

N, W, H = 4, 32, 24


def _poses(n: int = N, file_paths: bool = True) -> HumanPoses:
    """A walk placed in the world the way the actor capture writes it (root orientation in root_to_world)."""
    clip = walk_cycle(1.3, 1.7)
    T = clip.joint_transforms()[:n]
    q = clip.local_rotations_wxyz[:n].copy()
    q[:, 0] = (1.0, 0.0, 0.0, 0.0)
    names = tuple(f"images/frame_{i:05d}.png" for i in range(n)) if file_paths else (None,) * n
    return HumanPoses(clip.skeleton, 1.7, T[:, 0], q, np.arange(n) / 10.0, names, {"note": "test"})


def _dataset(root, n: int = N):
    """transforms.json, images, masks and poses.json for ``n`` frames; returns the poses."""
    camera = Camera.pinhole_from_fov(W, H, 60.0)
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    rng = np.random.default_rng(0)
    frames = []
    for i in range(n):
        write_image(root / "images" / f"frame_{i:05d}.png", rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        mask = np.zeros((H, W), np.uint8)
        mask[5 + i:15, 10:20] = 255
        write_image(root / "masks" / f"frame_{i:05d}.png", mask)
        frames.append(Frame(f"images/frame_{i:05d}.png", look_at([3.0, i * 0.1, 1.5], [0.0, 0.0, 1.0]), camera))
    write_transforms(root / "transforms.json", TransformsData(frames=frames))
    poses = _poses(n)
    write_poses(root / "poses.json", poses)
    return poses


def _edit_poses(root, edit) -> None:
    data = json.loads((root / "poses.json").read_text())
    edit(data)
    (root / "poses.json").write_text(json.dumps(data))


def test_load_round_trip(tmp_path):
    poses = _dataset(tmp_path)
    data = HumanData.load(tmp_path)
    assert data.num_frames == N and data.skeleton.joint_names == JOINT_NAMES
    # poses.json rounds to 1e-9 (nsim.io.canonical)
    np.testing.assert_allclose(data.poses.local_rotations_wxyz, poses.local_rotations_wxyz, rtol=0, atol=2e-9)
    np.testing.assert_allclose(data.poses.root_to_world, poses.root_to_world, rtol=0, atol=2e-9)
    np.testing.assert_allclose(data.joint_transforms(), poses.joint_transforms(), rtol=0, atol=1e-8)
    np.testing.assert_allclose(data.joint_transforms(), walk_cycle(1.3, 1.7).joint_transforms()[:N], atol=1e-8)
    assert data.poses.meta == {"note": "test"} and data.poses.timestamps_s[2] == pytest.approx(0.2)
    m = data.mask(2)
    assert m.dtype == bool and m.sum() == (15 - 7) * 10
    assert data.image(0).shape == (H, W, 3) and data.background(0) is None
    images, masks, backgrounds = data.read_all()
    assert images.shape == (N, H, W, 3) and images.dtype == np.uint8 and backgrounds is None
    assert masks.shape == (N, H, W) and masks[2].sum() == m.sum()
    assert data.camera() == Camera.pinhole_from_fov(W, H, 60.0)


def test_joints_in_any_order_and_optional_blocks(tmp_path):
    poses = _dataset(tmp_path)
    perm = np.random.default_rng(1).permutation(len(JOINT_NAMES))

    def shuffle(d):
        sk = d["skeleton"]
        inverse = np.argsort(perm)
        sk["parents"] = [int(inverse[sk["parents"][p]]) if sk["parents"][p] >= 0 else -1 for p in perm]
        for key in ("joint_names", "offsets_m", "end_sites_m"):
            sk[key] = [sk[key][p] for p in perm]
        for fr in d["frames"]:
            for key in ("local_rotations_wxyz", "joint_positions_m"):
                fr[key] = [fr[key][p] for p in perm]

    _edit_poses(tmp_path, shuffle)
    np.testing.assert_allclose(HumanData.load(tmp_path).joint_transforms(), poses.joint_transforms(), atol=1e-8)

    def minimal(d):  # names only; no joint positions, timestamps or file paths
        d["skeleton"] = {"joint_names": d["skeleton"]["joint_names"]}
        for fr in d["frames"]:
            for key in ("joint_positions_m", "timestamp", "file_path"):
                fr.pop(key)

    _edit_poses(tmp_path, minimal)
    data = HumanData.load(tmp_path)
    assert np.isnan(data.poses.timestamps_s).all()
    np.testing.assert_allclose(data.poses.skeleton.offsets_m, poses.skeleton.offsets_m, atol=1e-12)


def test_bvh_poses_with_root_transforms(tmp_path):
    poses = _dataset(tmp_path)
    (tmp_path / "poses.json").unlink()
    write_bvh(tmp_path / "poses.bvh", walk_cycle(1.3, 1.7).with_name("walk"))  # more frames than images
    with pytest.raises(InputError, match=r"poses.bvh: \d+ BVH frames but transforms.json has 4 frames"):
        HumanData.load(tmp_path)
    clip = walk_cycle(1.3, 1.7)
    short = MotionClip(clip.skeleton, clip.fps, clip.root_positions_m[:N], clip.local_rotations_wxyz[:N], "walk")
    write_bvh(tmp_path / "poses.bvh", short)
    shift = np.tile(np.eye(4), (N, 1, 1))
    shift[:, :3, 3] = (1.0, 2.0, 0.0)
    (tmp_path / "root_transforms.json").write_text(json.dumps({"root_to_world": shift.tolist()}))
    data = HumanData.load(tmp_path, height_m=1.7)
    expected = poses.joint_positions_m() + (1.0, 2.0, 0.0)
    np.testing.assert_allclose(data.poses.joint_positions_m(), expected, atol=1e-4)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["frames"].pop(), r"poses.json: 3 pose frames but transforms.json has 4 frames"),
        (lambda d: d["frames"][1]["local_rotations_wxyz"][3].__setitem__(0, float("nan")),
         r"poses.json: frames\[1\].local_rotations_wxyz: contains NaN"),
        (lambda d: d["frames"][2]["root_to_world"][0].__setitem__(3, float("nan")),
         r"poses.json: frames\[2\].root_to_world: contains NaN"),
        (lambda d: d["skeleton"]["joint_names"].__setitem__(1, "LeftUpLeg"),
         r"poses.json: skeleton.joint_names: unknown joint 'LeftUpLeg'"),
        (lambda d: d["frames"][0].__setitem__("file_path", "images/other.png"),
         r"poses.json: frames\[0\].file_path: 'images/other.png' does not match transforms.json"),
        (lambda d: d["frames"][3]["joint_positions_m"][7].__setitem__(2, 5.0),
         r"poses.json: frames\[3\].joint_positions_m: joint 'left_ankle' is .* m from"),
        (lambda d: d["frames"][0].__setitem__("local_rotation", []), r"poses.json: frames\[0\]: unknown key"),
        (lambda d: d["skeleton"]["parents"].__setitem__(4, 2),
         r"poses.json: skeleton.parents: joint 'left_knee' has parent 'right_hip'"),
        (lambda d: d["frames"][1]["local_rotations_wxyz"].pop(), r"poses.json: frames\[1\].local_rotations_wxyz: "
                                                                 r"expected shape \(24, 4\)"),
    ],
    ids=["frame-count", "nan-rotation", "nan-root", "unknown-joint", "file-path", "joint-positions", "typo",
         "parents", "shape"],
)
def test_bad_poses_file(tmp_path, edit, message):
    _dataset(tmp_path)
    _edit_poses(tmp_path, edit)
    with pytest.raises(InputError, match=message) as info:
        HumanData.load(tmp_path)
    assert "\n" not in str(info.value)


def test_missing_mask_is_named(tmp_path):
    _dataset(tmp_path)
    (tmp_path / "masks" / "frame_00002.png").unlink()
    with pytest.raises(InputError, match=r"masks/frame_00002.png: person mask of frame 2 \(images/frame_00002.png\) "
                                         r"not found"):
        HumanData.load(tmp_path)


def test_mask_size_must_match_image(tmp_path):
    _dataset(tmp_path)
    write_image(tmp_path / "masks" / "frame_00001.png", np.zeros((12, 16), np.uint8))
    with pytest.raises(InputError, match=r"frame_00001.png: mask is 16x12 but image images/frame_00001.png is 32x24"):
        HumanData.load(tmp_path)


def test_missing_poses_and_images(tmp_path):
    _dataset(tmp_path)
    (tmp_path / "images" / "frame_00003.png").unlink()
    with pytest.raises(InputError, match=r"frame_00003.png: image of frame 3 not found"):
        HumanData.load(tmp_path)
    (tmp_path / "poses.json").unlink()
    with pytest.raises(InputError, match="no per-frame poses: expected poses.json or poses.bvh"):
        HumanData.load(tmp_path)


def test_write_read_poses_to_1e_9(tmp_path):
    """poses.json holds the poses rounded to 1e-9 (nsim.io.canonical: the same bytes on every CPU)."""
    poses = _poses(file_paths=False)
    back = read_poses(write_poses(tmp_path / "p.json", poses))
    for name in ("root_to_world", "local_rotations_wxyz", "timestamps_s"):
        np.testing.assert_allclose(getattr(back, name), getattr(poses, name), rtol=0, atol=2e-9)
    assert back.file_paths == (None,) * N and back.height_m == 1.7


def test_mask_conventions(tmp_path):
    m = np.array([[0, 1], [1, 0]], np.uint8)
    write_image(tmp_path / "binary.png", m)
    np.testing.assert_array_equal(read_mask(tmp_path / "binary.png"), m == 1)
    write_image(tmp_path / "grey.png", np.array([[0, 127], [128, 255]], np.uint8))
    np.testing.assert_array_equal(read_mask(tmp_path / "grey.png"), [[False, False], [True, True]])
    write_image(tmp_path / "rgb.png", np.dstack([m * 255, m * 0, m * 255]))
    with pytest.raises(InputError, match="expected a grey mask"):
        read_mask(tmp_path / "rgb.png")
