"""Skeleton fitting: a person's 33 body landmarks per frame onto the nsim body (24 joints).

The landmarks are BlazePose's (``nsim.human.landmarks.LANDMARK_NAMES``: nose, eyes, ears, mouth,
shoulders, elbows, wrists, three hand points, hips, knees, ankles, heels, toe tips), as
MediaPipe Pose predicts them, in metres. The fit is marker-based inverse kinematics:

* **Body model** (``BodyModel``): each landmark is a point fixed in one joint's frame of the
  nsim body (``LANDMARK_ATTACHMENTS``: shoulders, elbows, wrists, hips, knees and ankles *at*
  their joints; nose, eyes, ears and mouth on the head; the hand points on the wrist's frame;
  heels on the ankle's, toe tips on the ball of the foot's). Posing the skeleton
  (``forward_kinematics``) places every landmark (``BodyModel.landmarks``).
* **Bone lengths, once per person** (``estimate_body``): the nsim body's rest offsets are
  scaled group by group (thighs, shins, feet, upper arms, forearms, hands, hip width, shoulder
  width, torso, head and neck) so that the rest distance between each group's landmark pairs
  equals the *median* over frames of the measured distance (left and right averaged). The
  skeleton is then fixed for every frame: bone lengths cannot change.
* **Joint angles per frame** (``fit_poses``): one nonlinear least-squares problem over all
  frames (``IKProblem``, its Jacobian in closed form; ``levenberg_marquardt``): per frame the
  root's position and orientation and every joint's local rotation (rotation vectors).
  Residuals are the landmark errors (weighted by the detector's visibility), optionally their
  reprojection errors in a static camera (``ImageLandmarks``; the 3D landmarks then weigh
  ``FitConfig.weight_3d``), a *temporal smoothness* term (the second difference of every
  joint's position between consecutive frames, i.e. its acceleration times ``dt^2``) and a
  small pull of each local rotation towards the rest pose (which only decides what the
  landmarks cannot see, such as how a bend is shared between the three spine joints).
  **Joint limits** are hard bounds on each local rotation vector's components
  (``JOINT_LIMITS_RAD``: knees and elbows bend one way only, the spine and neck a little,
  shoulders and hips widely). Every frame is first fitted on its own (the problem separates:
  exact per-frame solves, linear in the frames), then all together with the smoothness term.
  The root trajectory is in the landmarks' frame.

Everything here is arrays in, arrays out. ``mpjpe_m`` measures a fit against ground truth
(mean per-joint position error, optionally after per-frame Procrustes alignment).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial.transform import Rotation

from nsim.geometry.transforms import umeyama
from nsim.human import skeleton as skel
from nsim.human.landmarks import LANDMARK_NAMES

log = logging.getLogger(__name__)

NUM_LANDMARKS = len(LANDMARK_NAMES)

# Where each landmark sits on the nsim body: (joint, offset in that joint's frame at 1.75 m; x forward,
# y left, z up in the rest pose). Face points match nsim's test actor (``nsim.synth.actor``: head
# ellipsoid centred 0.07 m above the head joint, nose tip 0.138 m in front of it).
LANDMARK_ATTACHMENTS: dict[str, tuple[str, tuple[float, float, float]]] = {
    "nose": ("head", (0.13, 0.0, 0.055)),
    "left_eye_inner": ("head", (0.105, 0.015, 0.085)),
    "left_eye": ("head", (0.105, 0.03, 0.085)),
    "left_eye_outer": ("head", (0.095, 0.045, 0.085)),
    "right_eye_inner": ("head", (0.105, -0.015, 0.085)),
    "right_eye": ("head", (0.105, -0.03, 0.085)),
    "right_eye_outer": ("head", (0.095, -0.045, 0.085)),
    "left_ear": ("head", (0.0, 0.08, 0.065)),
    "right_ear": ("head", (0.0, -0.08, 0.065)),
    "mouth_left": ("head", (0.1, 0.025, 0.022)),
    "mouth_right": ("head", (0.1, -0.025, 0.022)),
    "left_shoulder": ("left_shoulder", (0.0, 0.0, 0.0)),
    "right_shoulder": ("right_shoulder", (0.0, 0.0, 0.0)),
    "left_elbow": ("left_elbow", (0.0, 0.0, 0.0)),
    "right_elbow": ("right_elbow", (0.0, 0.0, 0.0)),
    "left_wrist": ("left_wrist", (0.0, 0.0, 0.0)),
    "right_wrist": ("right_wrist", (0.0, 0.0, 0.0)),
    # hand points on the wrist's frame (the T-pose hand is palm down: thumb forward, little finger back)
    "left_pinky": ("left_wrist", (-0.03, 0.075, 0.0)),
    "right_pinky": ("right_wrist", (-0.03, -0.075, 0.0)),
    "left_index": ("left_wrist", (0.03, 0.08, 0.0)),
    "right_index": ("right_wrist", (0.03, -0.08, 0.0)),
    "left_thumb": ("left_wrist", (0.045, 0.04, -0.01)),
    "right_thumb": ("right_wrist", (0.045, -0.04, -0.01)),
    "left_hip": ("left_hip", (0.0, 0.0, 0.0)),
    "right_hip": ("right_hip", (0.0, 0.0, 0.0)),
    "left_knee": ("left_knee", (0.0, 0.0, 0.0)),
    "right_knee": ("right_knee", (0.0, 0.0, 0.0)),
    "left_ankle": ("left_ankle", (0.0, 0.0, 0.0)),
    "right_ankle": ("right_ankle", (0.0, 0.0, 0.0)),
    # heel on the sole behind the ankle (as nsim.human.gait's planted foot), toe tip at the foot's end site
    "left_heel": ("left_ankle", (-0.06, 0.0, -0.05)),
    "right_heel": ("right_ankle", (-0.06, 0.0, -0.05)),
    "left_foot_index": ("left_foot", (0.05, 0.0, 0.0)),
    "right_foot_index": ("right_foot", (0.05, 0.0, 0.0)),
}
"""Landmark -> (nsim joint, offset in the joint's frame, metres at ``REFERENCE_HEIGHT_M``)."""

_DEG = np.pi / 180.0
_SIDES = (("left", 1.0), ("right", -1.0))


def _limits() -> np.ndarray:
    """``(J, 3, 2)`` lower/upper bounds of each joint's local rotation vector components (rad)."""
    lim = np.zeros((len(skel.JOINT_NAMES), 3, 2))
    lim[:, :, 0], lim[:, :, 1] = -np.inf, np.inf  # the root: free

    def put(name: str, x: tuple[float, float], y: tuple[float, float], z: tuple[float, float]) -> None:
        lim[skel.JOINT_NAMES.index(name)] = np.array([x, y, z]) * _DEG

    for name in ("spine1", "spine2", "spine3"):
        put(name, (-30, 30), (-35, 35), (-30, 30))
    put("neck", (-40, 40), (-45, 45), (-60, 60))
    put("head", (-40, 40), (-45, 45), (-60, 60))
    for side, s in _SIDES:
        def sided(lo: float, hi: float, sign: float = s) -> tuple[float, float]:
            """A range given for the left side, mirrored for the right (about the sagittal plane)."""
            return (lo, hi) if sign > 0 else (-hi, -lo)

        # hip: x abduction (+ left), y extension (+) / flexion (-), z rotation
        put(f"{side}_hip", sided(-40, 70), (-135, 40), (-60, 60))
        # knee: a hinge about y, flexion positive; a little play about x and z
        put(f"{side}_knee", (-15, 15), (-5, 160), (-25, 25))
        put(f"{side}_ankle", (-40, 40), (-50, 50), (-45, 45))
        put(f"{side}_foot", (-20, 20), (-70, 45), (-20, 20))  # toes bend up to 62 deg in nsim's fast walk
        put(f"{side}_collar", (-30, 30), (-30, 30), (-30, 30))
        put(f"{side}_shoulder", (-165, 165), (-165, 165), (-165, 165))
        # elbow: a hinge about z (left: flexion negative, right: positive), forearm twist about the bone (y)
        put(f"{side}_elbow", (-25, 25), (-100, 100), sided(-160, 5))
        put(f"{side}_wrist", (-90, 90), (-90, 90), (-90, 90))
        put(f"{side}_hand", (-90, 90), (-90, 90), (-90, 90))
    lim.setflags(write=False)
    return lim


JOINT_LIMITS_RAD = _limits()
"""``(J, 3, 2)``: bounds (lower, upper) on the components of each local rotation vector (root: none)."""


@dataclass(frozen=True, eq=False)
class BodyModel:
    """A person's skeleton and where each landmark sits on it.

    skeleton: the nsim body with this person's bone lengths.
    attach_joint: (L,) int64 joint index of each landmark (``LANDMARK_NAMES`` order).
    attach_offset_m: (L, 3) offset of each landmark in its joint's frame.
    """

    skeleton: skel.Skeleton
    attach_joint: np.ndarray
    attach_offset_m: np.ndarray

    def landmarks(self, joint_transforms: np.ndarray) -> np.ndarray:
        """Landmark positions ``(..., L, 3)`` of posed bodies ``joint_transforms (..., J, 4, 4)``."""
        T = np.asarray(joint_transforms, dtype=np.float64)[..., self.attach_joint, :, :]
        return T[..., :3, 3] + np.einsum("...ij,...j->...i", T[..., :3, :3], self.attach_offset_m)

    def rest_landmarks(self) -> np.ndarray:
        """Landmarks ``(L, 3)`` of the rest pose (T-pose)."""
        return self.landmarks(self.skeleton.rest_transforms())

    @property
    def height_m(self) -> float:
        """Body height, floor to top of head (the rest extent plus the soles, as ``nsim_skeleton``)."""
        return self.skeleton.height_m() * skel.REFERENCE_HEIGHT_M / skel.nsim_skeleton(skel.REFERENCE_HEIGHT_M).height_m()


def _idx(name: str) -> int:
    return LANDMARK_NAMES.index(name)


def _reference_attachments() -> tuple[np.ndarray, np.ndarray]:
    joints = np.array([skel.JOINT_NAMES.index(LANDMARK_ATTACHMENTS[n][0]) for n in LANDMARK_NAMES], dtype=np.int64)
    offsets = np.array([LANDMARK_ATTACHMENTS[n][1] for n in LANDMARK_NAMES], dtype=np.float64)
    return joints, offsets


def reference_body(height_m: float = skel.REFERENCE_HEIGHT_M) -> BodyModel:
    """The nsim body of ``height_m`` (``nsim_skeleton``) with the landmarks scaled alike."""
    joints, offsets = _reference_attachments()
    return BodyModel(skel.nsim_skeleton(height_m), joints, offsets * (float(height_m) / skel.REFERENCE_HEIGHT_M))


# ---------------------------------------------------------------------------------------------- bone lengths

# A measurement: distance between two landmark points (a point is a landmark name or the midpoint of two).
_Point = str | tuple[str, str]
_MID_HIP: _Point = ("left_hip", "right_hip")
_MID_SHOULDER: _Point = ("left_shoulder", "right_shoulder")


def _groups() -> list[tuple[str, list[tuple[_Point, _Point]], list[tuple[str, str, tuple[int, ...]]]]]:
    """``(group, measured landmark pairs, scaled items)``; an item is ``(kind, name, components)``
    with kind ``off`` (a joint's rest offset), ``end`` (its end site) or ``att`` (a landmark's
    attachment offset). Fitted in this order (later groups' rest distances use earlier factors)."""
    xyz, xz, y = (0, 1, 2), (0, 2), (1,)
    both = [s for s, _ in _SIDES]
    g = [
        ("hip_width", [("left_hip", "right_hip")], [("off", f"{s}_hip", y) for s in both]),
        ("shoulder_width", [("left_shoulder", "right_shoulder")],
         [("off", f"{s}_{j}", y) for s in both for j in ("collar", "shoulder")]),
        ("torso", [(_MID_HIP, _MID_SHOULDER)],
         [("off", n, xz) for n in ("spine1", "spine2", "spine3")]
         + [("off", f"{s}_{j}", xz) for s in both for j in ("hip", "collar", "shoulder")]),
        ("thigh", [(f"{s}_hip", f"{s}_knee") for s in both], [("off", f"{s}_knee", xyz) for s in both]),
        ("shin", [(f"{s}_knee", f"{s}_ankle") for s in both], [("off", f"{s}_ankle", xyz) for s in both]),
        ("foot", [(f"{s}_heel", f"{s}_foot_index") for s in both],
         [("off", f"{s}_foot", xyz) for s in both] + [("end", f"{s}_foot", xyz) for s in both]
         + [("att", f"{s}_{p}", xyz) for s in both for p in ("heel", "foot_index")]),
        ("upper_arm", [(f"{s}_shoulder", f"{s}_elbow") for s in both], [("off", f"{s}_elbow", xyz) for s in both]),
        ("forearm", [(f"{s}_elbow", f"{s}_wrist") for s in both], [("off", f"{s}_wrist", xyz) for s in both]),
        ("hand", [(f"{s}_wrist", f"{s}_{p}") for s in both for p in ("index", "pinky")],
         [("off", f"{s}_hand", xyz) for s in both] + [("end", f"{s}_hand", xyz) for s in both]
         + [("att", f"{s}_{p}", xyz) for s in both for p in ("index", "pinky", "thumb")]),
        ("head", [(_MID_SHOULDER, "nose"), ("left_ear", "right_ear")],
         [("off", "neck", xyz), ("off", "head", xyz), ("end", "head", xyz)]
         + [("att", n, xyz) for n in LANDMARK_NAMES if LANDMARK_ATTACHMENTS[n][0] == "head"]),
    ]
    return g


BONE_GROUPS = tuple(name for name, _, _ in _groups())
"""The groups of rest offsets ``estimate_body`` scales, in the order it fits them."""


def _point(landmarks: np.ndarray, p: _Point) -> np.ndarray:
    if isinstance(p, tuple):
        return 0.5 * (landmarks[..., _idx(p[0]), :] + landmarks[..., _idx(p[1]), :])
    return landmarks[..., _idx(p), :]


def _point_weight(weights: np.ndarray, p: _Point) -> np.ndarray:
    if isinstance(p, tuple):
        return np.minimum(weights[..., _idx(p[0])], weights[..., _idx(p[1])])
    return weights[..., _idx(p)]


def scaled_body(factors: dict[str, float]) -> BodyModel:
    """The reference body (1.75 m) with each group's items multiplied by its factor (1 where absent)."""
    sk = skel.nsim_skeleton(skel.REFERENCE_HEIGHT_M)
    off, end = sk.offsets_m.copy(), sk.end_sites_m.copy()
    joints, att = _reference_attachments()
    for name, _, items in _groups():
        k = factors.get(name, 1.0)
        for kind, item, comps in items:
            c = list(comps)
            if kind == "off":
                off[sk.index(item), c] *= k
            elif kind == "end":
                end[sk.index(item), c] *= k
            else:
                att[_idx(item), c] *= k
    return BodyModel(skel.Skeleton(sk.joint_names, sk.parents, off, end), joints, att)


def estimate_body(landmarks_m: np.ndarray, weights: np.ndarray | None = None, min_weight: float = 0.5,
                  iterations: int = 4) -> BodyModel:
    """A person's body from landmarks over frames: bone lengths fixed once (see the module docstring).

    landmarks_m: (F, L, 3) metres, any frame. weights: (F, L) in [0, 1] (the detector's
    visibility; None: all 1); a pair counts in a frame where both points weigh ``>= min_weight``.
    Each group's factor is found by a fixed-point iteration (rest distances depend a little on
    the other factors). Groups never measured keep the mean factor of the others.
    Raises ValueError if no group could be measured.
    """
    lm = np.asarray(landmarks_m, dtype=np.float64)
    if lm.ndim != 3 or lm.shape[1:] != (NUM_LANDMARKS, 3):
        raise ValueError(f"estimate_body: expected landmarks (F, {NUM_LANDMARKS}, 3), got {lm.shape}")
    w = np.ones(lm.shape[:2]) if weights is None else np.asarray(weights, dtype=np.float64)
    measured: dict[str, float] = {}
    for name, pairs, _ in _groups():
        values = []
        for a, b in pairs:
            ok = (_point_weight(w, a) >= min_weight) & (_point_weight(w, b) >= min_weight)
            ok &= np.all(np.isfinite(_point(lm, a)), axis=-1) & np.all(np.isfinite(_point(lm, b)), axis=-1)
            if ok.any():
                values.append(float(np.median(np.linalg.norm(_point(lm[ok], a) - _point(lm[ok], b), axis=-1))))
        if values:
            measured[name] = float(np.mean(values))
    if not measured:
        raise ValueError("estimate_body: no bone could be measured (every landmark pair is missing)")
    factors: dict[str, float] = {}
    for _ in range(iterations):
        for name, pairs, _ in _groups():
            if name not in measured:
                continue
            rest = scaled_body(factors).rest_landmarks()
            d_rest = float(np.mean([np.linalg.norm(_point(rest, a) - _point(rest, b)) for a, b in pairs]))
            factors[name] = factors.get(name, 1.0) * measured[name] / d_rest
    mean = float(np.mean(list(factors.values())))
    for name in BONE_GROUPS:
        factors.setdefault(name, mean)
    log.debug("estimate_body: factors %s", {k: round(v, 3) for k, v in factors.items()})
    return scaled_body(factors)


# ---------------------------------------------------------------------------------------------- IK


SMOOTH_FPS = 30.0
"""The frame rate ``FitConfig.smooth_weight`` is given for."""


@dataclass(frozen=True)
class FitConfig:
    """Weights of the fit's residuals (landmark errors are in metres, weight 1).

    smooth_weight: per metre of a joint's second difference between consecutive frames at
        ``SMOOTH_FPS`` (at another frame rate the same acceleration weighs the same:
        the weight is multiplied by ``(fps / SMOOTH_FPS)^2``).
    rest_weight: per radian of each (non-root) local rotation vector.
    weight_3d: the 3D landmarks' weight when their image positions are fitted too (``ImageLandmarks``).
    max_iterations: most Levenberg-Marquardt iterations fitting each frame on its own (``levenberg_marquardt``).
    joint_iterations: most iterations then fitting all frames together with the smoothness term.
    tolerance: the solver stops when an iteration lowers the cost by less than this fraction.
    min_visibility: landmarks below this weigh nothing (not seen); the others weigh their visibility. MediaPipe
        still places a landmark it calls hidden (an arm behind the body seen from the side, visibility 0.1-0.3),
        and close to right: on the test room's actor video at 480x360 (``bench/real_people.py --fit-only``) the
        far arm's wrist was 11-25 px from the truth in the side-view frames, and dropping it at 0.3 let the fit
        put it 84-104 px off; MPJPE 11.55 cm at 0.3, 9.13 at 0.1 (7.88 and 7.43 at 320x240, 30 frames;
        ``--min-visibility V [--quick]``).

    smooth_weight_image: ``smooth_weight`` when the landmarks' image positions are fitted too: their residuals
        are pixels over ``ImageLandmarks.sigma_px``, some 30 times a 3D landmark's per metre at a few metres from
        the camera, so the smoothness must weigh more to weigh the same.

    smooth_weight_image (then smooth_weight, 0.5) and weight_3d were 0.5 and 0.05 until the legs' sides were
    made consistent (``nsim.human.landmarks.consistent_sides``). On the test room's actor video (``bench/real_people.py
    --fit-only [--quick] [--fit smooth_weight_image=0.5 --fit weight_3d=0.05]``; 60 frames at 480x360 / 30 at
    320x240, both 10 fps), PA-MPJPE 7.24 / 6.45 cm with the old weights, 6.99 / 6.32 with these. A sweep over the
    detector's looks recorded once and fitted again (a scratch harness, so its figures differ from the bench's by
    0.1 cm), PA-MPJPE at weight_3d 0.01 and smooth_weight_image 10 / 20 / 35 / 50 / 80 / 150: 7.16 / 6.33,
    6.93 / 6.35, **6.81 / 6.25**, 6.75 / 6.37, 7.30 / 8.19, 8.39 / 10.25 (weight_3d 0.02 at 35: 6.90 / 6.24).
    At 0.5 the term weighed almost nothing beside the image's (0.02 to 2 changed the error by 0.0001 cm); too
    strong, it drags the swinging foot behind.
    """

    smooth_weight: float = 0.5
    smooth_weight_image: float = 35.0
    rest_weight: float = 0.01
    weight_3d: float = 0.01
    max_iterations: int = 50
    joint_iterations: int = 8
    tolerance: float = 1e-6
    min_visibility: float = 0.1

    def __post_init__(self) -> None:
        for name in ("smooth_weight", "smooth_weight_image", "rest_weight", "weight_3d", "min_visibility", "tolerance"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0.0):
                raise ValueError(f"FitConfig.{name}: must be >= 0, got {v!r}")
        if self.max_iterations < 1 or self.joint_iterations < 0:
            raise ValueError(f"FitConfig: max_iterations must be >= 1 and joint_iterations >= 0, got "
                             f"{self.max_iterations!r}, {self.joint_iterations!r}")


@dataclass(frozen=True, eq=False)
class PoseFit:
    """Fitted poses of F frames.

    body: the person's body (fixed bone lengths).
    root_positions_m: (F, 3) the root joint (pelvis) per frame, in the landmarks' frame.
    local_rotations_wxyz: (F, J, 4) local rotations, row 0 the root's orientation in that frame.
    joint_transforms: (F, J, 4, 4) joint-to-frame transforms.
    landmark_error_m: (F, L) distance of each fitted landmark from its observation (NaN where unseen).
    iterations: the solver's iterations (Jacobian evaluations).
    """

    body: BodyModel
    root_positions_m: np.ndarray
    local_rotations_wxyz: np.ndarray
    joint_transforms: np.ndarray
    landmark_error_m: np.ndarray
    iterations: int

    @property
    def joint_positions_m(self) -> np.ndarray:
        """(F, J, 3)."""
        return self.joint_transforms[..., :3, 3]


def _rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(v.shape[:-1] + (3, 3))


def _ancestors(parents: np.ndarray, j: int) -> list[int]:
    """``j`` and its ancestors up to the root."""
    out = []
    while j >= 0:
        out.append(j)
        j = int(parents[j])
    return out


def _initial_rotations(body: BodyModel, landmarks: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per-frame starting guess: root orientation from hips and shoulders (Kabsch), then each limb bone
    turned by the smallest rotation onto its observed direction (spine, neck and hands at rest).
    landmarks (F, L, 3), weights (F, L). Returns local rotation matrices ``(F, J, 3, 3)``."""
    from nsim.human.retarget import rotation_between

    sk = body.skeleton
    F, J = landmarks.shape[0], sk.num_joints
    rest = body.rest_landmarks()
    torso = [_idx(n) for n in ("left_hip", "right_hip", "left_shoulder", "right_shoulder")]
    G = np.broadcast_to(np.eye(3), (F, J, 3, 3)).copy()
    rest_joints = sk.rest_positions_m()
    # limb bones: joint -> landmark its child bone points to
    bones = [(f"{s}_{a}", f"{s}_{b}") for s, _ in _SIDES for a, b in
             (("hip", "knee"), ("knee", "ankle"), ("shoulder", "elbow"), ("elbow", "wrist"))]
    below = {j: [k for k in range(J) if j in _ancestors(sk.parents, k)] for j in range(J)}
    for f in range(F):
        src, dst = rest[torso], landmarks[f, torso]
        if np.all(np.isfinite(dst)):
            try:
                _, R, _ = umeyama(src, dst, with_scale=False)
            except ValueError:
                R = np.eye(3)
        else:
            R = np.eye(3)
        G[f, :] = R  # every joint starts with the root's orientation (rest pose, turned)
        for joint, child in bones:
            j = sk.index(joint)
            a = rest_joints[sk.index(child)] - rest_joints[j]
            b = landmarks[f, _idx(child)] - landmarks[f, _idx(joint)]
            if weights[f, _idx(child)] <= 0 or weights[f, _idx(joint)] <= 0 or not np.all(np.isfinite(b)):
                continue
            p = int(sk.parents[j])
            turn = rotation_between(G[f, p] @ a, b)
            new = turn @ G[f, p]
            G[f, below[j]] = new  # the joint and everything below it turn alike
    return skel.local_rotations_from_global(sk, G)


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(a) @ b = a x b``."""
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    return K


def right_jacobian_so3(v: np.ndarray) -> np.ndarray:
    """Right Jacobian ``(..., 3, 3)`` of SO(3) at rotation vectors ``v (..., 3)``:
    ``exp(v + d) = exp(v) exp(J_r(v) d)`` to first order in ``d``
    (``J_r = I - (1 - cos t) / t^2 K + (t - sin t) / t^3 K^2``, ``K = skew(v)``, ``t = |v|``)."""
    t2 = np.sum(v * v, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0, (ts - np.sin(ts)) / ts**3)
    K = _skew(v)
    return np.eye(3) - a[..., None, None] * K + b[..., None, None] * (K @ K)


@dataclass(frozen=True, eq=False)
class ImageLandmarks:
    """Where a pinhole camera saw the landmarks: a reprojection term for ``fit_poses``.

    uv_px: (F, L, 2) pixels (NaN where unseen). world_to_cam: (4, 4) for a static camera or
    (F, 4, 4), one per frame, for a moving one; OpenCV camera axes.
    fx, fy, cx, cy: the pinhole intrinsics. sigma_px: reprojection errors are divided by it, so a
    landmark ``sigma_px`` off in the image costs as much as one 1 m off in 3D at weight 1.
    """

    uv_px: np.ndarray
    world_to_cam: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    sigma_px: float = 4.0

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``(..., 2)`` of world points ``(..., 3)`` and ``d uv / d point`` ``(..., 2, 3)``."""
        w2c = np.asarray(self.world_to_cam)
        if w2c.ndim == 3:  # one camera per frame: points (F, ..., 3)
            extra = (1,) * (points.ndim - 2)
            R = w2c[:, :3, :3].reshape(w2c.shape[0], *extra, 3, 3)
            t = w2c[:, :3, 3].reshape(w2c.shape[0], *extra, 3)
            pc = (R @ points[..., None])[..., 0] + t
        else:
            R, t = w2c[:3, :3], w2c[:3, 3]
            pc = points @ R.T + t
        z = np.maximum(pc[..., 2], 0.05)
        uv = np.stack([self.fx * pc[..., 0] / z + self.cx, self.fy * pc[..., 1] / z + self.cy], axis=-1)
        D = np.zeros(points.shape[:-1] + (2, 3))
        D[..., 0, 0] = self.fx / z
        D[..., 0, 2] = -self.fx * pc[..., 0] / z**2
        D[..., 1, 1] = self.fy / z
        D[..., 1, 2] = -self.fy * pc[..., 1] / z**2
        return uv, D @ R


class IKProblem:
    """The least-squares problem ``fit_poses`` solves, with its Jacobian in closed form.

    Parameters ``x (F * P,)``, per frame (``P = 3 + 3 J``): the root position, then each joint's
    local rotation vector (row 0 the root's orientation). Residuals, in this order: landmark
    errors ``(F, L, 3)`` times the square root of their weights; joint second differences
    ``(T, J, 3)`` of the frame triplets ``(T, 3)``, times ``smooth``; the non-root rotation vectors
    ``(F, J - 1, 3)`` times ``rest_weight``; with ``image`` (``ImageLandmarks``), the landmarks'
    reprojection errors ``(F, L, 2)`` in pixels times ``sqrt_weights / image.sigma_px``.

    Jacobian: turning joint ``j`` by a small rotation ``w`` (in its own frame) moves a point ``p``
    below it by ``(G_j w) x (p - o_j)`` (``G_j``, ``o_j``: the joint's world orientation and
    position); a change ``d`` of its rotation vector ``v`` is ``w = J_r(v) d``
    (``right_jacobian_so3``). ``tests/human/test_fit.py`` checks it against finite differences.
    """

    def __init__(self, body: BodyModel, landmarks_m: np.ndarray, sqrt_weights: np.ndarray, triplets: np.ndarray,
                 smooth: float, rest_weight: float, image: ImageLandmarks | None = None,
                 sqrt_weights_3d: np.ndarray | None = None) -> None:
        sk = body.skeleton
        F, L = landmarks_m.shape[:2]
        J = sk.num_joints
        self.body, self.lm = body, landmarks_m
        self.sqrt_w = sqrt_weights if sqrt_weights_3d is None else sqrt_weights_3d
        self.image = image
        if image is not None:
            seen2d = np.isfinite(image.uv_px).all(-1)
            self.sqrt_w2 = np.where(seen2d, sqrt_weights, 0.0) / image.sigma_px
            self.uv = np.where(seen2d[..., None], image.uv_px, 0.0)
        self.triplets = np.asarray(triplets, dtype=np.int64).reshape(-1, 3)
        self.smooth, self.rest_weight = float(smooth), float(rest_weight)
        self.F, self.L, self.J, self.P = F, L, J, 3 + 3 * J
        P, T = self.P, self.triplets.shape[0]
        # (landmark, joint that turns it) and (joint, strict ancestor that moves it) pairs
        lp = [(k, j) for k in range(L) for j in _ancestors(sk.parents, int(body.attach_joint[k]))]
        ap = [(i, j) for i in range(J) for j in _ancestors(sk.parents, i)[1:]]
        self.lp_k, self.lp_j = (np.array(c, dtype=np.int64) for c in zip(*lp, strict=True))
        self.ap_i, self.ap_j = (np.array(c, dtype=np.int64) for c in zip(*ap, strict=True))
        f = np.arange(F)
        a3 = np.arange(3)
        base_acc = F * L * 3
        base_rest = base_acc + T * J * 3
        self.n_rows = base_rest + F * (J - 1) * 3
        rows, cols = [], []
        # landmark rows, root position: (F, L, 3) diagonal
        rows.append(((f[:, None, None] * L + np.arange(L)[None, :, None]) * 3 + a3).reshape(-1))
        cols.append(np.broadcast_to(f[:, None, None] * P + a3, (F, L, 3)).reshape(-1))
        # landmark rows, rotations: (F, n_lp, 3 rows, 3 cols)
        r = (f[:, None, None, None] * L + self.lp_k[None, :, None, None]) * 3 + a3[None, None, :, None]
        c = f[:, None, None, None] * P + 3 + 3 * self.lp_j[None, :, None, None] + a3[None, None, None, :]
        rows.append(np.broadcast_to(r, (F, len(lp), 3, 3)).reshape(-1))
        cols.append(np.broadcast_to(c, (F, len(lp), 3, 3)).reshape(-1))
        if T:
            t = np.arange(T)
            # acceleration rows, root positions: (T, 3 frames, J, 3) diagonal
            r = base_acc + (t[:, None, None, None] * J + np.arange(J)[None, None, :, None]) * 3 + a3
            c = self.triplets[:, :, None, None] * P + a3
            rows.append(np.broadcast_to(r, (T, 3, J, 3)).reshape(-1))
            cols.append(np.broadcast_to(c, (T, 3, J, 3)).reshape(-1))
            # acceleration rows, rotations: (T, 3 frames, n_ap, 3, 3)
            r = base_acc + (t[:, None, None, None, None] * J + self.ap_i[None, None, :, None, None]) * 3 \
                + a3[None, None, None, :, None]
            c = self.triplets[:, :, None, None, None] * P + 3 + 3 * self.ap_j[None, None, :, None, None] \
                + a3[None, None, None, None, :]
            rows.append(np.broadcast_to(r, (T, 3, len(ap), 3, 3)).reshape(-1))
            cols.append(np.broadcast_to(c, (T, 3, len(ap), 3, 3)).reshape(-1))
        # rest rows: (F, J - 1, 3) diagonal
        rows.append(base_rest + np.arange(F * (J - 1) * 3))
        cols.append((f[:, None] * P + 6 + np.arange((J - 1) * 3)[None, :]).reshape(-1))
        if image is not None:  # reprojection rows: (F, L, 2, 3) root position, (F, n_lp, 2, 3) rotations
            base_2d = self.n_rows
            self.n_rows += F * L * 2
            a2 = np.arange(2)
            r = base_2d + (f[:, None, None, None] * L + np.arange(L)[None, :, None, None]) * 2 + a2[:, None]
            c = f[:, None, None, None] * P + a3
            rows.append(np.broadcast_to(r, (F, L, 2, 3)).reshape(-1))
            cols.append(np.broadcast_to(c, (F, L, 2, 3)).reshape(-1))
            r = base_2d + (f[:, None, None, None] * L + self.lp_k[None, :, None, None]) * 2 + a2[:, None]
            c = f[:, None, None, None] * P + 3 + 3 * self.lp_j[None, :, None, None] + a3
            rows.append(np.broadcast_to(r, (F, len(lp), 2, 3)).reshape(-1))
            cols.append(np.broadcast_to(c, (F, len(lp), 2, 3)).reshape(-1))
        self._rows, self._cols = np.concatenate(rows), np.concatenate(cols)
        self._cache: tuple[bytes, tuple] | None = None

    def _pose(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation vectors ``(F, J, 3)`` and joint transforms ``(F, J, 4, 4)`` of ``x`` (last one cached)."""
        key = x.tobytes()
        if self._cache is None or self._cache[0] != key:
            X = x.reshape(self.F, self.P)
            rv = X[:, 3:].reshape(self.F, self.J, 3)
            T = skel.forward_kinematics(self.body.skeleton, _rotvec_to_matrix(rv), X[:, :3])
            self._cache = (key, (rv, T))
        return self._cache[1]

    def transforms(self, x: np.ndarray) -> np.ndarray:
        return self._pose(x)[1]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        rv, T = self._pose(x)
        r_lm = (self.sqrt_w[..., None] * (self.body.landmarks(T) - self.lm)).reshape(-1)
        p = T[..., :3, 3]
        tr = self.triplets
        acc = p[tr[:, 0]] - 2.0 * p[tr[:, 1]] + p[tr[:, 2]]
        out = [r_lm, self.smooth * acc.reshape(-1), self.rest_weight * rv[:, 1:].reshape(-1)]
        if self.image is not None:
            uv, _ = self.image.project(self.body.landmarks(T))
            out.append((self.sqrt_w2[..., None] * (uv - self.uv)).reshape(-1))
        return np.concatenate(out)

    def jacobian(self, x: np.ndarray) -> csr_matrix:
        rv, T = self._pose(x)
        F = self.F
        G, o = T[..., :3, :3], T[..., :3, 3]
        B = G @ right_jacobian_so3(rv)  # (F, J, 3, 3): world rotation axis per rotation-vector change
        pts = self.body.landmarks(T)
        sw = self.sqrt_w
        vals = [np.broadcast_to(sw[..., None], (F, self.L, 3)).reshape(-1)]
        d = -_skew(pts[:, self.lp_k] - o[:, self.lp_j]) @ B[:, self.lp_j]  # (F, n_lp, 3, 3)
        vals.append((d * sw[:, self.lp_k, None, None]).reshape(-1))
        T_n = self.triplets.shape[0]
        if T_n:
            coef = self.smooth * np.array([1.0, -2.0, 1.0])
            vals.append(np.broadcast_to(coef[None, :, None, None], (T_n, 3, self.J, 3)).reshape(-1))
            da = -_skew(o[:, self.ap_i] - o[:, self.ap_j]) @ B[:, self.ap_j]  # (F, n_ap, 3, 3)
            vals.append((da[self.triplets] * coef[None, :, None, None, None]).reshape(-1))
        vals.append(np.full(F * (self.J - 1) * 3, self.rest_weight))
        if self.image is not None:
            _, Dp = self.image.project(pts)  # (F, L, 2, 3)
            w2 = self.sqrt_w2
            vals.append((Dp * w2[..., None, None]).reshape(-1))
            d_raw = -_skew(pts[:, self.lp_k] - o[:, self.lp_j]) @ B[:, self.lp_j]
            vals.append((Dp[:, self.lp_k] @ d_raw * w2[:, self.lp_k, None, None]).reshape(-1))
        return csr_matrix((np.concatenate(vals), (self._rows, self._cols)), shape=(self.n_rows, F * self.P))


    def _frame_jacobians(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Dense per-frame Jacobians of the landmark positions ``(F, 3 L, P)`` and of the joint positions
        ``(F, 3 J, P)`` with respect to the frame's own parameters (unweighted; ``jacobian`` scatters them)."""
        rv, T = self._pose(x)
        F, L, J, P = self.F, self.L, self.J, self.P
        G, o = T[..., :3, :3], T[..., :3, 3]
        B = G @ right_jacobian_so3(rv)
        a3 = np.arange(3)
        j_lm = np.zeros((F, 3 * L, P))  # unweighted
        for a in range(3):
            j_lm[:, 3 * np.arange(L) + a, a] = 1.0
        d = -_skew(self.body.landmarks(T)[:, self.lp_k] - o[:, self.lp_j]) @ B[:, self.lp_j]
        r = (3 * self.lp_k[:, None, None] + a3[None, :, None]).repeat(3, axis=2)
        c = (3 + 3 * self.lp_j[:, None, None] + a3[None, None, :]).repeat(3, axis=1)
        j_lm[:, r.reshape(-1), c.reshape(-1)] = d.reshape(F, -1)
        j_p = np.zeros((F, 3 * J, P))
        for a in range(3):
            j_p[:, 3 * np.arange(J) + a, a] = 1.0
        da = -_skew(o[:, self.ap_i] - o[:, self.ap_j]) @ B[:, self.ap_j]
        r = (3 * self.ap_i[:, None, None] + a3[None, :, None]).repeat(3, axis=2)
        c = (3 + 3 * self.ap_j[:, None, None] + a3[None, None, :]).repeat(3, axis=1)
        j_p[:, r.reshape(-1), c.reshape(-1)] = da.reshape(F, -1)
        return j_lm, j_p

    def normal_blocks(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The gradient ``J^T r`` ``(F * P,)`` and the per-frame diagonal blocks of ``J^T J`` ``(F, P, P)``
        at ``x`` with residuals ``r`` (the cross-frame blocks, from the smoothness term, are left out)."""
        F, L, J, P = self.F, self.L, self.J, self.P
        j_raw, j_p = self._frame_jacobians(x)
        j_lm = j_raw * np.repeat(self.sqrt_w, 3, axis=1)[..., None]
        r_lm = r[: F * L * 3].reshape(F, 3 * L)
        n_acc = self.triplets.shape[0] * J * 3
        r_acc = r[F * L * 3: F * L * 3 + n_acc].reshape(-1, 3 * J)
        n_rest = F * (J - 1) * 3
        r_rest = r[F * L * 3 + n_acc: F * L * 3 + n_acc + n_rest].reshape(F, -1)
        coef = np.array([1.0, -2.0, 1.0])
        q = np.zeros((F, 3 * J))  # per frame: sum of coef * acceleration residual over its triplets
        weight = np.zeros(F)  # per frame: sum of coef^2 over its triplets
        for s in range(3):
            np.add.at(q, self.triplets[:, s], coef[s] * r_acc)
            np.add.at(weight, self.triplets[:, s], coef[s] ** 2)
        g = np.einsum("fri,fr->fi", j_lm, r_lm) + self.smooth * np.einsum("fri,fr->fi", j_p, q)
        g[:, 6:] += self.rest_weight * r_rest
        A = np.einsum("fri,frj->fij", j_lm, j_lm)
        A += (self.smooth**2 * weight)[:, None, None] * np.einsum("fri,frj->fij", j_p, j_p)
        idx = np.arange(6, P)
        A[:, idx, idx] += self.rest_weight**2
        if self.image is not None:
            T = self._pose(x)[1]
            _, Dp = self.image.project(self.body.landmarks(T))  # (F, L, 2, 3)
            j2 = np.einsum("flab,flbp->flap", Dp, j_raw.reshape(F, L, 3, P)) * self.sqrt_w2[..., None, None]
            j2 = j2.reshape(F, 2 * L, P)
            r2 = r[F * L * 3 + n_acc + n_rest:].reshape(F, 2 * L)
            g += np.einsum("fri,fr->fi", j2, r2)
            A += np.einsum("fri,frj->fij", j2, j2)
        return g.reshape(-1), A

    def normal_equations(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, csr_matrix]:
        """The gradient ``J^T r`` and the whole sparse ``J^T J`` at ``x`` (frames coupled by the smoothness)."""
        jac = self.jacobian(x)
        return jac.T @ r, (jac.T @ jac).tocsr()


def levenberg_marquardt(residuals, normal_system, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                        max_iterations: int = 50, tolerance: float = 1e-6) -> tuple[np.ndarray, int]:
    """Minimise ``|residuals(x)|^2`` within the box ``[lower, upper]`` from ``x0``.

    Levenberg-Marquardt with Marquardt's scaling: ``normal_system(x, r)`` gives the gradient
    ``g = J^T r`` ``(n,)`` and the Gauss-Newton matrix ``A = J^T J``, either a scipy sparse ``(n, n)``
    matrix (solved directly) or independent blocks ``(B, b, b)`` with ``B * b = n`` (solved block by
    block: exact when the problem separates into the blocks). Each step solves
    ``(A + lam diag(A)) d = -g`` and is projected onto the box; a step that lowers the cost is taken
    (``lam`` shrinks), one that does not is retried with a larger ``lam``. Stops after
    ``max_iterations`` steps, when a step lowers the cost by less than ``tolerance`` of it, or when
    no step lowers it. Returns ``x`` and the steps taken.
    """
    from scipy.sparse import diags
    from scipy.sparse.linalg import spsolve

    x = np.clip(np.asarray(x0, dtype=np.float64), lower, upper)
    r = residuals(x)
    cost = float(r @ r)
    lam = 1e-3
    steps = 0
    for _ in range(max_iterations):
        g, A = normal_system(x, r)
        blocks = isinstance(A, np.ndarray)
        if blocks:
            gb = g.reshape(A.shape[0], A.shape[1])
            scale = np.einsum("kii->ki", A) + 1e-12
            eye = np.eye(A.shape[1])
        else:
            scale = A.diagonal() + 1e-12
        improved = False
        while lam < 1e10:
            if blocks:
                step = -np.linalg.solve(A + lam * scale[:, :, None] * eye, gb[..., None])[..., 0].reshape(-1)
            else:
                step = spsolve((A + diags(lam * scale)).tocsc(), -g)
            x_new = np.clip(x + step, lower, upper)
            r_new = residuals(x_new)
            cost_new = float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                improved = True
                lam = max(lam / 3.0, 1e-9)
                break
            lam *= 4.0
        if not improved:
            break
        steps += 1
        gain = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        if gain < tolerance * cost:
            break
    return x, steps

def fit_poses(landmarks_m: np.ndarray, body: BodyModel, weights: np.ndarray | None = None,
              frame_index: np.ndarray | None = None, cfg: FitConfig = FitConfig(),
              fps: float = SMOOTH_FPS, image: ImageLandmarks | None = None) -> PoseFit:
    """Joint angles and root trajectory of ``body`` that best explain the landmarks (module docstring).

    landmarks_m: (F, L, 3) metres in any frame (the root trajectory comes out in it); NaN where
    not detected. weights: (F, L) visibility in [0, 1] (None: 1; below ``cfg.min_visibility``: 0).
    frame_index: (F,) increasing ints, the frames' positions in the video: smoothness links only
    frames that follow each other (``frame_index`` differing by 1); None: ``0 .. F-1``.
    fps: the frames' rate (scales the smoothness weight, see ``FitConfig``).
    image: where a static camera saw the landmarks (adds their reprojection error; the 3D
    landmarks then weigh ``cfg.weight_3d``: a detector's depth is its weakest guess).
    Returns ``PoseFit``; the skeleton is ``body.skeleton`` in every frame.
    """
    lm = np.asarray(landmarks_m, dtype=np.float64)
    if lm.ndim != 3 or lm.shape[1:] != (NUM_LANDMARKS, 3) or lm.shape[0] < 1:
        raise ValueError(f"fit_poses: expected landmarks (F >= 1, {NUM_LANDMARKS}, 3), got {lm.shape}")
    F = lm.shape[0]
    w = np.ones((F, NUM_LANDMARKS)) if weights is None else np.asarray(weights, dtype=np.float64).copy()
    if w.shape != (F, NUM_LANDMARKS):
        raise ValueError(f"fit_poses: weights: expected {(F, NUM_LANDMARKS)}, got {w.shape}")
    seen = np.all(np.isfinite(lm), axis=-1) & (w >= cfg.min_visibility)
    w = np.where(seen, np.clip(w, 0.0, 1.0), 0.0)
    lm = np.where(seen[..., None], lm, 0.0)
    idx = np.arange(F) if frame_index is None else np.asarray(frame_index, dtype=np.int64).reshape(-1)
    if idx.shape != (F,) or np.any(np.diff(idx) <= 0):
        raise ValueError("fit_poses: frame_index must be (F,) strictly increasing")
    consecutive = np.flatnonzero((idx[1:-1] - idx[:-2] == 1) & (idx[2:] - idx[1:-1] == 1))
    triplets = np.stack([consecutive, consecutive + 1, consecutive + 2], axis=1) if consecutive.size else \
        np.zeros((0, 3), dtype=np.int64)

    sk = body.skeleton
    J = sk.num_joints
    P = 3 + 3 * J
    R0 = _initial_rotations(body, np.where(seen[..., None], lm, np.nan), w)
    rv0 = Rotation.from_matrix(R0.reshape(-1, 3, 3)).as_rotvec().reshape(F, J, 3)
    lo = np.broadcast_to(JOINT_LIMITS_RAD[..., 0], (F, J, 3))
    hi = np.broadcast_to(JOINT_LIMITS_RAD[..., 1], (F, J, 3))
    margin = 1e-3
    rv0 = np.clip(rv0, lo + margin, hi - margin)
    # root position: observed mid-hip minus the rotated rest offset of the mid-hip from the pelvis
    rest = body.rest_landmarks()
    hip_mid_rest = 0.5 * (rest[_idx("left_hip")] + rest[_idx("right_hip")]) - sk.offsets_m[0]
    hip_mid = 0.5 * (lm[:, _idx("left_hip")] + lm[:, _idx("right_hip")])
    hips_seen = seen[:, _idx("left_hip")] & seen[:, _idx("right_hip")]
    if not hips_seen.any():
        raise ValueError("fit_poses: the hips are not seen in any frame")
    hip_mid = np.where(hips_seen[:, None], hip_mid, np.nan)
    for k in range(3):  # frames without hips: nearest frames' values
        hip_mid[:, k] = np.interp(np.arange(F), np.flatnonzero(hips_seen), hip_mid[hips_seen, k])
    root0 = hip_mid - np.einsum("fij,j->fi", _rotvec_to_matrix(rv0[:, 0]), hip_mid_rest)
    x0 = np.concatenate([root0, rv0.reshape(F, -1)], axis=1).reshape(-1)
    lb = np.concatenate([np.full((F, 3), -np.inf), lo.reshape(F, -1)], axis=1).reshape(-1)
    ub = np.concatenate([np.full((F, 3), np.inf), hi.reshape(F, -1)], axis=1).reshape(-1)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fit_poses: fps must be > 0, got {fps!r}")
    smooth = (cfg.smooth_weight if image is None else cfg.smooth_weight_image) * (float(fps) / SMOOTH_FPS) ** 2
    # 1. every frame on its own (the problem separates: exact block solves, cost linear in the frames);
    # 2. all frames together with the smoothness term, from there (a sparse direct solve per step)
    sw3 = np.sqrt(w) * (np.sqrt(cfg.weight_3d) if image is not None else 1.0)
    alone = IKProblem(body, lm, np.sqrt(w), triplets[:0], 0.0, cfg.rest_weight, image, sw3)
    x_alone, it_alone = levenberg_marquardt(alone.residuals, alone.normal_blocks, x0, lb, ub, cfg.max_iterations,
                                            cfg.tolerance)
    problem = IKProblem(body, lm, np.sqrt(w), triplets, smooth, cfg.rest_weight, image, sw3)
    x_opt, it_joint = levenberg_marquardt(problem.residuals, problem.normal_equations, x_alone, lb, ub,
                                          cfg.joint_iterations, cfg.tolerance)
    iterations = it_alone + it_joint
    x = x_opt.reshape(F, P)
    T = problem.transforms(x_opt)
    q = skel.quats_from_matrices(_rotvec_to_matrix(x[:, 3:].reshape(F, J, 3)))
    err = np.linalg.norm(body.landmarks(T) - lm, axis=-1)
    err = np.where(seen, err, np.nan)
    log.debug("fit_poses: %d frames, %d iterations, landmark error median %.4f m", F, iterations,
              float(np.nanmedian(err)) if np.isfinite(err).any() else float("nan"))
    return PoseFit(body, x[:, :3].copy(), q, T, err, iterations)


# ---------------------------------------------------------------------------------------------- metrics


def mpjpe_m(pred_m: np.ndarray, true_m: np.ndarray, procrustes: bool = True) -> np.ndarray:
    """Mean per-joint position error of each frame ``(F,)`` (metres).

    pred_m, true_m: (F, J, 3) joint positions. procrustes: first align each predicted frame to
    the true one by the similarity (scale, rotation, translation) that fits best (Umeyama), as
    "PA-MPJPE" in the human pose literature; False compares the positions as they are.
    """
    pred = np.asarray(pred_m, dtype=np.float64)
    true = np.asarray(true_m, dtype=np.float64)
    if pred.shape != true.shape or pred.ndim != 3 or pred.shape[-1] != 3:
        raise ValueError(f"mpjpe_m: expected two (F, J, 3) arrays of one shape, got {pred.shape}, {true.shape}")
    if procrustes:
        aligned = np.empty_like(pred)
        for f in range(pred.shape[0]):
            s, R, t = umeyama(pred[f], true[f], with_scale=True)
            aligned[f] = s * pred[f] @ R.T + t
        pred = aligned
    return np.linalg.norm(pred - true, axis=-1).mean(axis=-1)


def bone_lengths_m(skeleton: skel.Skeleton, joint_positions_m: np.ndarray) -> np.ndarray:
    """Length of every bone (joint to its parent) per frame: ``(..., J - 1)`` from ``(..., J, 3)``."""
    p = np.asarray(joint_positions_m, dtype=np.float64)
    return np.linalg.norm(p[..., 1:, :] - p[..., skeleton.parents[1:], :], axis=-1)


__all__ = ["BONE_GROUPS", "JOINT_LIMITS_RAD", "LANDMARK_ATTACHMENTS", "SMOOTH_FPS", "BodyModel", "FitConfig",
           "IKProblem", "ImageLandmarks", "PoseFit", "bone_lengths_m", "estimate_body", "fit_poses", "levenberg_marquardt", "mpjpe_m",
           "reference_body", "scaled_body"]
