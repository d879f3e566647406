"""``nsim reconstruct``: a video, a folder of photos or a capture in, metric camera poses out.

Inputs are files (a video, an image folder, optional reference/intrinsics files) or a capture
artifact. Files are not artifacts: their content digests enter the action key, so editing a
file never serves a stale result. ``--import transforms.json`` skips SfM and brings poses
from nerfstudio / PolyCam / Record3D exports (OpenGL convention) into the workspace
(``nsim.sfm.imported``): the files it names (images, depths, masks, ply) must lie inside its
folder (or ``images_root``), the images decode and match its ``w``, ``h``, and every file's
bytes and name in the artifact enter the action key. A missing file is an error, or with
``skip_missing`` a skipped frame (or a dropped depth, mask or ply) that report.json lists. The
scale sources and gravity alignment are the SfM run's; an import may also be declared metric
(``metric``, or nsim's own keys in the file: ``nsim.io.transforms_json.declared_world``);
without any source its scale is arbitrary and transforms.json (``nsim_scale``,
``nsim_metric``) and report.json say so.

Artifact layout (kind ``poses``)::

    transforms.json      nerfstudio convention, metric (unless report.json says the scale is
                         arbitrary), per-frame intrinsics and distortion, timestamps for video;
                         nsim_scale (the scale source), nsim_metric, nsim_z_up
    images/              the selected frames (PNG, lossless); an import's under their own names
    depth/, masks/       an import's depth and mask images, as given (depth_unit_scale_factor
                         in transforms.json: stored value x factor = depth in output units)
    sparse/              the COLMAP model (cameras.bin, images.bin, points3D.bin), metric, z up
                         (not for an import)
    sparse_points.ply    the sparse points with colour, reprojection error and track length; an
                         import's ply_file_path points, moved into the output world
    report.json          images given/registered, mean reprojection error, mean track length,
                         number of 3D points, scale source and Sim(3) residual, the options used;
                         ``images``: every input image and what became of it; ``video_frames``
                         (a video source, else null): every frame of the video, blurred,
                         duplicate, not sampled or an image's status, and the measure that
                         decided it (``nsim.sfm.frames.video_frame_report``)
    top_down.png         the camera path over the sparse points, from above

Wall time per phase is in the manifest's ``timing`` (``nsim show``), outside the artifact's
digest, so that a rerun keeps the same id. The frame selection, SfM, scale step and these files are
``nsim.sfm.reconstruction``'s (an import's, ``nsim.sfm.imported``'s): this stage reads the inputs,
keys the run and publishes.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.config import param, param_from
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.sfm.options import SfmOptions
from nsim.stages.runner import cached, device_kind, rerun

if TYPE_CHECKING:
    from nsim.sfm.imported import ImportPlan

log = logging.getLogger(__name__)

STAGE = "reconstruct"
VERSION = 5  # 5: poses, trajectories and metrics written rounded (nsim.io.canonical: the same bytes on any CPU)


@dataclasses.dataclass(frozen=True)
class Config:
    """The SfM settings (camera_model ... refine_principal_point) are ``nsim.sfm.options.SfmOptions``'s
    fields: their bounds, choices, help and defaults are written there (``param_from``)."""

    frames: int = param(150, ge=3, le=100_000, help="about this many frames are taken from a video")
    blur_ratio: float = param(0.4, ge=0.0, le=1.0, help="drop frames less sharp than this fraction of the video's "
                                                       "median sharpness")
    dedup_threshold: float = param(0.01, ge=0.0, help="drop frames closer than this to the last kept one "
                                                       "(mean absolute difference of 32x24 grey thumbnails, 0-1)")
    camera_model: str = param_from(SfmOptions, "camera_model")
    shared_intrinsics: bool = param_from(SfmOptions, "shared_intrinsics")
    matcher: str = param_from(SfmOptions, "matcher")
    overlap: int = param_from(SfmOptions, "overlap")
    loop_detection: bool = param_from(SfmOptions, "loop_detection")
    max_features: int = param_from(SfmOptions, "max_features")
    min_registered_fraction: float = param_from(SfmOptions, "min_registered_fraction")
    refine_principal_point: str = param_from(SfmOptions, "refine_principal_point")
    exif_focal_prior: bool = param(True, help="an image folder's EXIF 35 mm focal length as the first focal guess")
    max_dt_s: float = param(0.02, gt=0.0, help="largest timestamp gap when matching a reference")


#: The settings of ``Config`` that are ``SfmOptions`` fields, passed on as they are.
SFM_SETTINGS = tuple(f.name for f in dataclasses.fields(Config) if f.name in SfmOptions.__dataclass_fields__)


@dataclasses.dataclass(frozen=True)
class Inputs:
    """What to reconstruct and how to scale it.

    source: a video file, an image folder, or (``capture``) a capture artifact id whose video
    is used; import_transforms: an exported transforms.json, whose files (paths relative to
    its folder) must lie inside images_root (default: its folder); skip_missing: skip its
    frames whose image is missing (and drop missing depths, masks, ply) instead of failing;
    metric: its poses are in metres (PolyCam, Record3D). reference: transforms.json or TUM file
    with metric poses; intrinsics: a transforms.json / YAML / JSON camera file; known_distance:
    (x1, y1, z1, x2, y2, z2, d_m) in the frame of an unscaled run; camera_height_m: the
    capture's mean camera height. reference_poses: the reference's poses are the cameras' (a
    motion capture's, say): the frames are not mapped, only their features triangulated at those
    poses (``nsim.sfm.colmap``, "Known poses"); needs ``reference`` and ``intrinsics``.
    """

    source: Path | None = None
    capture: str | None = None
    reference: Path | None = None
    intrinsics: Path | None = None
    known_distance: tuple[float, ...] | None = None
    camera_height_m: float | None = None
    import_transforms: Path | None = None
    images_root: Path | None = None
    skip_missing: bool = False
    metric: bool = False
    reference_poses: bool = False

    def ids(self) -> dict[str, str]:
        return {"capture": self.capture} if self.capture else {}

    def validate(self) -> None:
        sources = [x is not None for x in (self.source, self.capture, self.import_transforms)]
        if sum(sources) != 1:
            raise InputError("reconstruct: give exactly one of a video/image folder, a capture, or --import")
        scales = [x is not None for x in (self.reference, self.known_distance, self.camera_height_m)] + [self.metric]
        if sum(scales) > 1:
            raise InputError("reconstruct: give at most one of --reference, --known-distance, --camera-height, "
                             "--metric")
        if self.reference_poses and (self.reference is None or self.intrinsics is None
                                     or self.import_transforms is not None):
            raise InputError("--reference-poses: needs --reference (the cameras' poses) and --intrinsics (the "
                             "camera), and a video, an image folder or a capture (not --import)")
        for flag, value in (("--metric", self.metric), ("--skip-missing", self.skip_missing)):
            if value and self.import_transforms is None:
                raise InputError(f"{flag}: only with --import")
        for name in ("source", "reference", "intrinsics", "import_transforms", "images_root"):
            p = getattr(self, name)
            if p is not None and not Path(p).exists():
                raise InputError(f"{p}: no such file or directory")
        if self.images_root is not None:
            if self.import_transforms is None:
                raise InputError("--images-root: only with --import")
            if not Path(self.images_root).is_dir():
                raise InputError(f"--images-root: {self.images_root} is not a directory")
        if self.known_distance is not None:
            kd = self.known_distance
            if len(kd) != 7 or not np.all(np.isfinite(kd)) or kd[6] <= 0:
                raise InputError("--known-distance: expected X1 Y1 Z1 X2 Y2 Z2 D with finite values and D > 0 (metres)")
        if self.camera_height_m is not None and not (np.isfinite(self.camera_height_m) and self.camera_height_m > 0):
            raise InputError(f"--camera-height: expected a height > 0 in metres, got {self.camera_height_m}")


@dataclasses.dataclass(frozen=True)
class Outputs:
    poses: str
    cache_hit: bool = False


# ----------------------------------------------------------------------------------------------
# Action key: file inputs are digested by content


FILE_INPUTS = ("source", "reference", "intrinsics", "import_transforms")


def file_digests(inputs: Inputs, import_digest: str | None = None) -> dict[str, str]:
    """Content digests of the file inputs; an import's files (names in the artifact and content) as one."""
    from nsim.workspace.store import sha256_path

    files = {name: sha256_path(Path(p)) for name in FILE_INPUTS if (p := getattr(inputs, name)) is not None}
    if import_digest is not None:
        files["import_files"] = import_digest
    return files


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext, device: str,
               files: dict[str, str] | None = None) -> str:
    files = file_digests(inputs) if files is None else files
    extra = {
        "files": files,
        "known_distance": list(inputs.known_distance) if inputs.known_distance else None,
        "camera_height_m": inputs.camera_height_m,
        "metric": inputs.metric,
        "skip_missing": inputs.skip_missing,
        "device": device,
    }
    if inputs.reference_poses:  # only when set: the keys of every other run stay as they were
        extra["reference_poses"] = True
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    inputs.validate()
    if inputs.capture is not None:
        ctx.store.resolve(inputs.capture, kind="capture")
    device = "cpu" if inputs.import_transforms is not None else device_kind(ctx.device)
    plan = None
    if inputs.import_transforms is not None:
        from nsim.sfm.imported import plan_import

        plan = plan_import(Path(inputs.import_transforms), inputs.images_root, inputs.skip_missing)
    files = file_digests(inputs, None if plan is None else plan.digest())
    key = action_key(inputs, cfg, ctx, device, files)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(poses=hit, cache_hit=True)
    if plan is not None:
        from nsim.sfm.imported import check_import

        check_import(plan)  # before anything is published
    with ctx.store.publish(
        kind="poses", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(), seed=ctx.seed
    ) as out:
        if plan is not None:
            summary = import_transforms(inputs, cfg, ctx, plan, out.dir)
        else:
            summary = reconstruct(inputs, cfg, ctx, device, out.dir, out.timing)
        out.summary.update(summary)
        out.summary["file_inputs"] = files
        out.summary["scale_inputs"] = {
            "known_distance": list(inputs.known_distance) if inputs.known_distance else None,
            "camera_height_m": inputs.camera_height_m,
            "metric": inputs.metric,
        }
        if inputs.reference_poses:
            out.summary["scale_inputs"]["reference_poses"] = True
        # where the file inputs were read (outside the id: the same files elsewhere give the same artifact)
        out.timing["source"] = {name: str(Path(p).resolve()) for name in FILE_INPUTS
                                if (p := getattr(inputs, name)) is not None}
    return Outputs(poses=out.ref)


def reconstruct(inputs: Inputs, cfg: Config, ctx: RunContext, device: str, out_dir: Path,
                timing: dict[str, Any]) -> dict[str, Any]:
    """SfM on the source's frames, made metric, into ``out_dir`` (``nsim.sfm.reconstruction``); returns the summary."""
    from nsim.sfm.reconstruction import reconstruct as reconstruct_frames

    capture_times: dict[str, float] = {}
    if inputs.capture is not None:
        # the capture's lossless frames (its video is H.264-compressed, as a phone's would be)
        from nsim.io.transforms_json import read_transforms

        art = ctx.store.get(ctx.store.resolve(inputs.capture, kind="capture"))
        source = art.path / "images"
        # by stem: the frames are written as PNG whatever the capture's format (a phone capture's are JPEG)
        capture_times = {Path(f.file_path).stem: f.timestamp_s
                         for f in read_transforms(art.file("transforms.json")).frames if f.timestamp_s is not None}
    else:
        source = Path(inputs.source)
    options = SfmOptions(**{name: getattr(cfg, name) for name in SFM_SETTINGS}, device=device, seed=ctx.seed)
    summary, phases = reconstruct_frames(out_dir, inputs, cfg, options, source, capture_times, ctx.show_progress)
    timing["phases_s"] = {k: round(v, 3) for k, v in phases.items()}
    if "video_frames" in summary:  # a video: what became of its frames (shown with nsim -v)
        log.info("%s: %s", source.name, summary["video_frames"])
    return summary


def import_transforms(inputs: Inputs, cfg: Config, ctx: RunContext, plan: ImportPlan,
                      out_dir: Path) -> dict[str, Any]:
    """Bring an exported transforms.json (nerfstudio / PolyCam / Record3D) and its files in (``plan_import``)."""
    from nsim.sfm.imported import write_import
    from nsim.sfm.reconstruction import scale_inputs

    reference, kd = scale_inputs(inputs.reference, inputs.known_distance)
    report = write_import(plan, out_dir, reference=reference, known_distance=kd,
                          camera_height_m=inputs.camera_height_m, metric=inputs.metric, max_dt_s=cfg.max_dt_s,
                          seed=ctx.seed)
    return {"images_given": report["images_given"], "images_registered": report["images_registered"],
            "images_skipped": len(report["skipped_frames"]), "scale_source": report["scale"]["source"]}


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    """Rebuild from the recorded capture and the file inputs where they were read (``timing.source``), while
    they are there with the content the artifact was made from; an imported transforms.json is not rebuilt."""
    summary = manifest.get("summary", {})
    files = summary.get("file_inputs") or {}
    source = manifest.get("timing", {}).get("source") or {}
    if "import_files" in files or ("capture" not in manifest.get("inputs", {}) and not source.get("source")):
        raise InputError("this poses artifact was imported from files the workspace does not hold: rerun nsim "
                         "reconstruct on them with --force to compare")
    paths = {name: Path(str(source[name])) for name in files if name in source}
    if set(paths) != set(files):
        raise InputError(f"this poses artifact was made from files ({', '.join(sorted(files))}) whose paths it does "
                         "not record: rerun nsim reconstruct on them with --force to compare")
    for name, p in paths.items():
        if not p.exists():
            raise InputError(f"{p}: the {name} this poses artifact was made from is no longer there: rerun nsim "
                             "reconstruct on it with --force to compare")
    scale = summary.get("scale_inputs", {})
    kd = scale.get("known_distance")
    inputs = Inputs(capture=manifest["inputs"].get("capture"), known_distance=tuple(kd) if kd else None,
                    camera_height_m=scale.get("camera_height_m"), metric=bool(scale.get("metric")),
                    reference_poses=bool(scale.get("reference_poses")), **paths)
    if file_digests(inputs) != files:
        changed = sorted(n for n, d in file_digests(inputs).items() if files.get(n) != d)
        raise InputError(f"{paths[changed[0]]}: the {changed[0]} has changed since this poses artifact was made from it")
    return rerun(run, inputs, Config, manifest, ctx).poses
