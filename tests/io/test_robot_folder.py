"""Recording folders (nsim.io.robot_folder): a bag nsim writes, exported as a folder, reads back as the bag
does (streams, stamps, camera models, extrinsics, trajectory, pixels, clouds); camera_info YAML for every
model; stamps from names and from timestamp files; the rig's three forms and a URDF; each kind of bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry import Camera, make_se3
from nsim.io.images import write_depth_png_mm, write_image, write_png16
from nsim.io.ply import write_ply
from nsim.io.robot_folder import (
    RobotFolder,
    camera_from_info_yaml,
    camera_info_yaml,
    frame_stamps,
    is_robot_folder,
    read_tum_ns,
    stamp_ns,
)
from nsim.io.robot_log import RobotLog
from nsim.io.rosbag import BagWriter, camera_from_info, camera_info_message
from nsim.io.tum import Trajectory
from nsim.sensors import Rig

T0 = 1_700_000_000 * 10**9
TICK = 100_000_123  # not a round number of microseconds: float seconds could not hold these stamps


# ---------------------------------------------------------------------------- writing folders


def write_stamped_tum(path: Path, stamps_ns: np.ndarray, body_to_odom: np.ndarray) -> None:
    """A TUM file whose stamps are exact decimals to the nanosecond, poses as ``repr`` floats."""
    traj = Trajectory.from_poses(np.zeros(len(stamps_ns)), body_to_odom)
    rows = [f"{int(s) // 10**9}.{int(s) % 10**9:09d} " + " ".join(map(repr, [*p, *q[[1, 2, 3, 0]].tolist()]))
            for s, p, q in zip(stamps_ns, traj.positions_xyz.tolist(), traj.orientations_quat_wxyz, strict=True)]
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows) + "\n")


def write_camera_info(path: Path, camera: Camera, name: str = "", depth_m_per_unit: float | None = None) -> None:
    data = camera_info_yaml(camera, name) | ({} if depth_m_per_unit is None else {"depth_m_per_unit": depth_m_per_unit})
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def export_folder(rl, out: Path, *, depth_suffix: str = ".npy", stamps_file: str | None = None) -> Path:
    """Write the open RobotLog ``rl`` as a recording folder (the layout of nsim.io.robot_folder): frames named
    by their stamps in nanoseconds (``stamps_file``: named ``frame_NNN`` with a timestamps file in seconds),
    depth as ``depth_suffix``, clouds as PLY, the rig's extrinsics as 4 x 4 matrices."""
    out.mkdir()
    traj = rl.body_trajectory()
    write_stamped_tum(out / "trajectory.tum", traj.stamps_ns, traj.body_to_odom)
    sensors = {}
    for folder, group in (("cameras", rl.cameras), ("depth", rl.depth)):
        for name, s in group.items():
            d = out / folder / name
            d.mkdir(parents=True)
            write_camera_info(d / "camera_info.yaml", s.camera, name,
                              depth_m_per_unit=0.001 if folder == "depth" and depth_suffix == ".png" else None)
            sensors[name] = {"sensor_to_body": rl.sensor_to_body(s.frame_id).tolist()}
            rows = []
            for i, image in (rl.images(s)):
                stem = f"frame_{i}" if stamps_file else str(s.stamps_ns[i])
                rows.append(f"{s.stamps_ns[i] // 10**9}.{s.stamps_ns[i] % 10**9:09d}")
                if folder == "depth":
                    if depth_suffix == ".png":
                        write_depth_png_mm(d / f"{stem}.png", image)
                    elif depth_suffix == ".exr":
                        from nsim.io.exr import write_depth_exr

                        write_depth_exr(d / f"{stem}.exr", image)
                    else:
                        np.save(d / f"{stem}.npy", image)
                elif image.dtype == np.uint16:
                    write_png16(d / f"{stem}.png", image)
                else:
                    write_image(d / f"{stem}.png", image)
            if stamps_file:
                (d / stamps_file).write_text("\n".join(rows) + "\n")
    for name, s in rl.lidars.items():
        d = out / "lidar" / name
        d.mkdir(parents=True)
        sensors[name] = {"sensor_to_body": rl.sensor_to_body(s.frame_id).tolist()}
        for i, cloud in rl.clouds(s):
            fields = {"intensity": cloud.intensity}
            if cloud.ring is not None:
                fields["ring"] = cloud.ring.astype(np.int32)
            write_ply(d / f"{s.stamps_ns[i]}.ply", cloud.xyz_m, fields=fields)
    rig = {"body_frame": traj.body_frame, "odom_frame": traj.odom_frame, "sensors": sensors}
    (out / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    return out


@pytest.fixture(scope="module")
def rig() -> Rig:
    return Rig.from_data({
        "name": "mini",
        "sensors": [
            {"name": "front", "type": "camera", "mount": {"xyz_m": [0.4, 0.0, 0.1], "rpy_deg": [78.0, 30.0, -20.0]},
             "intrinsics": {"model": "OPENCV_FISHEYE", "width": 16, "height": 12, "preset": "spot_fisheye"}, "depth": True},
            {"name": "wide", "type": "camera", "mount": {"xyz_m": [0.1, 0.0, 0.2]},
             "intrinsics": {"model": "FULL_OPENCV", "width": 8, "height": 6, "fx": 5.0,
                            "dist": [0.1, -0.01, 0.001, 0.002, 0.003, 0.2, 0.01, 0.001]}, "color": "gray"},
            {"name": "lidar", "type": "lidar", "mount": {"xyz_m": [0.0, 0.0, 0.3], "rpy_deg": [0.0, 0.0, 10.0]},
             "lidar": {"channels": 4, "vertical_fov_deg": [-15, 15], "azimuth_samples": 10}},
        ],
    })


@pytest.fixture(scope="module")
def bag(rig, tmp_path_factory) -> Path:
    """A 4-tick bag of the mini rig: a fisheye colour camera with depth, a grey rational camera, a LiDAR."""
    path = tmp_path_factory.mktemp("bag") / "run"
    rng = np.random.default_rng(5)
    with BagWriter(path, rig, time_offset_ns=T0) as bag:
        for k in range(4):
            pose = make_se3(Rotation.from_euler("z", 0.1 * k).as_matrix(), np.array([0.2 * k, 0.1, 0.5]))
            lidar = rig["lidar"]
            scan = lidar.scan(rng.uniform(1, 9, lidar.ray_shape), intensity=rng.uniform(0, 1, lidar.ray_shape))
            depth = rng.uniform(0.2, 5.0, (12, 16)).astype(np.float32)
            depth[0, :3] = np.nan
            bag.write_tick(None, pose, t_ns=TICK * k, images={"front": rng.integers(0, 256, (12, 16, 3), np.uint8),
                                                              "wide": rng.integers(0, 256, (6, 8), np.uint8)},
                           depths={"front": depth}, clouds={"lidar": scan})
    return path


def assert_same_recording(a, b) -> None:
    """Two open readers (RobotLog or RobotFolder) hold the same recording."""
    for group in ("cameras", "depth", "lidars"):
        ga, gb = getattr(a, group), getattr(b, group)
        assert sorted(ga) == sorted(gb), group
        for name in ga:
            sa, sb = ga[name], gb[name]
            np.testing.assert_array_equal(sa.stamps_ns, sb.stamps_ns)
            np.testing.assert_array_equal(a.sensor_to_body(sa.frame_id), b.sensor_to_body(sb.frame_id))
            if group == "lidars":
                assert sa.fields == sb.fields
                for (_, ca), (_, cb) in zip(a.clouds(sa), b.clouds(sb), strict=True):
                    np.testing.assert_array_equal(ca.xyz_m, cb.xyz_m)
                    np.testing.assert_array_equal(ca.intensity, cb.intensity)
                    np.testing.assert_array_equal(ca.ring, cb.ring)
            else:
                assert sa.camera == sb.camera and sa.encoding == sb.encoding and sa.is_depth == sb.is_depth
                for (_, ia), (_, ib) in zip(a.images(sa), b.images(sb), strict=True):
                    assert ia.dtype == ib.dtype
                    np.testing.assert_array_equal(ia, ib)
                np.testing.assert_array_equal(a.image(sa, len(sa) - 1), b.image(sb, len(sb) - 1))
    ta, tb = a.body_trajectory(), b.body_trajectory()
    np.testing.assert_array_equal(ta.stamps_ns, tb.stamps_ns)
    np.testing.assert_allclose(ta.body_to_odom, tb.body_to_odom, rtol=0, atol=1e-12)
    assert (ta.body_frame, ta.odom_frame) == (tb.body_frame, tb.odom_frame)


# ---------------------------------------------------------------------------- the folder reads as the bag


@pytest.mark.parametrize("stamps_file", [None, "timestamps.txt"])
def test_folder_matches_bag(bag, tmp_path, stamps_file):
    with RobotLog(bag) as rl:
        folder = export_folder(rl, tmp_path / "run", stamps_file=stamps_file)
        assert is_robot_folder(folder) and not is_robot_folder(bag)
        with RobotFolder(folder) as rf:
            assert rf.cameras["wide"].camera.model == "FULL_OPENCV"
            assert rf.cameras["front"].camera.model == "OPENCV_FISHEYE"
            assert rf.cameras["front"].encoding == "rgb8" and rf.cameras["wide"].encoding == "mono8"
            assert rf.depth["front"].encoding == "32FC1" and rf.lidars["lidar"].fields == ("x", "y", "z", "intensity",
                                                                                           "ring")
            assert rf.body_trajectory().source == "trajectory.tum"
            np.testing.assert_array_equal(rf.cameras["front"].stamps_ns, T0 + TICK * np.arange(4))
            assert_same_recording(rl, rf)


def _as_tum_depth(folder: Path, stream: str = "front") -> Path:
    """The folder's depth stream rewritten as TUM RGB-D stores depth: 16-bit PNGs at 5000 per metre, listed in a
    ``depth.txt`` (``stamp filename`` in seconds), camera_info.yaml without a unit."""
    import cv2

    from nsim.io.robot_folder import read_depth_frame

    d = folder / "depth" / stream
    info = yaml.safe_load((d / "camera_info.yaml").read_text())
    info.pop("depth_m_per_unit", None)
    (d / "camera_info.yaml").write_text(yaml.safe_dump(info, sort_keys=False))
    rows = ["# depth maps", "# file: 'rgbd_dataset_freiburg1_xyz.bag'", "# timestamp filename"]
    for i, path in enumerate(sorted(d.glob("*.npy"), key=lambda p: int(p.stem))):
        depth_m = read_depth_frame(path, None)
        raw = np.where(np.isfinite(depth_m), np.round(np.nan_to_num(depth_m) * 5000.0), 0).astype(np.uint16)
        cv2.imwrite(str(d / f"frame_{i:03d}.png"), raw)
        rows.append(f"{int(path.stem) // 10**9}.{int(path.stem) % 10**9:09d} depth/frame_{i:03d}.png")
        path.unlink()
    (d / "depth.txt").write_text("\n".join(rows) + "\n")
    return folder


def test_tum_depth_is_metric(bag, tmp_path, caplog):
    """TUM RGB-D's 16-bit depth is 1/5000 m (depth.txt beside it says so): read as metres, not as millimetres."""
    with RobotLog(bag) as rl:
        want = rl.image(rl.depth["front"], 2)
        folder = _as_tum_depth(export_folder(rl, tmp_path / "tum"))
    with caplog.at_level("INFO", logger="nsim.io.robot_folder"), RobotFolder(folder) as rf:
        stream = rf.depth["front"]
        got = rf.image(stream, 2)
    assert stream.depth_unit.m_per_unit == pytest.approx(1 / 5000) and "depth.txt" in stream.depth_unit.source
    assert any("0.0002 m per unit" in r.getMessage() and "TUM" in r.getMessage() for r in caplog.records)
    np.testing.assert_array_equal(np.isnan(got), ~np.isfinite(want))
    np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], rtol=0, atol=1 / 10000 + 1e-6)


@pytest.mark.parametrize(("change", "message"), [
    ({"drop_tum": True}, r"depth/front: 16-bit PNG depth without its unit: add depth_m_per_unit to camera_info.yaml"),
    ({"depth_scale": 5000}, r"camera_info.yaml: depth_scale is ambiguous"),
    ({"depth_m_per_unit": 0}, r"camera_info.yaml: depth_m_per_unit must be a positive number of metres per unit, got 0"),
    ({"depth_m_per_unit": -0.001}, r"must be a positive number"),
    ({"depth_m_per_unit": "mm"}, r"must be a positive number"),
    ({"depth_m_per_unit": True}, r"must be a positive number"),
    ({"depth_m_per_unit": 0.001}, r"depth_m_per_unit 0.001 disagrees with depth.txt"),
])
def test_depth_unit_errors(bag, tmp_path, change, message):
    with RobotLog(bag) as rl:
        folder = _as_tum_depth(export_folder(rl, tmp_path / "f"))
    d = folder / "depth" / "front"
    if change.pop("drop_tum", False):
        rows = (d / "depth.txt").read_text().splitlines()[3:]
        (d / "timestamps.txt").write_text("\n".join(rows) + "\n")
        (d / "depth.txt").unlink()
    info = yaml.safe_load((d / "camera_info.yaml").read_text()) | change
    (d / "camera_info.yaml").write_text(yaml.safe_dump(info, sort_keys=False))
    with pytest.raises(InputError, match=message):
        RobotFolder(folder)


def test_depth_unit_for_float_frames_is_refused(bag, tmp_path):
    with RobotLog(bag) as rl:
        folder = export_folder(rl, tmp_path / "exr", depth_suffix=".exr")
    info_path = folder / "depth" / "front" / "camera_info.yaml"
    info_path.write_text(yaml.safe_dump(yaml.safe_load(info_path.read_text()) | {"depth_m_per_unit": 0.001}))
    with pytest.raises(InputError, match="depth_m_per_unit is for 16-bit PNG depth; .exr frames are metres"):
        RobotFolder(folder)


def test_depth_formats(bag, tmp_path):
    with RobotLog(bag) as rl:
        want = rl.image(rl.depth["front"], 1)
        for suffix in (".png", ".exr"):
            with RobotFolder(export_folder(rl, tmp_path / suffix[1:], depth_suffix=suffix)) as rf:
                got = rf.image(rf.depth["front"], 1)
                assert got.dtype == np.float32 and rf.depth["front"].encoding == {".png": "16UC1", ".exr": "32FC1"}[suffix]
                np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
                tol = 0.0005 if suffix == ".png" else 0.0  # whole millimetres
                np.testing.assert_allclose(got, want, rtol=0, atol=tol + 1e-7)


# ---------------------------------------------------------------------------- camera_info YAML

CAMERAS = {
    "pinhole": Camera("PINHOLE", 640, 480, 500.0, 501.0, 319.5, 239.5),
    "plumb_bob": Camera("OPENCV", 640, 480, 500.0, 501.0, 320.1, 240.2, (-0.28, 0.07, 1e-4, -2e-4, 0.01)),
    "rational": Camera("FULL_OPENCV", 320, 240, 250.0, 250.0, 160.0, 120.0, (0.1, -0.01, 1e-3, 2e-3, 3e-3, 0.2, 0.01, 1e-3)),
    "fisheye": Camera("OPENCV_FISHEYE", 64, 48, 20.0, 20.5, 31.5, 23.5, (0.01, -0.002, 3e-4, -1e-5)),
}


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_camera_info_yaml_round_trip_and_bag_mapping(name):
    camera = CAMERAS[name]
    data = yaml.safe_load(yaml.safe_dump(camera_info_yaml(camera, name)))
    assert camera_from_info_yaml(data) == camera
    assert camera_from_info(camera_info_message(0, name, camera)) == camera  # the bag's mapping, the same camera


def test_camera_calibration_file():
    """A file as ROS's camera_calibration writes it (its own example, ost.yaml)."""
    text = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [430.15, 0, 306.27, 0, 430.17, 220.4, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.337, 0.1164, 0.00065, -0.00012, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [300.2, 0, 307.3, 0, 0, 382.2, 219.8, 0, 0, 0, 1, 0]
"""
    assert camera_from_info_yaml(yaml.safe_load(text)) == Camera(
        "OPENCV", 640, 480, 430.15, 430.17, 306.27, 220.4, (-0.337, 0.1164, 0.00065, -0.00012, 0.0))


@pytest.mark.parametrize("edit, words", [
    ({"distortion_model": "kannala_brandt"}, "unknown distortion model 'kannala_brandt'"),
    ({"camera_matrx": None}, "did you mean 'camera_matrix'"),
    ({"camera_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0]}}, "camera_matrix: expected rows 3, cols 3"),
    ({"image_width": -4}, "image_width and image_height"),
    ({"distortion_coefficients": {"rows": 1, "cols": 3, "data": [0.1, 0.0, 0.0]}}, "plumb_bob needs"),
])
def test_camera_info_yaml_errors(edit, words):
    data = camera_info_yaml(CAMERAS["plumb_bob"], "x") | edit
    with pytest.raises(InputError, match=words) as err:
        camera_from_info_yaml(data, "cam/camera_info.yaml")
    assert str(err.value).startswith("cam/camera_info.yaml") and "\n" not in str(err.value)


# ---------------------------------------------------------------------------- stamps


def test_stamps_are_exact():
    assert stamp_ns("1700000000123456789", "x") == 1700000000123456789
    assert stamp_ns("1700000000.123456789", "x") == 1700000000123456789
    assert stamp_ns("1305031102.175304", "x") == 1305031102175304000  # TUM RGB-D: float64 would be 256 ns off
    assert stamp_ns("1.5e9", "x") == 1_500_000_000 * 10**9
    assert stamp_ns("12", "x", unit="s") == 12 * 10**9
    with pytest.raises(InputError, match=r"^t.txt:3: 'abc' is not a timestamp"):
        stamp_ns("abc", "t.txt:3")


def test_frame_stamps_from_names_and_tables(tmp_path):
    d = tmp_path / "cam"
    d.mkdir()
    for name in ("img_2.png", "img_10.png", "img_1.png", "notes.md"):
        (d / name).write_bytes(b"")
    (d / "timestamps.txt").write_text("# stamps\n100\n\n1.000000200\n1000000300\n")
    files, stamps = frame_stamps(d, (".png",))
    assert [f.name for f in files] == ["img_1.png", "img_2.png", "img_10.png"]  # natural order
    assert stamps.tolist() == [100, 1_000_000_200, 1_000_000_300]
    (d / "timestamps.txt").unlink()
    (d / "times.csv").write_text("#timestamp [ns],filename\n5,img_10.png\n7,cam/img_2.png\n9,img_1.png\n")
    files, stamps = frame_stamps(d, (".png",))  # EuRoC's data.csv: the rows give the order
    assert [f.name for f in files] == ["img_10.png", "img_2.png", "img_1.png"] and stamps.tolist() == [5, 7, 9]
    e = tmp_path / "named"
    e.mkdir()
    for name in ("1305031102.175304.png", "1305031102.211214.png"):
        (e / name).write_bytes(b"")
    files, stamps = frame_stamps(e, (".png",))
    assert stamps.tolist() == [1305031102175304000, 1305031102211214000]


def test_tum_stamps_to_the_nanosecond_and_repeats(tmp_path, caplog):
    path = tmp_path / "t.tum"
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.0]
    want = [T0 + 1, T0 + 1_000_002, T0 + 2_000_003]  # microseconds apart, to the nanosecond
    write_stamped_tum(path, np.array(want), poses)
    stamps, body_to_odom = read_tum_ns(path)
    assert stamps.tolist() == want
    np.testing.assert_array_equal(body_to_odom, poses)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], lines[1], lines[2], lines[2], lines[3]]) + "\n")  # a repeated stamp
    stamps, body_to_odom = read_tum_ns(path)
    assert stamps.tolist() == want and "repeat" in caplog.text


# ---------------------------------------------------------------------------- the rig


def test_rig_forms_and_urdf(tmp_path):
    sensor_to_body = make_se3(Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix(), np.array([0.4, -0.1, 0.25]))
    q_xyzw = Rotation.from_matrix(sensor_to_body[:3, :3]).as_quat()
    t = sensor_to_body[:3, 3].tolist()
    forms = {"a": {"sensor_to_body": sensor_to_body.tolist()},
             "b": {"translation_m": t, "quaternion_xyzw": q_xyzw.tolist()},
             "c": {"translation_m": t, "quaternion_wxyz": np.roll(q_xyzw, 1).tolist()}}
    root = tiny_folder(tmp_path / "run", names=tuple(forms))
    (root / "rig.yaml").write_text(yaml.safe_dump({"sensors": forms}))
    with RobotFolder(root) as rf:
        for name in forms:
            np.testing.assert_allclose(rf.sensor_to_body(name), sensor_to_body, rtol=0, atol=1e-12)
        assert (rf.body_frame, rf.odom_frame) == ("body", "odom")
    (root / "rig.yaml").unlink()
    rpy = Rotation.from_matrix(sensor_to_body[:3, :3]).as_euler("xyz")
    joints = "".join(f'<link name="{n}"/><joint name="j_{n}" type="fixed"><parent link="mount"/><child link="{n}"/>'
                     f'<origin xyz="{t[0]} {t[1]} {t[2] - 0.5}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/></joint>'
                     for n in forms)
    (root / "rig.urdf").write_text(
        '<robot name="r"><link name="base_link"/><link name="mount"/><joint name="m" type="fixed">'
        f'<parent link="base_link"/><child link="mount"/><origin xyz="0 0 0.5"/></joint>{joints}</robot>')
    with RobotFolder(root) as rf:
        assert rf.body_frame == "base_link"
        for name in forms:
            np.testing.assert_allclose(rf.sensor_to_body(name), sensor_to_body, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- bad input: one line each

TINY = Camera("OPENCV", 8, 6, 6.0, 6.0, 3.5, 2.5, (0.01, 0.0, 0.0, 0.0, 0.0))


def tiny_folder(root: Path, names: tuple[str, ...] = ("cam",), n: int = 3) -> Path:
    """A small valid folder: ``n`` 8 x 6 colour frames per camera named by stamp, a TUM trajectory, a rig."""
    rng = np.random.default_rng(0)
    for name in names:
        d = root / "cameras" / name
        d.mkdir(parents=True)
        write_camera_info(d / "camera_info.yaml", TINY, name)
        for k in range(n):
            write_image(d / f"{T0 + k * TICK}.png", rng.integers(0, 256, (6, 8, 3), np.uint8))
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * 0.1
    write_stamped_tum(root / "trajectory.tum", T0 + TICK * np.arange(n), poses)
    rig = {"sensors": {name: {"translation_m": [0.1, 0, 0.2], "quaternion_wxyz": [1, 0, 0, 0]} for name in names}}
    (root / "rig.yaml").write_text(yaml.safe_dump(rig))
    return root


def _rewrite(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new))


def _frames(root: Path) -> list[Path]:
    return sorted((root / "cameras" / "cam").glob("*.png"))


BAD = {
    "no trajectory": (lambda r: (r / "trajectory.tum").unlink(), "trajectory.tum: no such file"),
    "no camera_info": (lambda r: (r / "cameras/cam/camera_info.yaml").unlink(), "cameras/cam/camera_info.yaml: no such"),
    "unknown distortion model": (lambda r: _rewrite(r / "cameras/cam/camera_info.yaml", "plumb_bob", "radtan"),
                                 "camera_info.yaml: unknown distortion model 'radtan'"),
    "no rig": (lambda r: (r / "rig.yaml").unlink(), "no rig.yaml or rig.urdf"),
    "sensor missing from the rig": (lambda r: _rewrite(r / "rig.yaml", "cam:", "camera:"), "rig.yaml: no sensor 'cam'"),
    "bad rig key": (lambda r: _rewrite(r / "rig.yaml", "translation_m", "translation"),
                    "rig.yaml.sensors.cam: unknown key 'translation' (did you mean 'translation_m'?)"),
    "non-monotonic timestamps": (lambda r: (r / "cameras/cam/timestamps.txt").write_text("10\n30\n20\n"),
                                 "cameras/cam/timestamps.txt:3: timestamp 20 ns is not after"),
    "timestamp count": (lambda r: (r / "cameras/cam/timestamps.txt").write_text("10\n30\n"),
                        "cameras/cam/timestamps.txt: 2 timestamps for 3 frames"),
    "unnamed frame": (lambda r: _frames(r)[0].rename(_frames(r)[0].with_name("first.png")),
                      "first.png: not named by its timestamp"),
    "same stamp twice": (lambda r: shutil.copy(_frames(r)[1], _frames(r)[1].with_name("0" + _frames(r)[1].name)),
                         "the same timestamp as"),
    "first image does not decode": (lambda r: _frames(r)[0].write_bytes(b"not a png"), "png: the compressed image"),
    "wrong size": (lambda r: write_image(_frames(r)[0], np.zeros((5, 8, 3), np.uint8)),
                   "the image is 8x5, its camera_info (cameras/cam/camera_info.yaml) says 8x6"),
    "grey after colour": (lambda r: write_image(_frames(r)[0], np.zeros((6, 8), np.uint8)), "rgb8, the stream began with mono8"),
    "no streams": (lambda r: (r / "cameras").rename(r / "camera"), "no stream folders"),
    "tum": (lambda r: _rewrite(r / "trajectory.tum", " 1.0\n", " 2.0\n"), "trajectory.tum:2: quaternion is not unit"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_names_the_file(tmp_path, case):
    root = tiny_folder(tmp_path / "run")
    edit, words = BAD[case]
    edit(root)
    with pytest.raises(InputError) as err:
        with RobotFolder(root) as rf:
            rf.sensor_to_body(rf.cameras["cam"].frame_id)
            for _ in rf.images(rf.cameras["cam"]):
                pass
    message = str(err.value)
    assert words in message and "\n" not in message, message
    assert message.startswith(str(root)) or message.startswith(str(tmp_path)), message


def test_a_later_frame_that_does_not_decode_fails_when_read(tmp_path):
    root = tiny_folder(tmp_path / "run")
    _frames(root)[2].write_bytes(b"\x89PNG broken")
    with RobotFolder(root) as rf:  # the first frame is fine: opening works
        stream = rf.cameras["cam"]
        rf.image(stream, 1)
        with pytest.raises(InputError, match=rf"^{_frames(root)[2]}: the compressed image .* does not decode"):
            rf.image(stream, 2)
        with pytest.raises(InputError, match="trajectory=tf reads a bag's topics"):
            rf.body_trajectory("tf")


def test_links_out_of_the_folder_are_refused(tmp_path):
    root = tiny_folder(tmp_path / "run")
    outside = tmp_path / "elsewhere.png"
    _frames(root)[1].rename(outside)
    (root / "cameras" / "cam" / f"{T0 + TICK}.png").symlink_to(outside)
    with pytest.raises(InputError, match="links outside the recording folder"):
        RobotFolder(root)
