"""Occupancy grid: baking, queries, empty-space skipping == dense marching, obstacle maps."""

from __future__ import annotations

import numpy as np
import torch
from torch.testing import assert_close

from nsim.rendering.occupancy import OccupancyGrid, obstacle_map
from nsim.rendering.renderer import MarchConfig, march, render_rays
from nsim.volume.rays import make_rays
from tests.rendering.reference import BoxField, ToyModel

AABB = [[0.0, 0.0, 0.0], [4.0, 4.0, 2.0]]


def _scene():
    field = BoxField(lo=[2.5, 1.0, 0.0], hi=[3.0, 2.5, 1.2], sigma_in=80.0)
    return ToyModel(field, AABB)


def _rays(n=300, seed=0):
    g = torch.Generator().manual_seed(seed)
    origins = torch.tensor([0.5, 1.75, 0.6]) + (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([0.4, 1.0, 0.6])
    target = torch.tensor([2.75, 1.75, 0.6]) + (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([0.2, 2.6, 1.8])
    dirs = torch.nn.functional.normalize(target - origins, dim=-1)
    return make_rays(origins, dirs, 0.05, 30.0, torch.tensor(AABB))


def test_bake_and_query():
    model = _scene()
    grid = OccupancyGrid.bake(lambda x: model.field.density(x)[0], torch.tensor(AABB), 0.1, 1.0, samples_per_cell=1, dilate=0)
    assert grid.shape == (40, 40, 20)
    pts = torch.tensor([[2.75, 1.75, 0.6], [1.0, 1.0, 1.0], [-1.0, 0.0, 0.0]])
    assert grid.query(pts).tolist() == [True, False, True]  # outside the box: "occupied" (evaluate)
    assert grid.query(pts, outside=False).tolist() == [True, False, False]
    dilated = OccupancyGrid.bake(lambda x: model.field.density(x)[0], torch.tensor(AABB), 0.1, 1.0, samples_per_cell=1, dilate=1)
    assert dilated.occupied.sum() > grid.occupied.sum()
    assert (dilated.occupied | ~grid.occupied).all()  # dilation only adds cells


def test_save_load_roundtrip(tmp_path):
    model = _scene()
    grid = OccupancyGrid.bake(lambda x: model.field.density(x)[0], torch.tensor(AABB), 0.2, 1.0)
    grid.save(tmp_path / "occ.npy")
    back = OccupancyGrid.load(tmp_path / "occ.npy")
    assert torch.equal(back.occupied, grid.occupied) and torch.equal(back.aabb, grid.aabb)
    assert back.density_threshold == grid.density_threshold


def test_grid_marching_equals_dense_marching():
    model = _scene()
    rays = _rays()
    cfg_dense = MarchConfig(step_m=0.01, block_steps=32, stop_transmittance=0.0, color_skip_weight=0.0)
    dense = march(model, rays, None, cfg_dense)
    dense_calls = model.field.calls
    model.field.calls = 0
    grid = OccupancyGrid.bake(lambda x: model.field.density(x)[0], torch.tensor(AABB), 0.1, 1.0, samples_per_cell=2)
    model.field.calls = 0
    fast = march(model, rays, grid, MarchConfig(step_m=0.01, block_steps=32))
    assert model.field.calls * 10 < dense_calls  # most samples skipped
    mse = float(((fast.rgb - dense.rgb) ** 2).mean())
    assert -10 * np.log10(max(mse, 1e-20)) >= 45.0
    assert_close(fast.depth, dense.depth, atol=2e-3, rtol=0)
    assert_close(fast.depth_median, dense.depth_median)
    # the opaque box face: rays hit it and the depth is the distance to x = 2.5
    hit = dense.accumulation > 0.99
    assert hit.sum() > 100
    t_face = (2.5 - rays.origins[hit, 0]) / rays.dirs[hit, 0]
    assert (dense.depth_median[hit] - t_face).abs().max() < 0.011


def test_colour_skipping_is_bounded_in_haze():
    """Faint haze everywhere: the lightest samples' colour is skipped only up to the ray's budget."""
    field = BoxField(lo=[2.5, 1.0, 0.0], hi=[3.0, 2.5, 1.2], sigma_in=80.0, sigma_out=0.02)
    model = ToyModel(field, AABB)
    rays = _rays()
    dense = march(model, rays, None, MarchConfig(step_m=0.01, stop_transmittance=0.0, color_skip_weight=0.0))
    dense_colour = field.color_calls
    for budget in (1e-3, 1e-2):
        field.color_calls = 0
        fast = march(model, rays, None, MarchConfig(step_m=0.01, stop_transmittance=0.0, color_skip_weight=budget))
        assert field.color_calls < 0.95 * dense_colour  # the lightest samples lose their colour
        err = (fast.rgb - dense.rgb).abs().max()
        assert 0.2 * budget < err <= budget + 1e-6  # skipped samples count as black: bounded, not free
        assert_close(fast.accumulation, dense.accumulation)


def test_chunked_render_and_samples():
    model = _scene()
    rays = _rays(64, seed=1)
    grid = OccupancyGrid.bake(lambda x: model.field.density(x)[0], torch.tensor(AABB), 0.1, 1.0)
    whole = render_rays(model, rays, "march", grid, chunk=1000, return_samples=True)
    parts = render_rays(model, rays, "march", grid, chunk=10, return_samples=True)
    assert_close(whole.rgb, parts.rgb)
    s = parts.samples
    assert s.t_starts.shape == s.sigma.shape and s.rgb.shape == (*s.sigma.shape, 3)
    # re-compositing the returned samples gives the rendered colour
    from nsim.volume.compositing import composite

    again = composite(s)
    assert_close(again.rgb, parts.rgb, atol=2e-3, rtol=0)


def test_obstacle_map_and_polygons():
    model = _scene()
    om = obstacle_map(lambda x: model.field.density(x)[0], torch.tensor(AABB), (0.1, 1.0), 0.05, 1.0)
    assert om.occupied.shape == (80, 80)
    xs = om.origin_xy_m[0] + (np.arange(80) + 0.5) * 0.05
    ys = om.origin_xy_m[1] + (np.arange(80) + 0.5) * 0.05
    inside = (xs[:, None] > 2.5) & (xs[:, None] < 3.0) & (ys[None, :] > 1.0) & (ys[None, :] < 2.5)
    assert (om.occupied == inside).mean() > 0.98
    assert om.observed is None and (om.free == ~om.occupied).all()  # no cameras: every cell counts as observed
    regions = om.regions()
    assert len(regions) == 1 and regions[0].holes_m == ()
    p = regions[0].outer_m
    assert abs(p[:, 0].min() - 2.5) < 0.06 and abs(p[:, 0].max() - 3.0) < 0.06
    assert abs(p[:, 1].min() - 1.0) < 0.06 and abs(p[:, 1].max() - 2.5) < 0.06
    area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    assert area > 0  # counter-clockwise
    high = obstacle_map(lambda x: model.field.density(x)[0], torch.tensor(AABB), (1.5, 1.9), 0.05, 1.0)
    assert not high.occupied.any()  # above the box
