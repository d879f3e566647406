"""Garbage collection (``nsim gc``): remove objects nothing keeps, run-cache entries to missing objects, and debris.

**gc never collects live work.** Roots are the refs, the ids in live leases, and every object
younger than the grace period (``nsim gc --grace``, 1 hour by default); their inputs are kept
too. Victims are chosen and renamed into ``trash/`` (one rename each) while gc has ``hold.lock``
exclusive, so a process that holds an id and looks at the object under the shared lock either
is seen by gc or sees the object gone (see :mod:`nsim.workspace.leases`). Removal is atomic: an
object is whole in ``objects/`` or not there at all. Before deleting the trash, gc reads refs
and leases once more and moves back anything they reach (refs written by hand, or the trash of
a gc killed midway).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Protocol

from nsim.errors import InputError, WorkspaceError
from nsim.workspace.artifacts import MANIFEST, Artifact, is_id
from nsim.workspace.leases import collecting, live_leases
from nsim.workspace.verify import complete_manifest
from nsim.workspace.writers import small_tmp_abandoned, tmp_dir_abandoned

DEFAULT_GRACE_S = 3600.0


class GcStore(Protocol):
    """What gc needs of :class:`nsim.workspace.store.Store` (which calls it, so it is not imported here)."""

    root: Path

    def object_dirs(self) -> dict[str, Path]: ...
    def object_path(self, art_id: str) -> Path: ...
    def refs(self) -> dict[str, str]: ...
    def read_action(self, p: Path) -> str | None: ...
    def size_bytes(self, art: Artifact) -> int: ...
    def _to_trash(self, path: Path, art_id: str, suffix: str = "gc") -> Path | None: ...
    def _delete_tree(self, path: Path) -> None: ...


@dataclasses.dataclass
class GcReport:
    objects: list[str] = dataclasses.field(default_factory=list)
    actions: list[str] = dataclasses.field(default_factory=list)
    tmp: list[str] = dataclasses.field(default_factory=list)
    restored: list[str] = dataclasses.field(default_factory=list)
    leases: list[str] = dataclasses.field(default_factory=list)
    kept_young: int = 0
    kept_leased: int = 0
    bytes_freed: int = 0


def _inputs_of(path: Path, art_id: str) -> list[str]:
    try:
        return list(Artifact(art_id, path).manifest.get("inputs", {}).values())
    except WorkspaceError:
        return []


def closure(roots: Iterable[str], where: Mapping[str, Path]) -> set[str]:
    """Ids reachable from ``roots`` through manifests' inputs (objects looked up in ``where``)."""
    seen: set[str] = set()
    stack = [i for i in roots if is_id(i)]
    while stack:
        i = stack.pop()
        if i in seen:
            continue
        seen.add(i)
        if i in where:
            stack.extend(_inputs_of(where[i], i))
    return seen


@contextlib.contextmanager
def _gc_lock(root: Path) -> Iterator[None]:
    import fcntl

    fd = os.open(root / "gc.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise WorkspaceError(f"{root}: another 'nsim gc' is running on this workspace; try again later") from None
        yield
    finally:
        os.close(fd)


def collect_garbage(store: GcStore, dry_run: bool = False, grace_s: float = DEFAULT_GRACE_S) -> GcReport:
    """Remove what nothing keeps from ``store``'s workspace (or only report it, with ``dry_run``).

    Kept: objects reachable (through inputs) from refs, from live leases, and from objects
    younger than ``grace_s`` (by the ctime of their directory, set when it was renamed into
    place). Victims are chosen and renamed into ``trash/`` one by one under ``hold.lock``
    exclusive; refs and leases are read again and anything they reach is moved back (a ref
    written by hand meanwhile); then the trash is deleted. A
    gc killed at any step leaves every object whole in ``objects/`` or in ``trash/``, which
    the next gc finishes (restoring what is reachable then).
    """
    if grace_s < 0:
        raise InputError(f"--grace: expected seconds >= 0, got {grace_s}")
    report = GcReport()
    with _gc_lock(store.root):
        # Choosing and trashing victims excludes every hold-and-look (see the module doc).
        with collecting(store.root) if not dry_run else contextlib.nullcontext():
            now = time.time()
            objs = store.object_dirs()
            young = set()
            for i, p in objs.items():
                try:
                    if now - p.lstat().st_ctime < grace_s:
                        young.add(i)
                except FileNotFoundError:
                    pass
            held, expired = live_leases(store.root, remove_expired=not dry_run)
            report.leases = expired
            keep = closure({*store.refs().values(), *held, *young}, objs)
            report.kept_young = len(young)
            report.kept_leased = len(held & set(objs))
            victims = [i for i in objs if i not in keep]
            for i in victims:
                report.bytes_freed += store.size_bytes(Artifact(i, objs[i]))
            report.objects = list(victims)
            if not dry_run:
                for i in victims:
                    store._to_trash(objs[i], i)
        if not dry_run:
            report.restored = _empty_trash(store)
            report.objects = [i for i in victims if i not in report.restored]
        _gc_actions(store, report, dry_run)
        _gc_debris(store, report, dry_run)
    return report


def _empty_trash(store: GcStore) -> list[str]:
    """Move back trashed objects that refs or leases reach now; delete the rest. Returns the restored ids."""
    trash = store.root / "trash"
    entries: dict[str, Path] = {}
    for p in sorted(trash.iterdir()) if trash.is_dir() else []:
        art_id = p.name.split(".", 1)[0]
        if is_id(art_id) and p.name.endswith(".gc") and p.is_dir() and not p.is_symlink():
            entries.setdefault(art_id, p)
    restored: list[str] = []
    if entries:
        held, _ = live_leases(store.root)
        where = {**entries, **store.object_dirs()}
        need = closure({*store.refs().values(), *held}, where)
        for art_id, p in entries.items():
            if art_id not in need or complete_manifest(p, art_id) is None:
                continue
            dest = store.object_path(art_id)
            dest.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.rename(p, dest)
            except OSError as exc:
                if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                    raise
                continue  # republished meanwhile: that copy stays, this one is deleted
            os.chmod(dest, 0o555)
            restored.append(art_id)
    for p in sorted(trash.iterdir()) if trash.is_dir() else []:
        store._delete_tree(p)
    return restored


def _gc_actions(store: GcStore, report: GcReport, dry_run: bool) -> None:
    """Run-cache entries that are unreadable or name an object that is gone."""
    gone = set(report.objects)
    for dirpath, dirnames, filenames in os.walk(store.root / "actions"):
        dirnames[:] = [d for d in dirnames if not os.path.islink(os.path.join(dirpath, d))]
        for fn in sorted(filenames):
            p = Path(dirpath) / fn
            if fn.startswith("."):
                continue  # an entry being written (or debris: see _gc_debris)
            target = store.read_action(p) if is_id(fn) else None
            if target is None or target in gone or not (store.object_path(target) / MANIFEST).is_file():
                report.actions.append(fn)
                if not dry_run:
                    with contextlib.suppress(FileNotFoundError):
                        p.unlink()


def _gc_debris(store: GcStore, report: GcReport, dry_run: bool) -> None:
    """What dead writers left: ``tmp/`` entries, half-written small files, markers of objects that are gone."""
    root = store.root
    tmp_root = root / "tmp"
    if tmp_root.is_symlink() or not tmp_root.is_dir():
        raise WorkspaceError(f"{tmp_root}: the workspace's tmp/ is not a directory; move that file away")
    for p in sorted(tmp_root.iterdir()):
        if tmp_dir_abandoned(p):
            report.tmp.append(p.name)
            if not dry_run:
                store._delete_tree(p)
    # half-written small files (refs, cache entries, leases, markers) of dead writers
    for sub in ("refs", "actions", "leases", "verified"):
        for dirpath, dirnames, filenames in os.walk(root / sub):
            dirnames[:] = [d for d in dirnames if not os.path.islink(os.path.join(dirpath, d))]
            for fn in filenames:
                if fn.startswith(".") and fn.endswith(".tmp") and small_tmp_abandoned(Path(dirpath) / fn):
                    report.tmp.append(f"{sub}/{fn}")
                    if not dry_run:
                        with contextlib.suppress(FileNotFoundError):
                            os.unlink(os.path.join(dirpath, fn))
    # verified/ markers of objects that are gone
    if not dry_run:
        objs = store.object_dirs()
        for dirpath, _dirnames, filenames in os.walk(root / "verified"):
            for fn in filenames:
                if is_id(fn) and fn not in objs:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(os.path.join(dirpath, fn))
