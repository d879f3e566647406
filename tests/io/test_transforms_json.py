"""nerfstudio transforms.json: exact round trips, nerfstudio's OpenGL convention, malformed input."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import make_se3
from nsim.io.transforms_json import (
    Frame,
    TransformsData,
    declared_world,
    depth_unit_scale,
    linked_files,
    read_transforms,
    write_transforms,
)

CAMERAS = {
    "pinhole": Camera("PINHOLE", 640, 480, 500.123456789, 501.987654321, 319.7, 240.3),
    "opencv": Camera("OPENCV", 640, 480, 480.5, 481.25, 321.1, 238.9, (-0.11, 0.023, 1.5e-4, -3.3e-4)),
    "opencv_k3": Camera("OPENCV", 640, 480, 480.5, 481.25, 321.1, 238.9, (-0.11, 0.023, 1.5e-4, -3.3e-4, 1e-3)),
    "fisheye": Camera.fisheye_spot_like(),
    "full_opencv": Camera("FULL_OPENCV", 640, 480, 480.5, 481.25, 321.1, 238.9,
                          (0.31, -0.12, 1.5e-4, -3.3e-4, 0.01, 0.62, -0.05, 0.02)),
    "equirect": Camera.equirect(2048, 1024),
}


def _frames(cameras: list[Camera], seed: int = 0) -> list[Frame]:
    rng = np.random.default_rng(seed)
    poses = make_se3(Rotation.random(len(cameras), random_state=rng).as_matrix(), rng.normal(size=(len(cameras), 3)))
    return [Frame(f"images/frame_{i:05d}.png", pose, cam) for i, (pose, cam) in enumerate(zip(poses, cameras, strict=True))]


def _assert_same(a: TransformsData, b: TransformsData) -> None:
    assert len(a.frames) == len(b.frames)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        # poses are written rounded to 1e-9 (nsim.io.canonical: the same bytes on every CPU)
        np.testing.assert_allclose(fa.cam_to_world, fb.cam_to_world, rtol=0, atol=1e-9)
        assert fa.camera == fb.camera
        assert (fa.file_path, fa.depth_file_path, fa.mask_path, fa.timestamp_s, fa.extra) == (
            fb.file_path, fb.depth_file_path, fb.mask_path, fb.timestamp_s, fb.extra)
    assert a.extra == b.extra
    if a.applied_transform is None:
        assert b.applied_transform is None
    else:
        np.testing.assert_allclose(a.applied_transform, b.applied_transform, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", list(CAMERAS))
def test_round_trip_shared_camera(tmp_path, name):
    data = TransformsData(_frames([CAMERAS[name]] * 4))
    path = write_transforms(tmp_path / "transforms.json", data)
    _assert_same(read_transforms(path), data)
    raw = json.loads(path.read_text())
    assert raw["camera_model"] == CAMERAS[name].model and "fl_x" in raw and "w" in raw  # shared: top level
    assert all(set(f) == {"file_path", "transform_matrix"} for f in raw["frames"])


def test_round_trip_per_frame_cameras_and_optional_fields(tmp_path):
    cams = [CAMERAS["opencv"], CAMERAS["opencv"].scaled(0.5), CAMERAS["fisheye"], CAMERAS["pinhole"]]
    frames = _frames(cams, seed=1)
    frames[0] = Frame(frames[0].file_path, frames[0].cam_to_world, frames[0].camera, depth_file_path="depth/0.exr",
                      mask_path="masks/0.png", timestamp_s=0.033333333333333333, extra={"colmap_im_id": 7})
    data = TransformsData(frames, applied_transform=np.arange(12.0).reshape(3, 4) / 7,
                          extra={"ply_file_path": "sparse_pc.ply", "aabb_scale": 16})
    path = write_transforms(tmp_path / "transforms.json", data)
    _assert_same(read_transforms(path), data)
    raw = json.loads(path.read_text())
    assert "fl_x" not in raw and "camera_model" not in raw  # differ between frames
    assert raw["frames"][0]["camera_model"] == "OPENCV" and raw["frames"][0]["colmap_im_id"] == 7


def test_shared_keys_go_to_top_level(tmp_path):
    a = CAMERAS["opencv"]
    b = Camera("OPENCV", a.width, a.height, a.fx * 1.01, a.fy * 1.01, a.cx, a.cy, a.dist)
    raw = json.loads(write_transforms(tmp_path / "t.json", TransformsData(_frames([a, b]))).read_text())
    assert {"camera_model", "w", "h", "cx", "cy", "k1", "k2", "p1", "p2"} <= raw.keys()
    assert "fl_x" not in raw and all("fl_x" in f and "w" not in f for f in raw["frames"])


NERFSTUDIO_FILE = {
    "w": 640, "h": 480, "fl_x": 500.0, "fl_y": 500.0, "cx": 320.0, "cy": 240.0,
    "k1": -0.1, "k2": 0.01, "p1": 0.0, "p2": 0.0, "camera_model": "OPENCV",
    "frames": [
        {
            "file_path": "images/frame_00001.png",
            # OpenGL camera at (1, 2, 3) looking along world -z, camera +y = world +y
            "transform_matrix": [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0], [0.0, 0.0, 0.0, 1.0]],
            "colmap_im_id": 1,
        },
        {
            "file_path": "images/frame_00002.png",
            # OpenGL camera at the origin looking along world +x with world z up: cam x = -y_w, y = z_w, z = -x_w
            "transform_matrix": [[0.0, 0.0, -1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
            "colmap_im_id": 2,
        },
    ],
    "applied_transform": [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]],
    "ply_file_path": "sparse_pc.ply",
}


def test_reads_nerfstudio_file(tmp_path):
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(NERFSTUDIO_FILE, indent=4))
    data = read_transforms(path)
    f0, f1 = data.frames
    np.testing.assert_array_equal(f0.cam_to_world, [[1, 0, 0, 1], [0, -1, 0, 2], [0, 0, -1, 3], [0, 0, 0, 1]])
    np.testing.assert_array_equal(f1.cam_to_world[:3, 2], [1.0, 0.0, 0.0])  # optical axis = world +x
    np.testing.assert_array_equal(f1.cam_to_world[:3, 1], [0.0, 0.0, -1.0])  # image down = world -z
    assert f0.camera == Camera("OPENCV", 640, 480, 500.0, 500.0, 319.5, 239.5, (-0.1, 0.01, 0.0, 0.0))
    assert f0.extra == {"colmap_im_id": 1}
    assert data.extra == {"ply_file_path": "sparse_pc.ply"}
    assert data.applied_transform.shape == (3, 4)
    out = json.loads(write_transforms(tmp_path / "out.json", data).read_text())
    assert out["frames"] == NERFSTUDIO_FILE["frames"]
    assert {k: out[k] for k in NERFSTUDIO_FILE if k != "frames"} == {k: v for k, v in NERFSTUDIO_FILE.items() if k != "frames"}


def test_missing_camera_model_defaults(tmp_path):
    meta = {k: v for k, v in NERFSTUDIO_FILE.items() if k not in ("camera_model", "k1", "k2", "p1", "p2")}
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(meta))
    assert read_transforms(path).frames[0].camera.model == "PINHOLE"
    path.write_text(json.dumps(meta | {"k1": 0.1}))
    assert read_transforms(path).frames[0].camera.model == "OPENCV"


def _set(path: list, value):
    def mutate(meta):
        target = meta
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return mutate


def _delete(path: list):
    def mutate(meta):
        target = meta
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]
    return mutate


SCALED = [[2.0, 0.0, 0.0, 0.0], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
NAN_POSE = [[math.nan, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


@pytest.mark.parametrize(
    "mutate, message",
    [
        (_delete(["frames"]), "frames: missing"),
        (_set(["frames"], {}), "frames: expected a list"),
        (_set(["frames", 1], "x.png"), "frames[1]: expected an object"),
        (_delete(["frames", 1, "transform_matrix"]), "frames[1].transform_matrix: missing"),
        (_delete(["frames", 0, "file_path"]), "frames[0].file_path: missing"),
        (_set(["frames", 1, "transform_matrix"], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
         "frames[1].transform_matrix: expected a 4x4 matrix"),
        (_set(["frames", 1, "transform_matrix"], [[1.0, 0.0], "abc"]), "frames[1].transform_matrix: expected a matrix"),
        (_set(["frames", 1, "transform_matrix"], NAN_POSE), "frames[1].transform_matrix: contains NaN"),
        (_set(["frames", 1, "transform_matrix"], SCALED), "frames[1].transform_matrix: upper-left 3x3 is not a rotation"),
        (_set(["frames", 0, "transform_matrix", 3], [0.0, 0.0, 1.0, 1.0]), "frames[0].transform_matrix: last row"),
        (_set(["camera_model"], "KB8"), "camera_model: unknown camera_model 'KB8'"),
        (_set(["frames", 1, "camera_model"], "FOV"), "frames[1].camera_model: unknown camera_model"),
        (_delete(["fl_x"]), "frames[0].fl_x: missing"),
        (_set(["fl_y"], -5.0), "fl_y: focal length must be > 0"),
        (_set(["frames", 1, "w"], 640.5), "frames[1].w: expected a positive integer"),
        (_set(["cx"], "320"), "cx: expected a number"),
        (_set(["k4"], 0.1), "k4: camera_model OPENCV has no k4 coefficient"),
        (_set(["frames", 0, "timestamp"], "noon"), "frames[0].timestamp: expected a number"),
        (_set(["applied_transform"], [[1.0, 0.0]]), "applied_transform: expected a 3x4 or 4x4 matrix"),
    ],
)
def test_malformed_input_names_file_and_field(tmp_path, mutate, message):
    meta = json.loads(json.dumps(NERFSTUDIO_FILE))
    mutate(meta)
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(meta))
    with pytest.raises(InputError) as info:
        read_transforms(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


def test_missing_file_and_bad_json(tmp_path):
    with pytest.raises(InputError, match="transforms.json: file not found"):
        read_transforms(tmp_path / "transforms.json")
    path = tmp_path / "transforms.json"
    path.write_text('{"frames": [}')
    with pytest.raises(InputError, match=r"transforms.json: invalid JSON at line 1 column 13"):
        read_transforms(path)
    path.write_text("[]")
    with pytest.raises(InputError, match="expected a JSON object"):
        read_transforms(path)


def test_write_rejects_reserved_extra_keys(tmp_path):
    with pytest.raises(ValueError, match="reserved"):
        write_transforms(tmp_path / "t.json", TransformsData([], extra={"frames": []}))
    assert not (tmp_path / "t.json").exists()


# ---------------------------------------------------------------------------- the files frames name

def _touch(path, content: bytes = b"x"):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(content)
    return path


def _with_paths(tmp_path, file_paths, **top):
    cam = CAMERAS["pinhole"]
    frames = [Frame(fp, np.eye(4), cam, **({"depth_file_path": "d/0.png"} if i == 0 else {}))
              for i, fp in enumerate(file_paths)]
    (tmp_path / "scan").mkdir()
    return write_transforms(tmp_path / "scan" / "transforms.json", TransformsData(frames, extra=top))


def test_linked_files_resolve_suffixes_in_nerfstudio_order(tmp_path):
    path = _with_paths(tmp_path, ["./train/r_0", "train/r_1", "train/r_2.png"], ply_file_path="pc.ply")
    scan = path.parent
    for name in ("train/r_0.jpg", "train/r_0.png", "train/r_1.JPG", "d/0.png"):
        _touch(scan / name)
    frames, ply = linked_files(path, read_transforms(path))
    assert [f.image.rel for f in frames] == ["train/r_0.png", "train/r_1.JPG", "train/r_2.png"]
    assert frames[0].image.path == (scan / "train/r_0.png").resolve() and frames[2].image.path is None  # missing
    assert frames[0].depth.rel == "d/0.png" and frames[1].depth is None and frames[0].mask is None
    assert ply.where == "ply_file_path" and ply.path is None and ply.rel == "pc.ply"


def test_linked_files_relative_to_the_root(tmp_path):
    path = _with_paths(tmp_path, ["../shared/a.png", "b.png"])
    _touch(tmp_path / "shared/a.png")
    _touch(path.parent / "b.png")
    with pytest.raises(InputError, match=r"frames\[0\].file_path: ../shared/a.png resolves outside"):
        linked_files(path, read_transforms(path))
    frames, _ = linked_files(path, read_transforms(path), root=tmp_path)
    assert [f.image.rel for f in frames] == ["shared/a.png", "scan/b.png"]


def test_depth_unit_scale(tmp_path):
    data = TransformsData([])
    assert depth_unit_scale("t.json", data, ["d/0.png", "d/1.png"]) == 1e-3  # nerfstudio's millimetre PNGs
    assert depth_unit_scale("t.json", data, ["d/0.exr"]) == 1.0  # nsim's EXRs in metres
    assert depth_unit_scale("t.json", TransformsData([], extra={"depth_unit_scale_factor": 0.5}), ["d.png"]) == 0.5
    with pytest.raises(InputError, match="partly EXR"):
        depth_unit_scale("t.json", data, ["d/0.exr", "d/1.png"])
    with pytest.raises(InputError, match="t.json: depth_unit_scale_factor: expected a number > 0"):
        depth_unit_scale("t.json", TransformsData([], extra={"depth_unit_scale_factor": 0}), ["d.png"])


@pytest.mark.parametrize("extra, declared", [
    ({}, (None, False)),
    ({"aabb_scale": 16, "orientation_override": "none"}, (None, False)),  # PolyCam via nerfstudio: not declared
    ({"nsim_capture": "capture"}, ("an nsim capture (nsim_capture)", True)),
    ({"nsim_scale": "camera_height", "nsim_metric": True, "nsim_z_up": True}, ("nsim_metric: true", True)),
    ({"nsim_scale": "arbitrary", "nsim_metric": False, "nsim_z_up": True}, (None, True)),
    ({"nsim_scale": "reference"}, ("nsim_scale: reference", False)),  # written before nsim_metric
])
def test_declared_world(extra, declared):
    assert declared_world("t.json", TransformsData([], extra=extra)) == declared


def test_declared_world_rejects_non_booleans():
    with pytest.raises(InputError, match="t.json: nsim_metric: expected true or false"):
        declared_world("t.json", TransformsData([], extra={"nsim_metric": "yes"}))


def test_written_poses_are_canonical(tmp_path):
    """Poses one last bit apart (as two CPUs compute them) write the same bytes; no -0 in the file."""
    data = TransformsData(_frames([CAMERAS["pinhole"]] * 3))
    nudged = TransformsData([dataclasses.replace(f, cam_to_world=np.nextafter(f.cam_to_world, np.inf))
                             for f in data.frames])
    a = write_transforms(tmp_path / "a.json", data).read_bytes()
    b = write_transforms(tmp_path / "b.json", nudged).read_bytes()
    assert a == b and b"-0.0," not in a and b"-0.0\n" not in a
