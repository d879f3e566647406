"""Image fidelity: PSNR and SSIM over whole images or a mask (LPIPS lives in ``nsim.metrics.lpips``).

Images are channels-last ``(H, W)`` or ``(H, W, C)`` floating-point arrays with values in
``[0, data_range]`` (default 1.0: float images in [0, 1]); both images of a pair must have the same
shape. Anything else is an InputError naming the argument, never a silently wrong number: an 8-bit
image (convert it with ``nsim.io.images.to_float``) or one in [-1, 1] would otherwise score as a
different image. ``RANGE_TOLERANCE`` (relative to ``data_range``) admits rounding just outside the
range, e.g. ``x * 255 / 255``. A mask is an ``(H, W)`` bool array selecting the pixels that count
(e.g. the human's box).

PSNR is ``psnr_from_mse``: the one formula, also for callers that already hold an MSE (a training
batch's loss).

SSIM is scikit-image's ``structural_similarity`` with the settings of Wang et al. 2004 (and of the
NeRF literature): an 11x11 Gaussian window with sigma 1.5, population covariances, K1 = 0.01,
K2 = 0.03 and ``data_range`` as given; colour images get the mean of the per-channel SSIM.
``gaussian=False`` switches to scikit-image's default 7x7 uniform window with sample covariances.
The score is the mean of the SSIM map over the selected pixels, leaving out a border of half a window
(where scikit-image's own mean leaves it out too), so an all-True mask gives scikit-image's value.
"""

from __future__ import annotations

import math

import numpy as np
from skimage.metrics import structural_similarity

from nsim.errors import InputError

SSIM_SIGMA = 1.5  # Gaussian window: scikit-image truncates at 3.5 sigma -> 11x11
SSIM_GAUSSIAN_WIN = 11
SSIM_UNIFORM_WIN = 7
RANGE_TOLERANCE = 1e-6  # of data_range: values within it outside [0, data_range] still pass


def check_image_pair(
    pred: np.ndarray, target: np.ndarray, what: str = "images", data_range: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Both as float64 arrays of the same shape.

    InputError (one line, naming ``pred`` or ``target``) for a non-floating dtype (uint8, bool, int),
    differing sizes, NaN/inf, or values outside ``[0, data_range]`` (give or take ``RANGE_TOLERANCE``).
    """
    pred, target = np.asarray(pred), np.asarray(target)
    for name, image in (("pred", pred), ("target", target)):
        if image.dtype.kind != "f":
            hint = " (8-bit images: nsim.io.images.to_float)" if image.dtype == np.uint8 else ""
            raise InputError(
                f"{what}: {name} must be a floating-point image in [0, {data_range:g}], got dtype {image.dtype}{hint}"
            )
    if pred.shape != target.shape:
        raise InputError(f"{what} differ in size: pred {pred.shape} vs target {target.shape}")
    if pred.ndim not in (2, 3) or pred.size == 0:
        raise InputError(f"{what}: expected non-empty (H, W) or (H, W, C) arrays, got {pred.shape}")
    pred, target = pred.astype(np.float64), target.astype(np.float64)
    if not (np.isfinite(pred).all() and np.isfinite(target).all()):
        raise InputError(f"{what} contain NaN or inf")
    slack = RANGE_TOLERANCE * data_range
    for name, image in (("pred", pred), ("target", target)):
        lo, hi = float(image.min()), float(image.max())
        if lo < -slack or hi > data_range + slack:
            raise InputError(
                f"{what}: {name} values must lie in [0, {data_range:g}], got [{lo:.6g}, {hi:.6g}]"
            )
    return pred, target


def check_mask(mask: np.ndarray | None, shape_hw: tuple[int, ...]) -> np.ndarray | None:
    """``mask`` validated as a non-empty (H, W) bool array (None passes through)."""
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.shape != tuple(shape_hw):
        raise InputError(f"mask: expected shape {tuple(shape_hw)} (the images' H, W), got {mask.shape}")
    if mask.dtype != bool:
        raise InputError(f"mask: expected a bool array, got dtype {mask.dtype}")
    if not mask.any():
        raise InputError("mask is empty (no pixel selected)")
    return mask


def _check_data_range(data_range: float) -> None:
    if not (math.isfinite(data_range) and data_range > 0):
        raise ValueError(f"data_range: expected a finite value > 0, got {data_range!r}")


def psnr_from_mse(mse: float, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of a mean squared error: ``10 log10(data_range^2 / mse)``;
    ``inf`` for ``mse == 0``. ValueError for a negative or non-finite ``mse``.
    """
    _check_data_range(data_range)
    mse = float(mse)
    if not (math.isfinite(mse) and mse >= 0.0):
        raise ValueError(f"mse: expected a finite value >= 0, got {mse!r}")
    return math.inf if mse == 0.0 else 10.0 * math.log10(data_range**2 / mse)


def psnr(
    pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None, data_range: float = 1.0
) -> float:
    """Peak signal-to-noise ratio in dB (``psnr_from_mse``), MSE over every channel of the selected
    pixels. ``inf`` for identical images.
    """
    _check_data_range(data_range)
    pred, target = check_image_pair(pred, target, data_range=data_range)
    mask = check_mask(mask, pred.shape[:2])
    sq = (pred - target) ** 2
    return psnr_from_mse(float(np.mean(sq if mask is None else sq[mask])), data_range)


def ssim(
    pred: np.ndarray,
    target: np.ndarray,
    mask: np.ndarray | None = None,
    data_range: float = 1.0,
    gaussian: bool = True,
) -> float:
    """Mean SSIM (window and border as in the module docstring) over all pixels or the mask's.

    Raises InputError for images smaller than the window or a mask with no pixel off the border.
    """
    _check_data_range(data_range)
    pred, target = check_image_pair(pred, target, data_range=data_range)
    mask = check_mask(mask, pred.shape[:2])
    win = SSIM_GAUSSIAN_WIN if gaussian else SSIM_UNIFORM_WIN
    if min(pred.shape[:2]) < win:
        raise InputError(f"SSIM: images must be at least {win} px on each side, got {pred.shape[:2]}")
    options = dict(gaussian_weights=True, sigma=SSIM_SIGMA, use_sample_covariance=False) if gaussian else {}
    channel_axis = -1 if pred.ndim == 3 else None
    _, ssim_map = structural_similarity(
        pred, target, data_range=data_range, channel_axis=channel_axis, full=True, **options
    )
    if ssim_map.ndim == 3:
        ssim_map = ssim_map.mean(axis=2)
    pad = (win - 1) // 2
    inner = np.zeros(pred.shape[:2], dtype=bool)
    inner[pad : pred.shape[0] - pad, pad : pred.shape[1] - pad] = True
    selected = inner if mask is None else inner & mask
    if not selected.any():
        raise InputError(f"SSIM: the mask selects no pixel farther than {pad} px from the image border")
    return float(ssim_map[selected].mean())
