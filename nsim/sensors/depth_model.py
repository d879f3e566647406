"""Depth cameras: z-depth vs ray range, valid range, Gaussian noise and quantisation.

A renderer (or the test room's oracle) gives the *range* ``r`` of each pixel's ray: the distance
from the camera centre along the unit ray direction ``d`` (camera axes, OpenCV: +z forward). A
depth camera reports either

``z`` (default)
    z-depth along the optical axis, ``z = r * d_z`` (what ``*.exr`` depth files hold). Undefined
    (NaN) where ``d_z <= 0``: fisheye pixels at or beyond 90 deg off-axis.
``range``
    the ray range ``r`` itself (time-of-flight style).

Invalid values follow the EXR convention (``nsim.io.exr``): ``inf`` = no return (the ray hit
nothing, or the measurement is beyond ``max_m``), ``NaN`` = no valid measurement (nearer than
``min_m``, or undefined). The measurement model, in this order, on finite values only:

1. noise: ``m = true + n * (noise_abs_std_m + noise_rel_std * true)`` with ``n ~ N(0, 1)``; one
   draw per pixel for the whole image (finite or not), so the draws do not depend on the scene;
2. quantisation: ``m = round(m / quantization_m) * quantization_m`` when ``quantization_m > 0``;
3. valid range: ``m > max_m`` -> inf, ``m < min_m`` -> NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nsim.config import param

DEPTH_KINDS = ("z", "range")


@dataclass(frozen=True)
class DepthConfig:
    """A depth camera's output (see the module docstring; defaults: exact z-depth, no limits)."""

    kind: str = param("z", choices=DEPTH_KINDS, help="z: z-depth along the optical axis; range: ray range")
    min_m: float = param(0.0, ge=0.0, help="nearer measurements are invalid (NaN)")
    max_m: float = param(math.inf, gt=0.0, help="farther measurements are no return (inf)")
    noise_abs_std_m: float = param(0.0, ge=0.0, help="std of additive Gaussian noise, metres")
    noise_rel_std: float = param(0.0, ge=0.0, help="std of Gaussian noise relative to the depth")
    quantization_m: float = param(0.0, ge=0.0, help="output step in metres (0: none; 0.001 = mm)")

    def __post_init__(self) -> None:
        if self.kind not in DEPTH_KINDS:
            raise ValueError(f"kind: {self.kind!r} is not one of {', '.join(DEPTH_KINDS)}")
        for name in ("min_m", "noise_abs_std_m", "noise_rel_std", "quantization_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: expected a finite float >= 0, got {value!r}")
        if not self.max_m > self.min_m:  # inf allowed
            raise ValueError(f"max_m: expected > min_m ({self.min_m:g}), got {self.max_m!r}")

    @property
    def noisy(self) -> bool:
        return self.noise_abs_std_m > 0.0 or self.noise_rel_std > 0.0


def range_to_z_depth(range_m: np.ndarray, dirs_cam_z: np.ndarray) -> np.ndarray:
    """z-depth ``r * d_z`` from ray range. range_m, dirs_cam_z: (...) broadcastable; NaN where ``d_z <= 0``."""
    range_m = np.asarray(range_m, dtype=np.float64)
    dz = np.asarray(dirs_cam_z, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(dz > 0.0, range_m * np.where(dz > 0.0, dz, 1.0), np.nan)


def z_depth_to_range(z_m: np.ndarray, dirs_cam_z: np.ndarray) -> np.ndarray:
    """Ray range ``z / d_z`` from z-depth. z_m, dirs_cam_z: (...) broadcastable; NaN where ``d_z <= 0``."""
    z_m = np.asarray(z_m, dtype=np.float64)
    dz = np.asarray(dirs_cam_z, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(dz > 0.0, z_m / np.where(dz > 0.0, dz, 1.0), np.nan)


def apply_depth_model(depth_m: np.ndarray, cfg: DepthConfig, rng: np.random.Generator | None = None) -> np.ndarray:
    """The measured depth ``(...)`` float32 from exact depth ``depth_m (...)`` (in ``cfg.kind``).

    ``rng`` is required when ``cfg`` has noise (a seeded ``np.random.Generator``); the input is not
    modified. See the module docstring for the order of noise, quantisation and range gating.
    """
    true = np.asarray(depth_m, dtype=np.float64)
    m = true.copy()
    finite = np.isfinite(m)
    if cfg.noisy:
        if rng is None:
            raise ValueError("apply_depth_model: a noisy depth model needs a seeded rng (np.random.Generator)")
        n = rng.standard_normal(true.shape)
        std = cfg.noise_abs_std_m + cfg.noise_rel_std * np.where(finite, np.abs(true), 0.0)
        m = np.where(finite, true + n * std, m)
    if cfg.quantization_m > 0.0:
        m = np.where(finite, np.round(np.where(finite, m, 0.0) / cfg.quantization_m) * cfg.quantization_m, m)
    with np.errstate(invalid="ignore"):
        m = np.where(m > cfg.max_m, np.inf, m)
        m = np.where(m < cfg.min_m, np.nan, m)
    return m.astype(np.float32)
