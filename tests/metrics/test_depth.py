"""Depth metrics: hand-computed pairs, median scaling, validity masks and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.metrics.depth import (
    DepthConfig,
    abs_rel,
    depth_error_map,
    depth_metrics,
    mean_depth_metrics,
    scored_depths,
    valid_depth_mask,
)


def test_known_pair():
    gt = np.array([[1.0, 2.0], [4.0, 5.0]])
    pred = np.array([[1.1, 2.0], [3.0, 5.0]])  # errors 0.1, 0, -1, 0
    m = depth_metrics(pred, gt)
    assert m.abs_rel == pytest.approx((0.1 / 1 + 0 + 1 / 4 + 0) / 4, abs=1e-15)
    assert m.sq_rel == pytest.approx((0.01 / 1 + 1 / 4) / 4, abs=1e-15)
    assert m.rmse_m == pytest.approx(math.sqrt((0.01 + 1) / 4), abs=1e-15)
    assert m.log_rmse == pytest.approx(math.sqrt((math.log(1.1) ** 2 + math.log(3 / 4) ** 2) / 4), abs=1e-15)
    # ratios max(p/g, g/p): 1.1, 1, 4/3, 1
    assert (m.delta_1_05, m.delta_1_10, m.delta_1_25) == (0.5, 0.5, 0.75)  # 1.1 < 1.10 is false
    assert (m.delta_1_25_2, m.delta_1_25_3) == (1.0, 1.0)
    assert m.n_valid == 4 and not m.median_scaled and m.scale == 1.0


def test_perfect_prediction():
    gt = np.linspace(0.5, 8.0, 30).reshape(5, 6)
    m = depth_metrics(gt.copy(), gt)
    assert (m.abs_rel, m.sq_rel, m.rmse_m, m.log_rmse) == (0.0, 0.0, 0.0, 0.0)
    assert m.delta_1_05 == 1.0


def test_median_scaling_removes_a_global_scale():
    gt = np.linspace(0.5, 8.0, 30).reshape(5, 6)
    unscaled = depth_metrics(gt * 0.55, gt)
    assert unscaled.abs_rel == pytest.approx(0.45)
    # ratio 1/0.55 = 1.82: above 1.25^2 = 1.56, below 1.25^3 = 1.95
    assert unscaled.delta_1_25_3 == 1.0 and unscaled.delta_1_25_2 == 0.0
    scaled = depth_metrics(gt * 0.55, gt, DepthConfig(median_scaling=True))
    assert scaled.median_scaled and scaled.scale == pytest.approx(1 / 0.55)
    assert scaled.abs_rel == pytest.approx(0.0, abs=1e-15)
    assert scaled.row()["scaling"] == "median" and unscaled.row()["scaling"] == "none"


def test_invalid_ground_truth_is_ignored():
    gt = np.array([[1.0, np.nan], [np.inf, 20.0], [0.0, 2.0]])
    pred = np.array([[2.0, 7.0], [7.0, 7.0], [7.0, 2.0]])
    assert valid_depth_mask(gt, DepthConfig()).tolist() == [[True, False], [False, False], [False, True]]
    m = depth_metrics(pred, gt)
    assert m.n_valid == 2 and m.abs_rel == pytest.approx(0.5)
    wide = depth_metrics(pred, gt, DepthConfig(max_depth_m=30.0))
    assert wide.n_valid == 3


def test_mask_restricts_pixels():
    gt = np.full((2, 2), 2.0)
    pred = np.array([[2.0, 4.0], [2.0, 4.0]])
    mask = np.array([[True, False], [True, False]])
    assert depth_metrics(pred, gt, mask=mask).abs_rel == 0.0
    assert depth_metrics(pred, gt).abs_rel == pytest.approx(0.5)


def test_predictions_are_clamped_to_the_range():
    gt = np.array([[5.0, 5.0]])
    pred = np.array([[np.inf, 0.0]])  # no hit -> max depth; nonpositive -> min depth
    cfg = DepthConfig(min_depth_m=0.1, max_depth_m=10.0)
    m = depth_metrics(pred, gt, cfg)
    assert m.abs_rel == pytest.approx(((10 - 5) / 5 + (5 - 0.1) / 5) / 2)
    assert math.isfinite(m.log_rmse)


def test_mean_over_frames():
    gt = np.full((2, 2), 2.0)
    a = depth_metrics(gt, gt)
    b = depth_metrics(gt * 1.5, gt)
    mean = mean_depth_metrics([a, b])
    assert mean.abs_rel == pytest.approx(0.25) and mean.n_valid == 8
    with pytest.raises(ValueError, match="mix"):
        mean_depth_metrics([a, depth_metrics(gt, gt, DepthConfig(median_scaling=True))])


def test_bad_input():
    gt = np.full((3, 4), 2.0)
    with pytest.raises(InputError, match="differ in size"):
        depth_metrics(np.ones((4, 3)), gt)
    with pytest.raises(InputError, match="no valid pixel"):
        depth_metrics(gt, np.full((3, 4), np.nan))
    with pytest.raises(InputError, match="no valid pixel"):
        depth_metrics(gt, np.full((3, 4), 50.0))  # all beyond max_depth_m
    with pytest.raises(InputError, match="mask is empty"):
        depth_metrics(gt, gt, mask=np.zeros((3, 4), dtype=bool))
    pred = gt.copy()
    pred[0, 0] = np.nan
    with pytest.raises(InputError, match="NaN at 1 valid pixel"):
        depth_metrics(pred, gt)
    with pytest.raises(ValueError, match="max_depth_m"):
        DepthConfig(min_depth_m=5.0, max_depth_m=1.0)


# ---- AbsRel: one definition (abs_rel, depth_metrics and depth_error_map agree) -----------------------


def test_abs_rel_known_values_and_the_one_rule():
    gt = np.array([[1.0, 2.0, 4.0], [5.0, np.nan, 0.0], [20.0, 2.0, 2.0]])
    pred = np.array([[1.1, 2.0, 3.0], [5.0, 9.0, 9.0], [9.0, np.inf, 0.0]])
    # valid ground truth: finite and in [1e-3, 10] m -> 1, 2, 4, 5, 2, 2 (NaN, 0 and 20 m are left out);
    # the prediction is clamped into the range: inf -> 10 m, 0 -> 1 mm
    expected = (0.1 / 1 + 0 + 1 / 4 + 0 + 8 / 2 + (2 - 1e-3) / 2) / 6
    assert abs_rel(pred, gt) == pytest.approx(expected, abs=1e-15)
    assert depth_metrics(pred, gt).abs_rel == abs_rel(pred, gt)
    err = depth_error_map(pred, gt)
    assert np.isnan(err).tolist() == [[False] * 3, [False, True, True], [True, False, False]]
    assert err[0].tolist() == pytest.approx([0.1, 0.0, 0.25], abs=1e-15)
    assert float(np.nanmean(err)) == pytest.approx(expected, abs=1e-15)
    mask = np.zeros(gt.shape, bool)
    mask[0] = True
    assert abs_rel(pred, gt, mask=mask) == pytest.approx((0.1 + 0 + 0.25) / 3, abs=1e-15)
    scaled = DepthConfig(median_scaling=True)
    assert abs_rel(gt[:1] * 3.0, gt[:1], scaled) == pytest.approx(0.0, abs=1e-15)
    assert abs_rel(gt[:1] * 3.0, gt[:1], scaled) == depth_metrics(gt[:1] * 3.0, gt[:1], scaled).abs_rel


def test_scored_depths_and_abs_rel_refuse_what_depth_metrics_refuses():
    gt = np.full((3, 4), 2.0)
    valid, p, g, scale = scored_depths(np.full((3, 4), 50.0), gt)
    assert valid.all() and p.tolist() == [10.0] * 12 and g.tolist() == [2.0] * 12 and scale == 1.0
    pred = gt.copy()
    pred[0, 0] = np.nan
    for fn in (abs_rel, depth_error_map):
        with pytest.raises(InputError, match="NaN at 1 valid pixel"):
            fn(pred, gt)
        with pytest.raises(InputError, match="no valid pixel"):
            fn(gt, np.full((3, 4), np.nan))
        with pytest.raises(InputError, match="differ in size"):
            fn(gt[:2], gt)
