"""A robot's sensor rig: cameras, depth cameras and LiDARs mounted on its body, read from YAML.

Frames
    ``body``: the robot's body frame, x forward, y left, z up -- the frame of the trajectory's
    ``robot_pose_se3`` (``body_to_world``). Camera sensors use OpenCV optical axes (+x right, +y
    down, +z forward); LiDARs are x forward, y left, z up (``nsim.sensors.lidar``). A sensor's
    mount is ``sensor_to_body (4, 4)``, so ``sensor_to_world = body_to_world @ sensor_to_body``.

Rig file (``nsim/configs/robots/*.yaml``)::

    name: spot                  # optional, default: the file name
    urdf: spot_like.urdf        # optional: mounts may name links of this URDF (relative to the file)
    sensors:
      - name: frontleft         # unique; [A-Za-z0-9_-]
        type: camera            # camera (RGB/gray, optionally depth) | depth (depth only) | lidar
        mount: {xyz_m: [0.42, 0.04, 0.0], rpy_deg: [0, 30, -20]}
        intrinsics: {model: OPENCV_FISHEYE, width: 640, height: 480, preset: spot_fisheye}
        color: rgb              # camera only: rgb | gray
        exposure_ev: 0.0        # camera only: exposure change in stops
        depth: true             # camera: also emit depth (true, or a depth block); depth: the depth block
      - name: lidar
        type: lidar
        mount: {xyz_m: [0, 0, 0.25]}
        lidar: {channels: 16, vertical_fov_deg: [-15, 15], azimuth_samples: 1800}

``mount`` keys (all optional): ``xyz_m`` translation; at most one rotation -- ``rpy_deg`` (roll,
pitch, yaw in degrees, fixed-axis as URDF: ``Rz(yaw) Ry(pitch) Rx(roll)``), ``quat_wxyz`` (unit)
or ``rotation_matrix`` (3 rows, orthonormal, det +1); ``axes``: ``link`` (default) when the
rotation orients the sensor's *link* frame (x = viewing direction, y left, z up, as ROS
``camera_link``; cameras get the optical axes from it, ``R_link_optical = [[0,0,1],[-1,0,0],[0,-1,0]]``),
``optical`` when it orients the OpenCV optical frame directly (cameras only); ``link`` (and
optionally ``urdf`` and ``base_link``): start from that URDF link's frame in ``base_link``'s frame
(default: the URDF's root link, which must be the body), then apply ``xyz_m`` and the rotation
as an offset in the link's frame.

``intrinsics`` keys: ``model`` (PINHOLE, OPENCV, FULL_OPENCV, OPENCV_FISHEYE, EQUIRECTANGULAR), ``width``,
``height`` and one of: ``preset: spot_fisheye`` (``Camera.fisheye_spot_like``), ``hfov_deg``
(a centred PINHOLE, ``Camera.pinhole_from_fov``), or ``fx`` (``fy`` defaults to ``fx``, ``cx, cy``
to the image centre, OpenCV pixel convention) with ``dist`` as ``nsim.geometry.Camera`` takes it.
A depth block is ``nsim.sensors.depth_model.DepthConfig``; a lidar block is :class:`LidarSpec`.

Every error is one :class:`~nsim.errors.ConfigError` line naming the file, the line and the
sensor: ``spot.yaml:14: sensor 'frontleft': mount.quat_wxyz: norm 1.2, expected a unit quaternion``.

Rays (``Sensor.rays``) are flattened row-major from ``Sensor.ray_shape``: ``(H, W)`` pixels for
cameras (index ``v * W + u``), ``(channels, azimuth_samples)`` for LiDARs (index ``ring * A + a``).
Everything is float64 numpy and deterministic; per-sensor directions are computed once.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import yaml

from nsim.config import from_dict, param, parse_yaml, read_text_file, to_dict
from nsim.errors import ConfigError, NsimError
from nsim.geometry.cameras import MODELS, Camera, dirs_to_world
from nsim.geometry.transforms import is_rotation, make_se3, matrix_from_quat_wxyz
from nsim.sensors.depth_model import DepthConfig, apply_depth_model, range_to_z_depth
from nsim.sensors.lidar import BeamPattern, LidarConfig
from nsim.sensors.urdf import Urdf, load_urdf, rpy_to_matrix

SENSOR_TYPES = ("camera", "depth", "lidar")
COLORS = ("rgb", "gray")
INTRINSICS_PRESETS = ("spot_fisheye",)
#: Columns: the OpenCV optical axes (x right, y down, z forward) in a FLU link frame (REP 103).
LINK_TO_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
LINK_TO_OPTICAL.setflags(write=False)
_NAME_RE = re.compile(r"[A-Za-z0-9_-]+")
_UNIT_TOL = 1e-6


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------------------
# Typed blocks of the rig file (strict: unknown keys, wrong types and ranges fail by name)
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MountSpec:
    """A sensor's ``mount`` block as written (see the module docstring)."""

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] | None = None
    quat_wxyz: tuple[float, float, float, float] | None = None
    rotation_matrix: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]] | None = None
    axes: str = param("link", choices=("link", "optical"))
    urdf: str | None = None
    link: str | None = None
    base_link: str | None = None


@dataclass(frozen=True)
class IntrinsicsSpec:
    """A camera's ``intrinsics`` block as written (see the module docstring)."""

    model: str = param("PINHOLE", choices=MODELS)
    width: int = param(640, ge=1, le=16384)
    height: int = param(480, ge=1, le=16384)
    preset: str | None = param(None, choices=INTRINSICS_PRESETS)
    hfov_deg: float | None = param(None, gt=0.0, lt=180.0)
    fx: float | None = param(None, gt=0.0)
    fy: float | None = param(None, gt=0.0)
    cx: float | None = None
    cy: float | None = None
    dist: tuple[float, ...] = ()


@dataclass(frozen=True)
class LidarSpec(LidarConfig):
    """A LiDAR's ``lidar`` block: :class:`~nsim.sensors.lidar.LidarConfig` (its keys and defaults) plus
    explicit beam angles and dropout.

    vertical_angles_deg: explicit beam elevations (sorted ascending into rows, ring 0 lowest; must be
    distinct); when given, ``channels`` (if set) must match their count, and ``channels`` and
    ``vertical_fov_deg`` become their count and span (a written ``vertical_fov_deg`` is ignored).
    channels: unset (None) means the angles' count, else ``LidarConfig``'s default.
    dropout_prob: chance that a return is lost (range -> inf).
    """

    channels: int | None = param(None, ge=1)
    vertical_angles_deg: tuple[float, ...] | None = None
    dropout_prob: float = param(0.0, ge=0.0, lt=1.0)

    def __post_init__(self) -> None:
        if self.vertical_angles_deg is not None:
            try:
                beams = BeamPattern.from_angles(self.vertical_angles_deg, self.azimuth_samples)
            except ValueError as exc:  # name the block's key, not BeamPattern's field
                key, _, message = str(exc).partition(": ")
                key = {"elevations_deg": "vertical_angles_deg"}.get(key.split(".")[-1], key.split(".")[-1])
                raise ValueError(f"LidarSpec.{key}: {message}") from None
            if self.channels is not None and self.channels != beams.channels:
                raise ValueError(f"LidarSpec.channels: {self.channels} channels but {beams.channels} vertical_angles_deg")
            object.__setattr__(self, "vertical_angles_deg", beams.elevations_deg)
            object.__setattr__(self, "channels", beams.channels)
            object.__setattr__(self, "vertical_fov_deg", (beams.elevations_deg[0], beams.elevations_deg[-1]))
        elif self.channels is None:
            object.__setattr__(self, "channels", LidarConfig.__dataclass_fields__["channels"].default)
        super().__post_init__()
        if not (0.0 <= self.dropout_prob < 1.0):
            raise ValueError(f"LidarSpec.dropout_prob: expected 0 <= p < 1, got {self.dropout_prob!r}")

    @property
    def beams(self) -> BeamPattern:
        """The explicit ``vertical_angles_deg`` when given, else ``LidarConfig``'s even spread."""
        if self.vertical_angles_deg is None:
            return super().beams
        return BeamPattern(self.vertical_angles_deg, self.azimuth_samples)

    def config(self) -> LidarConfig:
        """The ``LidarConfig`` part (its fields only): a ``LidarSensor``'s ``config``."""
        return LidarConfig(**{f.name: getattr(self, f.name) for f in fields(LidarConfig)})


# --------------------------------------------------------------------------------------
# Sensors
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Sensor:
    """A mounted sensor. sensor_to_body: ``(4, 4)`` float64 (read-only); see the module docstring."""

    name: str
    sensor_to_body: np.ndarray
    type: ClassVar[str] = ""

    @property
    def ray_shape(self) -> tuple[int, int]:
        """Layout of the sensor's rays: ``(H, W)`` for cameras, ``(channels, azimuth_samples)`` for LiDARs."""
        raise NotImplementedError

    @property
    def dirs_sensor(self) -> np.ndarray:
        """Unit ray directions in the sensor frame, ``(*ray_shape, 3)`` float64, read-only."""
        raise NotImplementedError

    def world_pose(self, body_to_world: np.ndarray) -> np.ndarray:
        """``sensor_to_world (..., 4, 4) = body_to_world (..., 4, 4) @ sensor_to_body``."""
        body_to_world = np.asarray(body_to_world, dtype=np.float64)
        if body_to_world.ndim < 2 or body_to_world.shape[-2:] != (4, 4):
            raise ValueError(f"body_to_world: expected shape (..., 4, 4), got {body_to_world.shape}")
        return body_to_world @ self.sensor_to_body

    def rays(self, body_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame ray origins and unit directions, each ``(N, 3)`` float64 with ``N = prod(ray_shape)``.

        body_to_world: ``(4, 4)``. Row-major over ``ray_shape`` (see the module docstring).
        """
        pose = self.world_pose(body_to_world)
        if pose.shape != (4, 4):
            raise ValueError(f"body_to_world: expected shape (4, 4), got {pose.shape}")
        origins, dirs = dirs_to_world(self.dirs_sensor.reshape(-1, 3), pose, normalize=False)
        return np.ascontiguousarray(origins), dirs


@dataclass(frozen=True, eq=False)
class CameraSensor(Sensor):
    """A camera (``type`` ``camera``: RGB or gray, with depth if ``depth`` is set) or a depth camera
    (``type`` ``depth``: depth only). Sensor frame: OpenCV optical axes.

    camera: intrinsics and image size; color: ``rgb`` | ``gray``; exposure_ev: exposure change in
    stops applied by ``expose``; depth: the depth output, or None for an image-only camera.
    """

    camera: Camera
    kind: str = "camera"
    color: str = "rgb"
    exposure_ev: float = 0.0
    depth: DepthConfig | None = None

    @property
    def type(self) -> str:  # type: ignore[override]
        return self.kind

    @property
    def emits_image(self) -> bool:
        return self.kind == "camera"

    @property
    def emits_depth(self) -> bool:
        return self.depth is not None

    @property
    def ray_shape(self) -> tuple[int, int]:
        return (self.camera.height, self.camera.width)

    @cached_property
    def dirs_sensor(self) -> np.ndarray:
        """Unit directions ``(H, W, 3)`` through every pixel centre, camera axes (read-only)."""
        return _readonly(self.camera.pixel_dirs_cam())

    def depth_from_range(self, range_m: np.ndarray) -> np.ndarray:
        """Exact depth ``(H, W)`` float64 in this camera's ``depth.kind`` from ray range ``range_m (H, W)``.

        ``z``: ``r * d_z``, NaN where a fisheye pixel looks 90 deg or more off-axis; ``range``: ``r``.
        inf (no hit) stays inf.
        """
        if self.depth is None:
            raise ValueError(f"sensor {self.name!r} has no depth output")
        range_m = np.asarray(range_m, dtype=np.float64)
        if range_m.shape != self.ray_shape:
            raise ValueError(f"range_m: expected shape {self.ray_shape}, got {range_m.shape}")
        if self.depth.kind == "range":
            return range_m.copy()
        return range_to_z_depth(range_m, self.dirs_sensor[..., 2])

    def measure_depth(self, range_m: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """The depth image ``(H, W)`` float32 this camera outputs for ray range ``range_m (H, W)``:
        ``depth_from_range`` then the noise/quantisation/valid-range model (``rng`` if noisy)."""
        return apply_depth_model(self.depth_from_range(range_m), self.depth, rng)

    def expose(self, rgb: np.ndarray) -> np.ndarray:
        """The image this camera records from a rendered display-referred colour image ``rgb (H, W, 3)``
        in [0, 1] (what a NeRF trained on 8-bit images renders).

        ``exposure_ev != 0``: sRGB decode, scale the linear values by ``2 ** exposure_ev``, clip,
        re-encode. ``color: gray``: Rec. 709 luma of the linear values, re-encoded, ``(H, W)``.
        Otherwise the input is returned unchanged (float32).
        """
        rgb = np.asarray(rgb, dtype=np.float32)
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise ValueError(f"rgb: expected shape (H, W, 3), got {rgb.shape}")
        if self.exposure_ev == 0.0 and self.color == "rgb":
            return rgb
        lin = _srgb_to_linear(np.clip(rgb, 0.0, 1.0)) * np.float32(2.0**self.exposure_ev)
        if self.color == "gray":
            lin = lin @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        return _linear_to_srgb(np.clip(lin, 0.0, 1.0)).astype(np.float32)


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


@dataclass(frozen=True, eq=False)
class OrganizedScan:
    """One LiDAR sweep as an organised image, sensor frame (x forward, y left, z up).

    range_m: (C, A) float32, inf = no return; xyz_m: (C, A, 3) float32, NaN where no return;
    intensity: (C, A) float32 (0 where no return); ring: (C, A) uint16, the row (beam) index,
    0 = lowest elevation. Rows = beams in ascending elevation, columns = azimuth steps.
    """

    range_m: np.ndarray
    xyz_m: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray

    def __post_init__(self) -> None:
        shape = self.range_m.shape
        if len(shape) != 2 or 0 in shape:
            raise ValueError(f"OrganizedScan.range_m: expected non-empty (C, A), got {shape}")
        if self.xyz_m.shape != shape + (3,):
            raise ValueError(f"OrganizedScan.xyz_m: expected {shape + (3,)}, got {self.xyz_m.shape}")
        for name in ("intensity", "ring"):
            if getattr(self, name).shape != shape:
                raise ValueError(f"OrganizedScan.{name}: expected {shape}, got {getattr(self, name).shape}")

    @property
    def hit(self) -> np.ndarray:
        """(C, A) bool: the beam returned (finite range)."""
        return np.isfinite(self.range_m)

    @classmethod
    def from_ranges(
        cls, range_m: np.ndarray, dirs_sensor: np.ndarray, intensity: np.ndarray | None = None
    ) -> OrganizedScan:
        """Scan from ranges ``(C, A)`` (inf/NaN = no return) and unit directions ``(C, A, 3)``.

        intensity: (C, A) or None (then 1 for returns). Non-returns get inf range, NaN xyz, 0 intensity.
        """
        r = np.asarray(range_m, dtype=np.float64)
        d = np.asarray(dirs_sensor, dtype=np.float64)
        if r.ndim != 2 or d.shape != r.shape + (3,):
            raise ValueError(f"from_ranges: expected range (C, A) and dirs (C, A, 3), got {r.shape}, {d.shape}")
        hit = np.isfinite(r)
        inten = np.ones(r.shape) if intensity is None else np.asarray(intensity, dtype=np.float64)
        if inten.shape != r.shape:
            raise ValueError(f"from_ranges: intensity must be {r.shape}, got {inten.shape}")
        xyz = np.where(hit[..., None], np.where(hit, r, 0.0)[..., None] * d, np.nan)
        ring = np.broadcast_to(np.arange(r.shape[0], dtype=np.uint16)[:, None], r.shape).copy()
        return cls(
            range_m=np.where(hit, r, np.inf).astype(np.float32),
            xyz_m=xyz.astype(np.float32),
            intensity=np.where(hit, inten, 0.0).astype(np.float32),
            ring=ring,
        )


@dataclass(frozen=True, eq=False)
class LidarSensor(Sensor):
    """A spinning LiDAR. Sensor frame x forward, y left, z up (``nsim.sensors.lidar``).

    config: range, noise and azimuth settings (``LidarConfig``); its ``channels`` and
    ``vertical_fov_deg`` are the beams' count and span. elevations_deg: ``(C,)`` ascending, the beams'
    elevations (row ``c`` = ring ``c``), read-only; dropout_prob: chance a return is lost.

    ``beams`` (elevations_deg x ``config.azimuth_samples``) is where this LiDAR's beams point: its
    rays, and what ``render_lidar`` and the oracle's ``lidar_gt`` scan with when given the sensor.
    Give them the sensor, not ``config``: ``config.beams`` are spread evenly, which explicit
    ``vertical_angles_deg`` are not.
    """

    config: LidarConfig
    elevations_deg: np.ndarray
    dropout_prob: float = 0.0
    type: ClassVar[str] = "lidar"

    def __post_init__(self) -> None:
        el = np.array(self.elevations_deg, dtype=np.float64)  # a copy: the caller's array stays writable
        el.setflags(write=False)
        object.__setattr__(self, "elevations_deg", el)
        beams = self.beams  # checks the elevations (ascending, distinct, within [-90, 90])
        cfg = self.config
        if beams.channels != cfg.channels or (beams.elevations_deg[0], beams.elevations_deg[-1]) != cfg.vertical_fov_deg:
            raise ValueError(f"sensor {self.name!r}: {beams.channels} elevations spanning "
                             f"[{beams.elevations_deg[0]:g}, {beams.elevations_deg[-1]:g}] deg, but config has "
                             f"{cfg.channels} channels over {list(cfg.vertical_fov_deg)} deg")

    @cached_property
    def beams(self) -> BeamPattern:
        """The beam pattern: ``elevations_deg`` (rows) x ``config.azimuth_samples`` (columns)."""
        return BeamPattern(tuple(self.elevations_deg.tolist()), self.config.azimuth_samples)

    @property
    def ray_shape(self) -> tuple[int, int]:
        return self.beams.shape

    @property
    def evenly_spaced(self) -> bool:
        """Whether the beams are ``config.beams`` (evenly over the vertical FoV)."""
        return self.beams == self.config.beams

    @cached_property
    def dirs_sensor(self) -> np.ndarray:
        """Unit beam directions ``(C, A, 3)`` (``BeamPattern.directions``), read-only."""
        return _readonly(self.beams.directions())

    def measure(self, range_m: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """The ranges ``(C, A)`` float32 this LiDAR reports for exact ranges ``range_m (C, A)`` (inf = miss).

        Gaussian noise (``range_noise_std_m``), then dropout (``dropout_prob``), then the
        ``[min_range_m, max_range_m]`` gate; lost or gated returns are inf. One noise draw and one
        dropout draw per beam for the whole scan, so draws do not depend on the scene. ``rng`` is
        required when either is nonzero.
        """
        r = np.asarray(range_m, dtype=np.float64)
        if r.shape != self.ray_shape:
            raise ValueError(f"range_m: expected shape {self.ray_shape}, got {r.shape}")
        cfg = self.config
        if (cfg.range_noise_std_m > 0.0 or self.dropout_prob > 0.0) and rng is None:
            raise ValueError(f"sensor {self.name!r}: range noise / dropout need a seeded rng (np.random.Generator)")
        if cfg.range_noise_std_m > 0.0:
            r = r + rng.normal(0.0, cfg.range_noise_std_m, size=r.shape)
        if self.dropout_prob > 0.0:
            r = np.where(rng.random(r.shape) < self.dropout_prob, np.inf, r)
        ok = np.isfinite(r) & (r >= cfg.min_range_m) & (r <= cfg.max_range_m)
        return np.where(ok, r, np.inf).astype(np.float32)

    def scan(self, range_m: np.ndarray, intensity: np.ndarray | None = None) -> OrganizedScan:
        """Organised scan (points in the sensor frame) from reported ranges ``(C, A)``."""
        return OrganizedScan.from_ranges(range_m, self.dirs_sensor, intensity)


# --------------------------------------------------------------------------------------
# The rig
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Rig:
    """A robot's sensors. ``sensors`` keep the file's order; ``rig["name"]`` looks one up."""

    name: str
    sensors: tuple[Sensor, ...]
    source: Path | None = None

    def __getitem__(self, name: str) -> Sensor:
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(f"rig {self.name!r} has no sensor {name!r} (has {', '.join(self.names)})")

    def __iter__(self):
        return iter(self.sensors)

    def __len__(self) -> int:
        return len(self.sensors)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    @property
    def cameras(self) -> tuple[CameraSensor, ...]:
        """Camera and depth-camera sensors, in file order."""
        return tuple(s for s in self.sensors if isinstance(s, CameraSensor))

    @property
    def lidars(self) -> tuple[LidarSensor, ...]:
        return tuple(s for s in self.sensors if isinstance(s, LidarSensor))

    def to_dict(self) -> dict[str, Any]:
        """The resolved rig as plain JSON-ready data (mounts as ``sensor_to_body`` rows, URDF links
        resolved), for manifests and run-cache keys: equal rigs give equal data whatever file said it."""
        sensors = []
        for s in self.sensors:
            d: dict[str, Any] = {"name": s.name, "type": s.type, "sensor_to_body": s.sensor_to_body.tolist()}
            if isinstance(s, CameraSensor):
                d |= {"camera": s.camera.to_dict(), "color": s.color, "exposure_ev": s.exposure_ev,
                      "depth": None if s.depth is None else to_dict(s.depth)}
            elif isinstance(s, LidarSensor):
                d |= {"lidar": to_dict(s.config), "elevations_deg": s.elevations_deg.tolist(),
                      "dropout_prob": s.dropout_prob}
            sensors.append(d)
        return {"name": self.name, "sensors": sensors}

    @classmethod
    def from_resolved(cls, data: Mapping[str, Any]) -> Rig:
        """The rig back from :meth:`to_dict` output (e.g. a render artifact's ``rig.json``)."""
        sensors: list[Sensor] = []
        for d in data["sensors"]:
            pose = _readonly(np.asarray(d["sensor_to_body"], dtype=np.float64))
            if d["type"] == "lidar":
                sensors.append(LidarSensor(name=d["name"], sensor_to_body=pose, config=from_dict(LidarConfig, d["lidar"]),
                                           elevations_deg=np.asarray(d["elevations_deg"], dtype=np.float64),
                                           dropout_prob=float(d["dropout_prob"])))
            else:
                depth = None if d.get("depth") is None else from_dict(DepthConfig, d["depth"])
                sensors.append(CameraSensor(name=d["name"], sensor_to_body=pose, camera=Camera.from_dict(d["camera"]),
                                            kind=d["type"], color=d["color"], exposure_ev=float(d["exposure_ev"]),
                                            depth=depth))
        return cls(name=data["name"], sensors=tuple(sensors))

    @classmethod
    def load(cls, path: str | Path) -> Rig:
        """Read and validate a rig YAML file (see the module docstring)."""
        path = Path(path)
        text = read_text_file(path, "rig")
        data = parse_yaml(text, path)
        return cls.from_data(data, source=path, lines=_line_index(text))

    @classmethod
    def from_data(
        cls, data: Any, *, source: str | Path = "<rig>", lines: Mapping[tuple, int] | None = None
    ) -> Rig:
        """Validate plain rig data (as the YAML file holds it). URDF paths are relative to ``source``'s folder."""
        return _RigParser(Path(source), lines or {}).parse(data)


def _line_index(text: str) -> dict[tuple, int]:
    """Map each key path in a YAML document (``("sensors", 2, "mount")``) to its 1-based line."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    index: dict[tuple, int] = {}

    def walk(node, path: tuple) -> None:
        index[path] = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                if isinstance(key, yaml.ScalarNode):
                    walk(value, path + (key.value,))
                    index[path + (key.value,)] = key.start_mark.line + 1  # the key's line, not the value's
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                walk(item, path + (i,))

    if root is not None:
        walk(root, ())
    return index


class _RigParser:
    """Turns rig data into a Rig; every failure is one ConfigError naming file, line and sensor."""

    def __init__(self, source: Path, lines: Mapping[tuple, int]) -> None:
        self.source = source
        self.lines = lines
        self.urdfs: dict[Path, Urdf] = {}
        self.default_urdf: str | None = None

    def where(self, path: tuple) -> str:
        """``file:line`` of the deepest part of ``path`` the file has (``file`` alone without lines)."""
        for k in range(len(path), -1, -1):
            if path[:k] in self.lines:
                return f"{self.source}:{self.lines[path[:k]]}"
        return str(self.source)

    def fail(self, path: tuple, message: str, sensor: str | None = None, key: str | None = None) -> ConfigError:
        """One-line error at ``path`` (``("sensors", i, ...)``); ``key`` overrides the dotted key shown."""
        if sensor is not None:
            dotted = key if key is not None else ".".join(str(k) for k in path[2:])
            return ConfigError(f"{self.where(path)}: sensor {sensor!r}: {dotted + ': ' if dotted else ''}{message}")
        dotted = "".join(f"[{k}]" if isinstance(k, int) else (f".{k}" if i else str(k)) for i, k in enumerate(path))
        return ConfigError(f"{self.where(path)}: {dotted + ': ' if dotted else ''}{message}")

    def block(self, cls: type, data: Any, path: tuple, sensor: str):
        """Strictly parse a typed block (``nsim.config.from_dict``); errors name the sensor and dotted key."""
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise self.fail(path, f"expected a mapping, got {type(data).__name__}", sensor)
        try:
            return from_dict(cls, data)
        except ConfigError as exc:
            msg = str(exc).removeprefix(f"{cls.__name__}: ")
            key, _, rest = msg.partition(": ")
            for base in cls.__mro__:  # a __post_init__ error names its class: LidarConfig.max_range_m
                key = key.removeprefix(f"{base.__name__}.")
            top = key.split(".")[0].split("[")[0]
            line_path = path + (top,) if top in data else path
            block = ".".join(str(k) for k in path[2:])
            raise self.fail(line_path, rest, sensor, key=f"{block}.{key}") from None

    def parse(self, data: Any) -> Rig:
        if not isinstance(data, Mapping):
            raise self.fail((), "expected a mapping with a 'sensors' list at the top level")
        if unknown := sorted(set(data) - {"name", "urdf", "sensors"}):
            raise self.fail((unknown[0],), "unknown key; valid keys: name, urdf, sensors")
        name = data.get("name", self.source.stem)
        if not isinstance(name, str) or not name:
            raise self.fail(("name",), f"expected a non-empty string, got {name!r}")
        urdf = data.get("urdf")
        if urdf is not None and not isinstance(urdf, str):
            raise self.fail(("urdf",), f"expected a path string, got {urdf!r}")
        self.default_urdf = urdf
        sensors = data.get("sensors")
        if sensors is None:
            raise self.fail(("sensors",), "required key is missing")
        if not isinstance(sensors, list) or not sensors:
            raise self.fail(("sensors",), "expected a non-empty list of sensors")
        out: list[Sensor] = []
        seen: dict[str, int] = {}
        for i, item in enumerate(sensors):
            sensor = self.sensor(item, ("sensors", i))
            if sensor.name in seen:
                raise self.fail(("sensors", i, "name"), f"duplicate sensor name {sensor.name!r} (also sensors[{seen[sensor.name]}])")
            seen[sensor.name] = i
            out.append(sensor)
        return Rig(name=name, sensors=tuple(out), source=self.source)

    def sensor(self, item: Any, path: tuple) -> Sensor:
        if not isinstance(item, Mapping):
            raise self.fail(path, f"expected a sensor mapping, got {type(item).__name__}")
        name = item.get("name")
        if name is None:
            raise self.fail(path, "sensor has no 'name'")
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
            raise self.fail(path + ("name",), f"expected a name of letters, digits, '_' or '-', got {name!r}")
        kind = item.get("type")
        if kind is None:
            raise self.fail(path, "type: required key is missing (camera, depth or lidar)", name)
        if kind not in SENSOR_TYPES:
            raise self.fail(path + ("type",), f"unknown sensor type {kind!r} (expected one of {', '.join(SENSOR_TYPES)})", name)
        allowed = {
            "camera": {"name", "type", "mount", "intrinsics", "color", "exposure_ev", "depth"},
            "depth": {"name", "type", "mount", "intrinsics", "depth"},
            "lidar": {"name", "type", "mount", "lidar"},
        }[kind]
        if unknown := sorted(set(item) - allowed):
            raise self.fail(path + (unknown[0],), f"unknown key for a {kind} sensor; valid keys: {', '.join(sorted(allowed))}", name)
        if "mount" not in item:
            raise self.fail(path, "mount: required key is missing", name)
        mount_spec = self.block(MountSpec, item["mount"], path + ("mount",), name)
        sensor_to_body = self.mount(mount_spec, kind, path + ("mount",), name)
        if kind == "lidar":
            if "lidar" not in item:
                raise self.fail(path, "lidar: required key is missing", name)
            return self.lidar(name, sensor_to_body, item["lidar"], path + ("lidar",))
        if "intrinsics" not in item:
            raise self.fail(path, "intrinsics: required key is missing", name)
        camera = self.intrinsics(self.block(IntrinsicsSpec, item["intrinsics"], path + ("intrinsics",), name),
                                 path + ("intrinsics",), name)
        depth_raw = item.get("depth", kind == "depth")
        if depth_raw is False:
            if kind == "depth":
                raise self.fail(path + ("depth",), "a depth sensor cannot have depth: false", name)
            depth = None
        elif depth_raw is True:
            depth = DepthConfig()
        elif isinstance(depth_raw, Mapping):
            depth = self.block(DepthConfig, depth_raw, path + ("depth",), name)
        else:
            raise self.fail(path + ("depth",), f"expected true, false or a depth mapping, got {depth_raw!r}", name)
        color = item.get("color", "rgb")
        if color not in COLORS:
            raise self.fail(path + ("color",), f"{color!r} is not one of {', '.join(COLORS)}", name)
        ev = item.get("exposure_ev", 0.0)
        if isinstance(ev, bool) or not isinstance(ev, int | float) or not math.isfinite(ev):
            raise self.fail(path + ("exposure_ev",), f"expected a finite number of stops, got {ev!r}", name)
        return CameraSensor(name=name, sensor_to_body=_readonly(sensor_to_body), camera=camera, kind=kind,
                            color=color, exposure_ev=float(ev), depth=depth)

    def rotation(self, m: MountSpec, path: tuple, sensor: str) -> np.ndarray:
        given = [k for k in ("rpy_deg", "quat_wxyz", "rotation_matrix") if getattr(m, k) is not None]
        if len(given) > 1:
            raise self.fail(path + (given[1],), f"give one rotation, got {' and '.join(given)}", sensor)
        if not given:
            return np.eye(3)
        if m.rpy_deg is not None:
            return rpy_to_matrix(np.radians(m.rpy_deg))
        if m.quat_wxyz is not None:
            q = np.asarray(m.quat_wxyz, dtype=np.float64)
            norm = float(np.linalg.norm(q))
            if not np.all(np.isfinite(q)) or abs(norm - 1.0) > _UNIT_TOL:
                raise self.fail(path + ("quat_wxyz",), f"norm {norm:.6g}, expected a unit quaternion (w, x, y, z)", sensor)
            return matrix_from_quat_wxyz(q)
        R = np.asarray(m.rotation_matrix, dtype=np.float64)
        if not is_rotation(R, tol=_UNIT_TOL):
            err = float(np.abs(R.T @ R - np.eye(3)).max()) if np.all(np.isfinite(R)) else math.inf
            raise self.fail(path + ("rotation_matrix",),
                            f"not a rotation (orthonormal with det +1): max |R^T R - I| = {err:.3g}, det = {np.linalg.det(R):.6g}",
                            sensor)
        return R

    def mount(self, m: MountSpec, kind: str, path: tuple, sensor: str) -> np.ndarray:
        if not all(math.isfinite(v) for v in m.xyz_m):
            raise self.fail(path + ("xyz_m",), f"expected finite metres, got {list(m.xyz_m)}", sensor)
        if m.axes == "optical" and kind == "lidar":
            raise self.fail(path + ("axes",), "a lidar has no optical frame; use axes: link", sensor)
        offset = make_se3(self.rotation(m, path, sensor), np.asarray(m.xyz_m, dtype=np.float64))
        base = np.eye(4)
        if m.link is not None:
            base = self.urdf_link(m, path, sensor)
        elif m.urdf is not None or m.base_link is not None:
            raise self.fail(path + ("link",), "urdf/base_link need a link name", sensor)
        pose = base @ offset
        if kind != "lidar" and m.axes == "link":
            pose = pose @ make_se3(LINK_TO_OPTICAL, np.zeros(3))
        return pose

    def urdf_link(self, m: MountSpec, path: tuple, sensor: str) -> np.ndarray:
        rel = m.urdf if m.urdf is not None else self.default_urdf
        if rel is None:
            raise self.fail(path + ("link",), "a link needs a URDF: set mount.urdf or the rig's urdf", sensor)
        urdf_path = (self.source.parent / rel) if not Path(rel).is_absolute() else Path(rel)
        try:
            if urdf_path not in self.urdfs:
                self.urdfs[urdf_path] = load_urdf(urdf_path)
            urdf = self.urdfs[urdf_path]
            reference = m.base_link if m.base_link is not None else urdf.root_link
            return urdf.link_to_link(m.link, reference)
        except NsimError as exc:
            raise self.fail(path + ("link",), str(exc), sensor) from None

    def intrinsics(self, s: IntrinsicsSpec, path: tuple, sensor: str) -> Camera:
        ways = [k for k in ("preset", "hfov_deg", "fx") if getattr(s, k) is not None]
        if len(ways) != 1 and s.model != "EQUIRECTANGULAR":
            got = " and ".join(ways) if ways else "none"
            raise self.fail(path, f"give exactly one of preset, hfov_deg or fx (got {got})", sensor)
        try:
            if s.preset == "spot_fisheye":
                if s.model != "OPENCV_FISHEYE":
                    raise self.fail(path + ("preset",), "preset spot_fisheye needs model: OPENCV_FISHEYE", sensor)
                if s.dist or s.cx is not None or s.cy is not None or s.fy is not None:
                    raise self.fail(path + ("preset",), "a preset takes only model, width and height", sensor)
                return Camera.fisheye_spot_like(s.width, s.height)
            if s.model == "EQUIRECTANGULAR":
                return Camera.equirect(s.width, s.height)
            if s.hfov_deg is not None:
                if s.model != "PINHOLE":
                    raise self.fail(path + ("hfov_deg",), "hfov_deg makes a PINHOLE camera; give fx for other models", sensor)
                if s.dist or s.cx is not None or s.cy is not None or s.fy is not None:
                    raise self.fail(path + ("hfov_deg",), "hfov_deg takes only width and height", sensor)
                return Camera.pinhole_from_fov(s.width, s.height, s.hfov_deg)
            cx = s.width / 2.0 - 0.5 if s.cx is None else s.cx
            cy = s.height / 2.0 - 0.5 if s.cy is None else s.cy
            return Camera(s.model, s.width, s.height, s.fx, s.fy if s.fy is not None else s.fx, cx, cy, s.dist)
        except ValueError as exc:
            raise self.fail(path, str(exc).replace("Camera.", ""), sensor) from None

    def lidar(self, name: str, sensor_to_body: np.ndarray, raw: Any, path: tuple) -> LidarSensor:
        spec: LidarSpec = self.block(LidarSpec, raw, path, name)
        return LidarSensor(name=name, sensor_to_body=_readonly(sensor_to_body), config=spec.config(),
                           elevations_deg=np.asarray(spec.beams.elevations_deg), dropout_prob=spec.dropout_prob)


def load_rig(path: str | Path) -> Rig:
    """Same as ``Rig.load``."""
    return Rig.load(path)


def static_transforms(rig: Rig) -> dict[str, np.ndarray]:
    """``{sensor name: sensor_to_body (4, 4)}`` for every sensor, in file order."""
    return {s.name: np.array(s.sensor_to_body) for s in rig.sensors}


__all__ = [
    "COLORS",
    "LINK_TO_OPTICAL",
    "SENSOR_TYPES",
    "CameraSensor",
    "IntrinsicsSpec",
    "LidarSensor",
    "LidarSpec",
    "MountSpec",
    "OrganizedScan",
    "Rig",
    "Sensor",
    "load_rig",
    "static_transforms",
]
