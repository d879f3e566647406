"""Opening a ROS bag with ``rosbags.highlevel.AnyReader``, and listing its topics.

Bags are opened with ``rosbags.highlevel.AnyReader``: one or more ROS 1 ``.bag`` files (a split
recording), or one ROS 2 bag directory (``metadata.yaml`` with ``.db3`` or ``.mcap``; the storage
file itself is accepted too). Message types come from the bag's own definitions, or from ROS 2
Humble's where a ROS 2 bag has none. Nothing is executed or unpickled. A bag that does not open
(not a bag, a ROS 1 bag cut short without its index) is one line naming it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from rosbags.highlevel import AnyReader, AnyReaderError

from nsim.errors import InputError
from nsim.io.rosbag import TYPESTORE


@dataclass(frozen=True)
class TopicSummary:
    """A topic of the bag: its message type (None when its connections disagree) and message count."""

    topic: str
    msgtype: str | None
    count: int


def bag_paths(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    """The paths AnyReader wants: ROS 1 ``.bag`` files, or one ROS 2 bag directory."""
    items = [paths] if isinstance(paths, str | os.PathLike) else list(paths)
    if not items:
        raise InputError("bag: no path given")
    out = []
    for item in items:
        path = Path(item)
        if not os.path.lexists(path):
            raise InputError(f"bag {path}: does not exist")
        if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
            path = path.parent  # the storage file of a ROS 2 bag: read the bag
        out.append(path)
    ros1 = [p.suffix == ".bag" for p in out]
    if len(out) > 1 and not all(ros1):
        raise InputError(f"bag {out[0]}: several paths must all be ROS 1 .bag files (a ROS 2 bag is one directory)")
    return out


def list_topics(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> dict[str, TopicSummary]:
    """Every topic of a bag with its message type and count, without reading messages."""
    found = bag_paths(paths)
    reader = open_bag_reader(found, str(found[0]))
    try:
        return {name: TopicSummary(name, info.msgtype, info.msgcount) for name, info in reader.topics.items()}
    finally:
        reader.close()


def open_bag_reader(paths: list[Path], name: str) -> AnyReader:
    """An open AnyReader on ``paths`` (from :func:`bag_paths`); InputError naming ``name`` when it is no bag."""
    try:
        reader = AnyReader(paths, default_typestore=TYPESTORE)
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        reason = " ".join(str(exc).split())
        hint = ""
        if all(p.suffix == ".bag" for p in paths) and "index" in reason.lower():
            hint = ("; a ROS 1 bag cut short (a recording that did not close, a partial copy) has no index: "
                    "`rosbag reindex` rebuilds it")
        raise InputError(f"bag {name}: not a readable ROS bag: {reason}{hint}") from None
    return reader
