"""LiDAR metrics: per-beam range errors, hit/miss agreement, Chamfer distance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from nsim.errors import InputError
from nsim.metrics.lidar_realism import chamfer_distance, lidar_range_metrics


def test_range_errors_and_agreement():
    inf = np.inf
    gt = np.array([[1.0, 2.0, 3.0, inf], [5.0, inf, 4.0, 10.0]])
    pred = np.array([[1.1, 2.0, 2.5, inf], [5.0, 7.0, inf, 11.0]])
    m = lidar_range_metrics(pred, gt)
    err = np.array([0.1, 0.0, 0.5, 0.0, 1.0])  # beams where both hit
    assert m.n_beams == 8 and m.n_both_hit == 5 and m.n_both_miss == 1
    assert m.n_pred_only == 1 and m.n_gt_only == 1
    assert m.hit_agreement == pytest.approx(6 / 8)
    assert m.range_error_median_m == pytest.approx(0.1)
    assert m.range_error_mean_m == pytest.approx(err.mean())
    assert m.range_error_p95_m == pytest.approx(np.percentile(err, 95))
    assert m.range_bias_m == pytest.approx((0.1 + 0 - 0.5 + 0 + 1.0) / 5)


def test_identical_scans_and_nan_as_miss():
    gt = np.array([[1.0, np.nan, 3.0]])
    m = lidar_range_metrics(np.array([[1.0, np.inf, 3.0]]), gt)
    assert m.hit_agreement == 1.0 and m.range_error_p95_m == 0.0 and m.n_both_miss == 1


def test_no_common_hit_gives_na_range_errors():
    m = lidar_range_metrics(np.full((2, 3), np.inf), np.ones((2, 3)))
    assert m.range_error_mean_m is None and m.range_error_median_m is None and m.hit_agreement == 0.0
    assert m.row()["range err p95 [m]"] is None


def test_mask_selects_beams():
    gt = np.ones((2, 2))
    pred = np.array([[1.0, 3.0], [1.0, 3.0]])
    mask = np.array([[True, False], [True, False]])
    assert lidar_range_metrics(pred, gt, mask=mask).range_error_mean_m == 0.0
    assert lidar_range_metrics(pred, gt, mask=mask).n_beams == 2


def test_range_bad_input():
    with pytest.raises(InputError, match="differ in size"):
        lidar_range_metrics(np.ones((16, 10)), np.ones((16, 11)))
    with pytest.raises(InputError, match="negative"):
        lidar_range_metrics(-np.ones((2, 2)), np.ones((2, 2)))
    with pytest.raises(InputError, match="mask is empty"):
        lidar_range_metrics(np.ones((2, 2)), np.ones((2, 2)), mask=np.zeros((2, 2), dtype=bool))


def test_chamfer_matches_brute_force():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(200, 3))
    b = rng.normal(size=(150, 3)) + 0.2
    d = cdist(a, b)
    result = chamfer_distance(a, b)
    assert result.a_to_b_m == pytest.approx(d.min(axis=1).mean(), abs=1e-12)
    assert result.b_to_a_m == pytest.approx(d.min(axis=0).mean(), abs=1e-12)
    assert result.chamfer_m == pytest.approx(0.5 * (result.a_to_b_m + result.b_to_a_m))
    assert chamfer_distance(b, a).chamfer_m == pytest.approx(result.chamfer_m)


def test_chamfer_known_offset_and_scan_layout():
    a = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    assert chamfer_distance(a, a + [0, 0, 0.25]).chamfer_m == pytest.approx(0.25)
    scan = np.full((2, 2, 3), np.nan)  # (channels, azimuth, 3) with missing returns
    scan[0, 0] = [0.0, 0, 0]
    scan[1, 1] = [1.0, 0, 0]
    r = chamfer_distance(scan, a)
    assert (r.n_a, r.n_b) == (2, 3)
    assert r.a_to_b_m == 0.0 and r.b_to_a_m == pytest.approx(1 / 3)
    with pytest.raises(InputError, match="no finite point"):
        chamfer_distance(np.full((4, 3), np.nan), a)
    with pytest.raises(InputError, match=r"\(\.\.\., 3\)"):
        chamfer_distance(np.ones((4, 2)), a)
