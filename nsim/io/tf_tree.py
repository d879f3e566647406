"""A robot's transforms from /tf_static and /tf, as a tree: static links chained, moving ones sampled.

A transform ``parent -> child`` is the child's pose in the parent, ``child_to_parent (4, 4)``;
frame ids are taken without a leading ``/``. :meth:`TfTree.sensor_to_body` chains /tf_static links only;
:meth:`TfTree.transforms_at` and :meth:`TfTree.trajectory` also cross moving /tf links, each
interpolated between its stamps (linear position, slerped rotation) and never extrapolated: stamps
outside a moving link's span are dropped, as tf2 refuses them.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from nsim.errors import InputError
from nsim.geometry.transforms import interpolate_poses, invert_se3

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StaticLink:
    """A /tf_static transform: ``child_to_parent (4, 4)``, the child's pose in the parent."""

    parent: str
    child: str
    child_to_parent: np.ndarray


@dataclass(frozen=True)
class MovingLink:
    """A /tf link over time: stamps_ns (N,) int64 increasing, child_to_parent (N, 4, 4)."""

    parent: str
    child: str
    stamps_ns: np.ndarray
    child_to_parent: np.ndarray



@dataclass(frozen=True)
class TfTree:
    """The transforms of /tf_static (``static``, one per child frame, the last one sent) and /tf
    (``moving``, one per parent -> child link)."""

    static: tuple[StaticLink, ...] = ()
    moving: tuple[MovingLink, ...] = ()

    @property
    def frames(self) -> set[str]:
        """Every frame any link names."""
        return {f for link in (*self.static, *self.moving) for f in (link.parent, link.child)}

    def _path(self, source: str, target: str, with_moving: bool) -> list[tuple[StaticLink | MovingLink, bool]] | None:
        """Links from ``source`` to ``target`` (breadth first, fewest links), each with True when
        it is walked child -> parent; None if there is no path."""
        neighbours: dict[str, list[tuple[str, StaticLink | MovingLink, bool]]] = {}
        for link in (*self.static, *(self.moving if with_moving else ())):
            neighbours.setdefault(link.child, []).append((link.parent, link, True))
            neighbours.setdefault(link.parent, []).append((link.child, link, False))
        previous: dict[str, tuple[str, StaticLink | MovingLink, bool] | None] = {source: None}
        queue = deque([source])
        while queue:
            frame = queue.popleft()
            if frame == target:
                path = []
                while previous[frame] is not None:
                    before, link, upward = previous[frame]
                    path.append((link, upward))
                    frame = before
                return path[::-1]
            for nxt, link, upward in neighbours.get(frame, ()):
                if nxt not in previous:
                    previous[nxt] = (frame, link, upward)
                    queue.append(nxt)
        return None

    def _no_link(self, source: str, target: str) -> InputError:
        known = sorted({f for link in self.static for f in (link.parent, link.child)})
        shown = ", ".join(known[:12]) + (", ..." if len(known) > 12 else "") if known else "none"
        through = " (there is one only through moving /tf links)" if self._path(source, target, True) else ""
        return InputError(f"tf: no link between {source!r} and {target!r}{through}; static frames: {shown}")

    def static_transform(self, source: str, target: str) -> np.ndarray:
        """``source_to_target (4, 4)`` through /tf_static links; InputError when there is no path."""
        source, target = source.lstrip("/"), target.lstrip("/")
        path = self._path(source, target, with_moving=False)
        if path is None:
            raise self._no_link(source, target)
        out = np.eye(4)
        for link, upward in path:
            out = (link.child_to_parent if upward else invert_se3(link.child_to_parent)) @ out
        return out

    def sensor_to_body(self, frame_id: str, body_frame: str) -> np.ndarray:
        """``sensor_to_body (4, 4)``: points in ``frame_id`` to ``body_frame``, chaining /tf_static links.

        Raises ``InputError("tf: no link between 'X' and 'body' ...")`` when no static path joins them.
        """
        return self.static_transform(frame_id, body_frame)

    def transforms_at(self, source: str, target: str, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``source_to_target`` at each of ``stamps_ns (N,)`` through /tf_static and /tf links.

        Returns ``kept (N,)`` bool and ``source_to_target (K, 4, 4)`` at ``stamps_ns[kept]``. A
        moving link is taken as sent at its own stamps and interpolated between them (linear
        position, slerped rotation); a stamp outside a moving link's first..last stamp is not kept
        (tf2 does not extrapolate either). InputError when no path joins the frames.
        """
        source, target = source.lstrip("/"), target.lstrip("/")
        path = self._path(source, target, with_moving=True)
        if path is None:
            raise InputError(f"tf: no link between {source!r} and {target!r} in /tf or /tf_static")
        return _compose(path, np.asarray(stamps_ns, dtype=np.int64))

    def trajectory(self, odom_frame: str, body_frame: str) -> tuple[np.ndarray, np.ndarray]:
        """``stamps_ns (N,)`` and ``body_to_odom (N, 4, 4)`` from /tf along the path from body to odom.

        The stamps are those of the path's moving link with the most stamps (of equal ones, the
        nearest the body: ``odom -> base_link`` on a ``map -> odom -> base_link`` tree read in
        ``map``); the other moving links are interpolated at them and stamps outside their span
        are dropped (see :meth:`transforms_at`); static links are composed in. InputError when
        there is no path, when it has no moving link, or when no stamp lies in every moving
        link's span.
        """
        odom_frame, body_frame = odom_frame.lstrip("/"), body_frame.lstrip("/")
        path = self._path(body_frame, odom_frame, with_moving=True)
        if path is None:
            raise InputError(f"tf: no link between {body_frame!r} and {odom_frame!r} in /tf or /tf_static")
        moving = [link for link, _ in path if isinstance(link, MovingLink)]
        if not moving:
            raise InputError(f"tf: the path from {odom_frame!r} to {body_frame!r} has no moving link (the body does "
                             "not move in that frame)")
        clock = max(moving, key=lambda link: len(link.stamps_ns))  # the first of equals: nearest the body
        kept, body_to_odom = _compose(path, clock.stamps_ns)
        if not kept.any():
            spans = ", ".join(f"{link.parent} -> {link.child} {link.stamps_ns[0]}..{link.stamps_ns[-1]} ns"
                              for link in moving)
            raise InputError(f"tf: the moving links from {odom_frame!r} to {body_frame!r} share no time ({spans})")
        if not kept.all():
            log.info("tf %s -> %s: %d of %d stamps of %s -> %s lie outside another moving link's span; dropped",
                     odom_frame, body_frame, int((~kept).sum()), len(kept), clock.parent, clock.child)
        return clock.stamps_ns[kept], body_to_odom


def _link_at(link: MovingLink, stamps_ns: np.ndarray) -> np.ndarray:
    """``child_to_parent (N, 4, 4)`` of a moving link at stamps inside its span: its own matrices at
    its own stamps, interpolated between them (:func:`nsim.geometry.transforms.interpolate_poses`)."""
    at = np.clip(np.searchsorted(link.stamps_ns, stamps_ns), 0, len(link.stamps_ns) - 1)
    exact = link.stamps_ns[at] == stamps_ns
    out = link.child_to_parent[at]
    if not exact.all():
        t0 = link.stamps_ns[0]  # seconds from the first stamp keep float64's resolution
        out[~exact] = interpolate_poses((link.stamps_ns - t0) / 1e9, link.child_to_parent,
                                        (stamps_ns[~exact] - t0) / 1e9)
    return out


def _compose(path: list[tuple[StaticLink | MovingLink, bool]], stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``kept (N,)`` and the path's ``source_to_target (K, 4, 4)`` at ``stamps_ns[kept]`` (see
    :meth:`TfTree.transforms_at`)."""
    kept = np.ones(len(stamps_ns), dtype=bool)
    for link, _ in path:
        if isinstance(link, MovingLink):
            kept &= (stamps_ns >= link.stamps_ns[0]) & (stamps_ns <= link.stamps_ns[-1])
    at = stamps_ns[kept]
    out = np.broadcast_to(np.eye(4), (len(at), 4, 4)).copy()
    for link, upward in path:
        step = _link_at(link, at) if isinstance(link, MovingLink) else link.child_to_parent
        out = (step if upward else invert_se3(step)) @ out
    return kept, out
