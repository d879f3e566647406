"""Poses imported from an exported transforms.json (nerfstudio, PolyCam, Record3D) instead of SfM.

Two steps, so that the stage can key its run cache on everything the output depends on before
any work is done:

* :func:`plan_import` reads the file and resolves every file it names (images, depths, masks,
  the top-level ``ply_file_path``), confined to a root folder (``nsim.io.transforms_json.
  linked_files``); decides what a missing file means (an error, or with ``skip_missing`` a
  skipped frame / a dropped depth, mask or point file); names each file in the artifact; and
  hashes each. :meth:`ImportPlan.digest` covers all of it.
* :func:`write_import` brings the poses into a metric (or z-up arbitrary-scale) world with the
  same scale sources as an SfM run (``nsim.sfm.metric.metric_frame``: reference, known distance,
  camera height, a declared metric scale; gravity alignment unless the file is declared z-up),
  copies the files (checking each against its hash), and writes the artifact's files.

Names in the artifact are the original ones: ``images/<basename>`` (likewise ``depth/``,
``masks/``) when the basenames are unique, else ``images/<path relative to the root>``, so
evaluation tables keep the original names.

World frames: an imported file's poses and its ``ply_file_path`` points are in the file's world
(for nerfstudio's COLMAP exports: COLMAP's world after the file's ``applied_transform`` A). The
output world is ``S`` of it (the :class:`~nsim.sfm.metric.Similarity` found here), and the
output's ``applied_transform`` is ``S A`` (3x4, scale included): it maps the original world
(before A; the file's world when it had no A) into the artifact's. Depth images are copied as
they are; the output's ``depth_unit_scale_factor`` is the input's (``nsim.io.transforms_json.
depth_unit_scale``) times S's scale, so that stored value x factor = depth in output units.
"""

from __future__ import annotations

import hashlib
import json
import logging
import posixpath
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.io.transforms_json import (
    DEPTH_SCALE_KEY,
    METRIC_KEY,
    SCALE_KEY,
    Z_UP_KEY,
    LinkedFile,
    TransformsData,
    declared_world,
    depth_unit_scale,
    linked_files,
    read_transforms,
)
from nsim.sfm.align import apply_sim3_to_points, apply_sim3_to_poses
from nsim.sfm.metric import Reference, ScaleReport, Similarity, metric_frame

log = logging.getLogger(__name__)

#: How many missing files an error message names before "and N more".
MISSING_NAMED = 3
#: Top-level keys that list image paths (nerfstudio's split files): rewritten to the new names.
SPLIT_KEYS = ("train_filenames", "val_filenames", "test_filenames")
#: Top-level keys of the input not carried into the output (re-derived, or meaningless there).
DROPPED_KEYS = ("ply_file_path", DEPTH_SCALE_KEY, "applied_scale")
POINTS_NAME = "sparse_points.ply"


@dataclass(frozen=True)
class Copy:
    """One file to bring into the artifact: src (resolved), dest (relative to the artifact), its SHA-256."""

    src: Path
    dest: str
    sha256: str


@dataclass(frozen=True, eq=False)
class ImportPlan:
    """What an import reads and writes.

    kept: indices of the imported frames (those whose image exists); images, depths, masks: one
    per kept frame (depths, masks: None where the frame has none); points: the ply (dest is the
    artifact's rewritten ``sparse_points.ply``); missing: files named but absent (skipped frames'
    images, dropped depths, masks, ply), only when skipping was asked for.
    """

    path: Path
    data: TransformsData
    kept: tuple[int, ...]
    images: tuple[Copy, ...]
    depths: tuple[Copy | None, ...]
    masks: tuple[Copy | None, ...]
    points: Copy | None
    missing: tuple[LinkedFile, ...]

    @property
    def skipped(self) -> list[tuple[int, str]]:
        """(frame index, file_path as written) of the frames skipped for a missing image."""
        kept = set(self.kept)
        return [(i, f.file_path) for i, f in enumerate(self.data.frames) if i not in kept]

    def digest(self) -> str:
        """SHA-256 over every file's name in the artifact and content, and the missing ones."""
        h = hashlib.sha256()
        for c in (*self.images, *self.depths, *self.masks, self.points):
            if c is not None:
                h.update(f"{c.dest}\0{c.sha256}\n".encode())
        for f in self.missing:
            h.update(f"missing\0{f.where}\n".encode())
        return h.hexdigest()


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def artifact_names(rel_paths: list[str]) -> dict[str, str]:
    """Name in the artifact of each distinct path (relative to the root): its basename when the
    basenames of all are unique, else the relative path itself (``a/x.png``, ``b/x.png``)."""
    distinct = sorted(set(rel_paths))
    base = [PurePosixPath(r).name for r in distinct]
    flat = len(set(base)) == len(distinct)
    return {r: b if flat else r for r, b in zip(distinct, base, strict=True)}


def _missing_message(path: Path, missing: list[LinkedFile], n_frames: int) -> str:
    images = sum(f.where.endswith(".file_path") for f in missing)
    named = ", ".join(f"{f.where}: {f.value}" for f in missing[:MISSING_NAMED])
    more = f" and {len(missing) - MISSING_NAMED} more" if len(missing) > MISSING_NAMED else ""
    return (f"{path}: {len(missing)} of the files it names are missing ({images} of {n_frames} frames' images): "
            f"{named}{more}; give --skip-missing to import without them (frames without an image are skipped)")


def plan_import(path: Path, root: Path | None = None, skip_missing: bool = False) -> ImportPlan:
    """Read ``path``, resolve and hash the files it names (see the module docstring).

    Without ``skip_missing`` a missing file is an InputError naming how many and the first few;
    with it, the frames whose image is missing are skipped (one warning line says how many) and
    missing depths, masks and ply are dropped. Paths outside ``root`` are always an error.
    """
    data = read_transforms(path)
    if not data.frames:
        raise InputError(f"{path}: has no frames")
    frames, ply = linked_files(path, data, root)
    listed = [f for ff in frames for f in (ff.image, ff.depth, ff.mask) if f is not None]
    missing = [f for f in (*listed, ply) if f is not None and f.path is None]
    if missing and not skip_missing:
        raise InputError(_missing_message(path, missing, len(frames)))
    kept = [i for i, ff in enumerate(frames) if ff.image.path is not None]
    if not kept:
        raise InputError(f"{path}: none of the images of its {len(frames)} frames exists")
    skipped = [ff.image for ff in frames if ff.image.path is None]
    dropped = [f for i in kept for f in (frames[i].depth, frames[i].mask) if f is not None and f.path is None]
    dropped += [ply] if ply is not None and ply.path is None else []
    missing = skipped + dropped
    if missing:
        also = f" and dropped {len(dropped)} missing depth, mask or ply files" if dropped else ""
        log.warning("%s: skipped %d of %d frames whose image is missing%s (report.json lists them)",
                    path.name, len(skipped), len(frames), also)

    def copies(key: str, folder: str) -> tuple[Copy | None, ...]:
        linked: list[LinkedFile | None] = [getattr(frames[i], key) for i in kept]
        present = [f for f in linked if f is not None and f.path is not None]
        names = artifact_names([f.rel for f in present])
        return tuple(None if f is None or f.path is None
                     else Copy(f.path, f"{folder}/{names[f.rel]}", _sha256(f.path)) for f in linked)

    points = None if ply is None or ply.path is None else Copy(ply.path, POINTS_NAME, _sha256(ply.path))
    return ImportPlan(path, data, tuple(kept), copies("image", "images"), copies("depth", "depth"),
                      copies("mask", "masks"), points, tuple(missing))


def check_import(plan: ImportPlan) -> None:
    """Decode every kept frame's image and check its size (``check_frame_images``); InputError on a bad one."""
    from nsim.io.transforms_json import check_frame_images

    images: list[Path | None] = [None] * len(plan.data.frames)
    for i, c in zip(plan.kept, plan.images, strict=True):
        images[i] = c.src
    check_frame_images(plan.path, plan.data, images)


def _read_checked(plan: ImportPlan, c: Copy) -> bytes:
    content = c.src.read_bytes()
    if hashlib.sha256(content).hexdigest() != c.sha256:
        raise InputError(f"{plan.path}: {c.src} changed during the import")
    return content


def _read_points(plan: ImportPlan):
    """The ply's points, read from the bytes that were hashed."""
    from nsim.io.ply import read_ply

    content = _read_checked(plan, plan.points)
    with tempfile.TemporaryDirectory(prefix="nsim-import-") as tmp:
        copy = Path(tmp) / "points.ply"
        copy.write_bytes(content)
        try:
            return read_ply(copy)
        except InputError as e:
            raise InputError(f"{plan.path}: ply_file_path: {plan.points.src}: "
                             f"{str(e).removeprefix(f'{copy}: ')}") from None


def _transformed_cloud(cloud, sim: Similarity) -> dict[str, Any]:
    """write_ply arguments for ``cloud`` moved by ``sim`` (normals nx, ny, nz rotated)."""
    xyz = apply_sim3_to_points(sim.s, sim.R, sim.t, cloud.xyz)
    fields = dict(cloud.fields)
    if all(k in fields for k in ("nx", "ny", "nz")):
        n = np.stack([fields[k] for k in ("nx", "ny", "nz")], axis=1).astype(np.float64) @ sim.R.T
        for j, k in enumerate(("nx", "ny", "nz")):
            fields[k] = n[:, j].astype(fields[k].dtype)
    return {"xyz": xyz.astype(cloud.xyz.dtype), "rgb": cloud.rgb, "fields": fields}


def _top_level_extra(plan: ImportPlan, new_paths: dict[str, str]) -> dict[str, Any]:
    """The input's unknown top-level keys that still mean something in the output."""
    extra = {}
    for key, value in plan.data.extra.items():
        if key in DROPPED_KEYS or key.startswith("nsim_") or key.endswith("_path"):
            continue
        if key in SPLIT_KEYS:
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise InputError(f"{plan.path}: {key}: expected a list of file paths")
            value = [new_paths[p] for v in value if (p := posixpath.normpath(v)) in new_paths]
        extra[key] = value
    return extra


def write_import(plan: ImportPlan, out_dir: Path, reference: Reference | None = None,
                 known_distance: tuple[np.ndarray, np.ndarray, float] | None = None,
                 camera_height_m: float | None = None, metric: bool = False, max_dt_s: float = 0.02,
                 seed: int = 0) -> dict[str, Any]:
    """Write the artifact's files for ``plan`` into ``out_dir``; returns report.json's content.

    metric: the user declared the file's units metres (``--metric``); reference, known_distance,
    camera_height_m: as for an SfM run (``nsim.sfm.metric.metric_frame``), at most one.
    Files: transforms.json, images/, depth/, masks/ (those given), sparse_points.ply (when the
    file names a ply), report.json, top_down.png.
    """
    from nsim.io.ply import write_ply
    from nsim.io.transforms_json import Frame, write_transforms
    from nsim.sfm.plot import write_top_down_png

    data, path = plan.data, plan.path
    frames = [data.frames[i] for i in plan.kept]
    names = [c.dest.removeprefix("images/") for c in plan.images]
    cloud = _read_points(plan) if plan.points is not None else None
    points_in = np.zeros((0, 3)) if cloud is None else np.asarray(cloud.xyz, dtype=np.float64)
    declared_metric, declared_z_up = declared_world(path, data)
    sim, scale = metric_frame(
        np.stack([f.cam_to_world for f in frames]), points_in, names,
        {n: f.timestamp_s for n, f in zip(names, frames, strict=True) if f.timestamp_s is not None},
        reference=reference, known_distance=known_distance, camera_height_m=camera_height_m,
        declared_metric="--metric" if metric else declared_metric, declared_z_up=declared_z_up,
        max_dt_s=max_dt_s, seed=seed)

    for c in (*plan.images, *plan.depths, *plan.masks):
        if c is not None and not (out_dir / c.dest).exists():  # two frames may share a file
            (out_dir / c.dest).parent.mkdir(parents=True, exist_ok=True)
            (out_dir / c.dest).write_bytes(_read_checked(plan, c))
    poses = apply_sim3_to_poses(sim.s, sim.R, sim.t, np.stack([f.cam_to_world for f in frames]))
    out_frames = [
        Frame(file_path=image.dest, cam_to_world=pose, camera=f.camera,
              depth_file_path=None if depth is None else depth.dest,
              mask_path=None if mask is None else mask.dest, timestamp_s=f.timestamp_s,
              extra={k: v for k, v in f.extra.items() if not k.endswith("_path")})
        for f, pose, image, depth, mask in zip(frames, poses, plan.images, plan.depths, plan.masks, strict=True)
    ]
    new_paths = {posixpath.normpath(f.file_path): c.dest for f, c in zip(frames, plan.images, strict=True)}
    extra = _top_level_extra(plan, new_paths) | _world_keys(scale)
    depth_files = [f.depth_file_path for f, d in zip(frames, plan.depths, strict=True) if d is not None]
    if depth_files:
        extra[DEPTH_SCALE_KEY] = depth_unit_scale(path, data, depth_files) * sim.s
    if cloud is not None:
        extra["ply_file_path"] = POINTS_NAME
        try:
            write_ply(out_dir / POINTS_NAME, **_transformed_cloud(cloud, sim))
        except ValueError as e:
            raise InputError(f"{path}: ply_file_path: {plan.points.src}: cannot carry its points: {e}") from None
    applied = np.eye(4)
    if data.applied_transform is not None:
        applied[: data.applied_transform.shape[0]] = data.applied_transform
    write_transforms(out_dir / "transforms.json", TransformsData(
        frames=out_frames, applied_transform=(sim.matrix() @ applied)[:3], extra=extra))

    points_out = apply_sim3_to_points(sim.s, sim.R, sim.t, points_in)
    report = {
        "source": path.name,
        "images_given": len(data.frames),
        "images_registered": len(frames),
        "skipped_frames": [{"index": i, "file_path": p} for i, p in plan.skipped],
        "dropped_files": [{"field": f.where, "path": f.value} for f in plan.missing
                          if not f.where.endswith(".file_path")],
        "num_points3d": len(points_out),
        "scale": scale.to_dict(),
        "world_from_import": sim.matrix().tolist(),
        "applied_transform_given": None if data.applied_transform is None else data.applied_transform.tolist(),
        DEPTH_SCALE_KEY: extra.get(DEPTH_SCALE_KEY),
    }
    (out_dir / "report.json").write_text(json.dumps(report, indent=1, sort_keys=True, allow_nan=False) + "\n")
    title = f"{path.name}: {len(frames)}/{len(data.frames)} imported, scale: {scale.source}"
    write_top_down_png(out_dir / "top_down.png", poses, points_out, title=title,
                       units="m" if scale.source != "arbitrary" else "units",
                       reference_xyz=None if reference is None else reference.cam_to_world[:, :3, 3])
    return report


def _world_keys(scale: ScaleReport) -> dict[str, Any]:
    """nsim's keys saying what the output world is (``nsim.io.transforms_json.declared_world`` reads them)."""
    return {SCALE_KEY: scale.source, METRIC_KEY: scale.source != "arbitrary",
            Z_UP_KEY: scale.frame in ("gravity", "as_given")}

