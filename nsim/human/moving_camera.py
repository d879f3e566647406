"""A person filmed by a moving (handheld) camera: detect the motion, find the camera's path, place the person.

1. **Static or moving** (``decide_camera``): two cues, each with its numbers in the decision
   (``CameraDecision``, logged in one line and kept in ``person_fit.json``).

   * *The background*: corners of the background (the person's mask, dilated, left out) are tracked
     from each frame to the next (``background_motion_px``: pyramidal Lucas-Kanade, OpenCV); a pair's
     motion is the median displacement of the corners tracked there and back again, whose patches
     match. The camera moves when the median over pairs exceeds ``MOVING_FRACTION`` of the frame's
     width (a static camera's frames give sub-pixel values: noise and compression).
   * *The person*: a camera that follows a walker sees the legs walk while the person stays where it
     is in the image, at the same size; a static camera sees a walker cross the image or grow and
     shrink. The steps are counted in the detector's landmarks (``count_steps``: the ankles' fore-aft
     separation changes sign at every step), and how far the person advances is measured as a static
     camera would place it (``nsim.human.monocular.root_translations``, smoothed over
     ``ROOT_SMOOTHING_S``): a person who takes at least ``MIN_STEPS`` steps but advances less than
     ``FOLLOWED_MAX_ADVANCE_M`` per step is followed by the camera. This is what tells a camera that
     follows a walker down a road: the far background hardly moves in the image (a median 0.66 px per
     frame against a 2.56 px threshold on such a video) while the person walks on.

2. **The camera's path** (``camera_path``): nsim's own SfM (``nsim.sfm.colmap.run_sfm``, what
   ``nsim reconstruct`` runs) with the person's dilated mask excluded from feature extraction, so
   that the walking person does not pull the background's geometry; on keyframes only (``keyframes``:
   ``KEYFRAME_FPS`` a second, more where the background moves fast; every frame of a clip of at
   most ``KEYFRAMES_ALL_UP_TO``), ``SFM_MAX_FEATURES`` features, sequential matching over
   ``SFM_OVERLAP`` neighbours, no loop detection. The other frames are placed on SfM's points
   (``register_frames``: the points a keyframe sees tracked into them, PnP), or interpolated between
   registered keyframes where too few points track. Its world has an arbitrary scale. (A 7.4 s
   following-camera video at 640x360, 89 frames at 12 fps: 1,002 s with every frame; 31 keyframes,
   all registered, in 68-90 s on two busy cores.) Where SfM places fewer than
   ``MIN_REGISTERED_FRACTION`` of the keyframes or keeps fewer than ``SFM_MIN_POINTS`` points (a far
   or plain background, a camera turning where it stands, grass and leaves), the lighter model: the
   camera's turns from the background's image motion (``rotation_path``: a far background moves in
   the image as the camera turns, whatever its travel), its travel left to the person (step 3),
   said in a warning line.
3. **Metres** (``place_landmarks_moving``): each frame's landmarks in its camera frame (metric, from
   the detector's body-size prior; ``nsim.human.monocular.root_translations``) go into SfM's world
   as ``R_f p + s C_f`` with the camera's rotation ``R_f`` and centre ``C_f``. The one unknown,
   ``s`` (metres per SfM unit), comes from, in this order:

   * *the floor*, when SfM's sparse points show one (``nsim.sfm.align.gravity_align``, as ``nsim
     reconstruct``): the camera's height above it in SfM units against its height above the
     person's lowest foot (heel or toe, ``SOLE_HEIGHT_M`` over the floor) in metres, medians over
     the frames; the world is then SfM's, floor z = 0;
   * *the path*: where the person's root moves most nearly on a straight line at constant speed
     (``metric_scale``: a wrong ``s`` adds a multiple of the camera's own path to the root's; linear
     least squares in ``s``); only when the camera's own path is far enough from a straight line at
     constant speed for that to tell (``MAX_PATH_SCALE_ERROR``); a camera that follows a walker down a
     straight road cannot;
   * *the steps*, the last resort: ``s`` makes the person's mean velocity as fast as its cadence
     says (``speed_from_cadence``: nsim's stride-speed relation, ``nsim.human.gait_phase``), logged
     with the number.

   With the turns alone (``rotation_path``), the person seen from a camera turning where it stands
   either already walks at least half as fast as the steps say (a camera panning after the walker:
   "standing", the detector's metres) or the camera travels with the person at the steps' speed the
   way the person faces (``travel_with_person``, "steps").

   Without the floor, up and floor come from the person as for a static camera
   (``nsim.human.monocular.floor_frame``). ``--camera-height`` (the median camera height above the
   floor) or the person's height then rescales everything. Walking speed and path length are then
   the world's (``walking_speed_mps``), not the image's.
"""

from __future__ import annotations

import logging
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.human.gait_phase import MIN_SPEED_MPS, STEP_COEFF_M
from nsim.human.landmarks import LANDMARK_NAMES
from nsim.human.monocular import Placement, floor_frame, root_translations, static_camera
from nsim.human.skeleton import REFERENCE_HEIGHT_M, SOLE_HEIGHT_M

log = logging.getLogger(__name__)

MOVING_FRACTION = 0.004
"""The camera moves when the background's median motion between frames exceeds this share of the width."""

MASK_DILATION_FRACTION = 0.02
"""The person's mask is grown by this share of the frame's width before it excludes the background."""

MIN_STEPS = 3
"""The person walks (``Steps.walks``) with at least this many steps counted ..."""

MIN_SWING_M = 0.08
"""... and the ankles' fore-aft separation varying by at least this much (standard deviation, the detector's metres;
a walk swings them by 0.2-0.3 m, a person standing still by a few centimetres of noise)."""

FOLLOWED_MAX_ADVANCE_M = 0.25
"""A walking person who advances less than this per step as a static camera would place them is followed by the
camera (a walker's step is 0.5-0.8 m; a following camera's video gave 0.04-0.15 m)."""

ROOT_SMOOTHING_S = 0.5
"""The person's path is smoothed over this (Gaussian sigma) before its length is taken: the detector's depth jitters
from frame to frame, and the hips sway with every step."""

WALK_CADENCE_STEPS_S = (1.2, 2.6)
"""Steps per second of a walk; outside, the fit says so in a warning (a slow-motion video shows fewer)."""

KEYFRAME_FPS = 4.0
"""SfM sees at most about this many frames a second (the others' poses are interpolated) ..."""

KEYFRAME_MOTION_FRACTION = 0.05
"""... and a keyframe whenever the background has moved this share of the width since the last one ..."""

KEYFRAMES_ALL_UP_TO = 40
"""... but SfM sees every frame of a clip this short: seconds either way, and on the test room's 30-frame actor clip
(320x240) every frame gave a PA-MPJPE of 6.17 cm where 18 keyframes gave 6.56 (60 frames at 480x360: 6.62 cm with
every frame, 6.54 with 32 keyframes in half the time)."""

MAX_INTERPOLATION_GAP_S = 1.0
"""Poses are interpolated between registered keyframes at most this far apart; the frames of a longer gap are not placed."""

SFM_MAX_FEATURES = 2048
SFM_OVERLAP = 5
"""SfM on the keyframes: SIFT features per image; sequential matching against this many next keyframes."""

REGISTER_MIN_POINTS = 12
REGISTER_MAX_ERROR_PX = 2.0
"""A frame between keyframes is placed on SfM's points (``register_frames``) with at least this many of them within
this many pixels of where it sees them; else its pose is interpolated."""

MIN_REGISTERED_FRACTION = 0.5
"""SfM must place at least this share of the keyframes, else the camera's turns are taken from the background's image
motion instead (``rotation_path``) ..."""

SFM_MIN_POINTS = 50
"""... and keep at least this many sparse points (a model without them is degenerate: on a real tracking shot 19 of 24
keyframes came back "registered" with no point left after bundle adjustment lost its gauge)."""

MAX_PATH_SCALE_ERROR = 0.1
"""The path's scale (``metric_scale``) is used only when its relative standard error (``metric_scale_error``) is below
this: a camera that moves nearly on a straight line at constant speed leaves it to the person's own jitter."""

FB_MAX_PX = 1.0
"""A background corner counts when tracking it forward and back again lands within this many pixels."""

PATCH_MAX_DIFF = 15.0
"""... and its 21 x 21 patch differs from where it landed by less than this mean absolute grey level (0-255)."""

SCALE_SOURCES = ("floor", "path", "steps", "standing")
"""``Placement.scale_from`` of a moving camera: where its metres per SfM unit came from (module docstring, step 3);
"standing": a camera only turning (``CameraPath.model`` "rotation"), the metres the detector's."""

_FEET = [LANDMARK_NAMES.index(n) for n in ("left_heel", "right_heel", "left_foot_index", "right_foot_index")]
_ANKLES = [LANDMARK_NAMES.index("left_ankle"), LANDMARK_NAMES.index("right_ankle")]
_HIPS = [LANDMARK_NAMES.index("left_hip"), LANDMARK_NAMES.index("right_hip")]
_SHOULDERS = [LANDMARK_NAMES.index("left_shoulder"), LANDMARK_NAMES.index("right_shoulder")]


@dataclass(frozen=True, eq=False)
class CameraPath:
    """A moving camera found by SfM (``camera_path``), in SfM's world and scale.

    cam_to_world: (N, 4, 4) OpenCV axes, one per frame (NaN: not placed: outside the registered keyframes' span or in a
    gap longer than ``MAX_INTERPOLATION_GAP_S``). camera: the shared intrinsics.
    points_xyz: (P, 3) SfM's sparse points of the background.
    keyframes: (K,) the frames SfM saw; registered: (K,) bool, those it placed (None: every frame, all registered).
    seconds: the wall time. model: "sfm" (SfM's world, arbitrary scale), or "rotation" when SfM placed too few
    keyframes: the camera's turns from the background's image motion (``rotation_path``), every centre at the
    origin, its travel left to the person (``place_landmarks_moving``).
    """

    cam_to_world: np.ndarray
    camera: Camera
    points_xyz: np.ndarray
    keyframes: np.ndarray | None = None
    registered: np.ndarray | None = None
    seconds: float = float("nan")
    model: str = "sfm"

    def summary(self) -> dict[str, Any]:
        """What ``person_fit.json`` records of the path."""
        n = self.cam_to_world.shape[0]
        keys = np.arange(n) if self.keyframes is None else self.keyframes
        reg = np.ones(len(keys), bool) if self.registered is None else self.registered
        return {"model": self.model, "keyframes": int(len(keys)), "keyframes_registered": int(reg.sum()),
                "frames_placed": int(np.isfinite(self.cam_to_world).all(axis=(1, 2)).sum()),
                "points": int(len(self.points_xyz)), "hfov_deg": float(self.camera.fov_deg[0]),
                "seconds": round(float(self.seconds), 1)}


def _dilated(mask: np.ndarray, width: int) -> np.ndarray:
    import cv2

    r = max(1, round(MASK_DILATION_FRACTION * width))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.dilate(np.asarray(mask, dtype=np.uint8), kernel) > 0


def _background_tracks(frames: list[np.ndarray], person_masks: np.ndarray, max_corners: int = 400):
    """Yields ``(i, from_px (K, 2), to_px (K, 2))``: background corners tracked from frame ``i`` to ``i + 1`` that
    tracked back within ``FB_MAX_PX`` with matching patches (``PATCH_MAX_DIFF``); pairs with fewer than 8 are
    skipped."""
    import cv2

    grey = [cv2.cvtColor(np.asarray(f, dtype=np.uint8), cv2.COLOR_RGB2GRAY) for f in frames]
    w = grey[0].shape[1] if grey else 0
    for i in range(len(frames) - 1):
        allowed = (~_dilated(person_masks[i], w)).astype(np.uint8) * 255
        pts = cv2.goodFeaturesToTrack(grey[i], max_corners, 0.01, max(3.0, 0.01 * w), mask=allowed)
        if pts is None or len(pts) < 8:
            continue
        nxt, status, err = cv2.calcOpticalFlowPyrLK(grey[i], grey[i + 1], pts, None, winSize=(21, 21), maxLevel=3)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(grey[i + 1], grey[i], nxt, None, winSize=(21, 21),
                                                        maxLevel=3)
        fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
        ok = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb < FB_MAX_PX) & (err.ravel() < PATCH_MAX_DIFF)
        if ok.sum() >= 8:
            yield i, pts.reshape(-1, 2)[ok].astype(np.float64), nxt.reshape(-1, 2)[ok].astype(np.float64)


def background_motion_px(frames: list[np.ndarray], person_masks: np.ndarray, max_corners: int = 400) -> np.ndarray:
    """Median background displacement (pixels) from each frame to the next, ``(N - 1,)``.

    frames: N ``(H, W, 3)`` uint8 RGB. person_masks: (N, H, W) bool, left out (dilated). A corner
    counts when tracking it forward and back lands within ``FB_MAX_PX`` of where it started and its
    patch matches (``PATCH_MAX_DIFF``); NaN for
    a pair with fewer than 8 such corners (frames that share no background: no evidence either way).
    """
    out = np.full(max(len(frames) - 1, 0), np.nan)
    for i, a, b in _background_tracks(frames, person_masks, max_corners):
        out[i] = float(np.median(np.linalg.norm(b - a, axis=1)))
    return out


def rotation_between(bearings_a: np.ndarray, bearings_b: np.ndarray, rounds: int = 3) -> np.ndarray:
    """The rotation ``R (3, 3)`` with ``b ~ R a`` for unit bearings ``(K, 3)`` of far points seen from one place
    (Wahba's problem: the SVD of ``sum b a^T``), refitted ``rounds`` times on the pairs within three times the
    median angle (at least 0.1 deg) of it: near points' parallax and things that move are left out."""
    a, b = np.asarray(bearings_a, dtype=np.float64), np.asarray(bearings_b, dtype=np.float64)
    use = np.ones(len(a), dtype=bool)
    R = np.eye(3)
    for _ in range(rounds + 1):
        U, _, Vt = np.linalg.svd(b[use].T @ a[use])
        R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        angle = np.arccos(np.clip(np.einsum("ki,ki->k", b, a @ R.T), -1.0, 1.0))
        cut = max(3.0 * float(np.median(angle[use])), math.radians(0.1))
        if (angle <= cut).sum() < 3:
            break
        use = angle <= cut
    return R


def rotation_path(frames: list[np.ndarray], person_masks: np.ndarray, camera: Camera,
                  max_corners: int = 400) -> tuple[np.ndarray, int]:
    """The camera's rotations ``(N, 3, 3)`` (camera-to-world, frame 0's axes as the world) from the background's
    image motion alone, as for a camera turning where it stands (``rotation_between`` on the tracked corners'
    bearings, chained); and how many frame pairs had no background to track (taken as not turning)."""
    R = np.tile(np.eye(3), (len(frames), 1, 1))
    step = np.tile(np.eye(3), (max(len(frames) - 1, 0), 1, 1))
    found = np.zeros(len(step), dtype=bool)
    for i, a, b in _background_tracks(frames, person_masks, max_corners):
        da, db = camera.unproject(a), camera.unproject(b)
        da /= np.linalg.norm(da, axis=1, keepdims=True)
        db /= np.linalg.norm(db, axis=1, keepdims=True)
        step[i], found[i] = rotation_between(da, db), True  # b = R_{i+1}^T R_i a
    for i in range(len(step)):
        R[i + 1] = R[i] @ step[i].T
    return R, int((~found).sum())


def camera_moves(motion_px: np.ndarray, width: int) -> bool:
    """Whether the background's motion (``background_motion_px``) says the camera moves."""
    m = np.asarray(motion_px, dtype=np.float64)
    m = m[np.isfinite(m)]
    return bool(m.size) and float(np.median(m)) > MOVING_FRACTION * width


# ------------------------------------------------------------------------------------------------- the person's steps


@dataclass(frozen=True)
class Steps:
    """A person's steps counted in the detector's landmarks (``count_steps``).

    count: steps (sign changes of the ankles' fore-aft separation); cadence_steps_s: steps per second between the
    first and the last one (NaN: fewer than two); swing_m: the separation's standard deviation (detector's metres).
    """

    count: int
    cadence_steps_s: float
    swing_m: float

    @property
    def walks(self) -> bool:
        return self.count >= MIN_STEPS and self.swing_m >= MIN_SWING_M and math.isfinite(self.cadence_steps_s)


def _filled(values: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """``values (F, ...)`` with the rows where ``ok`` is False linearly interpolated from the others (held at the ends)."""
    idx = np.flatnonzero(ok)
    flat = values.reshape(len(values), -1)
    out = np.stack([np.interp(np.arange(len(values)), idx, flat[idx, k]) for k in range(flat.shape[1])], axis=1)
    return out.reshape(values.shape)


def count_steps(body_m: np.ndarray, fps: float) -> Steps:
    """The steps of a walking person in F consecutive frames (module docstring, step 1).

    body_m: (F, L, 3) the detector's landmarks relative to the hips (NaN: not found). The ankles' separation
    (left minus right) swings back and forth along the walking direction, its main axis over the frames; a step is
    counted where it changes sign, with a hysteresis of 30 % of its standard deviation (noise around zero is no step).
    """
    d = np.asarray(body_m, dtype=np.float64)[:, _ANKLES[0]] - np.asarray(body_m, dtype=np.float64)[:, _ANKLES[1]]
    ok = np.isfinite(d).all(axis=1)
    if ok.sum() < 3:
        return Steps(0, float("nan"), 0.0)
    d = _filled(d, ok)
    d -= np.median(d, axis=0)
    axis = np.linalg.svd(d, full_matrices=False)[2][0]
    sig = d @ axis
    swing = float(sig.std())
    h = 0.3 * swing
    state, crossings = 0, []
    for i, v in enumerate(sig):
        side = 1 if v > h else -1 if v < -h else 0
        if side and side != state:
            if state:
                crossings.append(i)
            state = side
    cadence = (len(crossings) - 1) * fps / (crossings[-1] - crossings[0]) if len(crossings) >= 2 else float("nan")
    return Steps(len(crossings), float(cadence), swing)


def speed_from_cadence(cadence_steps_s: float, height_m: float = REFERENCE_HEIGHT_M) -> float:
    """Walking speed (m/s) of a person of ``height_m`` taking ``cadence_steps_s`` steps a second.

    The inverse of ``nsim.human.gait.cadence_steps_per_min`` (nsim's one stride-speed relation,
    ``nsim.human.gait_phase``: a step is ``STEP_COEFF_M * sqrt(v) * height / 1.75 m``), so
    ``v = (STEP_COEFF_M * cadence * height / 1.75 m)^2``; held at ``MIN_SPEED_MPS`` below it.
    """
    v = (STEP_COEFF_M * float(cadence_steps_s) * float(height_m) / REFERENCE_HEIGHT_M) ** 2
    return max(v, MIN_SPEED_MPS)


def path_length_m(xyz_m: np.ndarray, fps: float, smoothing_s: float = ROOT_SMOOTHING_S) -> float:
    """Length of a path ``(F, D)`` sampled at ``fps`` after Gaussian smoothing over ``smoothing_s`` (NaN rows
    interpolated; NaN if fewer than two rows are finite), its ends padded by point reflection (``smooth_path``: a
    straight walk at constant speed keeps its length)."""
    p = np.asarray(xyz_m, dtype=np.float64)
    ok = np.isfinite(p).all(axis=1)
    if ok.sum() < 2:
        return float("nan")
    first, last = np.flatnonzero(ok)[[0, -1]]
    p = smooth_path(_filled(p, ok)[first:last + 1], smoothing_s * fps)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def smooth_path(xyz: np.ndarray, sigma_frames: float) -> np.ndarray:
    """A path ``(F, D)`` smoothed along F by a Gaussian of ``sigma_frames``, its ends padded by point reflection:
    a straight line at constant speed stays as it is (repeating the ends would slow it down there)."""
    from scipy.ndimage import gaussian_filter1d

    p = np.asarray(xyz, dtype=np.float64)
    k = min(len(p) - 1, int(math.ceil(4.0 * sigma_frames)))
    if k <= 0 or sigma_frames <= 0:
        return p.copy()
    padded = np.concatenate([2.0 * p[0] - p[k:0:-1], p, 2.0 * p[-1] - p[-2:-k - 2:-1]])
    return gaussian_filter1d(padded, sigma_frames, axis=0, mode="nearest")[k:k + len(p)]


def walking_speed_mps(root_xyz_m: np.ndarray, fps: float) -> float:
    """A walker's speed over consecutive frames: the length of the root's horizontal path (x, y of a z-up world),
    smoothed over ``ROOT_SMOOTHING_S`` (the hips' sway), over the time it took."""
    r = np.asarray(root_xyz_m, dtype=np.float64)
    if len(r) < 2:
        return float("nan")
    return path_length_m(r[:, :2], fps) * fps / (len(r) - 1)


# ------------------------------------------------------------------------------------------------- static or moving


@dataclass(frozen=True)
class CameraDecision:
    """Static or moving, and why (module docstring, step 1).

    moving: the decision. by: what decided it: "background", "person" (the person walks on the spot in the image),
    "neither" (static: neither cue says it moves), or "option" (``--camera`` said so).
    background_px: the background's median motion per frame (NaN: not measured or no background seen);
    threshold_px: the motion above which the camera moves; steps: the person's steps; advance_per_step_m: how far
    the person advances per step as a static camera would place them.
    """

    moving: bool
    by: str
    background_px: float
    threshold_px: float
    steps: Steps
    advance_per_step_m: float

    def describe(self) -> str:
        bg = (f"the background moves {self.background_px:.2f} px a frame (threshold {self.threshold_px:.2f})"
              if math.isfinite(self.background_px) else "no background motion measured")
        walk = (f"the person takes {self.steps.count} steps ({self.steps.cadence_steps_s:.2f} a second) and advances "
                f"{self.advance_per_step_m:.2f} m per step in a static camera's view (followed below "
                f"{FOLLOWED_MAX_ADVANCE_M:g} m)" if self.steps.walks else "the person does not walk")
        verdict = {"background": "the camera moves", "person": "the camera follows the person",
                   "neither": "the camera is static", "option": f"the camera is {'moving' if self.moving else 'static'} "
                                                              "(--camera)"}[self.by]
        return f"{verdict}: {bg}; {walk}"

    def to_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return round(float(v), 4) if math.isfinite(v) else None

        return {"camera": "moving" if self.moving else "static", "by": self.by,
                "background_px": num(self.background_px), "threshold_px": num(self.threshold_px),
                "steps": self.steps.count, "cadence_steps_s": num(self.steps.cadence_steps_s),
                "swing_m": num(self.steps.swing_m), "advance_per_step_m": num(self.advance_per_step_m)}


def decide_camera(motion_px: np.ndarray | None, width: int, body_m: np.ndarray, image_uv_px: np.ndarray,
                  visibility: np.ndarray, camera: Camera, fps: float, mode: str = "auto") -> CameraDecision:
    """Static or moving (module docstring, step 1) from F consecutive frames of one person.

    motion_px: ``background_motion_px`` (None: not measured); body_m, image_uv_px, visibility: the detector's
    (F, L, ...) for those frames (NaN where not found); camera: a static camera's intrinsics (to place the person as
    it would); mode: "auto" decides, "static" / "moving" only records the numbers beside the given answer.
    """
    m = np.asarray([] if motion_px is None else motion_px, dtype=np.float64)
    m = m[np.isfinite(m)]
    background = float(np.median(m)) if m.size else float("nan")
    threshold = MOVING_FRACTION * width
    steps = count_steps(body_m, fps)
    w = np.clip(np.nan_to_num(np.asarray(visibility, dtype=np.float64)), 0.0, 1.0)
    root = root_translations(body_m, image_uv_px, w, camera)
    advance = path_length_m(root, fps) / max(steps.count, 1)
    if mode != "auto":
        return CameraDecision(mode == "moving", "option", background, threshold, steps, advance)
    if background > threshold:
        return CameraDecision(True, "background", background, threshold, steps, advance)
    if steps.walks and advance < FOLLOWED_MAX_ADVANCE_M:
        return CameraDecision(True, "person", background, threshold, steps, advance)
    return CameraDecision(False, "neither", background, threshold, steps, advance)


# ------------------------------------------------------------------------------------------------- the camera's path


def keyframes(num_frames: int, fps: float, motion_px: np.ndarray | None = None, width: int | None = None) -> np.ndarray:
    """The frames SfM sees, ``(K,)`` increasing (module docstring, step 2): every frame of a clip of at most
    ``KEYFRAMES_ALL_UP_TO``; else the first, then the next whenever ``1 / KEYFRAME_FPS`` seconds have passed or the
    background (``motion_px``, per frame pair; NaN counts as none) has moved ``KEYFRAME_MOTION_FRACTION`` of
    ``width`` since the last keyframe, and the last frame."""
    if num_frames <= KEYFRAMES_ALL_UP_TO:
        return np.arange(num_frames, dtype=np.int64)
    step = max(1, int(round(fps / KEYFRAME_FPS)))
    moved = np.zeros(max(num_frames - 1, 0)) if motion_px is None else np.nan_to_num(np.asarray(motion_px, float))
    limit = KEYFRAME_MOTION_FRACTION * width if width else math.inf
    keys, since, acc = [0], 0, 0.0
    for i in range(1, num_frames):
        since += 1
        acc += float(moved[i - 1]) if i - 1 < len(moved) else 0.0
        if since >= step or acc >= limit or i == num_frames - 1:
            keys.append(i)
            since, acc = 0, 0.0
    return np.asarray(keys if num_frames > 0 else [], dtype=np.int64)


def interpolate_path(keys: np.ndarray, key_c2w: np.ndarray, num_frames: int, fps: float) -> np.ndarray:
    """Every frame's camera ``(num_frames, 4, 4)`` from the keyframes' ``key_c2w (K, 4, 4)`` (NaN: not registered):
    interpolated between consecutive registered keyframes at most ``MAX_INTERPOLATION_GAP_S`` apart (positions
    linear, rotations slerped: ``nsim.geometry.transforms.interpolate_poses``), NaN elsewhere."""
    from nsim.geometry.transforms import interpolate_poses

    keys = np.asarray(keys, dtype=np.int64)
    ok = np.isfinite(key_c2w).all(axis=(1, 2))
    out = np.full((num_frames, 4, 4), np.nan)
    k, T = keys[ok], np.asarray(key_c2w, dtype=np.float64)[ok]
    if len(k) == 1:
        out[k[0]] = T[0]
    for a in range(len(k) - 1):
        if (k[a + 1] - k[a]) / fps > MAX_INTERPOLATION_GAP_S:
            out[k[a]], out[k[a + 1]] = T[a], T[a + 1]
            continue
        frames = np.arange(k[a], k[a + 1] + 1)
        out[frames] = interpolate_poses(k[a:a + 2] / fps, T[a:a + 2], frames / fps)
    return out


def camera_path(frames: list[np.ndarray], person_masks: np.ndarray, fps: float, hfov_deg: float | None = None,
                motion_px: np.ndarray | None = None, work_dir: str | Path | None = None, num_threads: int = -1,
                source: str = "video") -> CameraPath:
    """The moving camera of each frame by SfM on keyframes with the person masked out (step 2 of the module docstring).

    frames: N ``(H, W, 3)`` uint8 RGB at ``fps``; person_masks: (N, H, W) bool; motion_px: ``background_motion_px``
    (more keyframes where the background moves fast; None: by time only). The intrinsics are shared by every frame:
    fixed at ``hfov_deg`` when given, else estimated. InputError naming ``source`` when too few keyframes register.
    """
    import time

    from nsim.io.images import write_image
    from nsim.sfm.colmap import run_sfm
    from nsim.sfm.options import SfmOptions

    t0 = time.perf_counter()
    n = len(frames)
    h, w = frames[0].shape[:2]
    keys = keyframes(n, fps, motion_px, w)
    known = None if hfov_deg is None else Camera.pinhole_from_fov(w, h, float(hfov_deg))
    opts = SfmOptions(matcher="sequential", loop_detection=False, num_threads=num_threads, camera_model="PINHOLE",
                      shared_intrinsics=True, max_features=SFM_MAX_FEATURES, overlap=SFM_OVERLAP,
                      retry_below_fraction=0.9, min_registered_fraction=0.0)
    with tempfile.TemporaryDirectory(dir=work_dir) as tmp:
        root = Path(tmp)
        (root / "images").mkdir()
        (root / "masks").mkdir()
        names = [f"frame_{i:05d}.png" for i in keys]
        for name, i in zip(names, keys, strict=True):
            write_image(root / "images" / name, np.asarray(frames[i], dtype=np.uint8))
            write_image(root / "masks" / f"{name}.png", (~_dilated(person_masks[i], w)).astype(np.uint8) * 255)
        try:
            result = run_sfm(root / "images", root / "sfm", opts, known_camera=known, image_names=names,
                             mask_dir=root / "masks")
            placed, points = len(result.registered_names), len(result.points_xyz)
        except InputError:  # fewer than two registered (run_sfm's hint names reconstruct's options, not these)
            placed, points = 0, 0
    if placed < MIN_REGISTERED_FRACTION * len(names) or points < SFM_MIN_POINTS:
        camera = known if known is not None else static_camera(w, h)
        R, blind = rotation_path(frames, person_masks, camera)
        if blind > MIN_REGISTERED_FRACTION * max(n - 1, 1):
            raise InputError(f"{source}: the camera moves, but SfM placed {placed} of {len(names)} keyframes with "
                             f"{points} points, and "
                             f"{blind} of {n - 1} frame pairs show no background to track; if the camera stands "
                             "still, give --camera static")
        log.warning("%s: SfM placed %d of %d keyframes with %d points (a far or plain background, or a camera turning "
                    "where it stands): the camera's turns from the background's image motion instead (%d of %d frame "
                    "pairs tracked), its travel from the person", source, placed, len(names), points, n - 1 - blind,
                    n - 1)
        c2w = np.tile(np.eye(4), (n, 1, 1))
        c2w[:, :3, :3] = R
        return CameraPath(c2w, camera, np.zeros((0, 3)), keys, np.zeros(len(keys), dtype=bool),
                          time.perf_counter() - t0, "rotation")
    key_c2w = np.stack([result.cam_to_world.get(name, np.full((4, 4), np.nan)) for name in names])
    camera = known if known is not None else result.cameras[result.registered_names[0]]
    c2w = interpolate_path(keys, key_c2w, n, fps)
    seen = {}  # keyframe -> (its points' pixels (P, 2) OpenCV convention, the points (P, 3))
    for k, name in zip(keys, names, strict=True):
        image = result.reconstruction.find_image_with_name(name)
        if image is not None and image.has_pose:
            obs = [(p.xy, result.reconstruction.points3D[p.point3D_id].xyz) for p in image.points2D if p.has_point3D()]
            if obs:
                seen[int(k)] = (np.array([o[0] for o in obs]) - 0.5, np.array([o[1] for o in obs]))
    c2w = register_frames(frames, camera, seen, c2w)
    return CameraPath(c2w, camera, np.asarray(result.points_xyz, dtype=np.float64), keys,
                      np.isfinite(key_c2w).all(axis=(1, 2)), time.perf_counter() - t0)


def register_frames(frames: list[np.ndarray], camera: Camera, seen: dict[int, tuple[np.ndarray, np.ndarray]],
                    cam_to_world: np.ndarray) -> np.ndarray:
    """Every frame between the keyframes placed on SfM's points (module docstring, step 2): the points a registered
    keyframe sees (``seen``: keyframe -> its points' pixels ``(P, 2)`` and the points ``(P, 3)``) are tracked into
    the frame from the nearest such keyframe (Lucas-Kanade, forward and back within ``FB_MAX_PX``), and the frame's
    pose solved from them (RANSAC PnP, refined, started at its interpolated pose ``cam_to_world (N, 4, 4)``). A
    frame with fewer than ``REGISTER_MIN_POINTS`` inliers keeps the interpolated pose. Returns the poses (N, 4, 4)."""
    import cv2

    out = np.array(cam_to_world, dtype=np.float64)
    if not seen:
        return out
    K = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
    grey = [cv2.cvtColor(np.asarray(f, dtype=np.uint8), cv2.COLOR_RGB2GRAY) for f in frames]
    keys = np.array(sorted(seen))
    for f in range(len(frames)):
        if f in seen or not np.isfinite(out[f]).all():
            continue
        k = int(keys[np.argmin(np.abs(keys - f))])
        uv, xyz = seen[k]
        pts = uv.astype(np.float32).reshape(-1, 1, 2)
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(grey[k], grey[f], pts, None, winSize=(21, 21), maxLevel=3)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(grey[f], grey[k], nxt, None, winSize=(21, 21), maxLevel=3)
        ok = ((status.ravel() == 1) & (status_back.ravel() == 1)
              & (np.linalg.norm((back - pts).reshape(-1, 2), axis=1) < FB_MAX_PX))
        if ok.sum() < REGISTER_MIN_POINTS:
            continue
        w2c = np.linalg.inv(out[f])
        rvec, tvec = cv2.Rodrigues(w2c[:3, :3])[0], w2c[:3, 3].reshape(3, 1)
        found, rvec, tvec, inliers = cv2.solvePnPRansac(
            xyz[ok].astype(np.float64), nxt.reshape(-1, 2)[ok].astype(np.float64), K, None, rvec.copy(), tvec.copy(),
            useExtrinsicGuess=True, iterationsCount=200, reprojectionError=REGISTER_MAX_ERROR_PX,
            flags=cv2.SOLVEPNP_ITERATIVE)
        if not found or inliers is None or len(inliers) < REGISTER_MIN_POINTS:
            continue
        idx = inliers.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(xyz[ok][idx].astype(np.float64), nxt.reshape(-1, 2)[ok][idx].astype(np.float64),
                                         K, None, rvec, tvec)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
        out[f] = np.linalg.inv(pose)
    return out


# ------------------------------------------------------------------------------------------------- metres


def _line_residuals(x: np.ndarray, time: np.ndarray) -> np.ndarray:
    """What is left of ``x (F, 3)`` after the best straight line at constant speed in ``time (F,)`` (least squares)."""
    V = np.stack([np.ones(len(time)), time - time.mean()], axis=1)
    return x - V @ (np.linalg.pinv(V) @ x)


def _path_parts(root_cam_m: np.ndarray, cam_to_world: np.ndarray,
                times: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``metric_scale``'s two paths after their best straight lines at constant speed: the root's rotated into the
    world ``R_f t_f`` and the camera's ``C_f`` (rows where both are finite; None: fewer than 3); and the camera
    centres' spread (sum of squares about their mean)."""
    t = np.asarray(root_cam_m, dtype=np.float64)
    T = np.asarray(cam_to_world, dtype=np.float64)
    time = np.arange(len(t), dtype=np.float64) if times is None else np.asarray(times, dtype=np.float64)
    ok = np.isfinite(t).all(1) & np.isfinite(T[:, :3, :]).all((1, 2))
    if ok.sum() < 3:
        return None
    a, b = np.einsum("fij,fj->fi", T[ok, :3, :3], t[ok]), T[ok, :3, 3]
    return _line_residuals(a, time[ok]), _line_residuals(b, time[ok]), float(((b - b.mean(0)) ** 2).sum())


def metric_scale(root_cam_m: np.ndarray, cam_to_world: np.ndarray, times: np.ndarray | None = None) -> float:
    """Metres per SfM unit: the ``s`` making the root's path ``R_f t_f + s C_f`` straightest (module docstring).

    root_cam_m: (F, 3) the person's root in each frame's camera (metres; NaN rows skipped);
    cam_to_world: (F, 4, 4) in SfM's units; times: (F,) seconds (None: evenly spaced). A person walks
    at a nearly constant velocity, and a wrong ``s`` adds a multiple of the camera's own path to the
    root's: ``s`` minimises what is left of the root's path after the best straight line at constant
    speed (least squares per axis against ``1, t``), linear least squares in ``s``. (Second
    differences instead are dominated by the detector's frame-to-frame depth noise, which biases
    ``s`` low.) NaN when the camera itself moves on a straight line at constant speed (then the
    images cannot tell); ``metric_scale_error`` says how well the path tells it.
    """
    parts = _path_parts(root_cam_m, cam_to_world, times)
    if parts is None:
        return float("nan")
    pa, pb, spread = parts
    den = float((pb**2).sum())
    if den <= 1e-9 * max(spread, 1e-12):
        return float("nan")
    return -float((pa * pb).sum()) / den


def metric_scale_error(root_cam_m: np.ndarray, cam_to_world: np.ndarray, times: np.ndarray | None, s: float) -> float:
    """The relative standard error of ``metric_scale``'s ``s``: what is left of the root's path at ``s`` taken as
    noise, against how far the camera's own path bends (a camera on a straight line at constant speed: infinite)."""
    parts = _path_parts(root_cam_m, cam_to_world, times)
    if parts is None or not (np.isfinite(s) and s > 0):
        return float("inf")
    pa, pb, _ = parts
    den = float((pb**2).sum())
    dof = max(pa.size - 1, 1)
    sigma = math.sqrt(float(((pa + s * pb) ** 2).sum()) / dof)
    return sigma / math.sqrt(den) / s if den > 0 else float("inf")


def steps_scale(root_cam_m: np.ndarray, cam_to_world: np.ndarray, times: np.ndarray, speed_mps: float) -> float:
    """Metres per SfM unit making the root's mean velocity (the slope of the best straight line through ``R_f t_f +
    s C_f`` in ``times``) ``speed_mps`` long (the larger root of that quadratic in ``s``; NaN if none is > 0)."""
    t = np.asarray(root_cam_m, dtype=np.float64)
    T = np.asarray(cam_to_world, dtype=np.float64)
    time = np.asarray(times, dtype=np.float64)
    ok = np.isfinite(t).all(1) & np.isfinite(T[:, :3, :]).all((1, 2))
    if ok.sum() < 3:
        return float("nan")
    tc = time[ok] - time[ok].mean()
    if not (tc**2).sum() > 0:
        return float("nan")

    def slope(x: np.ndarray) -> np.ndarray:
        return (tc[:, None] * (x - x.mean(0))).sum(0) / (tc**2).sum()

    a, b = slope(np.einsum("fij,fj->fi", T[ok, :3, :3], t[ok])), slope(T[ok, :3, 3])
    qa, qb, qc = float(b @ b), 2.0 * float(a @ b), float(a @ a) - float(speed_mps) ** 2
    disc = qb * qb - 4.0 * qa * qc
    if qa <= 0 or disc < 0:
        return float("nan")
    s = (-qb + math.sqrt(disc)) / (2.0 * qa)
    return s if s > 0 else float("nan")


def floor_scale(cam_points_m: np.ndarray, weights: np.ndarray, cam_to_world_zup: np.ndarray,
                min_weight: float = 0.5, sole_height_m: float = SOLE_HEIGHT_M) -> float:
    """Metres per SfM unit from the floor (step 3 of the module docstring).

    cam_points_m: (F, L, 3) landmarks in each frame's camera (metres); weights (F, L);
    cam_to_world_zup: (F, 4, 4) the cameras in SfM's units with the floor at z = 0, +z up.
    NaN when no frame shows a foot or the cameras are not above the floor.
    """
    p = np.asarray(cam_points_m, dtype=np.float64)[:, _FEET]
    w = np.asarray(weights, dtype=np.float64)[:, _FEET]
    T = np.asarray(cam_to_world_zup, dtype=np.float64)
    z = np.einsum("fj,fkj->fk", T[:, 2, :3], p)  # each foot point's height relative to the camera (m)
    z = np.where((w >= min_weight) & np.isfinite(z), z, np.nan)
    rows = np.isfinite(z).any(axis=1) & np.isfinite(T[:, 2, 3])
    if not rows.any():
        return float("nan")
    metres = float(np.median(-np.nanmin(z[rows], axis=1))) + sole_height_m
    units = float(np.median(T[rows, 2, 3]))
    return metres / units if units > 0 and metres > 0 else float("nan")


def facing_cam(body_m: np.ndarray) -> np.ndarray:
    """The way a person faces, ``(F, 3)`` unit vectors in the camera's axes, from the detector's landmarks
    ``(F, L, 3)``: across the hips (left minus right) crossed with the body's axis (hips to shoulders). NaN where
    those landmarks are not all finite."""
    b = np.asarray(body_m, dtype=np.float64)
    across = b[:, _HIPS[0]] - b[:, _HIPS[1]]
    up = b[:, _SHOULDERS].mean(axis=1) - b[:, _HIPS].mean(axis=1)
    f = np.cross(across, up)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def travel_with_person(root_world_m: np.ndarray, facing_world: np.ndarray, times: np.ndarray,
                       speed_mps: float) -> np.ndarray:
    """Where a camera that turns in place ``(F, 3)`` would have to travel so that the person it films, at
    ``root_world_m (F, 3)`` as seen from the origin, walks at ``speed_mps`` the way it faces (``facing_world (F,
    3)``, smoothed over ``ROOT_SMOOTHING_S``): the walk dead-reckoned from the first frame, minus the person's
    place in view, smoothed alike (the person's own sway stays theirs). Rows NaN in either input: NaN."""
    from scipy.ndimage import gaussian_filter1d

    r, f = np.asarray(root_world_m, dtype=np.float64), np.asarray(facing_world, dtype=np.float64)
    time = np.asarray(times, dtype=np.float64)
    ok = np.isfinite(r).all(axis=1) & np.isfinite(f).all(axis=1)
    out = np.full(r.shape, np.nan)
    if ok.sum() < 2:
        return out
    idx = np.flatnonzero(ok)
    fps = 1.0 / float(np.median(np.diff(time[idx])))
    heading = gaussian_filter1d(f[idx], ROOT_SMOOTHING_S * fps, axis=0, mode="nearest")
    heading /= np.linalg.norm(heading, axis=1, keepdims=True)
    dt = np.diff(time[idx], prepend=time[idx[0]])
    walked = r[idx[0]] + np.cumsum(speed_mps * heading * dt[:, None], axis=0)
    out[idx] = smooth_path(walked - r[idx], ROOT_SMOOTHING_S * fps)
    return out


def place_landmarks_moving(body_m: np.ndarray, image_uv_px: np.ndarray, visibility: np.ndarray, camera: Camera,
                           cam_to_world_sfm: np.ndarray, points_xyz: np.ndarray | None = None,
                           camera_height_m: float | None = None, body_height_m: float | None = None,
                           times: np.ndarray | None = None, steps_speed_mps: float | None = None,
                           rotation_only: bool = False) -> Placement:
    """``nsim.human.monocular.place_landmarks`` for a moving camera (step 3 of the module docstring).

    cam_to_world_sfm: (F, 4, 4) SfM's camera of each frame (NaN rows: not registered, not placed);
    points_xyz: SfM's sparse points (None or no floor among them: the scale from the root's path,
    ``metric_scale``, with the frames' ``times`` in seconds, None: evenly spaced); steps_speed_mps: the speed the
    person's steps say (``speed_from_cadence``), the scale's last resort (``steps_scale``; None: none).
    Returns a ``Placement`` whose ``cam_to_world`` is (F, 4, 4) (z-up metric world, floor z = 0),
    ``camera_height_m`` the median camera height, ``scale`` the metres per SfM unit and ``scale_from`` where that
    came from (``SCALE_SOURCES``). ValueError if no frame can be placed or no scale found.

    rotation_only: ``cam_to_world_sfm`` holds only the camera's turns (``CameraPath.model`` "rotation"; centres
    ignored). If the person, seen from a camera turning where it stands, already walks at least half as fast as
    the steps say, that is taken as so ("standing": a camera panning after a walker); else the camera travels with
    the person (``travel_with_person``, "steps").
    """
    if camera_height_m is not None and body_height_m is not None:
        raise ValueError("place_landmarks_moving: give camera_height_m or body_height_m, not both")
    c2w = np.asarray(cam_to_world_sfm, dtype=np.float64)
    time = np.arange(len(c2w), dtype=np.float64) if times is None else np.asarray(times, dtype=np.float64)
    w = np.clip(np.nan_to_num(np.asarray(visibility, dtype=np.float64)), 0.0, 1.0)
    t = root_translations(body_m, image_uv_px, w, camera)
    placed = np.isfinite(t).all(axis=1) & np.isfinite(c2w).all(axis=(1, 2))
    if not placed.any():
        raise ValueError("place_landmarks_moving: no frame could be placed in front of a registered camera")
    cam = np.asarray(body_m, dtype=np.float64) + t[:, None, :]
    w = np.where(placed[:, None], w, 0.0)
    G = None
    root_t = np.where(placed[:, None], t, np.nan)
    target = None if steps_speed_mps is None else float(steps_speed_mps)
    if target is not None and body_height_m is not None:  # the speed is the person's metres; the path the detector's
        from nsim.human.fit import estimate_body

        target *= estimate_body(cam, w).height_m / float(body_height_m)
    if rotation_only:
        c2w = c2w.copy()
        c2w[:, :3, 3] = 0.0
        c2w[~placed] = np.nan
        seen = np.einsum("fij,fj->fi", c2w[:, :3, :3], root_t)
        fps = 1.0 / float(np.median(np.diff(time[placed]))) if placed.sum() > 1 else 1.0
        seen_speed = path_length_m(seen, fps) / max(float(np.ptp(time[placed])), 1e-9)
        if target is None or seen_speed >= 0.5 * target:
            s, scale_from = 1.0, "standing"
        else:
            facing = np.einsum("fij,fj->fi", c2w[:, :3, :3], facing_cam(body_m))
            c2w[:, :3, 3] = travel_with_person(seen, facing, time, target)
            s, scale_from = 1.0, "steps"
        placed &= np.isfinite(c2w).all(axis=(1, 2))
        w = np.where(placed[:, None], w, 0.0)
        points_xyz = None
    if points_xyz is not None and len(points_xyz):
        from nsim.sfm.align import gravity_align

        grav = gravity_align(points_xyz, c2w[placed])
        if grav.floor_found:
            G = grav.T
    if not rotation_only:
        s, scale_from = float("nan"), ""
    if G is not None:  # SfM's floor: z-up SfM world, scale from the camera's height over the person's feet
        zup = np.einsum("ij,fjk->fik", G, c2w)
        s, scale_from = floor_scale(np.where(placed[:, None, None], cam, np.nan), w, zup), "floor"
    if not (np.isfinite(s) and s > 0):
        G = None
        s, scale_from = metric_scale(root_t, c2w, time), "path"
        if not metric_scale_error(root_t, c2w, time, s) <= MAX_PATH_SCALE_ERROR:
            s = float("nan")
    if not (np.isfinite(s) and s > 0) and target is not None:
        s, scale_from = steps_scale(root_t, c2w, time, target), "steps"
    if not (np.isfinite(s) and s > 0):
        steps = "the person's steps were not seen" if target is None else "the steps give none either"
        raise ValueError("place_landmarks_moving: the camera's path gives no scale (no floor among its points, it "
                         f"moves too nearly on a straight line at constant speed, and {steps})")
    if G is None:
        R, C = c2w[:, :3, :3], s * c2w[:, :3, 3]
    else:
        R, C = zup[:, :3, :3], s * zup[:, :3, 3]
    world = np.einsum("fij,flj->fli", R, cam) + C[:, None, :]
    world = np.where(placed[:, None, None], world, np.nan)
    cams = np.tile(np.eye(4), (c2w.shape[0], 1, 1))
    cams[:, :3, :3], cams[:, :3, 3] = R, C
    if G is None:  # up and floor from the person
        F_ = floor_frame(world, w).cam_to_world
        world = world @ F_[:3, :3].T + F_[:3, 3]
        cams = np.einsum("ij,fjk->fik", F_, cams)
    cams[~placed] = np.nan
    height = float(np.median(cams[placed, 2, 3]))
    scale = 1.0
    if camera_height_m is not None:
        if not height > 0:
            raise ValueError("place_landmarks_moving: the cameras are not above the person's floor")
        scale = float(camera_height_m) / height
    elif body_height_m is not None:
        from nsim.human.fit import estimate_body

        scale = float(body_height_m) / estimate_body(world, w).height_m
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"place_landmarks_moving: cannot scale to the given height (scale {scale!r})")
    world = world * scale
    cams[:, :3, 3] *= scale
    return Placement(world, w, cams, height * scale, s * scale, scale_from)


__all__ = ["FB_MAX_PX", "FOLLOWED_MAX_ADVANCE_M", "KEYFRAME_FPS", "KEYFRAME_MOTION_FRACTION", "KEYFRAMES_ALL_UP_TO", "MASK_DILATION_FRACTION",
           "MAX_INTERPOLATION_GAP_S", "MAX_PATH_SCALE_ERROR", "MIN_REGISTERED_FRACTION", "MIN_STEPS", "SFM_MIN_POINTS", "MIN_SWING_M", "MOVING_FRACTION",
           "PATCH_MAX_DIFF", "REGISTER_MAX_ERROR_PX", "REGISTER_MIN_POINTS", "ROOT_SMOOTHING_S", "SCALE_SOURCES", "SFM_MAX_FEATURES", "SFM_OVERLAP",
           "WALK_CADENCE_STEPS_S", "CameraDecision", "CameraPath", "Steps", "background_motion_px", "camera_moves",
           "camera_path", "count_steps", "decide_camera", "facing_cam", "floor_scale", "interpolate_path", "keyframes",
           "metric_scale", "metric_scale_error", "path_length_m", "place_landmarks_moving", "rotation_between",
           "register_frames", "rotation_path", "smooth_path", "speed_from_cadence", "steps_scale", "travel_with_person", "walking_speed_mps"]
