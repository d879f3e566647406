"""A reconstruction from frames, as files: the selected frames, SfM, the scale-and-frame step, and
the ``poses`` artifact's transforms.json, COLMAP model, sparse-point PLY, report.json and top-down
picture (``nsim reconstruct``'s artifact, laid out in ``nsim.stages.reconstruct``'s docstring; the
stage reads its inputs, calls :func:`reconstruct` or ``nsim.sfm.imported.write_import``, and publishes).

``inputs`` and ``cfg``: the stage's inputs and config, read for their fields (``intrinsics``,
``reference``, ``reference_poses``, ``known_distance``, ``camera_height_m``, ``capture``; ``frames``, ``blur_ratio``,
``dedup_threshold``, ``shared_intrinsics``, ``exif_focal_prior``, ``max_dt_s``, ``camera_model``).
No workspace code: a capture's frames come in as a folder and its timestamps by frame stem.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.sfm.options import SfmOptions


def load_known_camera(path: Path | None):
    """A known camera (``nsim.geometry.cameras.Camera``) from a transforms.json (its first frame) or a
    YAML/JSON camera mapping; None when ``path`` is None. Raises InputError naming the file."""
    if path is None:
        return None
    from nsim.config import read_yaml
    from nsim.geometry.cameras import Camera
    from nsim.io.transforms_json import read_transforms

    path = Path(path)
    if path.suffix == ".json":
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: malformed JSON at line {exc.lineno}: {exc.msg}") from None
        if isinstance(data, dict) and ("frames" in data or "fl_x" in data):
            return read_transforms(path).frames[0].camera
    else:
        data = read_yaml(path, "intrinsics")
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a camera mapping (model, width, height, fx, fy, cx, cy, dist)")
    try:
        return Camera.from_dict(data)
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"{path}: not a camera: {exc}") from None


def scale_inputs(reference: Path | None, known_distance: tuple[float, ...] | None):
    """The reference (named by file name only: where the file lies must not change the artifact's
    bytes) and the known distance as (point_a, point_b, metres), each None when not given."""
    from nsim.sfm.metric import load_reference

    ref = kd = None
    if reference is not None:
        ref = dataclasses.replace(load_reference(reference), source=Path(reference).name)
    if known_distance is not None:
        v = np.asarray(known_distance, dtype=float)
        kd = (v[:3], v[3:6], float(v[6]))
    return ref, kd


def image_status(name: str, stats: dict[str, Any]) -> str:
    """What became of input image ``name`` in an SfM run whose statistics are ``stats``."""
    from nsim.sfm.frames import NOT_REGISTERED, POSE_JUMP, USED

    if name in stats.get("rejected", ()):
        return POSE_JUMP
    if name in stats.get("unregistered", ()):
        return NOT_REGISTERED
    return USED


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars and arrays as Python values and non-finite floats as None (report.json)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def _select_frames(source: Path, cfg, show_progress: bool):
    """The frames of ``source`` (an image folder, or a video's sharp, distinct frames) and the video's
    selection (None for a folder)."""
    from nsim.progress import progress_bar
    from nsim.sfm.frames import VIDEO_SUFFIXES, load_image_folder, select_video

    with progress_bar(None, "selecting frames", show_progress) as bar:
        if source.is_dir():
            return load_image_folder(source, shared_intrinsics=cfg.shared_intrinsics), None
        if source.suffix.lower() in VIDEO_SUFFIXES:
            selection = select_video(source, cfg.frames, cfg.blur_ratio, cfg.dedup_threshold,
                                     progress=lambda phase, done, total: bar.info(f"{phase} {done}/{total}"))
            return selection.frames, selection
    raise InputError(f"{source}: expected a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of images")


def frame_timestamps(frames, capture_times: dict[str, float], source: Path) -> dict[str, float] | None:
    """Each frame's time in seconds: a video's, a capture's (``capture_times`` by stem), or an image folder's
    file names when they are timestamps (``nsim.sfm.frames.stamps_from_names``); None when the frames have none."""
    from nsim.sfm.frames import stamps_from_names

    if video := {f.name: f.timestamp_s for f in frames if f.timestamp_s is not None}:
        return video
    if capture_times:
        return {f.name: capture_times[Path(f.name).stem] for f in frames if Path(f.name).stem in capture_times} or None
    return stamps_from_names([f.name for f in frames], str(source)) if source.is_dir() else None


def reconstruct(out_dir: Path, inputs, cfg, options: SfmOptions, source: Path, capture_times: dict[str, float],
                show_progress: bool = False) -> tuple[dict[str, Any], dict[str, float]]:
    """SfM on the frames of ``source`` (a video or an image folder; a capture's images folder, with
    ``capture_times``: its frames' timestamps by file stem), made metric by the scale source of
    ``inputs``, written into ``out_dir`` (module docstring). ``options``: the SfM settings (the EXIF
    focal prior of an image folder is added here when ``cfg.exif_focal_prior`` and no camera is known).
    Returns the manifest's summary and the seconds of each phase."""
    from nsim.progress import progress_bar
    from nsim.sfm.colmap import run_sfm
    from nsim.sfm.frames import write_frames
    from nsim.sfm.metric import to_metric

    phases: dict[str, float] = {}
    t0 = time.perf_counter()
    known_camera = load_known_camera(inputs.intrinsics)
    reference, kd = scale_inputs(inputs.reference, inputs.known_distance)
    frames, selection = _select_frames(source, cfg, show_progress)
    timestamps = frame_timestamps(frames, capture_times, source)
    known_poses = None
    if reference is not None:  # the frames must match the reference before SfM, not after it
        from nsim.sfm.metric import associate_reference

        ie, ir, _ = associate_reference([f.name for f in frames], timestamps, reference, cfg.max_dt_s)
        if getattr(inputs, "reference_poses", False):  # the reference's poses are the cameras' (no mapping)
            if len(ie) != len(frames):
                raise InputError(f"--reference-poses: {len(frames) - len(ie)} of {len(frames)} frames have no "
                                 f"pose in {reference.source} (within {cfg.max_dt_s} s): every frame needs one")
            known_poses = {frames[i].name: reference.cam_to_world[j] for i, j in zip(ie, ir, strict=True)}
    write_frames(frames, out_dir / "images")
    phases["frame_selection_s"] = time.perf_counter() - t0

    focal_prior = None
    if source.is_dir() and inputs.capture is None and known_camera is None and cfg.exif_focal_prior:
        from nsim.sfm.frames import exif_hfov_deg, list_image_files

        focal_prior = exif_hfov_deg(list_image_files(source))
    options = dataclasses.replace(options, focal_prior_hfov_deg=focal_prior)
    with tempfile.TemporaryDirectory(prefix="nsim-sfm-") as work, \
            progress_bar(None, "structure from motion", show_progress) as bar:
        result = run_sfm(out_dir / "images", Path(work), options, known_camera=known_camera,
                         progress=lambda phase, done, total: bar.info(f"{phase} {done}/{total}"),
                         known_poses=known_poses)
    t1 = time.perf_counter()
    result, scale = to_metric(result, timestamps, reference=reference, known_distance=kd,
                              camera_height_m=inputs.camera_height_m, max_dt_s=cfg.max_dt_s, seed=options.seed)
    phases.update({f"{k}_s": v for k, v in result.stats.phase_wall_s.items()} if result.stats.phase_wall_s else {})
    phases["scale_s"] = time.perf_counter() - t1
    summary = write_reconstruction(out_dir, inputs, cfg, source, frames, selection, result, scale, timestamps,
                                   reference, focal_prior)
    return summary, phases


def write_reconstruction(out_dir: Path, inputs, cfg, source: Path, frames, selection, result, scale,
                         timestamps: dict[str, float] | None, reference, focal_prior: float | None) -> dict[str, Any]:
    """The files of a metric SfM ``result`` (``nsim.sfm.colmap.SfmResult`` after ``to_metric``, whose
    ``scale`` it returned) of ``frames`` (``selection``: the video's, or None); returns the summary."""
    from nsim.io.ply import write_ply
    from nsim.io.transforms_json import (
        METRIC_KEY,
        SCALE_KEY,
        Z_UP_KEY,
        Frame,
        TransformsData,
        write_transforms,
    )
    from nsim.sfm.colmap import write_model
    from nsim.sfm.frames import frame_summary_line
    from nsim.sfm.plot import write_top_down_png

    names = result.registered_names
    tframes = [
        Frame(file_path=f"images/{n}", cam_to_world=result.cam_to_world[n], camera=result.cameras[n],
              timestamp_s=(timestamps or {}).get(n))
        for n in names
    ]
    write_transforms(out_dir / "transforms.json", TransformsData(frames=tframes, extra={
        SCALE_KEY: scale.source, METRIC_KEY: scale.source != "arbitrary", Z_UP_KEY: scale.frame == "gravity"}))
    write_model(result, out_dir / "sparse")
    write_ply(out_dir / "sparse_points.ply", result.points_xyz.astype(np.float32),
              rgb=result.points_rgb.astype(np.uint8),
              fields={"error_px": result.points_error_px.astype(np.float32),
                      "track_length": result.points_track_length.astype(np.uint16)})
    stats = result.stats.to_dict()
    stats.pop("phase_wall_s", None)
    fates = {f.name: image_status(f.name, stats) for f in frames}
    video_frames = selection.report(fates) if selection is not None else None
    report = {
        "source": f"capture {inputs.capture[:12]}" if inputs.capture else source.name,
        "images_given": stats.get("images_given"),
        "images_registered": stats.get("images_registered"),
        "mean_reprojection_error_px": stats.get("mean_reprojection_error_px"),
        "mean_track_length": stats.get("mean_track_length"),
        "num_points3d": stats.get("num_points3d"),
        "scale": scale.to_dict(),
        "sfm": stats,
        "frames_selected": len(frames),
        "focal_prior": {"source": "exif", "hfov_deg": focal_prior} if focal_prior is not None else None,
        "principal_point": stats.get("principal_point"),
        # every input image and what became of it
        "images": [{"name": f.name, "status": fates[f.name]} for f in frames],
        # every frame of a video source and what became of it (joins ``images`` on name)
        "video_frames": video_frames,
    }
    (out_dir / "report.json").write_text(json.dumps(jsonable(report), indent=1, sort_keys=True) + "\n")
    ref_xyz = reference.cam_to_world[:, :3, 3] if reference is not None else None
    title = f"{source.name}: {len(names)}/{len(frames)} registered, scale: {scale.source}"
    write_top_down_png(out_dir / "top_down.png", result.poses_se3(names), result.points_xyz, title=title,
                       units="m" if scale.source != "arbitrary" else "units", reference_xyz=ref_xyz)
    summary = {
        "images_given": report["images_given"],
        "images_registered": report["images_registered"],
        "scale_source": scale.source,
        "camera_model": cfg.camera_model,
    }
    if video_frames is not None:
        summary["video_frames"] = frame_summary_line(video_frames)
    return summary
