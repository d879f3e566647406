"""Body landmarks and person masks per frame, from a person detector that runs offline.

The landmarks are BlazePose's 33 (``LANDMARK_NAMES``, the order of MediaPipe Pose's
``PoseLandmark`` enum in google-ai-edge/mediapipe, ``mediapipe/python/solutions/pose.py``;
left/right are the person's own). For each frame a detector gives (``FrameObservation``):

* ``image_uv_px (L, 2)``: pixel coordinates, nsim's convention (``nsim.geometry.cameras``:
  the centre of the top-left pixel is ``(0, 0)``, u right, v down);
* ``body_m (L, 3)``: the landmarks in metres relative to the midpoint of the hips, in the
  camera's axes (OpenCV: x right, y down, z forward), MediaPipe's "world landmarks";
* ``visibility (L,)``: how likely each landmark is in view and not hidden, in [0, 1];
* ``person_mask (H, W)``: probability that a pixel shows the tracked person;
* ``people_mask (H, W)`` or None: probability that a pixel shows any person (to tell when a
  second person is in the frame; ``other_people``).

``PoseDetector`` is the interface (a callable on one RGB frame, None when no person is found);
``MediaPipePoseDetector`` implements it with the models the ``mediapipe`` wheels ship
(``pose_detection.tflite`` + ``pose_landmark_full.tflite``, and ``selfie_segmentation.tflite``
for everyone in the frame), nothing downloaded. MediaPipe is the optional extra ``nsim[people]``
and is imported only when a detector is made; without it that raises a one-line ``InputError``.
``observe`` runs a detector over frames and stacks what it found (``Observations``).

Two ways to look again with the same models, both on by default in ``nsim.human.person_video.PersonVideoConfig``
(``mirror_landmarks``, ``both_directions``): ``MediaPipePoseDetector(mirror=True)`` runs a second tracker on the
mirrored frames and takes its landmarks back (``unmirror``); ``observe(..., backward=detector)`` runs a second
detector over the frames last to first (a tracker's smoothing lags behind the motion, one run backwards lags the
other way). The looks at a frame are averaged (``average_looks``). On the test room's actor video the fitted
skeleton's PA-MPJPE falls from 7.43 to 6.45 cm (320x240, 30 frames) and from 9.1 to 8.3 cm (480x360, 60 frames),
the mask IoU rises from 0.892 to 0.909 and from 0.903 to 0.916 (``bench/real_people.py --fit-only [--quick]``;
mirrored only: 7.31 and 8.46 cm; both directions only: 6.80 and 8.85 cm), for three times the detector's
time (1.0 -> 3.0 s and 2.0 -> 6.3 s).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from nsim.errors import InputError

log = logging.getLogger(__name__)

LANDMARK_NAMES: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
"""BlazePose's 33 body landmarks, in MediaPipe's order."""

PEOPLE_EXTRA = "nsim[people]"
"""The optional extra that installs the person detector."""

MASK_THRESHOLD = 0.5
"""A pixel belongs to a person where the mask's probability is at least this."""

TRAINING_MASK_THRESHOLD = 0.7
"""The person's training masks (``person_training_mask``) keep pixels whose probability is at least this.
MediaPipe's soft masks bleed into the background around the body (armpits, between the legs, above the hair),
so the mask errs on the side of too much at 0.5. On the test room's actor video at 480x360, 60 frames, the
mean mask IoU against the true masks is 0.889 at 0.5, 0.903 at 0.7, 0.881 at 0.9
(``bench/real_people.py --fit-only --mask-threshold T``)."""

LANDMARK_BONES: tuple[tuple[str, str], ...] = (
    ("left_shoulder", "right_shoulder"), ("left_hip", "right_hip"),
    ("left_shoulder", "left_hip"), ("right_shoulder", "right_hip"),
    ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"),
    ("left_wrist", "left_index"), ("left_wrist", "left_pinky"), ("left_wrist", "left_thumb"),
    ("right_wrist", "right_index"), ("right_wrist", "right_pinky"), ("right_wrist", "right_thumb"),
    ("left_hip", "left_knee"), ("left_knee", "left_ankle"), ("left_ankle", "left_heel"),
    ("left_heel", "left_foot_index"), ("left_ankle", "left_foot_index"),
    ("right_hip", "right_knee"), ("right_knee", "right_ankle"), ("right_ankle", "right_heel"),
    ("right_heel", "right_foot_index"), ("right_ankle", "right_foot_index"),
    ("nose", "left_eye"), ("nose", "right_eye"), ("left_eye", "left_ear"), ("right_eye", "right_ear"),
    ("mouth_left", "mouth_right"),
)
"""The segments between BlazePose's landmarks that lie on the body (MediaPipe's pose connections)."""

MIRRORED_LANDMARKS: tuple[int, ...] = tuple(
    LANDMARK_NAMES.index(n.replace("left", "#").replace("right", "left").replace("#", "right")) for n in LANDMARK_NAMES)
"""For each landmark, the index of its mirror image (left <-> right; the nose and the others on the midline stay):
in a mirrored frame BlazePose calls the person's right wrist its left one."""

LOOKS_MAX_DISAGREEMENT = 0.5
"""Two looks at a frame are averaged only where their landmarks lie within this many torso lengths (median over
the landmarks) of each other: farther, the two trackers follow different people (``average_looks``)."""

OTHER_PERSON_MIN_FRACTION = 0.2
"""A blob of ``people_mask`` away from the tracked person counts as another person when its area is
at least this fraction of the tracked person's."""


@dataclass(frozen=True, eq=False)
class FrameObservation:
    """What a detector found in one frame (L landmarks; see the module docstring for the conventions).

    image_uv_px: (L, 2) float64. body_m: (L, 3) float64. visibility: (L,) float64 in [0, 1].
    person_mask: (H, W) float32 in [0, 1]. people_mask: (H, W) float32 in [0, 1], or None.
    """

    image_uv_px: np.ndarray
    body_m: np.ndarray
    visibility: np.ndarray
    person_mask: np.ndarray
    people_mask: np.ndarray | None = None


class PoseDetector(Protocol):
    """One person's landmarks and mask in an RGB frame ``(H, W, 3)`` uint8; None when nobody is found.

    Frames are given in video order (a detector may track the person from frame to frame).
    """

    def __call__(self, rgb: np.ndarray) -> FrameObservation | None: ...

    def close(self) -> None: ...


@dataclass(frozen=True, eq=False)
class Observations:
    """A detector's results over F frames (arrays NaN / 0 where nobody was found).

    found: (F,) bool. image_uv_px: (F, L, 2). body_m: (F, L, 3). visibility: (F, L).
    person_masks: (F, H, W) float32. other_people: (F,) int, people found beside the tracked one.
    width, height: frame size in pixels.
    """

    found: np.ndarray
    image_uv_px: np.ndarray
    body_m: np.ndarray
    visibility: np.ndarray
    person_masks: np.ndarray
    other_people: np.ndarray
    width: int
    height: int

    @property
    def num_frames(self) -> int:
        return int(self.found.shape[0])


def other_people_blobs(person_mask: np.ndarray, people_mask: np.ndarray | None,
                       min_fraction: float = OTHER_PERSON_MIN_FRACTION) -> list[np.ndarray]:
    """The blobs of ``people_mask`` that count as other people: ``(H, W)`` bool each.

    person_mask: (H, W) the tracked person's probabilities; people_mask: (H, W) everyone's (None: none).
    Blobs of ``people_mask`` (at ``MASK_THRESHOLD``) that do not touch the tracked person's mask
    (grown by 2 % of the frame's diagonal) and cover at least ``min_fraction`` of its area count.
    """
    import cv2

    if people_mask is None:
        return []
    person = np.asarray(person_mask) >= MASK_THRESHOLD
    people = np.asarray(people_mask) >= MASK_THRESHOLD
    if person.shape != people.shape or person.ndim != 2:
        raise ValueError(f"other_people: expected two (H, W) masks of one size, got {person.shape}, {people.shape}")
    area = int(person.sum())
    if area == 0:
        return []
    grow = max(1, int(round(0.02 * np.hypot(*person.shape))))
    near = cv2.dilate(person.astype(np.uint8), np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)) > 0
    n, labels, stats, _ = cv2.connectedComponentsWithStats(people.astype(np.uint8), connectivity=8)
    blobs = []
    for k in range(1, n):
        blob = labels == k
        if stats[k, cv2.CC_STAT_AREA] >= min_fraction * area and not (blob & near).any():
            blobs.append(blob)
    return blobs


def other_people(person_mask: np.ndarray, people_mask: np.ndarray | None,
                 min_fraction: float = OTHER_PERSON_MIN_FRACTION) -> int:
    """How many people besides the tracked one a frame shows: ``len(other_people_blobs(...))``."""
    return len(other_people_blobs(person_mask, people_mask, min_fraction))


CONFIRM_MIN_LANDMARKS = 8
"""A blob is a person when at least this many of the body found in its crop lie on it, seen (visibility >= 0.5)."""


def confirmed_person(rgb: np.ndarray, blob: np.ndarray, find_body, pad: float = 0.25) -> bool:
    """Whether a blob a segmenter marked as a person holds one: ``find_body`` (an image -> ``(L, 3)`` pixel u, v,
    visibility, or None) is run on the blob's bounding box grown by ``pad`` of its size on each side, and at least
    ``CONFIRM_MIN_LANDMARKS`` seen landmarks must fall on the blob (grown by a tenth of its size)."""
    import cv2

    ys, xs = np.nonzero(blob)
    if ys.size == 0:
        return False
    h, w = blob.shape
    by, bx = ys.max() - ys.min() + 1, xs.max() - xs.min() + 1
    y0, y1 = max(0, int(ys.min() - pad * by)), min(h, int(ys.max() + pad * by) + 1)
    x0, x1 = max(0, int(xs.min() - pad * bx)), min(w, int(xs.max() + pad * bx) + 1)
    body = find_body(rgb[y0:y1, x0:x1])
    if body is None:
        return False
    g = max(1, int(round(0.1 * max(by, bx))))
    grown = cv2.dilate(blob.astype(np.uint8), np.ones((2 * g + 1, 2 * g + 1), np.uint8)) > 0
    u = np.round(body[:, 0]).astype(int) + x0
    v = np.round(body[:, 1]).astype(int) + y0
    seen = (body[:, 2] >= 0.5) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return int(grown[v[seen], u[seen]].sum()) >= CONFIRM_MIN_LANDMARKS


def person_training_mask(person_mask: np.ndarray, image_uv_px: np.ndarray,
                         threshold: float = TRAINING_MASK_THRESHOLD) -> np.ndarray:
    """The pixels a human NeRF trains on as the person: ``(H, W)`` bool.

    person_mask: ``(H, W)`` the tracked person's probabilities; image_uv_px: ``(L, 2)`` its landmarks in
    ``LANDMARK_NAMES`` order (NaN where not found). Pixels at ``threshold`` or above, in the connected
    components (8-connected) that the landmarks' skeleton (``LANDMARK_BONES``, drawn one pixel wide) crosses:
    a blob of background the detector marked beside the person is dropped, the person's own loose clothes and
    hair (attached to the body) are kept. With no skeleton in the frame every pixel at the threshold is kept."""
    import cv2

    prob = np.asarray(person_mask, dtype=np.float32)
    if prob.ndim != 2:
        raise ValueError(f"person_training_mask: expected an (H, W) mask, got shape {prob.shape}")
    uv = np.asarray(image_uv_px, dtype=np.float64)
    if uv.shape != (len(LANDMARK_NAMES), 2):
        raise ValueError(f"person_training_mask: expected ({len(LANDMARK_NAMES)}, 2) landmarks, got {uv.shape}")
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"person_training_mask: threshold must be in (0, 1), got {threshold!r}")
    mask = prob >= threshold
    skeleton = np.zeros(prob.shape, np.uint8)
    index = {n: k for k, n in enumerate(LANDMARK_NAMES)}
    for a, b in LANDMARK_BONES:
        pa, pb = uv[index[a]], uv[index[b]]
        if np.isfinite(pa).all() and np.isfinite(pb).all():
            cv2.line(skeleton, tuple(int(v) for v in np.round(pa)), tuple(int(v) for v in np.round(pb)), 1, 1)
    on_skeleton = mask & skeleton.astype(bool)
    if not on_skeleton.any():
        return mask
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    keep = np.unique(labels[on_skeleton])
    return np.isin(labels, keep[keep > 0])


def unmirror(ob: FrameObservation, width: int) -> FrameObservation:
    """A detector's look at a frame mirrored left-right (``rgb[:, ::-1]``), as seen in the frame itself.

    width: the frame's width W in pixels. Pixel u -> W - 1 - u (nsim's pixel-centre convention), the
    landmarks' names left <-> right (``MIRRORED_LANDMARKS``), ``body_m``'s x (the camera's right) negated,
    the masks mirrored back."""
    order = np.asarray(MIRRORED_LANDMARKS)
    uv = np.asarray(ob.image_uv_px, dtype=np.float64)[order].copy()
    uv[:, 0] = width - 1 - uv[:, 0]
    body = np.asarray(ob.body_m, dtype=np.float64)[order].copy()
    body[:, 0] = -body[:, 0]
    people = None if ob.people_mask is None else np.ascontiguousarray(ob.people_mask[:, ::-1])
    return FrameObservation(uv, body, np.asarray(ob.visibility, dtype=np.float64)[order],
                            np.ascontiguousarray(ob.person_mask[:, ::-1]), people)


def _torso_length(points: np.ndarray) -> np.ndarray:
    """The length ``(...)`` from the hips' midpoint to the shoulders' of landmarks ``(..., L, D)`` (pixels or metres)."""
    i = {n: LANDMARK_NAMES.index(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")}
    shoulders = 0.5 * (points[..., i["left_shoulder"], :] + points[..., i["right_shoulder"], :])
    hips = 0.5 * (points[..., i["left_hip"], :] + points[..., i["right_hip"], :])
    return np.linalg.norm(shoulders - hips, axis=-1)


def average_looks(first: FrameObservation | None, second: FrameObservation | None,
                  max_disagreement: float = LOOKS_MAX_DISAGREEMENT) -> FrameObservation | None:
    """One look at a frame from two trackers' looks at it (a mirrored one already ``unmirror``-ed): their mean.

    Landmarks (pixels, ``body_m``), visibilities and the person's mask are averaged; ``people_mask`` is the
    first look's. Where only one look found the person it is taken as it is; where their landmarks lie
    more than ``max_disagreement`` torso lengths apart (median over the landmarks) the two follow different
    people and the first look is kept."""
    if first is None or second is None:
        return first if second is None else second
    apart = np.nanmedian(np.linalg.norm(first.image_uv_px - second.image_uv_px, axis=-1))
    if not (apart <= max_disagreement * float(_torso_length(first.image_uv_px))):
        return first
    mask = 0.5 * (np.asarray(first.person_mask, np.float32) + np.asarray(second.person_mask, np.float32))
    return FrameObservation(0.5 * (first.image_uv_px + second.image_uv_px), 0.5 * (first.body_m + second.body_m),
                            0.5 * (first.visibility + second.visibility), mask, first.people_mask)


def observe(frames: Iterable[np.ndarray], detector: PoseDetector, backward: PoseDetector | None = None) -> Observations:
    """Run ``detector`` on every frame (``(H, W, 3)`` uint8 RGB, one size) and stack the results.

    backward: a second detector (a fresh one, of the same kind) run over the frames last to first; where both
    find the person their looks are averaged (``average_looks``, the forward one's ``people_mask``)."""
    frames = list(frames)
    size = None
    for i, rgb in enumerate(frames):
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"observe: frame {i}: expected (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
        if size is None:
            size = rgb.shape[:2]
        elif rgb.shape[:2] != size:
            raise InputError(f"frame {i} is {rgb.shape[1]}x{rgb.shape[0]}, frame 0 is {size[1]}x{size[0]} "
                             "(one camera, one frame size)")
    if size is None:
        raise InputError("no frames to look for a person in")
    looks = [detector(np.asarray(rgb)) for rgb in frames]
    if backward is not None:
        back = [backward(np.asarray(rgb)) for rgb in frames[::-1]][::-1]
        looks = [average_looks(a, b) for a, b in zip(looks, back, strict=True)]
    found, uv, body, vis, masks, others = [], [], [], [], [], []
    L = len(LANDMARK_NAMES)
    for ob in looks:
        found.append(ob is not None)
        if ob is None:
            uv.append(np.full((L, 2), np.nan))
            body.append(np.full((L, 3), np.nan))
            vis.append(np.zeros(L))
            masks.append(np.zeros(size, np.float32))
            others.append(0)
            continue
        uv.append(ob.image_uv_px)
        body.append(ob.body_m)
        vis.append(ob.visibility)
        masks.append(np.asarray(ob.person_mask, dtype=np.float32))
        others.append(other_people(ob.person_mask, ob.people_mask))
    return Observations(np.array(found), np.stack(uv), np.stack(body), np.stack(vis), np.stack(masks),
                        np.array(others, dtype=np.int64), int(size[1]), int(size[0]))


LIMB_SIDES: dict[str, tuple[str, ...]] = {
    "legs": ("knee", "ankle", "heel", "foot_index"),
    "arms": ("elbow", "wrist", "pinky", "index", "thumb"),
}
"""The landmarks (without their ``left_`` / ``right_`` prefix) of each limb pair whose sides
``consistent_sides`` may exchange; hips and shoulders stay: they say which way the body faces."""

SIDE_SWITCH_COST = 0.5
"""``consistent_sides``: the cost of relabelling a limb pair in one frame, in the units of its motion residual
(torso lengths, summed over the pair's landmarks): a stretch is relabelled only when that makes the limbs'
motion smoother by more than this per frame."""


def _side_swap_order(parts: tuple[str, ...]) -> np.ndarray:
    """The landmark order ``(L,)`` that exchanges the left and right landmarks of ``parts``."""
    order = np.arange(len(LANDMARK_NAMES))
    sided = [LANDMARK_NAMES.index(f"{side}_{p}") for p in parts for side in ("left", "right")]
    order[sided] = np.asarray(MIRRORED_LANDMARKS)[sided]
    return order


def limb_side_switches(body_m: np.ndarray, parts: tuple[str, ...], switch_cost: float = SIDE_SWITCH_COST) -> np.ndarray:
    """Which frames' left and right ``parts`` (a ``LIMB_SIDES`` entry) to exchange so that the limbs move smoothly.

    body_m: ``(F, L, 3)`` a detector's hip-centred metric landmarks of consecutive frames (all found). A pose
    detector that sees a walking person from the side often exchanges the legs' sides for a few frames just
    after they cross (BlazePose on the test room's actor video at 480x360: 6 of 60 frames, in all four of its
    looks): the image is the same either way, the 3D pose is not. Over the frames, the limbs' landmarks (divided
    by the torso's length) should move at a steady pace: the labelling is chosen by a Viterbi pass over the
    pair (previous, this) frame's choice, minimising the sum over frames of each landmark's constant-velocity
    residual ``|x_t - 2 x_{t-1} + x_{t-2}|`` plus ``switch_cost`` for each exchanged frame (so the detector's
    own labelling wins unless a stretch of exchanged frames moves clearly more smoothly).
    Returns ``(F,)`` bool: True where the pair's sides are to be exchanged."""
    body = np.asarray(body_m, dtype=np.float64)
    F = body.shape[0]
    if F < 3:
        return np.zeros(F, dtype=bool)
    torso = _torso_length(body)
    torso = np.where(torso > 1e-6, torso, np.nanmedian(torso) if np.isfinite(torso).any() else 1.0)
    sel = [LANDMARK_NAMES.index(f"{s}_{p}") for p in parts for s in ("left", "right")]
    order = _side_swap_order(parts)
    x = np.stack([body[:, sel], body[:, order][:, sel]], axis=1) / torso[:, None, None, None]  # (F, 2, P, 3)
    x = np.nan_to_num(x)
    unary = np.array([0.0, switch_cost])
    # state (a, b): the labelling of the previous frame and of this one; cost[a, b]
    cost = unary[:, None] + unary[None, :]
    back = np.zeros((F, 2, 2), dtype=np.int64)
    for t in range(2, F):
        # residual[a, b, c] of frames t-2 (a), t-1 (b), t (c)
        res = np.linalg.norm(x[t][None, None] - 2.0 * x[t - 1][None, :, None] + x[t - 2][:, None, None],
                             axis=-1).sum(-1)
        total = cost[:, :, None] + res  # (a, b, c)
        back[t] = total.argmin(0)  # best a for each (b, c)
        cost = total.min(0) + unary[None, :]
    b, c = np.unravel_index(int(np.argmin(cost)), cost.shape)
    states = np.zeros(F, dtype=bool)
    states[F - 1], states[F - 2] = bool(c), bool(b)
    for t in range(F - 1, 1, -1):
        a = back[t, b, c]
        states[t - 2] = bool(a)
        b, c = a, b
    return states


def consecutive_runs(indices: np.ndarray) -> list[np.ndarray]:
    """The runs of consecutive integers in increasing ``indices (N,)``: ``[0, 1, 2, 5, 6] -> [[0, 1, 2], [5, 6]]``."""
    indices = np.asarray(indices)
    return np.split(indices, np.flatnonzero(np.diff(indices) != 1) + 1) if indices.size else []


def consistent_sides(obs: Observations, frames: np.ndarray | None = None,
                     switch_cost: float = SIDE_SWITCH_COST) -> tuple[Observations, dict[str, list[int]]]:
    """``obs`` with each limb pair's (``LIMB_SIDES``) left and right landmarks exchanged where
    ``limb_side_switches`` finds the detector's labelling jumping. frames: ``(F,)`` bool, the frames that form the
    sequence (None: those where the person was found; the others are left alone, and each unbroken run of the
    rest is a sequence of its own: the motion across a gap tells nothing). Returns the observations (landmarks, image positions and visibilities
    relabelled; masks as they were) and, per limb pair, the frames (indices into ``obs``) relabelled."""
    found = np.flatnonzero(obs.found if frames is None else np.asarray(frames, dtype=bool) & obs.found)
    uv, body, vis = obs.image_uv_px.copy(), obs.body_m.copy(), obs.visibility.copy()
    changed: dict[str, list[int]] = {}
    runs = consecutive_runs(found)
    for limb, parts in LIMB_SIDES.items():
        flip = np.concatenate([run[limb_side_switches(body[run], parts, switch_cost)] for run in runs] or
                              [np.zeros(0, dtype=np.int64)])
        order = _side_swap_order(parts)
        uv[flip], body[flip], vis[flip] = uv[flip][:, order], body[flip][:, order], vis[flip][:, order]
        changed[limb] = [int(f) for f in flip]
    return dataclasses.replace(obs, image_uv_px=uv, body_m=body, visibility=vis), changed


TRACK_OUTLIER_TORSOS = 0.65
"""``track_outliers``'s cut: a landmark farther than this many torso lengths from where its track's neighbours put
it is an outlier. On the test room's actor video at 480x360 (60 frames, 10 fps), BlazePose put the far arm's
wrist 68 and 103 px (0.8 and 1.3 torso lengths off its track) from the truth in two side-view frames. PA-MPJPE of
the fit, in a scratch harness over the detector's looks recorded once (so 0.1 cm off the bench's figures), 6.90 cm
without the cut; 6.66 / 6.69 / **6.56** / 6.65 / 6.81 cm at 0.4 / 0.5 / 0.65 / 0.8 / 1.0; 320x240, 30 frames:
6.25 without, 6.35 / 6.14 / **6.22** / 6.25 / 6.25. ``TRACK_OUTLIER_WINDOW`` 2 / 4 at 0.65: 6.82 / 6.61 and
6.22 / 6.22 cm."""

TRACK_OUTLIER_WINDOW = 3
"""``track_outliers`` predicts a frame from the pairs of frames at most this many before and after it."""


def track_outliers(uv_px: np.ndarray, frames: np.ndarray | None = None, max_torsos: float = TRACK_OUTLIER_TORSOS,
                   window: int = TRACK_OUTLIER_WINDOW) -> np.ndarray:
    """Landmarks that jump off their own track in the image: ``(F, L)`` bool.

    uv_px: (F, L, 2) image positions (NaN where not seen). frames: (F,) bool, the frames that form the sequence
    (None: all); each unbroken run of them is a track of its own. Each landmark's position relative to the
    midpoint of the hips is predicted at frame ``t`` by linear interpolation between every pair of frames of
    the track ``(a, b)`` with ``t - window <= a < t < b <= t + window``; its deviation
    is the *median* distance from those predictions, in torso lengths (mid-shoulder to mid-hip at ``t``): a
    landmark off its track in one or two frames in a row is far from most pairs' predictions, one on a fast
    but smooth path is not. Per landmark, the frame of largest deviation above ``max_torsos`` is an outlier,
    it leaves the track (the pairs skip it), and the others are judged again, until none is above. A frame
    with fewer than two frames of the track within ``window`` on either side (at a run's ends, say) is never an
    outlier: one frame beside it could be the one that jumped.
    """
    uv = np.asarray(uv_px, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[2] != 2:
        raise ValueError(f"track_outliers: expected uv_px (F, L, 2), got {uv.shape}")
    if window < 1 or not max_torsos > 0:
        raise ValueError(f"track_outliers: window must be >= 1 and max_torsos > 0, got {window!r}, {max_torsos!r}")
    F, L = uv.shape[:2]
    use = np.ones(F, dtype=bool) if frames is None else np.asarray(frames, dtype=bool)
    hips = 0.5 * (uv[:, LANDMARK_NAMES.index("left_hip")] + uv[:, LANDMARK_NAMES.index("right_hip")])
    rel = uv - hips[:, None]
    torso = _torso_length(uv)
    out = np.zeros((F, L), dtype=bool)
    kept = np.flatnonzero(use & np.isfinite(torso) & (torso > 0))
    for run in consecutive_runs(kept):
        for k in range(L):
            track = run[np.isfinite(rel[run, k]).all(axis=1)]  # the frames where the landmark is seen
            while track.size >= 3:
                dev = np.zeros(track.size)
                for i in range(1, track.size - 1):
                    t = track[i]
                    before, after = track[:i][track[:i] >= t - window], track[i + 1:][track[i + 1:] <= t + window]
                    if before.size < 2 or after.size < 2:  # too little around it to tell which frame jumped
                        continue
                    a, b = (m.reshape(-1) for m in np.meshgrid(before, after, indexing="ij"))
                    w = ((t - a) / (b - a))[:, None]
                    dev[i] = np.median(np.linalg.norm(rel[t, k] - (rel[a, k] + (rel[b, k] - rel[a, k]) * w), axis=-1))
                    dev[i] /= torso[t]
                worst = int(dev.argmax())
                if dev[worst] <= max_torsos:
                    break
                out[track[worst], k] = True
                track = np.delete(track, worst)
    return out


# ---------------------------------------------------------------------------------------------- MediaPipe


def _import_mediapipe():
    """The ``mediapipe`` module with its bundled legacy solutions; InputError (one line) otherwise."""
    try:
        import mediapipe as mp
    except ImportError:
        raise InputError(f"finding a person in a video needs MediaPipe: pip install '{PEOPLE_EXTRA}'") from None
    solutions = getattr(mp, "solutions", None)
    if solutions is None or not hasattr(solutions, "pose"):
        raise InputError(f"mediapipe {getattr(mp, '__version__', '?')} ships no pose models (the 0.10 wheels do): "
                         f"pip install '{PEOPLE_EXTRA}'")
    return mp


class MediaPipePoseDetector:
    """``PoseDetector`` on MediaPipe Pose (BlazePose, full model) and Selfie Segmentation, offline.

    Tracks one person from frame to frame (MediaPipe's video mode). min_detection_confidence,
    min_tracking_confidence: MediaPipe's thresholds (0.5 each, its defaults). mirror: a second tracker
    follows the person in the mirrored frames and its look is averaged with the direct one
    (``unmirror``, ``average_looks``).

    Everyone else in the frame comes from Selfie Segmentation, which also marks things that are not people
    (on the test room's actor video, a brown textured box in 9 of 60 frames at 480x360). A blob it marks away
    from the tracked person (``other_people``'s rule) stays in ``people_mask`` only when BlazePose, run on the
    blob's own crop (``confirmed_person``), finds a body there; the others are cleared.
    """

    def __init__(self, min_detection_confidence: float = 0.5, min_tracking_confidence: float = 0.5,
                 find_others: bool = True, mirror: bool = True) -> None:
        mp = _import_mediapipe()

        def tracker():
            return mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1, smooth_landmarks=True,
                                          enable_segmentation=True, smooth_segmentation=True,
                                          min_detection_confidence=min_detection_confidence,
                                          min_tracking_confidence=min_tracking_confidence)

        self._pose = tracker()
        self._mirrored = tracker() if mirror else None
        self._people = mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=0) if find_others else None
        self._check = (mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1, enable_segmentation=False,
                                              min_detection_confidence=min_detection_confidence)
                       if find_others else None)

    def __call__(self, rgb: np.ndarray) -> FrameObservation | None:
        rgb = np.ascontiguousarray(rgb)
        h, w = rgb.shape[:2]
        ob = self._look(self._pose, rgb, w, h)
        if self._mirrored is not None:
            flipped = self._look(self._mirrored, np.ascontiguousarray(rgb[:, ::-1]), w, h)
            ob = average_looks(ob, None if flipped is None else unmirror(flipped, w))
        if ob is None:
            return None
        mask = ob.person_mask
        people = None
        if self._people is not None:
            seg = self._people.process(rgb).segmentation_mask
            people = None if seg is None else np.asarray(seg, dtype=np.float32)
            if people is not None:
                for blob in other_people_blobs(mask, people):
                    if not confirmed_person(rgb, blob, self._find_body):
                        people = np.where(blob, 0.0, people).astype(np.float32)
        return FrameObservation(ob.image_uv_px, ob.body_m, ob.visibility, mask, people)

    @staticmethod
    def _look(pose, rgb: np.ndarray, w: int, h: int) -> FrameObservation | None:
        """One tracker's landmarks and mask on an ``(h, w)`` frame."""
        res = pose.process(rgb)
        if res.pose_landmarks is None or res.pose_world_landmarks is None:
            return None
        img = np.array([(p.x, p.y, p.visibility) for p in res.pose_landmarks.landmark], dtype=np.float64)
        world = np.array([(p.x, p.y, p.z) for p in res.pose_world_landmarks.landmark], dtype=np.float64)
        uv = img[:, :2] * np.array([w, h]) - 0.5  # normalised [0, 1] edges -> nsim pixel centres
        mask = res.segmentation_mask
        mask = np.zeros((h, w), np.float32) if mask is None else np.asarray(mask, dtype=np.float32)
        return FrameObservation(uv, world, np.clip(img[:, 2], 0.0, 1.0), mask)

    def _find_body(self, rgb: np.ndarray) -> np.ndarray | None:
        """BlazePose on one image, on its own (no tracking): ``(L, 3)`` pixel u, v and visibility, or None."""
        res = self._check.process(np.ascontiguousarray(rgb))
        if res.pose_landmarks is None:
            return None
        h, w = rgb.shape[:2]
        img = np.array([(p.x, p.y, p.visibility) for p in res.pose_landmarks.landmark], dtype=np.float64)
        img[:, :2] = img[:, :2] * np.array([w, h]) - 0.5
        return img

    def close(self) -> None:
        self._pose.close()
        if self._mirrored is not None:
            self._mirrored.close()
        if self._people is not None:
            self._people.close()
            self._check.close()

    def __enter__(self) -> MediaPipePoseDetector:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["LANDMARK_BONES", "LANDMARK_NAMES", "LIMB_SIDES", "MIRRORED_LANDMARKS", "PEOPLE_EXTRA", "SIDE_SWITCH_COST",
           "TRACK_OUTLIER_TORSOS", "TRACK_OUTLIER_WINDOW", "TRAINING_MASK_THRESHOLD", "FrameObservation",
           "MediaPipePoseDetector", "Observations", "PoseDetector", "average_looks", "confirmed_person",
           "consecutive_runs", "consistent_sides", "limb_side_switches", "observe", "other_people", "other_people_blobs",
           "person_training_mask", "track_outliers", "unmirror"]
