"""Gait phase from the distance walked, so an animated walk cycle never slides its feet.

The phase ``phi in [0, 1)`` counts gait cycles (strides: two steps, left then right). It
advances by the distance walked divided by the current stride length, never by time: a human
who stands still keeps its phase, and a walk cycle played at ``phi`` moves the planted foot
exactly as far as the root moved.

Stride length from speed (an assumption, stated here once): step length grows with the square
root of speed and in proportion to body height,

    stride_length_m = 2 * STEP_COEFF_M * sqrt(speed_mps / 1 m/s) * height_m / 1.75 m

with ``STEP_COEFF_M = 0.63``, so a 1.75 m adult walking at 1.4 m/s takes 0.75 m steps at
about 113 steps/min, a typical comfortable cadence. The square-root form is the usual simple
fit to measured speed-cadence data (see Grieve & Gear 1966 for the measured relations); below
``MIN_SPEED_MPS`` the stride is held at its value there. nsim's procedural walks
(``nsim.human.gait``) are built with this stride.

A recorded clip (a BVH file, a person's motion fitted from a video) has one stride of its own, so a
person it drives advances by the distance walked over that stride (``clip_stride_m``), and a clip
that does not travel (standing idle) advances with time over its cycle (``clip_period_s``):
``advance_person_phase`` is the one rule for all three.
"""

from __future__ import annotations

import numpy as np

from nsim.human.skeleton import REFERENCE_HEIGHT_M

STEP_COEFF_M = 0.63
MIN_SPEED_MPS = 0.1


def stride_length_m(speed_mps: np.ndarray, height_m: np.ndarray | float = REFERENCE_HEIGHT_M) -> np.ndarray:
    """Stride length (two steps) at a walking speed: ``(*batch)`` metres, broadcast over inputs."""
    speed = np.maximum(np.asarray(speed_mps, dtype=np.float64), MIN_SPEED_MPS)
    return 2.0 * STEP_COEFF_M * np.sqrt(speed) * (np.asarray(height_m, dtype=np.float64) / REFERENCE_HEIGHT_M)


def gait_phase(distance_walked_m: np.ndarray, stride_length_m: np.ndarray | float) -> np.ndarray:
    """Phase in ``[0, 1)`` after walking ``distance_walked_m`` at a constant stride length."""
    return np.mod(np.asarray(distance_walked_m, dtype=np.float64) / stride_length_m, 1.0)


def advance_gait_phase(
    phase: np.ndarray, step_distance_m: np.ndarray, stride_length_m: np.ndarray | float
) -> np.ndarray:
    """Phase after walking ``step_distance_m`` more at ``stride_length_m`` (for varying speeds)."""
    return np.mod(np.asarray(phase, dtype=np.float64) + np.asarray(step_distance_m) / stride_length_m, 1.0)


def advance_person_phase(
    phase: np.ndarray,
    step_distance_m: np.ndarray,
    dt_s: float,
    speed_mps: np.ndarray,
    height_m: np.ndarray,
    clip_stride_m: np.ndarray,
    clip_period_s: np.ndarray,
) -> np.ndarray:
    """Phases ``(N,)`` one step of ``dt_s`` later, each person by its clip (the module docstring).

    step_distance_m: (N,) walked in the step; speed_mps: (N,) its speed (for the stride formula);
    clip_stride_m: (N,) > 0 the clip's own stride, 0 the formula's (``stride_length_m(speed_mps, height_m)``);
    clip_period_s: (N,) > 0 a clip that does not travel (the phase advances by ``dt_s`` over it), else 0.
    """
    clip_stride_m = np.asarray(clip_stride_m, dtype=np.float64)
    clip_period_s = np.asarray(clip_period_s, dtype=np.float64)
    stride = np.where(clip_stride_m > 0, clip_stride_m, stride_length_m(speed_mps, height_m))
    by_distance = advance_gait_phase(phase, step_distance_m, stride)
    timed = clip_period_s > 0
    by_time = np.mod(np.asarray(phase, dtype=np.float64) + dt_s / np.where(timed, clip_period_s, 1.0), 1.0)
    return np.where(timed, by_time, by_distance)
