"""The renders an evaluation scores, where their world comes from, and reading their frames.

``load_render`` reads a render artifact's ``render.json`` (any mode: ``poses``, ``trajectory``,
``recording``) into a ``RenderData`` through an ``ArtifactReader`` (the workspace, read only); ``lineage``
walks scene-checkpoint -> poses -> capture to find the test room behind a render (the oracle's ground
truth). A recording-mode render's world is its
registration's: its lineage names the recording, the registration and the scene, nothing more.

Frames as the tables compare them: ``read_rgb`` (float (H, W, 3) in [0, 1]), ``read_depth`` (metres),
``as_captured`` / ``uint8_rgb`` (what an 8-bit camera stores, grey replicated to three channels).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from nsim.errors import InputError

if TYPE_CHECKING:
    from nsim.workspace.store import Artifact


class ArtifactReader(Protocol):
    """Reads published artifacts by id: all the evaluation asks of the workspace (``nsim.workspace.store.Store``
    is one). The stage hands it over; the evaluation reads the artifacts its renders name (lineage, the test
    room, recordings, registrations) and never publishes."""

    def get(self, art_id: str) -> Artifact: ...


@dataclasses.dataclass(frozen=True, eq=False)
class Lineage:
    """Where a render's world comes from. capture: the test-room capture (None: real data);
    aligned: the scene's world frame is the room's (ground-truth poses, or poses Sim(3)-fitted to the
    capture's ground-truth trajectory); note: that, in words."""

    capture: str | None
    aligned: bool
    note: str


@dataclasses.dataclass(frozen=True, eq=False)
class RenderData:
    id: str
    path: Path
    manifest: dict[str, Any]
    meta: dict[str, Any]
    lineage: Lineage

    @property
    def short(self) -> str:
        return self.id[:12]

    @property
    def mode(self) -> str:
        return self.meta["mode"]

    @property
    def frames(self) -> list[dict[str, Any]]:
        return self.meta["frames"]

    @property
    def humans(self) -> list[str]:
        """The human checkpoints in the render's order (person k is drawn by ``humans[k % len]``)."""
        ids = self.manifest["inputs"]
        keys = [k for k in ids if k.startswith("human") and k[5:].isdigit()]
        return [ids[k] for k in sorted(keys, key=lambda k: int(k[5:]))]

    @property
    def has_people(self) -> bool:
        """Whether the render drew people (by human checkpoints or with the default look; ``people_checkpoints``)."""
        return bool(self.humans) or bool(self.manifest.get("summary", {}).get("people_checkpoints"))

    def file(self, rel: str) -> Path:
        p = self.path / rel
        if not p.is_file():
            listed = ("render.json lists that frame" if self.mode == "recording"
                      else f"render.json lists {len(self.frames)} frames")
            raise InputError(f"render {self.short}: has no file {rel} ({listed})")
        return p

    def rig(self):
        from nsim.sensors.rig import Rig

        return Rig.from_resolved(json.loads(self.file("rig.json").read_text()))


def require_mode(renders: tuple[RenderData, ...], mode: str, table: str, how: str) -> None:
    """InputError unless every render is a ``mode``-mode render (``how``: the command that makes one)."""
    for r in renders:
        if r.mode != mode:
            raise InputError(f"render {r.short}: a {r.mode}-mode render; --table {table} needs "
                             f"{mode}-mode renders ({how})")


def lineage(artifacts: ArtifactReader, scene_id: str) -> Lineage:
    """Walk scene-checkpoint -> poses -> capture (see ``Lineage``)."""
    scene = artifacts.get(scene_id)
    poses_id = scene.manifest.get("inputs", {}).get("poses")
    if poses_id is None:
        return Lineage(None, False, f"scene {scene_id[:12]} names no poses")
    src = artifacts.get(poses_id)
    if src.kind == "capture":
        return Lineage(src.id, True, f"scene trained on capture {src.id[:12]} (ground-truth poses)")
    cap = src.manifest.get("inputs", {}).get("capture")
    if cap is None:
        return Lineage(None, False, f"scene trained on poses {src.id[:12]} of real data (no test-room ground truth)")
    summary = src.manifest.get("summary", {})
    ref = summary.get("file_inputs", {}).get("reference")
    gt_sha = artifacts.get(cap).manifest["files"].get("gt_trajectory.tum", {}).get("sha256")
    # reconstruct records a file input as sha256 of the file's hex digest (nsim.workspace.store.sha256_path)
    gt_digests = {gt_sha, hashlib.sha256(gt_sha.encode()).hexdigest()} if gt_sha else set()
    aligned = summary.get("scale_source") == "reference" and ref in gt_digests
    how = ("Sim(3)-fitted to the capture's ground-truth trajectory" if aligned
           else "not fitted to the capture's ground-truth trajectory (its world frame is not the room's)")
    return Lineage(cap, aligned, f"scene trained on poses {src.id[:12]} reconstructed from capture {cap[:12]}, {how}")


def _short(value: Any) -> str:
    return str(value)[:12] if value else "?"


def load_render(artifacts: ArtifactReader, render_id: str) -> RenderData:
    art = artifacts.get(render_id)
    try:
        meta = json.loads(art.file("render.json").read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"render {render_id[:12]}: render.json: {err}") from None
    if not isinstance(meta, dict):
        raise InputError(f"render {render_id[:12]}: render.json is not an object")
    manifest = art.manifest
    if meta.get("mode") == "recording":
        if not meta.get("streams"):
            raise InputError(f"render {render_id[:12]}: render.json lists no streams")
        note = (f"recording {_short(meta.get('recording'))} registered into scene {_short(meta.get('scene'))} by "
                f"registration {_short(meta.get('registration'))}")
        return RenderData(render_id, art.path, manifest, meta, Lineage(None, False, note))
    scene = manifest.get("inputs", {}).get("scene")
    if scene is None:
        raise InputError(f"render {render_id[:12]}: its manifest names no scene checkpoint")
    if not meta.get("frames"):
        raise InputError(f"render {render_id[:12]}: render.json lists no frames")
    return RenderData(render_id, art.path, manifest, meta, lineage(artifacts, scene))


# ---------------------------------------------------------------------------------- reading frames
def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1]."""
    from nsim.io.images import read_image, to_float

    return to_float(read_image(path))


def read_depth(path: Path) -> np.ndarray:
    from nsim.io.exr import read_depth_exr

    try:
        return read_depth_exr(path)
    except InputError:
        raise
    except Exception as err:  # OpenEXR raises plain exceptions for damaged files
        raise InputError(f"{path}: cannot read depth EXR ({err})") from None


def as_captured(rgb: np.ndarray) -> np.ndarray:
    """A float image as a camera stores it: 8-bit, (H, W, 3) (grey replicated), back to float."""
    from nsim.io.images import to_float, to_uint8

    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=-1)
    return to_float(to_uint8(rgb))


def uint8_rgb(rgb: np.ndarray) -> np.ndarray:
    from nsim.io.images import to_uint8

    return to_uint8(as_captured(rgb))
