"""The occupancy-grid training sampler (``sampler.kind: grid``) against a dense reference."""

from __future__ import annotations

import math

import pytest
import torch
from torch.testing import assert_close

from nsim.config import from_dict
from nsim.fields.scene_field import SceneFieldConfig
from nsim.rendering.model import SamplerConfig, SceneModel
from nsim.volume import quadrature
from nsim.volume.rays import make_rays

AABB = torch.tensor([[0.0, 0.0, 0.0], [4.0, 3.0, 2.0]])
FIELD = SceneFieldConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16, color_hidden_dim=16,
                         color_hidden_layers=1, appearance_dim=0, sh_degree=2, backend="torch", contract=False)


def _model(**sampler) -> SceneModel:
    base = {"kind": "grid", "grid_cell_m": 0.25, "grid_step_m": 0.05, "grid_samples_per_ray": 10_000,
            "grid_stop_transmittance": 0.0, "grid_block_steps": 7}
    cfg = from_dict(SamplerConfig, {**base, **sampler})
    model = SceneModel(FIELD, cfg, AABB, 4, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():  # a density with structure: raise the output bias so rays terminate
        model.field.density_mlp.layers[-1].bias[0] += 3.0
    return model.eval()


def _rays(n=64, seed=0):
    g = torch.Generator().manual_seed(seed)
    origins = torch.tensor([0.5, 1.5, 1.0]) + (torch.rand(n, 3, generator=g) - 0.5) * 0.4
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) + torch.tensor([2.0, 0.0, 0.0]), dim=-1)
    return make_rays(origins, dirs, 0.1, 30.0, AABB)


def _dense_reference(model: SceneModel, rays, step: float, occupied=None):
    """Every marching interval from near to the box (optionally only those in occupied cells),
    one ray at a time, rendered with ``volume`` over the last sample's colour (``background:
    last_sample``) or ``background_rgb``: rgb (R, 3), expected depth (R,)."""
    rgbs, depths = [], []
    for r in range(len(rays)):
        near, far = float(rays.near[r]), float(rays.far[r])
        k = torch.arange(0, max(1, math.ceil((far - near) / step)) + 1, dtype=torch.float32)
        t0 = near + (k + 0.5) * step
        t0 = t0[t0 < far]
        t1 = torch.minimum(t0 + step, torch.tensor(far))
        x = rays.origins[r] + rays.dirs[r] * (0.5 * (t0 + t1))[:, None]
        if occupied is not None:
            keep = occupied(x)
            t0, t1, x = t0[keep], t1[keep], x[keep]
        if len(t0) == 0:
            rgbs.append(model.background.clone())
            depths.append(torch.tensor(far))
            continue
        sigma, geo = model.field.density(x)
        rgb = model.field.color(geo, rays.dirs[r].expand(len(t0), 3), None)
        w, _ = quadrature.render_weights(sigma[None], (t1 - t0)[None])
        acc = w.sum()
        bg = rgb[-1] if model.sampler_cfg.background == "last_sample" else model.background  # the last sample's colour
        rgbs.append((w[0, :, None] * rgb).sum(0) + (1 - acc) * bg)
        depths.append(quadrature.expected_depth(w, (0.5 * (t0 + t1))[None], acc[None])[0])
    return torch.stack(rgbs), torch.stack(depths)


@torch.no_grad()
def test_all_cells_occupied_equals_dense_marching():
    model = _model()
    rays = _rays()
    out = model.render(rays)
    rgb, depth = _dense_reference(model, rays, 0.05)
    assert_close(out.rgb, rgb, atol=1e-5, rtol=0)
    assert_close(out.depth, depth, atol=1e-4, rtol=0)


@torch.no_grad()
def test_free_cells_are_skipped_exactly():
    model = _model()
    g = torch.Generator().manual_seed(1)
    model.grid_occupied.copy_(torch.rand(model.grid_occupied.shape, generator=g) < 0.4)
    rays = _rays()
    out = model.render(rays, return_samples=True)
    rgb, depth = _dense_reference(model, rays, 0.05, occupied=model._grid_query)
    assert_close(out.rgb, rgb, atol=1e-5, rtol=0)
    # every evaluated sample lies in an occupied cell
    s = out.samples
    real = s.t_ends > s.t_starts
    mid = 0.5 * (s.t_starts + s.t_ends)
    x = rays.origins[:, None, :] + rays.dirs[:, None, :] * mid[..., None]
    assert model._grid_query(x[real]).all()


@torch.no_grad()
def test_early_termination_changes_the_image_by_at_most_the_stop_transmittance():
    rays = _rays()
    full = _model().render(rays)
    model = _model(grid_stop_transmittance=1e-3)
    cut = model.render(rays)
    assert (cut.weights > 0).sum() < (full.weights > 0).sum()  # it did stop early
    assert (full.rgb - cut.rgb).abs().max() <= 1e-3 + 1e-6
    assert (full.accumulation - cut.accumulation).abs().max() <= 1e-3 + 1e-6


def test_training_pass_equals_inference_pass_and_has_gradients():
    model = _model(grid_stop_transmittance=1e-3)
    rays = _rays()
    model.train()
    out = model.render(rays, generator=torch.Generator().manual_seed(3))
    out.rgb.sum().backward()
    grads = [p.grad for p in model.field.parameters() if p.grad is not None]
    assert grads and any(float(g.abs().sum()) > 0 for g in grads)
    with torch.no_grad():
        ref = model.render(rays, generator=torch.Generator().manual_seed(3))
    assert_close(out.rgb.detach(), ref.rgb, atol=1e-6, rtol=0)


@torch.no_grad()
def test_sample_budget_grows_the_step():
    model = _model(grid_samples_per_ray=8)
    rays = _rays()
    counts, ray, t0, t1 = model._grid_candidates(rays, torch.full((len(rays),), 0.5))
    assert counts.float().mean() <= 8
    step = float((t1 - t0).max())
    assert step > 0.05 and abs(step / 0.05 - round(step / 0.05)) < 1e-4  # an integer multiple of grid_step_m
    assert int(counts.sum()) == ray.numel() and (torch.diff(ray) >= 0).all()


@torch.no_grad()
def test_update_grid_is_a_decaying_maximum():
    model = _model(grid_decay=0.5, grid_density_threshold=1e9)
    before = torch.full_like(model.grid_density, 7.0)
    model.grid_density.copy_(before)
    frac = model.update_grid(torch.Generator().manual_seed(0), all_cells=True)
    # redo the update by hand with the same generator
    g = torch.Generator().manual_seed(0)
    shape = before.shape
    idx = torch.arange(before.numel())
    ijk = torch.stack([idx // (shape[1] * shape[2]), (idx // shape[2]) % shape[1], idx % shape[2]], -1).float()
    cell = (AABB[1] - AABB[0]) / torch.tensor(shape, dtype=torch.float32)
    x = AABB[0] + (ijk + torch.rand(ijk.shape, generator=g)) * cell
    expected = torch.maximum(before.view(-1) * 0.5, model.field.density(x)[0])
    assert_close(model.grid_density.view(-1), expected)
    # threshold: min(grid_density_threshold, mean)
    assert torch.equal(model.grid_occupied, model.grid_density > model.grid_density.mean())
    assert frac == pytest.approx(float(model.grid_occupied.float().mean()))
