"""``train-human --video`` / ``--images``: a person's frames become the human data folder train-human reads.

``prepare_person_data(source, out_dir)``:

1. makes the person detector first (``nsim.human.landmarks.MediaPipePoseDetector``), so a
   missing ``nsim[people]`` extra fails before any decoding;
2. reads the frames (``read_person_frames``): every frame of a video, thinned to at most
   ``max_fps`` and shrunk to at most ``max_width`` pixels wide, or the images of a folder in
   name order at ``images_fps``;
3. checks what needs the detector only (``nsim.human.person_video.person_frames``: length, one
   person), then tells a static camera from a moving one (``nsim.human.moving_camera.decide_camera``:
   the background's motion, or the person walking on the spot in the image; one log line with the
   numbers) and finds a moving camera's path (SfM on keyframes with the person masked out), then
   finds and fits the person (``nsim.human.person_video.fit_person``: masks, a metric camera,
   bone lengths and per-frame joint angles; bad input is a one-line ``InputError``) and logs the
   walking speed in the world and where its metres came from;
4. writes the human data format (docs/human_data.md) for the kept frames into ``out_dir``::

       transforms.json    the camera of each frame (the same pose throughout for a static one), intrinsics
       images/frame_NNNNN.png, masks/frame_NNNNN.png   NNNNN: the frame's index in the input
       poses.json         the fitted poses (nsim.human.data)
       person.bvh         the person's own motion (longest unbroken stretch), nsim.human.bvh
       person_fit.json    camera height, scale, field of view, bone lengths, dropped stretches; the
                          camera decision and its numbers (camera_decision), a moving camera's SfM
                          (camera_path), walking_speed_mps, scale_from, cadence_steps_s
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.human.landmarks import MASK_THRESHOLD, consistent_sides
from nsim.human.monocular import static_camera
from nsim.human.moving_camera import (
    WALK_CADENCE_STEPS_S,
    CameraDecision,
    CameraPath,
    background_motion_px,
    camera_path,
    decide_camera,
    speed_from_cadence,
)
from nsim.human.person_video import PersonFit, PersonVideoConfig, fit_person, person_frames

log = logging.getLogger(__name__)

SOURCES = ("video", "images")
PERSON_FIT_FILE = "person_fit.json"
PERSON_BVH_FILE = "person.bvh"


@dataclass(frozen=True)
class PersonSource:
    """Where the person's frames come from and how they are read.

    path: a video file (kind "video") or a folder of images (kind "images").
    images_fps: the frame rate of an image folder (a video states its own).
    max_fps: a video's frames are thinned to at most this rate. max_width: frames are shrunk to this width.
    person: how the person is found and fitted.
    """

    path: Path
    kind: str = "video"
    images_fps: float = 30.0
    max_fps: float = 15.0
    max_width: int = 640
    person: PersonVideoConfig = field(default_factory=PersonVideoConfig)

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        if self.kind not in SOURCES:
            raise ValueError(f"PersonSource.kind: expected one of {SOURCES}, got {self.kind!r}")
        for name in ("images_fps", "max_fps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 < v <= 240.0):
                raise ValueError(f"PersonSource.{name}: must be in (0, 240], got {v!r}")
        if not 64 <= self.max_width <= 8192:
            raise ValueError(f"PersonSource.max_width: must be in [64, 8192], got {self.max_width!r}")


def _shrink(rgb: np.ndarray, max_width: int) -> np.ndarray:
    import cv2

    h, w = rgb.shape[:2]
    if w <= max_width:
        return rgb
    return cv2.resize(rgb, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)


def read_person_frames(source: PersonSource) -> tuple[list[np.ndarray], np.ndarray, float]:
    """The frames ``(H, W, 3)`` uint8 RGB, their indices in the input ``(N,)`` and the frame rate they have.

    InputError for a missing or unreadable input, or frames of different sizes.
    """
    if source.kind == "images":
        from nsim.io.images import read_image
        from nsim.sfm.frames import list_image_files

        files = list_image_files(source.path)
        if not files:
            raise InputError(f"{source.path}: no images (jpg/jpeg/png)")
        frames = [_shrink(read_image(p), source.max_width) for p in files]
        return frames, np.arange(len(frames)), float(source.images_fps)
    import cv2

    path = source.path
    if not path.is_file():
        raise InputError(f"{path}: no such video file")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise InputError(f"{path}: cannot open as a video (unreadable, corrupt or unsupported format)")
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    if not (math.isfinite(fps) and 0.0 < fps < 10_000.0):
        cap.release()
        raise InputError(f"{path}: the video states no frame rate")
    every = max(1, math.ceil(fps / source.max_fps - 1e-9))
    frames, index, i = [], [], 0
    try:
        while True:
            ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            if i % every == 0:
                frames.append(_shrink(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), source.max_width))
                index.append(i)
            i += 1
    finally:
        cap.release()
    if not frames:
        raise InputError(f"{path}: no frames could be decoded (empty or corrupt video)")
    return frames, np.asarray(index, dtype=np.int64), fps / every


def write_person_data(out_dir: Path, frames: list[np.ndarray], index: np.ndarray, fit: PersonFit,
                      decision: CameraDecision | None = None, path: CameraPath | None = None) -> dict:
    """Write the human data folder of the kept frames (module docstring); returns person_fit.json's content.

    decision: how the camera was told static or moving, and path: a moving camera's SfM, both recorded in it."""
    from nsim.human.bvh import write_bvh
    from nsim.human.data import write_poses
    from nsim.io import atomic_write_text
    from nsim.io.images import write_image
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms

    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    (out_dir / "masks").mkdir(parents=True, exist_ok=True)
    names = [f"frame_{int(index[k]):05d}" for k in fit.frames]
    out_frames = []
    for row, (k, name) in enumerate(zip(fit.frames, names, strict=True)):
        write_image(out_dir / "images" / f"{name}.png", frames[int(k)])
        write_image(out_dir / "masks" / f"{name}.png", fit.masks[row].astype(np.uint8) * 255)
        c2w = fit.cam_to_world if fit.cam_to_world.ndim == 2 else fit.cam_to_world[row]
        out_frames.append(Frame(file_path=f"images/{name}.png", cam_to_world=c2w, camera=fit.camera,
                                timestamp_s=float(k) / fit.fps))
    write_transforms(out_dir / "transforms.json", TransformsData(frames=out_frames))
    write_poses(out_dir / "poses.json", fit.human_poses(tuple(f"images/{n}.png" for n in names)))
    write_bvh(out_dir / PERSON_BVH_FILE, fit.motion_clip("person"))
    sk = fit.poses.body.skeleton
    report = {
        "frames_in": len(frames), "frames_kept": int(fit.frames.size), "fps": fit.fps,
        "camera": "moving" if fit.cam_to_world.ndim == 3 else "static",
        "hfov_deg": float(fit.camera.fov_deg[0]), "camera_height_m": fit.camera_height_m, "scale": fit.scale,
        "height_m": fit.poses.body.height_m,
        "bone_lengths_m": {sk.joint_names[j]: float(np.linalg.norm(sk.offsets_m[j])) for j in range(1, sk.num_joints)},
        "landmark_error_median_m": float(np.nanmedian(fit.poses.landmark_error_m)),
        "dropped": [d.describe(fit.fps) for d in fit.dropped],
        "sides_relabelled": fit.relabelled,
        "track_outliers": [[f, name] for f, name in fit.track_outliers],
        "walking_speed_mps": _number(fit.walking_speed_mps()),
        "camera_decision": None if decision is None else decision.to_dict(),
        "camera_path": None if path is None else path.summary(),
        "scale_from": fit.scale_from or None,
        "cadence_steps_s": None if fit.steps is None else _number(fit.steps.cadence_steps_s),
    }
    atomic_write_text(out_dir / PERSON_FIT_FILE, json.dumps(report, indent=1) + "\n")
    return report


def prepare_person_data(source: PersonSource, out_dir: str | Path, detector=None) -> dict:
    """Steps 1-4 of the module docstring; returns the person_fit.json content.

    detector: a ``nsim.human.landmarks.PoseDetector`` run over the frames once, in order (None: MediaPipe, which
    needs ``nsim[people]``, mirrored and in both directions as ``source.person`` says).
    """
    from nsim.human.landmarks import MediaPipePoseDetector, observe

    cfg = source.person
    own = detector is None
    made = []
    try:
        if own:
            made.append(MediaPipePoseDetector(mirror=cfg.mirror_landmarks))
            if cfg.both_directions:
                made.append(MediaPipePoseDetector(mirror=cfg.mirror_landmarks))
            detector = made[0]
        frames, index, fps = read_person_frames(source)
        obs = observe(frames, detector, backward=made[1] if len(made) > 1 else None)
    finally:
        for d in made:
            d.close()
    src = str(source.path)
    keep, _ = person_frames(obs, fps, cfg, source=src)  # checks that need the detector only, before SfM
    masks = obs.person_masks >= MASK_THRESHOLD
    motion = background_motion_px(frames, masks) if cfg.camera != "static" else None
    sided = consistent_sides(obs, keep)[0] if cfg.consistent_sides else obs
    decision = decide_camera(motion, obs.width, np.where(keep[:, None, None], sided.body_m, np.nan),
                             sided.image_uv_px, np.where(keep[:, None], sided.visibility, 0.0),
                             static_camera(obs.width, obs.height, cfg.hfov_deg), fps, cfg.camera)
    log.info("%s: %s", src, decision.describe())
    moving = None
    if decision.moving:
        moving = camera_path(frames, masks, fps, cfg.hfov_deg, motion, source=src)
        summary = moving.summary()
        if moving.model == "sfm":
            log.info("%s: the camera's path from %d of %d keyframes (SfM, the person masked out, %d points) in %.0f s",
                     src, summary["keyframes_registered"], summary["keyframes"], summary["points"], moving.seconds)
    fit = fit_person(obs, fps, cfg, source=src, camera_path=moving)
    _log_speed(src, fit)
    for d in fit.dropped:
        log.warning("%s: dropped %s", source.path, d.describe(fit.fps))
    for limb, frames_relabelled in fit.relabelled.items():
        if frames_relabelled:
            log.info("%s: the %s' left and right landmarks exchanged in %d frames (%s)", source.path, limb,
                     len(frames_relabelled), ", ".join(map(str, frames_relabelled)))
    if fit.track_outliers:
        log.info("%s: %d landmarks off their tracks left out of the fit (%s)", source.path, len(fit.track_outliers),
                 ", ".join(f"frame {f} {name}" for f, name in fit.track_outliers[:8])
                 + (", ..." if len(fit.track_outliers) > 8 else ""))
    return write_person_data(Path(out_dir), frames, index, fit, decision, moving)


def _number(v: float) -> float | None:
    return round(float(v), 4) if math.isfinite(v) else None


def _log_speed(name: str, fit: PersonFit) -> None:
    """One line with the person's walking speed and where its metres came from; a warning for a scale guessed from
    the steps, and for a cadence no walk has (a slow-motion video)."""
    run = fit.longest_run()
    speed, seconds = fit.walking_speed_mps(), (len(run) - 1) / fit.fps
    if fit.steps is None:
        log.info("%s: walking speed %.2f m/s over %.1f s (static camera)", name, speed, seconds)
        return
    said = (f"{fit.steps.count} steps, {fit.steps.cadence_steps_s:.2f} a second, say "
            f"{speed_from_cadence(fit.steps.cadence_steps_s, fit.poses.body.height_m):.2f} m/s"
            if fit.steps.walks else "no steps seen")
    if fit.scale_from == "steps":
        log.warning("%s: walking speed %.2f m/s over %.1f s, from the person's steps (%s): the camera's path gave no "
                    "scale (no floor among its points, and it moves too nearly on a straight line at constant speed)",
                    name, speed, seconds, said)
    else:
        metres = {"floor": "metres per SfM unit from the floor", "path": "metres per SfM unit from the path's shape",
                  "standing": "a camera turning where it stands, the detector's metres"}[fit.scale_from]
        log.info("%s: walking speed %.2f m/s over %.1f s (moving camera, %s; %s)", name, speed, seconds, metres, said)
    lo, hi = WALK_CADENCE_STEPS_S
    if fit.steps.walks and not lo <= fit.steps.cadence_steps_s <= hi:
        log.warning("%s: the person takes %.2f steps a second, outside a walk's %g-%g: %s", name,
                    fit.steps.cadence_steps_s, lo, hi, "a slow-motion video? Speeds are in the video's time"
                    if fit.steps.cadence_steps_s < lo else "running, or a sped-up video?")


__all__ = ["PERSON_BVH_FILE", "PERSON_FIT_FILE", "PersonSource", "prepare_person_data", "read_person_frames",
           "write_person_data"]
