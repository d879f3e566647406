"""``sampler.background``: what a ray's remaining light is composited over, in every renderer."""

from __future__ import annotations

import torch
from torch.testing import assert_close

from nsim.config import from_dict
from nsim.fields.scene_field import SceneFieldConfig
from nsim.rendering.model import SamplerConfig, SceneModel
from nsim.rendering.occupancy import OccupancyGrid
from nsim.rendering.renderer import MarchConfig, march
from nsim.volume.rays import make_rays
from tests.rendering.reference import BoxField, ToyModel

AABB = [[0.0, 0.0, 0.0], [4.0, 4.0, 2.0]]
FIELD = SceneFieldConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16, color_hidden_dim=16,
                         color_hidden_layers=1, appearance_dim=0, sh_degree=2, backend="torch", contract=False)


def _rays():
    """8 rays into the box's wall (opaque) and 8 pointing up and away from it (they leave the
    scene box through its top without meeting anything)."""
    g = torch.Generator().manual_seed(0)
    o = torch.tensor([0.5, 1.75, 0.6]) + (torch.rand(16, 3, generator=g) - 0.5) * 0.2
    to_box = torch.tensor([2.75, 1.75, 0.6]) - o[:8]
    up = torch.tensor([-0.3, 0.2, 1.0]).expand(8, 3) + torch.rand(8, 3, generator=g) * 0.1
    d = torch.nn.functional.normalize(torch.cat([to_box, up]), dim=-1)
    return make_rays(o, d, 0.05, 30.0, torch.tensor(AABB))


def _colour_at(model, rays, t):
    x = rays.origins + rays.dirs * t[:, None]
    _, geo = model.field.density(x)
    return model.field.color(geo, rays.dirs, None)


@torch.no_grad()
def test_march_composites_escaping_rays_over_the_colour_at_their_far_end():
    field = BoxField(lo=[2.5, 1.0, 0.0], hi=[3.0, 2.5, 1.2], sigma_in=80.0)
    last, const = ToyModel(field, AABB, background="last_sample"), ToyModel(field, AABB, background="constant")
    rays = _rays()
    cfg = MarchConfig(step_m=0.01, block_steps=32)
    a, b = march(last, rays, None, cfg), march(const, rays, None, cfg)
    hit, away = slice(0, 8), slice(8, 16)
    assert (a.accumulation[hit] > 0.9999).all() and (a.accumulation[away] == 0).all()
    # the far end's colour: the midpoint of the last step, the one that ends where the ray leaves the box
    length = rays.far - rays.near
    t_last = rays.near + (torch.ceil(length / cfg.step_m) - 1) * cfg.step_m
    far_colour = _colour_at(last, rays, 0.5 * (t_last + torch.minimum(t_last + cfg.step_m, rays.far)))
    assert_close(a.rgb[away], far_colour[away], atol=1e-6, rtol=0)
    assert_close(a.background[away], far_colour[away])
    assert (b.rgb[away] == 0).all() and (b.background == 0).all()
    # rays that stop on a surface keep at most stop_transmittance of light: the same image either way
    assert_close(a.rgb[hit], b.rgb[hit], atol=cfg.stop_transmittance, rtol=0)
    assert (far_colour[away] > 0.05).all()  # the test would see a black background
    # the grid skips the free cells but the far end's colour is evaluated all the same
    grid = OccupancyGrid.bake(lambda x: field.density(x)[0], torch.tensor(AABB), 0.1, 1.0, samples_per_cell=2)
    assert not bool(grid.query(rays.origins[away] + rays.dirs[away] * (0.5 * (t_last + rays.far))[away, None]).all())
    assert_close(march(last, rays, grid, cfg).rgb, a.rgb, atol=1e-6, rtol=0)


def _empty_model(background: str, kind: str = "proposal") -> SceneModel:
    cfg = from_dict(SamplerConfig, {"kind": kind, "proposal_samples": [16], "proposal_hash_max_resolutions": [32],
                                    "final_samples": 8, "background": background, "background_rgb": [0.2, 0.3, 0.4],
                                    "grid_cell_m": 0.5, "grid_step_m": 0.1})
    model = SceneModel(FIELD, cfg, torch.tensor(AABB), 1, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():  # no density anywhere: every ray keeps all its light
        model.field.density_mlp.layers[-1].bias[0] -= 40.0
    return model.eval()


@torch.no_grad()
def test_proposal_and_grid_samplers_composite_over_the_last_sample():
    rays = _rays()
    for kind in ("proposal", "grid"):
        last = _empty_model("last_sample", kind).render(rays, return_samples=True)
        assert float(last.accumulation.max()) < 1e-6
        # the last sample of each ray: the last non-empty interval of its padded samples
        n_real = (last.samples.t_ends > last.samples.t_starts).sum(-1)
        assert (n_real > 0).all()
        want = last.samples.rgb[torch.arange(len(rays)), n_real - 1]
        assert_close(last.rgb, want, atol=1e-5, rtol=0)
        assert_close(last.background, want)
        const = _empty_model("constant", kind).render(rays)
        assert_close(const.rgb, torch.tensor([0.2, 0.3, 0.4]).expand(len(rays), 3), atol=1e-5, rtol=0)
        assert not torch.allclose(last.rgb, const.rgb, atol=0.01)
