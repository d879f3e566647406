"""The content-addressed workspace: an action cache over an immutable object store.

Layout of a workspace root::

    nsim-workspace.json          marker: {"format": 1}
    objects/ab/abcdef.../        one artifact: its files + manifest.json, read-only
    actions/12/1234.../          action key -> {"id": ...}: the run cache
    refs/scene/lab               human names -> artifact id (one line)
    tmp/                         artifacts being written; debris after a crash (gc removes it)

An artifact's **id** is the SHA-256 of its manifest without the ``id`` and ``timing`` fields;
the manifest lists every file's SHA-256 and size, so the id covers the content. The
**action key** is the SHA-256 of (stage, stage version, canonical config, named input ids,
seed, code fingerprint); :meth:`Store.lookup` maps it to an id, so a stage whose key is
present returns at once.

Publishing writes under ``tmp/``, fsyncs, hashes, then ``os.replace``-renames the directory
into ``objects/``. A writer that finds the id already there lost a race to an identical
writer and discards its copy. A writer killed at any point leaves only ``tmp/`` debris.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import os
import re
import shutil
import socket
import stat
import time
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from nsim.config import canonical_json, to_dict
from nsim.errors import InputError, WorkspaceError
from nsim.workspace.fingerprint import code_fingerprint

FORMAT = 1
MARKER = "nsim-workspace.json"
MANIFEST = "manifest.json"
KINDS = ("capture", "poses", "scene-checkpoint", "human-checkpoint", "trajectory", "render", "evaluation")
# Manifest fields that describe one run rather than the content; they do not enter the id.
VOLATILE_FIELDS = ("id", "timing")
_REF_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*(/[A-Za-z0-9_][A-Za-z0-9_.-]*)*$")
_HEX_RE = re.compile(r"^[0-9a-f]+$")
_CHUNK = 1 << 20
STALE_TMP_S = 24 * 3600.0


def sha256_file(path: Path) -> tuple[str, int]:
    """SHA-256 hex digest and size in bytes of one file."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return h.hexdigest(), size


def manifest_id(manifest: Mapping[str, Any]) -> str:
    """The artifact id: digest of the manifest without its volatile fields."""
    content = {k: v for k, v in manifest.items() if k not in VOLATILE_FIELDS}
    return hashlib.sha256(canonical_json(content)).hexdigest()


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


def _write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _make_writable(path: Path) -> None:
    for dirpath, dirnames, _ in os.walk(path):
        os.chmod(dirpath, stat.S_IRWXU | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)
        for d in dirnames:
            p = os.path.join(dirpath, d)
            if not os.path.islink(p):
                os.chmod(p, stat.S_IRWXU | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)


def remove_tree(path: Path) -> None:
    """Remove a directory tree, read-only artifacts included."""
    if not path.exists() and not path.is_symlink():
        return
    if path.is_dir() and not path.is_symlink():
        _make_writable(path)
        shutil.rmtree(path, ignore_errors=False)
    else:
        path.unlink()


@dataclasses.dataclass(frozen=True)
class Artifact:
    """A published artifact: an immutable directory addressed by its id."""

    id: str
    path: Path

    @property
    def manifest(self) -> dict[str, Any]:
        return json.loads((self.path / MANIFEST).read_text())

    @property
    def kind(self) -> str:
        return self.manifest["kind"]

    def file(self, rel: str) -> Path:
        """Path of one file of the artifact; :class:`InputError` if it does not exist."""
        p = self.path / rel
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
    bytes_freed: int = 0


class Store:
    """A workspace rooted at ``root`` (created on first use)."""

    def __init__(self, root: str | os.PathLike[str], create: bool = True):
        self.root = Path(root).expanduser().absolute()
        marker = self.root / MARKER
        if self.root.exists() and not self.root.is_dir():
            raise WorkspaceError(f"{self.root}: workspace path exists and is not a directory")
        if marker.is_file():
            try:
                fmt = json.loads(marker.read_text()).get("format")
            except (json.JSONDecodeError, AttributeError):
                raise WorkspaceError(f"{marker}: corrupt workspace marker") from None
            if fmt != FORMAT:
                raise WorkspaceError(f"{marker}: workspace format {fmt} is not supported (expected {FORMAT})")
        elif create:
            if self.root.is_dir() and any(p.name != MARKER for p in self.root.iterdir()):
                known = {"objects", "actions", "refs", "tmp"}
                if not {p.name for p in self.root.iterdir()} <= known:
                    raise WorkspaceError(
                        f"{self.root}: directory exists, is not empty and is not an nsim workspace"
                    )
            for sub in ("objects", "actions", "refs", "tmp"):
                (self.root / sub).mkdir(parents=True, exist_ok=True)
            _write_atomic(marker, json.dumps({"format": FORMAT}).encode() + b"\n")
        else:
            raise WorkspaceError(f"{self.root}: not an nsim workspace (no {MARKER})")

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
        return self.root / "actions" / key[:2] / key

    def lookup(self, key: str) -> Artifact | None:
        """The artifact an action key maps to, or None (a cache miss)."""
        p = self._action_path(key)
        try:
            record = json.loads(p.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None
        art_id = record.get("id", "")
        obj = self.object_path(art_id)
        if not (obj / MANIFEST).is_file():
            return None
        return Artifact(art_id, obj)

    def object_path(self, art_id: str) -> Path:
        return self.root / "objects" / art_id[:2] / art_id

    def get(self, art_id: str) -> Artifact:
        obj = self.object_path(art_id)
        if not (obj / MANIFEST).is_file():
            raise WorkspaceError(f"artifact {art_id[:12]} is not in the workspace {self.root}")
        return Artifact(art_id, obj)

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
        """
        if kind not in KINDS:
            raise ValueError(f"unknown artifact kind {kind!r}")
        if ref is not None:
            check_ref_name(ref)
        t0 = time.time()
        tmp = self.root / "tmp" / f"{stage}.{socket.gethostname()}.{os.getpid()}.{uuid.uuid4().hex[:12]}"
        tmp.mkdir(parents=True)
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
                "summary": pending.summary,
            }
            art_id = manifest_id(manifest)
            manifest = {"id": art_id, **manifest}
            manifest["timing"] = {
                "wall_time_s": round(time.time() - t0, 3),
                "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "host": socket.gethostname(),
                **pending.timing,
            }
            mpath = tmp / MANIFEST
            with open(mpath, "wb") as f:
                f.write(json.dumps(manifest, indent=1, sort_keys=False).encode() + b"\n")
                f.flush()
                os.fsync(f.fileno())
            self._freeze(tmp)
            _fsync_dir(tmp)
            dest = self.object_path(art_id)
            dest.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.rename(tmp, dest)
            except OSError as exc:
                if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.EISDIR):
                    raise
                # Another writer published the same content first: keep theirs.
                remove_tree(tmp)
                pending.raced = True
            else:
                os.chmod(dest, 0o555)
                _fsync_dir(dest.parent)
            pending.artifact = Artifact(art_id, dest)
        except BaseException:
            remove_tree(tmp)
            raise
        self._record_action(key, art_id, stage)
        self.set_ref(f"{kind}/latest", art_id)
        if ref is not None:
            self.set_ref(ref, art_id)

    def _record_action(self, key: str, art_id: str, stage: str) -> None:
        _write_atomic(self._action_path(key), json.dumps({"id": art_id, "stage": stage}).encode() + b"\n")

    @staticmethod
    def _hash_and_sync(root: Path) -> dict[str, dict[str, Any]]:
        """Digest every file under ``root`` and make the data durable before the rename."""
        files: dict[str, dict[str, Any]] = {}
        paths: list[Path] = []
        for dirpath, dirnames, filenames in os.walk(root):
            dirnames.sort()
            for name in sorted(filenames):
                p = Path(dirpath) / name
                rel = p.relative_to(root).as_posix()
                if p.is_symlink() or not p.is_file():
                    raise RuntimeError(f"artifact file {rel} is not a regular file")
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
    def set_ref(self, name: str, art_id: str) -> None:
        check_ref_name(name)
        if not (self.object_path(art_id) / MANIFEST).is_file():
            raise WorkspaceError(f"cannot point ref {name} at {art_id[:12]}: no such artifact")
        _write_atomic(self.root / "refs" / name, art_id.encode() + b"\n")

    def delete_ref(self, name: str) -> None:
        check_ref_name(name)
        p = self.root / "refs" / name
        if not p.is_file():
            raise WorkspaceError(f"no ref named {name}")
        p.unlink()

    def refs(self) -> dict[str, str]:
        """All refs, name -> id (broken refs included; see :meth:`broken_refs`)."""
        out = {}
        base = self.root / "refs"
        for p in sorted(base.rglob("*")):
            if p.is_file() and not p.name.startswith("."):
                out[p.relative_to(base).as_posix()] = p.read_text().strip()
        return out

    def broken_refs(self) -> dict[str, str]:
        return {n: i for n, i in self.refs().items() if not (self.object_path(i) / MANIFEST).is_file()}

    # ---------------------------------------------------------------- resolution
    def all_ids(self) -> list[str]:
        base = self.root / "objects"
        ids = []
        for shard in sorted(base.iterdir()) if base.is_dir() else []:
            if shard.is_dir():
                ids.extend(p.name for p in sorted(shard.iterdir()) if (p / MANIFEST).is_file())
        return ids

    def resolve(self, spec: str, kind: str | None = None) -> str:
        """An artifact id from an id, a unique id prefix (>= 4 hex digits) or a ref name."""
        spec = spec.strip()
        if not spec:
            raise InputError("empty artifact reference")
        art_id: str | None = None
        ref_file = self.root / "refs" / spec
        if _REF_RE.match(spec) and ref_file.is_file():
            art_id = ref_file.read_text().strip()
            if not (self.object_path(art_id) / MANIFEST).is_file():
                raise WorkspaceError(f"ref {spec} points at {art_id[:12]}, which is not in the workspace")
        elif _HEX_RE.match(spec) and len(spec) >= 4:
            shard = self.root / "objects" / spec[:2]
            hits = sorted(p.name for p in shard.iterdir() if p.name.startswith(spec)) if shard.is_dir() else []
            hits = [h for h in hits if (shard / h / MANIFEST).is_file()]
            if len(hits) > 1:
                shown = ", ".join(h[:12] for h in hits[:5])
                raise InputError(f"artifact prefix {spec} is ambiguous: {shown}; give more digits")
            if hits:
                art_id = hits[0]
        if art_id is None:
            raise InputError(f"no artifact or ref named '{spec}' in workspace {self.root} (see 'nsim ls')")
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
        """Re-hash an artifact; the list of mismatches is empty when it is intact."""
        art = self.get(art_id)
        problems: list[VerifyProblem] = []
        try:
            m = art.manifest
        except json.JSONDecodeError:
            return [VerifyProblem(MANIFEST, "not valid JSON")]
        listed = m.get("files", {})
        for rel, info in listed.items():
            p = art.path / rel
            if not p.is_file():
                problems.append(VerifyProblem(rel, "missing"))
                continue
            digest, size = sha256_file(p)
            if size != info.get("size"):
                problems.append(VerifyProblem(rel, f"size {size} != {info.get('size')} in manifest"))
            elif digest != info.get("sha256"):
                problems.append(VerifyProblem(rel, "content digest does not match the manifest"))
        for p in sorted(art.path.rglob("*")):
            rel = p.relative_to(art.path).as_posix()
            if p.is_file() and rel != MANIFEST and rel not in listed:
                problems.append(VerifyProblem(rel, "file is not listed in the manifest"))
        if manifest_id(m) != art_id or m.get("id") != art_id:
            problems.append(VerifyProblem(MANIFEST, "manifest does not hash to the artifact id"))
        return problems

    def size_bytes(self, art: Artifact) -> int:
        return sum(int(v["size"]) for v in art.manifest.get("files", {}).values())

    # ---------------------------------------------------------------- garbage collection
    def reachable(self) -> set[str]:
        """Ids reachable from refs, following each artifact's inputs."""
        seen: set[str] = set()
        stack = [i for i in self.refs().values()]
        while stack:
            i = stack.pop()
            if i in seen or not (self.object_path(i) / MANIFEST).is_file():
                continue
            seen.add(i)
            stack.extend(self.get(i).manifest.get("inputs", {}).values())
        return seen

    def gc(self, dry_run: bool = False) -> GcReport:
        """Remove unreferenced objects, their action records, and abandoned ``tmp/`` entries."""
        report = GcReport()
        keep = self.reachable()
        for art in self.artifacts():
            if art.id not in keep:
                report.objects.append(art.id)
                report.bytes_freed += self.size_bytes(art)
                if not dry_run:
                    remove_tree(art.path)
        actions = self.root / "actions"
        for p in sorted(actions.rglob("*")) if actions.is_dir() else []:
            if not p.is_file():
                continue
            try:
                target = json.loads(p.read_text()).get("id", "")
            except json.JSONDecodeError:
                target = ""
            gone = not target or target in report.objects or not (self.object_path(target) / MANIFEST).is_file()
            if gone:
                report.actions.append(p.name)
                if not dry_run:
                    p.unlink()
        for p in sorted((self.root / "tmp").iterdir()):
            if self._tmp_abandoned(p):
                report.tmp.append(p.name)
                if not dry_run:
                    remove_tree(p)
        if not dry_run:
            for sub in ("objects", "actions"):
                for shard in (self.root / sub).iterdir():
                    if shard.is_dir() and not any(shard.iterdir()):
                        shard.rmdir()
        return report

    @staticmethod
    def _tmp_abandoned(p: Path) -> bool:
        parts = p.name.split(".")
        host = socket.gethostname()
        try:
            age = time.time() - p.lstat().st_mtime
        except FileNotFoundError:
            return False
        if len(parts) >= 4 and parts[-2].isdigit():
            pid = int(parts[-2])
            writer_host = ".".join(parts[1:-2])
            if writer_host == host:
                return not _pid_alive(pid)
        return age > STALE_TMP_S


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # A zombie (killed, not yet reaped) counts as dead.
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def check_ref_name(name: str) -> None:
    if not _REF_RE.match(name) or any(seg in (".", "..") for seg in name.split("/")) or name.endswith(".tmp"):
        raise InputError(f"invalid ref name {name!r}: use letters, digits, '_', '-', '.' and '/' (e.g. scene/lab)")
    if _HEX_RE.match(name) and len(name) >= 4:
        raise InputError(f"invalid ref name {name!r}: it looks like an artifact id prefix")


def default_root() -> Path:
    """``$NSIM_WORKSPACE`` if set, else ``./nsim-workspace``."""
    env = os.environ.get("NSIM_WORKSPACE")
    return Path(env) if env else Path("nsim-workspace")
