"""PSNR and SSIM: hand-computed values, scikit-image as the reference, masks, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from nsim.errors import InputError
from nsim.io.images import to_float, to_uint8
from nsim.metrics.image import psnr, psnr_from_mse, ssim


@pytest.fixture
def pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    target = rng.uniform(0.2, 0.8, size=(40, 48, 3))
    pred = np.clip(target + rng.normal(0.0, 0.05, size=target.shape), 0.0, 1.0)
    return pred, target


def test_psnr_hand_computed():
    target = np.zeros((4, 4))
    pred = np.full((4, 4), 0.1)  # MSE 0.01 -> 20 dB at data range 1
    assert psnr(pred, target) == pytest.approx(20.0, abs=1e-12)
    assert psnr(pred * 255, target, data_range=255.0) == pytest.approx(20.0, abs=1e-12)
    assert psnr(target, target) == math.inf


def test_psnr_matches_skimage(pair):
    pred, target = pair
    assert psnr(pred, target) == pytest.approx(
        peak_signal_noise_ratio(target, pred, data_range=1.0), abs=1e-10
    )


def test_psnr_mask_counts_only_selected_pixels():
    target = np.zeros((6, 6, 3))
    pred = target.copy()
    pred[:3] = 0.1  # top half off by 0.1
    pred[3:] = 0.5
    mask = np.zeros((6, 6), dtype=bool)
    mask[:3] = True
    assert psnr(pred, target, mask=mask) == pytest.approx(20.0, abs=1e-12)
    assert psnr(pred, target, mask=np.ones((6, 6), bool)) == pytest.approx(psnr(pred, target), abs=1e-12)


@pytest.mark.parametrize("gaussian", [True, False])
@pytest.mark.parametrize("channels", [None, 3])
def test_ssim_matches_skimage(pair, gaussian, channels):
    pred, target = pair
    if channels is None:
        pred, target = pred[..., 0], target[..., 0]
    options = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False) if gaussian else {}
    expected = structural_similarity(
        pred, target, data_range=1.0, channel_axis=None if channels is None else -1, **options
    )
    assert ssim(pred, target, gaussian=gaussian) == pytest.approx(expected, abs=1e-12)
    full = np.ones(pred.shape[:2], dtype=bool)
    assert ssim(pred, target, mask=full, gaussian=gaussian) == pytest.approx(expected, abs=1e-12)


def test_ssim_identical_is_one_and_mask_averages_the_map(pair):
    pred, target = pair
    assert ssim(target, target) == pytest.approx(1.0, abs=1e-12)
    # Perfect on the left half, noisy on the right: the left-half mask scores ~1, the right half less.
    half = target.copy()
    half[:, 24:] = pred[:, 24:]
    left = np.zeros(target.shape[:2], dtype=bool)
    left[:, :16] = True  # farther than a window from the noisy half
    assert ssim(half, target, mask=left) == pytest.approx(1.0, abs=1e-12)
    right = np.zeros_like(left)
    right[:, 30:] = True
    assert ssim(half, target, mask=right) == pytest.approx(ssim(pred, target, mask=right), abs=1e-12)
    assert ssim(half, target, mask=right) < 0.99


def test_ssim_mask_equals_map_mean(pair):
    pred, target = pair
    _, smap = structural_similarity(
        pred, target, data_range=1.0, channel_axis=-1, full=True,
        gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
    )  # fmt: skip
    mask = np.zeros(pred.shape[:2], dtype=bool)
    mask[10:20, 7:31] = True
    assert ssim(pred, target, mask=mask) == pytest.approx(smap.mean(axis=2)[mask].mean(), abs=1e-12)


@pytest.mark.parametrize("metric", [psnr, ssim])
def test_bad_input(metric, pair):
    pred, target = pair
    with pytest.raises(InputError, match="differ in size"):
        metric(pred[:-1], target)
    with pytest.raises(InputError, match="mask is empty"):
        metric(pred, target, mask=np.zeros(pred.shape[:2], dtype=bool))
    with pytest.raises(InputError, match="expected shape"):
        metric(pred, target, mask=np.ones((3, 3), dtype=bool))
    with pytest.raises(InputError, match="bool"):
        metric(pred, target, mask=np.ones(pred.shape[:2]))
    bad = pred.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN or inf"):
        metric(bad, target)


def test_ssim_bad_input(pair):
    pred, target = pair
    with pytest.raises(InputError, match="at least 11 px"):
        ssim(pred[:8], target[:8])
    border = np.zeros(pred.shape[:2], dtype=bool)
    border[:3] = True
    with pytest.raises(InputError, match="border"):
        ssim(pred, target, mask=border)


# ---- one definition, and refusing images that are not float in [0, data_range] ---------------------


def test_psnr_from_mse_is_the_formula():
    assert psnr_from_mse(0.01) == pytest.approx(20.0, abs=1e-12)
    assert psnr_from_mse(0.0001) == pytest.approx(40.0, abs=1e-12)
    assert psnr_from_mse(0.01 * 255.0**2, data_range=255.0) == pytest.approx(20.0, abs=1e-12)
    assert psnr_from_mse(0.0) == math.inf
    for bad in (-1e-3, math.nan, math.inf):
        with pytest.raises(ValueError, match="mse"):
            psnr_from_mse(bad)


def test_psnr_of_8bit_levels_hand_computed():
    # Two 8-bit images, one level apart everywhere but one pixel five levels apart.
    a = np.full((4, 5, 3), 100, np.uint8)
    b = a.copy()
    b[...] = 101
    b[0, 0] = (105, 105, 105)
    mse = (57 * 1 + 3 * 25) / 60 / 255.0**2  # 132 / 60 levels squared
    expected = 10.0 * math.log10(1.0 / mse)
    assert psnr(to_float(b), to_float(a)) == pytest.approx(expected, abs=1e-4)  # float32 levels
    assert psnr(b / 255.0, a / 255.0) == pytest.approx(expected, abs=1e-10)
    assert expected == pytest.approx(44.707, abs=1e-3)


@pytest.mark.parametrize("metric", [psnr, ssim])
def test_uint8_images_are_refused(metric, pair):
    pred, target = pair
    pred_u8, target_u8 = to_uint8(pred), to_uint8(target)
    with pytest.raises(InputError, match=r"pred must be a floating-point image in \[0, 1\], got dtype uint8") as err:
        metric(pred_u8, target)
    assert "\n" not in str(err.value) and "to_float" in str(err.value)
    with pytest.raises(InputError, match=r"target must be a floating-point image in \[0, 1\], got dtype uint8"):
        metric(pred, target_u8)
    with pytest.raises(InputError, match="got dtype uint8"):  # even with the 8-bit data range
        metric(pred_u8, target_u8, data_range=255.0)
    with pytest.raises(InputError, match="got dtype bool"):
        metric(pred > 0.5, target)
    # the same 8-bit images as float: accepted, and the score of the float pair
    assert metric(to_float(pred_u8), to_float(target_u8)) == pytest.approx(
        metric(pred_u8 / 255.0, target_u8 / 255.0), abs=1e-6
    )


@pytest.mark.parametrize("metric", [psnr, ssim])
def test_minus_one_to_one_images_are_refused(metric, pair):
    pred, target = pair
    signed_pred, signed_target = pred * 2.0 - 1.0, target * 2.0 - 1.0
    lo, hi = signed_pred.min(), signed_pred.max()
    with pytest.raises(InputError, match=rf"pred values must lie in \[0, 1\], got \[{lo:.6g}, {hi:.6g}\]") as err:
        metric(signed_pred, signed_target)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match=r"target values must lie in \[0, 1\], got \[-"):
        metric(pred, signed_target)
    with pytest.raises(InputError, match=r"target values must lie in \[0, 1\], got \[0, 255\]"):
        metric(pred, np.linspace(0.0, 255.0, target.size).reshape(target.shape))


def test_range_tolerance_and_data_range():
    target = np.zeros((12, 12))
    target[::2] = 1.0
    pred = target * 255.0 / 255.0 + 1e-9  # rounding just outside [0, 1] passes
    assert psnr(pred, target) > 100.0
    with pytest.raises(InputError, match=r"pred values must lie in \[0, 1\], got \[0.001, 1.001\]"):
        psnr(target + 1e-3, target)
    # data_range sets the range: 8-bit values as float are fine at 255 and refused at 1
    assert psnr(target * 255.0, target * 255.0 + 2.55 * (target < 1), data_range=255.0) == pytest.approx(
        10.0 * math.log10(1.0 / (0.01**2 / 2)), abs=1e-9
    )
    with pytest.raises(InputError, match=r"\[0, 1\], got \[0, 255\]"):
        ssim(target * 255.0, target * 255.0)
