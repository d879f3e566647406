"""File formats at nsim's edges: EXR, PNG, PLY, TUM (and transforms.json, COLMAP elsewhere).

Readers raise `nsim.errors.InputError` naming the file for bad input; writers write atomically, all
through :func:`atomic_path` (or its text and bytes forms :func:`atomic_write_text`,
:func:`atomic_write_bytes`), the one write-to-a-temporary-then-rename in nsim. (Directories are
published by renaming a whole temporary directory instead: the workspace store's artifacts, the
render engine's shards, a rosbag2 bag.)
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def fsync_path(path: str | os.PathLike) -> None:
    """Make a file's data, or a directory's entries (names created or renamed in it), durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike, tmp: str | os.PathLike | None = None) -> Iterator[Path]:
    """Yield a not-yet-existing temporary path next to `path` for the caller to write.

    On a clean exit the temporary file is fsynced and `os.replace`d onto `path`; on an exception it is
    removed. A crash never leaves a half-written file under the final name.

    tmp: the temporary path to use, for a writer whose temporaries carry a name of their own (the
    workspace store's and the render engine's name their host and pid, so that a cleanup can tell a
    live writer's from debris); default ``.<name>.<random>.tmp<suffix>`` beside `path`.
    """
    path = Path(path)
    tmp = Path(tmp) if tmp is not None else path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp{path.suffix}")
    try:
        yield tmp
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, tmp: str | os.PathLike | None = None) -> Path:
    """Write `data` to `path` atomically (:func:`atomic_path`); returns the path."""
    path = Path(path)
    with atomic_path(path, tmp) as t:
        t.write_bytes(data)
    return path


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8",
                      tmp: str | os.PathLike | None = None) -> Path:
    """Write `text` to `path` atomically (:func:`atomic_path`), newlines as given; returns the path."""
    return atomic_write_bytes(path, text.encode(encoding), tmp)
