"""The reconstruction's input readers and report helpers (nsim.sfm.reconstruction): a known camera from
YAML, JSON or a transforms.json, bad camera files as one-line errors naming the file, the scale inputs
(a reference named by file name only), report.json's values and each image's status."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.transforms_json import Frame, TransformsData, write_transforms
from nsim.io.tum import Trajectory, write_tum
from nsim.sfm.frames import NOT_REGISTERED, POSE_JUMP, USED
from nsim.sfm.reconstruction import image_status, jsonable, load_known_camera, scale_inputs

CAMERA = {"model": "PINHOLE", "width": 64, "height": 48, "fx": 50.0, "fy": 51.0, "cx": 31.5, "cy": 23.5, "dist": []}


def test_known_camera_from_yaml_json_and_transforms(tmp_path):
    want = Camera.from_dict(CAMERA)
    (tmp_path / "cam.yaml").write_text("\n".join(f"{k}: {v}" for k, v in CAMERA.items()) + "\n")
    (tmp_path / "cam.json").write_text(json.dumps(CAMERA))
    frames = [Frame(file_path=f"images/{k}.png", cam_to_world=np.eye(4), camera=want) for k in range(2)]
    write_transforms(tmp_path / "transforms.json", TransformsData(frames=frames))
    for name in ("cam.yaml", "cam.json", "transforms.json"):
        assert load_known_camera(tmp_path / name).to_dict() == want.to_dict(), name
    assert load_known_camera(None) is None


def test_bad_camera_files_are_one_line_errors_naming_the_file(tmp_path):
    cases = {
        "broken.json": ('{"model": "OPENCV",', "malformed JSON at line 1"),
        "list.json": ("[1, 2, 3]", "expected a camera mapping"),
        "short.json": (json.dumps({"model": "PINHOLE", "width": 4}), "not a camera: camera: missing keys"),
        "extra.yaml": ("\n".join(f"{k}: {v}" for k, v in {**CAMERA, "lens": 3}.items()), "unknown keys"),
    }
    for name, (text, message) in cases.items():
        path = tmp_path / name
        path.write_text(text)
        with pytest.raises(InputError) as err:
            load_known_camera(path)
        assert str(err.value).startswith(str(path)) and message in str(err.value), name
        assert "\n" not in str(err.value)


def test_scale_inputs_name_the_reference_by_file_name(tmp_path):
    t = np.arange(4, dtype=float)
    xyz = np.column_stack([t, 2 * t, np.zeros(4)])
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    write_tum(tmp_path / "odometry.tum", Trajectory(t, xyz, quat))
    reference, kd = scale_inputs(tmp_path / "odometry.tum", (0, 0, 0, 3, 4, 0, 2.5))
    assert reference.source == "odometry.tum"  # where the file lies must not change the artifact's bytes
    np.testing.assert_allclose(reference.cam_to_world[:, :3, 3], xyz)
    a, b, metres = kd
    assert a.tolist() == [0, 0, 0] and b.tolist() == [3, 4, 0] and metres == 2.5
    assert scale_inputs(None, None) == (None, None)


def test_report_values_and_image_status():
    value = {1: np.float32(0.5), "xs": np.arange(3), "t": (np.int64(7), float("nan"), float("inf")), "s": "ok"}
    assert jsonable(value) == {"1": 0.5, "xs": [0, 1, 2], "t": [7, None, None], "s": "ok"}
    json.dumps(jsonable(value), allow_nan=False)  # strict JSON
    stats = {"rejected": ["b.png"], "unregistered": ["c.png"]}
    assert [image_status(n, stats) for n in ("a.png", "b.png", "c.png")] == [USED, POSE_JUMP, NOT_REGISTERED]
    assert image_status("a.png", {}) == USED
