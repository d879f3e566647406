"""Who writes into a workspace, and the temporary names that say so.

Every temporary name the workspace makes carries its writer's host and pid, so that a cleanup can
tell a dead writer's debris from live work:

* ``.<name>.<host>.<pid>.<rand>.tmp`` beside a small file being replaced (:func:`tmp_name`);
* ``tmp/<stage>.<host>.<pid>.<rand>`` for an artifact being published (:func:`tmp_dir_name`).

A writer on this host is dead when its pid no longer runs (:func:`pid_alive`); one on another
host cannot be asked, so its debris is taken as abandoned after :data:`STALE_TMP_S`.
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from pathlib import Path

HOST = socket.gethostname()
STALE_TMP_S = 24 * 3600.0


def proc_start(pid: int) -> str | None:
    """The start time of a local process (clock ticks since boot), to tell a reused pid apart."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[-1].split()
    except OSError:
        return None
    return fields[19] if len(fields) > 19 else None


def pid_alive(pid: int, start: str | None = None) -> bool:
    """True while a local process runs (a zombie counts as dead); with ``start``, only that same process."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    except OverflowError:
        return False
    # A zombie (killed, not yet reaped) counts as dead.
    try:
        with open(f"/proc/{pid}/stat") as f:
            if f.read().rsplit(")", 1)[-1].split()[0] == "Z":
                return False
    except OSError:
        return True
    return start is None or proc_start(pid) in (None, start)


def tmp_name(path: Path) -> Path:
    """A sibling temp name that says who writes it (host, pid), so gc can tell debris from work."""
    return path.with_name(f".{path.name}.{HOST}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")


def tmp_dir_name(stage: str) -> str:
    """The name under ``tmp/`` of an artifact this process starts writing for ``stage``."""
    return f"{stage}.{HOST}.{os.getpid()}.{uuid.uuid4().hex[:12]}"


def small_tmp_abandoned(p: Path) -> bool:
    """A :func:`tmp_name` file whose writer is gone: a dead local pid, or older than :data:`STALE_TMP_S`."""
    try:
        age = time.time() - p.lstat().st_mtime
    except FileNotFoundError:
        return False
    parts = p.name[: -len(".tmp")].rsplit(".", 2)
    if len(parts) == 3 and parts[1].isdigit() and parts[0].endswith("." + HOST):
        return not pid_alive(int(parts[1]))
    return age > STALE_TMP_S


def tmp_dir_abandoned(p: Path) -> bool:
    """An entry of ``tmp/`` whose writer is gone: a dead local pid, or older than :data:`STALE_TMP_S`."""
    parts = p.name.split(".")
    try:
        age = time.time() - p.lstat().st_mtime
    except FileNotFoundError:
        return False
    if len(parts) >= 4 and parts[-2].isdigit():
        pid = int(parts[-2])
        writer_host = ".".join(parts[1:-2])
        if writer_host == HOST:
            return not pid_alive(pid)
    return age > STALE_TMP_S
