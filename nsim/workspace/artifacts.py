"""What an artifact is: its id, its manifest (checked as read) and a handle on a published one.

An artifact's **id** is the SHA-256 of its manifest without the volatile fields (``id``,
``timing``); the manifest lists every file's SHA-256 and size, so the id covers the content.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import posixpath
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from nsim.config import canonical_json
from nsim.errors import InputError, WorkspaceError
from nsim.workspace.files import read_small

MANIFEST = "manifest.json"
KINDS = ("capture", "poses", "scene-checkpoint", "human-checkpoint", "trajectory", "render", "evaluation", "export",
         "recording", "registration", "baked-scene")
# Manifest fields that describe one run rather than the content; they do not enter the id.
VOLATILE_FIELDS = ("id", "timing")
MAX_MANIFEST_BYTES = 64 << 20
_HEX_RE = re.compile(r"^[0-9a-f]+$")
_ID_RE = re.compile(r"^[0-9a-f]{64}$")


def is_id(value: object) -> bool:
    """True for a full artifact id: 64 lower-case hex digits."""
    return isinstance(value, str) and _ID_RE.match(value) is not None


def is_hex(text: str) -> bool:
    """True when ``text`` is lower-case hex digits only (what an id or an id prefix looks like)."""
    return _HEX_RE.match(text) is not None


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
            raw = read_small(self.path / MANIFEST, MAX_MANIFEST_BYTES, what)
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
