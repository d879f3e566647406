"""One static camera, one person: landmarks placed in a metric, z-up world.

A pose detector gives, per frame, the body's landmarks in metres relative to the hips in the
camera's axes (``body_m``) and where they are in the image (``image_uv_px``); see
``nsim.human.landmarks``. This module turns them into world positions:

1. **Camera**: a static pinhole (``static_camera``) with square pixels, centred, and a horizontal
   field of view given (``--fov``) or ``DEFAULT_HFOV_DEG`` (a phone's main camera).
2. **Root translation per frame** (``root_translations``): the hip midpoint's position in the
   camera frame that makes the body's landmarks project where the detector saw them: with
   ``d = (x, y, 1)`` the normalised image point of landmark ``k`` and ``P_k`` its body
   position, ``P_k + t`` must lie on the ray through ``d``, which is linear in ``t``
   (``t_x - x t_z = x Z_k - X_k``, ``t_y - y t_z = y Z_k - Y_k``), solved by weighted least
   squares (weights: the landmarks' visibility). Depth comes from the body's metric size.
3. **Up and floor** (``floor_frame``): up is the mean body axis (feet to shoulders) over frames,
   with its tilt along the walking direction removed when the person travels (a walker leans
   forward); the floor is the median height of the lowest foot landmark (heel or toe, which sit
   ``SOLE_HEIGHT_M`` above the ground) along up. The world is z up with its origin on the floor
   under the camera, x the camera's viewing direction along the floor: ``cam_to_world (4, 4)``
   (OpenCV camera axes), the same for every frame.
4. **Metric scale**: the detector's metres come from its own body-size prior. A known camera
   height or body height rescales everything (``place_landmarks``), which the images cannot tell
   apart from the detector's guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nsim.geometry.cameras import Camera
from nsim.human.landmarks import LANDMARK_NAMES
from nsim.human.skeleton import SOLE_HEIGHT_M

DEFAULT_HFOV_DEG = 65.0
"""Horizontal field of view assumed for a video without ``--fov`` (a phone's main camera, landscape)."""

MIN_TRAVEL_M = 0.3
"""The foot contacts must spread at least this far (standard deviation along their main direction)
for the walking direction to correct the body axis's lean."""

_L = {n: i for i, n in enumerate(LANDMARK_NAMES)}
_FEET = [_L[n] for n in ("left_heel", "right_heel", "left_foot_index", "right_foot_index")]
_SHOULDERS = [_L["left_shoulder"], _L["right_shoulder"]]


def static_camera(width: int, height: int, hfov_deg: float | None = None) -> Camera:
    """The pinhole camera of a ``width x height`` video with horizontal FOV ``hfov_deg`` (None: default)."""
    return Camera.pinhole_from_fov(int(width), int(height), DEFAULT_HFOV_DEG if hfov_deg is None else float(hfov_deg))


def root_translations(body_m: np.ndarray, image_uv_px: np.ndarray, weights: np.ndarray, camera: Camera,
                      min_points: int = 4) -> np.ndarray:
    """Camera-frame position of the body's origin (hip midpoint) per frame (step 2 of the module docstring).

    body_m: (F, L, 3) camera axes, relative to the hips. image_uv_px: (F, L, 2). weights: (F, L) >= 0.
    Returns (F, 3); NaN rows where fewer than ``min_points`` landmarks weigh > 0 or the solution is
    behind the camera.
    """
    P = np.asarray(body_m, dtype=np.float64)
    uv = np.asarray(image_uv_px, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    F, L = P.shape[:2]
    if P.shape != (F, L, 3) or uv.shape != (F, L, 2) or w.shape != (F, L):
        raise ValueError(f"root_translations: expected body (F, L, 3), uv (F, L, 2), weights (F, L); got "
                         f"{P.shape}, {uv.shape}, {w.shape}")
    ok = np.isfinite(P).all(-1) & np.isfinite(uv).all(-1) & (w > 0)
    w = np.where(ok, w, 0.0)
    d = camera.unproject(np.where(ok[..., None], uv, 0.0))
    x = d[..., 0] / d[..., 2]
    y = d[..., 1] / d[..., 2]
    X, Y, Z = (np.where(ok, P[..., k], 0.0) for k in range(3))
    # rows [1, 0, -x] t = x Z - X and [0, 1, -y] t = y Z - Y, weighted
    A = np.zeros((F, L, 2, 3))
    A[..., 0, 0], A[..., 0, 2] = 1.0, -x
    A[..., 1, 1], A[..., 1, 2] = 1.0, -y
    b = np.stack([x * Z - X, y * Z - Y], axis=-1)
    Aw = A * w[..., None, None]
    AtA = np.einsum("flri,flrj->fij", Aw, A)
    Atb = np.einsum("flri,flr->fi", Aw, b)
    t = np.full((F, 3), np.nan)
    enough = ok.sum(axis=1) >= min_points
    if enough.any():
        t[enough] = np.linalg.solve(AtA[enough], Atb[enough][..., None])[..., 0]
    t[~(t[:, 2] > 0)] = np.nan
    return t


@dataclass(frozen=True)
class FloorFrame:
    """The world a static camera sees a person in (step 3 of the module docstring).

    cam_to_world: (4, 4) OpenCV camera axes to the z-up world (floor ``z = 0``, camera above the origin).
    camera_height_m: the camera's height above the floor.
    up_cam: (3,) the world's up in camera axes.
    """

    cam_to_world: np.ndarray
    camera_height_m: float
    up_cam: np.ndarray


def floor_frame(points_cam_m: np.ndarray, weights: np.ndarray, min_weight: float = 0.5,
                sole_height_m: float = SOLE_HEIGHT_M) -> FloorFrame:
    """Up, floor and the z-up world of landmarks ``points_cam_m (F, L, 3)`` in the camera frame.

    weights: (F, L) visibility; feet and shoulders count where ``>= min_weight``.
    ValueError when no frame shows both the shoulders and a foot.
    """
    p = np.asarray(points_cam_m, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    seen = np.isfinite(p).all(-1) & (w >= min_weight)
    feet_ok = seen[:, _FEET]
    sh_ok = seen[:, _SHOULDERS].all(axis=1)
    frames = np.flatnonzero(sh_ok & feet_ok.any(axis=1))
    if frames.size == 0:
        raise ValueError("floor_frame: no frame shows the shoulders and a foot")
    feet = np.where(feet_ok[..., None], p[:, _FEET], np.nan)
    foot_mid = np.nanmean(feet[frames], axis=1)
    shoulder_mid = p[frames][:, _SHOULDERS].mean(axis=1)
    axis = (shoulder_mid - foot_mid).sum(axis=0)
    up = axis / np.linalg.norm(axis)
    # the lowest foot point along up in each frame: the foot on the ground
    heights = np.einsum("fkc,c->fk", feet[frames], up)
    low = np.nanargmin(heights, axis=1)
    contacts = feet[frames, low]
    if contacts.shape[0] >= 3:
        centred = contacts - contacts.mean(axis=0)
        _, sv, vt = np.linalg.svd(centred, full_matrices=False)
        spread = sv / np.sqrt(contacts.shape[0])
        if spread[0] >= MIN_TRAVEL_M:  # walking: the contacts line up along the floor; drop the lean
            walk = vt[0]
            up = up - np.dot(up, walk) * walk
            up /= np.linalg.norm(up)
    floor = float(np.median(contacts @ up)) - sole_height_m
    height = -floor
    forward = np.array([0.0, 0.0, 1.0]) - up * up[2]
    if np.linalg.norm(forward) < 1e-6:  # looking straight down: any horizontal x
        forward = np.array([1.0, 0.0, 0.0]) - up * up[0]
    x = forward / np.linalg.norm(forward)
    y = np.cross(up, x)
    R = np.stack([x, y, up])  # rows: world axes in camera coordinates
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = (0.0, 0.0, height)
    return FloorFrame(T, height, up)


@dataclass(frozen=True, eq=False)
class Placement:
    """Landmarks of F frames in the world (``place_landmarks``).

    landmarks_m: (F, L, 3) world (z up, floor z = 0); NaN where unseen. weights: (F, L).
    cam_to_world: (4, 4). camera_height_m: as used (after scaling). scale: the factor applied to
    the detector's metres (1 unless a camera or body height was given). scale_from: for a moving camera
    (``nsim.human.moving_camera.place_landmarks_moving``), where its metres per SfM unit came from
    (``nsim.human.moving_camera.SCALE_SOURCES``); empty for a static one.
    """

    landmarks_m: np.ndarray
    weights: np.ndarray
    cam_to_world: np.ndarray
    camera_height_m: float
    scale: float
    scale_from: str = ""


def place_landmarks(body_m: np.ndarray, image_uv_px: np.ndarray, visibility: np.ndarray, camera: Camera,
                    camera_height_m: float | None = None, body_height_m: float | None = None) -> Placement:
    """Steps 2-4 of the module docstring for F frames (all with a person).

    camera_height_m: the camera's true height above the floor (rescales everything); body_height_m:
    the person's height instead (rescales so that the fitted body is that tall; measured from the
    landmarks' bone lengths, ``nsim.human.fit.estimate_body``). Give at most one.
    ValueError if no frame can be placed.
    """
    if camera_height_m is not None and body_height_m is not None:
        raise ValueError("place_landmarks: give camera_height_m or body_height_m, not both")
    w = np.clip(np.nan_to_num(np.asarray(visibility, dtype=np.float64)), 0.0, 1.0)
    t = root_translations(body_m, image_uv_px, w, camera)
    placed = np.isfinite(t).all(axis=1)
    if not placed.any():
        raise ValueError("place_landmarks: no frame could be placed in front of the camera")
    cam = np.asarray(body_m, dtype=np.float64) + t[:, None, :]
    w = np.where(placed[:, None], w, 0.0)
    frame = floor_frame(cam, w)
    scale = 1.0
    if camera_height_m is not None:
        scale = float(camera_height_m) / frame.camera_height_m
    elif body_height_m is not None:
        from nsim.human.fit import estimate_body

        scale = float(body_height_m) / estimate_body(cam, w).height_m
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"place_landmarks: cannot scale to the given height (scale {scale!r})")
    T = frame.cam_to_world.copy()
    T[:3, 3] *= scale
    world = scale * cam @ T[:3, :3].T + T[:3, 3]
    return Placement(world, w, T, frame.camera_height_m * scale, scale)


__all__ = ["DEFAULT_HFOV_DEG", "FloorFrame", "Placement", "floor_frame", "place_landmarks",
           "root_translations", "static_camera"]
