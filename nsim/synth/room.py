"""The test room: a declarative, seeded room with exact geometry.

World frame (``nsim.geometry.conventions``): metres, z up. The room is the axis-aligned box
``[0, X] x [0, Y] x [0, Z]`` with ``(X, Y, Z) = spec.size_xyz_m``: floor ``z = 0``, ceiling
``z = Z`` and four walls. Furniture is a set of axis-aligned boxes (no yaw: it keeps the
ray caster, the footprints and the occupancy grid exact and cheap); composite pieces (a
desk is a top and two side panels, a sofa a seat and a back) are several boxes.

Surface ids (``RayHits.surface_id``, texture faces): 0 floor, 1 ceiling, 2 wall ``x = 0``,
3 wall ``x = X``, 4 wall ``y = 0``, 5 wall ``y = Y``, ``6 + k`` furniture box ``k``; -1 is
"no hit". Each surface is split into planar *faces* (``room_faces``): one per room surface,
six per box, each with its own texture coordinates ``(u, v)`` in metres.

Every spec carries a *walk loop*: an ellipse in the free middle of the room that keeps at
least ``LOOP_CLEARANCE_M`` (2D) from every wall and furniture footprint. The capture path
walks it; later the robot and the simulated people can too.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

SURFACE_FLOOR = 0
SURFACE_CEILING = 1
SURFACE_WALL_X0 = 2
SURFACE_WALL_X1 = 3
SURFACE_WALL_Y0 = 4
SURFACE_WALL_Y1 = 5
FIRST_BOX_SURFACE_ID = 6
ROOM_SURFACE_NAMES = ("floor", "ceiling", "wall_x0", "wall_x1", "wall_y0", "wall_y1")
WALL_SURFACE_IDS = (SURFACE_WALL_X0, SURFACE_WALL_X1, SURFACE_WALL_Y0, SURFACE_WALL_Y1)
# (axis, side) of each room surface: side 0 is the plane at 0, side 1 the plane at the room size.
ROOM_SURFACE_AXIS_SIDE = ((2, 0), (2, 1), (0, 0), (0, 1), (1, 0), (1, 1))

LOOP_CLEARANCE_M = 0.7
"""Minimum 2D distance from the walk loop to any wall or furniture footprint."""

WALL_THICKNESS_M = 0.1
"""Thickness of the wall polygons in ``occupancy_polygons`` (outside the room interior)."""


@dataclass(frozen=True)
class Material:
    """A surface appearance: a photo (``nsim.synth.textures.PHOTO_NAMES``) laid out at a physical scale.

    metres_per_texel: size of one photo pixel on the surface.
    tint_rgb: per-channel multiplier in [0, 4] (grey photos get their colour here).
    contrast: albedo = clip((mean + contrast * (photo - mean)) * tint, 0, 1), ``mean`` the photo's mean colour.
    """

    texture: str
    metres_per_texel: float
    tint_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    contrast: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "tint_rgb", tuple(float(c) for c in self.tint_rgb))
        if not isinstance(self.texture, str) or not self.texture:
            raise ValueError(f"Material.texture: expected a photo name, got {self.texture!r}")
        if not (math.isfinite(self.metres_per_texel) and self.metres_per_texel > 0.0):
            raise ValueError(f"Material.metres_per_texel: expected float > 0, got {self.metres_per_texel!r}")
        if len(self.tint_rgb) != 3 or not all(0.0 <= c <= 4.0 for c in self.tint_rgb):
            raise ValueError(f"Material.tint_rgb: expected 3 floats in [0, 4], got {self.tint_rgb!r}")
        if not (math.isfinite(self.contrast) and self.contrast > 0.0):
            raise ValueError(f"Material.contrast: expected float > 0, got {self.contrast!r}")


@dataclass(frozen=True)
class Box:
    """An axis-aligned furniture box ``[min_xyz_m, max_xyz_m]`` with one material; ``label`` e.g. "desk.top"."""

    min_xyz_m: tuple[float, float, float]
    max_xyz_m: tuple[float, float, float]
    material: Material
    label: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "min_xyz_m", tuple(float(v) for v in self.min_xyz_m))
        object.__setattr__(self, "max_xyz_m", tuple(float(v) for v in self.max_xyz_m))
        lo, hi = self.min_xyz_m, self.max_xyz_m
        if len(lo) != 3 or len(hi) != 3 or not all(math.isfinite(v) for v in lo + hi):
            raise ValueError(f"Box {self.label!r}: expected finite 3-vectors, got {lo!r}, {hi!r}")
        if not all(a < b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"Box {self.label!r}: expected min < max on every axis, got {lo!r}, {hi!r}")


@dataclass(frozen=True)
class Poster:
    """A photo hung on a wall (``surface_id`` in ``WALL_SURFACE_IDS``), centre-cropped to its aspect.

    centre_u_m: along the wall, from its left end as seen from inside the room.
    centre_z_m: height of the poster centre above the floor.
    """

    surface_id: int
    texture: str
    centre_u_m: float
    centre_z_m: float
    width_m: float
    height_m: float

    def __post_init__(self) -> None:
        if self.surface_id not in WALL_SURFACE_IDS:
            raise ValueError(f"Poster.surface_id: expected a wall id {WALL_SURFACE_IDS}, got {self.surface_id!r}")
        if not (self.width_m > 0.0 and self.height_m > 0.0):
            raise ValueError(f"Poster: expected positive size, got {self.width_m!r} x {self.height_m!r}")


@dataclass(frozen=True)
class RoomSpec:
    """A complete, declarative room (see the module docstring for frames and ids).

    name: preset name (or any label); seed: the seed it was generated from.
    size_xyz_m: interior size (X, Y, Z).
    surfaces: 6 materials indexed by room surface id (floor, ceiling, wall_x0, wall_x1, wall_y0, wall_y1).
    boxes: furniture; box k has surface id ``6 + k``.
    posters: photos on the walls.
    walk_loop_xy_m: (centre_x, centre_y, radius_x, radius_y) of the walk-loop ellipse.
    """

    name: str
    seed: int
    size_xyz_m: tuple[float, float, float]
    surfaces: tuple[Material, ...]
    boxes: tuple[Box, ...]
    posters: tuple[Poster, ...]
    walk_loop_xy_m: tuple[float, float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "size_xyz_m", tuple(float(v) for v in self.size_xyz_m))
        object.__setattr__(self, "walk_loop_xy_m", tuple(float(v) for v in self.walk_loop_xy_m))
        for name in ("surfaces", "boxes", "posters"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        X, Y, Z = self.size_xyz_m
        if not all(math.isfinite(v) and v > 0.0 for v in self.size_xyz_m):
            raise ValueError(f"RoomSpec.size_xyz_m: expected 3 positive floats, got {self.size_xyz_m!r}")
        if len(self.surfaces) != 6:
            raise ValueError(f"RoomSpec.surfaces: expected 6 materials {ROOM_SURFACE_NAMES}, got {len(self.surfaces)}")
        for k, box in enumerate(self.boxes):
            if not all(-1e-9 <= lo and hi <= s + 1e-9 for lo, hi, s in zip(box.min_xyz_m, box.max_xyz_m, self.size_xyz_m, strict=True)):
                raise ValueError(f"RoomSpec.boxes[{k}] ({box.label}): box leaves the room {self.size_xyz_m}")
        for k, p in enumerate(self.posters):
            length = Y if p.surface_id in (SURFACE_WALL_X0, SURFACE_WALL_X1) else X
            if not (0.0 <= p.centre_u_m - p.width_m / 2 and p.centre_u_m + p.width_m / 2 <= length
                    and 0.0 <= p.centre_z_m - p.height_m / 2 and p.centre_z_m + p.height_m / 2 <= Z):
                raise ValueError(f"RoomSpec.posters[{k}]: poster leaves its wall")
        cx, cy, rx, ry = self.walk_loop_xy_m
        if not (rx > 0.0 and ry > 0.0):
            raise ValueError(f"RoomSpec.walk_loop_xy_m: expected positive radii, got {self.walk_loop_xy_m!r}")
        clearance = float(clearance_xy_m(self, walk_loop_points_xy(self, 720)).min())
        if clearance < LOOP_CLEARANCE_M - 1e-6:
            raise ValueError(
                f"RoomSpec.walk_loop_xy_m: loop passes {clearance:.3f} m from an obstacle, "
                f"needs >= {LOOP_CLEARANCE_M} m"
            )

    def to_dict(self) -> dict:
        """Plain nested dict (JSON/YAML-ready); ``RoomSpec.from_dict`` inverts it exactly."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> RoomSpec:
        """Inverse of ``to_dict``; unknown or missing keys raise ValueError naming the key."""
        _check_keys("RoomSpec", data, cls)
        boxes = []
        for k, b in enumerate(data["boxes"]):
            _check_keys(f"RoomSpec.boxes[{k}]", b, Box)
            boxes.append(Box(**{**b, "material": _material_from_dict(f"RoomSpec.boxes[{k}].material", b["material"])}))
        posters = []
        for k, p in enumerate(data["posters"]):
            _check_keys(f"RoomSpec.posters[{k}]", p, Poster)
            posters.append(Poster(**p))
        surfaces = [_material_from_dict(f"RoomSpec.surfaces[{k}]", m) for k, m in enumerate(data["surfaces"])]
        return cls(**{**data, "surfaces": surfaces, "boxes": boxes, "posters": posters})


def _check_keys(where: str, data: dict, cls: type) -> None:
    want = {f.name for f in fields(cls)}
    got = set(data)
    if got - want:
        raise ValueError(f"{where}: unknown keys {sorted(got - want)}")
    if want - got:
        raise ValueError(f"{where}: missing keys {sorted(want - got)}")


def _material_from_dict(where: str, data: dict) -> Material:
    _check_keys(where, data, Material)
    return Material(**data)


# ----------------------------------------------------------------------------------------------
# Faces: planar pieces with texture coordinates.


@dataclass(frozen=True)
class Face:
    """A planar rectangle of one surface, with its texture frame.

    Points on the face are ``origin_xyz_m + u * u_dir + v * v_dir`` for ``(u, v)`` in
    ``[0, size_uv_m[0]] x [0, size_uv_m[1]]``. ``normal`` points to the side the face is seen
    from (into the room for room surfaces, out of the box for furniture). On vertical faces
    ``u`` runs left to right and ``v`` top to bottom as seen from the front, so photos appear
    upright and unmirrored.
    """

    surface_id: int
    axis: int
    side: int
    normal: tuple[float, float, float]
    origin_xyz_m: tuple[float, float, float]
    u_dir: tuple[float, float, float]
    v_dir: tuple[float, float, float]
    size_uv_m: tuple[float, float]
    material: Material


def face_index(surface_id: int, axis: int, side: int) -> int:
    """Index into ``room_faces(spec)``: room surfaces 0..5 by id, box k faces ``6 + 6k + 2 axis + side``."""
    if surface_id < FIRST_BOX_SURFACE_ID:
        return surface_id
    return FIRST_BOX_SURFACE_ID + 6 * (surface_id - FIRST_BOX_SURFACE_ID) + 2 * axis + side


def _face(surface_id: int, axis: int, side: int, lo: np.ndarray, hi: np.ndarray, normal_sign: float,
          material: Material) -> Face:
    normal = np.zeros(3)
    normal[axis] = normal_sign
    if axis == 2:  # horizontal: u along +x, v along +y
        u_dir, v_dir = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    else:  # vertical: u to the right of a viewer looking at the face (forward = -normal), v down
        u_dir = np.cross(-normal, [0.0, 0.0, 1.0])
        v_dir = np.array([0.0, 0.0, -1.0])
    plane = lo[axis] if side == 0 else hi[axis]
    # origin: the corner where u and v are smallest
    origin = np.where(u_dir + v_dir > 0, lo, hi).astype(np.float64)
    origin[axis] = plane
    size_u = float(np.abs(u_dir) @ (hi - lo))
    size_v = float(np.abs(v_dir) @ (hi - lo))
    return Face(surface_id, axis, side, tuple(normal), tuple(origin), tuple(u_dir), tuple(v_dir),
                (size_u, size_v), material)


def room_faces(spec: RoomSpec) -> list[Face]:
    """All faces: 6 room surfaces (index = surface id), then 6 per box (see ``face_index``)."""
    size = np.asarray(spec.size_xyz_m)
    faces = []
    for sid, (axis, side) in enumerate(ROOM_SURFACE_AXIS_SIDE):
        faces.append(_face(sid, axis, side, np.zeros(3), size, 1.0 if side == 0 else -1.0, spec.surfaces[sid]))
    for k, box in enumerate(spec.boxes):
        lo, hi = np.asarray(box.min_xyz_m), np.asarray(box.max_xyz_m)
        for axis in range(3):
            for side in range(2):
                faces.append(_face(FIRST_BOX_SURFACE_ID + k, axis, side, lo, hi, -1.0 if side == 0 else 1.0,
                                   box.material))
    return faces


# ----------------------------------------------------------------------------------------------
# 2D footprints, clearance and occupancy.


def box_footprints_xy(spec: RoomSpec) -> np.ndarray:
    """Furniture footprints ``(B, 4)`` as ``[x_min, y_min, x_max, y_max]`` in metres."""
    if not spec.boxes:
        return np.zeros((0, 4))
    return np.array([[b.min_xyz_m[0], b.min_xyz_m[1], b.max_xyz_m[0], b.max_xyz_m[1]] for b in spec.boxes])


def clearance_xy_m(spec: RoomSpec, points_xy: np.ndarray) -> np.ndarray:
    """2D distance from ``points_xy (..., 2)`` to the nearest wall or furniture footprint: ``(...)``.

    Zero inside a footprint, negative outside the room (minus the distance to the room).
    Furniture counts at every height, so this is a lower bound on the 3D clearance.
    """
    p = np.asarray(points_xy, dtype=np.float64)
    X, Y, _ = spec.size_xyz_m
    d = np.minimum(np.minimum(p[..., 0], X - p[..., 0]), np.minimum(p[..., 1], Y - p[..., 1]))
    for x0, y0, x1, y1 in box_footprints_xy(spec):
        dx = np.maximum(np.maximum(x0 - p[..., 0], p[..., 0] - x1), 0.0)
        dy = np.maximum(np.maximum(y0 - p[..., 1], p[..., 1] - y1), 0.0)
        d = np.minimum(d, np.hypot(dx, dy))
    return d


def walk_loop_points_xy(spec: RoomSpec, n: int) -> np.ndarray:
    """``n`` points ``(n, 2)`` evenly spaced in angle on the walk-loop ellipse, counter-clockwise from +x."""
    cx, cy, rx, ry = spec.walk_loop_xy_m
    a = 2.0 * np.pi * np.arange(n) / n
    return np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], axis=-1)


def occupancy_polygons(spec: RoomSpec) -> list[np.ndarray]:
    """2D obstacle polygons ``(K, 2)`` (counter-clockwise, x/y metres): 4 walls, then one per box.

    Walls are ``WALL_THICKNESS_M`` thick rectangles just outside the interior (they overlap at
    the corners so the outline is closed). Furniture polygons are the box footprints, in
    ``spec.boxes`` order (composite pieces give overlapping or touching rectangles).
    """
    X, Y, _ = spec.size_xyz_m
    t = WALL_THICKNESS_M
    rects = [(-t, -t, 0.0, Y + t), (X, -t, X + t, Y + t), (-t, -t, X + t, 0.0), (-t, Y, X + t, Y + t)]
    rects += [tuple(r) for r in box_footprints_xy(spec)]
    return [np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64) for x0, y0, x1, y1 in rects]


def occupancy_grid(spec: RoomSpec, resolution_m: float) -> np.ndarray:
    """Occupied cells of the room interior: ``(H, W)`` bool, ``H = ceil(Y / res)``, ``W = ceil(X / res)``.

    Cell ``[i, j]`` covers ``x in [j res, (j+1) res)``, ``y in [i res, (i+1) res)``: origin at
    the world origin (the room corner), rows along +y, columns along +x. A cell is occupied
    when it overlaps a furniture footprint (conservative) or sticks out of the room (the last
    row/column when the size is not a multiple of ``res``). The walls are the grid border:
    treat every index outside the grid as occupied.
    """
    if not (math.isfinite(resolution_m) and resolution_m > 0.0):
        raise ValueError(f"occupancy_grid: resolution_m must be > 0, got {resolution_m!r}")
    X, Y, _ = spec.size_xyz_m
    H, W = math.ceil(Y / resolution_m - 1e-9), math.ceil(X / resolution_m - 1e-9)
    edges_x = np.arange(W + 1) * resolution_m
    edges_y = np.arange(H + 1) * resolution_m
    grid = np.zeros((H, W), dtype=bool)
    eps = 1e-9
    for x0, y0, x1, y1 in box_footprints_xy(spec):
        cols = (edges_x[1:] > x0 + eps) & (edges_x[:-1] < x1 - eps)
        rows = (edges_y[1:] > y0 + eps) & (edges_y[:-1] < y1 - eps)
        grid |= rows[:, None] & cols[None, :]
    grid[:, edges_x[1:] > X + eps] = True
    grid[edges_y[1:] > Y + eps, :] = True
    return grid


def room_diagonal_m(spec: RoomSpec) -> float:
    """Length of the room's 3D interior diagonal (the scene scale used to normalise errors)."""
    return float(np.linalg.norm(spec.size_xyz_m))


# ----------------------------------------------------------------------------------------------
# Presets.

_GAP_TO_WALL_M = 0.02
_GAP_BETWEEN_M = 0.12


def _mat(texture: str, mpt: float, tint=(1.0, 1.0, 1.0), contrast: float = 1.0) -> Material:
    return Material(texture, mpt, tuple(tint), contrast)


# Furniture pieces in local coordinates: (u0, u1) along the wall, (d0, d1) away from it (0 at the
# wall, or the footprint's min corner for free-standing pieces), (z0, z1); part name.
def _parts_desk(w, d, h):
    t = 0.04
    return [((0, w, 0, d, h - t, h), "top"), ((0, t, 0, d, 0, h - t), "leg"), ((w - t, w, 0, d, 0, h - t), "leg")]


def _parts_block(w, d, h):
    return [((0, w, 0, d, 0, h), "body")]


def _parts_sofa(w, d, h):
    back = 0.22
    return [((0, w, back, d, 0, 0.45), "seat"), ((0, w, 0, back, 0, h), "back")]


def _parts_counter(w, d, h):
    t = 0.04
    return [((0, w, 0, d - 0.04, 0, h - t), "base"), ((0, w, 0, d, h - t, h), "worktop")]


def _parts_tv(w, d, h):
    screen_w, screen_h = min(1.2, w - 0.1), 0.62
    u0 = (w - screen_w) / 2
    return [((0, w, 0, d, 0, h), "stand"), ((u0, u0 + screen_w, 0.05, 0.13, h, h + screen_h), "screen")]


_PARTS = {
    "desk": _parts_desk, "table": _parts_desk, "cabinet": _parts_block, "shelf": _parts_block,
    "fridge": _parts_block, "sofa": _parts_sofa, "armchair": _parts_sofa, "counter": _parts_counter,
    "tv-stand": _parts_tv,
}

# kind: (width range, depth range, height range)
_SIZES = {
    "desk": ((1.2, 1.6), (0.7, 0.8), (0.72, 0.76)),
    "table": ((1.2, 1.6), (0.7, 0.9), (0.72, 0.76)),
    "cabinet": ((0.8, 1.2), (0.45, 0.6), (0.9, 1.2)),
    "shelf": ((0.8, 1.2), (0.3, 0.4), (1.8, 2.1)),
    "fridge": ((0.6, 0.7), (0.6, 0.7), (1.75, 1.9)),
    "sofa": ((1.8, 2.2), (0.85, 0.95), (0.8, 0.9)),
    "armchair": ((0.8, 0.95), (0.8, 0.9), (0.8, 0.9)),
    "counter": ((1.4, 2.2), (0.6, 0.62), (0.9, 0.92)),
    "tv-stand": ((1.4, 1.8), (0.4, 0.45), (0.45, 0.55)),
}


@dataclass(frozen=True)
class _Recipe:
    size_ranges_m: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    floor: tuple[Material, ...]
    ceiling: tuple[Material, ...]
    walls: tuple[Material, ...]
    wall_items: tuple[tuple[str, int], ...]
    island: str | None
    furniture: tuple[Material, ...]
    posters: tuple[str, ...]
    poster_count: tuple[int, int]


_CEILING = (_mat("gravel", 0.008, (1.7, 1.7, 1.65), 0.6), _mat("text", 0.006, (1.6, 1.6, 1.6), 0.8))
_PICTURES = ("astronaut", "coffee", "chelsea", "rocket", "camera", "page", "hubble_deep_field",
             "immunohistochemistry", "retina", "stereo_motorcycle", "coins", "text")

_RECIPES: dict[str, _Recipe] = {
    "robot-lab": _Recipe(
        size_ranges_m=((7.0, 8.0), (6.0, 7.0), (3.0, 3.2)),
        floor=(_mat("gravel", 0.005, (0.62, 0.63, 0.65), 1.4), _mat("coins", 0.004, (0.7, 0.7, 0.72))),
        ceiling=_CEILING,
        walls=(_mat("brick", 0.004, (0.92, 0.9, 0.88), 1.6), _mat("brick", 0.004, (0.8, 0.86, 0.95), 1.6),
               _mat("grass", 0.004, (0.85, 0.85, 0.85), 1.0)),
        wall_items=(("desk", 3), ("shelf", 2), ("cabinet", 2)),
        island=None,
        furniture=(_mat("immunohistochemistry", 0.003), _mat("coffee", 0.002), _mat("gravel", 0.003, (0.75, 0.6, 0.45), 1.3),
                   _mat("astronaut", 0.002), _mat("coins", 0.003, (0.6, 0.7, 0.8))),
        posters=_PICTURES,
        poster_count=(5, 8),
    ),
    "common-room": _Recipe(
        size_ranges_m=((6.0, 7.0), (5.2, 6.0), (2.6, 2.8)),
        floor=(_mat("grass", 0.004, (0.55, 0.45, 0.35), 1.5), _mat("gravel", 0.005, (0.7, 0.6, 0.5))),
        ceiling=_CEILING,
        walls=(_mat("immunohistochemistry", 0.004, (0.95, 0.92, 0.85)), _mat("text", 0.004, (0.9, 0.85, 0.75), 1.3),
               _mat("brick", 0.004, (0.95, 0.75, 0.6), 1.5)),
        wall_items=(("sofa", 2), ("shelf", 2), ("desk", 1), ("cabinet", 1)),
        island=None,
        furniture=(_mat("chelsea", 0.002), _mat("coffee", 0.002), _mat("grass", 0.003, (0.5, 0.55, 0.8), 1.6),
                   _mat("gravel", 0.003, (0.8, 0.55, 0.4), 1.3)),
        posters=_PICTURES,
        poster_count=(4, 7),
    ),
    "kitchen": _Recipe(
        size_ranges_m=((6.0, 6.8), (5.2, 5.8), (2.5, 2.7)),
        floor=(_mat("brick", 0.004, (0.85, 0.8, 0.7), 1.5), _mat("coins", 0.004, (0.8, 0.75, 0.7))),
        ceiling=_CEILING,
        walls=(_mat("text", 0.004, (0.95, 0.95, 0.9), 1.4), _mat("immunohistochemistry", 0.004, (0.9, 0.95, 0.95)),
               _mat("gravel", 0.004, (0.95, 0.9, 0.8), 0.9)),
        wall_items=(("counter", 3), ("fridge", 1), ("cabinet", 1)),
        island="counter",
        furniture=(_mat("gravel", 0.003, (0.9, 0.9, 0.92)), _mat("coffee", 0.002), _mat("coins", 0.003),
                   _mat("immunohistochemistry", 0.003, (0.8, 0.8, 0.9))),
        posters=("coffee", "chelsea", "astronaut", "page", "rocket", "stereo_motorcycle"),
        poster_count=(3, 5),
    ),
    "living-room": _Recipe(
        size_ranges_m=((5.8, 6.6), (5.0, 5.8), (2.5, 2.7)),
        floor=(_mat("grass", 0.004, (0.75, 0.55, 0.4), 1.1), _mat("gravel", 0.004, (0.7, 0.55, 0.45), 1.2)),
        ceiling=_CEILING,
        walls=(_mat("brick", 0.004, (0.95, 0.88, 0.75), 1.4), _mat("immunohistochemistry", 0.004, (0.9, 0.88, 0.95)),
               _mat("grass", 0.004, (0.8, 0.9, 0.8))),
        wall_items=(("sofa", 1), ("armchair", 2), ("tv-stand", 1), ("shelf", 1)),
        island="table",
        furniture=(_mat("chelsea", 0.002), _mat("astronaut", 0.002), _mat("grass", 0.003, (0.7, 0.4, 0.35), 1.6),
                   _mat("coffee", 0.002)),
        posters=_PICTURES,
        poster_count=(4, 6),
    ),
    "seminar-room": _Recipe(
        size_ranges_m=((8.0, 9.0), (6.0, 7.0), (2.9, 3.1)),
        floor=(_mat("gravel", 0.005, (0.5, 0.55, 0.65), 1.3), _mat("grass", 0.005, (0.45, 0.5, 0.6), 1.5)),
        ceiling=_CEILING,
        walls=(_mat("brick", 0.004, (0.9, 0.9, 0.9), 1.5), _mat("text", 0.004, (0.9, 0.92, 0.95), 1.3),
               _mat("immunohistochemistry", 0.004)),
        wall_items=(("shelf", 3), ("cabinet", 2), ("desk", 1)),
        island="table",
        furniture=(_mat("coins", 0.003), _mat("gravel", 0.003, (0.8, 0.65, 0.5), 1.3), _mat("coffee", 0.002),
                   _mat("astronaut", 0.002)),
        posters=_PICTURES,
        poster_count=(6, 9),
    ),
}

ROOM_PRESETS: tuple[str, ...] = tuple(_RECIPES)
"""Preset names accepted by ``make_room``."""


def _round_cm(x: float) -> float:
    return round(float(x), 2)


def _uniform(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    return _round_cm(rng.uniform(*lo_hi))


def _pick(rng: np.random.Generator, options: tuple):
    return options[int(rng.integers(len(options)))]


def _wall_piece_to_world(wall: int, start_m: float, local, size) -> tuple[tuple, tuple]:
    """Map a piece (u0, u1, d0, d1, z0, z1) of an item against ``wall`` starting at ``start_m`` along it."""
    X, Y, _ = size
    u0, u1, d0, d1, z0, z1 = local
    a, b = start_m + u0, start_m + u1  # along the wall, in world x or y
    g = _GAP_TO_WALL_M
    if wall == SURFACE_WALL_X0:
        lo, hi = (g + d0, a, z0), (g + d1, b, z1)
    elif wall == SURFACE_WALL_X1:
        lo, hi = (X - g - d1, a, z0), (X - g - d0, b, z1)
    elif wall == SURFACE_WALL_Y0:
        lo, hi = (a, g + d0, z0), (b, g + d1, z1)
    else:
        lo, hi = (a, Y - g - d1, z0), (b, Y - g - d0, z1)
    return tuple(map(_round_cm, lo)), tuple(map(_round_cm, hi))


def _overlaps(r, rects, gap) -> bool:
    return any(r[0] < q[2] + gap and q[0] < r[2] + gap and r[1] < q[3] + gap and q[1] < r[3] + gap for q in rects)


def make_room(preset: str, seed: int = 0) -> RoomSpec:
    """Generate the room ``preset`` (one of ``ROOM_PRESETS``) deterministically from ``seed >= 0``.

    Furniture stands against the walls (plus, for some presets, one free-standing island
    piece in the middle); the walk loop is the largest ellipse keeping ``LOOP_CLEARANCE_M``
    from it all. Same preset and seed give an identical spec.
    """
    if preset not in _RECIPES:
        raise ValueError(f"unknown room preset {preset!r}; valid presets: {', '.join(ROOM_PRESETS)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"make_room: seed must be an int >= 0, got {seed!r}")
    recipe = _RECIPES[preset]
    rng = np.random.default_rng([ROOM_PRESETS.index(preset), int(seed)])
    size = tuple(_uniform(rng, r) for r in recipe.size_ranges_m)
    X, Y, Z = size

    walls = [_pick(rng, recipe.walls) for _ in range(2)]
    surfaces = (_pick(rng, recipe.floor), _pick(rng, recipe.ceiling), walls[0], walls[0], walls[1], walls[1])

    boxes: list[Box] = []
    footprints: list[tuple] = []
    depth_on_wall = dict.fromkeys(WALL_SURFACE_IDS, 0.0)
    for kind, count in recipe.wall_items:
        for _ in range(count):
            w, d, h = (_uniform(rng, r) for r in _SIZES[kind])
            material = _pick(rng, recipe.furniture)
            for _attempt in range(60):
                wall = WALL_SURFACE_IDS[int(rng.integers(4))]
                length = Y if wall in (SURFACE_WALL_X0, SURFACE_WALL_X1) else X
                start = _round_cm(rng.uniform(0.05, length - w - 0.05))
                pieces = [(_wall_piece_to_world(wall, start, local, size), part) for local, part in _PARTS[kind](w, d, h)]
                lo = np.min([p[0][0] for p in pieces], axis=0)
                hi = np.max([p[0][1] for p in pieces], axis=0)
                rect = (lo[0], lo[1], hi[0], hi[1])
                if not _overlaps(rect, footprints, _GAP_BETWEEN_M):
                    footprints.append(rect)
                    depth_on_wall[wall] = max(depth_on_wall[wall], d + _GAP_TO_WALL_M)
                    boxes += [Box(lo_, hi_, material, f"{kind}.{part}") for (lo_, hi_), part in pieces]
                    break

    free = (depth_on_wall[SURFACE_WALL_X0], depth_on_wall[SURFACE_WALL_Y0],
            X - depth_on_wall[SURFACE_WALL_X1], Y - depth_on_wall[SURFACE_WALL_Y1])
    cx, cy = _round_cm((free[0] + free[2]) / 2), _round_cm((free[1] + free[3]) / 2)
    rx = math.floor((min(cx - free[0], free[2] - cx) - LOOP_CLEARANCE_M) * 100) / 100
    ry = math.floor((min(cy - free[1], free[3] - cy) - LOOP_CLEARANCE_M) * 100) / 100
    loop = (cx, cy, rx, ry)

    if recipe.island is not None:
        w, d, h = (_uniform(rng, r) for r in _SIZES[recipe.island])
        material = _pick(rng, recipe.furniture)
        ellipse = np.stack([cx + rx * np.cos(np.linspace(0, 2 * np.pi, 720)),
                            cy + ry * np.sin(np.linspace(0, 2 * np.pi, 720))], axis=-1)
        for _shrink in range(40):  # shrink the island until the loop keeps its clearance around it
            x0, y0 = _round_cm(cx - w / 2), _round_cm(cy - d / 2)
            fx0, fy0, fx1, fy1 = x0, y0, x0 + w, y0 + d
            dx = np.maximum(np.maximum(fx0 - ellipse[:, 0], ellipse[:, 0] - fx1), 0.0)
            dy = np.maximum(np.maximum(fy0 - ellipse[:, 1], ellipse[:, 1] - fy1), 0.0)
            if np.hypot(dx, dy).min() >= LOOP_CLEARANCE_M + 0.01:
                boxes += [Box((_round_cm(x0 + u0), _round_cm(y0 + d0), z0), (_round_cm(x0 + u1), _round_cm(y0 + d1), z1),
                              material, f"{recipe.island}.{part}")
                          for (u0, u1, d0, d1, z0, z1), part in _PARTS[recipe.island](w, d, h)]
                break
            w, d = _round_cm(w * 0.9), _round_cm(d * 0.9)

    posters: list[Poster] = []
    n_posters = int(rng.integers(recipe.poster_count[0], recipe.poster_count[1] + 1))
    placed: dict[int, list[tuple[float, float]]] = {w_: [] for w_ in WALL_SURFACE_IDS}
    textures = list(recipe.posters)
    for _ in range(n_posters):
        for _attempt in range(40):
            wall = WALL_SURFACE_IDS[int(rng.integers(4))]
            length = Y if wall in (SURFACE_WALL_X0, SURFACE_WALL_X1) else X
            width = _uniform(rng, (0.6, 1.3))
            height = _round_cm(width * _pick(rng, (0.75, 1.0, 0.66, 1.33)))
            z_lo, z_hi = 1.0 + height / 2, Z - 0.2 - height / 2  # bottom edge >= 1 m, top 20 cm under the ceiling
            if z_lo > z_hi:
                continue
            cz = _uniform(rng, (z_lo, z_hi))
            cu = _uniform(rng, (0.2 + width / 2, length - 0.2 - width / 2))
            if any(abs(cu - u) < (width + w_) / 2 + 0.15 for u, w_ in placed[wall]):
                continue
            texture = textures.pop(int(rng.integers(len(textures)))) if textures else _pick(rng, recipe.posters)
            posters.append(Poster(wall, texture, cu, cz, width, height))
            placed[wall].append((cu, width))
            break

    return RoomSpec(name=preset, seed=int(seed), size_xyz_m=size, surfaces=surfaces, boxes=tuple(boxes),
                    posters=tuple(posters), walk_loop_xy_m=loop)
