"""Held-out scoring: chunked renders match the one-shot render, the appearance fit's cached colour is the
renderer's, the fit is deterministic and touches only its vector, eval.json says what was scored."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from nsim.io.labels import LABEL_HEIGHT_PX
from nsim.train.scene import SceneTrainer, train_scene
from nsim.train.scene_eval import (
    PROTOCOL_HALF,
    RECOLOUR_COEFFICIENT,
    AppearanceFit,
    EvalConfig,
    left_half_pixels,
    pixel_rays,
    render_image,
)
from nsim.train.scene_export import export_scene
from tests.train.test_scene import micro_cfg


@pytest.fixture(scope="module")
def trained(tiny_data, tmp_path_factory):
    """A micro model after a few steps (so its colours depend on the embedding)."""
    return train_scene(tiny_data, micro_cfg(optim={"steps": 12}), tmp_path_factory.mktemp("w"), seed=0).trainer


def _view(tr: SceneTrainer, i: int = 8, side: int = 0):
    return tr.view_rays(i, tr.data.eval_camera(i, side))


def test_chunked_render_matches_the_one_shot_render(trained):
    view = _view(trained)
    h, w = view.camera.height, view.camera.width
    idx = torch.arange(h * w)
    rays, z = pixel_rays(view, idx // w, idx % w, "cpu")
    with torch.no_grad():
        whole = trained.model.eval().render(rays)
    with ThreadPoolExecutor(2) as pool:
        chunked = render_image(trained.model, view, chunk=500, pool=pool)  # 500: chunks end mid-row
    torch.testing.assert_close(torch.from_numpy(chunked["rgb"]).view(-1, 3), whole.rgb.clamp(0, 1), atol=1e-6, rtol=0)
    torch.testing.assert_close(torch.from_numpy(chunked["depth_median_z"]).view(-1), whole.depth_median * z,
                               atol=1e-5, rtol=1e-6)
    cols = render_image(trained.model, view, chunk=333, cols=(w // 2, w))
    np.testing.assert_array_equal(cols["rgb"], chunked["rgb"][:, w // 2:])
    assert all(a.dtype == np.float32 for a in chunked.values())
    # the right half recoloured under another embedding in the same pass: the renderer's colour under it
    code = trained.model.field.appearance.weight[3].detach()
    both = render_image(trained.model, view, chunk=500, recolour=code, recolour_from=w // 2)
    np.testing.assert_array_equal(both["rgb"], chunked["rgb"])
    right = render_image(trained.model, view, chunk=500, cols=(w // 2, w), appearance=code)
    samples = trained.cfg.sampler.final_samples
    np.testing.assert_allclose(both["rgb_recoloured"], right["rgb"], atol=samples * RECOLOUR_COEFFICIENT + 2e-6, rtol=0)


@pytest.mark.parametrize("background", ["constant", "last_sample"])
def test_fit_colour_is_the_renderers(trained, background):
    model = trained.model.eval()
    old = model.sampler_cfg
    import dataclasses

    model.sampler_cfg = dataclasses.replace(old, background=background)
    try:
        view = _view(trained)
        v, u = left_half_pixels(view.camera.height, view.camera.width, 300, torch.Generator().manual_seed(1))
        rays, _ = pixel_rays(view, v, u, "cpu")
        mean = model.field.appearance_codes(None, 1, "mean", model.train_mask)[0].detach()
        fit = AppearanceFit.of(model, rays, mean)
        torch.testing.assert_close(fit.colour(mean), fit.rendered, atol=2e-6, rtol=0)
        other = model.field.appearance.weight[3].detach()  # another image's embedding
        with torch.no_grad():
            want = model.render(rays, appearance=other).rgb
        # samples below the coefficient threshold keep their mean-embedding colour: nearly the renderer's
        torch.testing.assert_close(fit.colour(other), want, atol=5e-3, rtol=0)
    finally:
        model.sampler_cfg = old


def test_fit_is_deterministic_and_changes_only_the_vector(trained):
    model = trained.model.eval()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    grads = [None if p.grad is None else p.grad.clone() for p in model.parameters()]
    view = _view(trained)
    v, u = left_half_pixels(view.camera.height, view.camera.width, 400, torch.Generator().manual_seed(2))
    assert (u < view.camera.width // 2).all() and len(set(zip(v.tolist(), u.tolist(), strict=True))) == 400
    rays, _ = pixel_rays(view, v, u, "cpu")
    mean = model.field.appearance_codes(None, 1, "mean", model.train_mask)[0].detach()
    target_code = model.field.appearance.weight[5].detach()
    with torch.no_grad():
        target = model.render(rays, appearance=target_code).rgb
    fit = AppearanceFit.of(model, rays, mean)
    a = fit.fit(target, mean, 60, 0.05)
    b = AppearanceFit.of(model, rays, mean).fit(target, mean, 60, 0.05)
    assert torch.equal(a, b)
    mse = lambda c: float(torch.mean((fit.colour(c) - target) ** 2))  # noqa: E731
    assert mse(a) < 0.5 * mse(mean)
    for k, val in model.state_dict().items():
        assert torch.equal(val, before[k]), k
    for p, g in zip(model.parameters(), grads, strict=True):  # the model's gradients are left as they were
        assert (p.grad is None and g is None) or torch.equal(p.grad, g)


def test_views_fitted_together_get_their_separate_fits_codes(trained):
    """fit_codes fits several views' codes in one batch: each equals that view's own fit (Adam is
    elementwise and each loss involves one code), and an unrelated view in the batch changes nothing."""
    from nsim.train.scene_eval import fit_codes

    model = trained.model.eval()
    view = _view(trained)
    mean = model.field.appearance_codes(None, 1, "mean", model.train_mask)[0].detach()
    fits, targets = [], []
    for seed, image in ((3, 5), (4, 1), (5, 7)):  # three "views": pixel sets and appearances of their own
        v, u = left_half_pixels(view.camera.height, view.camera.width, 200 + 50 * seed, torch.Generator().manual_seed(seed))
        rays, _ = pixel_rays(view, v, u, "cpu")
        with torch.no_grad():
            targets.append(model.render(rays, appearance=model.field.appearance.weight[image].detach()).rgb)
        fits.append(AppearanceFit.of(model, rays, mean))
    together = fit_codes(fits, targets, mean, 40, 0.05)
    assert together.shape == (3, mean.shape[0])
    for k in range(3):
        alone = fits[k].fit(targets[k], mean, 40, 0.05)
        torch.testing.assert_close(together[k], alone, atol=1e-5, rtol=0)
    assert not torch.allclose(together[0], together[1], atol=1e-3)  # the views' codes differ
    pair = fit_codes(fits[:2], targets[:2], mean, 40, 0.05)
    torch.testing.assert_close(pair, together[:2], atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="2 fits and 1 targets"):
        fit_codes(fits[:2], targets[:1], mean, 1, 0.05)


def test_view_abs_rel_scores_what_a_view_has():
    """The held-out views' AbsRel (nsim.metrics.depth.view_abs_rel): the metric's own rule (ground truth in
    [1 mm, 10 m], predictions clamped there), pixels without a rendered depth left out, NaN for a view
    with nothing to score; ``DepthConfig.in_units``: the same bounds in a scene's own units."""
    from nsim.errors import InputError
    from nsim.metrics.depth import DepthConfig, abs_rel, view_abs_rel

    gt = np.array([[1.0, 2.0], [4.0, 20.0]])  # 20 m: beyond the bound, never scored
    pred = np.array([[1.1, np.nan], [5.0, 30.0]])  # NaN: nothing rendered there
    assert view_abs_rel(pred, gt) == pytest.approx((0.1 + 0.25) / 2, abs=1e-15)
    clamped = np.array([[1.1, 2.0], [12.0, 1.0]])  # 12 m counts as 10 m
    assert view_abs_rel(clamped, gt) == pytest.approx((0.1 + 0.0 + 1.5) / 3, abs=1e-15)
    assert view_abs_rel(clamped, gt) == abs_rel(clamped, gt)  # the one definition
    assert np.isnan(view_abs_rel(np.full((2, 2), np.nan), gt))  # nothing rendered
    assert np.isnan(view_abs_rel(pred, np.full((2, 2), np.nan)))  # no ground truth
    with pytest.raises(InputError, match="differ in size"):
        view_abs_rel(pred[:1], gt)
    tens = DepthConfig().in_units(0.1)  # a scene in units of 10 m
    assert (tens.min_depth_m, tens.max_depth_m) == (pytest.approx(1e-4), pytest.approx(1.0))
    assert view_abs_rel(pred / 10, gt / 10, tens) == pytest.approx(view_abs_rel(pred, gt), abs=1e-12)
    with pytest.raises(ValueError, match="units_per_m"):
        DepthConfig().in_units(0.0)


def test_held_out_depth_abs_rel_is_the_depth_metric(trained):
    """score_view's AbsRel is nsim.metrics.depth's: ground truth beyond its 10 m bound does not count
    (the rule the trainer once had of its own, any positive ground truth, would count it)."""
    from nsim.metrics.depth import DepthConfig, abs_rel
    from nsim.train.scene_eval import score_view

    i = int(trained.eval_ids[1])
    camera = trained.data.eval_camera(i, 0)
    view = trained.view_rays(i, camera)
    gt = trained.data.eval_depth_z(i, camera).astype(np.float64)
    gt[: gt.shape[0] // 4] = 50.0  # a far wall: beyond the metric's bound
    row = score_view(trained.model, view, trained.data.eval_image(i, camera), gt, 500, trained.cfg.eval, False)
    pred = render_image(trained.model, view, 500)
    for key, depth in (("abs_rel_median", pred["depth_median_z"]), ("abs_rel_expected", pred["depth_z"])):
        assert row[key] == pytest.approx(abs_rel(depth, gt, DepthConfig(), ~np.isnan(depth)), rel=1e-12), key
        old = np.isfinite(gt) & (gt > 0) & np.isfinite(depth)
        assert abs(row[key] - float(np.mean(np.abs(depth[old] - gt[old]) / gt[old]))) > 0.05, key


def test_eval_json_scores_the_asked_resolution_and_the_half_protocol(tiny_data, tmp_path):
    cfg = micro_cfg(optim={"steps": 3}, output={"final_eval_views": 2}, eval={"image_side": 32, "fit_steps": 20})
    result = train_scene(tiny_data, cfg, tmp_path / "work", seed=0)
    summary = export_scene(tmp_path / "out", result)
    ev = json.loads((tmp_path / "out" / "eval.json").read_text())
    assert ev["resolution"]["scored_wh"] == [32, 24] and ev["resolution"]["captured_wh"] == [64, 48]
    assert ev["resolution"]["trained_wh"] == [64, 48]
    assert PROTOCOL_HALF in ev["protocol"]["psnr_half, ssim_half, lpips_half"]
    row = ev["views"][0]
    for key in ("psnr", "ssim", "psnr_half", "ssim_half", "psnr_half_mean_embedding", "abs_rel_median"):
        assert np.isfinite(row[key]), key
    assert "lpips" in row and "lpips_half" in row  # a value, or None with the reason beside it
    assert summary["eval_image_size"] == [32, 24] and "eval_psnr_half" in summary
    from nsim.io.images import read_image

    assert read_image(tmp_path / "out" / "eval" / "frame_00000.png").shape == (24 + LABEL_HEIGHT_PX, 64, 3)  # label strip over render | truth
    scene = json.loads((tmp_path / "out" / "scene.json").read_text())
    assert scene["metric"] is True and scene["units"] == "m" and scene["units_per_m"] == 1.0
    assert json.loads((tmp_path / "out" / "bounds.json").read_text())["metric"] is True


def test_models_without_appearance_get_no_half_scores(tiny_data):
    cfg = micro_cfg(optim={"steps": 1}, field={"appearance_dim": 0})
    tr = SceneTrainer(tiny_data, cfg, seed=0)
    ev = tr.evaluate([8], final=True)
    assert "psnr_half" not in ev["views"][0] and np.isfinite(ev["mean"]["psnr"])


def test_arbitrary_scale_scene_says_so_and_writes_no_metres(tiny_data, tmp_path):
    import dataclasses

    c2w = tiny_data.cam_to_world.copy()
    c2w[:, :3, 3] *= 0.1  # the room in units of 10 m
    data = dataclasses.replace(tiny_data, cam_to_world=c2w, metric=False, scale_source="arbitrary")
    cfg = micro_cfg(optim={"steps": 2}, output={"final_eval_views": 1})
    result = train_scene(data, cfg, tmp_path / "work", seed=0)
    tr = result.trainer
    assert tr.units_per_m == pytest.approx(0.1 * np.sqrt(np.mean(np.sum(
        (tiny_data.cam_to_world[:, :3, 3] - tiny_data.cam_to_world[:, :3, 3].mean(0)) ** 2, -1))) / 2.1)
    assert tr.cfg.sampler.near_m == pytest.approx(cfg.sampler.near_m * tr.units_per_m)
    assert tr.given_cfg is cfg
    export_scene(tmp_path / "out", result)
    scene = json.loads((tmp_path / "out" / "scene.json").read_text())
    assert scene["metric"] is False and scene["units"] == "arbitrary" and scene["scale_source"] == "arbitrary"
    bounds = json.loads((tmp_path / "out" / "bounds.json").read_text())
    assert bounds["metric"] is False and bounds["units"] == "arbitrary"
    assert not any(k.endswith("_m") for k in bounds)
    grid = json.loads((tmp_path / "out" / "occupancy_grid.json").read_text())
    assert grid["units"] == "arbitrary" and grid["metric"] is False


def test_eval_config_defaults():
    cfg = EvalConfig()
    assert cfg.image_side == 0 and cfg.fit_steps > 0 and cfg.lpips_net == "alex"


def test_export_on_two_threads_repeats_byte_for_byte(tiny_data, tmp_path):
    """Renders and the occupancy bake split over the worker threads: reruns still write the same bytes."""
    import hashlib

    cfg = micro_cfg(optim={"steps": 2, "batch_threads": 2}, output={"final_eval_views": 1, "render_chunk_rays": 700},
                    eval={"fit_steps": 10})
    digests = []
    for run in ("a", "b"):
        result = train_scene(tiny_data, cfg, tmp_path / f"work_{run}", seed=1)
        export_scene(tmp_path / run, result)
        files = sorted(p for p in (tmp_path / run).rglob("*") if p.is_file())
        digests.append({p.relative_to(tmp_path / run).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in files})
    assert digests[0] == digests[1]


def test_occupancy_cells_grow_to_stay_under_the_cap():
    import math

    from nsim.rendering.occupancy import grid_shape
    from nsim.train.scene_export import occupancy_cell

    aabb = np.array([[0.0, 0.0, 0.0], [10.0, 8.0, 3.0]])
    assert occupancy_cell(aabb, 0.1, 10**9) == 0.1
    cell = occupancy_cell(aabb, 0.01, 100_000)
    assert math.prod(grid_shape(aabb, cell)) <= 100_000 < math.prod(grid_shape(aabb, cell / 1.02))
