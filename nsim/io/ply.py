"""PLY point clouds: positions, optional uint8 colour, and named per-point scalar fields (via `plyfile`).

On disk: one `vertex` element with properties `x y z` (float or double), optionally `red green blue`
(uchar), then one scalar property per field (e.g. `intensity` float, `ring` ushort). Other elements
(faces of a mesh) are ignored on reading.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement, PlyListProperty, PlyParseError

from nsim.errors import InputError
from nsim.io import atomic_path

_RESERVED = ("x", "y", "z", "red", "green", "blue")
_PLY_DTYPES = {np.dtype(t) for t in ("i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8")}


@dataclass(frozen=True)
class PointCloud:
    """xyz: (N, 3) float32/float64; rgb: (N, 3) uint8 or None; fields: name -> (N,) array."""

    xyz: np.ndarray
    rgb: np.ndarray | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.xyz)
        if self.xyz.shape != (n, 3):
            raise ValueError(f"PointCloud.xyz: expected (N, 3), got {self.xyz.shape}")
        if self.rgb is not None and (self.rgb.shape != (n, 3) or self.rgb.dtype != np.uint8):
            raise ValueError(
                f"PointCloud.rgb: expected ({n}, 3) uint8, got {self.rgb.shape} {self.rgb.dtype}"
            )
        for name, values in self.fields.items():
            if values.shape != (n,):
                raise ValueError(f"PointCloud.fields[{name!r}]: expected ({n},), got {values.shape}")

    def __len__(self) -> int:
        return len(self.xyz)


def write_ply(
    path: str | os.PathLike,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    fields: Mapping[str, np.ndarray] | None = None,
    binary: bool = True,
) -> Path:
    """Write N points atomically as binary little-endian (default) or ASCII PLY; returns `path`.

    xyz: (N, 3) float32 or float64 (kept as is). rgb: (N, 3) uint8. fields: name -> (N,) array of a PLY
    scalar type (int8/16/32, uint8/16/32, float32/64). Both encodings round-trip bit-exactly.
    """
    xyz = np.asarray(xyz)
    fields = {name: np.asarray(v) for name, v in (fields or {}).items()}
    cloud = PointCloud(xyz, None if rgb is None else np.asarray(rgb), fields)  # checks shapes
    if xyz.dtype not in (np.float32, np.float64):
        raise ValueError(f"write_ply: xyz must be float32 or float64, got {xyz.dtype}")
    for name, values in fields.items():
        if name in _RESERVED or name.split() != [name] or not name.isascii():
            raise ValueError(f"write_ply: invalid field name {name!r}")
        if values.dtype not in _PLY_DTYPES:
            raise ValueError(f"write_ply: field {name!r} has dtype {values.dtype}, not a PLY scalar type")
    columns = {c: xyz[:, i] for i, c in enumerate("xyz")}
    if cloud.rgb is not None:
        columns |= {c: cloud.rgb[:, i] for i, c in enumerate(("red", "green", "blue"))}
    columns |= fields
    return write_ply_columns(path, columns, binary=binary)


def write_ply_columns(
    path: str | os.PathLike,
    columns: Mapping[str, np.ndarray],
    faces: np.ndarray | None = None,
    comments: Sequence[str] = (),
    binary: bool = True,
) -> Path:
    """Write a ``vertex`` element with these (N,) columns, in this order, atomically; returns `path`.

    faces: optional (F, 3) vertex indices (a ``face`` element, uchar counts, int32 indices);
    comments: header lines (one line each, no line breaks). Values are stored little-endian as given.
    """
    for c in comments:
        if "\n" in c or "\r" in c:
            raise ValueError(f"PLY comment with a line break: {c!r}")
    n = len(next(iter(columns.values())))
    vertex = np.empty(n, dtype=[(name, np.asarray(v).dtype.newbyteorder("<")) for name, v in columns.items()])
    for name, values in columns.items():
        vertex[name] = values
    elements = [PlyElement.describe(vertex, "vertex")]
    if faces is not None:
        face = np.empty(len(faces), dtype=[("vertex_indices", "<i4", (3,))])
        face["vertex_indices"] = np.asarray(faces).astype("<i4")
        elements.append(PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"},
                                            val_types={"vertex_indices": "i4"}))
    ply = PlyData(elements, text=not binary, byte_order="<", comments=list(comments))
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "xb") as f:
        ply.write(f)
    return path


def read_ply(path: str | os.PathLike) -> PointCloud:
    """Read the `vertex` element of a PLY file (ASCII or binary, either byte order) as a PointCloud.

    rgb is set when `red green blue` are all uchar (otherwise they stay in `fields`). xyz keeps its
    stored float type (integer coordinates become float64). Arrays are native-endian and contiguous.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            ply = PlyData.read(f, mmap=False)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except PlyParseError as err:
        raise InputError(f"{path}: malformed PLY: {err}") from None
    except Exception as err:  # plyfile lets numpy/decoding errors through for some corruptions
        raise InputError(f"{path}: not a readable PLY file ({type(err).__name__}: {err})") from None
    if "vertex" not in ply:
        raise InputError(f"{path}: no 'vertex' element")
    element = ply["vertex"]
    if lists := [p.name for p in element.properties if isinstance(p, PlyListProperty)]:
        raise InputError(f"{path}: vertex list properties are not supported: {lists}")
    data = element.data
    columns = {
        n: np.ascontiguousarray(data[n], dtype=data[n].dtype.newbyteorder("=")) for n in data.dtype.names
    }
    if missing := [c for c in "xyz" if c not in columns]:
        raise InputError(f"{path}: vertex element lacks properties {missing}")
    xyz = np.stack([columns.pop(c) for c in "xyz"], axis=1)
    if xyz.dtype.kind != "f":
        xyz = xyz.astype(np.float64)
    rgb = None
    if all(c in columns and columns[c].dtype == np.uint8 for c in ("red", "green", "blue")):
        rgb = np.stack([columns.pop(c) for c in ("red", "green", "blue")], axis=1)
    return PointCloud(xyz, rgb, columns)
