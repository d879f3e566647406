"""A realistic robot log of the test room: the oracle's rig sensors along a run, with real-world faults.

What a Spot log recorded in a real room looks like, but with exact ground truth: the rig's
cameras, depth cameras and LiDARs rendered by ``RoomOracle`` along the robot's true trajectory,
then degraded as real sensors and real robots degrade them, and written as a ROS bag through
``nsim.io.rosbag.BagWriter`` (read it back with ``nsim.io.robot_log.RobotLog``).
``write_robot_log`` also writes ``<bag>.truth.json``: what an importer must recover (the odometry
frame's pose in the room, the clock offset) and the true trajectory to score it against.

Frames and clocks
    ``world``: the room's frame (metres, z up). ``odom``: the frame of the robot's odometry, whose
    pose in the world is ``odom_to_world`` (``RobotLogFaults.odom_frame_yaw_deg`` about +z, then
    ``odom_frame_xyz_m``): the robot does not know where the room is. ``body``: the robot's body
    (x forward, y left, z up); ``body_to_world (N, 4, 4)`` is the truth at the ticks ``stamps_s
    (N,)``. Every sensor samples at every tick i, at the true pose ``body_to_world[i]``. The
    odometry, the depth images and the LiDARs are stamped on one clock, the odometry's: tick i at
    ``stamps_s[i]``. The cameras' clock runs ``clock_offset_s`` ahead of it: the colour frames of
    tick i are stamped ``stamps_s[i] + clock_offset_s``, so a frame stamped ``s`` was captured at
    odometry time ``s - clock_offset_s``. In the bag the offset is exact: camera stamp - odometry
    stamp = ``round(clock_offset_s * 1e9)`` ns at every tick (``log_stamps_ns``).

The faults (``RobotLogFaults``; ``RobotLogFaults.none()`` turns every one off), in the order applied:

cameras (per camera, ``camera_faults``)
    the oracle's colour decoded to linear light, times an auto-exposure gain that drifts smoothly
    over the run (``exposure_gains``: ``nsim.synth.phone.smooth_drift`` in stops, one independent
    drift per camera), shot and read noise, the white level (``nsim.synth.phone.develop``); then
    the rig's own exposure and colour (``CameraSensor.expose``), 8 bits, then JPEG at
    ``jpeg_quality`` (``nsim.synth.phone.encode_jpeg``, 4:2:0): the bag holds those very bytes as
    sensor_msgs/CompressedImage on ``/<camera>/image/compressed`` (a gray camera's is a one-component
    JPEG, as gray drivers write it). ``jpeg_quality`` None: raw sensor_msgs/Image on
    ``/<camera>/image``.
depth (per depth-emitting camera, ``depth_faults``)
    the rig's depth model (``nsim.sensors.depth_model.apply_depth_model``: kind, maximum range,
    quantisation) with the faults' noise and a minimum range of ``max(rig min_m,
    depth_min_range_m)`` (nearer -> NaN), then holes: ``depth_hole_fraction`` of the pixels, in
    blobs of about ``depth_hole_size_px``, set to NaN (``depth_holes``).
LiDAR (per LiDAR, ``lidar_faults``)
    the rig's LiDAR model (``LidarSensor.measure``) with the faults' Gaussian range noise and
    dropout (a lost return: range inf), then the rig's range gate. Every return has intensity 1
    (the oracle has no reflectance model).
odometry (``odometry_from_truth``)
    the true motion between consecutive ticks, in the body frame of the earlier tick, with its
    translation scaled by ``1 + odom_scale_error_percent / 100`` plus a random walk, and its
    heading turned by a bias per metre, a random walk per square root of a metre and a gyro bias
    per second; composed from the true first pose in ``odom``. The error therefore starts at
    exactly zero (tick 0 is the frame offset alone) and grows with the distance walked, as leg
    odometry's does. Both ``/odom`` and ``/tf`` (``odom -> body``) carry this estimate.

Randomness: every draw comes from ``np.random.default_rng([seed, TAG, ...])`` with one tag per
effect and sensor (and per tick for per-frame noise), so two runs with the same seed write the
same bag and the same truth, and switching one fault off leaves the others' realisations as they
were (except the LiDAR's: ``LidarSensor.measure`` draws its noise and dropout from one stream).

The core functions are pure (arrays in, arrays out); ``write_robot_log`` does the I/O.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import from_dict, param, to_dict
from nsim.errors import InputError
from nsim.geometry.transforms import invert_se3, is_rotation, make_se3
from nsim.io.canonical import canonical_floats, round_decimals
from nsim.sensors.depth_model import DepthConfig, apply_depth_model
from nsim.sensors.rig import CameraSensor, LidarSensor, Rig
from nsim.synth.phone import PhoneConfig, develop, encode_jpeg, smooth_drift
from nsim.synth.room import RoomSpec

log = logging.getLogger(__name__)

ODOM_TAG = 0x10D0
EXPOSURE_TAG = 0x10D1
CAMERA_TAG = 0x10D2
DEPTH_TAG = 0x10D3
LIDAR_TAG = 0x10D4

TRUTH_FORMAT = "nsim-robot-log-truth"
TRUTH_VERSION = 2


@dataclasses.dataclass(frozen=True)
class RobotLogFaults:
    """What the real world does to a robot's log (see the module docstring). Defaults: a plausible
    Spot run (noisy, auto-exposed, JPEG cameras; holey depth; a VLP-16's range noise; leg odometry
    drifting about 1 % of the distance; a 30 ms camera clock offset; odom 35 deg and 1.4 m off)."""

    camera_read_noise_std: float = param(0.004, ge=0.0, le=0.5, help="read-noise std, linear units of the white level")
    camera_shot_noise_std_at_white: float = param(0.01, ge=0.0, le=0.5, help="shot-noise std at the white level")
    exposure_drift_std_stops: float = param(0.25, ge=0.0, le=2.0, help="auto-exposure drift: std of log2 gain")
    exposure_drift_timescale_s: float = param(3.0, gt=0.0, le=600.0, help="auto-exposure drift: smoothing sigma")
    jpeg_quality: int | None = param(85, ge=1, le=100, help="JPEG round trip at this quality (null: none)")
    depth_min_range_m: float = param(0.3, ge=0.0, le=10.0, help="depth nearer than this is invalid (NaN)")
    depth_noise_abs_std_m: float = param(0.005, ge=0.0, le=1.0, help="depth noise std: this + rel * depth, metres")
    depth_noise_rel_std: float = param(0.01, ge=0.0, le=0.5, help="depth noise std relative to the depth")
    depth_hole_fraction: float = param(0.03, ge=0.0, lt=1.0, help="fraction of depth pixels lost (NaN)")
    depth_hole_size_px: float = param(2.0, ge=0.0, le=100.0, help="blob scale of the holes (Gaussian sigma, px)")
    lidar_range_noise_std_m: float = param(0.03, ge=0.0, le=1.0, help="LiDAR range noise std, metres")
    lidar_dropout_fraction: float = param(0.01, ge=0.0, lt=1.0, help="chance that a LiDAR return is lost")
    odom_scale_error_percent: float = param(1.0, ge=-50.0, le=50.0, help="odometry over-reports distance by this")
    odom_xy_walk_m_per_sqrt_m: float = param(0.003, ge=0.0, le=1.0,
                                             help="odometry translation random walk, per sqrt(metre walked)")
    odom_yaw_drift_deg_per_m: float = param(0.2, ge=-90.0, le=90.0, help="odometry heading bias per metre walked")
    odom_yaw_walk_deg_per_sqrt_m: float = param(0.1, ge=0.0, le=90.0,
                                                help="odometry heading random walk, per sqrt(metre walked)")
    odom_yaw_rate_bias_deg_per_s: float = param(0.005, ge=-10.0, le=10.0, help="gyro bias: heading drift per second")
    clock_offset_s: float = param(0.03, ge=-1.0, le=1.0, help="camera stamp minus capture time on the odometry clock")
    odom_frame_yaw_deg: float = param(35.0, ge=-180.0, le=180.0, help="the odom frame's yaw in the world")
    odom_frame_xyz_m: tuple[float, float, float] = (1.2, -0.6, 0.5)

    @classmethod
    def none(cls) -> RobotLogFaults:
        """No fault at all: the log holds the oracle's clean readings (through the rig's own models,
        noise-free) and the odometry is the truth in a frame equal to the world's."""
        zero = {f.name: 0.0 for f in dataclasses.fields(cls)}
        return cls(**{**zero, "exposure_drift_timescale_s": cls.exposure_drift_timescale_s, "jpeg_quality": None,
                      "odom_frame_xyz_m": (0.0, 0.0, 0.0)})

    def validated(self) -> RobotLogFaults:
        """This config after the strict loader's checks (ConfigError naming the key otherwise)."""
        return from_dict(RobotLogFaults, to_dict(self))


# ---------------------------------------------------------------------------------- odometry
def odom_to_world(faults: RobotLogFaults) -> np.ndarray:
    """The odometry frame's pose in the world, ``(4, 4)``: yaw ``odom_frame_yaw_deg`` about +z, then ``odom_frame_xyz_m``."""
    return make_se3(_rz(math.radians(faults.odom_frame_yaw_deg)), np.asarray(faults.odom_frame_xyz_m, dtype=np.float64))


def _rz(yaw_rad: float | np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` about +z by ``yaw_rad (...)``."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def _check_trajectory(body_to_world: np.ndarray, stamps_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    body = np.asarray(body_to_world, dtype=np.float64)
    stamps = np.asarray(stamps_s, dtype=np.float64)
    if body.ndim != 3 or body.shape[1:] != (4, 4) or body.shape[0] < 1:
        raise ValueError(f"body_to_world: expected shape (N, 4, 4) with N >= 1, got {body.shape}")
    if not np.all(np.isfinite(body)) or not np.all(is_rotation(body[:, :3, :3])):
        raise ValueError("body_to_world: expected finite rigid poses")
    if stamps.shape != (body.shape[0],) or not np.all(np.isfinite(stamps)):
        raise ValueError(f"stamps_s: expected {body.shape[0]} finite times, got shape {stamps.shape}")
    if np.any(np.diff(stamps) <= 0.0):
        raise ValueError("stamps_s: expected strictly increasing times")
    return body, stamps


def odometry_from_truth(body_to_world: np.ndarray, stamps_s: np.ndarray, faults: RobotLogFaults,
                        rng: np.random.Generator) -> np.ndarray:
    """The robot's odometry ``body_to_odom (N, 4, 4)`` for its true run ``body_to_world (N, 4, 4)``
    at ``stamps_s (N,)`` (see the module docstring for the drift model).

    Tick 0 is exact: ``odom_to_world(faults) @ body_to_odom[0] == body_to_world[0]``. Tick i
    composes tick i-1 with the true relative motion ``inv(B[i-1]) @ B[i]`` (distance ``d``, time
    ``dt``) after its translation is scaled by ``1 + odom_scale_error_percent / 100`` and given a
    random walk ``odom_xy_walk_m_per_sqrt_m * sqrt(d) * n_xy`` in the body's xy plane, and its
    rotation is preceded by a yaw about body z of ``odom_yaw_drift_deg_per_m * d +
    odom_yaw_rate_bias_deg_per_s * dt + odom_yaw_walk_deg_per_sqrt_m * sqrt(d) * n_yaw``. Always
    draws ``3 (N - 1)`` normals from ``rng``.
    """
    body, stamps = _check_trajectory(body_to_world, stamps_s)
    n = body.shape[0]
    n_yaw = rng.standard_normal(n - 1)
    n_xy = rng.standard_normal((n - 1, 2))
    rel = invert_se3(body[:-1]) @ body[1:]  # (N-1, 4, 4): motion in the earlier tick's body frame
    dist_m = np.linalg.norm(rel[:, :3, 3], axis=-1)
    dt_s = np.diff(stamps)
    yaw_deg = (faults.odom_yaw_drift_deg_per_m * dist_m + faults.odom_yaw_rate_bias_deg_per_s * dt_s
               + faults.odom_yaw_walk_deg_per_sqrt_m * np.sqrt(dist_m) * n_yaw)
    t = rel[:, :3, 3] * (1.0 + faults.odom_scale_error_percent / 100.0)
    t[:, :2] += faults.odom_xy_walk_m_per_sqrt_m * np.sqrt(dist_m)[:, None] * n_xy
    R = _rz(np.radians(yaw_deg)) @ rel[:, :3, :3]
    measured = make_se3(R, t)
    out = np.empty_like(body)
    out[0] = invert_se3(odom_to_world(faults)) @ body[0]
    for i in range(1, n):
        out[i] = out[i - 1] @ measured[i - 1]
    return out


def log_stamps_ns(stamps_s: np.ndarray, faults: RobotLogFaults) -> tuple[np.ndarray, np.ndarray]:
    """The bag's stamps of the ticks at ``stamps_s (N,)`` (odometry clock, seconds): ``(odometry_ns,
    camera_ns)``, both ``(N,)`` int64 nanoseconds.

    odometry_ns (odometry, /tf, depth, LiDAR) is ``round(stamps_s * 1e9)``; camera_ns (the colour
    frames, on the camera clock) is ``odometry_ns + round(clock_offset_s * 1e9)``: exactly the
    offset apart, whatever the rounding of the seconds.
    """
    odometry_ns = np.array([int(round(float(t) * 1e9)) for t in np.asarray(stamps_s, dtype=np.float64).reshape(-1)],
                           dtype=np.int64)
    return odometry_ns, odometry_ns + np.int64(int(round(faults.clock_offset_s * 1e9)))


# ---------------------------------------------------------------------------------- cameras
def exposure_gains(times_s: np.ndarray, faults: RobotLogFaults, rng: np.random.Generator) -> np.ndarray:
    """One camera's auto-exposure gains ``(M,)`` (linear, around 1) at its frame times ``times_s (M,)``.

    ``2 ** smooth_drift(...)``: stationary, std ``exposure_drift_std_stops`` in stops, smoothed
    over ``exposure_drift_timescale_s`` (in frames: over the median frame interval).
    """
    times = np.asarray(times_s, dtype=np.float64)
    if times.ndim != 1:
        raise ValueError(f"times_s: expected shape (M,), got {times.shape}")
    if times.size == 0:
        return np.ones(0)
    step_s = float(np.median(np.diff(times))) if times.size > 1 else faults.exposure_drift_timescale_s
    sigma_frames = faults.exposure_drift_timescale_s / step_s
    # to 1e-9 (nsim.io.canonical): numpy's exp2 differs in the last bits between CPUs; the images and the
    # truth that records the gains then do not
    return round_decimals(np.exp2(smooth_drift(rng, times.size, faults.exposure_drift_std_stops, sigma_frames)))


def jpeg_bytes(image_u8: np.ndarray, quality: int) -> bytes:
    """The JPEG (``nsim.synth.phone.encode_jpeg`` at ``quality``) of ``image_u8``: (H, W, 3) RGB or
    (H, W) gray uint8 (a one-component JPEG)."""
    return encode_jpeg(np.asarray(image_u8), quality)


def jpeg_round_trip(image_u8: np.ndarray, quality: int) -> np.ndarray:
    """``image_u8`` ((H, W, 3) RGB or (H, W) gray, uint8) after ``jpeg_bytes`` at ``quality`` and
    decoding: the same shape and dtype."""
    import cv2

    image = np.asarray(image_u8)
    data = np.frombuffer(jpeg_bytes(image, quality), dtype=np.uint8)
    if image.ndim == 2:
        return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    return np.ascontiguousarray(cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1])


def camera_faults(rgb: np.ndarray, exposure_gain: float, sensor: CameraSensor, faults: RobotLogFaults,
                  rng: np.random.Generator, *, jpeg: bool = True) -> np.ndarray:
    """The image ``sensor`` records, uint8 ``(H, W, 3)`` (or ``(H, W)`` for a gray camera), from the
    oracle's colour ``rgb (H, W, 3)`` in [0, 1] at this frame's auto-exposure gain.

    Linear light times the gain plus shot and read noise, clipped (``phone.develop``; skipped when
    there is neither gain nor noise, so a clean log holds the oracle's pixels exactly), then
    ``sensor.expose``, 8 bits and the JPEG round trip (``jpeg_quality``; ``jpeg`` False: the image
    before it, whose ``jpeg_bytes`` the log holds). ``rng`` gives the noise (``H * W * 3`` normals
    when there is noise).
    """
    from nsim.io.images import to_uint8
    from nsim.sensors.rig import _srgb_to_linear

    rgb = np.asarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"rgb: expected shape (H, W, 3), got {rgb.shape}")
    phone = PhoneConfig(read_noise_std=faults.camera_read_noise_std,
                        shot_noise_std_at_white=faults.camera_shot_noise_std_at_white)
    if phone.noisy or exposure_gain != 1.0:
        H, W = rgb.shape[:2]
        rgb = develop(_srgb_to_linear(np.clip(rgb, 0.0, 1.0)), float(exposure_gain), np.ones(3),
                      np.ones((H, W), dtype=np.float32), phone, rng)
    image = to_uint8(sensor.expose(rgb))
    if jpeg and faults.jpeg_quality is not None:
        image = jpeg_round_trip(image, faults.jpeg_quality)
    return image


# ---------------------------------------------------------------------------------- depth
def faulty_depth_config(depth: DepthConfig, faults: RobotLogFaults) -> DepthConfig:
    """The rig's depth model with the faults' noise and minimum range (the larger of the two)."""
    return dataclasses.replace(depth, min_m=max(depth.min_m, faults.depth_min_range_m),
                               noise_abs_std_m=faults.depth_noise_abs_std_m, noise_rel_std=faults.depth_noise_rel_std)


def depth_holes(shape: tuple[int, int], fraction: float, size_px: float, rng: np.random.Generator) -> np.ndarray:
    """Where a depth image has holes: ``(H, W)`` bool, exactly ``round(fraction * H * W)`` pixels,
    in blobs: the largest values of white noise smoothed by a Gaussian of sigma ``size_px``.

    Draws ``H * W`` normals from ``rng`` (none when ``fraction`` is 0).
    """
    from scipy.ndimage import gaussian_filter

    mask = np.zeros(shape, dtype=bool)
    k = int(round(fraction * mask.size))
    if k == 0:
        return mask
    field = rng.standard_normal(shape)
    if size_px > 0.0:
        field = gaussian_filter(field, size_px, mode="reflect")
    mask.reshape(-1)[np.argpartition(field.reshape(-1), -k)[-k:]] = True
    return mask


def depth_faults(range_m: np.ndarray, sensor: CameraSensor, faults: RobotLogFaults,
                 rng: np.random.Generator) -> np.ndarray:
    """The depth image ``(H, W)`` float32 ``sensor`` records for the oracle's ray ranges ``range_m (H, W)``
    (inf: no hit, NaN: undefined pixel): its depth kind through ``faulty_depth_config``, then holes.

    inf = no return, NaN = no valid measurement (nearer than the minimum range, undefined, a hole).
    The noise and the holes draw from two generators seeded from two draws of ``rng``.
    """
    if sensor.depth is None:
        raise ValueError(f"sensor {sensor.name!r} has no depth output")
    r = np.asarray(range_m, dtype=np.float64)
    noise_rng, hole_rng = (np.random.default_rng(int(k)) for k in rng.integers(0, 2**63, size=2))
    exact = sensor.depth_from_range(np.nan_to_num(r, nan=np.inf))
    depth = apply_depth_model(exact, faulty_depth_config(sensor.depth, faults), noise_rng)
    holes = depth_holes(r.shape, faults.depth_hole_fraction, faults.depth_hole_size_px, hole_rng)
    return np.where(np.isnan(r) | holes, np.nan, depth).astype(np.float32)


# ---------------------------------------------------------------------------------- LiDAR
def lidar_faults(range_m: np.ndarray, sensor: LidarSensor, faults: RobotLogFaults,
                 rng: np.random.Generator) -> np.ndarray:
    """The ranges ``(C, A)`` float32 ``sensor`` reports for exact ranges ``range_m (C, A)`` (inf or NaN:
    no hit): ``LidarSensor.measure`` with the faults' range noise and dropout; inf = no return."""
    faulty = dataclasses.replace(
        sensor, config=dataclasses.replace(sensor.config, range_noise_std_m=faults.lidar_range_noise_std_m),
        dropout_prob=faults.lidar_dropout_fraction)
    return faulty.measure(np.nan_to_num(np.asarray(range_m, dtype=np.float64), nan=np.inf), rng)


# ---------------------------------------------------------------------------------- the log
def truth_path(bag_path: str | os.PathLike) -> Path:
    """Where ``write_robot_log`` puts the ground truth of the bag at ``bag_path``: ``<bag>.truth.json``."""
    bag_path = Path(bag_path)
    return bag_path.with_name(bag_path.name + ".truth.json")


def _rng(seed: int, *tags: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), *(int(t) for t in tags)])


def write_robot_log(
    out_path: str | os.PathLike,
    room_spec: RoomSpec,
    rig: Rig,
    body_to_world: np.ndarray,
    stamps_s: np.ndarray,
    faults: RobotLogFaults = RobotLogFaults(),
    seed: int = 0,
    storage: str = "sqlite3",
    *,
    oracle: Any | None = None,
    supersample: int = 1,
) -> dict[str, Any]:
    """Write the log of ``rig`` driven along ``body_to_world (N, 4, 4)`` at ``stamps_s (N,)`` through
    the test room ``room_spec``, with ``faults``, as a bag at ``out_path`` (``BagWriter``'s
    ``storage``), then its ground truth beside it (``truth_path``); returns that truth.

    Tick i renders every sensor at the true pose ``body_to_world[i]`` and writes (``log_stamps_ns``):
    the odometry (``odometry_from_truth``), the depth images and the LiDAR sweeps stamped
    ``stamps_s[i]``; the colour frames stamped ``stamps_s[i] + clock_offset_s`` on the camera
    clock (JPEG bytes as CompressedImage, or raw Image when ``jpeg_quality`` is None). Messages go
    into the bag in stamp order, so any offset works; one that would stamp a frame before time 0
    raises ValueError.

    oracle: a ``RoomOracle`` of ``room_spec`` already built (skips baking the textures).
    supersample: the oracle's sub-pixel rays per axis for colour. Raises ``InputError`` when the
    bag or its truth file exists already (or the folder cannot take them) before any rendering;
    an error while writing leaves neither.
    """
    from nsim.io import atomic_path
    from nsim.io.rosbag import BagWriter

    body, stamps = _check_trajectory(body_to_world, stamps_s)
    faults = faults.validated()
    out_path = Path(out_path)
    truth_file = truth_path(out_path)
    if os.path.lexists(truth_file):
        raise InputError(f"{truth_file}: exists already; a robot log's truth is never overwritten")
    n = body.shape[0]
    odom = odometry_from_truth(body, stamps, faults, _rng(seed, ODOM_TAG))
    odometry_ns, camera_ns = log_stamps_ns(stamps, faults)
    if min(odometry_ns[0], camera_ns[0]) < 0:
        raise ValueError(f"stamps_s: the first tick at {stamps[0]} s with a camera clock offset of "
                         f"{faults.clock_offset_s} s stamps data before time 0")
    index = {s.name: k for k, s in enumerate(rig.sensors)}
    gains = {s.name: exposure_gains(stamps, faults, _rng(seed, EXPOSURE_TAG, index[s.name]))
             for s in rig.cameras if s.emits_image}
    # what is written when: (stamp, 0: odometry, depth and LiDAR / 1: colour, tick), in stamp order
    events = [(int(t), 0, i) for i, t in enumerate(odometry_ns)]
    if gains:
        events += [(int(t), 1, i) for i, t in enumerate(camera_ns)]
    events.sort()
    sides = 2 if gains else 1

    def render(i: int) -> dict[str, dict]:
        """Every reading of tick i, at the true pose ``body[i]``."""
        out: dict[str, dict] = {"images": {}, "compressed_images": {}, "depths": {}, "clouds": {}}
        for s in rig.cameras:
            k = index[s.name]
            view = oracle.render_gt(s.camera, s.world_pose(body[i]), supersample=supersample)
            if s.emits_image:
                image = camera_faults(view.rgb, float(gains[s.name][i]), s, faults, _rng(seed, CAMERA_TAG, i, k),
                                      jpeg=False)
                if faults.jpeg_quality is None:
                    out["images"][s.name] = image
                else:
                    out["compressed_images"][s.name] = jpeg_bytes(image, faults.jpeg_quality)
            if s.emits_depth:
                out["depths"][s.name] = depth_faults(view.depth_range, s, faults, _rng(seed, DEPTH_TAG, i, k))
        for s in rig.lidars:
            hits = oracle.cast_rays(*s.rays(body[i]))
            ranges = lidar_faults(hits.t.reshape(s.ray_shape), s, faults, _rng(seed, LIDAR_TAG, i, index[s.name]))
            out["clouds"][s.name] = s.scan(ranges)
        return out

    with BagWriter(out_path, rig, storage=storage) as bag:  # checks the destination before any rendering
        if oracle is None:
            from nsim.synth.oracle import RoomOracle

            oracle = RoomOracle(room_spec)
        elif oracle.spec != room_spec:
            raise ValueError("oracle: built for another room than room_spec")
        pending: dict[int, tuple[dict[str, dict], list[int]]] = {}  # tick -> (readings, sides written)
        for t_ns, group in itertools.groupby(events, key=lambda e: e[0]):
            sensors: dict[str, dict] = {"images": {}, "compressed_images": {}, "depths": {}, "clouds": {}}
            odometry_tick = None
            for _, side, i in group:  # at most one odometry tick and one camera tick share a stamp
                if i not in pending:
                    pending[i] = (render(i), [])
                    log.debug("robot log %s: tick %d/%d rendered", out_path.name, i + 1, n)
                readings, done = pending[i]
                for key in (("depths", "clouds") if side == 0 else ("images", "compressed_images")):
                    sensors[key].update(readings[key])
                if side == 0:
                    odometry_tick = i
                done.append(side)
                if len(done) == sides:
                    del pending[i]
            if odometry_tick is not None:
                bag.write_odometry(None, odom[odometry_tick], t_ns=t_ns)
            bag.write_sensors(t_ns=t_ns, **sensors)

    truth = {
        "format": TRUTH_FORMAT,
        "version": TRUTH_VERSION,
        "bag": out_path.name,
        "storage": storage,
        "seed": int(seed),
        "frames": {
            "world": "the room's frame (metres, z up)",
            "odom": "the frame of /odom and /tf; odom_to_world is its pose in the world",
            "body": "the robot's body (x forward, y left, z up)",
        },
        "odom_to_world": odom_to_world(faults).tolist(),
        "clock_offset_s": faults.clock_offset_s,
        "clock": "every sensor samples at every tick i, at the true pose body_to_world[i]; odometry, /tf, depth and "
                 "LiDAR are stamped stamps_ns[i] (the odometry clock), the colour frames camera_frames.stamps_ns[i] "
                 "= stamps_ns[i] + round(clock_offset_s * 1e9) (the camera clock)",
        "odometry_drift_model": "per tick: the true relative motion with translation * (1 + odom_scale_error_percent"
                                " / 100) + odom_xy_walk_m_per_sqrt_m * sqrt(d) * N(0, I2) in body xy, and a body-z"
                                " yaw of odom_yaw_drift_deg_per_m * d + odom_yaw_rate_bias_deg_per_s * dt +"
                                " odom_yaw_walk_deg_per_sqrt_m * sqrt(d) * N(0, 1) before its rotation; tick 0 exact",
        "faults": to_dict(faults),
        "stamps_s": stamps.tolist(),
        "stamps_ns": odometry_ns.tolist(),
        "body_to_world": body.tolist(),
        "camera_frames": {
            "stamps_ns": camera_ns.tolist(),
            "capture_times_s": stamps.tolist(),
            "topic": "/<camera>/image" if faults.jpeg_quality is None else "/<camera>/image/compressed",
            "exposure_gains": {name: g.tolist() for name, g in gains.items()},
        },
        "room": room_spec.to_dict(),
        "rig": rig.to_dict(),
    }
    text = json.dumps(canonical_floats(truth), indent=1, sort_keys=True) + "\n"  # the same bytes on any CPU
    with atomic_path(truth_file) as tmp:
        tmp.write_text(text)
    return json.loads(text)


__all__ = [
    "RobotLogFaults",
    "camera_faults",
    "depth_faults",
    "depth_holes",
    "exposure_gains",
    "faulty_depth_config",
    "jpeg_bytes",
    "jpeg_round_trip",
    "lidar_faults",
    "log_stamps_ns",
    "odom_to_world",
    "odometry_from_truth",
    "truth_path",
    "write_robot_log",
]
