"""Camera intrinsics: pinhole, OpenCV radial-tangential (plain and rational), Kannala-Brandt fisheye, equirectangular.

Every projection method takes numpy arrays *or* torch tensors and returns the same kind (torch:
same device and dtype, differentiable). Pixel coordinates follow OpenCV: ``(u, v)`` = (column,
row), the *centre* of the top-left pixel is ``(0, 0)`` and the image spans
``[-0.5, W - 0.5] x [-0.5, H - 0.5]``, so results compare directly with ``cv2.projectPoints``.
COLMAP and nerfstudio put that centre at ``(0.5, 0.5)``: their ``cx, cy`` are ours + 0.5, and
the readers/writers in ``nsim/io`` convert (``nsim.geometry.conventions.principal_point_*``);
``Camera.cx, cy`` are always OpenCV. Camera axes are OpenCV: +x right, +y down, +z forward.

Models (names as in COLMAP / nerfstudio), with normalised coordinates ``(x/z, y/z)``:

``PINHOLE``
    ``u = fx x/z + cx``, ``v = fy y/z + cy``; ``dist == ()``.
``OPENCV``
    radial-tangential distortion of ``(x/z, y/z)`` with ``dist = (k1, k2, p1, p2, k3)``
    (a 4-tuple is accepted and gets ``k3 = 0``), exactly as ``cv2.projectPoints``.
``FULL_OPENCV``
    OpenCV's rational model (``cv2.CALIB_RATIONAL_MODEL``; ROS's ``rational_polynomial``) with
    ``dist = (k1, k2, p1, p2, k3, k4, k5, k6)``, OpenCV's order: with ``r^2 = x^2 + y^2`` of the
    normalised point, ``radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``,
    then ``xd = x radial + 2 p1 x y + p2 (r^2 + 2 x^2)``, ``yd = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y``,
    exactly as ``cv2.projectPoints`` with an 8-coefficient vector. COLMAP's ``FULL_OPENCV`` has
    the same parameters (``fx, fy, cx, cy`` then these eight).
``OPENCV_FISHEYE``
    Kannala-Brandt as ``cv2.fisheye``: ``theta`` = angle from +z,
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
    ``u = fx theta_d x / r + cx`` with ``r = sqrt(x^2 + y^2)``; ``dist = (k1, k2, k3, k4)``.
    Unlike ``cv2.fisheye`` it also handles ``theta >= 90 deg`` (points behind the image plane).
``EQUIRECTANGULAR``
    full sphere: longitude ``atan2(x, z)`` in ``[-pi, pi]`` across the width, latitude
    ``atan2(y, hypot(x, z))`` in ``[-pi/2, pi/2]`` down the height (top row looks along -y).
    ``u = fx lon + cx``, ``v = fy lat + cy`` with the intrinsics *derived from the size*
    (``fx = W / 2pi``, ``fy = H / pi``, centred); values passed in are replaced.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.polynomial.polynomial as P

from nsim.geometry.array_kind import is_tensor, namespace, no_grad

if TYPE_CHECKING:
    import torch

    Array = np.ndarray | torch.Tensor

MODELS = ("PINHOLE", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE", "EQUIRECTANGULAR")
#: The models with OpenCV's radial-tangential distortion of ``(x/z, y/z)`` (plain and rational).
RADTAN_MODELS = ("OPENCV", "FULL_OPENCV")
_DIST_LENGTHS = {"PINHOLE": (0,), "OPENCV": (4, 5), "FULL_OPENCV": (8,), "OPENCV_FISHEYE": (4,), "EQUIRECTANGULAR": (0,)}
_DIST_NAMES = {"OPENCV": "(k1, k2, p1, p2[, k3])", "FULL_OPENCV": "(k1, k2, p1, p2, k3, k4, k5, k6)",
               "OPENCV_FISHEYE": "(k1, k2, k3, k4)"}
#: Newton iterations for undistortion. Quadratic convergence: strong distortion (k1 = -0.3 at the
#: corners of a 1920x1080 image) reaches 1e-12 px after 5; the rest is margin.
NEWTON_ITERS = 10
_TINY = 1e-30  # floor for squared radii under sqrt (keeps gradients finite at the optical axis)
_Z_MIN = 1e-12  # points with z <= this are "behind" a pinhole/OpenCV camera


def _as_float(x, name: str, tail: tuple[int, ...]) -> Array:
    """Tensors stay tensors (ints become the default float dtype), the rest floating numpy; checks ``(..., *tail)``."""
    if is_tensor(x):
        if not x.is_floating_point():
            import torch

            x = x.to(torch.get_default_dtype())
    else:
        x = np.asarray(x)
        if not np.issubdtype(x.dtype, np.floating):
            x = x.astype(np.float64)
    if x.ndim < len(tail) or tuple(x.shape[-len(tail):]) != tail:
        raise ValueError(f"{name}: expected shape (..., {', '.join(map(str, tail))}), got {tuple(x.shape)}")
    return x


def _detach(x: Array) -> Array:
    return x.detach() if is_tensor(x) else x


def _first_positive_root(coeffs_low_to_high) -> float:
    """Smallest positive real root of a polynomial given by ascending coefficients, or inf."""
    c = np.trim_zeros(np.asarray(coeffs_low_to_high, dtype=np.float64)[::-1], "f")
    if c.size <= 1:
        return math.inf
    roots = np.roots(c)
    real = roots.real[np.abs(roots.imag) <= 1e-9 * (1.0 + np.abs(roots.real))]
    positive = real[real > 0.0]
    return float(positive.min()) if positive.size else math.inf


#: The direction given to pixels a model cannot unproject when a caller asks for a finite ray
#: (``fill_invalid``): straight ahead, camera axes. Such pixels are still invalid and must be masked.
FORWARD_DIR = (0.0, 0.0, 1.0)


def fill_invalid_dirs(dirs_cam: Array) -> tuple[Array, Array]:
    """``dirs_cam (..., 3)`` with non-finite rows replaced by ``FORWARD_DIR``, and the validity mask ``(...,)``.

    Numpy or torch (same kind, dtype and device back); the input is not modified.
    """
    if is_tensor(dirs_cam):
        import torch

        valid = torch.isfinite(dirs_cam).all(-1)
        fwd = torch.tensor(FORWARD_DIR, dtype=dirs_cam.dtype, device=dirs_cam.device)
        return torch.where(valid[..., None], dirs_cam, fwd), valid
    dirs_cam = np.asarray(dirs_cam)
    valid = np.isfinite(dirs_cam).all(-1)
    return np.where(valid[..., None], dirs_cam, np.asarray(FORWARD_DIR, dtype=dirs_cam.dtype)), valid


def dirs_to_world(dirs_cam: Array, cam_to_world: Array, *, normalize: bool = True) -> tuple[Array, Array]:
    """World-frame ray origins and directions from camera-axes directions (the camera-to-world rotation).

    dirs_cam: ``(R, 3)``; cam_to_world: ``(4, 4)`` (one pose for all rays) or ``(R, 4, 4)`` (a pose a
    ray), OpenCV axes, numpy or torch like ``dirs_cam``. Returns origins (a broadcast view of the
    translation) and directions ``(R, 3)``, re-normalised to unit length with ``normalize``
    (a pose refined by a learnt correction may not be exactly rigid).
    """
    xp = namespace(dirs_cam)
    if cam_to_world.ndim == 2:
        dirs = dirs_cam @ cam_to_world[:3, :3].T
    else:
        dirs = xp.einsum("rij,rj->ri", cam_to_world[:, :3, :3], dirs_cam)
    if xp is not np:
        if normalize:
            dirs = dirs / xp.linalg.vector_norm(dirs, dim=-1, keepdim=True)
        return cam_to_world[..., :3, 3].expand_as(dirs), dirs
    if normalize:
        dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    return np.broadcast_to(cam_to_world[..., :3, 3], dirs.shape), dirs


@dataclass(frozen=True)
class Camera:
    """Intrinsics of one camera; see the module docstring for the models and pixel convention.

    ``fx, fy, cx, cy`` are in pixels (OpenCV pixel centres). Construction validates and
    normalises: sizes become ``int``, intrinsics ``float``, ``dist`` a tuple of floats (OPENCV
    always 5 long, FULL_OPENCV 8). Invalid arguments raise ``ValueError``.
    """

    model: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.model not in MODELS:
            raise ValueError(f"Camera.model: unknown camera model {self.model!r}, expected one of {MODELS}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ValueError(f"Camera.{name}: expected an integer, got {value!r}")
            if value <= 0:
                raise ValueError(f"Camera.{name}: must be > 0, got {value}")
            put(name, int(value))
        if self.model == "EQUIRECTANGULAR":
            put("fx", self.width / (2.0 * math.pi))
            put("fy", self.height / math.pi)
            put("cx", self.width / 2.0 - 0.5)
            put("cy", self.height / 2.0 - 0.5)
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
                raise ValueError(f"Camera.{name}: expected a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"Camera.{name}: must be finite, got {value}")
            put(name, float(value))
        for name in ("fx", "fy"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"Camera.{name}: focal length must be > 0, got {getattr(self, name)}")
        try:
            dist = tuple(float(d) for d in self.dist)
        except (TypeError, ValueError):
            raise ValueError(f"Camera.dist: expected a sequence of numbers, got {self.dist!r}") from None
        if len(dist) not in _DIST_LENGTHS[self.model]:
            want = _DIST_NAMES.get(self.model, "()")
            raise ValueError(f"Camera.dist: {self.model} takes {want}, got {len(dist)} coefficients")
        if not all(math.isfinite(d) for d in dist):
            raise ValueError(f"Camera.dist: must be finite, got {dist}")
        if self.model == "OPENCV" and len(dist) == 4:
            dist = dist + (0.0,)
        put("dist", dist)

    # ------------------------------------------------------------------ factories

    @classmethod
    def equirect(cls, width: int, height: int) -> Camera:
        """Full-sphere equirectangular camera (``width == 2 * height`` is the usual choice)."""
        return cls("EQUIRECTANGULAR", width, height, width / (2 * math.pi), height / math.pi,
                   width / 2 - 0.5, height / 2 - 0.5)

    @classmethod
    def pinhole_from_fov(cls, width: int, height: int, hfov_deg: float) -> Camera:
        """Centred pinhole with square pixels and horizontal field of view ``hfov_deg`` (edge to edge)."""
        if not 0.0 < hfov_deg < 180.0:
            raise ValueError(f"hfov_deg: must be in (0, 180), got {hfov_deg}")
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls("PINHOLE", width, height, f, f, width / 2.0 - 0.5, height / 2.0 - 0.5)

    @classmethod
    def fisheye_spot_like(cls, width: int = 640, height: int = 480) -> Camera:
        """Kannala-Brandt fisheye like Boston Dynamics Spot's body cameras: 180 deg horizontal FOV.

        Small nonzero ``k1..k4``; the focal length puts ``theta = 90 deg`` on the left/right
        image edges (the corners see ~110 deg off-axis, still inside the invertible range).
        """
        k = (-0.015, 0.002, -0.0004, 0.00003)
        half = math.pi / 2
        theta_d = half * (1 + k[0] * half**2 + k[1] * half**4 + k[2] * half**6 + k[3] * half**8)
        f = (width / 2.0) / theta_d
        return cls("OPENCV_FISHEYE", width, height, f, f, width / 2.0 - 0.5, height / 2.0 - 0.5, k)

    # ------------------------------------------------------------------ simple properties

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (OpenCV pixel convention), float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def max_angle_rad(self) -> float:
        """Largest angle from +z that projects (uniquely) into the model.

        PINHOLE: pi/2. OPENCV: up to where the radial distortion stops being monotonic. FULL_OPENCV:
        likewise, and before any pole of the rational factor. FISHEYE: up to where
        ``theta_d(theta)`` stops increasing, at most pi. EQUIRECTANGULAR: pi.
        """
        if self.model == "OPENCV":
            k1, k2, _, _, k3 = self.dist
            r2_max = _first_positive_root([1.0, 3 * k1, 5 * k2, 7 * k3])  # d(r * radial(r^2))/dr = 0
            return math.atan(math.sqrt(r2_max)) if math.isfinite(r2_max) else math.pi / 2
        if self.model == "FULL_OPENCV":
            k1, k2, _, _, k3, k4, k5, k6 = self.dist
            num, den = np.array([1.0, k1, k2, k3]), np.array([1.0, k4, k5, k6])  # ascending powers of s = r^2
            # d(r num(s) / den(s))/dr = (num den + 2 s (num' den - num den')) / den^2
            slope = P.polyadd(P.polymul(num, den),
                              P.polymulx(2.0 * P.polysub(P.polymul(P.polyder(num), den), P.polymul(num, P.polyder(den)))))
            r2_max = min(_first_positive_root(slope), _first_positive_root(den))
            return math.atan(math.sqrt(r2_max)) if math.isfinite(r2_max) else math.pi / 2
        if self.model == "OPENCV_FISHEYE":
            k1, k2, k3, k4 = self.dist
            t2_max = _first_positive_root([1.0, 3 * k1, 5 * k2, 7 * k3, 9 * k4])
            return min(math.sqrt(t2_max), math.pi)
        return math.pi if self.model == "EQUIRECTANGULAR" else math.pi / 2

    @property
    def fov_deg(self) -> tuple[float, float]:
        """(horizontal, vertical) field of view in degrees, edge to edge through the principal point."""
        if self.model == "EQUIRECTANGULAR":
            return 360.0, 180.0
        w, h = self.width - 0.5, self.height - 0.5
        d = self.unproject(np.array([[-0.5, self.cy], [w, self.cy], [self.cx, -0.5], [self.cx, h]]))
        hfov = math.atan2(d[1, 0], d[1, 2]) - math.atan2(d[0, 0], d[0, 2])
        vfov = math.atan2(d[3, 1], d[3, 2]) - math.atan2(d[2, 1], d[2, 2])
        return math.degrees(hfov), math.degrees(vfov)

    def scaled(self, factor: float) -> Camera:
        """The camera for this image resized by ``factor`` (size rounded to whole pixels).

        The image edges stay fixed: ``f' = f sx``, ``c' = (c + 0.5) sx - 0.5`` with
        ``sx = round(W factor) / W`` (likewise y). Distortion is unchanged.
        """
        if not (math.isfinite(factor) and factor > 0.0):
            raise ValueError(f"factor: must be finite and > 0, got {factor}")
        width, height = round(self.width * factor), round(self.height * factor)
        if width < 1 or height < 1:
            raise ValueError(f"factor: {factor} shrinks a {self.width}x{self.height} image to nothing")
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=(self.cx + 0.5) * sx - 0.5, cy=(self.cy + 0.5) * sy - 0.5)

    # ------------------------------------------------------------------ serialisation

    def to_dict(self) -> dict:
        """JSON-friendly dict (OpenCV pixel convention); inverse of ``from_dict``."""
        return {"model": self.model, "width": self.width, "height": self.height, "fx": self.fx,
                "fy": self.fy, "cx": self.cx, "cy": self.cy, "dist": list(self.dist)}

    @classmethod
    def from_dict(cls, d: Mapping) -> Camera:
        """Strict inverse of ``to_dict``: missing or unknown keys raise ``ValueError``."""
        if not isinstance(d, Mapping):
            raise ValueError(f"camera: expected a mapping, got {type(d).__name__}")
        required = {"model", "width", "height", "fx", "fy", "cx", "cy"}
        if missing := sorted(required - d.keys()):
            raise ValueError(f"camera: missing keys {missing}")
        if unknown := sorted(d.keys() - required - {"dist"}):
            raise ValueError(f"camera: unknown keys {unknown}")
        dist = d.get("dist", ())
        if not isinstance(dist, list | tuple):
            raise ValueError(f"camera.dist: expected a list, got {dist!r}")
        return cls(**{k: d[k] for k in required}, dist=tuple(dist))

    # ------------------------------------------------------------------ projection

    def project(self, points_cam: Array) -> tuple[Array, Array]:
        """Project camera-frame points to pixels.

        points_cam: (..., 3) in camera axes. Returns ``uv (..., 2)`` and ``valid (...,)`` bool:
        in front of the camera (z > 0 for PINHOLE/OPENCV, within ``max_angle_rad`` otherwise)
        and inside the image. ``uv`` of invalid points is unspecified (but finite for finite input).
        """
        p = _as_float(points_cam, "points_cam", (3,))
        xp = namespace(p)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        if self.model == "EQUIRECTANGULAR":
            u = self.fx * xp.arctan2(x, z) + self.cx
            v = self.fy * xp.arctan2(y, xp.hypot(x, z)) + self.cy
            front = x * x + y * y + z * z > 0.0
        elif self.model == "OPENCV_FISHEYE":
            r2 = x * x + y * y
            r = xp.sqrt(xp.where(r2 > _TINY, r2, _TINY))
            theta = xp.arctan2(r, z)
            scale = self._fisheye_distort(theta) / r
            u = self.fx * x * scale + self.cx
            v = self.fy * y * scale + self.cy
            front = (theta < self.max_angle_rad) & (r2 + z * z > 0.0)
        else:
            z_safe = xp.where(z > _Z_MIN, z, _Z_MIN)
            xn, yn = x / z_safe, y / z_safe
            front = z > _Z_MIN
            if self.model in RADTAN_MODELS:
                front = front & (xn * xn + yn * yn < math.tan(self.max_angle_rad) ** 2)
                xn, yn = self._radtan_distort(xn, yn)
            u = self.fx * xn + self.cx
            v = self.fy * yn + self.cy
        inside = (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)
        return xp.stack([u, v], -1), front & inside

    def unproject(self, uv: Array) -> Array:
        """Unit ray directions in camera axes through pixels ``uv (..., 2)``. Returns (..., 3).

        OPENCV, FULL_OPENCV and OPENCV_FISHEYE invert the distortion with ``NEWTON_ITERS`` vectorised Newton
        steps (no autograd), then one more step with autograd, which gives the exact
        implicit-function gradient at the solution.
        """
        uv = _as_float(uv, "uv", (2,))
        xp = namespace(uv)
        mx = (uv[..., 0] - self.cx) / self.fx
        my = (uv[..., 1] - self.cy) / self.fy
        if self.model == "EQUIRECTANGULAR":
            lon, lat = mx, my
            d = xp.stack([xp.cos(lat) * xp.sin(lon), xp.sin(lat), xp.cos(lat) * xp.cos(lon)], -1)
        elif self.model == "OPENCV_FISHEYE":
            td2 = mx * mx + my * my
            theta_d = xp.sqrt(xp.where(td2 > _TINY, td2, _TINY))
            theta = self._fisheye_undistort(theta_d)
            s = xp.sin(theta) / theta_d
            d = xp.stack([mx * s, my * s, xp.cos(theta)], -1)
        else:
            if self.model in RADTAN_MODELS:
                mx, my = self._radtan_undistort(mx, my)
            d = xp.stack([mx, my, xp.ones_like(mx)], -1)
        return d / xp.sqrt((d * d).sum(-1))[..., None]

    def pixel_centres(self, like: Array | None = None) -> Array:
        """``uv (H, W, 2)`` = (column, row) of every pixel centre: whole numbers (OpenCV; module docstring).

        Numpy float64 unless ``like`` is a tensor, whose dtype (floating, else the default) and device are then used.
        """
        if is_tensor(like):
            import torch

            dtype = like.dtype if like.is_floating_point() else torch.get_default_dtype()
            u = torch.arange(self.width, dtype=dtype, device=like.device)
            v = torch.arange(self.height, dtype=dtype, device=like.device)
            uu, vv = torch.meshgrid(u, v, indexing="xy")
            return torch.stack([uu, vv], -1)
        uu, vv = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return np.stack([uu, vv], -1)

    def pixel_dirs_cam(self, like: Array | None = None, *, fill_invalid: bool = False) -> Array:
        """Unit directions ``(H, W, 3)`` in camera axes through every pixel centre (``pixel_centres``).

        Computed afresh on each call. Numpy float64 unless ``like`` is a tensor, whose dtype and
        device are then used. Pixels the model cannot unproject are NaN, or ``FORWARD_DIR`` with
        ``fill_invalid`` (see ``fill_invalid_dirs``).
        """
        return self.dirs_through(self.pixel_centres(like), fill_invalid=fill_invalid)

    def dirs_through(self, uv: Array, *, fill_invalid: bool = False) -> Array:
        """Unit directions ``(..., 3)`` in camera axes through the pixel centres ``uv (..., 2)`` (column, row).

        ``unproject``, with the rows it cannot unproject (NaN) replaced by ``FORWARD_DIR`` when
        ``fill_invalid`` (callers that need a finite ray and mask the pixel themselves).
        """
        d = self.unproject(uv)
        return fill_invalid_dirs(d)[0] if fill_invalid else d

    def pixel_rays(self, cam_to_world: Array) -> tuple[Array, Array]:
        """World-frame ray origins and unit directions through every pixel centre.

        cam_to_world: (*batch, 4, 4), rigid, OpenCV axes. Returns origins, dirs: (*batch, H, W, 3).
        Pixels the model cannot unproject get NaN directions.
        """
        c2w = _as_float(cam_to_world, "cam_to_world", (4, 4))
        xp = namespace(c2w)
        dirs = xp.einsum("...ij,hwj->...hwi", c2w[..., :3, :3], self.pixel_dirs_cam(like=c2w))
        origins = c2w[..., None, None, :3, 3]
        if xp is not np:
            return origins.expand(dirs.shape).contiguous(), dirs
        return np.ascontiguousarray(np.broadcast_to(origins, dirs.shape)), dirs

    # ------------------------------------------------------------------ distortion models

    def _radial(self, r2: Array) -> tuple[Array, Array]:
        """Radial factor at squared radius ``r2`` and ``dradial`` with ``d radial / dx = dradial x``."""
        if self.model == "OPENCV":
            k1, k2, _, _, k3 = self.dist
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            return radial, 2.0 * k1 + r2 * (4.0 * k2 + r2 * 6.0 * k3)
        k1, k2, _, _, k3, k4, k5, k6 = self.dist
        num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dnum = k1 + r2 * (2.0 * k2 + r2 * 3.0 * k3)  # d/d(r2)
        dden = k4 + r2 * (2.0 * k5 + r2 * 3.0 * k6)
        return num / den, 2.0 * (dnum * den - num * dden) / (den * den)

    def _radtan_distort(self, x: Array, y: Array) -> tuple[Array, Array]:
        """OpenCV radial-tangential distortion of normalised coordinates (same shapes out)."""
        p1, p2 = self.dist[2], self.dist[3]
        r2 = x * x + y * y
        radial, _ = self._radial(r2)
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return xd, yd

    def _radtan_newton_step(self, x: Array, y: Array, xd: Array, yd: Array) -> tuple[Array, Array]:
        """One Newton step towards ``distort(x, y) == (xd, yd)`` with the analytic 2x2 Jacobian."""
        p1, p2 = self.dist[2], self.dist[3]
        r2 = x * x + y * y
        radial, dradial = self._radial(r2)
        xy = x * y
        ex = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x) - xd  # residual of _radtan_distort
        ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy - yd
        a = radial + dradial * x * x + 2.0 * p1 * y + 6.0 * p2 * x  # d xd / dx
        b = dradial * xy + 2.0 * p1 * x + 2.0 * p2 * y  # d xd / dy == d yd / dx
        d = radial + dradial * y * y + 6.0 * p1 * y + 2.0 * p2 * x  # d yd / dy
        det = a * d - b * b
        return x - (d * ex - b * ey) / det, y - (a * ey - b * ex) / det

    def _radtan_undistort(self, xd: Array, yd: Array) -> tuple[Array, Array]:
        with no_grad(xd):
            x, y = _detach(xd), _detach(yd)
            for _ in range(NEWTON_ITERS):
                x, y = self._radtan_newton_step(x, y, _detach(xd), _detach(yd))
        return self._radtan_newton_step(x, y, xd, yd)

    def _fisheye_distort(self, theta: Array) -> Array:
        k1, k2, k3, k4 = self.dist
        t2 = theta * theta
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _fisheye_newton_step(self, theta: Array, theta_d: Array) -> Array:
        k1, k2, k3, k4 = self.dist
        t2 = theta * theta
        slope = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
        xp = namespace(theta)
        return theta - (self._fisheye_distort(theta) - theta_d) / xp.clip(slope, 1e-6, None)

    def _fisheye_undistort(self, theta_d: Array) -> Array:
        """Solve ``theta_d = theta (1 + k1 theta^2 + ...)`` for theta in ``[0, max_angle_rad]``."""
        xp = namespace(theta_d)
        theta_max = self.max_angle_rad
        with no_grad(theta_d):
            target = _detach(theta_d)
            theta = xp.clip(target, 0.0, theta_max)
            for _ in range(NEWTON_ITERS):
                theta = xp.clip(self._fisheye_newton_step(theta, target), 0.0, theta_max)
        return self._fisheye_newton_step(theta, theta_d)
