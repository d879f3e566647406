"""A person filmed by a moving (handheld) camera: detect the motion, find the camera's path, place the person.

1. **Static or moving** (``background_motion_px``): corners of the background (the person's mask,
   dilated, left out) are tracked from each frame to the next (pyramidal Lucas-Kanade, OpenCV); a
   pair's motion is the median displacement of the corners tracked there and back again, whose
   patches match. The camera moves when the median over pairs exceeds ``MOVING_FRACTION`` of the frame's width (a static camera's frames
   give sub-pixel values: noise and compression).
2. **The camera's path** (``camera_path``): nsim's own SfM (``nsim.sfm.colmap.run_sfm``, what
   ``nsim reconstruct`` runs) on the frames with the person's dilated mask excluded from feature
   extraction, so that the walking person does not pull the background's geometry. Its world has
   an arbitrary scale.
3. **Metres** (``place_landmarks_moving``): each frame's landmarks in its camera frame (metric, from
   the detector's body-size prior; ``nsim.human.monocular.root_translations``) go into SfM's world
   as ``R_f p + s C_f`` with the camera's rotation ``R_f`` and centre ``C_f``. The one unknown,
   ``s`` (metres per SfM unit), comes from the floor when SfM's sparse points show one
   (``nsim.sfm.align.gravity_align``, as ``nsim reconstruct``): the camera's height above it in
   SfM units against its height above the person's lowest foot (heel or toe, ``SOLE_HEIGHT_M``
   over the floor) in metres, medians over the frames; the world is then SfM's, floor z = 0.
   Without a floor, ``s`` is where the person's root moves most nearly on a straight line at
   constant speed (``metric_scale``: a wrong ``s`` adds a multiple of the camera's own path to
   the root's; linear least squares in ``s``), and up and floor come from the person as for a static camera
   (``nsim.human.monocular.floor_frame``). ``--camera-height`` (the median camera height above the
   floor) or the person's height then rescales everything.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nsim.geometry.cameras import Camera
from nsim.human.landmarks import LANDMARK_NAMES
from nsim.human.monocular import Placement, floor_frame, root_translations
from nsim.human.skeleton import SOLE_HEIGHT_M

MOVING_FRACTION = 0.004
"""The camera moves when the background's median motion between frames exceeds this share of the width."""

MASK_DILATION_FRACTION = 0.02
"""The person's mask is grown by this share of the frame's width before it excludes the background."""


_FEET = [LANDMARK_NAMES.index(n) for n in ("left_heel", "right_heel", "left_foot_index", "right_foot_index")]


@dataclass(frozen=True, eq=False)
class CameraPath:
    """A moving camera found by SfM (``camera_path``), in SfM's world and scale.

    cam_to_world: (N, 4, 4) OpenCV axes (NaN: frame not registered). camera: the shared intrinsics.
    points_xyz: (P, 3) SfM's sparse points of the background.
    """

    cam_to_world: np.ndarray
    camera: Camera
    points_xyz: np.ndarray


FB_MAX_PX = 1.0
"""A background corner counts when tracking it forward and back again lands within this many pixels."""


PATCH_MAX_DIFF = 15.0
"""... and its 21 x 21 patch differs from where it landed by less than this mean absolute grey level (0-255)."""


def _dilated(mask: np.ndarray, width: int) -> np.ndarray:
    import cv2

    r = max(1, round(MASK_DILATION_FRACTION * width))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.dilate(np.asarray(mask, dtype=np.uint8), kernel) > 0


def background_motion_px(frames: list[np.ndarray], person_masks: np.ndarray, max_corners: int = 400) -> np.ndarray:
    """Median background displacement (pixels) from each frame to the next, ``(N - 1,)``.

    frames: N ``(H, W, 3)`` uint8 RGB. person_masks: (N, H, W) bool, left out (dilated). A corner
    counts when tracking it forward and back lands within ``FB_MAX_PX`` of where it started and its
    patch matches (``PATCH_MAX_DIFF``); NaN for
    a pair with fewer than 8 such corners (frames that share no background: no evidence either way).
    """
    import cv2

    n = len(frames)
    out = np.full(max(n - 1, 0), np.nan)
    if n < 2:
        return out
    grey = [cv2.cvtColor(np.asarray(f, dtype=np.uint8), cv2.COLOR_RGB2GRAY) for f in frames]
    w = grey[0].shape[1]
    for i in range(n - 1):
        allowed = (~_dilated(person_masks[i], w)).astype(np.uint8) * 255
        pts = cv2.goodFeaturesToTrack(grey[i], max_corners, 0.01, max(3.0, 0.01 * w), mask=allowed)
        if pts is None or len(pts) < 8:
            continue
        nxt, status, err = cv2.calcOpticalFlowPyrLK(grey[i], grey[i + 1], pts, None, winSize=(21, 21), maxLevel=3)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(grey[i + 1], grey[i], nxt, None, winSize=(21, 21),
                                                        maxLevel=3)
        fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
        ok = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb < FB_MAX_PX) & (err.ravel() < PATCH_MAX_DIFF)
        if ok.sum() < 8:
            continue
        out[i] = float(np.median(np.linalg.norm((nxt - pts).reshape(-1, 2)[ok], axis=1)))
    return out


def camera_moves(motion_px: np.ndarray, width: int) -> bool:
    """Whether the background's motion (``background_motion_px``) says the camera moves."""
    m = np.asarray(motion_px, dtype=np.float64)
    m = m[np.isfinite(m)]
    return bool(m.size) and float(np.median(m)) > MOVING_FRACTION * width


def camera_path(frames: list[np.ndarray], person_masks: np.ndarray, hfov_deg: float | None = None,
                work_dir: str | Path | None = None, num_threads: int = -1) -> CameraPath:
    """The moving camera of each frame by SfM with the person masked out (step 2 of the module docstring).

    The intrinsics are shared by every frame: fixed at ``hfov_deg`` when given, else estimated.
    InputError (``run_sfm``'s) when too few frames register.
    """
    from nsim.io.images import write_image
    from nsim.sfm.colmap import run_sfm
    from nsim.sfm.options import SfmOptions

    h, w = frames[0].shape[:2]
    known = None if hfov_deg is None else Camera.pinhole_from_fov(w, h, float(hfov_deg))
    opts = SfmOptions(matcher="sequential", loop_detection=False, num_threads=num_threads, camera_model="PINHOLE",
                      shared_intrinsics=True)
    with tempfile.TemporaryDirectory(dir=work_dir) as tmp:
        root = Path(tmp)
        (root / "images").mkdir()
        (root / "masks").mkdir()
        names = [f"frame_{i:05d}.png" for i in range(len(frames))]
        for name, rgb, m in zip(names, frames, person_masks, strict=True):
            write_image(root / "images" / name, np.asarray(rgb, dtype=np.uint8))
            write_image(root / "masks" / f"{name}.png", (~_dilated(m, w)).astype(np.uint8) * 255)
        result = run_sfm(root / "images", root / "sfm", opts, known_camera=known, image_names=names,
                         mask_dir=root / "masks")
    c2w = np.full((len(frames), 4, 4), np.nan)
    for i, name in enumerate(names):
        if name in result.cam_to_world:
            c2w[i] = result.cam_to_world[name]
    camera = known if known is not None else result.cameras[result.registered_names[0]]
    return CameraPath(c2w, camera, np.asarray(result.points_xyz, dtype=np.float64))


def metric_scale(root_cam_m: np.ndarray, cam_to_world: np.ndarray, times: np.ndarray | None = None) -> float:
    """Metres per SfM unit: the ``s`` making the root's path ``R_f t_f + s C_f`` straightest (module docstring).

    root_cam_m: (F, 3) the person's root in each frame's camera (metres; NaN rows skipped);
    cam_to_world: (F, 4, 4) in SfM's units; times: (F,) seconds (None: evenly spaced). A person walks
    at a nearly constant velocity, and a wrong ``s`` adds a multiple of the camera's own path to the
    root's: ``s`` minimises what is left of the root's path after the best straight line at constant
    speed (least squares per axis against ``1, t``), linear least squares in ``s``. (Second
    differences instead are dominated by the detector's frame-to-frame depth noise, which biases
    ``s`` low.) NaN when the camera itself moves on a straight line at constant speed (then the
    images cannot tell).
    """
    t = np.asarray(root_cam_m, dtype=np.float64)
    T = np.asarray(cam_to_world, dtype=np.float64)
    time = np.arange(len(t), dtype=np.float64) if times is None else np.asarray(times, dtype=np.float64)
    ok = np.isfinite(t).all(1) & np.isfinite(T[:, :3, :]).all((1, 2))
    if ok.sum() < 3:
        return float("nan")
    a = np.einsum("fij,fj->fi", T[ok, :3, :3], t[ok])
    b = T[ok, :3, 3]
    V = np.stack([np.ones(ok.sum()), time[ok] - time[ok].mean()], axis=1)
    proj = np.eye(len(V)) - V @ np.linalg.pinv(V)
    pa, pb = proj @ a, proj @ b
    den = float((pb**2).sum())
    if den <= 1e-9 * max(float(((b - b.mean(0)) ** 2).sum()), 1e-12):
        return float("nan")
    return -float((pa * pb).sum()) / den


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


def place_landmarks_moving(body_m: np.ndarray, image_uv_px: np.ndarray, visibility: np.ndarray, camera: Camera,
                           cam_to_world_sfm: np.ndarray, points_xyz: np.ndarray | None = None,
                           camera_height_m: float | None = None, body_height_m: float | None = None,
                           times: np.ndarray | None = None) -> Placement:
    """``nsim.human.monocular.place_landmarks`` for a moving camera (step 3 of the module docstring).

    cam_to_world_sfm: (F, 4, 4) SfM's camera of each frame (NaN rows: not registered, not placed);
    points_xyz: SfM's sparse points (None or no floor among them: the scale from the root's path,
    ``metric_scale``, with the frames' ``times`` in seconds, None: evenly spaced).
    Returns a ``Placement`` whose ``cam_to_world`` is (F, 4, 4) (z-up metric world, floor z = 0),
    ``camera_height_m`` the median camera height and ``scale`` the metres per SfM unit.
    ValueError if no frame can be placed or no scale found.
    """
    if camera_height_m is not None and body_height_m is not None:
        raise ValueError("place_landmarks_moving: give camera_height_m or body_height_m, not both")
    c2w = np.asarray(cam_to_world_sfm, dtype=np.float64)
    w = np.clip(np.nan_to_num(np.asarray(visibility, dtype=np.float64)), 0.0, 1.0)
    t = root_translations(body_m, image_uv_px, w, camera)
    placed = np.isfinite(t).all(axis=1) & np.isfinite(c2w).all(axis=(1, 2))
    if not placed.any():
        raise ValueError("place_landmarks_moving: no frame could be placed in front of a registered camera")
    cam = np.asarray(body_m, dtype=np.float64) + t[:, None, :]
    w = np.where(placed[:, None], w, 0.0)
    G = None
    if points_xyz is not None and len(points_xyz):
        from nsim.sfm.align import gravity_align

        grav = gravity_align(points_xyz, c2w[placed])
        if grav.floor_found:
            G = grav.T
    s = float("nan")
    if G is not None:  # SfM's floor: z-up SfM world, scale from the camera's height over the person's feet
        zup = np.einsum("ij,fjk->fik", G, c2w)
        s = floor_scale(np.where(placed[:, None, None], cam, np.nan), w, zup)
    if not (np.isfinite(s) and s > 0):
        G = None
        s = metric_scale(np.where(placed[:, None], t, np.nan), c2w, times)
    if not (np.isfinite(s) and s > 0):
        raise ValueError("place_landmarks_moving: the camera's path gives no scale (no floor among its points and "
                         "it moves at a constant velocity); give --camera-height")
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
    return Placement(world, w, cams, height * scale, s * scale)


__all__ = ["FB_MAX_PX", "PATCH_MAX_DIFF", "MASK_DILATION_FRACTION", "MOVING_FRACTION", "CameraPath", "background_motion_px", "camera_moves",
           "camera_path", "floor_scale", "metric_scale", "place_landmarks_moving"]
