"""Whether an object is whole: a cheap look, a full re-hash, and the ``verified/`` markers.

* :func:`complete_manifest` — parse, id and every listed file's size (what the run cache and refs ask).
* :func:`verify_object` — re-hash every file against the manifest (``nsim verify``).
* :func:`check_object` — what a stage reads goes through: the full re-hash runs once per object
  state, after which a marker ``verified/ab/abcdef...`` keeps the manifest's digest and each
  file's (size, mtime, ctime, inode); while they are unchanged (ctime changes with any write or
  chmod) the object is taken as verified.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from nsim.errors import WorkspaceError
from nsim.workspace.artifacts import MANIFEST, MAX_MANIFEST_BYTES, Artifact, manifest_id, parse_manifest
from nsim.workspace.files import read_small, sha256_file, stat_sig, write_atomic


@dataclasses.dataclass(frozen=True)
class VerifyProblem:
    file: str
    reason: str

    def __str__(self) -> str:
        return f"{self.file}: {self.reason}"


def complete_manifest(obj: Path, art_id: str) -> dict[str, Any] | None:
    """The manifest when the object at ``obj`` looks whole (cheap: parse, id, every listed file's size), else None."""
    try:
        m = Artifact(art_id, obj).manifest
    except WorkspaceError:
        return None
    if manifest_id(m) != art_id or m.get("id") != art_id:
        return None
    for rel, info in m["files"].items():
        sig = stat_sig(obj / rel)
        if sig is None or sig[0] != info["size"]:
            return None
    return m


def verify_object(obj: Path, art_id: str) -> list[VerifyProblem]:
    """Re-hash the object at ``obj``; the list of problems is empty when it is intact.

    Reports listed files that are missing, not regular files or symbolic links, or whose size
    or digest differ; entries the manifest does not list; and a manifest that is unreadable,
    names unsafe paths or does not hash to the id. Never follows a symbolic link.
    """
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


def _marker_path(root: Path, art_id: str) -> Path:
    return root / "verified" / art_id[:2] / art_id


def check_object(root: Path, obj: Path, art_id: str) -> None:
    """Raise WorkspaceError naming the file if the object at ``obj`` does not match its manifest.

    Re-hashes only when the workspace ``root`` has no marker for the object's present state,
    and writes one when the re-hash finds it whole.
    """
    try:
        raw = read_small(obj / MANIFEST, MAX_MANIFEST_BYTES, f"artifact {art_id[:12]}: {MANIFEST}")
    except FileNotFoundError:
        raise WorkspaceError(f"artifact {art_id[:12]} is not in the workspace {root}") from None
    digest = hashlib.sha256(raw).hexdigest()
    m = parse_manifest(raw, f"artifact {art_id[:12]}: {MANIFEST}")
    try:
        rec = json.loads(read_small(_marker_path(root, art_id), MAX_MANIFEST_BYTES, "marker"))
        ok = (isinstance(rec, dict) and rec.get("manifest_sha256") == digest
              and isinstance(rec.get("files"), dict) and set(rec["files"]) == set(m["files"])
              and all(stat_sig(obj / rel) == sig for rel, sig in rec["files"].items()))
    except (OSError, WorkspaceError, ValueError, TypeError):
        ok = False
    if not ok:
        problems = verify_object(obj, art_id)
        if problems:
            raise WorkspaceError(
                f"{m['kind']} artifact {art_id[:12]} is damaged: {problems[0]} "
                f"(see 'nsim verify {art_id[:12]}'; rerun the stage that made it with --force to repair it)"
            )
        write_marker(root, art_id, digest, {rel: stat_sig(obj / rel) for rel in m["files"]})


def write_marker(root: Path, art_id: str, manifest_sha256: str, sigs: Mapping[str, Any]) -> None:
    """Record that the object ``art_id`` of ``root`` was found whole in this state (best effort)."""
    body = {"manifest_sha256": manifest_sha256, "files": dict(sigs)}
    with contextlib.suppress(OSError):
        write_atomic(_marker_path(root, art_id), json.dumps(body).encode())
