"""Textures for the test room from real photographs shipped with scikit-image.

Only photos that load offline from the scikit-image wheel are used (``PHOTO_NAMES``; the
others in ``skimage.data`` need a pooch download). Photos become float32 RGB in [0, 1]
(grey ones replicated to three channels).

Texture coordinates are in metres: texel ``(row i, column j)`` of a texture laid out at
``metres_per_texel`` has its centre at ``uv_m = ((j + 0.5), (i + 0.5)) * metres_per_texel``
(``u`` along columns, ``v`` along rows).

``bake_room_textures(spec)`` turns a ``RoomSpec`` into one image per face (the material's
photo tiled with seeded flips so it does not repeat exactly, posters pasted onto walls) with
a mip pyramid, all packed into a flat texel buffer that ``sample_faces`` reads with
bilinear (or trilinear, by footprint) filtering, fully vectorised over rays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache, lru_cache

import cv2
import numpy as np

from nsim.synth.room import WALL_SURFACE_IDS, Face, RoomSpec, room_faces

# name -> skimage.data loader; all ship inside the scikit-image wheel (checked offline, skimage 0.26).
_PHOTO_LOADERS = {
    "astronaut": "astronaut",
    "brick": "brick",
    "camera": "camera",
    "chelsea": "chelsea",
    "coffee": "coffee",
    "coins": "coins",
    "grass": "grass",
    "gravel": "gravel",
    "hubble_deep_field": "hubble_deep_field",
    "immunohistochemistry": "immunohistochemistry",
    "page": "page",
    "retina": "retina",
    "rocket": "rocket",
    "stereo_motorcycle": "stereo_motorcycle",  # the left image
    "text": "text",
}
PHOTO_NAMES: tuple[str, ...] = tuple(_PHOTO_LOADERS)

MAX_MIP_LEVELS = 12
POSTER_FRAME_M = 0.015
_POSTER_FRAME_RGB = (0.08, 0.08, 0.08)


@cache
def _load_photo_cached(name: str) -> np.ndarray:
    import skimage.data

    image = getattr(skimage.data, _PHOTO_LOADERS[name])()
    if isinstance(image, tuple):
        image = image[0]
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    image = image[..., :3].astype(np.float32) / 255.0
    image.setflags(write=False)
    return image


def load_photo(name: str) -> np.ndarray:
    """A photo as float32 RGB ``(H, W, 3)`` in [0, 1] (read-only, cached). ValueError for unknown names."""
    if name not in _PHOTO_LOADERS:
        raise ValueError(f"unknown texture photo {name!r}; valid: {', '.join(PHOTO_NAMES)}")
    return _load_photo_cached(name)


def sample_texture(tex: np.ndarray, uv_m: np.ndarray, metres_per_texel: float, mode: str = "wrap") -> np.ndarray:
    """Bilinear lookup of ``tex (Ht, Wt, C)`` at texture coordinates ``uv_m (N, 2)`` metres.

    ``mode="wrap"`` tiles the texture infinitely; ``"clamp"`` repeats its border texels.
    Returns ``(N, C)`` float32. At texel centres the result is exactly that texel.
    """
    if mode not in ("wrap", "clamp"):
        raise ValueError(f"sample_texture: mode must be 'wrap' or 'clamp', got {mode!r}")
    tex = np.asarray(tex)
    uv = np.asarray(uv_m, dtype=np.float64)
    if tex.ndim != 3 or uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"sample_texture: expected tex (Ht, Wt, C), uv_m (N, 2), got {tex.shape}, {uv.shape}")
    if not metres_per_texel > 0.0:
        raise ValueError(f"sample_texture: metres_per_texel must be > 0, got {metres_per_texel!r}")
    height, width = tex.shape[:2]
    x = uv[:, 0] / metres_per_texel - 0.5
    y = uv[:, 1] / metres_per_texel - 0.5
    x0f, y0f = np.floor(x), np.floor(y)
    fx = (x - x0f).astype(np.float32)[:, None]
    fy = (y - y0f).astype(np.float32)[:, None]
    x0, y0 = x0f.astype(np.int64), y0f.astype(np.int64)
    x1, y1 = x0 + 1, y0 + 1
    if mode == "wrap":
        x0, x1, y0, y1 = x0 % width, x1 % width, y0 % height, y1 % height
    else:
        x0, x1 = np.clip(x0, 0, width - 1), np.clip(x1, 0, width - 1)
        y0, y1 = np.clip(y0, 0, height - 1), np.clip(y1, 0, height - 1)
    t = tex.astype(np.float32, copy=False)
    top = t[y0, x0] * (1 - fx) + t[y0, x1] * fx
    bottom = t[y1, x0] * (1 - fx) + t[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


# ----------------------------------------------------------------------------------------------
# Baked per-face textures.


@dataclass(frozen=True)
class RoomTextures:
    """All faces of a room, baked: face ``f`` at mip level ``l`` is an image of
    ``level_shape[f, l] = (height, width)`` texels starting at ``texels[level_offset[f, l]]``,
    row-major, spanning the face exactly (``texels_per_m[f, l] = (along u, along v)``).
    Faces with fewer levels repeat their coarsest level up to ``n_levels``.

    texels: (T,) uint32, RGB packed as ``r | g << 8 | b << 16`` (8-bit albedo).
    """

    texels: np.ndarray
    level_offset: np.ndarray  # (F, L) int64
    level_shape: np.ndarray  # (F, L, 2) int64
    texels_per_m: np.ndarray  # (F, L, 2) float64

    @property
    def n_faces(self) -> int:
        return self.level_offset.shape[0]

    @property
    def n_levels(self) -> int:
        return self.level_offset.shape[1]

    def face_image(self, face: int, level: int = 0) -> np.ndarray:
        """Face ``face`` at mip ``level`` as float32 RGB ``(h, w, 3)`` (for inspection and tests)."""
        h, w = self.level_shape[face, level]
        off = self.level_offset[face, level]
        return _unpack_rgb(self.texels[off:off + h * w]).reshape(h, w, 3)


def _unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """(N,) uint32 -> (N, 3) float32 in [0, 1]."""
    rgb = np.empty(packed.shape + (3,), dtype=np.float32)
    rgb[..., 0] = packed & 0xFF
    rgb[..., 1] = (packed >> 8) & 0xFF
    rgb[..., 2] = (packed >> 16) & 0xFF
    rgb *= np.float32(1.0 / 255.0)
    return rgb


def _pack_rgb(rgb_u8: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 -> (H * W,) uint32 ``r | g << 8 | b << 16``."""
    rgba = np.zeros(rgb_u8.shape[:2] + (4,), dtype=np.uint8)
    rgba[..., :3] = rgb_u8
    return rgba.reshape(-1).view("<u4").astype(np.uint32, copy=False)


def material_albedo(texture: str, tint_rgb: tuple[float, float, float], contrast: float) -> np.ndarray:
    """The photo with contrast and tint applied, quantised: uint8 ``(H, W, 3)`` (read-only, cached)."""
    return _material_albedo_cached(texture, tuple(float(c) for c in tint_rgb), float(contrast))


@lru_cache(maxsize=64)
def _material_albedo_cached(texture: str, tint_rgb: tuple[float, float, float], contrast: float) -> np.ndarray:
    photo = load_photo(texture)
    mean = photo.mean(axis=(0, 1), keepdims=True)
    albedo = (mean + np.float32(contrast) * (photo - mean)) * np.asarray(tint_rgb, dtype=np.float32)
    out = _to_u8(albedo)
    out.setflags(write=False)
    return out


def _to_u8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)


def _tiled(albedo: np.ndarray, height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """Cover ``(height, width)`` with copies of ``albedo``, each flipped at random, from a random offset."""
    th, tw = albedo.shape[:2]
    oy, ox = int(rng.integers(th)), int(rng.integers(tw))
    rows, cols = math.ceil((height + oy) / th), math.ceil((width + ox) / tw)
    flips = rng.integers(4, size=(rows, cols))
    variants = [albedo, albedo[:, ::-1], albedo[::-1], albedo[::-1, ::-1]]
    out = np.empty((height, width, 3), dtype=albedo.dtype)
    for r in range(rows):
        y0, y1 = max(r * th - oy, 0), min((r + 1) * th - oy, height)  # output rows of tile r
        for c in range(cols):
            x0, x1 = max(c * tw - ox, 0), min((c + 1) * tw - ox, width)
            src = variants[flips[r, c]]
            out[y0:y1, x0:x1] = src[y0 + oy - r * th:y1 + oy - r * th, x0 + ox - c * tw:x1 + ox - c * tw]
    return out


def _centre_crop(image: np.ndarray, aspect_w_over_h: float) -> np.ndarray:
    h, w = image.shape[:2]
    if w / h > aspect_w_over_h:
        new_w = max(1, round(h * aspect_w_over_h))
        x0 = (w - new_w) // 2
        return image[:, x0:x0 + new_w]
    new_h = max(1, round(w / aspect_w_over_h))
    y0 = (h - new_h) // 2
    return image[y0:y0 + new_h]


def _face_image(spec: RoomSpec, face_idx: int, face: Face) -> np.ndarray:
    """Level-0 albedo ``(h, w, 3)`` uint8 of one face: tiled material, plus posters on walls."""
    m = face.material
    size_u, size_v = face.size_uv_m
    width = max(1, round(size_u / m.metres_per_texel))
    height = max(1, round(size_v / m.metres_per_texel))
    rng = np.random.default_rng([spec.seed, face_idx])
    image = _tiled(material_albedo(m.texture, m.tint_rgb, m.contrast), height, width, rng)
    if face.surface_id in WALL_SURFACE_IDS:
        z_top = spec.size_xyz_m[2]
        tpm_u, tpm_v = width / size_u, height / size_v
        for p in spec.posters:
            if p.surface_id != face.surface_id:
                continue
            u0, u1 = p.centre_u_m - p.width_m / 2, p.centre_u_m + p.width_m / 2
            v0, v1 = z_top - (p.centre_z_m + p.height_m / 2), z_top - (p.centre_z_m - p.height_m / 2)
            c0, c1 = round(u0 * tpm_u), round(u1 * tpm_u)
            r0, r1 = round(v0 * tpm_v), round(v1 * tpm_v)
            frame = max(1, round(POSTER_FRAME_M * tpm_u))
            image[r0:r1, c0:c1] = _to_u8(np.asarray(_POSTER_FRAME_RGB))
            inner_h, inner_w = r1 - r0 - 2 * frame, c1 - c0 - 2 * frame
            if inner_h > 0 and inner_w > 0:
                photo = _to_u8(_centre_crop(load_photo(p.texture), inner_w / inner_h))
                image[r0 + frame:r1 - frame, c0 + frame:c1 - frame] = cv2.resize(
                    photo, (inner_w, inner_h), interpolation=cv2.INTER_AREA
                )
    return image


def bake_room_textures(spec: RoomSpec) -> RoomTextures:
    """Bake every face of ``spec`` (``room_faces`` order) with its mip pyramid. Deterministic.

    Unknown photo names raise ValueError. Albedo is quantised to 8 bits per channel.
    """
    faces = room_faces(spec)
    pyramids: list[list[np.ndarray]] = []
    for f, face in enumerate(faces):
        level = _face_image(spec, f, face)
        levels = [level]
        while len(levels) < MAX_MIP_LEVELS and max(level.shape[:2]) > 1:
            h, w = level.shape[:2]
            level = cv2.resize(level, (max(1, (w + 1) // 2), max(1, (h + 1) // 2)), interpolation=cv2.INTER_AREA)
            level = level.reshape(level.shape[0], level.shape[1], 3)
            levels.append(level)
        pyramids.append(levels)
    n_levels = max(len(p) for p in pyramids)
    offsets = np.zeros((len(faces), n_levels), dtype=np.int64)
    shapes = np.zeros((len(faces), n_levels, 2), dtype=np.int64)
    tpm = np.zeros((len(faces), n_levels, 2), dtype=np.float64)
    chunks, total = [], 0
    for f, (face, levels) in enumerate(zip(faces, pyramids, strict=True)):
        for lvl in range(n_levels):
            image = levels[min(lvl, len(levels) - 1)]
            if lvl < len(levels):
                chunks.append(_pack_rgb(image))
                offsets[f, lvl] = total
                total += image.shape[0] * image.shape[1]
            else:
                offsets[f, lvl] = offsets[f, lvl - 1]
            shapes[f, lvl] = image.shape[:2]
            tpm[f, lvl] = (image.shape[1] / face.size_uv_m[0], image.shape[0] / face.size_uv_m[1])
    texels = np.concatenate(chunks)
    for a in (texels, offsets, shapes, tpm):
        a.setflags(write=False)
    return RoomTextures(texels=texels, level_offset=offsets, level_shape=shapes, texels_per_m=tpm)


def _bilinear_faces(tex: RoomTextures, face: np.ndarray, level: np.ndarray, u_m: np.ndarray,
                    v_m: np.ndarray) -> np.ndarray:
    """Bilinear, edge-clamped lookup of face ``face (N,)`` at mip ``level (N,)``: (N, 3) float32."""
    off = tex.level_offset[face, level]
    h = tex.level_shape[face, level, 0]
    w = tex.level_shape[face, level, 1]
    x = u_m * tex.texels_per_m[face, level, 0] - 0.5
    y = v_m * tex.texels_per_m[face, level, 1] - 0.5
    x0f, y0f = np.floor(x), np.floor(y)
    fx = (x - x0f).astype(np.float32)[:, None]
    fy = (y - y0f).astype(np.float32)[:, None]
    x0 = x0f.astype(np.int64)
    y0 = y0f.astype(np.int64)
    wm1, hm1 = w - 1, h - 1
    x1 = np.clip(x0 + 1, 0, wm1)
    x0 = np.clip(x0, 0, wm1)
    y1 = np.clip(y0 + 1, 0, hm1) * w + off
    y0 = np.clip(y0, 0, hm1) * w + off
    t = tex.texels
    top = _unpack_rgb(t[y0 + x0]) * (1 - fx) + _unpack_rgb(t[y0 + x1]) * fx
    bottom = _unpack_rgb(t[y1 + x0]) * (1 - fx) + _unpack_rgb(t[y1 + x1]) * fx
    return top * (1 - fy) + bottom * fy


def sample_faces(tex: RoomTextures, face: np.ndarray, uv_m: np.ndarray,
                 footprint_m: np.ndarray | None = None) -> np.ndarray:
    """Albedo of faces ``face (N,)`` int at texture coordinates ``uv_m (N, 2)``: ``(N, 3)`` float32.

    footprint_m: ``(N,)`` side length in metres of each ray's footprint on the surface, or
    None for plain bilinear filtering of the full-resolution texture. With a footprint the
    lookup is trilinear: the mip level is ``log2(footprint * texels per metre)``, blended
    between the two nearest levels.
    """
    face = np.asarray(face, dtype=np.int64)
    u, v = uv_m[:, 0], uv_m[:, 1]
    if footprint_m is None:
        return _bilinear_faces(tex, face, np.zeros_like(face), u, v)
    texels = np.asarray(footprint_m, dtype=np.float64) * np.sqrt(
        tex.texels_per_m[face, 0, 0] * tex.texels_per_m[face, 0, 1]
    )
    lod = np.clip(np.log2(np.maximum(texels, 1e-12)), 0.0, tex.n_levels - 1)
    lod = np.nan_to_num(lod, nan=0.0)
    lo = np.floor(lod).astype(np.int64)
    hi = np.minimum(lo + 1, tex.n_levels - 1)
    frac = (lod - lo).astype(np.float32)[:, None]
    return _bilinear_faces(tex, face, lo, u, v) * (1 - frac) + _bilinear_faces(tex, face, hi, u, v) * frac
