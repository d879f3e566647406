"""Refs: human names for artifact ids, one file ``refs/<name>`` holding 64 hex digits and a newline.

A name is one or more ``/``-separated parts of letters, digits, ``_``, ``-`` and ``.`` (``scene/lab``,
``capture/latest``); it may not look like an id prefix. What a ref file holds is checked on every
read: one that does not hold an id is reported (:meth:`Refs.bad`) and protects nothing from gc.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

from nsim.errors import InputError, WorkspaceError
from nsim.workspace.artifacts import is_hex, is_id
from nsim.workspace.files import read_small, write_atomic

_REF_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*(/[A-Za-z0-9_][A-Za-z0-9_.-]*)*$")


def check_ref_name(name: str) -> None:
    if not _REF_RE.match(name) or any(seg in (".", "..") for seg in name.split("/")) or name.endswith(".tmp"):
        raise InputError(f"invalid ref name {name!r}: use letters, digits, '_', '-', '.' and '/' (e.g. scene/lab)")
    if is_hex(name) and len(name) >= 4:
        raise InputError(f"invalid ref name {name!r}: it looks like an artifact id prefix")


class Refs:
    """The ``refs/`` folder ``base`` of a workspace: reading, listing, writing and deleting refs."""

    def __init__(self, base: Path):
        self.base = base

    def check_destination(self, name: str) -> None:
        """Refuse a ref name that is invalid or cannot be written here (a folder of refs, or below a ref)."""
        check_ref_name(name)
        parts = name.split("/")
        for i in range(1, len(parts)):
            p = self.base.joinpath(*parts[:i])
            if p.is_symlink() or (p.exists() and not p.is_dir()):
                raise InputError(f"ref {'/'.join(parts[:i])} exists, so no ref can be named {name} (below it)")
        p = self.base / name
        if p.is_symlink():
            raise WorkspaceError(f"{p}: is a symbolic link, which the workspace never writes")
        if p.is_dir():
            raise InputError(f"{name} is a folder of refs (e.g. {name}/latest), not a ref; choose another name")

    def write(self, name: str, art_id: str) -> None:
        """Point ``name`` at ``art_id`` (the caller checks the name and that the artifact is there)."""
        write_atomic(self.base / name, art_id.encode() + b"\n")

    def delete(self, name: str) -> None:
        check_ref_name(name)
        p = self.base / name
        if p.is_symlink() or not p.is_file():
            raise WorkspaceError(f"no ref named {name}")
        p.unlink()

    def exists(self, spec: str) -> bool:
        """True when ``spec`` is shaped like a ref name and a file (or a link) of that name is in ``refs/``."""
        p = self.base / spec
        return bool(_REF_RE.match(spec)) and ".." not in spec.split("/") and (p.is_file() or p.is_symlink())

    def read(self, name: str) -> str:
        """The id ref ``name`` holds; WorkspaceError when there is no such ref or it does not hold an id."""
        try:
            raw = read_small(self.base / name, 256, f"ref {name}")
        except FileNotFoundError:
            raise WorkspaceError(f"no ref named {name}") from None
        text = raw.decode("ascii", errors="replace").strip()
        if not is_id(text):
            raise WorkspaceError(f"ref {name}: does not hold an artifact id (64 hex digits); fix it with 'nsim tag ID {name}'")
        return text

    def names(self) -> Iterator[str]:
        """Every ref file's name, sorted, not following symbolically linked folders."""
        for dirpath, dirnames, filenames in os.walk(self.base):
            dirnames[:] = sorted(d for d in dirnames if not os.path.islink(os.path.join(dirpath, d)))
            for fn in sorted(filenames):
                if fn.startswith("."):
                    continue
                yield (Path(dirpath) / fn).relative_to(self.base).as_posix()

    def ids(self) -> dict[str, str]:
        """All readable refs, name -> id (see :meth:`bad` for the others)."""
        out = {}
        for name in self.names():
            with contextlib.suppress(WorkspaceError):
                out[name] = self.read(name)
        return out

    def bad(self) -> dict[str, str]:
        """Refs whose file does not hold an id (name -> why); they protect nothing from gc."""
        out = {}
        for name in self.names():
            try:
                self.read(name)
            except WorkspaceError as exc:
                out[name] = str(exc)
        return out
