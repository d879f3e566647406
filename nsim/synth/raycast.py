"""Exact analytic ray caster for the test room (vectorised numpy, float64 geometry).

``cast(spec, origins, dirs, textures)`` intersects rays with the room's six interior
surfaces and the furniture boxes (slab test) and shades the nearest hit.

Surfaces are one-sided, like back-face culling: room surfaces are seen from inside the
room, boxes from outside. Consequences, by design:

* a ray starting outside the room passes through the near wall (invisible from outside),
  hits what is inside and, failing that, the inside of the far wall ("dollhouse" view);
  a ray that never crosses the room's interior is a miss (``t = inf``, ``surface_id = -1``);
* a ray starting inside a box ignores that box (its faces face away) and hits what lies
  beyond; a ray starting exactly on a surface counts a hit at ``t = 0`` only when it
  leaves that surface towards the side the surface faces away from (into a box or out of the room).

Shading is baked and view-independent: ``rgb = clip(albedo * (ambient + sun + lamp), 0, 1)``
with Lambertian terms for one directional "sun" and one point "lamp" under the ceiling
centre (``Lighting``); there are no shadows. Everything is deterministic and elementwise
over rays, so results do not depend on how a batch of rays is split.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import lru_cache

import numpy as np

from nsim.synth.room import FIRST_BOX_SURFACE_ID, ROOM_SURFACE_AXIS_SIDE, RoomSpec, room_faces
from nsim.synth.textures import RoomTextures, sample_faces

CHUNK_RAYS = 1 << 14
"""Rays per internal batch: keeps the temporaries in cache; results do not depend on it."""

_TINY = 1e-300


@dataclass(frozen=True)
class Lighting:
    """Baked lights: ``ambient + sun_intensity * max(0, n.sun) + lamp_intensity * max(0, n.l) / (1 + (r / lamp_falloff_m)^2)``.

    sun_dir_xyz: direction *towards* the sun (normalised on use).
    The lamp hangs ``lamp_below_ceiling_m`` under the centre of the ceiling.
    """

    ambient: float = 0.45
    sun_dir_xyz: tuple[float, float, float] = (0.35, 0.55, 1.0)
    sun_intensity: float = 0.3
    lamp_intensity: float = 0.6
    lamp_below_ceiling_m: float = 0.4
    lamp_falloff_m: float = 3.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "sun_dir_xyz", tuple(float(c) for c in self.sun_dir_xyz))
        for name in ("ambient", "sun_intensity", "lamp_intensity", "lamp_below_ceiling_m"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"Lighting.{name}: expected >= 0, got {getattr(self, name)!r}")
        if not self.lamp_falloff_m > 0.0:
            raise ValueError(f"Lighting.lamp_falloff_m: expected > 0, got {self.lamp_falloff_m!r}")
        if len(self.sun_dir_xyz) != 3 or not np.linalg.norm(self.sun_dir_xyz) > 0.0:
            raise ValueError(f"Lighting.sun_dir_xyz: expected a nonzero 3-vector, got {self.sun_dir_xyz!r}")

    def lamp_xyz_m(self, spec: RoomSpec) -> np.ndarray:
        """World position ``(3,)`` of the lamp."""
        X, Y, Z = spec.size_xyz_m
        return np.array([X / 2, Y / 2, Z - self.lamp_below_ceiling_m])


DEFAULT_LIGHTING = Lighting()


@dataclass(frozen=True)
class RayHits:
    """Nearest hit per ray (N rays).

    t: (N,) float64 distance along the unit ray; inf for a miss.
    normal: (N, 3) float64 unit normal of the surface, facing the ray; 0 for a miss.
    surface_id: (N,) int64, see ``nsim.synth.room`` (0 floor ... 6 + k box k); -1 for a miss.
    face: (N,) int64 index into ``room_faces(spec)``; -1 for a miss.
    point: (N, 3) float64 hit point in world coordinates; NaN for a miss.
    rgb: (N, 3) float32 shaded colour in [0, 1]; 0 for a miss. Albedo 1 when cast without textures.
    """

    t: np.ndarray
    normal: np.ndarray
    surface_id: np.ndarray
    face: np.ndarray
    point: np.ndarray
    rgb: np.ndarray


@dataclass(frozen=True)
class _Scene:
    """Flat arrays of a spec for the hot loop (F faces, B boxes)."""

    size: np.ndarray  # (3,)
    box_lo: np.ndarray  # (B, 3)
    box_hi: np.ndarray  # (B, 3)
    face_normal: np.ndarray  # (F, 3)
    face_surface: np.ndarray  # (F,)
    face_axis: np.ndarray  # (F,)
    face_u_axis: np.ndarray  # (F,) world axis of u
    face_v_axis: np.ndarray  # (F,)
    face_u_sign: np.ndarray  # (F,) +-1
    face_v_sign: np.ndarray  # (F,)
    face_u_origin: np.ndarray  # (F,) world coordinate where u = 0
    face_v_origin: np.ndarray  # (F,)
    face_plane: np.ndarray  # (F,) world coordinate of the face plane along face_axis
    face_sun: np.ndarray  # (F,) ambient + sun term of the face (constant: flat faces, directional light)
    room_face: np.ndarray  # (3, 2) face index of the room surface at (axis, side)


@lru_cache(maxsize=16)
def _scene(spec: RoomSpec, lighting: Lighting) -> _Scene:
    """Memoised (specs and lightings are frozen and hashable); the arrays are read-only."""
    faces = room_faces(spec)
    normal = np.array([f.normal for f in faces])
    u_dir = np.array([f.u_dir for f in faces])
    v_dir = np.array([f.v_dir for f in faces])
    origin = np.array([f.origin_xyz_m for f in faces])
    face_axis = np.array([f.axis for f in faces], dtype=np.int64)
    u_axis = np.abs(u_dir).argmax(1)
    v_axis = np.abs(v_dir).argmax(1)
    rows = np.arange(len(faces))
    sun = np.asarray(lighting.sun_dir_xyz, dtype=np.float64)
    room_face = np.zeros((3, 2), dtype=np.int64)
    for sid, (axis, side) in enumerate(ROOM_SURFACE_AXIS_SIDE):
        room_face[axis, side] = sid
    box_lo = np.array([b.min_xyz_m for b in spec.boxes]).reshape(-1, 3)
    box_hi = np.array([b.max_xyz_m for b in spec.boxes]).reshape(-1, 3)
    scene = _Scene(
        size=np.asarray(spec.size_xyz_m, dtype=np.float64),
        box_lo=box_lo,
        box_hi=box_hi,
        face_normal=normal,
        face_surface=np.array([f.surface_id for f in faces], dtype=np.int64),
        face_axis=face_axis,
        face_u_axis=u_axis,
        face_v_axis=v_axis,
        face_u_sign=u_dir[rows, u_axis],
        face_v_sign=v_dir[rows, v_axis],
        face_u_origin=origin[rows, u_axis],
        face_v_origin=origin[rows, v_axis],
        face_plane=origin[rows, face_axis],
        face_sun=lighting.ambient + lighting.sun_intensity * np.maximum(normal @ (sun / np.linalg.norm(sun)), 0.0),
        room_face=room_face,
    )
    for f in fields(scene):
        getattr(scene, f.name).setflags(write=False)
    return scene


def _intersect(scene: _Scene, o: tuple, d: tuple, inv: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit distance ``t (n,)`` (inf: miss) and face index ``(n,)`` (-1: miss).

    o: per-axis origins, each ``(n,)`` or a float when all rays share the origin (saves work).
    d, inv: per-axis ``(n,)`` directions (no zeros) and their inverses.
    """
    n = d[0].shape[0]
    # Room: the ray leaves the interior box through the nearest exit plane.
    t = np.full(n, np.inf)
    t_entry = np.zeros(n)
    exit_axis = np.zeros(n, dtype=np.int64)
    exit_side = np.zeros(n, dtype=np.int64)
    for axis in range(3):
        positive = d[axis] > 0
        far = np.where(positive, scene.size[axis], 0.0)
        near = np.where(positive, 0.0, scene.size[axis])
        t_far = (far - o[axis]) * inv[axis]
        np.maximum(t_entry, (near - o[axis]) * inv[axis], out=t_entry)
        closer = t_far < t
        t = np.where(closer, t_far, t)
        exit_axis[closer] = axis
        exit_side[closer] = positive[closer]
    face = scene.room_face[exit_axis, exit_side]
    miss = ~(t >= t_entry)  # also catches NaN
    t[miss] = np.inf
    face[miss] = -1

    # Boxes: slab test, entry distance t_near if 0 <= t_near <= t_far.
    t_near, t_far, lo_t, hi_t, tmp = (np.empty(n) for _ in range(5))
    for k in range(scene.box_lo.shape[0]):
        for axis in range(3):
            np.multiply(scene.box_lo[k, axis] - o[axis], inv[axis], out=lo_t)
            np.multiply(scene.box_hi[k, axis] - o[axis], inv[axis], out=hi_t)
            if axis == 0:
                np.minimum(lo_t, hi_t, out=t_near)
                np.maximum(lo_t, hi_t, out=t_far)
            else:
                np.maximum(t_near, np.minimum(lo_t, hi_t, out=tmp), out=t_near)
                np.minimum(t_far, np.maximum(lo_t, hi_t, out=tmp), out=t_far)
        hit = (t_near <= t_far) & (t_near >= 0.0) & (t_near < t)
        idx = np.nonzero(hit)[0]
        if idx.size == 0:
            continue
        # entry axis: the one whose near-plane distance is t_near (the largest of the three)
        d_hit = [d[a][idx] for a in range(3)]
        near_planes = [
            (np.where(d_hit[a] > 0, scene.box_lo[k, a], scene.box_hi[k, a]) - (o[a] if np.ndim(o[a]) == 0 else o[a][idx]))
            * inv[a][idx]
            for a in range(3)
        ]
        axis = np.where(near_planes[0] >= near_planes[1], 0, 1)
        axis = np.where(near_planes[2] > np.maximum(near_planes[0], near_planes[1]), 2, axis)
        side = np.where(np.choose(axis, d_hit) > 0, 0, 1)
        t[idx] = t_near[idx]
        face[idx] = FIRST_BOX_SURFACE_ID + 6 * k + 2 * axis + side  # room.face_index, vectorised
    return t, face


def _cast_chunk(scene: _Scene, o: np.ndarray, d: np.ndarray, textures: RoomTextures | None,
                footprint_rad: np.ndarray | None, lighting: Lighting, lamp: np.ndarray,
                out: dict[str, np.ndarray]) -> None:
    """Cast one chunk of rays ``o, d (n, 3)`` and write the results into the ``out`` views."""
    o_axes = (o[:, 0], o[:, 1], o[:, 2])
    d_axes = (d[:, 0], d[:, 1], d[:, 2])
    # no zero components: 1 / d stays finite and 0 * inf never happens
    safe = tuple(np.where(np.abs(da) < _TINY, np.where(np.signbit(da), -_TINY, _TINY), da) for da in d_axes)
    shared = o.shape[0] > 0 and bool(np.all(o == o[0]))  # cameras, LiDARs: one origin for all rays
    t, face = _intersect(scene, tuple(float(c) for c in o[0]) if shared else o_axes, safe,
                         tuple(1.0 / da for da in safe))
    hit = face >= 0
    # work on every ray (misses are rare) with harmless stand-ins, then blank the misses
    f = np.where(hit, face, 0)
    t_hit = np.where(hit, t, 0.0)
    axis = scene.face_axis[f]
    plane = scene.face_plane[f]
    p = [np.where(axis == a, plane, o_axes[a] + t_hit * d_axes[a]) for a in range(3)]  # snapped onto the face
    u = (np.choose(scene.face_u_axis[f], p) - scene.face_u_origin[f]) * scene.face_u_sign[f]
    v = (np.choose(scene.face_v_axis[f], p) - scene.face_v_origin[f]) * scene.face_v_sign[f]
    normal = [scene.face_normal[f, a] for a in range(3)]

    # shading: ambient + sun + lamp, Lambertian, no shadows
    to_lamp = [lamp[a] - p[a] for a in range(3)]
    r2 = to_lamp[0] * to_lamp[0] + to_lamp[1] * to_lamp[1] + to_lamp[2] * to_lamp[2]
    n_dot_l = (to_lamp[0] * normal[0] + to_lamp[1] * normal[1] + to_lamp[2] * normal[2]) / np.sqrt(
        np.maximum(r2, 1e-12))
    shade = (scene.face_sun[f] + lighting.lamp_intensity * np.maximum(n_dot_l, 0.0)
             / (1.0 + r2 * (1.0 / lighting.lamp_falloff_m**2))).astype(np.float32)
    if textures is None:
        rgb = np.repeat(shade[:, None], 3, axis=1)
    else:
        footprint_m = None
        if footprint_rad is not None:
            cos_in = np.abs(d_axes[0] * normal[0] + d_axes[1] * normal[1] + d_axes[2] * normal[2])
            footprint_m = t_hit * footprint_rad / np.sqrt(np.maximum(cos_in, 0.05))
        rgb = sample_faces(textures, f, np.stack([u, v], axis=-1), footprint_m)
        rgb *= shade[:, None]
    np.clip(rgb, 0.0, 1.0, out=rgb)

    out["t"][:] = t
    out["face"][:] = face
    out["surface_id"][:] = np.where(hit, scene.face_surface[f], -1)
    for a in range(3):
        out["normal"][:, a] = np.where(hit, normal[a], 0.0)
        out["point"][:, a] = np.where(hit, p[a], np.nan)
    out["rgb"][:] = np.where(hit[:, None], rgb, np.float32(0.0))


def cast(spec: RoomSpec, origins: np.ndarray, dirs: np.ndarray, textures: RoomTextures | None = None, *,
         footprint_rad: float | np.ndarray | None = None, lighting: Lighting = DEFAULT_LIGHTING) -> RayHits:
    """Cast rays ``origins (N, 3)``, unit ``dirs (N, 3)`` (world frame) into the room ``spec``.

    textures: ``bake_room_textures(spec)``; None gives white albedo (rgb = shading alone).
    footprint_rad: the angular spread of each ray (scalar or ``(N,)``, e.g. a pixel's
        angular size); enables trilinear mip filtering with footprint ``t * spread /
        sqrt(|cos incidence|)``. None samples the full-resolution texture (bilinear).
    Returns ``RayHits`` (see there). Rays are processed in chunks of ``CHUNK_RAYS``.
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(dirs, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"cast: expected origins and dirs of shape (N, 3), got {o.shape} and {d.shape}")
    n = o.shape[0]
    spread = None
    if footprint_rad is not None:
        spread = np.broadcast_to(np.asarray(footprint_rad, dtype=np.float64), (n,))
    scene = _scene(spec, lighting)
    lamp = lighting.lamp_xyz_m(spec)
    out = {
        "t": np.empty(n), "face": np.empty(n, dtype=np.int64), "surface_id": np.empty(n, dtype=np.int64),
        "normal": np.empty((n, 3)), "point": np.empty((n, 3)), "rgb": np.empty((n, 3), dtype=np.float32),
    }
    for start in range(0, n, CHUNK_RAYS):
        sl = slice(start, min(start + CHUNK_RAYS, n))
        _cast_chunk(scene, o[sl], d[sl], textures, None if spread is None else spread[sl], lighting, lamp,
                    {k: v[sl] for k, v in out.items()})
    return RayHits(t=out["t"], normal=out["normal"], surface_id=out["surface_id"], face=out["face"],
                   point=out["point"], rgb=out["rgb"])
