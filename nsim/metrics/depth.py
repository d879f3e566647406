"""Depth-map accuracy as in the monocular-depth literature (Eigen et al. 2014; Spencer et al. 2023).

Over the valid pixels ``i`` (ground truth finite and within ``[min_depth_m, max_depth_m]``, and inside
the optional mask), with prediction ``p`` and ground truth ``g`` in metres::

    AbsRel  = mean(|p - g| / g)            SqRel = mean((p - g)^2 / g)
    RMSE    = sqrt(mean((p - g)^2))        logRMSE = sqrt(mean((ln p - ln g)^2))
    delta<t = fraction with max(p / g, g / p) < t,   t in 1.05, 1.10, 1.25, 1.25^2, 1.25^3

With ``median_scaling`` the prediction is first multiplied by ``median(g) / median(p)`` over the valid
pixels (for predictions known only up to scale); the result says whether it was, and by what. Then,
as in Monodepth2's evaluation, predictions are clamped into ``[min_depth_m, max_depth_m]`` (a ray that
hits nothing, depth +inf, counts as ``max_depth_m``). Depth here is whatever the pair shares (z-depth
or range along the ray); both maps must use the same. NaN/inf in the ground truth just marks pixels
invalid; NaN in the prediction at a valid pixel is an error, as is a comparison with no valid pixel.

These are the only definitions: ``scored_depths`` selects, scales and clamps the pixels;
``depth_metrics`` computes every error from them, ``abs_rel`` AbsRel alone and ``depth_error_map`` the
per-pixel ``|p - g| / g`` (whose mean is AbsRel). ``view_abs_rel`` is ``abs_rel`` for one rendered
view among many: pixels with no rendered depth (NaN) do not count, and a view with nothing to score
is NaN (a mean over views leaves it out) instead of an error. For a scene of arbitrary scale,
``DepthConfig.in_units`` gives the same bounds in its units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from nsim.errors import InputError

DELTA_THRESHOLDS = (1.05, 1.10, 1.25, 1.25**2, 1.25**3)


@dataclass(frozen=True)
class DepthConfig:
    """Which ground-truth depths count, and whether to median-scale the prediction first."""

    min_depth_m: float = 1e-3
    max_depth_m: float = 10.0
    median_scaling: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_depth_m) and self.min_depth_m > 0.0):
            raise ValueError(f"DepthConfig.min_depth_m: expected finite float > 0, got {self.min_depth_m!r}")
        if not (math.isfinite(self.max_depth_m) and self.max_depth_m > self.min_depth_m):
            raise ValueError(
                f"DepthConfig.max_depth_m: expected finite float > min_depth_m ({self.min_depth_m}), "
                f"got {self.max_depth_m!r}"
            )

    def in_units(self, units_per_m: float) -> DepthConfig:
        """The same bounds in a scene's own length unit, ``units_per_m`` of which make a metre (1: metres)."""
        if not (math.isfinite(units_per_m) and units_per_m > 0.0):
            raise ValueError(f"DepthConfig.in_units: expected a finite units_per_m > 0, got {units_per_m!r}")
        return replace(self, min_depth_m=self.min_depth_m * units_per_m, max_depth_m=self.max_depth_m * units_per_m)


@dataclass(frozen=True, kw_only=True)
class DepthErrors:
    """The errors of the module docstring, by the names every depth result carries (``DepthMetrics``
    here, ``nsim.metrics.paper_tables.DepthRecord`` per frame); ``rmse_m`` in metres, the rest unitless.
    """

    abs_rel: float
    sq_rel: float
    rmse_m: float
    log_rmse: float
    delta_1_05: float
    delta_1_10: float
    delta_1_25: float
    delta_1_25_2: float
    delta_1_25_3: float


@dataclass(frozen=True, kw_only=True)
class DepthMetrics(DepthErrors):
    """Depth errors over ``n_valid`` pixels; the prediction was multiplied by ``scale`` (1.0 unless
    ``median_scaled``). Keyword-only, like its base.
    """

    n_valid: int
    median_scaled: bool
    scale: float

    def row(self) -> dict[str, float | int | str]:
        """Table columns as the literature names them (``nsim.metrics.results_table``)."""
        return {
            "AbsRel": self.abs_rel,
            "SqRel": self.sq_rel,
            "RMSE": self.rmse_m,
            "logRMSE": self.log_rmse,
            "δ<1.05": self.delta_1_05,
            "δ<1.10": self.delta_1_10,
            "δ<1.25": self.delta_1_25,
            "δ<1.25²": self.delta_1_25_2,
            "δ<1.25³": self.delta_1_25_3,
            "scaling": "median" if self.median_scaled else "none",
        }


def valid_depth_mask(gt_m: np.ndarray, cfg: DepthConfig) -> np.ndarray:
    """(H, W) bool: ground truth finite and within ``[min_depth_m, max_depth_m]``."""
    gt_m = np.asarray(gt_m)
    with np.errstate(invalid="ignore"):
        return np.isfinite(gt_m) & (gt_m >= cfg.min_depth_m) & (gt_m <= cfg.max_depth_m)


def scored_depths(pred_m: np.ndarray, gt_m: np.ndarray, cfg: DepthConfig = DepthConfig(),
                  mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The pixels every depth metric scores, as the module docstring defines them.

    Returns ``(valid, p, g, scale)``: valid (H, W) bool, the valid pixels' prediction ``p`` (median-scaled
    by ``scale`` if ``cfg.median_scaling``, then clamped into ``[min_depth_m, max_depth_m]``) and ground
    truth ``g``, both (n_valid,) float64. Raises InputError for differing sizes, an empty mask, NaN in
    the prediction at a valid pixel, or no valid pixel at all.
    """
    pred_m, gt_m = np.asarray(pred_m, dtype=np.float64), np.asarray(gt_m, dtype=np.float64)
    if pred_m.shape != gt_m.shape:
        raise InputError(f"depth maps differ in size: pred {pred_m.shape} vs ground truth {gt_m.shape}")
    if pred_m.ndim != 2:
        raise InputError(f"depth maps: expected (H, W) arrays, got {pred_m.shape}")
    valid = valid_depth_mask(gt_m, cfg)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gt_m.shape or mask.dtype != bool:
            raise InputError(
                f"mask: expected a bool array of shape {gt_m.shape}, got {mask.dtype} {mask.shape}"
            )
        if not mask.any():
            raise InputError("mask is empty (no pixel selected)")
        valid &= mask
    if not valid.any():
        raise InputError(
            f"depth: no valid pixel (ground truth finite, in [{cfg.min_depth_m}, {cfg.max_depth_m}] m"
            f"{', inside the mask' if mask is not None else ''})"
        )
    p, g = pred_m[valid], gt_m[valid]
    if np.isnan(p).any():
        raise InputError(f"depth prediction is NaN at {int(np.isnan(p).sum())} valid pixel(s)")
    scale = 1.0
    if cfg.median_scaling:
        median_p = float(np.median(p))
        if not (math.isfinite(median_p) and median_p > 0.0):
            raise InputError(f"depth: cannot median-scale, median prediction is {median_p}")
        scale = float(np.median(g)) / median_p
        p = p * scale
    return valid, np.clip(p, cfg.min_depth_m, cfg.max_depth_m), g, scale


def _relative_error(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``|p - g| / g`` per pixel: AbsRel is its mean."""
    return np.abs(p - g) / g


def depth_metrics(
    pred_m: np.ndarray,
    gt_m: np.ndarray,
    cfg: DepthConfig = DepthConfig(),
    mask: np.ndarray | None = None,
) -> DepthMetrics:
    """Errors of ``pred_m`` against ``gt_m`` (both (H, W) metres) over valid pixels (module docstring).

    mask: optional (H, W) bool restricting the pixels further. Raises InputError for differing sizes,
    an empty mask, NaN in the prediction at a valid pixel, or no valid pixel at all.
    """
    valid, p, g, scale = scored_depths(pred_m, gt_m, cfg, mask)
    ratio = np.maximum(p / g, g / p)
    deltas = [float(np.mean(ratio < t)) for t in DELTA_THRESHOLDS]
    return DepthMetrics(
        abs_rel=float(np.mean(_relative_error(p, g))),
        sq_rel=float(np.mean((p - g) ** 2 / g)),
        rmse_m=float(np.sqrt(np.mean((p - g) ** 2))),
        log_rmse=float(np.sqrt(np.mean((np.log(p) - np.log(g)) ** 2))),
        delta_1_05=deltas[0],
        delta_1_10=deltas[1],
        delta_1_25=deltas[2],
        delta_1_25_2=deltas[3],
        delta_1_25_3=deltas[4],
        n_valid=int(valid.sum()),
        median_scaled=cfg.median_scaling,
        scale=scale,
    )


def abs_rel(pred_m: np.ndarray, gt_m: np.ndarray, cfg: DepthConfig = DepthConfig(),
            mask: np.ndarray | None = None) -> float:
    """AbsRel alone, ``mean(|p - g| / g)`` over the pixels of ``scored_depths`` (the one definition:
    ``depth_metrics(...).abs_rel``). Raises InputError as ``depth_metrics`` does.
    """
    _, p, g, _ = scored_depths(pred_m, gt_m, cfg, mask)
    return float(np.mean(_relative_error(p, g)))


def view_abs_rel(pred_m: np.ndarray, gt_m: np.ndarray, cfg: DepthConfig = DepthConfig()) -> float:
    """``abs_rel`` of one rendered view: over the valid pixels whose prediction is a number (NaN: nothing
    was rendered there), or NaN when no pixel counts (no valid ground truth in the view, or no depth
    rendered where there is), so that a mean over views leaves the view out. Other bad input (differing
    sizes) raises InputError as ``abs_rel`` does."""
    pred_m = np.asarray(pred_m, dtype=np.float64)
    gt_m = np.asarray(gt_m, dtype=np.float64)
    scored = ~np.isnan(pred_m)
    if pred_m.shape == gt_m.shape and not (scored & valid_depth_mask(gt_m, cfg)).any():
        return math.nan
    return abs_rel(pred_m, gt_m, cfg, scored)


def depth_error_map(pred_m: np.ndarray, gt_m: np.ndarray, cfg: DepthConfig = DepthConfig(),
                    mask: np.ndarray | None = None) -> np.ndarray:
    """(H, W) relative error ``|p - g| / g`` at the pixels ``depth_metrics`` scores (median scaling and
    clamping per ``cfg``), NaN where a pixel does not count; its mean is AbsRel. Raises InputError as
    ``depth_metrics`` does.
    """
    valid, p, g, _ = scored_depths(pred_m, gt_m, cfg, mask)
    out = np.full(valid.shape, np.nan)
    out[valid] = _relative_error(p, g)
    return out


def mean_depth_metrics(per_frame: Sequence[DepthMetrics]) -> DepthMetrics:
    """Per-frame mean of every error (the convention of the depth benchmarks); ``n_valid`` is summed,
    ``scale`` is the mean scale. All frames must agree on ``median_scaled``.
    """
    if not per_frame:
        raise InputError("depth: no frames to average")
    if len({m.median_scaled for m in per_frame}) != 1:
        raise ValueError("mean_depth_metrics: frames mix median-scaled and unscaled results")
    values = {}
    for f in fields(DepthMetrics):
        column = [getattr(m, f.name) for m in per_frame]
        if f.name == "n_valid":
            values[f.name] = int(sum(column))
        elif f.name == "median_scaled":
            values[f.name] = column[0]
        else:
            values[f.name] = float(np.mean(column))
    return DepthMetrics(**values)
