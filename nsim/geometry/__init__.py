"""Cameras, SE(3)/Sim(3) helpers and the one coordinate convention (see ``conventions``)."""

from nsim.geometry.cameras import MODELS, Camera
from nsim.geometry.conventions import (
    OPENCV_TO_OPENGL,
    colmap_to_cam_to_world,
    opencv_to_opengl_c2w,
    opengl_to_opencv_c2w,
    world_to_cam_to_colmap,
)
from nsim.geometry.transforms import (
    apply_sim3,
    invert_se3,
    is_rotation,
    look_at,
    make_se3,
    matrix_from_quat_wxyz,
    quat_wxyz_from_matrix,
    rotation_angle_deg,
    se3_from_quat_wxyz_t,
    umeyama,
)

__all__ = [
    "MODELS",
    "OPENCV_TO_OPENGL",
    "Camera",
    "apply_sim3",
    "colmap_to_cam_to_world",
    "invert_se3",
    "is_rotation",
    "look_at",
    "make_se3",
    "matrix_from_quat_wxyz",
    "opencv_to_opengl_c2w",
    "opengl_to_opencv_c2w",
    "quat_wxyz_from_matrix",
    "rotation_angle_deg",
    "se3_from_quat_wxyz_t",
    "umeyama",
    "world_to_cam_to_colmap",
]
