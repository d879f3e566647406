"""File primitives of the workspace: content digests, durable writes and bounded reads of small files."""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

from nsim.errors import WorkspaceError
from nsim.io import atomic_write_bytes, fsync_path
from nsim.workspace.writers import tmp_name

_CHUNK = 1 << 20


def sha256_file(path: Path) -> tuple[str, int]:
    """SHA-256 hex digest and size in bytes of one file."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return h.hexdigest(), size


def sha256_path(path: Path) -> str:
    """Content digest of a file input or a folder of them (every file's relative name and content).

    For a file: the SHA-256 of its hex digest; for a folder: of each file's POSIX relative path and
    hex digest, in sorted order. Renaming or editing any file changes it; timestamps do not.
    """
    path = Path(path)
    h = hashlib.sha256()
    if path.is_dir():
        for p in sorted(path.rglob("*")):
            if p.is_file():
                h.update(p.relative_to(path).as_posix().encode() + b"\0")
                h.update(sha256_file(p)[0].encode())
    else:
        h.update(sha256_file(path)[0].encode())
    return h.hexdigest()


def _syncfs(path: Path) -> bool:
    """Flush the whole file system holding ``path`` in one call (Linux ``syncfs``); False if unavailable."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.syncfs
    except (OSError, AttributeError):
        return False
    fd = os.open(path, os.O_RDONLY)
    try:
        return fn(fd) == 0
    finally:
        os.close(fd)


def sync_files(root: Path, paths: list[Path]) -> None:
    """Make ``paths`` durable: one ``syncfs`` when there are many files, else an fsync each."""
    if len(paths) > 16 and _syncfs(root):
        return
    for p in paths:
        fsync_path(p)
    for d in {p.parent for p in paths}:
        fsync_path(d)


def write_atomic(path: Path, data: bytes) -> None:
    """Replace a small file (a ref, a cache entry, a lease, a marker) in one rename, via a writer-tagged temp."""
    if path.is_dir() and not path.is_symlink():
        raise WorkspaceError(f"{path}: is a directory, cannot write a file there")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, data, tmp=tmp_name(path))


def stat_sig(path: Path) -> list[int] | None:
    """What changes when a file is rewritten, renamed over or chmod-ed: size, mtime, ctime, inode."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    if not stat.S_ISREG(st.st_mode):
        return None
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]


def read_small(path: Path, limit: int, what: str) -> bytes:
    """A regular file's bytes (no symlinks, at most ``limit`` bytes); WorkspaceError otherwise."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise WorkspaceError(f"{what}: cannot be read ({exc.strerror})") from None
    if stat.S_ISLNK(st.st_mode):
        raise WorkspaceError(f"{what}: is a symbolic link, which the workspace never writes")
    if not stat.S_ISREG(st.st_mode):
        raise WorkspaceError(f"{what}: is not a regular file")
    if st.st_size > limit:
        raise WorkspaceError(f"{what}: {st.st_size} bytes, more than the {limit} a workspace file of this kind holds")
    with open(path, "rb") as f:
        return f.read(limit + 1)
