"""Leases and holds: what running processes read or publish, so that gc keeps it.

A process **holds** an id by writing it into its lease file, ``leases/<host>.<pid>.<tag>.json``
(:class:`Lease`). To rely on an object it finds, it holds the id and then looks at the object
inside :func:`holding` (``hold.lock`` shared); gc chooses its victims and moves them into
``trash/`` inside :func:`collecting` (``hold.lock`` exclusive). So either gc sees the hold, or
the holder sees the object gone (a cache miss) — never an object that vanishes after it was
found whole.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import threading
import time
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path

from nsim.errors import WorkspaceError
from nsim.workspace.artifacts import MAX_MANIFEST_BYTES, is_id
from nsim.workspace.files import read_small, write_atomic
from nsim.workspace.writers import HOST, pid_alive, proc_start

# A lease is refreshed by its process every LEASE_HEARTBEAT_S; one on another host whose file
# has not been touched for LEASE_TIMEOUT_S is taken as abandoned (its process cannot be asked).
LEASE_HEARTBEAT_S = 60.0
LEASE_TIMEOUT_S = 15 * 60.0


class Lease:
    """This process's lease file: the ids it reads or publishes, so that gc keeps them.

    ``leases/<host>.<pid>.<tag>.json`` holds ``{"host", "pid", "pid_start", "ids"}``. It is live
    while its process runs (checked by pid and start time on the same host) or, seen from
    another host, while a heartbeat thread keeps touching it. It goes when the process exits.
    """

    def __init__(self, root: Path):
        self.dir = root / "leases"
        self._lock = threading.Lock()
        self._reset()

    def _reset(self) -> None:
        self.pid = os.getpid()
        self.ids: set[str] = set()
        self.path: Path | None = None
        self._stop = threading.Event()
        self._atexit = False

    def hold(self, ids: Iterable[str]) -> None:
        with self._lock:
            if self.pid != os.getpid():  # a forked child holds its own lease
                self._reset()
            new = {i for i in ids if is_id(i)} - self.ids
            if not new:
                return
            self.ids |= new
            if self.path is None:
                self.path = self.dir / f"{HOST}.{self.pid}.{uuid.uuid4().hex[:12]}.json"
                if not self._atexit:
                    atexit.register(self.release)
                    self._atexit = True
                threading.Thread(target=self._heartbeat, name="nsim-lease", daemon=True).start()
            body = {"host": HOST, "pid": self.pid, "pid_start": proc_start(self.pid), "ids": sorted(self.ids)}
            write_atomic(self.path, json.dumps(body).encode() + b"\n")

    def _heartbeat(self) -> None:
        path, stop = self.path, self._stop
        while not stop.wait(LEASE_HEARTBEAT_S):
            with contextlib.suppress(OSError):
                os.utime(path)

    def release(self) -> None:
        if self.path is not None and self.pid == os.getpid():
            self._stop.set()
            self._stop = threading.Event()  # for the heartbeat of the next lease
            with contextlib.suppress(OSError):
                self.path.unlink()
            self.path = None
            self.ids = set()


def live_leases(root: Path, remove_expired: bool = False) -> tuple[set[str], list[str]]:
    """Ids held by the live leases of the workspace ``root``, and the names of expired lease files (removed if asked)."""
    held: set[str] = set()
    expired: list[str] = []
    base = root / "leases"
    now = time.time()
    for p in sorted(base.iterdir()) if base.is_dir() else []:
        if p.name.startswith(".") or not p.name.endswith(".json"):
            continue
        parts = p.name[: -len(".json")].rsplit(".", 2)
        try:
            st = p.lstat()
            body = json.loads(read_small(p, MAX_MANIFEST_BYTES, f"lease {p.name}"))
            ids = [i for i in body.get("ids", []) if is_id(i)]
        except FileNotFoundError:
            continue
        except (WorkspaceError, ValueError, AttributeError, TypeError, UnicodeDecodeError):
            body, ids = None, []
        live = False
        if body is not None and len(parts) == 3 and parts[1].isdigit():
            if parts[0] == HOST:
                live = pid_alive(int(parts[1]), body.get("pid_start"))
            else:
                live = now - st.st_mtime < LEASE_TIMEOUT_S
        elif now - st.st_mtime < LEASE_TIMEOUT_S:
            live = True  # unreadable but fresh: being written by hand? keep it for now
        if live:
            held.update(ids)
        else:
            expired.append(p.name)
            if remove_expired:
                with contextlib.suppress(OSError):
                    p.unlink()
    return held, expired


def _lock_fd(root: Path) -> int | None:
    try:
        return os.open(root / "hold.lock", os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        try:
            return os.open(root / "hold.lock", os.O_RDONLY)
        except OSError:
            return None  # a read-only workspace without the lock file: nobody can gc it either


@contextlib.contextmanager
def holding(root: Path) -> Iterator[None]:
    """``hold.lock`` shared: holds taken and objects looked at inside cannot interleave with gc's
    choosing and trashing of victims (which it does with the lock exclusive)."""
    import fcntl

    fd = _lock_fd(root)
    try:
        if fd is not None:
            fcntl.flock(fd, fcntl.LOCK_SH)
        yield
    finally:
        if fd is not None:
            os.close(fd)


@contextlib.contextmanager
def collecting(root: Path) -> Iterator[None]:
    """``hold.lock`` exclusive: gc chooses and trashes its victims inside, while no process is holding."""
    import fcntl

    fd = _lock_fd(root)
    if fd is None:
        raise WorkspaceError(f"{root}: cannot open hold.lock; gc needs a writable workspace")
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)
