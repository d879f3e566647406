"""The paper's five tables from per-frame records (hand-computed means, medians, pooled counts),
strict records, and the plots (per-frame curves, bars, depth error maps).
"""

from __future__ import annotations

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.images import read_image
from nsim.metrics.depth import DepthConfig, depth_metrics
from nsim.metrics.paper_tables import (
    TABLE_BUILDERS,
    DepthRecord,
    ImageRecord,
    SlamRecord,
    depth_error_map,
    depth_records,
    detection_table,
    image_records,
    plot_bars,
    plot_depth_error_map,
    plot_per_frame,
    scenes_table,
    slam_table,
    spot_depth_table,
    spot_rgb_table,
)
from nsim.metrics.results_table import NotAvailable

IMAGES = [
    {"group": "robot-lab", "frame": 0, "psnr_db": 23.0, "ssim": 0.78, "lpips": 0.26},
    ImageRecord("robot-lab", 1, 25.0, 0.80, 0.30),
    {"group": "kitchen", "frame": 0, "psnr_db": 20.0, "ssim": 0.70, "lpips": NotAvailable("no LPIPS weights")},
    {"group": "kitchen", "frame": 1, "psnr_db": 22.0, "ssim": 0.72, "lpips": 0.2},
]


def depth_record(group: str, frame: int, pred: float, gt: float = 2.0, scaled: bool = False) -> DepthRecord:
    pred_m, gt_m = np.full((4, 5), pred), np.full((4, 5), gt)
    return DepthRecord.from_metrics(group, frame, depth_metrics(pred_m, gt_m, DepthConfig(median_scaling=scaled)))


def test_scenes_table_means_and_na():
    depth = [depth_record("robot-lab", 0, 2.2), depth_record("robot-lab", 1, 2.3)]
    t = scenes_table(IMAGES, depth, DepthConfig(max_depth_m=8.0))
    assert [c.header for c in t.columns] == ["Environment", "PSNR ↑", "SSIM ↑", "LPIPS ↓", "AbsRel ↓",
                                             "RMSE [m] ↓", "δ<1.25 ↑", "frames"]
    lab, kitchen = t.rows
    assert lab["Environment"] == "robot-lab" and lab["frames"] == 2
    assert lab["PSNR"] == pytest.approx(24.0) and lab["SSIM"] == pytest.approx(0.79)
    assert lab["LPIPS"] == pytest.approx(0.28)
    assert lab["AbsRel"] == pytest.approx((0.1 + 0.15) / 2) and lab["RMSE [m]"] == pytest.approx(0.25)
    assert lab["δ<1.25"] == 1.0
    assert kitchen["LPIPS"] == NotAvailable("no LPIPS weights")
    assert kitchen["AbsRel"] == NotAvailable("no depth metrics for this environment")
    assert "depth metrics without median scaling" in t.notes and "depth over ground truth in [0.001, 8] m" in t.notes
    md = t.to_markdown()
    assert "| robot-lab | 24.00 | 0.790 | 0.280 | 0.125 | 0.250 | 1.000 | 2 |" in md
    assert "- n/a¹: no LPIPS weights" in md
    assert "Environment" in t.to_latex() and r"LPIPS $\downarrow$" in t.to_latex()
    only_images = scenes_table(IMAGES[:2])
    assert [c.name for c in only_images.columns] == ["Environment", "PSNR", "SSIM", "LPIPS", "frames"]


def test_spot_rgb_table():
    records = [ImageRecord(cam, k, 10.0 + k, 0.3, None) for cam in ("left", "right") for k in range(3)]
    t = spot_rgb_table(records)
    assert [r["Camera"] for r in t.rows] == ["left", "right"]
    assert t.rows[0]["PSNR"] == pytest.approx(11.0) and t.rows[0]["frames"] == 3
    assert t.rows[0]["LPIPS"] == NotAvailable("LPIPS not computed")


def test_spot_depth_table_hand_computed():
    # gt 2 m, pred 2.2 m: |e| = 0.2, AbsRel 0.1, SqRel 0.04 / 2 = 0.02, ratio 1.1 (above 1.05, at 1.10 not below)
    # gt 2 m, pred 1.6 m: AbsRel 0.2, SqRel 0.16 / 2 = 0.08, RMSE 0.4, ratio 1.25 (not below 1.25)
    t = spot_depth_table([depth_record("frontleft", 0, 2.2), depth_record("frontleft", 1, 1.6),
                          depth_record("back", 0, 2.0)])
    front = t.rows[0]
    assert front["AbsRel"] == pytest.approx(0.15) and front["SqRel"] == pytest.approx(0.05)
    assert front["RMSE [m]"] == pytest.approx(0.3)
    assert front["logRMSE"] == pytest.approx((np.log(1.1) + np.log(1.25)) / 2)
    assert front["δ<1.05"] == 0.0 and front["δ<1.25²"] == 1.0 and front["frames"] == 2
    assert t.rows[1]["AbsRel"] == 0.0 and t.rows[1]["δ<1.05"] == 1.0
    assert [c.header for c in t.columns][1:5] == ["AbsRel ↓", "SqRel ↓", "RMSE [m] ↓", "logRMSE ↓"]
    assert r"$\delta_{1.25^2}$ $\uparrow$" in t.to_latex()
    scaled = spot_depth_table([depth_record("back", 0, 4.0, scaled=True)])
    assert scaled.rows[0]["AbsRel"] == pytest.approx(0.0) and "with median scaling" in scaled.notes[1]
    with pytest.raises(InputError, match="mix median-scaled and unscaled"):
        spot_depth_table([depth_record("a", 0, 2.0), depth_record("a", 1, 2.0, scaled=True)])


def test_slam_table_medians():
    records = [SlamRecord("left", 0.10, 0.30), {"sequence": "right", "ate_real_m": 0.14, "ate_sim_m": 0.24},
               SlamRecord("back", 0.20, 0.20)]
    t = slam_table(records)
    assert [r["Sequence"] for r in t.rows] == ["left", "right", "back", "median"] and t.footer_rows == 1
    assert t.rows[0]["Δ sim−real [m]"] == pytest.approx(0.2)
    median = t.rows[-1]
    assert (median["ATE real [m]"], median["ATE sim [m]"]) == (0.14, 0.24)
    assert median["Δ sim−real [m]"] == pytest.approx(0.10)
    assert [c.name for c in t.columns] == ["Sequence", "ATE real [m]", "ATE sim [m]", "Δ sim−real [m]"]
    assert "SIM3 alignment" in t.notes[0]
    failed = slam_table([SlamRecord("a", 0.1, NotAvailable("SLAM lost track"), 1.0, 0.2), SlamRecord("b", 0.3, 0.4)])
    assert failed.rows[0]["Δ sim−real [m]"] == NotAvailable("SLAM lost track")
    assert failed.rows[-1]["ATE sim [m]"] == 0.4 and failed.rows[-1]["ATE real [m]"] == pytest.approx(0.2)
    assert "registered sim" in [c.name for c in failed.columns]
    assert any("over the 1 sequences" in n for n in failed.notes)
    assert len(slam_table(records[:1]).rows) == 1  # no median of one


def test_detection_table_pools_frames():
    records = [
        {"scene": "kitchen", "frame": 0, "n_sim": 2, "n_real": 1, "ious": [0.8]},
        {"scene": "kitchen", "frame": 1, "n_sim": 1, "n_real": 2, "ious": [0.6]},
        {"scene": "lab", "frame": 0, "n_sim": 0, "n_real": 1, "ious": []},
    ]
    t = detection_table(records, iou_threshold=0.5)
    kitchen, lab, total = t.rows
    assert kitchen["IoU"] == pytest.approx(0.7) and kitchen["precision"] == pytest.approx(2 / 3)
    assert kitchen["recall"] == pytest.approx(2 / 3) and kitchen["matched"] == 2 and kitchen["frames"] == 2
    assert lab["IoU"] == NotAvailable("no simulated box matched a real one")
    assert lab["precision"] == NotAvailable("no box detected on the simulated frames") and lab["recall"] == 0.0
    assert total["Scene"] == "all" and total["boxes real"] == 4 and total["recall"] == pytest.approx(0.5)
    assert "a simulated box matches a real one at IoU >= 0.5 (one-to-one)" in t.notes
    two = detection_table([{**records[0], "detector": "hog"}, {**records[0], "detector": "yolo"}])
    assert [c.name for c in two.columns][:2] == ["Scene", "Detector"] and len(two.rows) == 4
    with pytest.raises(InputError, match="2 matches but 1 simulated"):
        detection_table([{"scene": "a", "frame": 0, "n_sim": 1, "n_real": 3, "ious": [0.5, 0.6]}])


def test_strict_records():
    assert set(TABLE_BUILDERS) == {"scenes", "spot-rgb", "spot-depth", "slam", "detection"}
    with pytest.raises(InputError, match=r"scenes record 0: unknown field\(s\) \['psnr'\]"):
        scenes_table([{"group": "a", "frame": 0, "psnr": 1.0, "ssim": 0.5}])
    with pytest.raises(InputError, match=r"spot-rgb record 0: missing field\(s\) \['ssim'\]"):
        spot_rgb_table([{"group": "a", "frame": 0, "psnr_db": 1.0}])
    with pytest.raises(InputError, match="spot-rgb record 1: ssim is NaN"):
        spot_rgb_table([ImageRecord("a", 0, 1.0, 0.5), ImageRecord("a", 1, 1.0, float("nan"))])
    with pytest.raises(InputError, match="slam: no records"):
        slam_table([])
    with pytest.raises(InputError, match="expected a SlamRecord or a dict"):
        slam_table([("a", 1.0, 2.0)])


def test_tables_write_all(tmp_path):
    paths = spot_rgb_table(IMAGES).write_all(tmp_path, "spot-rgb")
    assert "PSNR ↑" in paths["md"].read_text(encoding="utf-8")
    assert r"\toprule" in paths["tex"].read_text(encoding="utf-8")


# ---- plots ---------------------------------------------------------------------------------


def test_plot_per_frame_and_bars(tmp_path):
    path = plot_per_frame(tmp_path / "psnr.png", IMAGES, "psnr_db", ylabel="PSNR [dB]")
    image = read_image(path)
    assert image.shape[:2] == (350, 700) and image.std() > 0
    lpips = plot_per_frame(tmp_path / "lpips.png", IMAGES, "lpips")  # n/a values are gaps
    assert lpips.is_file()
    with pytest.raises(InputError, match="no record has a value for 'psnr'"):
        plot_per_frame(tmp_path / "x.png", IMAGES, "psnr")
    bars = plot_bars(tmp_path / "bars.png", spot_rgb_table(IMAGES))
    assert read_image(bars).shape[:2] == (340, 840)  # three panels: PSNR, SSIM, LPIPS
    with pytest.raises(ValueError, match="unknown"):
        plot_bars(tmp_path / "bars.png", spot_rgb_table(IMAGES), ["PNSR"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bars.png", "lpips.png", "psnr.png"]


def test_depth_error_map(tmp_path):
    gt = np.full((30, 40), 2.0)
    gt[:5] = np.inf  # sky: invalid
    pred = np.full((30, 40), 2.5)
    pred[20:, :] = 1.5
    err = depth_error_map(pred, gt)
    assert np.isnan(err[:5]).all()
    np.testing.assert_allclose(err[5:20], 0.25)
    np.testing.assert_allclose(err[20:], 0.25)
    assert np.nanmean(err) == pytest.approx(depth_metrics(pred, gt).abs_rel)
    scaled = depth_error_map(pred * 3.0, gt, DepthConfig(median_scaling=True))
    assert np.nanmean(scaled) == pytest.approx(depth_metrics(pred * 3.0, gt, DepthConfig(median_scaling=True)).abs_rel)
    path = plot_depth_error_map(tmp_path / "err.png", pred, gt)
    png = read_image(path)
    assert png.ndim == 3 and len(np.unique(png.reshape(-1, png.shape[2]), axis=0)) > 10
    with pytest.raises(InputError, match="differ in size"):
        depth_error_map(pred[:10], gt)
    nan_pred = pred.copy()
    nan_pred[10, 10] = np.nan
    with pytest.raises(InputError, match="NaN"):
        plot_depth_error_map(tmp_path / "bad.png", nan_pred, gt)
    with pytest.raises(InputError, match="mask is empty"):
        depth_error_map(pred, gt, mask=np.zeros(gt.shape, bool))
    assert not (tmp_path / "bad.png").exists()


# ---- records from frames -------------------------------------------------------------------


def test_records_from_frames():
    rng = np.random.default_rng(0)
    targets = [rng.uniform(0.2, 0.8, (24, 32, 3)) for _ in range(3)]
    preds = [t + 0.1 for t in targets]  # MSE 0.01 -> PSNR 20 dB
    records = image_records("kitchen", preds, targets, lpips_net=None, frames=[4, 5, 6])
    assert [r.frame for r in records] == [4, 5, 6] and all(r.lpips is None for r in records)
    assert records[0].psnr_db == pytest.approx(20.0)
    assert 0.0 < records[0].ssim < 1.0
    with pytest.raises(InputError, match="kitchen: 3 rendered image frames but 2 ground-truth frames"):
        image_records("kitchen", preds, targets[:2], lpips_net=None)
    with pytest.raises(InputError, match=r"kitchen frame 1: images differ in size"):
        image_records("kitchen", [preds[0], preds[1][:10]], targets[:2], lpips_net=None)
    gts = [np.full((6, 8), 2.0), np.full((6, 8), 4.0)]
    depth = depth_records("back", [g * 1.1 for g in gts], gts)
    assert [r.abs_rel for r in depth] == [pytest.approx(0.1), pytest.approx(0.1)]
    assert depth[1].rmse_m == pytest.approx(0.4)
    bad = gts[1].copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="back frame 1: depth prediction is NaN"):
        depth_records("back", [gts[0], bad], gts)
    with pytest.raises(InputError, match="2 depth frames but 1 masks"):
        depth_records("back", gts, gts, masks=[None])


def test_image_records_lpips_is_the_metric_module_s():
    from nsim.metrics.lpips import lpips_or_na

    rng = np.random.default_rng(1)
    target = rng.uniform(0.0, 1.0, (64, 64, 3))
    pred = np.clip(target + rng.normal(0.0, 0.05, target.shape), 0.0, 1.0)
    record = image_records("lab", [pred * 255.0], [target * 255.0], data_range=255.0)[0]
    expected = lpips_or_na(pred, target)
    assert record.lpips == (expected if isinstance(expected, NotAvailable) else pytest.approx(expected, rel=1e-6))
