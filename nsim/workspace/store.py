"""The content-addressed workspace: an action cache over an immutable object store.

Layout of a workspace root::

    nsim-workspace.json          marker: {"format": 1}
    objects/ab/abcdef.../        one artifact: its files + manifest.json, read-only
    actions/12/1234.../          action key -> {"id": ...}: the run cache
    refs/scene/lab               human names -> artifact id (one line of 64 hex digits)
    leases/<host>.<pid>.<tag>.json   ids a running process reads or publishes (gc keeps them)
    verified/ab/abcdef...        what a stage last checked of an object: file stats, manifest digest
    trash/<id>.<tag>             objects being removed (renamed here first, then deleted)
    gc.lock, hold.lock           one gc at a time; holds exclude gc's choosing of victims
    tmp/                         artifacts being written; debris after a crash (gc removes it)

An artifact's **id** is the SHA-256 of its manifest without the ``id`` and ``timing`` fields;
the manifest lists every file's SHA-256 and size, so the id covers the content. The
**action key** is the SHA-256 of (stage, stage version, canonical config, named input ids,
seed, code fingerprint); :meth:`Store.lookup` maps it to an id, so a stage whose key is
present returns at once.

Publishing writes under ``tmp/``, fsyncs, hashes, then ``os.replace``-renames the directory
into ``objects/``. A writer that finds the id already there keeps that copy if it verifies and
replaces it (a repair) if it does not. A writer killed at any point leaves only ``tmp/`` debris.

:class:`Store` is the workspace as callers see it. It holds the objects, the run cache and
publishing itself, and hands the other concerns to one module each: ids, manifests and the
:class:`Artifact` handle (:mod:`~nsim.workspace.artifacts`), refs (:mod:`~nsim.workspace.refs`),
leases and ``hold.lock`` (:mod:`~nsim.workspace.leases`), whole-or-damaged checks and the
``verified/`` markers (:mod:`~nsim.workspace.verify`), gc (:mod:`~nsim.workspace.garbage`), and
below them file digests and durable writes (:mod:`~nsim.workspace.files`) and the writer-tagged
temporary names (:mod:`~nsim.workspace.writers`).

What holds under concurrent processes, kills and hostile files:

* **gc never collects live work.** Roots are the refs, the ids in live leases, and every object
  younger than the grace period; their inputs are kept too. A process holds an id and looks at
  the object under ``hold.lock`` shared, gc chooses and trashes its victims under it exclusive,
  so a stage never sees an object vanish after it found it whole (details in
  :mod:`~nsim.workspace.leases` and :mod:`~nsim.workspace.garbage`).
* **Nothing read from a workspace is trusted.** Ref contents and cache records must be 64 hex
  digits; every object path stays inside ``objects/``; manifest file names are relative and
  normalised; an input a stage reads is checked against its manifest first (``Store.get``, with
  a stat marker under ``verified/`` so an unchanged object is not re-hashed); a damaged input
  stops the stage with one line naming the artifact and the file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import logging
import os
import shutil
import stat
import time
import uuid
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from nsim.config import canonical_json, to_dict
from nsim.errors import InputError, WorkspaceError
from nsim.io import fsync_path
from nsim.io.canonical import canonical_floats
from nsim.workspace.artifacts import KINDS, MANIFEST, Artifact, is_hex, is_id, manifest_id, safe_relpath
from nsim.workspace.files import (
    read_small,
    sha256_file,
    sha256_path,
    stat_sig,
    sync_files,
    write_atomic,
)
from nsim.workspace.fingerprint import code_fingerprint
from nsim.workspace.garbage import DEFAULT_GRACE_S, GcReport, closure, collect_garbage
from nsim.workspace.leases import Lease, holding, live_leases
from nsim.workspace.refs import Refs
from nsim.workspace.verify import VerifyProblem, check_object, complete_manifest, verify_object, write_marker
from nsim.workspace.writers import HOST, tmp_dir_name

__all__ = [
    "FORMAT", "KINDS", "MANIFEST", "MARKER", "SUBDIRS", "Artifact", "GcReport", "Pending", "Store", "VerifyProblem",
    "default_root", "is_id", "manifest_id", "remove_tree", "safe_relpath", "sha256_file", "sha256_path",
]

log = logging.getLogger(__name__)

FORMAT = 1
MARKER = "nsim-workspace.json"
SUBDIRS = ("objects", "actions", "refs", "tmp", "leases", "verified", "trash")


@dataclasses.dataclass
class Pending:
    """An artifact being written: stages write files under ``dir``.

    After the ``publish`` block, ``artifact`` is the published artifact, ``raced`` is True if an
    identical artifact already existed (another writer won the race) and ``repaired`` if a damaged
    copy of it was replaced.
    """

    dir: Path
    summary: dict[str, Any] = dataclasses.field(default_factory=dict)
    # run facts that vary between identical runs (per-phase wall times): kept in the manifest's
    # ``timing``, outside the id, so reruns keep their digest
    timing: dict[str, Any] = dataclasses.field(default_factory=dict)
    artifact: Artifact | None = None
    raced: bool = False
    repaired: bool = False

    @property
    def ref(self) -> str:
        assert self.artifact is not None, "artifact is only known after the publish block"
        return self.artifact.id


class Store:
    """A workspace rooted at ``root``.

    ``create``: make the workspace if there is none (stages); False for commands that only read.
    ``checked``: :meth:`get` holds each artifact in this process's lease and checks it against its
    manifest before handing it out (what stages read); False for inspection (``ls``, ``show``,
    ``verify``), which must be able to look at a damaged artifact.
    """

    def __init__(self, root: str | os.PathLike[str], create: bool = True, checked: bool = True):
        self.root = Path(root).expanduser().absolute()
        self.checked = checked
        self._checked_ids: set[str] = set()
        self._lease = Lease(self.root)
        self._refs = Refs(self.root / "refs")
        marker = self.root / MARKER
        if self.root.exists() and not self.root.is_dir():
            raise WorkspaceError(f"{self.root}: workspace path exists and is not a directory")
        if marker.is_file():
            try:
                fmt = json.loads(read_small(marker, 4096, str(marker))).get("format")
            except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
                raise WorkspaceError(f"{marker}: corrupt workspace marker") from None
            if fmt != FORMAT:
                raise WorkspaceError(f"{marker}: workspace format {fmt} is not supported (expected {FORMAT})")
        elif create:
            if self.root.is_dir() and any(p.name != MARKER for p in self.root.iterdir()):
                known = {*SUBDIRS, "gc.lock", "hold.lock"}
                if not {p.name for p in self.root.iterdir()} <= known:
                    raise WorkspaceError(
                        f"{self.root}: directory exists, is not empty and is not an nsim workspace"
                    )
            for sub in SUBDIRS:
                (self.root / sub).mkdir(parents=True, exist_ok=True)
            write_atomic(marker, json.dumps({"format": FORMAT}).encode() + b"\n")
        else:
            raise WorkspaceError(
                f"{self.root}: no nsim workspace here (a stage such as 'nsim capture synth' creates one; "
                "or pass --workspace / set NSIM_WORKSPACE)"
            )
        for sub in SUBDIRS:
            p = self.root / sub
            if p.is_symlink() or (p.exists() and not p.is_dir()):
                raise WorkspaceError(f"{p}: the workspace's {sub}/ is not a directory; move that file away")
            if create:
                p.mkdir(exist_ok=True)

    # ---------------------------------------------------------------- run cache
    def action_key(
        self,
        stage: str,
        version: int,
        config: Any,
        inputs: Mapping[str, str] | None = None,
        seed: int | None = None,
        extra: Mapping[str, Any] | None = None,
    ) -> str:
        """Digest of everything that determines a stage's output."""
        payload = {
            "stage": stage,
            "version": version,
            "config": to_dict(config) if dataclasses.is_dataclass(config) else config,
            "inputs": dict(sorted((inputs or {}).items())),
            "seed": seed,
            "fingerprint": code_fingerprint(),
            "extra": dict(extra or {}),
        }
        return hashlib.sha256(canonical_json(payload)).hexdigest()

    def _action_path(self, key: str) -> Path:
        if not is_id(key):
            raise ValueError(f"action key {key!r} is not a SHA-256 hex digest")
        return self.root / "actions" / key[:2] / key

    def read_action(self, p: Path) -> str | None:
        """The id a run-cache entry names, or None when the entry is missing or not a valid record."""
        try:
            rec = json.loads(read_small(p, 4096, f"run cache entry {p.name[:12]}"))
        except FileNotFoundError:
            return None
        except (WorkspaceError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            log.warning("run cache entry %s is damaged (%s); ignored", p.name[:12], exc)
            return None
        art_id = rec.get("id") if isinstance(rec, dict) else None
        if not is_id(art_id):
            log.warning("run cache entry %s does not name an artifact id; ignored", p.name[:12])
            return None
        return art_id

    def lookup(self, key: str) -> Artifact | None:
        """The artifact an action key maps to, or None (a cache miss).

        A hit is held in this process's lease before its object is checked (so a concurrent gc
        either keeps it or this returns a miss), must be complete (manifest and every listed file
        of the listed size), and moves ``<kind>/latest`` to it, as a publish would.
        """
        art_id = self.read_action(self._action_path(key))
        if art_id is None:
            return None
        with holding(self.root):
            self.hold([art_id])
            m = complete_manifest(self.object_path(art_id), art_id)
        if m is None:
            return None
        if m["kind"] in KINDS:
            with contextlib.suppress(WorkspaceError):
                if self._refs.read(f"{m['kind']}/latest") != art_id:
                    self.set_ref(f"{m['kind']}/latest", art_id)
        return Artifact(art_id, self.object_path(art_id))

    def _record_action(self, key: str, art_id: str, stage: str) -> None:
        write_atomic(self._action_path(key), json.dumps({"id": art_id, "stage": stage}).encode() + b"\n")

    # ---------------------------------------------------------------- objects
    def object_path(self, art_id: str) -> Path:
        if not is_id(art_id):
            raise WorkspaceError(f"{str(art_id)[:80]!r} is not an artifact id (64 hex digits)")
        return self.root / "objects" / art_id[:2] / art_id

    def object_dirs(self) -> dict[str, Path]:
        """Every object directory, whole or damaged: id -> path."""
        base = self.root / "objects"
        out: dict[str, Path] = {}
        for shard in sorted(base.iterdir()) if base.is_dir() else []:
            if shard.is_symlink() or not shard.is_dir() or len(shard.name) != 2:
                continue
            for p in sorted(shard.iterdir()):
                if is_id(p.name) and p.name[:2] == shard.name and p.is_dir() and not p.is_symlink():
                    out[p.name] = p
        return out

    def all_ids(self) -> list[str]:
        return [i for i, p in self.object_dirs().items() if (p / MANIFEST).is_file()]

    def damaged_ids(self) -> list[str]:
        """Object directories without a manifest (left by an interrupted removal or by hand)."""
        return [i for i, p in self.object_dirs().items() if not (p / MANIFEST).is_file()]

    def hold(self, ids: Iterable[str]) -> None:
        """Add ids to this process's lease: gc keeps them (and their inputs) while the process runs.

        To rely on an object found after the hold, hold and look inside
        :func:`~nsim.workspace.leases.holding`.
        """
        self._lease.hold(ids)

    def release(self) -> None:
        """Drop this process's lease (it also goes when the process exits)."""
        self._lease.release()
        self._checked_ids.clear()  # no longer held: the next get holds and checks again

    def get(self, art_id: str) -> Artifact:
        """The artifact with this id; a checked store also holds it and verifies it (see :meth:`check`)."""
        obj = self.object_path(art_id)
        if art_id in self._checked_ids and self._lease.pid == os.getpid():  # held and checked: gc cannot take it
            return Artifact(art_id, obj)
        with holding(self.root) if self.checked else contextlib.nullcontext():
            if self.checked:
                self.hold([art_id])
            if obj.is_symlink():
                raise WorkspaceError(f"artifact {art_id[:12]}: {obj} is a symbolic link, which the workspace never writes")
            if not (obj / MANIFEST).is_file():
                raise WorkspaceError(f"artifact {art_id[:12]} is not in the workspace {self.root}")
        if self.checked:
            self.check(art_id)
        return Artifact(art_id, obj)

    def check(self, art_id: str) -> None:
        """Raise WorkspaceError naming the file if an artifact does not match its manifest.

        A full re-hash runs once per object state (see :func:`~nsim.workspace.verify.check_object`),
        and once per store while the artifact stays held.
        """
        if art_id in self._checked_ids:
            return
        check_object(self.root, self.object_path(art_id), art_id)
        self._checked_ids.add(art_id)

    def path(self, spec: str) -> Path:
        return self.get(self.resolve(spec)).path

    # ---------------------------------------------------------------- publishing
    @contextlib.contextmanager
    def publish(
        self,
        *,
        kind: str,
        stage: str,
        version: int,
        key: str,
        config: Any,
        inputs: Mapping[str, str] | None = None,
        seed: int | None = None,
        ref: str | None = None,
    ) -> Iterator[Pending]:
        """Write an artifact atomically.

        Usage::

            with store.publish(kind="capture", stage="capture", version=1, key=key, config=cfg) as out:
                write_files(out.dir)
            art = out.artifact

        The object is renamed into ``objects/``, then ``<kind>/latest`` and ``ref`` are pointed at
        it, then the run cache records it: a kill between any two steps leaves either nothing
        reachable from the cache or an object a ref reaches, never a cache entry to a missing one.
        """
        if kind not in KINDS:
            raise ValueError(f"unknown artifact kind {kind!r}")
        if ref is not None:
            self.check_ref_destination(ref)
        self.hold((inputs or {}).values())
        t0 = time.time()
        tmp_root = self.root / "tmp"
        if tmp_root.is_symlink() or not tmp_root.is_dir():
            raise WorkspaceError(f"{tmp_root}: the workspace's tmp/ is not a directory")
        tmp = tmp_root / tmp_dir_name(stage)
        tmp.mkdir()
        pending = Pending(dir=tmp)
        try:
            yield pending
            if (tmp / MANIFEST).exists():
                raise RuntimeError(f"stage {stage} wrote {MANIFEST}, which is reserved for the workspace")
            files = _hash_and_sync(tmp)
            manifest: dict[str, Any] = {
                "format": FORMAT,
                "kind": kind,
                "stage": stage,
                "stage_version": version,
                "action_key": key,
                "config": to_dict(config) if dataclasses.is_dataclass(config) else config,
                "inputs": dict(sorted((inputs or {}).items())),
                "seed": seed,
                "fingerprint": code_fingerprint(),
                "files": files,
                # floats to 10 significant digits, no -0: a summary computed on another CPU gives the same id
                "summary": canonical_floats(pending.summary),
            }
            art_id = manifest_id(manifest)
            manifest = {"id": art_id, **manifest}
            manifest["timing"] = {
                "wall_time_s": round(time.time() - t0, 3),
                "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "host": HOST,
                **pending.timing,
            }
            raw = json.dumps(manifest, indent=1, sort_keys=False).encode() + b"\n"
            with open(tmp / MANIFEST, "wb") as f:
                f.write(raw)
                f.flush()
                os.fsync(f.fileno())
            _freeze(tmp)
            fsync_path(tmp)
            sigs = {rel: stat_sig(tmp / rel) for rel in files}
            self.hold([art_id])
            placed = self._place(tmp, art_id, pending)
            pending.artifact = Artifact(art_id, self.object_path(art_id))
            if placed:
                write_marker(self.root, art_id, hashlib.sha256(raw).hexdigest(), sigs)
        except BaseException:
            remove_tree(tmp)
            raise
        self.set_ref(f"{kind}/latest", art_id)
        if ref is not None:
            self.set_ref(ref, art_id)
        self._record_action(key, art_id, stage)

    def _place(self, tmp: Path, art_id: str, pending: Pending) -> bool:
        """Rename a finished artifact into ``objects/``; True if this copy was placed.

        If the id is already there and verifies, it is kept (an identical writer won) and ``tmp``
        is discarded; if it is damaged or half-removed, it is moved to ``trash/`` and replaced.
        """
        dest = self.object_path(art_id)
        for _attempt in range(8):
            dest.parent.mkdir(parents=True, exist_ok=True)
            with holding(self.root):  # a copy found in place is held before gc can choose it
                self.hold([art_id])
                try:
                    os.rename(tmp, dest)
                    placed = True
                except OSError as exc:
                    if exc.errno not in (errno.ENOENT, errno.ENOTEMPTY, errno.EEXIST, errno.EISDIR, errno.ENOTDIR):
                        raise
                    placed = False
                    if exc.errno == errno.ENOENT:
                        continue
            if placed:
                os.chmod(dest, 0o555)
                fsync_path(dest.parent)
                return True
            if not self.verify(art_id):
                remove_tree(tmp)
                pending.raced = True
                return False
            log.warning("artifact %s in the workspace is damaged; replacing it with this run's copy", art_id[:12])
            self._to_trash(dest, art_id, suffix="damaged")
            self._checked_ids.discard(art_id)
            pending.repaired = True
        raise WorkspaceError(f"could not place artifact {art_id[:12]} in {dest.parent}: it keeps changing under us")

    # ---------------------------------------------------------------- removal (publish's repairs, and gc)
    def _to_trash(self, path: Path, art_id: str, suffix: str = "gc") -> Path | None:
        """Move an object directory into ``trash/`` in one rename (None if it was already gone)."""
        trash = self.root / "trash"
        trash.mkdir(exist_ok=True)
        target = trash / f"{art_id}.{HOST}.{os.getpid()}.{uuid.uuid4().hex[:8]}.{suffix}"
        try:
            if not path.is_symlink():
                os.chmod(path, 0o755)  # a directory only moves to another parent if it is writable
            os.rename(path, target)
        except FileNotFoundError:
            return None
        return target

    def _delete_tree(self, path: Path) -> None:
        """Delete a tree this store wrote (a ``trash/`` entry, a ``tmp/`` one), read-only files included."""
        with contextlib.suppress(FileNotFoundError):
            remove_tree(path)

    # ---------------------------------------------------------------- refs
    def check_ref_destination(self, name: str) -> None:
        """Refuse a ref name that is invalid or cannot be written here (a folder of refs, or below a ref)."""
        self._refs.check_destination(name)

    def set_ref(self, name: str, art_id: str) -> None:
        self.check_ref_destination(name)
        if not is_id(art_id):
            raise WorkspaceError(f"cannot point ref {name} at {str(art_id)[:80]!r}: not an artifact id")
        with holding(self.root):
            self.hold([art_id])
            if complete_manifest(self.object_path(art_id), art_id) is None:
                raise WorkspaceError(f"cannot point ref {name} at {art_id[:12]}: no such artifact")
            self._refs.write(name, art_id)

    def delete_ref(self, name: str) -> None:
        self._refs.delete(name)

    def refs(self) -> dict[str, str]:
        """All readable refs, name -> id (see :meth:`bad_refs` for the others)."""
        return self._refs.ids()

    def bad_refs(self) -> dict[str, str]:
        """Refs whose file does not hold an id (name -> why); they protect nothing from gc."""
        return self._refs.bad()

    def broken_refs(self) -> dict[str, str]:
        return {n: i for n, i in self.refs().items() if not (self.object_path(i) / MANIFEST).is_file()}

    # ---------------------------------------------------------------- resolution
    def resolve(self, spec: str, kind: str | None = None) -> str:
        """An artifact id from an id, a unique id prefix (>= 4 hex digits) or a ref name."""
        art_id = self.find(spec, kind)
        if art_id is None:
            raise InputError(f"no artifact or ref named '{spec.strip()}' in workspace {self.root} (see 'nsim ls')")
        return art_id

    def find(self, spec: str, kind: str | None = None) -> str | None:
        """:meth:`resolve`, but None where nothing in the workspace has that name (an ambiguous prefix, a dangling
        ref or another kind still raise)."""
        spec = spec.strip()
        if not spec:
            raise InputError("empty artifact reference")
        art_id: str | None = None
        if self._refs.exists(spec):
            art_id = self._refs.read(spec)
            with holding(self.root):
                self.hold([art_id])
                found = (self.object_path(art_id) / MANIFEST).is_file()
            if not found:
                raise WorkspaceError(f"ref {spec} points at {art_id[:12]}, which is not in the workspace")
        elif is_hex(spec) and 4 <= len(spec) <= 64:
            shard = self.root / "objects" / spec[:2]
            hits = sorted(p.name for p in shard.iterdir() if p.name.startswith(spec)) if shard.is_dir() else []
            hits = [h for h in hits if is_id(h) and (shard / h / MANIFEST).is_file()]
            if len(hits) > 1:
                shown = ", ".join(h[:12] for h in hits[:5])
                raise InputError(f"artifact prefix {spec} is ambiguous: {shown}; give more digits")
            if hits:
                art_id = hits[0]
        if art_id is None:
            return None
        if kind is not None:
            actual = self.get(art_id).kind
            if actual != kind:
                raise InputError(f"'{spec}' is a {actual} artifact, expected {kind}")
        return art_id

    # ---------------------------------------------------------------- inspection and maintenance
    def artifacts(self) -> list[Artifact]:
        return [Artifact(i, self.object_path(i)) for i in self.all_ids()]

    def lineage(self, art_id: str) -> dict[str, Any]:
        """Nested ``{"id", "kind", "stage", "inputs": {name: subtree}}`` down to the captures."""
        art = self.get(art_id)
        m = art.manifest
        subtree = {}
        for name, child in m.get("inputs", {}).items():
            if (self.object_path(child) / MANIFEST).is_file():
                subtree[name] = self.lineage(child)
            else:
                subtree[name] = {"id": child, "kind": "missing", "stage": "?", "inputs": {}}
        return {"id": art_id, "kind": m["kind"], "stage": m["stage"], "inputs": subtree}

    def verify(self, art_id: str) -> list[VerifyProblem]:
        """Re-hash an artifact; the list of problems is empty when it is intact (see
        :func:`~nsim.workspace.verify.verify_object`)."""
        return verify_object(self.object_path(art_id), art_id)

    def size_bytes(self, art: Artifact) -> int:
        try:
            return sum(int(v["size"]) for v in art.manifest["files"].values())
        except WorkspaceError:
            return 0

    def reachable(self) -> set[str]:
        """Ids reachable from refs, following each artifact's inputs."""
        objs = self.object_dirs()
        return closure(self.refs().values(), objs) & set(objs)

    def leases(self, remove_expired: bool = False) -> tuple[set[str], list[str]]:
        """Ids held by live leases, and the names of expired lease files (removed if asked)."""
        return live_leases(self.root, remove_expired)

    def gc(self, dry_run: bool = False, grace_s: float = DEFAULT_GRACE_S) -> GcReport:
        """Remove objects nothing keeps, run-cache entries to missing objects, and debris
        (see :func:`~nsim.workspace.garbage.collect_garbage`)."""
        return collect_garbage(self, dry_run, grace_s)


# ---------------------------------------------------------------- the trees the store writes
def _hash_and_sync(root: Path) -> dict[str, dict[str, Any]]:
    """Digest every file under ``root`` and make the data durable before the rename."""
    files: dict[str, dict[str, Any]] = {}
    paths: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in [*dirnames, *filenames]:
            p = Path(dirpath) / name
            if p.is_symlink():
                raise RuntimeError(f"artifact entry {p.relative_to(root).as_posix()} is a symbolic link")
        for name in sorted(filenames):
            p = Path(dirpath) / name
            rel = p.relative_to(root).as_posix()
            if not p.is_file():
                raise RuntimeError(f"artifact file {rel} is not a regular file")
            if not safe_relpath(rel):
                raise RuntimeError(f"artifact file name {rel!r} cannot be stored")
            digest, size = sha256_file(p)
            files[rel] = {"sha256": digest, "size": size}
            paths.append(p)
    sync_files(root, paths)
    return dict(sorted(files.items()))


def _freeze(root: Path) -> None:
    """Mark files and sub-directories read-only (the top directory is frozen after the rename)."""
    for dirpath, _dirnames, filenames in os.walk(root, topdown=False):
        for name in filenames:
            os.chmod(os.path.join(dirpath, name), 0o444)
        if Path(dirpath) != root:
            os.chmod(dirpath, 0o555)


def _make_writable(path: Path) -> None:
    mode = stat.S_IRWXU | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH
    if not path.is_symlink():
        with contextlib.suppress(FileNotFoundError):
            os.chmod(path, mode)
    for dirpath, dirnames, _ in os.walk(path):
        for d in dirnames:
            p = os.path.join(dirpath, d)
            if not os.path.islink(p):
                with contextlib.suppress(FileNotFoundError):
                    os.chmod(p, mode)


def remove_tree(path: Path) -> None:
    """Remove a directory tree, read-only artifacts included (symlinks are removed, never followed)."""
    if not path.exists() and not path.is_symlink():
        return
    if path.is_dir() and not path.is_symlink():
        _make_writable(path)
        shutil.rmtree(path, ignore_errors=False)
    else:
        path.unlink()


def default_root() -> Path:
    """``$NSIM_WORKSPACE`` if set, else ``./nsim-workspace``."""
    env = os.environ.get("NSIM_WORKSPACE")
    return Path(env) if env else Path("nsim-workspace")
