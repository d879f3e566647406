"""The one convention used everywhere in nsim, and the only conversions out of it.

Units and axes
    Metres, seconds, radians inside computations (``*_deg`` names where degrees). The world
    frame is right-handed with **z up**.
Arrays
    Channels last, leading ``*batch`` dimensions: points ``(..., 3)``, images ``(..., H, W, C)``.
Poses
    ``cam_to_world`` is a ``(..., 4, 4)`` homogeneous matrix mapping camera coordinates to world
    coordinates, with **OpenCV camera axes**: +x right, +y down, +z forward (the optical axis).
    ``world_to_cam`` is its inverse. Names carry the direction; a bare "pose" is cam_to_world.
Rotations
    Quaternions are **wxyz** (scalar first), unit norm, canonicalised to ``w >= 0`` on output.
Pixels
    OpenCV convention: ``(u, v)`` = (column, row) and the *centre* of the top-left pixel is
    ``(0, 0)``; the image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``. ``Camera.cx, cy`` are in
    this convention, so projections compare directly with ``cv2.projectPoints``.

Foreign conventions, converted only in ``nsim/io/`` with the helpers below:

* nerfstudio / instant-ngp ``transforms.json``: cam_to_world with **OpenGL camera axes**
  (+x right, +y up, +z backward), i.e. ``c2w_gl = c2w_cv @ diag(1, -1, -1, 1)``.
* COLMAP: stores **world_to_cam** as ``(qvec wxyz, tvec)`` in OpenCV camera axes.
* COLMAP and nerfstudio put the centre of the top-left pixel at ``(0.5, 0.5)``, so their
  principal point is ours plus 0.5 (``cx_colmap = cx + 0.5``); focal lengths and distortion
  coefficients are identical. See ``principal_point_to_colmap`` / ``principal_point_from_colmap``.
"""

from __future__ import annotations

import numpy as np

from nsim.geometry.transforms import invert_se3, make_se3, matrix_from_quat_wxyz, quat_wxyz_from_matrix

#: Right-multiplying a cam_to_world by this flips camera axes OpenCV <-> OpenGL (its own inverse).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
OPENCV_TO_OPENGL.setflags(write=False)

#: Where COLMAP / nerfstudio put the centre of the top-left pixel, in our pixel coordinates + this.
COLMAP_PIXEL_OFFSET = 0.5


def _as_poses(c2w) -> np.ndarray:
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.ndim < 2 or c2w.shape[-2:] != (4, 4):
        raise ValueError(f"cam_to_world: expected shape (..., 4, 4), got {c2w.shape}")
    return c2w


def opencv_to_opengl_c2w(c2w) -> np.ndarray:
    """cam_to_world ``(..., 4, 4)`` with OpenCV camera axes -> OpenGL camera axes."""
    return _as_poses(c2w) @ OPENCV_TO_OPENGL


def opengl_to_opencv_c2w(c2w) -> np.ndarray:
    """cam_to_world ``(..., 4, 4)`` with OpenGL camera axes -> OpenCV camera axes."""
    return _as_poses(c2w) @ OPENCV_TO_OPENGL


def world_to_cam_to_colmap(cam_to_world) -> tuple[np.ndarray, np.ndarray]:
    """Our cam_to_world ``(..., 4, 4)`` -> COLMAP's world_to_cam ``(qvec_wxyz (..., 4), tvec (..., 3))``."""
    w2c = invert_se3(_as_poses(cam_to_world))
    return quat_wxyz_from_matrix(w2c[..., :3, :3]), w2c[..., :3, 3].copy()


def colmap_to_cam_to_world(qvec_wxyz, tvec) -> np.ndarray:
    """COLMAP's world_to_cam ``(qvec_wxyz (..., 4), tvec (..., 3))`` -> cam_to_world ``(..., 4, 4)``."""
    w2c = make_se3(matrix_from_quat_wxyz(qvec_wxyz), np.asarray(tvec, dtype=np.float64))
    return invert_se3(w2c)


def principal_point_to_colmap(cx: float, cy: float) -> tuple[float, float]:
    """Our (OpenCV, pixel centre at 0) principal point -> COLMAP/nerfstudio (centre at 0.5)."""
    return cx + COLMAP_PIXEL_OFFSET, cy + COLMAP_PIXEL_OFFSET


def principal_point_from_colmap(cx: float, cy: float) -> tuple[float, float]:
    """COLMAP/nerfstudio principal point (pixel centre at 0.5) -> ours (OpenCV, centre at 0)."""
    return cx - COLMAP_PIXEL_OFFSET, cy - COLMAP_PIXEL_OFFSET
