"""The baked scene (``nsim.rendering.baked``, baked by ``nsim.rendering.bake_bricks``): the bake keeps the
field's values, the fast marcher agrees with a plain dense twin, files round-trip byte for byte, bad files are
one line, people composite over it."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from nsim.errors import InputError
from nsim.fields.scene_field import SceneFieldConfig
from nsim.rendering.bake_bricks import bake
from nsim.rendering.bake_config import BakeConfig
from nsim.rendering.baked import (
    BakedScene,
    ColorDecoder,
    density_at,
    features_at,
    locate,
    render_baked,
    render_chunk,
    steps,
)
from nsim.rendering.model import SamplerConfig, SceneModel
from nsim.rendering.occupancy import OccupancyGrid
from nsim.volume import quadrature
from nsim.volume.rays import Rays, make_rays

AABB = torch.tensor([[0.0, 0.0, 0.0], [2.0, 1.6, 1.2]])
FIELD = SceneFieldConfig(hash_levels=4, hash_log2_table_size=10, hash_base_resolution=4, hash_max_resolution=64,
                         hidden_dim=16, geo_feat_dim=7, color_hidden_dim=16, color_hidden_layers=1, sh_degree=2,
                         appearance_dim=4, backend="torch", density_bias=1.0, contract=False)
SAMPLER = SamplerConfig(proposal_samples=(16, 8), proposal_hash_max_resolutions=(32, 64), final_samples=8,
                        proposal_hash_log2_table_size=10, proposal_hash_levels=3, proposal_hidden_dim=8)


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def model() -> SceneModel:
    """An untrained field with structure: density exp(mlp + 1) that varies over the box by orders of magnitude."""
    m = SceneModel(FIELD, SAMPLER, AABB, n_images=3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        m.field.density_mlp.layers[-1].weight[0].mul_(8.0)  # sharpen the density: dense blobs and clear air
    return m.eval()


@pytest.fixture(scope="module")
def grid(model) -> OccupancyGrid:
    """An occupancy grid of 0.2 m cells at the field's median cell density (about half the cells occupied)."""
    fn = lambda x: model.field.density(x)[0]  # noqa: E731
    probe = torch.stack(torch.meshgrid(*(torch.linspace(0.1, float(s) - 0.1, 8) for s in AABB[1]), indexing="ij"),
                        -1).reshape(-1, 3)
    with torch.no_grad():
        threshold = float(torch.quantile(fn(probe), 0.5))
    g = OccupancyGrid.bake(fn, AABB, 0.2, threshold, samples_per_cell=2, dilate=0)
    assert 0.2 < g.occupied_fraction < 0.8, g.occupied_fraction
    return g


@pytest.fixture(scope="module")
def baked(model, grid) -> BakedScene:
    return bake(model, grid, BakeConfig(voxel_m=0.05, prune_density=0.0))


def some_rays(n: int = 300, seed: int = 3) -> Rays:
    """Rays from points inside the box in all directions, clipped to the box (as the renderer's)."""
    g = torch.Generator().manual_seed(seed)
    o = AABB[0] + torch.rand(n, 3, generator=g) * (AABB[1] - AABB[0])
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    return make_rays(o, d, 0.05, 30.0, AABB)


def dense_reference(baked: BakedScene, rays: Rays, field=None):
    """The plain twin: every fine step from near to far, trilinear density and colour at every sample in a
    brick, no coarse skipping, no early termination, no colour skipping; volume rendering as in volume.py.
    With ``field``, every sample's colour from the field's own features at the sample."""
    _, step_f, _ = steps(baked)
    n_steps = int(math.ceil(float((rays.far - rays.near).max()) / step_f))
    k = torch.arange(n_steps, dtype=torch.float32)
    t0 = rays.near[:, None] + k * step_f
    t1 = torch.minimum(t0 + step_f, rays.far[:, None])
    t0 = torch.minimum(t0, rays.far[:, None])
    mid = 0.5 * (t0 + t1)
    x = rays.origins[:, None] + rays.dirs[:, None] * mid[..., None]
    brick, local = locate(baked, x)
    inside = (brick >= 0) & (t1 > t0)
    sigma = torch.zeros_like(t0)
    rgb = torch.zeros(*t0.shape, 3)
    sigma[inside] = density_at(baked, brick[inside], local[inside])
    r = torch.nonzero(inside, as_tuple=True)[0]
    if field is None:
        geo = features_at(baked, brick[inside], local[inside])
    else:
        with torch.no_grad():
            geo = field.density(x[inside])[1]
    rgb[inside] = baked.decoder(geo, rays.dirs[r])
    w, _ = quadrature.render_weights(sigma, t1 - t0)
    acc = w.sum(-1)
    out = quadrature.accumulate(w, rgb) + (1 - acc)[:, None] * baked.background_rgb
    depth = torch.where(acc > quadrature.EPS, quadrature.expected_depth(w, mid, acc), rays.far)
    return out, depth, acc


def test_bake_keeps_the_fields_values_at_the_lattice_points(model, grid, baked):
    """supersample 1: each lattice point holds the field's density and features there; the decoder is the
    field's colour head with the mean appearance code."""
    assert baked.bricks_per_side == 4 and baked.n_bricks == int(grid.occupied.sum())
    g = torch.Generator().manual_seed(5)
    n = torch.randint(0, baked.n_bricks, (200,), generator=g)
    abc = torch.randint(0, 5, (200, 3), generator=g)
    cells = torch.nonzero(baked.brick_index >= 0)  # C order: brick n is the n-th occupied cell
    x = AABB[0] + (cells[n] * 4 + abc).float() * baked.voxel_m
    with torch.no_grad():
        sigma, geo = model.field.density(x)
    assert torch.equal(baked.brick_index[tuple(cells[n].T)].long(), n)
    got = density_at(baked, n, abc.float())
    torch.testing.assert_close(got, sigma, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(features_at(baked, n, abc.float()), geo, rtol=2e-3, atol=2e-3)  # float16 storage
    dirs = torch.nn.functional.normalize(torch.randn(200, 3, generator=g), dim=-1)
    codes = model.field.appearance_codes(None, 200, "mean", model.train_mask)
    with torch.no_grad():
        torch.testing.assert_close(baked.decoder(geo, dirs), model.field.color(geo, dirs, codes), rtol=1e-5, atol=1e-6)


def test_matches_dense_reference_exactly_without_shortcuts(baked):
    """Coarse skipping is exact: with early termination and colour skipping off, the fast marcher renders what
    the dense twin renders."""
    exact = dataclasses.replace(baked, stop_transmittance=0.0, color_skip_weight=0.0)
    rays = some_rays()
    out = render_chunk(exact, rays)
    rgb, depth, acc = dense_reference(exact, rays)
    assert 0.05 < float(acc.mean()) < 0.98 and float(acc.max()) > 0.9  # the rays see something, not everything
    torch.testing.assert_close(out.accumulation, acc, rtol=0, atol=2e-5)
    torch.testing.assert_close(out.rgb, rgb, rtol=0, atol=2e-5)
    torch.testing.assert_close(out.depth, depth, rtol=0, atol=1e-4)


def test_field_colour_for_the_heaviest_samples(baked, model):
    """field_color_samples: the heaviest samples of each ray take their colour from the field's own features
    (all of them here: the dense twin with the field's features); without the field attached, the baked ones."""
    weights, biases = baked.decoder.arrays()
    weights[0] = weights[0] * 30.0  # a colour head that shows its features (the untrained one is nearly flat)
    sharp = ColorDecoder([torch.as_tensor(w) for w in weights], [torch.as_tensor(b) for b in biases], 2)
    exact = dataclasses.replace(baked, stop_transmittance=0.0, color_skip_weight=0.0, field_color_samples=10**6,
                                field_samples=0, decoder=sharp)
    rays = some_rays(120)
    out = render_chunk(exact.with_field(model.field), rays)
    rgb, _, _ = dense_reference(exact, rays, model.field)
    torch.testing.assert_close(out.rgb, rgb, rtol=0, atol=5e-6)
    plain, _, _ = dense_reference(exact, rays)
    torch.testing.assert_close(render_chunk(exact, rays).rgb, plain, rtol=0, atol=5e-6)
    # between lattice points the baked features only approximate the field's (this smooth field: closely)
    assert float((rgb - plain).abs().max()) > 2e-5


def test_shortcuts_stay_within_their_bounds(baked):
    """Early termination at T < 1e-4 and colour skipping of at most 1e-3 of a ray's weight change a pixel by
    less than 1.2e-3; they do skip work (fewer samples kept than the exact march keeps)."""
    rays = some_rays()
    opaque = dataclasses.replace(baked, density=baked.density * 30.0)  # most rays end inside the box
    fast = render_chunk(opaque, rays, return_samples=True)
    exact = render_chunk(dataclasses.replace(opaque, stop_transmittance=0.0, color_skip_weight=0.0), rays,
                         return_samples=True)
    assert float((exact.accumulation > 0.9999).float().mean()) > 0.5
    assert float((fast.rgb - exact.rgb).abs().max()) < 1.2e-3
    assert float((fast.accumulation - exact.accumulation).abs().max()) < 1.2e-4
    kept = lambda o: int((o.samples.t_ends > o.samples.t_starts).sum())  # noqa: E731
    assert kept(fast) < kept(exact)


def test_chunks_do_not_change_the_result(baked):
    """The chunk size changes float rounding only (padding lengths, matrix blocking); the same chunks give
    the same bits with or without samples."""
    rays = some_rays(250)
    whole = render_baked(baked, rays, chunk=1000)
    parts = render_baked(baked, rays, chunk=37)
    for f in ("rgb", "depth", "depth_median", "accumulation", "background"):
        torch.testing.assert_close(getattr(whole, f), getattr(parts, f), rtol=0, atol=1e-5)
    with_samples = render_baked(baked, rays, chunk=37, return_samples=True)
    assert torch.equal(with_samples.rgb, parts.rgb) and with_samples.samples.sigma.shape[0] == 250
    assert len(render_baked(baked, rays[:0]).rgb) == 0


def test_background_last_sample(baked):
    """last_sample: the remaining light goes over the colour of the ray's last kept sample."""
    rays = some_rays(200)
    last = dataclasses.replace(baked, background="last_sample")
    out = render_chunk(last, rays, return_samples=True)
    s = out.samples
    n_kept = (s.t_ends > s.t_starts).sum(-1)
    has = n_kept > 0
    assert bool(has.any())
    idx = torch.nonzero(has, as_tuple=True)[0]
    torch.testing.assert_close(out.background[idx], s.rgb[idx, n_kept[idx] - 1])
    plain = render_chunk(baked, rays)
    assert torch.equal(plain.background, baked.background_rgb.expand(200, 3))


def test_save_load_round_trip_and_same_bytes(baked, model, grid, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    baked.save(a)
    bake(model, grid, BakeConfig(voxel_m=0.05, prune_density=0.0)).save(b)  # baked again: the same files
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir()) and "baked.json" in names
    assert all((a / n).read_bytes() == (b / n).read_bytes() for n in names)
    back = BakedScene.load(a)
    rays = some_rays(100)
    for f in ("rgb", "depth", "accumulation"):
        assert torch.equal(getattr(render_baked(back, rays), f), getattr(render_baked(baked, rays), f))
    c = tmp_path / "c"  # the NeRF fallback's settings travel with the file
    c.mkdir()
    dataclasses.replace(baked, nerf_fallback_share=0.25, nerf_fallback_voxels=3.0, nerf_fallback_accumulation=0.4).save(c)
    back = BakedScene.load(c)
    assert (back.nerf_fallback_share, back.nerf_fallback_voxels, back.nerf_fallback_accumulation) == (0.25, 3.0, 0.4)
    assert BakedScene.load(a).nerf_fallback_share is None and not BakedScene.load(a).falls_back


def test_pruning_drops_bricks_without_density(model, grid):
    full = bake(model, grid, BakeConfig(voxel_m=0.1, prune_density=0.0))
    high = float(full.density.amax(-1).median())
    pruned = bake(model, grid, BakeConfig(voxel_m=0.1, prune_density=high))
    assert 0 < pruned.n_bricks < full.n_bricks
    assert float(pruned.density.amax(-1).min()) >= high
    assert pruned.meta["pruned_bricks"] == full.n_bricks - pruned.n_bricks


def test_bad_files_are_one_line(baked, tmp_path):
    with pytest.raises(InputError, match="not a baked scene"):
        BakedScene.load(tmp_path)
    d = tmp_path / "b"
    d.mkdir()
    baked.save(d)
    np.save(d / "density.npy", np.zeros((3, 2), dtype=np.float32))
    with pytest.raises(InputError, match="density.npy") as e:
        BakedScene.load(d)
    assert "\n" not in str(e.value)
    baked.save(d)
    np.save(d / "density.npy", -baked.density.numpy())
    with pytest.raises(InputError, match="negative"):
        BakedScene.load(d)


def test_decoder_folds_the_appearance_code(model):
    g = torch.Generator().manual_seed(9)
    code = torch.randn(4, generator=g)
    dec = ColorDecoder.from_field(model.field, code)
    geo = torch.randn(50, 7, generator=g)
    dirs = torch.nn.functional.normalize(torch.randn(50, 3, generator=g), dim=-1)
    with torch.no_grad():
        torch.testing.assert_close(dec(geo, dirs), model.field.color(geo, dirs, code.expand(50, 4)))


def test_people_composite_over_the_baked_scene(baked):
    """``HumanSet.composite`` with the baked scene's samples: the same depth-ordered merge as
    ``compositing.composite_sets`` of the baked samples and the person's."""
    from nsim.rendering.people import CompositeConfig, HumanSet, PersonView
    from nsim.rendering.renderer import MarchConfig
    from nsim.volume.compositing import composite_sets
    from nsim.volume.samples import RaySamples
    from tests.rendering.people_fixture import opaque_person

    person, T = opaque_person((1.0, 0.8))
    n = 40
    target = torch.tensor(T[0, :3, 3], dtype=torch.float32) + torch.stack(
        [torch.zeros(n), torch.zeros(n), torch.linspace(-0.3, 0.3, n)], -1)
    origins = torch.tensor([[0.05, 0.8, 0.6]]).expand(n, 3).contiguous()
    rays = make_rays(origins, torch.nn.functional.normalize(target - origins, dim=-1), 0.05, 30.0, AABB)
    light = dataclasses.replace(baked, density=baked.density * 0.05)  # a haze before and behind the person
    scene = render_baked(light, rays, return_samples=True)
    people = [PersonView(k=0, joint_transforms=T, model=person, ray_mask=torch.ones(n, dtype=torch.bool))]
    cfg = CompositeConfig(method="baked", march=MarchConfig(), chunk_rays=1024, culling=True)
    out, instance = HumanSet([person], {}, "cpu").composite(None, None, rays, people, cfg,
                                                            scene_out=dataclasses.replace(scene, rgb=scene.rgb.clone()))
    with torch.no_grad():
        hs = person.render_samples(rays.origins, rays.dirs, torch.as_tensor(T, dtype=torch.float32), rays.near,
                                   rays.far, box_test=True)
    live = (hs.t_ends > hs.t_starts).any(-1)
    assert bool(live.any())
    sets = [RaySamples(*(getattr(s, f)[live] for f in ("t_starts", "t_ends", "sigma", "rgb"))) for s in (scene.samples, hs)]
    ref, _ = composite_sets(*sets, background_rgb=scene.background[live])
    torch.testing.assert_close(out.rgb[live], ref.rgb)
    assert torch.equal(out.rgb[~live], scene.rgb[~live])
    assert int((instance > 0).sum()) > 0


def test_visibility_culling_drops_what_no_camera_sees(baked):
    """A wall of 0.5 m cells (tau 25 across) seen head-on by a bundle of rays: the wall where the rays hit it
    and a thin brick in front of it stay; a brick behind the wall, one outside the bundle and the wall's
    unseen part go, and the kept bricks render the bundle as before."""
    from nsim.rendering.bake_bricks import brick_visibility, cull

    shape = (6, 4, 4)
    b = 2
    p = (b + 1) ** 3
    cells = {(2, j, k): 50.0 for j in range(4) for k in range(4)}  # the wall
    cells[(1, 1, 1)] = 0.5  # a thin haze in front of it, on the rays
    cells[(4, 1, 1)] = 5.0  # behind the wall
    cells[(1, 0, 0)] = 5.0  # beside the bundle
    order = sorted(cells)
    index = torch.full(shape, -1, dtype=torch.int32)
    for n, c in enumerate(order):
        index[c] = n
    g = baked.features.shape[-1]
    feats = torch.rand(len(order), p, g, generator=torch.Generator().manual_seed(1)).to(baked.features.dtype)
    scene = dataclasses.replace(baked, aabb=torch.tensor([[0.0, 0.0, 0.0], [3.0, 2.0, 2.0]]), brick_index=index,
                                density=torch.tensor([[cells[c]] * p for c in order]), features=feats, bricks_per_side=b,
                                field_color_samples=0, field=None)
    yz = torch.stack(torch.meshgrid(torch.linspace(0.55, 1.45, 7), torch.linspace(0.55, 1.45, 7), indexing="ij"),
                     -1).reshape(-1, 2)
    o = torch.cat([torch.full((len(yz), 1), 0.01), yz], -1)
    rays = make_rays(o, torch.tensor([[1.0, 0.0, 0.0]]).expand(len(yz), 3), 0.0, 10.0, scene.aabb)
    seen = brick_visibility(scene, rays, chunk=13)
    pos = {c: n for n, c in enumerate(order)}
    assert float(seen[pos[(1, 1, 1)]]) == pytest.approx(1 - math.exp(-0.25), rel=1e-3)
    assert float(seen[pos[(2, 1, 1)]]) > 0.5
    assert float(seen[pos[(4, 1, 1)]]) < 1e-9 and float(seen[pos[(1, 0, 0)]]) == 0.0
    culled = cull(scene, seen, 0.005)
    kept = {c for c in order if int(culled.brick_index[c]) >= 0}
    assert kept == {(1, 1, 1), (2, 1, 1), (2, 1, 2), (2, 2, 1), (2, 2, 2)}
    assert culled.n_bricks == 5 and culled.meta["culled_bricks"] == len(order) - 5
    for c in kept:  # the kept bricks keep their own lattice values
        assert torch.equal(culled.features[int(culled.brick_index[c])], scene.features[int(scene.brick_index[c])])
    before, after = render_baked(scene, rays), render_baked(culled, rays)
    torch.testing.assert_close(after.rgb, before.rgb, atol=1e-6, rtol=0)
    torch.testing.assert_close(after.depth, before.depth, atol=1e-5, rtol=0)



def test_field_samples_render_the_field_in_a_window_around_the_baked_surface(baked, model):
    """field_samples = m: the baked march decides where a ray's surface is (its median depth) and how much light
    it stops (accumulation); the field, volume-rendered by itself over m bins in +- field_window_voxels around
    that depth, its colour and (where the window holds over half the weight) its depth. Against a plain twin (a
    loop over rays over the dense march's samples); a LiDAR's rays (colour=False) the same depth, no colour."""
    weights, biases = baked.decoder.arrays()
    weights[0] = weights[0] * 30.0  # a colour head that shows its features (the untrained one is nearly flat)
    sharp = ColorDecoder([torch.as_tensor(w) for w in weights], [torch.as_tensor(b) for b in biases], 2)
    exact = dataclasses.replace(baked, stop_transmittance=0.0, color_skip_weight=0.0, field_color_samples=0,
                                field_samples=0, decoder=sharp)
    m, half_voxels = 6, 1.5
    windowed = dataclasses.replace(exact, field_samples=m, field_window_voxels=half_voxels).with_field(model.field)
    rays = some_rays(150, seed=11)
    plain = render_chunk(exact, rays)
    out = render_chunk(windowed, rays)
    torch.testing.assert_close(out.accumulation, plain.accumulation, rtol=0, atol=0)
    # the plain twin
    _, step_f, _ = steps(exact)
    half = half_voxels * float(exact.voxel_m.max())
    rgb, depth = torch.zeros(len(rays), 3), plain.depth.clone()
    for r in range(len(rays)):
        n_steps = int(math.ceil(float(rays.far[r] - rays.near[r]) / step_f))
        t0 = rays.near[r] + torch.arange(n_steps, dtype=torch.float32) * step_f
        t1 = torch.minimum(t0 + step_f, rays.far[r])
        x = rays.origins[r] + rays.dirs[r] * (0.5 * (t0 + t1))[:, None]
        brick, local = locate(exact, x)
        sigma = torch.where(brick >= 0, density_at(exact, brick.clamp(min=0), local), 0.0)
        w = quadrature.render_weights(sigma[None], (t1 - t0)[None])[0][0]
        acc = float(w.sum())
        if acc <= quadrature.EPS:
            continue
        centre = float(quadrature.median_depth(w[None], (0.5 * (t0 + t1))[None])[0])
        lo, hi = max(centre - half, float(rays.near[r])), min(centre + half, float(rays.far[r]))
        e = lo + (hi - lo) * torch.arange(m + 1, dtype=torch.float32) / m
        mid = 0.5 * (e[1:] + e[:-1])
        with torch.no_grad():
            sig, geo = model.field.density(rays.origins[r] + rays.dirs[r] * mid[:, None])
        ww = quadrature.render_weights(sig[None].float(), (e[1:] - e[:-1])[None])[0][0]
        c = sharp(geo.float(), rays.dirs[r].expand(m, 3))
        wsum = float(ww.sum())
        colour = (ww[:, None] * c).sum(0) / wsum if wsum > quadrature.EPS else c[m // 2]
        rgb[r] = acc * colour
        if wsum > 0.5:
            depth[r] = float((ww * mid).sum()) / wsum
    torch.testing.assert_close(out.rgb, rgb, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.depth, depth, rtol=0, atol=1e-4)
    assert float((out.rgb - plain.rgb).abs().max()) > 1e-5  # the field's colours, not the baked features'
    lidar = render_chunk(windowed, rays, colour=False)  # a LiDAR's rays: the same geometry, no colour
    assert torch.equal(lidar.depth, out.depth) and torch.equal(lidar.accumulation, out.accumulation)
    assert torch.equal(lidar.rgb, torch.zeros_like(lidar.rgb))


def test_no_features_with_field_samples(model, grid, baked, tmp_path):
    """feature_dtype none: no colour features stored (the field colours every camera ray), the same render as a
    bake with them; without field_samples it is a one-line config error, and such files do not load."""
    from nsim.errors import ConfigError

    with pytest.raises(ConfigError, match="field_samples"):
        bake(model, grid, BakeConfig(feature_dtype="none", field_samples=0))
    lean = bake(model, grid, BakeConfig(voxel_m=0.05, prune_density=0.0, feature_dtype="none", field_samples=2))
    assert lean.features.shape == (*baked.density.shape, 0) and torch.equal(lean.density, baked.density)
    lean.save(tmp_path)
    back = BakedScene.load(tmp_path).with_field(model.field)
    rays = some_rays(100)
    full = dataclasses.replace(baked, field_samples=2).with_field(model.field)
    assert torch.equal(render_baked(back, rays).rgb, render_baked(full, rays).rgb)
    # a chunk whose rays all cross no brick (a fisheye looking where nothing was baked): the background, no error
    empty = render_baked(back, make_rays(torch.full((5, 3), -50.0), torch.tensor([[-1.0, 0.0, 0.0]]).expand(5, 3),
                                          0.05, 30.0, None))
    assert torch.equal(empty.accumulation, torch.zeros(5))
    torch.testing.assert_close(empty.rgb, back.background_rgb.expand(5, 3))
    doc = json.loads((tmp_path / "baked.json").read_text())
    (tmp_path / "baked.json").write_text(json.dumps({**doc, "field_samples": 0}))
    with pytest.raises(InputError, match="no features"):
        BakedScene.load(tmp_path)


@pytest.mark.parametrize("rule", ["share", "accumulation"])
def test_fallback_rays_take_the_nerfs_outputs(baked, model, rule):
    """nerf_fallback_share: camera rays whose baked weight is split between surfaces (a share of it beyond
    nerf_fallback_voxels of the median depth), nerf_fallback_accumulation: those whose baked accumulation stays
    below it, take the NeRF's outputs; the other rays, a LiDAR's rays and rays rendered with their samples (the
    people's merge) are the baked scene's as before."""
    from nsim.rendering.baked import fallback_rays, march
    from nsim.rendering.renderer import PER_RAY_FIELDS, render_rays

    plain = dataclasses.replace(baked, field_samples=4).with_field(model.field)
    hybrid = dataclasses.replace(plain, **({"nerf_fallback_share": 0.2, "nerf_fallback_voxels": 1.0} if rule == "share"
                                           else {"nerf_fallback_accumulation": 0.5}))
    assert hybrid.falls_back and not plain.falls_back
    rays = some_rays(300, seed=8)
    calls = []

    def nerf(r):
        calls.append(len(r))
        return render_rays(model, r, "proposal")

    before = render_baked(plain, rays, fallback=nerf)
    assert not calls  # no share set: no fallback
    after = render_baked(hybrid, rays, fallback=nerf)
    ray, t0, t1, sigma, _, _ = march(hybrid, rays)
    counts = torch.bincount(ray, minlength=len(rays))
    slot = torch.arange(len(ray)) - (torch.cumsum(counts, 0) - counts)[ray]
    s_pad = int(counts.max())
    w = quadrature.render_weights(torch.zeros(len(rays), s_pad).index_put((ray, slot), sigma),
                              rays.far[:, None].expand(-1, s_pad).clone().index_put((ray, slot), t1 - t0))[0]
    mid = rays.far[:, None].expand(-1, s_pad).clone().index_put((ray, slot), 0.5 * (t0 + t1))
    split = fallback_rays(hybrid, w, mid)
    assert 0 < int(split.sum()) < len(rays) and calls == [int(split.sum())]
    # the plain twin of the rule: the share of each ray's weight beyond 1 voxel of its median depth, or its sum
    for r in range(len(rays)):
        wr, mr = w[r], mid[r]
        if rule == "accumulation":
            assert bool(split[r]) == (float(wr.sum()) < 0.5)
            continue
        if float(wr.sum()) <= quadrature.EPS:
            assert not split[r]
            continue
        med = float(quadrature.median_depth(wr[None], mr[None])[0])
        beyond = float(wr[(mr - med).abs() > float(hybrid.voxel_m.max())].sum())
        assert bool(split[r]) == (beyond >= 0.2 * float(wr.sum()))
    reference = render_rays(model, rays[torch.nonzero(split, as_tuple=True)[0]], "proposal")
    for f in PER_RAY_FIELDS:
        torch.testing.assert_close(getattr(after, f)[split], getattr(reference, f), rtol=0, atol=1e-6)
        assert torch.equal(getattr(after, f)[~split], getattr(before, f)[~split])
    lidar = render_baked(hybrid, rays, colour=False, fallback=nerf)
    assert torch.equal(lidar.depth, render_baked(plain, rays, colour=False).depth) and len(calls) == 1
    with_samples = render_baked(hybrid, rays, return_samples=True, fallback=nerf)
    assert torch.equal(with_samples.rgb, before.rgb) and len(calls) == 1
    # rays that may not fall back (a fisheye's pixels outside its image) keep the baked outputs
    allowed = torch.arange(len(rays)) % 2 == 0
    some = render_baked(hybrid, rays, fallback=nerf, may_fall_back=allowed)
    assert calls[-1] == int((split & allowed).sum())
    assert torch.equal(some.rgb[split & ~allowed], before.rgb[split & ~allowed])
    assert torch.equal(some.rgb[split & allowed], after.rgb[split & allowed])


@pytest.mark.gpu
def test_cpu_and_cuda_render_the_same(baked, model):
    """The baked march, the field window, the NeRF fallback and the LiDAR's colourless rays give the same result on
    CUDA as on the CPU (the scene, its field and the NeRF moved together; float32 on both)."""
    import copy

    from nsim.rendering.renderer import render_rays

    windowed = dataclasses.replace(baked, field_samples=6, field_window_voxels=1.5, nerf_fallback_share=0.2,
                                   nerf_fallback_voxels=1.0, nerf_fallback_accumulation=0.5).with_field(model.field)
    rays = some_rays(400, seed=21)
    model_cuda = copy.deepcopy(model).to("cuda")
    on_cuda = windowed.to("cuda").with_field(model_cuda.field)
    rays_cuda = rays.to("cuda")
    for colour in (True, False):
        cpu = render_baked(windowed, rays, colour=colour, fallback=lambda r: render_rays(model, r, "proposal"))
        gpu = render_baked(on_cuda, rays_cuda, colour=colour, fallback=lambda r: render_rays(model_cuda, r, "proposal"))
        assert gpu.depth.device.type == "cuda"
        torch.testing.assert_close(gpu.accumulation.cpu(), cpu.accumulation, rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(gpu.rgb.cpu(), cpu.rgb, rtol=1e-3, atol=1e-3)
        torch.testing.assert_close(gpu.depth.cpu(), cpu.depth, rtol=1e-3, atol=1e-3)
