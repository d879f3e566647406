"""Visibility culling of people's bounding boxes: the paper's Algorithm 1, corrected.

The paper (Algorithm 1) projects the 8 corners of a human's posed bounding box with ``K`` and
calls the box visible when some corner lands inside the image. That is wrong in three ways,
each reproduced by ``tests/rendering/test_culling.py`` against ``naive_corner_test``:

* a corner *behind* the camera projects through ``K`` with a flipped sign, so it can land in the
  image although nothing is visible (a false positive), and a box that straddles the image
  plane gets a 2D bound built from flipped points (wrong, usually too small);
* a box *larger than the image* (a person right in front of the lens) has every corner outside
  the image while it covers all of it (a false negative: the person vanishes);
* a box *surrounding the camera* has all corners outside the view (or behind) and fills the
  whole image (a false negative).

Corrected method, ``camera_box_bounds``:

PINHOLE (exact)
    each of the box's 6 faces is clipped (Sutherland-Hodgman) against the view frustum: the near
    plane ``z >= near_m`` and the four planes through the camera centre and the image edges. The
    clipped polygons bound ``box ∩ frustum``; under a pinhole projection straight lines stay
    straight, so the 2D bound is exactly the extent of their projected vertices.
OPENCV, OPENCV_FISHEYE, EQUIRECTANGULAR (conservative angular test)
    distortion bends edges and a fisheye sees beyond 90 deg, so frustum planes do not exist.
    The boundary of the visible region's image lies on (a) the images of the box's edges, (b) the
    image border where a border pixel's ray hits the box, (c) the rim of the model's valid cone
    (``Camera.max_angle_rad``) where such a ray hits the box. All three are sampled -- edges
    adaptively until consecutive projected samples are <= 0.5 px apart, border rays every
    0.5 px, the rim every 0.1 deg -- and the extent is grown by ``margin_px`` (default 1 px).
    A box across the equirectangular seam (longitude +-180 deg) gets the full image width.

Rays use a ray-box slab test on an oriented box (``ray_box_intervals``), which also serves the
LiDAR (``lidar_ray_box_mask``). Conventions (``nsim.geometry.conventions``): ``world_to_cam``
``(4, 4)`` with OpenCV camera axes; pixels ``(u, v)`` with the top-left pixel's centre at
``(0, 0)``, the image spanning ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``. A *bound* is
``(u0, v0, u1, v1)`` in those continuous pixel coordinates, inside that span; ``bounds_to_pixel_box``
turns it into the integer pixels to render. Box corners are ``(8, 3)`` with corner ``k`` at
``+x`` if bit 0 of ``k`` is set, ``+y`` if bit 1, ``+z`` if bit 2, in the box's own axes
(``OrientedBox.corners`` writes them so). Everything is float64 numpy and deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nsim.geometry.cameras import RADTAN_MODELS, Camera

Bounds = tuple[float, float, float, float]

#: The box's faces as corner-index cycles (see the corner order in the module docstring).
BOX_FACES = ((0, 2, 6, 4), (1, 3, 7, 5), (0, 1, 5, 4), (2, 3, 7, 6), (0, 1, 3, 2), (4, 5, 7, 6))
#: The box's 12 edges as corner-index pairs.
BOX_EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7))
_CORNER_SIGNS = np.array([[1 if k & 1 else -1, 1 if k & 2 else -1, 1 if k & 4 else -1] for k in range(8)], float)

MAX_EDGE_SAMPLES = 8192
EDGE_SPACING_PX = 0.5
BORDER_SPACING_PX = 0.5
RIM_SAMPLES = 3600


@dataclass(frozen=True, eq=False)
class OrientedBox:
    """A box in the world: centre ``(3,)``, half_extents ``(3,)`` >= 0 along its own axes, and
    rotation ``(3, 3)`` whose columns are those axes in world coordinates (box-to-world)."""

    center: np.ndarray
    half_extents: np.ndarray
    rotation: np.ndarray

    def __post_init__(self) -> None:
        for name, shape in (("center", (3,)), ("half_extents", (3,)), ("rotation", (3, 3))):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"OrientedBox.{name}: expected finite {shape}, got {value.shape}")
            object.__setattr__(self, name, value)
        if np.any(self.half_extents < 0.0):
            raise ValueError(f"OrientedBox.half_extents: must be >= 0, got {self.half_extents}")
        if np.abs(self.rotation.T @ self.rotation - np.eye(3)).max() > 1e-6:
            raise ValueError("OrientedBox.rotation: not orthonormal")

    @classmethod
    def from_min_max(cls, min_xyz, max_xyz, box_to_world: np.ndarray | None = None) -> OrientedBox:
        """The box ``[min_xyz, max_xyz]`` given in a local frame (e.g. the human's), posed by
        ``box_to_world (4, 4)`` (rigid; None = identity) -- the paper's ``(Min, Max)`` and ``T``."""
        lo, hi = np.asarray(min_xyz, dtype=np.float64), np.asarray(max_xyz, dtype=np.float64)
        if np.any(hi < lo):
            raise ValueError(f"from_min_max: max {hi} < min {lo}")
        T = np.eye(4) if box_to_world is None else np.asarray(box_to_world, dtype=np.float64)
        return cls(T[:3, :3] @ ((lo + hi) / 2.0) + T[:3, 3], (hi - lo) / 2.0, T[:3, :3])

    @classmethod
    def from_corners(cls, corners: np.ndarray, tol: float = 1e-6) -> OrientedBox:
        """The box with these corners ``(8, 3)`` in this module's order; ValueError if they are not a box."""
        c = np.asarray(corners, dtype=np.float64)
        if c.shape != (8, 3):
            raise ValueError(f"corners: expected shape (8, 3), got {c.shape}")
        edges = np.stack([c[1] - c[0], c[2] - c[0], c[4] - c[0]], axis=1)  # columns: full extents
        lengths = np.linalg.norm(edges, axis=0)
        axes = np.eye(3)
        for i in range(3):
            if lengths[i] > tol:
                axes[:, i] = edges[:, i] / lengths[i]
        if np.abs(axes.T @ axes - np.eye(3)).max() > 1e-6 or np.linalg.det(axes) < 0.0:
            raise ValueError("corners: not the corners of a box in the order of nsim.rendering.culling")
        box = cls(c.mean(axis=0), lengths / 2.0, axes)
        if np.abs(box.corners() - c).max() > tol * max(1.0, float(np.abs(c).max())) + tol:
            raise ValueError("corners: not the corners of a box in the order of nsim.rendering.culling")
        return box

    def corners(self) -> np.ndarray:
        """``(8, 3)`` world corners in this module's order."""
        return self.center + (_CORNER_SIGNS * self.half_extents) @ self.rotation.T

    def contains(self, points: np.ndarray) -> np.ndarray:
        """``(...,)`` bool: points ``(..., 3)`` inside or on the box."""
        local = (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation
        return np.all(np.abs(local) <= self.half_extents * (1 + 1e-12) + 1e-12, axis=-1)


def _as_box(box) -> OrientedBox:
    return box if isinstance(box, OrientedBox) else OrientedBox.from_corners(box)


def _transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ T[:3, :3].T + T[:3, 3]


# --------------------------------------------------------------------------------------
# Rays against a box (LiDAR, and the border/rim rays of the angular camera test)
# --------------------------------------------------------------------------------------


def ray_box_intervals(origins: np.ndarray, dirs: np.ndarray, box) -> tuple[np.ndarray, np.ndarray]:
    """Slab test of rays against an oriented box.

    origins, dirs: ``(N, 3)`` (dirs need not be unit; ``t`` is in units of ``|dir|``); box: an
    ``OrientedBox`` or its ``(8, 3)`` corners. Returns ``t_enter, t_exit (N,)``: the ray's points
    ``o + t d`` with ``t_enter <= t <= t_exit`` are in the box; a miss has ``t_enter > t_exit``
    (``+inf, -inf`` for a ray parallel to a slab it lies outside). A ray starting inside has
    ``t_enter < 0 <= t_exit``.
    """
    box = _as_box(box)
    o = (np.asarray(origins, dtype=np.float64) - box.center) @ box.rotation  # box frame
    d = np.asarray(dirs, dtype=np.float64) @ box.rotation
    if o.shape != d.shape or o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins, dirs: expected equal shapes (N, 3), got {o.shape}, {d.shape}")
    h = box.half_extents
    parallel = d == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(parallel, 1.0, d)
        t0 = (-h - o) * inv
        t1 = (h - o) * inv
    inside_slab = np.abs(o) <= h
    lo = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), np.minimum(t0, t1))
    hi = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), np.maximum(t0, t1))
    return lo.max(axis=1), hi.min(axis=1)


def lidar_ray_box_mask(
    origins: np.ndarray, dirs: np.ndarray, box, t_min: float = 0.0, t_max: float = math.inf
) -> np.ndarray:
    """``(N,)`` bool: which rays ``origins, dirs (N, 3)`` pass through the box within ``[t_min, t_max]``.

    box: an ``OrientedBox`` or ``(8, 3)`` corners. For a LiDAR, ``origins, dirs`` come from
    ``LidarSensor.rays`` (unit dirs, so ``t`` is metres: pass the sensor's min/max range).
    """
    t_enter, t_exit = ray_box_intervals(origins, dirs, box)
    return (t_exit >= np.maximum(t_enter, t_min)) & (t_enter <= t_max)


# --------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------


def _clip_polygon(poly: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of polygon ``(K, 3)`` with ``plane[:3] . p + plane[3] >= 0``."""
    if len(poly) == 0:
        return poly
    s = poly @ plane[:3] + plane[3]
    out = []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if s[i] >= 0.0:
            out.append(poly[i])
        if (s[i] >= 0.0) != (s[j] >= 0.0):
            t = s[i] / (s[i] - s[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.array(out).reshape(-1, 3)


def _pinhole_bounds(camera: Camera, corners_cam: np.ndarray, near_m: float) -> Bounds | None:
    a = (-0.5 - camera.cx) / camera.fx
    b = (camera.width - 0.5 - camera.cx) / camera.fx
    c = (-0.5 - camera.cy) / camera.fy
    d = (camera.height - 0.5 - camera.cy) / camera.fy
    planes = np.array(
        [[0, 0, 1, -near_m], [1, 0, -a, 0], [-1, 0, b, 0], [0, 1, -c, 0], [0, -1, d, 0]], dtype=np.float64
    )
    verts = []
    for face in BOX_FACES:
        poly = corners_cam[list(face)]
        for plane in planes:
            poly = _clip_polygon(poly, plane)
        verts.append(poly)
    pts = np.concatenate(verts)
    if len(pts) == 0:
        return None
    u = camera.fx * pts[:, 0] / pts[:, 2] + camera.cx
    v = camera.fy * pts[:, 1] / pts[:, 2] + camera.cy
    return _clip_bounds(camera, (u.min(), v.min(), u.max(), v.max()), 0.0)


def _clip_bounds(camera: Camera, b: Bounds, margin_px: float) -> Bounds:
    w, h = camera.width - 0.5, camera.height - 0.5
    return (
        float(np.clip(b[0] - margin_px, -0.5, w)),
        float(np.clip(b[1] - margin_px, -0.5, h)),
        float(np.clip(b[2] + margin_px, -0.5, w)),
        float(np.clip(b[3] + margin_px, -0.5, h)),
    )


def _in_domain(camera: Camera, p: np.ndarray, max_angle_rad: float) -> np.ndarray:
    """Camera-frame points ``(N, 3)`` that the model projects uniquely (in front, within ``max_angle_rad``)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if camera.model == "EQUIRECTANGULAR":
        return (x * x + y * y + z * z) > 0.0
    theta = np.arctan2(np.hypot(x, y), z)
    ok = theta < max_angle_rad
    if camera.model != "OPENCV_FISHEYE":
        ok &= z > 0.0
    return ok


def _edge_samples(camera: Camera, a: np.ndarray, b: np.ndarray, max_angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along segment a-b (camera frame) until consecutive in-domain projections are <= 0.5 px apart.

    Returns the projected ``uv (K, 2)`` and a ``keep (K,)`` mask (in domain and inside the image).
    """
    n = 65
    while True:
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts = a + t * (b - a)
        uv, inside = camera.project(pts)
        dom = _in_domain(camera, pts, max_angle_rad)
        # gaps matter only next to the image: the border rays cover where an edge leaves it
        both = dom[1:] & dom[:-1] & (inside[1:] | inside[:-1])
        gap = float(np.linalg.norm(np.diff(uv, axis=0), axis=1)[both].max()) if both.any() else 0.0
        if gap <= EDGE_SPACING_PX or n >= MAX_EDGE_SAMPLES:
            return uv, inside & dom
        n = min(MAX_EDGE_SAMPLES, int(math.ceil(n * gap / EDGE_SPACING_PX)) + 1)


def _border_pixels(camera: Camera) -> np.ndarray:
    """``(K, 2)`` pixel positions along the image's outer border, at most 0.5 px apart."""
    w, h = camera.width - 0.5, camera.height - 0.5
    us = np.linspace(-0.5, w, int(math.ceil(camera.width / BORDER_SPACING_PX)) + 1)
    vs = np.linspace(-0.5, h, int(math.ceil(camera.height / BORDER_SPACING_PX)) + 1)
    return np.concatenate(
        [
            np.stack([us, np.full_like(us, -0.5)], 1),
            np.stack([us, np.full_like(us, h)], 1),
            np.stack([np.full_like(vs, -0.5), vs], 1),
            np.stack([np.full_like(vs, w), vs], 1),
        ]
    )


def _rim_dirs(camera: Camera) -> np.ndarray:
    """Directions ``(K, 3)`` just inside the rim of the model's valid cone (none for EQUIRECTANGULAR)."""
    if camera.model in ("EQUIRECTANGULAR", "PINHOLE"):
        return np.zeros((0, 3))
    theta = camera.max_angle_rad * (1.0 - 1e-9)
    if camera.model in RADTAN_MODELS and theta >= math.pi / 2:
        return np.zeros((0, 3))
    psi = np.linspace(0.0, 2.0 * math.pi, RIM_SAMPLES, endpoint=False)
    return np.stack([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi), np.full_like(psi, math.cos(theta))], 1)


def _angular_bounds(camera: Camera, box: OrientedBox, near_m: float, margin_px: float) -> Bounds | None:
    """Sampled bound of a box given in the camera frame (see the module docstring)."""
    corners_cam = box.corners()
    max_angle = camera.max_angle_rad
    uvs = []
    for i, j in BOX_EDGES:
        uv, keep = _edge_samples(camera, corners_cam[i], corners_cam[j], max_angle)
        uvs.append(uv[keep])
    border = _border_pixels(camera)
    dirs = camera.unproject(border)
    if camera.model == "EQUIRECTANGULAR":
        valid = np.ones(len(border), dtype=bool)
    else:  # border pixels beyond the model's valid cone have no ray (unproject clamps them)
        uv_back, _ = camera.project(dirs)
        valid = np.linalg.norm(uv_back - border, axis=1) < 1e-3
    hit = lidar_ray_box_mask(np.zeros_like(dirs), dirs, box, t_min=near_m)
    uvs.append(border[valid & hit])
    rim = _rim_dirs(camera)
    if len(rim):
        uv_rim, inside = camera.project(rim)
        hit = lidar_ray_box_mask(np.zeros_like(rim), rim, box, t_min=near_m)
        uvs.append(uv_rim[inside & hit])
    pts = np.concatenate(uvs)
    if len(pts) == 0:
        return None
    return _clip_bounds(camera, (pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()), margin_px)


def camera_box_bounds(
    camera: Camera, world_to_cam: np.ndarray, box_corners, near_m: float = 1e-6, margin_px: float = 1.0
) -> Bounds | None:
    """The 2D pixel bound of the part of a box the camera sees, or None if it sees none of it.

    camera: intrinsics; world_to_cam: ``(4, 4)`` rigid, OpenCV camera axes; box_corners: ``(8, 3)``
    world corners (this module's order) or an ``OrientedBox``. near_m: points nearer than this along
    the optical axis do not count (PINHOLE; the sampled models only ignore border/rim ray hits
    nearer than this along the ray, which keeps them conservative). margin_px: growth of the
    sampled (non-PINHOLE) bound; PINHOLE bounds are exact. Returns ``(u0, v0, u1, v1)`` within
    ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``: every point of the box that projects into the image
    projects inside it. See the module docstring for the method.
    """
    T = np.asarray(world_to_cam, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"world_to_cam: expected shape (4, 4), got {T.shape}")
    box = _as_box(box_corners)
    box_cam = OrientedBox(_transform(T, box.center), box.half_extents, T[:3, :3] @ box.rotation)
    if camera.model == "PINHOLE":
        return _pinhole_bounds(camera, box_cam.corners(), near_m)
    return _angular_bounds(camera, box_cam, near_m, margin_px)


def pixels_in_bounds(camera: Camera, bounds: Bounds) -> np.ndarray:
    """``(H * W,)`` bool, row-major: the pixels whose centre (whole-number coordinates, the bound's own)
    lies in ``bounds``. A pixel ray meets the box only if its centre projects inside the bound, so
    these are exactly the camera rays that can meet it."""
    u0, v0, u1, v1 = bounds
    centres = camera.pixel_centres()
    uu, vv = centres[..., 0], centres[..., 1]
    return ((uu >= u0) & (uu <= u1) & (vv >= v0) & (vv <= v1)).reshape(-1)


def bounds_to_pixel_box(camera: Camera, bounds: Bounds | None) -> tuple[int, int, int, int] | None:
    """Integer pixels to render for a bound: ``(col0, row0, col1, row1)``, half-open (``col1``,
    ``row1`` excluded), every pixel whose footprint ``[u - 0.5, u + 0.5]`` meets the bound.
    Use as ``image[row0:row1, col0:col1]``. None for None."""
    if bounds is None:
        return None
    u0, v0, u1, v1 = bounds
    col0 = max(0, math.floor(u0 + 0.5))
    row0 = max(0, math.floor(v0 + 0.5))
    col1 = min(camera.width, math.floor(u1 + 0.5) + 1)
    row1 = min(camera.height, math.floor(v1 + 0.5) + 1)
    return col0, row0, col1, row1


# --------------------------------------------------------------------------------------
# The paper's original, for comparison
# --------------------------------------------------------------------------------------


def _naive_project(camera: Camera, world_to_cam: np.ndarray, box_corners) -> np.ndarray:
    corners = _as_box(box_corners).corners()
    p = _transform(np.asarray(world_to_cam, dtype=np.float64), corners)
    uvw = p @ camera.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return uvw[:, :2] / uvw[:, 2:3]


def naive_corner_test(camera: Camera, world_to_cam: np.ndarray, box_corners) -> bool:
    """The paper's Algorithm 1 as written: visible iff some corner's ``K p`` (divided by its z,
    whatever its sign) lands in ``0 <= u < W, 0 <= v < H``. Wrong in the cases of the module docstring."""
    uv = _naive_project(camera, world_to_cam, box_corners)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    return bool(inside.any())


def naive_corner_bounds(camera: Camera, world_to_cam: np.ndarray, box_corners) -> Bounds | None:
    """The bound a corner-only implementation would use: the extent of the 8 projected corners,
    clipped to the image, when ``naive_corner_test`` says visible; else None."""
    if not naive_corner_test(camera, world_to_cam, box_corners):
        return None
    uv = _naive_project(camera, world_to_cam, box_corners)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    return _clip_bounds(camera, (uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()), 0.0)
