"""A person in a static or moving camera's video -> masks, a metric camera and the nsim body's poses per frame.

``fit_person(observations, fps, cfg)`` is the core behind ``nsim train-human --video``: arrays
in (a detector's ``nsim.human.landmarks.Observations``), arrays out (``PersonFit``). It

1. checks the input, each failure one ``InputError`` line: a video shorter than
   ``min_duration_s``; no person in any frame; a second person in more than
   ``max_crowded_fraction`` of the frames where someone was found; too few frames left
   (``person_frames``: these need the detector's results only, so a caller runs them before
   anything costly, such as the moving camera's SfM);
2. drops the frames without the person or with a second person in view, and reports them as
   stretches (``DroppedStretch``: first and last frame, why);
   makes the limbs' left and right consistent over the video (``consistent_sides``) and gives no weight to
   landmarks that jump off their own image track (``track_outliers``: a hidden arm guessed far off);
3. places the landmarks in a metric z-up world seen by a static camera (``nsim.human.monocular``),
   or by a moving camera whose path SfM found (``nsim.human.moving_camera``; ``camera_path``), its
   scale from SfM's floor, the path's shape or, last, the person's steps (``count_steps``);
4. estimates the person's bone lengths once and fits joint angles per frame to the landmarks in
   3D and to where the camera saw them (``nsim.human.fit``).

``PersonFit.human_poses`` gives the per-frame poses in the human data format
(``nsim.human.data.HumanPoses``) and ``PersonFit.motion_clip`` the longest unbroken stretch as
a ``MotionClip`` (``nsim.human.bvh.write_bvh`` writes it as the person's own BVH clip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.human.fit import FitConfig, ImageLandmarks, PoseFit, estimate_body, fit_poses
from nsim.human.landmarks import (
    LANDMARK_NAMES,
    TRACK_OUTLIER_TORSOS,
    TRAINING_MASK_THRESHOLD,
    Observations,
    consecutive_runs,
    consistent_sides,
    person_training_mask,
    track_outliers,
)
from nsim.human.monocular import place_landmarks, static_camera
from nsim.human.moving_camera import (
    Steps,
    count_steps,
    place_landmarks_moving,
    speed_from_cadence,
    walking_speed_mps,
)
from nsim.human.skeleton import REFERENCE_HEIGHT_M

REFERENCE_WIDTH_PX = 480
"""``PersonVideoConfig.sigma_px`` is given for frames this wide (it scales with the width)."""

CAMERA_MODES = ("auto", "static", "moving")
"""``PersonVideoConfig.camera``: auto tells a moving camera by the background's motion (``nsim.human.moving_camera``)."""

NO_PERSON, CROWDED, UNPLACED = "no person", "another person in view", "could not be placed"
"""Why a frame is dropped."""


@dataclass(frozen=True)
class PersonVideoConfig:
    """How a person is found and fitted in a static camera's video.

    hfov_deg: the camera's horizontal field of view (None: ``nsim.human.monocular.DEFAULT_HFOV_DEG``).
    camera_height_m: the camera's height above the floor, if known (sets the metric scale);
    body_height_m: the person's height instead (at most one of the two; None: the detector's own scale).
    min_duration_s: shortest video, and shortest time the person must be in view.
    max_crowded_fraction: share of the frames with a person that may show someone else too (dropped).
    sigma_px: the detector's 2D landmark error, in pixels at ``REFERENCE_WIDTH_PX`` wide frames: the
        fit weighs a landmark's reprojection error in these units against its 3D error in metres.
    fit: the skeleton fit's weights.
    camera: ``CAMERA_MODES``: static, moving (its path found by SfM with the person masked out), or
        auto (moving when the background moves between frames).
    mask_threshold: the person's probability at which a pixel joins its training masks
        (``nsim.human.landmarks.person_training_mask``).
    mirror_landmarks: MediaPipe's person detector also looks at the mirrored frames
        (``nsim.human.landmarks.MediaPipePoseDetector``'s mirror).
    both_directions: a second detector also runs over the frames last to first (``nsim.human.landmarks.observe``'s
        backward); the looks at a frame are averaged.
    consistent_sides: relabel the legs' and arms' left and right landmarks where the detector's labelling jumps
        from frame to frame (``nsim.human.landmarks.consistent_sides``) before fitting.
    track_outlier_torsos: a landmark farther than this many torso lengths from where its own track's neighbours
        put it in the image is left out of the fit (``nsim.human.landmarks.track_outliers``); None: none is.
    """

    hfov_deg: float | None = None
    camera_height_m: float | None = None
    body_height_m: float | None = None
    min_duration_s: float = 2.0
    max_crowded_fraction: float = 0.1
    sigma_px: float = 4.0
    fit: FitConfig = field(default_factory=FitConfig)
    camera: str = "auto"
    mask_threshold: float = TRAINING_MASK_THRESHOLD
    mirror_landmarks: bool = True
    both_directions: bool = True
    consistent_sides: bool = True
    track_outlier_torsos: float | None = TRACK_OUTLIER_TORSOS

    def __post_init__(self) -> None:
        if self.track_outlier_torsos is not None and not (math.isfinite(self.track_outlier_torsos)
                                                          and self.track_outlier_torsos > 0.0):
            raise ValueError(f"PersonVideoConfig.track_outlier_torsos: must be > 0 or None, got "
                             f"{self.track_outlier_torsos!r}")
        if not (0.0 < self.mask_threshold < 1.0):
            raise ValueError(f"PersonVideoConfig.mask_threshold: must be in (0, 1), got {self.mask_threshold!r}")
        if self.camera not in CAMERA_MODES:
            raise ValueError(f"PersonVideoConfig.camera: expected one of {CAMERA_MODES}, got {self.camera!r}")
        if self.hfov_deg is not None and not (10.0 <= self.hfov_deg <= 170.0):
            raise ValueError(f"PersonVideoConfig.hfov_deg: must be in [10, 170], got {self.hfov_deg!r}")
        if self.camera_height_m is not None and not (0.1 <= self.camera_height_m <= 20.0):
            raise ValueError(f"PersonVideoConfig.camera_height_m: must be in [0.1, 20] m, got {self.camera_height_m!r}")
        if self.body_height_m is not None and not (0.5 <= self.body_height_m <= 2.5):
            raise ValueError(f"PersonVideoConfig.body_height_m: must be in [0.5, 2.5] m, got {self.body_height_m!r}")
        if self.camera_height_m is not None and self.body_height_m is not None:
            raise ValueError("PersonVideoConfig: give camera_height_m or body_height_m, not both")
        if not (self.min_duration_s >= 0.0 and math.isfinite(self.min_duration_s)):
            raise ValueError(f"PersonVideoConfig.min_duration_s: must be >= 0, got {self.min_duration_s!r}")
        if not (math.isfinite(self.sigma_px) and self.sigma_px > 0.0):
            raise ValueError(f"PersonVideoConfig.sigma_px: must be > 0, got {self.sigma_px!r}")
        if not (0.0 <= self.max_crowded_fraction <= 1.0):
            raise ValueError(f"PersonVideoConfig.max_crowded_fraction: must be in [0, 1], got {self.max_crowded_fraction!r}")


@dataclass(frozen=True)
class DroppedStretch:
    """Frames ``first .. last`` (inclusive, video frame indices) left out, and why."""

    first: int
    last: int
    reason: str

    def describe(self, fps: float) -> str:
        n = self.last - self.first + 1
        return (f"frames {self.first}-{self.last} ({self.first / fps:.1f}-{(self.last + 1) / fps:.1f} s, "
                f"{n} frame{'s' if n != 1 else ''}): {self.reason}")


@dataclass(frozen=True, eq=False)
class PersonFit:
    """The person in the kept frames (K of the video's N).

    frames: (K,) int64 video frame indices kept. camera: the camera's intrinsics.
    cam_to_world: (4, 4) OpenCV axes, the same in every frame (a static camera), or (K, 4, 4) (moving). camera_height_m, scale: see
    ``nsim.human.monocular.Placement``. poses: the fit (root trajectory in the world).
    masks: (K, H, W) bool person masks. dropped: stretches of frames left out.
    fps: the video's frame rate. relabelled: per limb pair (``nsim.human.landmarks.LIMB_SIDES``), the video
    frames whose left and right landmarks were exchanged before fitting (``PersonVideoConfig.consistent_sides``).
    track_outliers: (video frame, landmark name) of every landmark left out of the fit as off its track
    (``PersonVideoConfig.track_outlier_torsos``). scale_from: a moving camera's scale source
    (``nsim.human.monocular.Placement``); steps: the person's steps as counted for it (None: a static camera).
    """

    frames: np.ndarray
    camera: Camera
    cam_to_world: np.ndarray
    camera_height_m: float
    scale: float
    poses: PoseFit
    masks: np.ndarray
    dropped: tuple[DroppedStretch, ...]
    fps: float
    relabelled: dict[str, list[int]] = field(default_factory=dict)
    track_outliers: tuple[tuple[int, str], ...] = ()
    scale_from: str = ""
    steps: Steps | None = None

    def human_poses(self, file_paths: tuple[str | None, ...] | None = None):
        """The poses as ``nsim.human.data.HumanPoses`` (root orientation in ``root_to_world``)."""
        from nsim.human.data import HumanPoses

        T = self.poses.joint_transforms
        K = T.shape[0]
        local = self.poses.local_rotations_wxyz.copy()
        local[:, 0] = (1.0, 0.0, 0.0, 0.0)
        paths = (None,) * K if file_paths is None else tuple(file_paths)
        return HumanPoses(self.poses.body.skeleton, self.poses.body.height_m, T[:, 0], local,
                          self.frames / self.fps, paths,
                          {"source": "nsim person video fit", "camera_height_m": self.camera_height_m,
                           "scale": self.scale, "dropped": [d.describe(self.fps) for d in self.dropped]})

    def longest_run(self) -> np.ndarray:
        """Rows of the longest run of consecutive kept frames."""
        runs = np.split(np.arange(self.frames.size), np.flatnonzero(np.diff(self.frames) != 1) + 1)
        return max(runs, key=len)

    def walking_speed_mps(self) -> float:
        """The person's walking speed in the world over the longest unbroken run of frames
        (``nsim.human.moving_camera.walking_speed_mps``)."""
        return walking_speed_mps(self.poses.root_positions_m[self.longest_run()], self.fps)

    def motion_clip(self, name: str = "person"):
        """The longest run of consecutive kept frames as a ``MotionClip`` (for ``write_bvh``)."""
        from nsim.human.motion import MotionClip

        run = self.longest_run()
        p = self.poses
        return MotionClip(p.body.skeleton, self.fps, p.root_positions_m[run], p.local_rotations_wxyz[run], name=name)


def _stretches(frames: np.ndarray, reason: str) -> list[DroppedStretch]:
    return [DroppedStretch(int(r[0]), int(r[-1]), reason) for r in consecutive_runs(np.flatnonzero(frames))]


def person_frames(obs: Observations, fps: float, cfg: PersonVideoConfig = PersonVideoConfig(),
                  source: str = "video") -> tuple[np.ndarray, np.ndarray]:
    """The checks of step 1 (module docstring), which need the detector's results only: run before anything costly
    (SfM). Returns ``(keep, crowded)``, ``(N,)`` bool each: the frames with the one person, and those with someone
    else in view too. Bad input raises a one-line ``InputError`` naming ``source``."""
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"{source}: frame rate must be > 0, got {fps!r}")
    N = obs.num_frames
    duration = N / fps
    if duration < cfg.min_duration_s:
        raise InputError(f"{source}: {duration:.1f} s ({N} frames at {fps:g} fps) is too short: film the person "
                         f"for at least {cfg.min_duration_s:g} s")
    found = np.asarray(obs.found, dtype=bool)
    if not found.any():
        raise InputError(f"{source}: no person found in any of its {N} frames")
    crowded = found & (np.asarray(obs.other_people) > 0)
    if crowded.sum() > cfg.max_crowded_fraction * found.sum():
        first = int(np.flatnonzero(crowded)[0])
        raise InputError(f"{source}: more than one person in {int(crowded.sum())} of {int(found.sum())} frames "
                         f"(first at {first / fps:.1f} s): film one person at a time")
    keep = found & ~crowded
    _check_in_view(keep.sum() / fps, duration, cfg, source)
    return keep, crowded


def _check_in_view(kept_s: float, duration: float, cfg: PersonVideoConfig, source: str) -> None:
    if kept_s < cfg.min_duration_s:
        raise InputError(f"{source}: the person is in view for only {kept_s:.1f} s of {duration:.1f} s (at least "
                         f"{cfg.min_duration_s:g} s needed)")


def fit_person(obs: Observations, fps: float, cfg: PersonVideoConfig = PersonVideoConfig(),
               source: str = "video", camera_path=None) -> PersonFit:
    """Find, place and fit the one person of a camera's frames (module docstring).

    obs: the detector's results for every frame; fps: frames per second; source: names the input
    in error messages. camera_path: a moving camera (``nsim.human.moving_camera.CameraPath``, one
    pose per frame of ``obs``, NaN where SfM did not place it); None: a static camera.
    Bad input raises a one-line ``InputError``.
    """
    keep, crowded = person_frames(obs, fps, cfg, source)
    N = obs.num_frames
    found = np.asarray(obs.found, dtype=bool)
    relabelled: dict[str, list[int]] = {}
    if cfg.consistent_sides:
        obs, relabelled = consistent_sides(obs, keep)
    outliers = np.zeros(obs.visibility.shape, dtype=bool)
    if cfg.track_outlier_torsos is not None:  # after the sides are consistent: a swap is not an outlier
        outliers = track_outliers(obs.image_uv_px, keep, cfg.track_outlier_torsos)
        obs = replace(obs, visibility=np.where(outliers, 0.0, obs.visibility))
    steps = None
    try:
        if camera_path is None:
            camera = static_camera(obs.width, obs.height, cfg.hfov_deg)
            placed = place_landmarks(obs.body_m[keep], obs.image_uv_px[keep], obs.visibility[keep], camera,
                                     cfg.camera_height_m, cfg.body_height_m)
        else:
            camera = camera_path.camera
            steps = count_steps(np.where(keep[:, None, None], obs.body_m, np.nan), fps)
            speed = (speed_from_cadence(steps.cadence_steps_s, cfg.body_height_m or REFERENCE_HEIGHT_M)
                     if steps.walks else None)
            placed = place_landmarks_moving(obs.body_m[keep], obs.image_uv_px[keep], obs.visibility[keep], camera,
                                            np.asarray(camera_path.cam_to_world)[keep], camera_path.points_xyz,
                                            cfg.camera_height_m, cfg.body_height_m, np.flatnonzero(keep) / fps, speed,
                                            rotation_only=camera_path.model == "rotation")
    except ValueError as err:
        raise InputError(f"{source}: cannot place the person in 3D ({err})") from None
    unplaced = np.zeros(N, dtype=bool)
    unplaced[np.flatnonzero(keep)] = ~(placed.weights > 0).any(axis=1)
    keep &= ~unplaced
    dropped = sorted(_stretches(~found, NO_PERSON) + _stretches(crowded, CROWDED) + _stretches(unplaced, UNPLACED),
                     key=lambda d: d.first)
    _check_in_view(keep.sum() / fps, N / fps, cfg, source)
    rows = (placed.weights > 0).any(axis=1)  # rows of the kept-before-placing frames that were placed
    lm, w = placed.landmarks_m[rows], placed.weights[rows]
    frames = np.flatnonzero(keep)
    cam_to_world = placed.cam_to_world if placed.cam_to_world.ndim == 2 else placed.cam_to_world[rows]
    image = ImageLandmarks(obs.image_uv_px[frames], np.linalg.inv(cam_to_world), camera.fx, camera.fy,
                           camera.cx, camera.cy, sigma_px=cfg.sigma_px * obs.width / REFERENCE_WIDTH_PX)
    try:
        body = estimate_body(lm, w)
        poses = fit_poses(lm, body, w, frame_index=frames, cfg=cfg.fit, fps=fps, image=image)
    except ValueError as err:
        raise InputError(f"{source}: cannot fit a skeleton to the person ({err})") from None
    masks = np.stack([person_training_mask(obs.person_masks[f], obs.image_uv_px[f], cfg.mask_threshold)
                      for f in frames])
    return PersonFit(frames, camera, cam_to_world, placed.camera_height_m, placed.scale, poses, masks,
                     tuple(dropped), float(fps), relabelled,
                     tuple((int(f), LANDMARK_NAMES[k]) for f, k in np.argwhere(outliers)), placed.scale_from, steps)


__all__ = ["CAMERA_MODES", "CROWDED", "NO_PERSON", "UNPLACED", "DroppedStretch", "PersonFit", "PersonVideoConfig", "fit_person",
           "person_frames"]
