"""The body's trajectory from what a robot's bag holds, for :meth:`nsim.io.robot_log.RobotLog.body_trajectory`.

Three sources, each giving the body's poses in the odom frame at stamps in integer nanoseconds:

- **tf**: the path from the body frame to the odom frame on /tf and /tf_static, at the stamps of its
  busiest moving link (:meth:`nsim.io.tf_tree.TfTree.trajectory`);
- **odometry**: a nav_msgs/Odometry topic (the pose of ``child_frame_id`` in ``header.frame_id``);
- **pose**: a geometry_msgs/PoseStamped or PoseWithCovarianceStamped topic (the body's pose in
  ``header.frame_id``, which is the odom frame).

For a topic, where its frames differ from the odom and body frames they are joined through tf
(:meth:`~nsim.io.tf_tree.TfTree.transforms_at`: moving links interpolated, stamps outside their span
dropped); a topic without a child frame (a PoseStamped, an Odometry whose ``child_frame_id`` is empty)
gives the body's poses. A trajectory of fewer than two poses is an InputError naming its source.
"""

from __future__ import annotations

import logging

import numpy as np

from nsim.errors import InputError
from nsim.io.recording_streams import Trajectory
from nsim.io.tf_tree import TfTree

log = logging.getLogger(__name__)


def two_or_more(trajectory: Trajectory, where: str) -> Trajectory:
    """``trajectory`` if it has two poses or more; InputError starting with ``where`` otherwise."""
    n = len(trajectory.stamps_ns)
    if n < 2:
        raise InputError(f"{where}: {n} pose(s) for the trajectory ({trajectory.source}); a trajectory needs two or "
                         "more")
    return trajectory


def from_tf(tf: TfTree, odom: str, body: str, bag: str) -> Trajectory:
    """The path from ``body`` to ``odom`` on the tf tree (see :meth:`TfTree.trajectory`)."""
    stamps, body_to_odom = tf.trajectory(odom, body)
    return two_or_more(Trajectory(stamps, body_to_odom, odom, body, f"tf: {odom} -> {body}"), f"bag {bag}")


def from_topic(tf: TfTree, kind: str, topic: str, frame: str, child: str, stamps_ns: np.ndarray,
               child_to_frame: np.ndarray, odom: str, body: str, bag: str) -> Trajectory:
    """The body's poses in ``odom`` from a topic's poses of ``child`` (empty: the body) in ``frame`` (empty: odom),
    joined through ``tf`` where the frames differ; ``kind`` (``odometry``, ``pose``) names the source."""
    joins = [(body, child)] if child else []
    joins = [(a, b) for a, b in [*joins, (frame or odom, odom)] if a != b]
    kept = np.ones(len(stamps_ns), dtype=bool)
    for a, b in joins:
        kept &= tf.transforms_at(a, b, stamps_ns)[0]
    if not kept.any() and len(kept):
        raise InputError(f"bag {bag}: no stamp of {topic} lies within the tf links that join {frame!r} -> {child!r} "
                         f"to {odom!r} -> {body!r}")
    stamps = stamps_ns[kept]

    def join(a: str, b: str) -> np.ndarray:
        return tf.transforms_at(a, b, stamps)[1] if (a, b) in joins else np.eye(4)

    if not kept.all():
        log.info("bag %s: %d of %d poses of %s lie outside the tf links that join its frames; dropped",
                 bag, int((~kept).sum()), len(kept), topic)
    body_to_odom = join(frame or odom, odom) @ child_to_frame[kept] @ (join(body, child) if child else np.eye(4))
    return two_or_more(Trajectory(stamps, body_to_odom, odom, body, f"{kind} {topic}"), f"bag {bag}: {topic}")
