"""ROS 2 nav2 ``map_server`` maps: ``map.yaml`` + ``map.pgm`` (mode trinary).

nsim's map cells (``nsim.rendering.occupancy``): ``cells (NX, NY)`` int8, ``[i, j]`` the cell
``[x0 + i r, x0 + (i + 1) r) x [y0 + j r, y0 + (j + 1) r)``, values those of
``nav_msgs/OccupancyGrid``: 0 free, 100 occupied, -1 unknown. On disk they become an 8-bit
binary PGM (P5) of width NX and height NY whose row 0 is the *largest* y (north up; the
image's lower-left pixel is cell ``[0, 0]``): 254 free, 0 occupied, 205 unknown, as nav2's
``map_saver`` writes them. The YAML::

    image: map.pgm
    mode: trinary
    resolution: 0.05          # metres per cell
    origin: [x0, y0, 0.0]     # the lower-left corner of cell [0, 0]; yaw 0
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196

``map_server`` reads pixel ``v`` as the occupancy probability ``p = (255 - v) / 255`` (``v / 255``
with ``negate: 1``): occupied when ``p > occupied_thresh``, free when ``p < free_thresh``, unknown
in between (205 gives 0.19608). ``read_nav2_map`` applies the same rules, so it also reads a
trinary map saved by nav2 (PGM or PNG image; the image path relative to the YAML's folder, never
outside it); a scenario names one as its own map (``scene: {nav2_map: map.yaml}``, traced by the
simulate stage). Other modes and a non-zero yaw are refused; every error is one line naming the
file and the field (``map.yaml: resolution: expected > 0 (metres per cell), got -0.05``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nsim.errors import InputError
from nsim.io import atomic_path

PGM_FREE = 254
PGM_OCCUPIED = 0
PGM_UNKNOWN = 205
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
MAX_PIXELS = 1 << 28
"""Largest image ``read_nav2_map`` accepts (checked before memory is allocated)."""

CELL_FREE = 0
CELL_OCCUPIED = 100
CELL_UNKNOWN = -1
"""nsim's cell codes (int8, ``nsim.rendering.occupancy.ObstacleMap.cells``): those of ``nav_msgs/OccupancyGrid``."""


@dataclass(frozen=True, eq=False)
class Nav2Map:
    """A map read back: ``cells (NX, NY)`` int8 (0 free, 100 occupied, -1 unknown), the corner of
    cell ``[0, 0]`` at ``origin_xy_m``, square cells of ``resolution_m``."""

    cells: np.ndarray
    origin_xy_m: tuple[float, float]
    resolution_m: float


def cells_to_image(cells: np.ndarray) -> np.ndarray:
    """``cells (NX, NY)`` int8 -> the map image ``(NY, NX)`` uint8 (254 free, 0 occupied, 205 unknown), row 0 = max y."""
    cells = np.asarray(cells)
    if cells.ndim != 2 or not np.isin(cells, (CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN)).all():
        raise ValueError("cells: expected (NX, NY) with values 0 (free), 100 (occupied), -1 (unknown)")
    img = np.full(cells.shape, PGM_UNKNOWN, dtype=np.uint8)
    img[cells == CELL_FREE] = PGM_FREE
    img[cells == CELL_OCCUPIED] = PGM_OCCUPIED
    return np.ascontiguousarray(img.T[::-1])


def image_to_cells(image: np.ndarray, negate: bool = False, occupied_thresh: float = OCCUPIED_THRESH,
                   free_thresh: float = FREE_THRESH) -> np.ndarray:
    """A trinary map image ``(NY, NX)`` uint8 -> ``cells (NX, NY)`` int8, by map_server's rules."""
    v = np.asarray(image, dtype=np.float64)
    p = v / 255.0 if negate else (255.0 - v) / 255.0
    cells = np.full(v.shape, CELL_UNKNOWN, dtype=np.int8)
    cells[p > occupied_thresh] = CELL_OCCUPIED
    cells[p < free_thresh] = CELL_FREE
    return np.ascontiguousarray(cells[::-1].T)


def _fmt(x: float) -> str:
    return repr(float(x))


def write_nav2_map(yaml_path: str | os.PathLike, cells: np.ndarray, origin_xy_m: tuple[float, float],
                   resolution_m: float) -> Path:
    """Write ``yaml_path`` and the PGM beside it (same stem, ``.pgm``), atomically; returns ``yaml_path``.

    The bytes depend only on the arguments (no timestamps), so the same map gives the same files.
    """
    yaml_path = Path(yaml_path)
    if not (np.isfinite(resolution_m) and resolution_m > 0.0):
        raise ValueError(f"resolution_m: expected > 0, got {resolution_m}")
    img = cells_to_image(cells)
    pgm_path = yaml_path.with_suffix(".pgm")
    header = f"P5\n{img.shape[1]} {img.shape[0]}\n255\n".encode("ascii")
    with atomic_path(pgm_path) as tmp:
        tmp.write_bytes(header + img.tobytes())
    text = (f"image: {pgm_path.name}\nmode: trinary\nresolution: {_fmt(resolution_m)}\n"
            f"origin: [{_fmt(origin_xy_m[0])}, {_fmt(origin_xy_m[1])}, 0.0]\nnegate: 0\n"
            f"occupied_thresh: {OCCUPIED_THRESH}\nfree_thresh: {FREE_THRESH}\n")
    with atomic_path(yaml_path) as tmp:
        tmp.write_text(text)
    return yaml_path


def _read_pgm(path: Path) -> np.ndarray:
    """An 8-bit binary PGM (P5, maxval <= 255) as ``(H, W)`` uint8."""
    data = path.read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace() and data[pos : pos + 1] != b"#":
            pos += 1
        if start == pos:
            raise InputError(f"{path}: truncated PGM header")
        fields.append(data[start:pos])
    if fields[0] != b"P5":
        raise InputError(f"{path}: expected a binary PGM (P5), got {fields[0][:8]!r}")
    try:
        w, h, maxval = (int(f) for f in fields[1:])
    except ValueError:
        raise InputError(f"{path}: malformed PGM header {b' '.join(fields)!r}") from None
    if not (0 < w and 0 < h and w * h <= MAX_PIXELS and 0 < maxval <= 255):
        raise InputError(f"{path}: unsupported PGM {w}x{h}, maxval {maxval} (8-bit, at most {MAX_PIXELS} pixels)")
    pos += 1  # the single whitespace after maxval
    if len(data) - pos != w * h:
        raise InputError(f"{path}: expected {w * h} bytes of pixels, found {len(data) - pos}")
    img = np.frombuffer(data, dtype=np.uint8, count=w * h, offset=pos).reshape(h, w)
    return img if maxval == 255 else np.rint(img.astype(np.float64) * (255.0 / maxval)).astype(np.uint8)


def read_nav2_map(yaml_path: str | os.PathLike) -> Nav2Map:
    """Read a trinary map_server map (``map.yaml`` and the image it names, inside its folder)."""
    from nsim.config import parse_yaml

    yaml_path = Path(yaml_path)
    try:
        text = yaml_path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{yaml_path}: cannot read the map ({exc.__class__.__name__}: {exc})") from None
    doc = parse_yaml(text, yaml_path, InputError)  # one line naming the file and line
    if not isinstance(doc, dict):
        raise InputError(f"{yaml_path}: expected a mapping")

    def field(name, default=None):
        if name not in doc and default is None:
            raise InputError(f"{yaml_path}: {name}: missing")
        return doc.get(name, default)

    def number(name, default=None) -> float:
        return as_number(name, field(name, default))

    def as_number(name, value) -> float:
        try:
            if isinstance(value, bool):
                raise TypeError
            out = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{yaml_path}: {name}: expected a number, got {value!r}") from None
        if not np.isfinite(out):
            raise InputError(f"{yaml_path}: {name}: expected a finite number, got {value!r}")
        return out

    image = field("image")
    mode = field("mode", "trinary")
    if mode != "trinary":
        raise InputError(f"{yaml_path}: mode: only trinary maps are read, got {mode!r}")
    resolution = number("resolution")
    if resolution <= 0.0:
        raise InputError(f"{yaml_path}: resolution: expected > 0 (metres per cell), got {resolution:g}")
    origin = field("origin")
    if not isinstance(origin, list) or len(origin) != 3:
        raise InputError(f"{yaml_path}: origin: expected [x, y, 0.0] (yaw 0), got {origin!r}")
    origin = [as_number(f"origin[{k}]", v) for k, v in enumerate(origin)]
    if origin[2] != 0.0:
        raise InputError(f"{yaml_path}: origin: expected [x, y, 0.0] (yaw 0), got {origin}")
    negate = field("negate", 0)
    if negate not in (0, 1) or isinstance(negate, bool):
        raise InputError(f"{yaml_path}: negate: expected 0 or 1, got {negate!r}")
    occ_t, free_t = number("occupied_thresh", OCCUPIED_THRESH), number("free_thresh", FREE_THRESH)
    if not 0.0 <= free_t <= occ_t <= 1.0:
        raise InputError(f"{yaml_path}: free_thresh, occupied_thresh: expected 0 <= free_thresh <= occupied_thresh <= 1, "
                         f"got {free_t:g}, {occ_t:g}")
    rel = Path(str(image))
    if not isinstance(image, str) or not image or rel.is_absolute() or ".." in rel.parts:
        raise InputError(f"{yaml_path}: image: expected a path inside the map's folder, got {image!r}")
    img_path = yaml_path.parent / rel
    if not img_path.is_file():
        raise InputError(f"{yaml_path}: image: {image!r} not found (no file {img_path})")
    if img_path.suffix.lower() == ".pgm":
        img = _read_pgm(img_path)
    else:
        import cv2

        img = cv2.imread(str(img_path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{img_path}: not an image OpenCV can read")
    cells = image_to_cells(img, bool(negate), occ_t, free_t)
    return Nav2Map(cells, (origin[0], origin[1]), resolution)
