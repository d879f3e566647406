"""The baked surface (``nsim.rendering.surface``): marching cubes of a brick lattice finds a known sphere with its
slabs welded, the Gauss-Newton fit moves a mesh onto target depths, the texture learns colours, rays render the
mesh's exact range with one opaque sample, misses go to the NeRF, and a baked scene with a surface round-trips
byte for byte and refuses broken files in one line."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.rendering import surface as surf
from nsim.rendering.bake_bricks import bake, training_rays
from nsim.rendering.bake_config import BakeConfig
from nsim.rendering.baked import BakedScene, render_baked
from nsim.rendering.model import SceneModel
from nsim.rendering.occupancy import OccupancyGrid
from nsim.volume.rays import make_rays
from tests.rendering.test_baked import AABB, FIELD, SAMPLER  # the baked-scene tests' micro field


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


def sphere_bricks(radius: float, centre: np.ndarray, voxel: float, b: int = 4, slope: float = 100.0):
    """A brick lattice (``nsim.rendering.baked``'s layout) of density ``slope * (radius - |x - centre|)`` clipped at
    0, over every cell of a box around the sphere: its ``level`` iso-surface is the sphere of radius ``radius -
    level / slope``."""
    cell = voxel * b
    n = int(math.ceil(2.6 * radius / cell))
    lo = centre - n * cell / 2
    index = np.arange(n**3, dtype=np.int32).reshape(n, n, n)
    ijk = np.argwhere(index >= 0)
    abc = np.stack(np.meshgrid(*(np.arange(b + 1),) * 3, indexing="ij"), -1).reshape(-1, 3)
    x = lo + (ijk[:, None, :] * b + abc[None]) * voxel
    density = np.clip(slope * (radius - np.linalg.norm(x - centre, axis=-1)), 0.0, None).astype(np.float32)
    return index, density, lo


@pytest.mark.parametrize("slab_nodes", [1 << 25, 2000])
def test_marching_cubes_of_bricks_finds_the_sphere_and_welds_slabs(monkeypatch, slab_nodes):
    monkeypatch.setattr(surf, "SLAB_NODES", slab_nodes)  # 2000: one brick column a slab, many seams to weld
    centre = np.array([0.3, -0.2, 1.0])
    index, density, lo = sphere_bricks(0.5, centre, 0.025)
    v, f = surf.mesh_of_bricks(index, density, 4, lo, np.full(3, 0.025), level=10.0)
    r = np.linalg.norm(v - centre, axis=1)
    assert np.abs(r - 0.4).max() < 2e-3  # level 10 of slope 100: radius 0.5 - 0.1
    # one closed surface: Euler characteristic 2 (unwelded seams would leave more vertices and open edges)
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    assert len(v) - len(edges) + len(f) == 2
    assert v.dtype == np.float32 and f.dtype == np.int32
    none_v, none_f = surf.mesh_of_bricks(index, density, 4, lo, np.full(3, 0.025), level=1e4)
    assert none_v.shape == (0, 3) and none_f.shape == (0, 3)


def rays_at_sphere(centre: np.ndarray, n: int, seed: int = 0):
    """Rays from a shell of radius 2 around ``centre`` aimed at random points near it: origins, unit dirs."""
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o = centre + 2.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    aim = centre + rng.uniform(-0.3, 0.3, size=(n, 3))
    d = aim - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def sphere_range(o: np.ndarray, d: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """The exact range at which rays meet a sphere from outside (``inf`` for a miss)."""
    oc = o - centre
    b = (oc * d).sum(1)
    disc = b**2 - ((oc * oc).sum(1) - radius**2)
    return np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)


def test_fit_moves_the_mesh_onto_the_target_depths():
    centre = np.array([0.0, 0.0, 1.0])
    index, density, lo = sphere_bricks(0.5, centre, 0.025)
    v, f = surf.mesh_of_bricks(index, density, 4, lo, np.full(3, 0.025), level=10.0)  # radius 0.40
    o, d = rays_at_sphere(centre, 40000)
    target = sphere_range(o, d, centre, 0.42)
    hit = np.isfinite(target)
    fitted, stats = surf.fit_mesh(v, f, o[hit], d[hit], np.full(hit.sum(), 10.0), target[hit], passes=3,
                                  ridge=1e-3, gate_m=0.05, step_m=0.03)
    before = np.abs(np.linalg.norm(v - centre, axis=1) - 0.42)
    after = np.abs(np.linalg.norm(fitted - centre, axis=1) - 0.42)
    assert np.median(before) > 0.019 and np.median(after) < 1e-3, (np.median(before), np.median(after))
    assert len(stats["passes"]) == 3 and stats["passes"][0]["residual_median_m"] > stats["passes"][-1]["residual_median_m"]
    # the rays now meet the mesh where they meet the target sphere
    t = surf.MeshCaster(fitted, f).cast(o[hit], d[hit], np.full(hit.sum(), 10.0))["t"]
    assert np.median(np.abs(t - target[hit])) < 1e-3


def test_texture_learns_colours_and_round_trips_its_arrays():
    aabb = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(20000, 3, generator=g)
    pts[:, 2] = 0.5  # a texture lives on a surface: points on a plane
    colour = torch.stack([0.5 + 0.4 * torch.sin(6 * pts[:, 0]), pts[:, 1], 1 - pts[:, 0] * pts[:, 1]], 1)
    tex = surf.SurfaceTexture(aabb, levels=6, log2_table_size=12, max_resolution=64, width=16, generator=g)
    psnr = surf.fit_texture(tex, pts[:16000], colour[:16000], steps=300, batch=2048, lr=0.01, generator=g)
    with torch.no_grad():
        held = float(-10 * torch.log10(((tex(pts[16000:]) - colour[16000:]) ** 2).mean()))
    assert psnr > 30 and held > 28, (psnr, held)
    back = surf.SurfaceTexture.from_arrays(aabb, tex.settings, tex.arrays())
    with torch.no_grad():
        assert torch.equal(back(pts[:100]), tex(pts[:100]))
    bad = tex.arrays()
    bad["texture_layer0_weight"] = bad["texture_layer0_weight"][:, :-1]
    with pytest.raises(ValueError, match="texture_layer0_weight"):
        surf.SurfaceTexture.from_arrays(aabb, tex.settings, bad)


def flat_texture(aabb: torch.Tensor, rgb: tuple[float, float, float]) -> surf.SurfaceTexture:
    """A texture of one colour everywhere (its decoder's last bias)."""
    tex = surf.SurfaceTexture(aabb, levels=2, log2_table_size=8, max_resolution=32, width=8,
                              generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        tex.decoder.layers[-1].weight.zero_()
        tex.decoder.layers[-1].bias.copy_(torch.logit(torch.tensor(rgb)))
    return tex.eval().requires_grad_(False)


def quad_surface(z: float = 2.0) -> surf.BakedSurface:
    """The square |x|, |y| <= 1 at height z, two triangles, coloured (0.2, 0.6, 0.9)."""
    v = np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return surf.BakedSurface(v, f, flat_texture(torch.tensor([[-2.0, -2.0, 0.0], [2.0, 2.0, 4.0]]), (0.2, 0.6, 0.9)))


def test_render_surface_exact_range_colour_misses_and_one_opaque_sample():
    s = quad_surface()
    d = torch.nn.functional.normalize(torch.tensor([[0.0, 0.0, 1.0], [0.3, 0.1, 1.0], [3.0, 0.0, 1.0],
                                                    [0.0, 0.0, 1.0]]), dim=-1)
    o = torch.zeros(4, 3)
    rays = make_rays(o, d, 0.05, 30.0)
    rays.near[3] = 2.5  # starts beyond the quad: a miss
    bg = torch.tensor([0.1, 0.1, 0.1])
    out = surf.render_surface(s, rays, bg, return_samples=True)
    expect = 2.0 / d[:2, 2]
    assert torch.allclose(out.depth[:2], expect, atol=1e-5) and torch.equal(out.depth_median, out.depth)
    assert out.accumulation.tolist() == [1.0, 1.0, 0.0, 0.0]
    assert torch.allclose(out.rgb[:2], torch.tensor([0.2, 0.6, 0.9]).expand(2, 3), atol=1e-5)
    assert torch.equal(out.rgb[2:], bg.expand(2, 3)) and torch.equal(out.depth[2:], rays.far[2:])
    smp = out.samples  # the people's merge: one opaque sample at a hit, an empty one at a miss
    alpha = 1 - torch.exp(-smp.sigma * (smp.t_ends - smp.t_starts))
    assert torch.allclose(smp.t_starts[:2, 0], expect, atol=1e-5) and bool((alpha[:2] > 0.999).all())
    assert float(alpha[2:].abs().max()) == 0.0
    lidar = surf.render_surface(s, rays, bg, colour=False)  # depth alone
    assert torch.equal(lidar.depth, out.depth) and torch.equal(lidar.rgb, bg.expand(4, 3))


SURFACE = BakeConfig(voxel_m=0.05, prune_density=0.0, feature_dtype="none", field_samples=0, surface=True,
                     surface_level=None, texture_levels=4, texture_log2_size=10, texture_max_resolution=64,
                     texture_width=8, texture_steps=30, texture_batch=512, surface_fit_passes=2)


@pytest.fixture(scope="module")
def scene():
    """An untrained field with dense blobs and clear air, its occupancy grid and two 40x30 training cameras."""
    m = SceneModel(FIELD, SAMPLER, AABB, n_images=3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        m.field.density_mlp.layers[-1].weight[0].mul_(8.0)
    m = m.eval()
    fn = lambda x: m.field.density(x)[0]  # noqa: E731
    with torch.no_grad():
        probe = torch.rand(4096, 3, generator=torch.Generator().manual_seed(1)) * AABB[1]
        threshold = float(torch.quantile(fn(probe), 0.5))
    grid = OccupancyGrid.bake(fn, AABB, 0.2, threshold, samples_per_cell=2, dilate=0)
    cam = Camera("PINHOLE", 40, 30, 30.0, 30.0, 19.5, 14.5)
    frames = []
    for x in (0.3, 1.7):  # looking along +y from either end of the box (camera z forward, y down)
        c2w = np.eye(4, dtype=np.float32)
        c2w[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], np.float32)
        c2w[:3, 3] = [x, 0.05, 0.6]
        frames.append((cam, c2w))
    images = [np.random.default_rng(k).integers(0, 256, (30, 40, 3), dtype=np.uint8) for k in range(2)]
    return m, grid, frames, images


def test_bake_with_surface_is_deterministic_and_round_trips(scene, tmp_path):
    model, grid, frames, images = scene
    a = bake(model, grid, SURFACE, frames)
    assert a.surface is not None and len(a.surface.faces) > 100 and not a.uses_field
    st = a.surface.stats
    assert st["texture_from"] == "nerf" and st["rays_fitted"] > 0 and len(st["fit"]) == 2
    for name, baked in (("a", a), ("b", bake(model, grid, SURFACE, frames))):
        (tmp_path / name).mkdir()
        baked.save(tmp_path / name)
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert "surface_faces.npy" in names and "texture_table.npy" in names
    assert all((tmp_path / "a" / n).read_bytes() == (tmp_path / "b" / n).read_bytes() for n in names)
    back = BakedScene.load(tmp_path / "a")
    rays = training_rays(model, frames, 3)
    for f in ("rgb", "depth", "accumulation"):
        assert torch.equal(getattr(render_baked(back, rays), f), getattr(render_baked(a, rays), f))
    # the surface is what the rays meet: its hits are where the mesh casts them
    t, hit = a.surface.caster.cast_rays(rays)
    out = render_baked(a, rays)
    assert torch.equal(out.accumulation, hit.float()) and torch.equal(out.depth[hit], t[hit])


def test_texture_from_the_training_images(scene):
    """With the training images, the texture is fitted to their pixels: a texture of uniform grey images is grey."""
    model, grid, frames, _ = scene
    grey = [np.full((30, 40, 3), 77, np.uint8) for _ in frames]
    cfg = dataclasses.replace(SURFACE, texture_steps=150, texture_lr=0.02)
    from nsim.rendering.bake_bricks import bake_passes, bake_surface, nerf_targets

    volume = bake_passes(model, grid, cfg, frames, lambda plan, c, _n: _evaluate(model, plan, c))
    baked = bake_surface(model, volume, cfg, frames, lambda r: nerf_targets(model, grid, r), images=grey)
    assert baked.surface.stats["texture_from"] == "images"
    out = render_baked(baked, training_rays(model, frames, 2))
    hit = out.accumulation > 0
    assert int(hit.sum()) > 50 and float((out.rgb[hit] - 77 / 255).abs().max()) < 0.02
    with pytest.raises(InputError, match="training image 0 is 20x30"):
        bake_surface(model, volume, cfg, frames, lambda r: nerf_targets(model, grid, r),
                     images=[np.zeros((30, 20, 3), np.uint8)] * 2)


def _evaluate(model, plan, c):
    from nsim.rendering.bake_bricks import evaluate_lattice

    parts = [evaluate_lattice(model.field, plan, c, a, min(plan.n_points, a + c.chunk_points))
             for a in range(0, plan.n_points, c.chunk_points)]
    return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])


def test_rays_that_miss_the_surface_go_to_the_nerf():
    s = quad_surface()
    base = BakedScene(aabb=torch.tensor([[-2.0, -2.0, 0.0], [2.0, 2.0, 4.0]]),
                      brick_index=torch.full((1, 1, 1), -1, dtype=torch.int32), density=torch.zeros(0, 8),
                      features=torch.zeros(0, 8, 0), bricks_per_side=1,
                      decoder=None, step_voxels=0.5, block_cells=16, stop_transmittance=1e-4, color_skip_weight=1e-3,
                      background="constant", background_rgb=torch.zeros(3), surface=s,
                      nerf_fallback_accumulation=0.5)
    d = torch.nn.functional.normalize(torch.tensor([[0.0, 0.0, 1.0], [3.0, 0.0, 1.0], [0.0, 3.0, 1.0]]), dim=-1)
    rays = make_rays(torch.zeros(3, 3), d, 0.05, 30.0)
    calls = []

    def nerf(r):
        calls.append(len(r))
        out = surf.render_surface(quad_surface(z=5.0), r, torch.zeros(3))
        out.rgb = torch.full_like(out.rgb, 0.5)
        out.accumulation = torch.ones(len(r))
        return out

    out = render_baked(base, rays, fallback=nerf)
    assert calls == [2] and out.rgb[1:].eq(0.5).all() and float(out.accumulation.min()) == 1.0
    assert torch.allclose(out.depth[0], torch.tensor(2.0))
    calls.clear()
    render_baked(base, rays, fallback=nerf, may_fall_back=torch.tensor([True, True, False]))
    assert calls == [1]
    render_baked(base, rays, colour=False, fallback=nerf)  # a LiDAR: never
    assert calls == [1]


def test_broken_surface_files_are_one_line(scene, tmp_path):
    model, grid, frames, _ = scene
    baked = bake(model, grid, SURFACE, frames)
    baked.save(tmp_path)
    faces = np.load(tmp_path / "surface_faces.npy")
    np.save(tmp_path / "surface_faces.npy", faces + len(baked.surface.vertices))
    with pytest.raises(InputError, match="surface_faces.npy: vertex indices outside") as e:
        BakedScene.load(tmp_path)
    assert "\n" not in str(e.value)
    np.save(tmp_path / "surface_faces.npy", faces)
    (tmp_path / "texture_table.npy").unlink()
    with pytest.raises(InputError, match="texture_table.npy"):
        BakedScene.load(tmp_path)


def test_people_composite_over_the_surface_in_depth_order():
    """The people's merge (``HumanSet.composite``) over a surface: a person before the wall shows, a wall before
    the person hides it; the same result as ``compositing.composite_sets`` of the surface's one opaque sample and
    the person's samples."""
    from nsim.rendering.people import CompositeConfig, HumanSet, PersonView
    from nsim.rendering.renderer import MarchConfig
    from nsim.volume.compositing import composite_sets
    from nsim.volume.samples import RaySamples
    from tests.rendering.people_fixture import opaque_person

    person, T = opaque_person((0.0, 0.0))
    n = 40
    target = torch.tensor(T[0, :3, 3], dtype=torch.float32) + torch.stack(
        [torch.zeros(n), torch.zeros(n), torch.linspace(-0.3, 0.3, n)], -1)
    origins = target - torch.tensor([0.0, 3.0, 0.0])  # 3 m in front of the person, looking along +y
    rays = make_rays(origins, torch.nn.functional.normalize(target - origins, dim=-1), 0.05, 30.0)
    y = float(target[0, 1])
    aabb = torch.tensor([[-5.0, -5.0, -5.0], [5.0, 5.0, 5.0]])
    people = [PersonView(k=0, joint_transforms=T, model=person, ray_mask=torch.ones(n, dtype=torch.bool))]
    cfg = CompositeConfig(method="baked", march=MarchConfig(), chunk_rays=1024, culling=True)
    with torch.no_grad():
        hs = person.render_samples(rays.origins, rays.dirs, torch.as_tensor(T, dtype=torch.float32), rays.near,
                                   rays.far, box_test=True)
    live = (hs.t_ends > hs.t_starts).any(-1)
    assert int(live.sum()) > n // 2
    for wall_y, person_shows in ((y + 1.0, True), (y - 1.0, False)):  # a wall behind, then before the person
        v = np.array([[-9, wall_y, -9], [9, wall_y, -9], [9, wall_y, 9], [-9, wall_y, 9]], np.float32)
        s = surf.BakedSurface(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), flat_texture(aabb, (0.2, 0.6, 0.9)))
        scene = surf.render_surface(s, rays, torch.zeros(3), return_samples=True)
        out, instance = HumanSet([person], {}, "cpu").composite(None, None, rays, people, cfg,
                                                                scene_out=dataclasses.replace(scene, rgb=scene.rgb.clone()))
        sets = [RaySamples(*(getattr(x, f)[live] for f in ("t_starts", "t_ends", "sigma", "rgb")))
                for x in (scene.samples, hs)]
        ref, _ = composite_sets(*sets, background_rgb=scene.background[live])
        torch.testing.assert_close(out.rgb[live], ref.rgb)
        wall = torch.tensor([0.2, 0.6, 0.9])
        if person_shows:
            assert int((instance > 0).sum()) > 0 and float((out.rgb[live] - wall).abs().sum(-1).max()) > 0.1
        else:
            assert int((instance > 0).sum()) == 0
            torch.testing.assert_close(out.rgb, wall.expand(n, 3), atol=1e-4, rtol=0)


@pytest.mark.gpu
def test_surface_bakes_and_renders_on_cuda_as_on_the_cpu(scene):
    """The surface's cast stays on the CPU (Embree), its texture on CUDA: a CPU bake moved to CUDA renders what it
    renders on the CPU (the hits exactly), and a bake on CUDA gives nearly the same mesh and rays' ranges."""
    import copy

    model, grid, frames, _ = scene
    cpu = bake(model, grid, SURFACE, frames)
    rays = training_rays(model, frames, 3)
    a = render_baked(cpu, rays)
    b = render_baked(cpu.to("cuda"), rays.to("cuda"))
    assert b.rgb.device.type == "cuda"
    assert torch.equal(b.accumulation.cpu(), a.accumulation) and torch.equal(b.depth.cpu(), a.depth)
    torch.testing.assert_close(b.rgb.cpu(), a.rgb, rtol=1e-4, atol=1e-4)
    gpu = bake(copy.deepcopy(model).to("cuda"), grid.to("cuda"), SURFACE, frames)
    assert abs(len(gpu.surface.faces) - len(cpu.surface.faces)) <= 0.01 * len(cpu.surface.faces)
    c = render_baked(gpu, rays.to("cuda"))
    same = (c.accumulation.cpu() == a.accumulation) & (a.accumulation > 0)
    assert float(same.float().sum() / (a.accumulation > 0).sum()) > 0.98
    assert float((c.depth.cpu()[same] - a.depth[same]).abs().median()) < 1e-3
