"""URDF link frames: fixed chains, moving joints, the rpy convention, and one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry import invert_se3, is_rotation
from nsim.sensors.urdf import load_urdf, rpy_to_matrix

SPOT_URDF = Path(__file__).resolve().parents[2] / "nsim" / "configs" / "robots" / "spot_like.urdf"


def test_rpy_matches_fixed_axis_xyz_euler():
    rng = np.random.default_rng(0)
    for rpy in rng.uniform(-np.pi, np.pi, size=(20, 3)):
        ref = Rotation.from_euler("xyz", rpy).as_matrix()  # extrinsic x, y, z = Rz @ Ry @ Rx
        np.testing.assert_allclose(rpy_to_matrix(rpy), ref, atol=1e-12)
    np.testing.assert_allclose(rpy_to_matrix([0, 0, np.pi / 2]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rpy_to_matrix([0, np.pi / 2, 0]) @ [1, 0, 0], [0, 0, -1], atol=1e-12)  # pitch down


def test_spot_like_links_and_root():
    urdf = load_urdf(SPOT_URDF)
    assert urdf.robot_name == "spot_like" and urdf.root_link == "body"
    for link in ("frontleft_fisheye", "frontright_fisheye", "left_fisheye", "right_fisheye", "back_fisheye", "lidar"):
        assert link in urdf.links
        assert is_rotation(urdf.link_to_root(link)[:3, :3])
    np.testing.assert_allclose(urdf.link_to_root("body"), np.eye(4))


def test_fixed_chain_composes():
    urdf = load_urdf(SPOT_URDF)
    expected = np.eye(4)
    expected[:3, 3] = [-0.05, 0.0, 0.09 + 0.13]  # body -> rail -> lidar
    np.testing.assert_allclose(urdf.link_to_root("lidar"), expected, atol=1e-12)


def test_origin_is_rpy_then_xyz():
    urdf = load_urdf(SPOT_URDF)
    pose = urdf.link_to_root("frontleft_fisheye")
    np.testing.assert_allclose(pose[:3, 3], [0.415, 0.037, 0.02])
    ref = Rotation.from_euler("xyz", np.radians([78.0, 30.0, -20.0])).as_matrix()
    np.testing.assert_allclose(pose[:3, :3], ref, atol=1e-8)


def test_continuous_joint_rotates_about_its_axis():
    urdf = load_urdf(SPOT_URDF)
    rest = urdf.link_to_root("ptz_camera")
    turned = urdf.link_to_root("ptz_camera", {"ptz_pan": np.pi / 2})
    np.testing.assert_allclose(rest[:3, 3], turned[:3, 3], atol=1e-12)  # rotates in place
    np.testing.assert_allclose(rest[:3, :3] @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(turned[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # now looks left


def test_link_to_link_is_relative_pose():
    urdf = load_urdf(SPOT_URDF)
    rel = urdf.link_to_link("frontleft_fisheye", "lidar")
    np.testing.assert_allclose(
        rel, invert_se3(urdf.link_to_root("lidar")) @ urdf.link_to_root("frontleft_fisheye"), atol=1e-12
    )


def _write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "robot.urdf"
    path.write_text(f'<?xml version="1.0"?>\n<robot name="r">{body}</robot>')
    return path


def test_prismatic_joint(tmp_path):
    path = _write(tmp_path, '<link name="a"/><link name="b"/>'
                            '<joint name="lift" type="prismatic"><parent link="a"/><child link="b"/>'
                            '<origin xyz="1 0 0"/><axis xyz="0 0 2"/></joint>')
    np.testing.assert_allclose(load_urdf(path).link_to_root("b", {"lift": 0.5})[:3, 3], [1, 0, 0.5])


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ("<link name='a'/><link name='b'/><joint name='j' type='hinge'><parent link='a'/><child link='b'/></joint>",
         "type 'hinge'"),
        ("<link name='a'/><joint name='j' type='fixed'><parent link='a'/><child link='zz'/></joint>", "undefined link 'zz'"),
        ("<link name='a'/><link name='b'/>", "exactly one root link"),
        ("<link name='a'/><link name='b'/><joint name='j' type='fixed'><parent link='a'/><child link='b'/>"
         "<origin xyz='1 2'/></joint>", "origin.xyz"),
        ("<link name='a'/><link name='b'/><link name='c'/>"
         "<joint name='j1' type='fixed'><parent link='b'/><child link='c'/></joint>"
         "<joint name='j2' type='fixed'><parent link='c'/><child link='b'/></joint>", "cycle"),
        ("<link name='a'/><link name='a'/>", "defined twice"),
        ("<link name='a'", "malformed URDF XML"),
    ],
)
def test_bad_urdf_is_one_input_error(tmp_path, body, fragment):
    path = _write(tmp_path, body)
    with pytest.raises(InputError, match=fragment) as info:
        load_urdf(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_unknown_link_and_joint(tmp_path):
    urdf = load_urdf(SPOT_URDF)
    with pytest.raises(InputError, match="no link named 'nose'"):
        urdf.link_to_root("nose")
    with pytest.raises(InputError, match="fixed and takes no position"):
        urdf.link_to_root("lidar", {"lidar_joint": 1.0})
    with pytest.raises(InputError, match="not found"):
        load_urdf(tmp_path / "missing.urdf")
