"""LiDAR sweeps on disk: an organised EXR (the whole range image) and a PLY of the returns.

Organised EXR (one file per sweep), every channel ``(C, A)``: rows = beams in ascending
elevation (row 0 lowest; the row index is the ring), columns = azimuth steps ``2 pi a / A``
measured from +x towards +y. Channels:

===========  =======  ==========================================================
``X Y Z``    float32  the return in the sensor frame (x forward, y left, z up), metres
``range``    float32  distance from the sensor origin along the beam, metres
``intensity`` float32 return strength (the renderer's accumulation / reflectance), 0..1
``ring``     uint32   the beam (row) index
===========  =======  ==========================================================

A beam without a return has ``range = inf``, ``X = Y = Z = NaN`` and ``intensity = 0`` -- the
convention of ``nsim.synth.oracle.RoomOracle.lidar_gt`` and ``nsim.sensors.rig.OrganizedScan``.
All of this is also written into the EXR header as string attributes (``nsim_layout``,
``nsim_frame``, ``nsim_miss``, ``nsim_units``), with the beams' elevations
(``nsim_elevations_deg``, comma-separated) and the sensor's name (``nsim_sensor``) when given, so
a file explains itself to any EXR viewer. Storage is lossless (ZIP) and bit-exact.

PLY (``write_lidar_ply``): the returns only, as a binary point cloud (``nsim.io.ply``) with ``x y z``
(float32, sensor frame) and the fields ``intensity`` (float32), ``range`` (float32), ``ring``
(uint16) and ``column`` (uint32, the azimuth index), in row-major order of the range image.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import OpenEXR

from nsim.errors import InputError
from nsim.io import atomic_path
from nsim.io.exr import read_exr
from nsim.io.ply import PointCloud, read_ply, write_ply
from nsim.sensors.rig import OrganizedScan

CHANNELS = ("X", "Y", "Z", "range", "intensity", "ring")
ATTRIBUTES = {
    "nsim_layout": "organised LiDAR sweep: rows = beams in ascending elevation (row 0 lowest, row = ring), "
    "columns = azimuth steps 2*pi*a/A from +x towards +y",
    "nsim_frame": "X Y Z in the sensor frame: x forward, y left, z up",
    "nsim_units": "X Y Z range in metres; intensity in [0, 1]; ring = beam index",
    "nsim_miss": "no return: range = inf, X = Y = Z = NaN, intensity = 0",
}


def write_lidar_exr(
    path: str | os.PathLike,
    scan: OrganizedScan,
    sensor: str | None = None,
    elevations_deg: Sequence[float] | np.ndarray | None = None,
) -> Path:
    """Write a sweep as an organised EXR (see the module docstring), atomically; returns ``path``.

    sensor: the sensor's name (header ``nsim_sensor``); elevations_deg: ``(C,)`` beam elevations
    (header ``nsim_elevations_deg``).
    """
    header: dict = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **ATTRIBUTES}
    if sensor is not None:
        header["nsim_sensor"] = str(sensor)
    if elevations_deg is not None:
        el = np.asarray(elevations_deg, dtype=np.float64)
        if el.shape != (scan.range_m.shape[0],):
            raise ValueError(f"elevations_deg: expected ({scan.range_m.shape[0]},), got {el.shape}")
        header["nsim_elevations_deg"] = ",".join(f"{v:.9g}" for v in el)
    channels = {
        "X": scan.xyz_m[..., 0],
        "Y": scan.xyz_m[..., 1],
        "Z": scan.xyz_m[..., 2],
        "range": scan.range_m,
        "intensity": scan.intensity,
    }
    arrays = {name: np.ascontiguousarray(a, dtype=np.float32) for name, a in channels.items()}
    arrays["ring"] = np.ascontiguousarray(scan.ring, dtype=np.uint32)
    path = Path(path)
    with atomic_path(path) as tmp, OpenEXR.File(header, arrays) as exr:
        exr.write(str(tmp))
    return path


def read_lidar_exr(path: str | os.PathLike) -> OrganizedScan:
    """Read an organised sweep written by ``write_lidar_exr``; missing channels are an InputError."""
    path = Path(path)
    channels = read_exr(path)
    if missing := [c for c in CHANNELS if c not in channels]:
        raise InputError(f"{path}: not an organised LiDAR EXR: missing channels {missing} (has {sorted(channels)})")
    for name in CHANNELS[:-1]:
        if channels[name].dtype.kind != "f":
            raise InputError(f"{path}: channel {name!r} is {channels[name].dtype}, expected float")
    if channels["ring"].dtype.kind not in "ui":
        raise InputError(f"{path}: channel 'ring' is {channels['ring'].dtype}, expected an unsigned int")
    xyz = np.stack([channels[c].astype(np.float32) for c in "XYZ"], axis=-1)
    return OrganizedScan(
        range_m=channels["range"].astype(np.float32),
        xyz_m=xyz,
        intensity=channels["intensity"].astype(np.float32),
        ring=channels["ring"].astype(np.uint16),
    )


def lidar_exr_attributes(path: str | os.PathLike) -> dict[str, str]:
    """The ``nsim_*`` header attributes of a LiDAR EXR (``nsim_elevations_deg`` etc.) as strings."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:  # the header is emptied on exit: copy
            return {k: str(v) for k, v in exr.header().items() if k.startswith("nsim_")}
    except Exception as err:  # the binding raises bare RuntimeError for corrupt files
        raise InputError(f"{path}: not a readable OpenEXR file ({err})") from None


def elevations_from_attributes(attributes: Mapping[str, str]) -> np.ndarray | None:
    """``(C,)`` float64 elevations from ``lidar_exr_attributes``, or None if the file has none."""
    text = attributes.get("nsim_elevations_deg")
    return None if text is None else np.array([float(v) for v in text.split(",")], dtype=np.float64)


def write_lidar_ply(path: str | os.PathLike, scan: OrganizedScan) -> Path:
    """Write the returns of a sweep as a binary PLY (see the module docstring); returns ``path``."""
    hit = scan.hit
    _, cols = np.nonzero(hit)
    return write_ply(
        path,
        scan.xyz_m[hit].astype(np.float32),
        fields={
            "intensity": scan.intensity[hit].astype(np.float32),
            "range": scan.range_m[hit].astype(np.float32),
            "ring": scan.ring[hit].astype(np.uint16),
            "column": cols.astype(np.uint32),
        },
    )


def read_lidar_ply(path: str | os.PathLike) -> PointCloud:
    """Read a PLY written by ``write_lidar_ply``: xyz ``(N, 3)`` float32 and the fields
    ``intensity``, ``range``, ``ring``, ``column`` (each ``(N,)``)."""
    path = Path(path)
    cloud = read_ply(path)
    if missing := [f for f in ("intensity", "range", "ring", "column") if f not in cloud.fields]:
        raise InputError(f"{path}: not a LiDAR PLY: missing fields {missing}")
    return cloud


def scan_from_ply(cloud: PointCloud, shape: tuple[int, int]) -> OrganizedScan:
    """Rebuild the organised sweep ``shape = (C, A)`` from a LiDAR PLY's points (missing beams = no return)."""
    c, a = shape
    ring = cloud.fields["ring"].astype(np.int64)
    col = cloud.fields["column"].astype(np.int64)
    if len(ring) and (ring.max() >= c or col.max() >= a):
        raise ValueError(f"scan_from_ply: points index beyond the shape {shape}")
    range_m = np.full(shape, np.inf, dtype=np.float32)
    xyz = np.full(shape + (3,), np.nan, dtype=np.float32)
    intensity = np.zeros(shape, dtype=np.float32)
    range_m[ring, col] = cloud.fields["range"]
    xyz[ring, col] = cloud.xyz
    intensity[ring, col] = cloud.fields["intensity"]
    rings = np.broadcast_to(np.arange(c, dtype=np.uint16)[:, None], shape).copy()
    return OrganizedScan(range_m=range_m, xyz_m=xyz, intensity=intensity, ring=rings)
