"""Independent checks of the phone model: sRGB decoding, a depth-based image warp, JPEG quality.

The warp predicts what a camera at another pose sees from one exact view and its depth (the
room's shading is view-independent, so it is exact up to disocclusions and resampling); the
tests compare motion blur and rolling shutter against it.
"""

from __future__ import annotations

import cv2
import numpy as np


def srgb_to_linear(u8: np.ndarray) -> np.ndarray:
    """uint8 sRGB -> float64 linear (the standard curve, written out here on purpose)."""
    c = np.asarray(u8, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def flow_px(camera, depth_z: np.ndarray, src_c2w: np.ndarray, dst_c2w_rows: np.ndarray) -> np.ndarray:
    """Where each pixel's surface point moves from the camera at ``src_c2w`` to the one at
    ``dst_c2w_rows[v]`` (one pose per image row): ``(H, W, 2)`` pixels; 0 where depth is undefined."""
    H, W = depth_z.shape
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    uv = np.stack([uu, vv], -1)
    d = camera.unproject(uv)
    pts_cam = d / d[..., 2:3] * depth_z[..., None]
    pts_w = pts_cam @ src_c2w[:3, :3].T + src_c2w[:3, 3]
    R, t = dst_c2w_rows[:, :3, :3], dst_c2w_rows[:, :3, 3]  # (H, 3, 3), (H, 3)
    pts_dst = np.einsum("hji,hwj->hwi", R, pts_w - t[:, None, :])
    uv_dst, _ = camera.project(pts_dst)
    flow = uv_dst - uv
    return np.where(np.isfinite(flow).all(-1, keepdims=True) & np.isfinite(depth_z)[..., None], flow, 0.0)


def warp(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``image`` as seen after the motion ``flow (H, W, 2)``: ``out(q) = image(q - flow(q))`` (bilinear)."""
    H, W = flow.shape[:2]
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    map_x = (uu - flow[..., 0]).astype(np.float32)
    map_y = (vv - flow[..., 1]).astype(np.float32)
    return cv2.remap(image.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def detail_energy(linear_rgb: np.ndarray, sigma_px: float = 1.0, margin: int = 6) -> float:
    """Mean squared gradient of the grey image smoothed by a Gaussian of ``sigma_px``, away from the border:
    the fine detail that blur removes (the smoothing keeps resampling and pixel noise out of it)."""
    grey = cv2.GaussianBlur(np.asarray(linear_rgb, dtype=np.float64).mean(-1), (0, 0), sigma_px)
    gx, gy = cv2.Sobel(grey, cv2.CV_64F, 1, 0), cv2.Sobel(grey, cv2.CV_64F, 0, 1)
    return float(np.mean((gx * gx + gy * gy)[margin:-margin, margin:-margin]))


# libjpeg's base luminance table (ITU-T T.81 Annex K); order does not matter for the comparison below
_LUMA = np.array([16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                  14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
                  49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99])


def luma_table_for_quality(quality: int) -> np.ndarray:
    """The luminance quantisation table libjpeg writes at ``quality`` (sorted)."""
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality
    return np.sort(np.clip((_LUMA * scale + 50) // 100, 1, 255))


def jpeg_luma_table(data: bytes) -> np.ndarray:
    """The first (luminance) 8-bit quantisation table in a JPEG's DQT segment (sorted)."""
    assert data[:3] == b"\xff\xd8\xff", "not a JPEG"
    i = 2
    while i < len(data):
        marker, length = data[i + 1], int.from_bytes(data[i + 2:i + 4], "big")
        if marker == 0xDB:
            assert data[i + 4] == 0, "expected an 8-bit table 0 first"
            return np.sort(np.frombuffer(data[i + 5:i + 5 + 64], dtype=np.uint8).astype(np.int64))
        i += 2 + length
    raise AssertionError("no DQT segment")
