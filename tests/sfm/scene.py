"""A small textured box room rendered by exact ray casting, for SfM tests with known poses.

World frame: metres, z up, floor at z = 0. The room is the box ``[0, X] x [0, Y] x [0, Z]``
seen from inside, with a few axis-aligned boxes standing on the floor. Every face carries its
own procedural texture (multi-scale noise plus discs), which gives SIFT plenty of blobs. The
camera walks an ellipse around the middle of the room looking inwards and down, like a
handheld capture. Images are rendered at 2x and box-filtered down (anti-aliased).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import look_at

ROOM_XYZ_M = (5.0, 4.0, 2.6)
# (lo_xyz, hi_xyz) of boxes standing on the floor.
BOXES = (
    ((0.6, 0.5, 0.0), (1.4, 1.1, 0.8)),
    ((3.7, 2.9, 0.0), (4.5, 3.6, 1.1)),
    ((3.9, 0.4, 0.0), (4.6, 1.0, 0.5)),
)
TEXELS_PER_M = 96.0


def _texture(rng: np.random.Generator, width_m: float, height_m: float) -> np.ndarray:
    """(H, W, 3) float32 texture in [0, 1] covering a face of the given size."""
    w, h = max(8, int(width_m * TEXELS_PER_M)), max(8, int(height_m * TEXELS_PER_M))
    out = np.zeros((h, w, 3), np.float32)
    for sigma, weight in ((1.0, 0.35), (3.0, 0.6), (9.0, 1.0)):
        noise = ndimage.gaussian_filter(rng.standard_normal((h, w, 3)), (sigma, sigma, 0), mode="wrap")
        out += weight * (noise / (noise.std() + 1e-9)).astype(np.float32)
    out = 0.5 + 0.12 * out
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(int(width_m * height_m * 12) + 3):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(3, 14)
        mask = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
        out[mask] = rng.uniform(0.0, 1.0, 3)
    return np.clip(out, 0.0, 1.0)


@dataclass(frozen=True)
class _Face:
    axis: int  # the face's normal axis
    coord: float  # plane: x[axis] == coord
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    texture: np.ndarray  # (H, W, 3) over the face's two in-plane axes (sorted order)


def _faces(seed: int) -> list[_Face]:
    rng = np.random.default_rng(seed)
    boxes = [((0.0, 0.0, 0.0), ROOM_XYZ_M)] + list(BOXES)
    faces = []
    for lo, hi in boxes:
        for axis in range(3):
            for coord in (lo[axis], hi[axis]):
                if coord == 0.0 and axis == 2 and lo != (0.0, 0.0, 0.0):
                    continue  # a box's bottom lies on the floor
                a, b = [i for i in range(3) if i != axis]
                tex = _texture(rng, hi[a] - lo[a], hi[b] - lo[b])
                faces.append(_Face(axis, coord, lo, hi, tex))
    return faces


def _bilinear(tex: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Sample tex (H, W, 3) at fractional texel coords (s along W, t along H), clamped."""
    h, w = tex.shape[:2]
    s = np.clip(s, 0, w - 1.001)
    t = np.clip(t, 0, h - 1.001)
    s0, t0 = np.floor(s).astype(int), np.floor(t).astype(int)
    fs, ft = (s - s0)[:, None], (t - t0)[:, None]
    return ((tex[t0, s0] * (1 - fs) + tex[t0, s0 + 1] * fs) * (1 - ft)
            + (tex[t0 + 1, s0] * (1 - fs) + tex[t0 + 1, s0 + 1] * fs) * ft)


class BoxRoom:
    """Ray caster over the textured room; ``render(camera, cam_to_world) -> (H, W, 3) uint8``."""

    def __init__(self, seed: int = 0):
        self.faces = _faces(seed)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest hit of (N, 3) rays: (depth_along_ray (N,), rgb (N, 3) float)."""
        n = len(origins)
        best_t = np.full(n, np.inf)
        best_face = np.full(n, -1)
        for k, f in enumerate(self.faces):
            d = dirs[:, f.axis]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (f.coord - origins[:, f.axis]) / d
            p = origins + t[:, None] * dirs
            ok = (t > 1e-6) & (t < best_t)
            for i in range(3):
                if i != f.axis:
                    ok &= (p[:, i] >= f.lo[i] - 1e-9) & (p[:, i] <= f.hi[i] + 1e-9)
            best_t = np.where(ok, t, best_t)
            best_face = np.where(ok, k, best_face)
        rgb = np.zeros((n, 3))
        for k, f in enumerate(self.faces):
            sel = best_face == k
            if not sel.any():
                continue
            p = origins[sel] + best_t[sel, None] * dirs[sel]
            a, b = [i for i in range(3) if i != f.axis]
            s = (p[:, a] - f.lo[a]) * TEXELS_PER_M
            t = (p[:, b] - f.lo[b]) * TEXELS_PER_M
            rgb[sel] = _bilinear(f.texture, s, t)
        return best_t, rgb

    def render(self, camera: Camera, cam_to_world: np.ndarray, supersample: int = 2) -> np.ndarray:
        big = camera.scaled(supersample)
        origins, dirs = big.pixel_rays(np.asarray(cam_to_world, dtype=np.float64))
        _, rgb = self.cast(origins.reshape(-1, 3), dirs.reshape(-1, 3))
        rgb = rgb.reshape(big.height, big.width, 3)
        rgb = rgb.reshape(camera.height, supersample, camera.width, supersample, 3).mean(axis=(1, 3))
        return np.rint(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def handheld_loop(n: int, *, height_m: float = 1.4, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) cam_to_world (OpenCV axes): one loop on an ellipse round the room's middle.

    The camera looks inwards, past the centre at a point 0.8 m high, so it sees the far walls,
    the floor and the boxes from all sides (an orbit gives parallax and pins the focal length).
    A little seeded jitter in height, heading and roll mimics a hand-held walk; the loop closes.
    """
    rng = np.random.default_rng(seed)
    cx, cy = ROOM_XYZ_M[0] / 2, ROOM_XYZ_M[1] / 2
    poses = []
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = np.array([cx + 1.3 * math.cos(a), cy + 0.9 * math.sin(a), height_m + rng.normal(0, 0.03)])
        b = a + math.pi + rng.normal(0, 0.03)  # inwards, jittered heading
        target = np.array([cx + 0.6 * math.cos(b), cy + 0.4 * math.sin(b), 0.8])
        up = np.array([rng.normal(0, 0.03), rng.normal(0, 0.03), 1.0])  # a little roll
        poses.append(look_at(eye, target, up))
    return np.stack(poses)


def room_diagonal_m() -> float:
    return float(np.linalg.norm(ROOM_XYZ_M))


def render_sequence(out_dir, camera: Camera, cam_to_world: np.ndarray, seed: int = 0) -> list[str]:
    """Render every pose to ``out_dir/frame_{i:05d}.png``; returns the file names."""
    from pathlib import Path

    from nsim.io.images import write_image

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    room = BoxRoom(seed)
    names = []
    for i, c2w in enumerate(cam_to_world):
        name = f"frame_{i:05d}.png"
        write_image(out / name, room.render(camera, c2w))
        names.append(name)
    return names
