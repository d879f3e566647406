"""Trajectory-only bags: a PoseStamped (or PoseWithCovarianceStamped) topic as the body's path, an Odometry topic
alone, /tf alone. Each opens with no camera, depth or LiDAR stream and gives the poses it was written with; a
trajectory of one message, or a bag with none, is one line."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.geometry import make_se3
from nsim.io.robot_log import RobotLog
from nsim.io.topic_selection import Selection
from tests.io.test_robot_log import FORMATS, RawBag, _odom, bag_path

T0 = 1_700_000_000 * 10**9
TICK = 100_000_000


def poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([make_se3(Rotation.from_euler("xyz", rng.uniform(-1, 1, 3)).as_matrix(), rng.uniform(-5, 5, 3))
                     for _ in range(n)])


def pose_msg(b: RawBag, t_ns: int, frame: str, m: np.ndarray, covariance: bool = False):
    q = Rotation.from_matrix(m[:3, :3]).as_quat()
    pose = b.msg("geometry_msgs/msg/Pose", position=b.msg("geometry_msgs/msg/Point", x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                 orientation=b.msg("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))
    if covariance:
        return b.msg("geometry_msgs/msg/PoseWithCovarianceStamped", header=b.header(t_ns, frame),
                     pose=b.msg("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=np.zeros(36)))
    return b.msg("geometry_msgs/msg/PoseStamped", header=b.header(t_ns, frame), pose=pose)


def write(path: Path, fmt: str, messages) -> Path:
    """A bag of ``(topic, t_ns, make(bag))`` messages."""
    bag = RawBag(path, fmt)
    for topic, t_ns, make in messages:
        bag.write(topic, make(bag), t_ns)
    bag.close()
    return path


def assert_no_streams(log: RobotLog) -> None:
    assert log.cameras == {} and log.depth == {} and log.lidars == {}


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("covariance", [False, True])
def test_pose_stamped_only(tmp_path, fmt, covariance):
    truth = poses(5)
    path = write(bag_path(tmp_path, fmt), fmt, [
        ("/slam/pose", T0 + k * TICK, lambda b, k=k: pose_msg(b, T0 + k * TICK, "map", truth[k], covariance))
        for k in range(5)])
    with RobotLog(path) as log:
        assert_no_streams(log)
        assert log.pose is not None and log.pose.topic == "/slam/pose" and log.odometry is None
        assert log.odom_frame == "map" and log.body_frame is None
        for source in ("auto", "pose"):
            tr = log.body_trajectory(source)
            np.testing.assert_array_equal(tr.stamps_ns, T0 + np.arange(5) * TICK)
            np.testing.assert_allclose(tr.body_to_odom, truth, atol=1e-12)
            assert (tr.odom_frame, tr.body_frame, tr.source) == ("map", "", "pose /slam/pose")
        with pytest.raises(InputError, match="no Odometry topic"):
            log.body_trajectory("odometry")


def test_pose_joined_through_tf_to_the_odom_frame(tmp_path):
    """odom_frame named in the selection: the pose topic's frame is joined to it through /tf_static."""
    truth = poses(3)
    map_to_world = poses(1, seed=7)[0]
    msgs = [("/tf_static", T0, lambda b: b.msg("tf2_msgs/msg/TFMessage",
                                               transforms=[b.transform(T0, "world", "map", map_to_world)]))]
    msgs += [("/pose", T0 + k * TICK, lambda b, k=k: pose_msg(b, T0 + k * TICK, "map", truth[k])) for k in range(3)]
    path = write(tmp_path / "joined", "sqlite3", msgs)
    with RobotLog(path, Selection(odom_frame="world", body_frame="base_link")) as log:
        tr = log.body_trajectory()
        np.testing.assert_allclose(tr.body_to_odom, map_to_world @ truth, atol=1e-12)
        assert (tr.odom_frame, tr.body_frame) == ("world", "base_link")


@pytest.mark.parametrize("fmt", FORMATS)
def test_odometry_only(tmp_path, fmt):
    truth = poses(4, seed=1)
    path = write(bag_path(tmp_path, fmt), fmt, [
        ("/odom", T0 + k * TICK, lambda b, k=k: _odom(b, T0 + k * TICK, child_to_frame=truth[k])) for k in range(4)])
    with RobotLog(path) as log:
        assert_no_streams(log)
        assert log.pose is None and log.odometry.topic == "/odom"
        tr = log.body_trajectory()
        np.testing.assert_array_equal(tr.stamps_ns, T0 + np.arange(4) * TICK)
        np.testing.assert_allclose(tr.body_to_odom, truth, atol=1e-12)
        assert (tr.odom_frame, tr.body_frame, tr.source) == ("odom", "body", "odometry /odom")


@pytest.mark.parametrize("fmt", FORMATS)
def test_tf_only(tmp_path, fmt):
    truth = poses(4, seed=2)
    path = write(bag_path(tmp_path, fmt), fmt, [
        ("/tf", T0 + k * TICK, lambda b, k=k: b.msg("tf2_msgs/msg/TFMessage", transforms=[
            b.transform(T0 + k * TICK, "odom", "base_link", truth[k])])) for k in range(4)])
    with RobotLog(path) as log:
        assert_no_streams(log)
        assert log.odometry is None and log.pose is None
        tr = log.body_trajectory()
        np.testing.assert_array_equal(tr.stamps_ns, T0 + np.arange(4) * TICK)
        np.testing.assert_allclose(tr.body_to_odom, truth, atol=1e-12)
        assert tr.source == "tf: odom -> base_link"


def test_one_message_is_one_line(tmp_path):
    one = poses(1)[0]
    cases = {
        "pose": [("/pose", T0, lambda b: pose_msg(b, T0, "odom", one))],
        "odometry": [("/odom", T0, lambda b: _odom(b, T0, child_to_frame=one))],
        "tf": [("/tf", T0, lambda b: b.msg("tf2_msgs/msg/TFMessage",
                                           transforms=[b.transform(T0, "odom", "base_link", one)]))],
    }
    for source, msgs in cases.items():
        with RobotLog(write(tmp_path / source, "mcap", msgs)) as log:  # opening is fine
            for asked in ("auto", source):
                with pytest.raises(InputError, match=r"1 pose\(s\) for the trajectory .*needs two or more") as err:
                    log.body_trajectory(asked)
                assert "\n" not in str(err.value)
                if source != "tf":
                    assert f"/{source}" in str(err.value)


def test_no_trajectory_says_how_to_give_one(tmp_path):
    info = poses(1)[0]
    path = write(tmp_path / "static", "sqlite3", [("/tf_static", T0, lambda b: b.msg(
        "tf2_msgs/msg/TFMessage", transforms=[b.transform(T0, "base_link", "cam", info)]))])
    with RobotLog(path) as log, pytest.raises(InputError) as err:
        log.body_trajectory()
    text = str(err.value)
    assert "no trajectory" in text and "--trajectory FILE.tum" in text and "pose: TOPIC" in text
    assert "\n" not in text


def test_pose_defaults_several_and_goals(tmp_path, caplog):
    a, b_ = poses(2, seed=3), poses(2, seed=4)
    msgs = [(topic, T0 + k * TICK, lambda b, k=k, m=m: pose_msg(b, T0 + k * TICK, "odom", m[k]))
            for topic, m in (("/a/pose", a), ("/b/pose", b_)) for k in range(2)]
    msgs.append(("/goal_pose", T0, lambda b: pose_msg(b, T0, "map", a[0])))
    path = write(tmp_path / "several", "sqlite3", msgs)
    with caplog.at_level(logging.WARNING, logger="nsim.io.robot_log"), RobotLog(path) as log:
        assert log.pose is None
    assert "several PoseStamped topics (/a/pose, /b/pose); none read (choose one: pose: TOPIC)" in caplog.text
    with RobotLog(path, {"pose": "/b/pose"}) as log:
        np.testing.assert_allclose(log.body_trajectory().body_to_odom, b_, atol=1e-12)
    goal_only = write(tmp_path / "goal", "sqlite3", msgs[:2] + msgs[-1:])  # /a/pose and a goal: /a/pose taken
    with RobotLog(goal_only) as log:
        assert log.pose.topic == "/a/pose"
    with pytest.raises(InputError, match=r"pose: no such topic .*PoseStamped or PoseWithCovarianceStamped topics"):
        RobotLog(path, {"pose": "/c/pose"})
    with pytest.raises(InputError, match=r"selection: unknown key 'poses' \(did you mean 'pose'\?\)"):
        Selection.from_data({"poses": "/a/pose"})


def test_pose_not_default_beside_odometry(tmp_path):
    one = poses(2, seed=5)
    msgs = [("/odom", T0 + k * TICK, lambda b, k=k: _odom(b, T0 + k * TICK, child_to_frame=one[k])) for k in range(2)]
    msgs += [("/pose", T0 + k * TICK, lambda b, k=k: pose_msg(b, T0 + k * TICK, "odom", one[k])) for k in range(2)]
    with RobotLog(write(tmp_path / "both", "sqlite3", msgs)) as log:
        assert log.pose is None and log.body_trajectory().source == "odometry /odom"


def test_a_ros1_topic_without_its_leading_slash_is_found_by_either_name(tmp_path):
    """ROS 1 allowed topics without a leading slash (evo's ROS_example.bag has ``groundtruth``): a selection naming
    ``groundtruth`` or ``/groundtruth`` reads it."""
    truth = poses(4, seed=3)
    path = write(bag_path(tmp_path, "ros1"), "ros1", [
        (topic, T0 + k * TICK, lambda b, k=k: pose_msg(b, T0 + k * TICK, "world", truth[k]))
        for k in range(4) for topic in ("groundtruth", "slam")])
    for name in ("groundtruth", "/groundtruth"):
        with RobotLog(path, Selection.from_data({"pose": name})) as log:
            assert_no_streams(log)
            np.testing.assert_allclose(log.body_trajectory().body_to_odom, truth, atol=1e-9)
