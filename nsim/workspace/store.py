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

What holds under concurrent processes, kills and hostile files:

* **gc never collects live work.** Roots are the refs, the ids in live leases, and every object
  younger than the grace period (``nsim gc --grace``, 1 hour by default); their inputs are kept
  too. A process holds an id (writes it into its lease) and then looks at the object while it
  has ``hold.lock`` shared; gc chooses its victims and moves them into ``trash/`` (one rename
  each) while it has that lock exclusive. So either gc sees the hold, or the holder sees the
  object gone (a cache miss) — never an object that vanishes after it was found whole. Removal
  is atomic: an object is whole in ``objects/`` or not there at all. Before deleting the trash,
  gc reads refs and leases once more and moves back anything they reach (refs written by hand,
  or the trash of a gc killed midway).
* **Nothing read from a workspace is trusted.** Ref contents and cache records must be 64 hex
  digits; every object path stays inside ``objects/``; manifest file names are relative and
  normalised; an input a stage reads is checked against its manifest first (``Store.get``, with
  a stat marker under ``verified/`` so an unchanged object is not re-hashed); a damaged input
  stops the stage with one line naming the artifact and the file.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import errno
import hashlib
import json
import logging
import os
import posixpath
import re
import shutil
import socket
import stat
import threading
import time
import uuid
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from nsim.config import canonical_json, to_dict
from nsim.errors import InputError, WorkspaceError
from nsim.io import atomic_write_bytes
from nsim.io.canonical import canonical_floats
from nsim.workspace.fingerprint import code_fingerprint

log = logging.getLogger(__name__)

FORMAT = 1
MARKER = "nsim-workspace.json"
MANIFEST = "manifest.json"
KINDS = ("capture", "poses", "scene-checkpoint", "human-checkpoint", "trajectory", "render", "evaluation", "export",
         "recording", "registration", "baked-scene")
SUBDIRS = ("objects", "actions", "refs", "tmp", "leases", "verified", "trash")
# Manifest fields that describe one run rather than the content; they do not enter the id.
VOLATILE_FIELDS = ("id", "timing")
_REF_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*(/[A-Za-z0-9_][A-Za-z0-9_.-]*)*$")
_HEX_RE = re.compile(r"^[0-9a-f]+$")
_ID_RE = re.compile(r"^[0-9a-f]{64}$")
_CHUNK = 1 << 20
STALE_TMP_S = 24 * 3600.0
DEFAULT_GRACE_S = 3600.0
# A lease is refreshed by its process every LEASE_HEARTBEAT_S; one on another host whose file
# has not been touched for LEASE_TIMEOUT_S is taken as abandoned (its process cannot be asked).
LEASE_HEARTBEAT_S = 60.0
LEASE_TIMEOUT_S = 15 * 60.0
_MAX_MANIFEST_BYTES = 64 << 20
_HOST = socket.gethostname()


def is_id(value: object) -> bool:
    """True for a full artifact id: 64 lower-case hex digits."""
    return isinstance(value, str) and _ID_RE.match(value) is not None


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


def manifest_id(manifest: Mapping[str, Any]) -> str:
    """The artifact id: digest of the manifest without its volatile fields."""
    content = {k: v for k, v in manifest.items() if k not in VOLATILE_FIELDS}
    return hashlib.sha256(canonical_json(content)).hexdigest()


def safe_relpath(name: object) -> bool:
    """A manifest file name: relative, normalised POSIX, no ``..``, no empty or hidden-tmp parts."""
    if not isinstance(name, str) or not name or "\\" in name or "\x00" in name:
        return False
    if name.startswith("/") or posixpath.normpath(name) != name:
        return False
    return all(part not in ("", ".", "..") for part in name.split("/"))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


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


def _sync_files(root: Path, paths: list[Path]) -> None:
    """Make ``paths`` durable: one ``syncfs`` when there are many files, else an fsync each."""
    if len(paths) > 16 and _syncfs(root):
        return
    for p in paths:
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    for d in {p.parent for p in paths}:
        _fsync_dir(d)


def _tmp_name(path: Path) -> Path:
    """A sibling temp name that says who writes it (host, pid), so gc can tell debris from work."""
    return path.with_name(f".{path.name}.{_HOST}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")


def _write_atomic(path: Path, data: bytes) -> None:
    if path.is_dir() and not path.is_symlink():
        raise WorkspaceError(f"{path}: is a directory, cannot write a file there")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, data, tmp=_tmp_name(path))


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


def _proc_start(pid: int) -> str | None:
    """The start time of a local process (clock ticks since boot), to tell a reused pid apart."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[-1].split()
    except OSError:
        return None
    return fields[19] if len(fields) > 19 else None


def _pid_alive(pid: int, start: str | None = None) -> bool:
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
    return start is None or _proc_start(pid) in (None, start)


def _stat_sig(path: Path) -> list[int] | None:
    """What changes when a file is rewritten, renamed over or chmod-ed: size, mtime, ctime, inode."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    if not stat.S_ISREG(st.st_mode):
        return None
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]


def _read_small(path: Path, limit: int, what: str) -> bytes:
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


def parse_manifest(raw: bytes, what: str) -> dict[str, Any]:
    """A manifest's JSON, checked for the fields the workspace relies on; WorkspaceError naming ``what``."""
    try:
        m = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise WorkspaceError(f"{what}: not valid JSON") from None
    if not isinstance(m, dict):
        raise WorkspaceError(f"{what}: expected a JSON object, got {type(m).__name__}")
    if not isinstance(m.get("kind"), str) or not isinstance(m.get("stage"), str):
        raise WorkspaceError(f"{what}: 'kind' and 'stage' must be strings")
    files = m.get("files")
    if not isinstance(files, dict):
        raise WorkspaceError(f"{what}: 'files' must be an object")
    for name, info in files.items():
        if not safe_relpath(name) or name == MANIFEST:
            raise WorkspaceError(f"{what}: file name {name!r} is not a relative, normalised path inside the artifact")
        if (not isinstance(info, dict) or not isinstance(info.get("size"), int) or info["size"] < 0
                or not is_id(info.get("sha256"))):
            raise WorkspaceError(f"{what}: files[{name!r}] needs a 'sha256' of 64 hex digits and an integer 'size'")
    inputs = m.get("inputs", {})
    if not isinstance(inputs, dict) or not all(isinstance(k, str) and is_id(v) for k, v in inputs.items()):
        raise WorkspaceError(f"{what}: 'inputs' must map names to artifact ids")
    return m


@dataclasses.dataclass(frozen=True)
class Artifact:
    """A published artifact: an immutable directory addressed by its id."""

    id: str
    path: Path

    @property
    def manifest(self) -> dict[str, Any]:
        what = f"artifact {self.id[:12]}: {MANIFEST}"
        try:
            raw = _read_small(self.path / MANIFEST, _MAX_MANIFEST_BYTES, what)
        except FileNotFoundError:
            raise WorkspaceError(f"{what}: missing (the artifact is damaged or being removed)") from None
        return parse_manifest(raw, what)

    @property
    def kind(self) -> str:
        return self.manifest["kind"]

    def file(self, rel: str) -> Path:
        """Path of one file of the artifact; :class:`InputError` if it does not exist."""
        if not safe_relpath(rel):
            raise InputError(f"artifact {self.id[:12]}: {rel!r} is not a path inside the artifact")
        p = self.path / rel
        if p.is_symlink():
            raise WorkspaceError(f"artifact {self.id[:12]}: {rel} is a symbolic link (the artifact was tampered with)")
        if not p.is_file():
            raise InputError(f"artifact {self.id[:12]}: has no file {rel}")
        return p

    @property
    def short(self) -> str:
        return self.id[:12]


@dataclasses.dataclass
class Pending:
    """An artifact being written: stages write files under ``dir``.

    After the ``publish`` block, ``artifact`` is the published artifact and ``hit`` is
    True if an identical artifact already existed (another writer won the race).
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


@dataclasses.dataclass(frozen=True)
class VerifyProblem:
    file: str
    reason: str

    def __str__(self) -> str:
        return f"{self.file}: {self.reason}"


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


class _Lease:
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
                self.path = self.dir / f"{_HOST}.{self.pid}.{uuid.uuid4().hex[:12]}.json"
                if not self._atexit:
                    atexit.register(self.release)
                    self._atexit = True
                threading.Thread(target=self._heartbeat, name="nsim-lease", daemon=True).start()
            body = {"host": _HOST, "pid": self.pid, "pid_start": _proc_start(self.pid), "ids": sorted(self.ids)}
            _write_atomic(self.path, json.dumps(body).encode() + b"\n")

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
        self._lease = _Lease(self.root)
        marker = self.root / MARKER
        if self.root.exists() and not self.root.is_dir():
            raise WorkspaceError(f"{self.root}: workspace path exists and is not a directory")
        if marker.is_file():
            try:
                fmt = json.loads(_read_small(marker, 4096, str(marker))).get("format")
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
            _write_atomic(marker, json.dumps({"format": FORMAT}).encode() + b"\n")
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

    # ---------------------------------------------------------------- keys and lookup
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

    def _read_action(self, p: Path) -> str | None:
        """The id a run-cache entry names, or None when the entry is missing or not a valid record."""
        try:
            rec = json.loads(_read_small(p, 4096, f"run cache entry {p.name[:12]}"))
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
        art_id = self._read_action(self._action_path(key))
        if art_id is None:
            return None
        with self._holding():
            self.hold([art_id])
            m = self._complete_manifest(art_id)
        if m is None:
            return None
        if m["kind"] in KINDS:
            with contextlib.suppress(WorkspaceError):
                if self._read_ref_file(self.root / "refs" / m["kind"] / "latest", "") != art_id:
                    self.set_ref(f"{m['kind']}/latest", art_id)
        return Artifact(art_id, self.object_path(art_id))

    def object_path(self, art_id: str) -> Path:
        if not is_id(art_id):
            raise WorkspaceError(f"{str(art_id)[:80]!r} is not an artifact id (64 hex digits)")
        return self.root / "objects" / art_id[:2] / art_id

    def _complete_manifest(self, art_id: str, path: Path | None = None) -> dict[str, Any] | None:
        """The manifest when the object looks whole (cheap: parse, id, every listed file's size), else None."""
        obj = path if path is not None else self.object_path(art_id)
        try:
            m = Artifact(art_id, obj).manifest
        except WorkspaceError:
            return None
        if manifest_id(m) != art_id or m.get("id") != art_id:
            return None
        for rel, info in m["files"].items():
            sig = _stat_sig(obj / rel)
            if sig is None or sig[0] != info["size"]:
                return None
        return m

    def hold(self, ids: Iterable[str]) -> None:
        """Add ids to this process's lease: gc keeps them (and their inputs) while the process runs.

        To rely on an object found after the hold, hold and look inside :meth:`_holding`.
        """
        self._lease.hold(ids)

    def _lock_fd(self) -> int | None:
        try:
            return os.open(self.root / "hold.lock", os.O_RDWR | os.O_CREAT, 0o644)
        except OSError:
            try:
                return os.open(self.root / "hold.lock", os.O_RDONLY)
            except OSError:
                return None  # a read-only workspace without the lock file: nobody can gc it either

    @contextlib.contextmanager
    def _holding(self) -> Iterator[None]:
        """``hold.lock`` shared: holds taken and objects looked at inside cannot interleave with gc's
        choosing and trashing of victims (which it does with the lock exclusive)."""
        import fcntl

        fd = self._lock_fd()
        try:
            if fd is not None:
                fcntl.flock(fd, fcntl.LOCK_SH)
            yield
        finally:
            if fd is not None:
                os.close(fd)

    @contextlib.contextmanager
    def _collecting(self) -> Iterator[None]:
        import fcntl

        fd = self._lock_fd()
        if fd is None:
            raise WorkspaceError(f"{self.root}: cannot open hold.lock; gc needs a writable workspace")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)

    def release(self) -> None:
        """Drop this process's lease (it also goes when the process exits)."""
        self._lease.release()
        self._checked_ids.clear()  # no longer held: the next get holds and checks again

    def get(self, art_id: str) -> Artifact:
        """The artifact with this id; a checked store also holds it and verifies it (see :meth:`check`)."""
        obj = self.object_path(art_id)
        if art_id in self._checked_ids and self._lease.pid == os.getpid():  # held and checked: gc cannot take it
            return Artifact(art_id, obj)
        with self._holding() if self.checked else contextlib.nullcontext():
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

        A full re-hash runs once per object state: afterwards a marker under ``verified/`` keeps
        the manifest's digest and each file's (size, mtime, ctime, inode); while they are unchanged
        (ctime changes with any write or chmod) the object is taken as verified.
        """
        if art_id in self._checked_ids:
            return
        obj = self.object_path(art_id)
        marker = self.root / "verified" / art_id[:2] / art_id
        try:
            raw = _read_small(obj / MANIFEST, _MAX_MANIFEST_BYTES, f"artifact {art_id[:12]}: {MANIFEST}")
        except FileNotFoundError:
            raise WorkspaceError(f"artifact {art_id[:12]} is not in the workspace {self.root}") from None
        digest = hashlib.sha256(raw).hexdigest()
        m = parse_manifest(raw, f"artifact {art_id[:12]}: {MANIFEST}")
        try:
            rec = json.loads(_read_small(marker, _MAX_MANIFEST_BYTES, "marker"))
            ok = (isinstance(rec, dict) and rec.get("manifest_sha256") == digest
                  and isinstance(rec.get("files"), dict) and set(rec["files"]) == set(m["files"])
                  and all(_stat_sig(obj / rel) == sig for rel, sig in rec["files"].items()))
        except (OSError, WorkspaceError, ValueError, TypeError):
            ok = False
        if not ok:
            problems = self.verify(art_id)
            if problems:
                raise WorkspaceError(
                    f"{m['kind']} artifact {art_id[:12]} is damaged: {problems[0]} "
                    f"(see 'nsim verify {art_id[:12]}'; rerun the stage that made it with --force to repair it)"
                )
            self._write_marker(art_id, digest, {rel: _stat_sig(obj / rel) for rel in m["files"]})
        self._checked_ids.add(art_id)

    def _write_marker(self, art_id: str, manifest_sha256: str, sigs: Mapping[str, Any]) -> None:
        body = {"manifest_sha256": manifest_sha256, "files": dict(sigs)}
        with contextlib.suppress(OSError):
            _write_atomic(self.root / "verified" / art_id[:2] / art_id, json.dumps(body).encode())

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
        tmp = tmp_root / f"{stage}.{_HOST}.{os.getpid()}.{uuid.uuid4().hex[:12]}"
        tmp.mkdir()
        pending = Pending(dir=tmp)
        try:
            yield pending
            if (tmp / MANIFEST).exists():
                raise RuntimeError(f"stage {stage} wrote {MANIFEST}, which is reserved for the workspace")
            files = self._hash_and_sync(tmp)
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
                "host": _HOST,
                **pending.timing,
            }
            raw = json.dumps(manifest, indent=1, sort_keys=False).encode() + b"\n"
            with open(tmp / MANIFEST, "wb") as f:
                f.write(raw)
                f.flush()
                os.fsync(f.fileno())
            self._freeze(tmp)
            _fsync_dir(tmp)
            sigs = {rel: _stat_sig(tmp / rel) for rel in files}
            self.hold([art_id])
            placed = self._place(tmp, art_id, pending)
            pending.artifact = Artifact(art_id, self.object_path(art_id))
            if placed:
                self._write_marker(art_id, hashlib.sha256(raw).hexdigest(), sigs)
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
            with self._holding():  # a copy found in place is held before gc can choose it
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
                _fsync_dir(dest.parent)
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

    def _to_trash(self, path: Path, art_id: str, suffix: str = "gc") -> Path | None:
        """Move an object directory into ``trash/`` in one rename (None if it was already gone)."""
        trash = self.root / "trash"
        trash.mkdir(exist_ok=True)
        target = trash / f"{art_id}.{_HOST}.{os.getpid()}.{uuid.uuid4().hex[:8]}.{suffix}"
        try:
            if not path.is_symlink():
                os.chmod(path, 0o755)  # a directory only moves to another parent if it is writable
            os.rename(path, target)
        except FileNotFoundError:
            return None
        return target

    def _record_action(self, key: str, art_id: str, stage: str) -> None:
        _write_atomic(self._action_path(key), json.dumps({"id": art_id, "stage": stage}).encode() + b"\n")

    @staticmethod
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
        _sync_files(root, paths)
        return dict(sorted(files.items()))

    @staticmethod
    def _freeze(root: Path) -> None:
        """Mark files and sub-directories read-only (the top directory is frozen after the rename)."""
        for dirpath, _dirnames, filenames in os.walk(root, topdown=False):
            for name in filenames:
                os.chmod(os.path.join(dirpath, name), 0o444)
            if Path(dirpath) != root:
                os.chmod(dirpath, 0o555)

    # ---------------------------------------------------------------- refs
    def check_ref_destination(self, name: str) -> None:
        """Refuse a ref name that is invalid or cannot be written here (a folder of refs, or below a ref)."""
        check_ref_name(name)
        base = self.root / "refs"
        parts = name.split("/")
        for i in range(1, len(parts)):
            p = base.joinpath(*parts[:i])
            if p.is_symlink() or (p.exists() and not p.is_dir()):
                raise InputError(f"ref {'/'.join(parts[:i])} exists, so no ref can be named {name} (below it)")
        p = base / name
        if p.is_symlink():
            raise WorkspaceError(f"{p}: is a symbolic link, which the workspace never writes")
        if p.is_dir():
            raise InputError(f"{name} is a folder of refs (e.g. {name}/latest), not a ref; choose another name")

    def set_ref(self, name: str, art_id: str) -> None:
        self.check_ref_destination(name)
        if not is_id(art_id):
            raise WorkspaceError(f"cannot point ref {name} at {str(art_id)[:80]!r}: not an artifact id")
        with self._holding():
            self.hold([art_id])
            if self._complete_manifest(art_id) is None:
                raise WorkspaceError(f"cannot point ref {name} at {art_id[:12]}: no such artifact")
            _write_atomic(self.root / "refs" / name, art_id.encode() + b"\n")

    def delete_ref(self, name: str) -> None:
        check_ref_name(name)
        p = self.root / "refs" / name
        if p.is_symlink() or not p.is_file():
            raise WorkspaceError(f"no ref named {name}")
        p.unlink()

    def _read_ref_file(self, p: Path, name: str) -> str:
        try:
            raw = _read_small(p, 256, f"ref {name}")
        except FileNotFoundError:
            raise WorkspaceError(f"no ref named {name}") from None
        text = raw.decode("ascii", errors="replace").strip()
        if not is_id(text):
            raise WorkspaceError(f"ref {name}: does not hold an artifact id (64 hex digits); fix it with 'nsim tag ID {name}'")
        return text

    def _ref_files(self) -> Iterator[tuple[str, Path]]:
        base = self.root / "refs"
        for dirpath, dirnames, filenames in os.walk(base):
            dirnames[:] = sorted(d for d in dirnames if not os.path.islink(os.path.join(dirpath, d)))
            for fn in sorted(filenames):
                if fn.startswith("."):
                    continue
                p = Path(dirpath) / fn
                yield p.relative_to(base).as_posix(), p

    def refs(self) -> dict[str, str]:
        """All readable refs, name -> id (see :meth:`bad_refs` for the others)."""
        out = {}
        for name, p in self._ref_files():
            with contextlib.suppress(WorkspaceError):
                out[name] = self._read_ref_file(p, name)
        return out

    def bad_refs(self) -> dict[str, str]:
        """Refs whose file does not hold an id (name -> why); they protect nothing from gc."""
        out = {}
        for name, p in self._ref_files():
            try:
                self._read_ref_file(p, name)
            except WorkspaceError as exc:
                out[name] = str(exc)
        return out

    def broken_refs(self) -> dict[str, str]:
        return {n: i for n, i in self.refs().items() if not (self.object_path(i) / MANIFEST).is_file()}

    # ---------------------------------------------------------------- resolution
    def _object_dirs(self) -> dict[str, Path]:
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
        return [i for i, p in self._object_dirs().items() if (p / MANIFEST).is_file()]

    def damaged_ids(self) -> list[str]:
        """Object directories without a manifest (left by an interrupted removal or by hand)."""
        return [i for i, p in self._object_dirs().items() if not (p / MANIFEST).is_file()]

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
        ref_file = self.root / "refs" / spec
        if _REF_RE.match(spec) and ".." not in spec.split("/") and (ref_file.is_file() or ref_file.is_symlink()):
            art_id = self._read_ref_file(ref_file, spec)
            with self._holding():
                self.hold([art_id])
                found = (self.object_path(art_id) / MANIFEST).is_file()
            if not found:
                raise WorkspaceError(f"ref {spec} points at {art_id[:12]}, which is not in the workspace")
        elif _HEX_RE.match(spec) and 4 <= len(spec) <= 64:
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

    # ---------------------------------------------------------------- inspection
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
        """Re-hash an artifact; the list of problems is empty when it is intact.

        Reports listed files that are missing, not regular files or symbolic links, or whose size
        or digest differ; entries the manifest does not list; and a manifest that is unreadable,
        names unsafe paths or does not hash to the id. Never follows a symbolic link.
        """
        obj = self.object_path(art_id)
        if obj.is_symlink() or not obj.is_dir():
            return [VerifyProblem("(object)", "missing from objects/")]
        try:
            m = Artifact(art_id, obj).manifest
        except WorkspaceError as exc:
            return [VerifyProblem(MANIFEST, str(exc).split(f"{MANIFEST}: ", 1)[-1])]
        problems: list[VerifyProblem] = []
        listed = m["files"]
        present: dict[str, str] = {}  # rel -> "file" | "link" | "other"
        for dirpath, dirnames, filenames in os.walk(obj):
            for name in [*dirnames, *filenames]:
                p = Path(dirpath) / name
                rel = p.relative_to(obj).as_posix()
                try:
                    mode = os.lstat(p).st_mode
                except FileNotFoundError:
                    continue
                if stat.S_ISLNK(mode):
                    present[rel] = "link"
                elif stat.S_ISREG(mode):
                    present[rel] = "file"
                elif not stat.S_ISDIR(mode):
                    present[rel] = "other"
        for rel in sorted(present):
            if rel == MANIFEST or rel in listed:
                continue
            what = {"link": "symbolic link", "other": "special file", "file": "file"}[present[rel]]
            problems.append(VerifyProblem(rel, f"{what} is not listed in the manifest"))
        for rel, info in listed.items():
            kind = present.get(rel)
            if kind is None:
                problems.append(VerifyProblem(rel, "missing"))
                continue
            if kind == "link":
                problems.append(VerifyProblem(rel, "is a symbolic link (not followed)"))
                continue
            if kind != "file":
                problems.append(VerifyProblem(rel, "is not a regular file"))
                continue
            digest, size = sha256_file(obj / rel)
            if size != info["size"]:
                problems.append(VerifyProblem(rel, f"size {size} != {info['size']} in manifest"))
            elif digest != info["sha256"]:
                problems.append(VerifyProblem(rel, "content digest does not match the manifest"))
        if manifest_id(m) != art_id or m.get("id") != art_id:
            problems.append(VerifyProblem(MANIFEST, "manifest does not hash to the artifact id"))
        return problems

    def size_bytes(self, art: Artifact) -> int:
        try:
            return sum(int(v["size"]) for v in art.manifest["files"].values())
        except WorkspaceError:
            return 0

    # ---------------------------------------------------------------- garbage collection
    def _inputs_of(self, path: Path, art_id: str) -> list[str]:
        try:
            return list(Artifact(art_id, path).manifest.get("inputs", {}).values())
        except WorkspaceError:
            return []

    def _closure(self, roots: Iterable[str], where: Mapping[str, Path]) -> set[str]:
        """Ids reachable from ``roots`` through manifests' inputs (objects looked up in ``where``)."""
        seen: set[str] = set()
        stack = [i for i in roots if is_id(i)]
        while stack:
            i = stack.pop()
            if i in seen:
                continue
            seen.add(i)
            if i in where:
                stack.extend(self._inputs_of(where[i], i))
        return seen

    def reachable(self) -> set[str]:
        """Ids reachable from refs, following each artifact's inputs."""
        objs = self._object_dirs()
        return self._closure(self.refs().values(), objs) & set(objs)

    def leases(self, remove_expired: bool = False) -> tuple[set[str], list[str]]:
        """Ids held by live leases, and the names of expired lease files (removed if asked)."""
        held: set[str] = set()
        expired: list[str] = []
        base = self.root / "leases"
        now = time.time()
        for p in sorted(base.iterdir()) if base.is_dir() else []:
            if p.name.startswith(".") or not p.name.endswith(".json"):
                continue
            parts = p.name[: -len(".json")].rsplit(".", 2)
            try:
                st = p.lstat()
                body = json.loads(_read_small(p, _MAX_MANIFEST_BYTES, f"lease {p.name}"))
                ids = [i for i in body.get("ids", []) if is_id(i)]
            except FileNotFoundError:
                continue
            except (WorkspaceError, ValueError, AttributeError, TypeError, UnicodeDecodeError):
                body, ids = None, []
            live = False
            if body is not None and len(parts) == 3 and parts[1].isdigit():
                if parts[0] == _HOST:
                    live = _pid_alive(int(parts[1]), body.get("pid_start"))
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

    @contextlib.contextmanager
    def _gc_lock(self) -> Iterator[None]:
        import fcntl

        fd = os.open(self.root / "gc.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise WorkspaceError(f"{self.root}: another 'nsim gc' is running on this workspace; try again later") from None
            yield
        finally:
            os.close(fd)

    def gc(self, dry_run: bool = False, grace_s: float = DEFAULT_GRACE_S) -> GcReport:
        """Remove objects nothing keeps, run-cache entries to missing objects, and debris.

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
        with self._gc_lock():
            # Choosing and trashing victims excludes every hold-and-look (see the module doc).
            with self._collecting() if not dry_run else contextlib.nullcontext():
                now = time.time()
                objs = self._object_dirs()
                young = set()
                for i, p in objs.items():
                    try:
                        if now - p.lstat().st_ctime < grace_s:
                            young.add(i)
                    except FileNotFoundError:
                        pass
                held, expired = self.leases(remove_expired=not dry_run)
                report.leases = expired
                keep = self._closure({*self.refs().values(), *held, *young}, objs)
                report.kept_young = len(young)
                report.kept_leased = len(held & set(objs))
                victims = [i for i in objs if i not in keep]
                for i in victims:
                    report.bytes_freed += self.size_bytes(Artifact(i, objs[i]))
                report.objects = list(victims)
                if not dry_run:
                    for i in victims:
                        self._to_trash(objs[i], i)
            if not dry_run:
                report.restored = self._empty_trash()
                report.objects = [i for i in victims if i not in report.restored]
            self._gc_actions(report, dry_run)
            self._gc_debris(report, dry_run)
        return report

    def _empty_trash(self) -> list[str]:
        """Move back trashed objects that refs or leases reach now; delete the rest. Returns the restored ids."""
        trash = self.root / "trash"
        entries: dict[str, Path] = {}
        for p in sorted(trash.iterdir()) if trash.is_dir() else []:
            art_id = p.name.split(".", 1)[0]
            if is_id(art_id) and p.name.endswith(".gc") and p.is_dir() and not p.is_symlink():
                entries.setdefault(art_id, p)
        restored: list[str] = []
        if entries:
            held, _ = self.leases()
            where = {**entries, **self._object_dirs()}
            need = self._closure({*self.refs().values(), *held}, where)
            for art_id, p in entries.items():
                if art_id not in need or self._complete_manifest(art_id, p) is None:
                    continue
                dest = self.object_path(art_id)
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
            with contextlib.suppress(FileNotFoundError):
                remove_tree(p)
        return restored

    def _gc_actions(self, report: GcReport, dry_run: bool) -> None:
        actions = self.root / "actions"
        gone = set(report.objects)
        for dirpath, dirnames, filenames in os.walk(actions):
            dirnames[:] = [d for d in dirnames if not os.path.islink(os.path.join(dirpath, d))]
            for fn in sorted(filenames):
                p = Path(dirpath) / fn
                if fn.startswith("."):
                    continue  # an entry being written (or debris: see _gc_debris)
                target = self._read_action(p) if is_id(fn) else None
                if target is None or target in gone or not (self.object_path(target) / MANIFEST).is_file():
                    report.actions.append(fn)
                    if not dry_run:
                        with contextlib.suppress(FileNotFoundError):
                            p.unlink()

    def _gc_debris(self, report: GcReport, dry_run: bool) -> None:
        tmp_root = self.root / "tmp"
        if tmp_root.is_symlink() or not tmp_root.is_dir():
            raise WorkspaceError(f"{tmp_root}: the workspace's tmp/ is not a directory; move that file away")
        for p in sorted(tmp_root.iterdir()):
            if self._tmp_abandoned(p):
                report.tmp.append(p.name)
                if not dry_run:
                    with contextlib.suppress(FileNotFoundError):
                        remove_tree(p)
        # half-written small files (refs, cache entries, leases, markers) of dead writers
        for sub in ("refs", "actions", "leases", "verified"):
            for dirpath, dirnames, filenames in os.walk(self.root / sub):
                dirnames[:] = [d for d in dirnames if not os.path.islink(os.path.join(dirpath, d))]
                for fn in filenames:
                    if fn.startswith(".") and fn.endswith(".tmp") and self._small_tmp_abandoned(Path(dirpath) / fn):
                        report.tmp.append(f"{sub}/{fn}")
                        if not dry_run:
                            with contextlib.suppress(FileNotFoundError):
                                os.unlink(os.path.join(dirpath, fn))
        # verified/ markers of objects that are gone
        if not dry_run:
            objs = self._object_dirs()
            for dirpath, _dirnames, filenames in os.walk(self.root / "verified"):
                for fn in filenames:
                    if is_id(fn) and fn not in objs:
                        with contextlib.suppress(FileNotFoundError):
                            os.unlink(os.path.join(dirpath, fn))

    @staticmethod
    def _small_tmp_abandoned(p: Path) -> bool:
        """``.<name>.<host>.<pid>.<rand>.tmp`` from :func:`_write_atomic`: dead local pid, or old."""
        try:
            age = time.time() - p.lstat().st_mtime
        except FileNotFoundError:
            return False
        parts = p.name[: -len(".tmp")].rsplit(".", 2)
        if len(parts) == 3 and parts[1].isdigit() and parts[0].endswith("." + _HOST):
            return not _pid_alive(int(parts[1]))
        return age > STALE_TMP_S

    @staticmethod
    def _tmp_abandoned(p: Path) -> bool:
        parts = p.name.split(".")
        try:
            age = time.time() - p.lstat().st_mtime
        except FileNotFoundError:
            return False
        if len(parts) >= 4 and parts[-2].isdigit():
            pid = int(parts[-2])
            writer_host = ".".join(parts[1:-2])
            if writer_host == _HOST:
                return not _pid_alive(pid)
        return age > STALE_TMP_S


def check_ref_name(name: str) -> None:
    if not _REF_RE.match(name) or any(seg in (".", "..") for seg in name.split("/")) or name.endswith(".tmp"):
        raise InputError(f"invalid ref name {name!r}: use letters, digits, '_', '-', '.' and '/' (e.g. scene/lab)")
    if _HEX_RE.match(name) and len(name) >= 4:
        raise InputError(f"invalid ref name {name!r}: it looks like an artifact id prefix")


def default_root() -> Path:
    """``$NSIM_WORKSPACE`` if set, else ``./nsim-workspace``."""
    env = os.environ.get("NSIM_WORKSPACE")
    return Path(env) if env else Path("nsim-workspace")
