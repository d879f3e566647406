"""One compositor: the human trainer's merge (``render_merged``) and the renderer's (``HumanSet.composite``)
are ``nsim.volume.compositing``, and give the same pixels on the same sample sets."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nsim.human.gait import walk_cycle
from nsim.human.motion import LocomotionLoop
from nsim.human.nerf import HumanModel, HumanModelConfig, render_merged
from nsim.human.skeleton import forward_kinematics, nsim_skeleton
from nsim.rendering.people import HumanSet, PersonView
from nsim.volume import quadrature
from nsim.volume.compositing import composite, composite_sets, merge_samples, set_weights
from nsim.volume.rays import Rays
from nsim.volume.samples import RaySamples, RenderOutput

SMALL = HumanModelConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16,
                         color_hidden_dim=16, samples_per_ray=16)


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def person():
    """A small human model, semi-transparent (every sample matters), in a walking pose."""
    skeleton = nsim_skeleton(1.75)
    m = HumanModel(SMALL, skeleton, torch.Generator().manual_seed(0))
    with torch.no_grad():
        m.field.density_mlp.layers[-1].weight.mul_(0.1)
        m.field.density_mlp.layers[-1].bias.fill_(2.0)
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, 1.75))
    root, quats = loop.pose_at(np.array([0.3]), np.array([[0.0, 0.0]]), np.array([0.4]))
    return m.eval(), forward_kinematics(skeleton, quats[0], root[0])


def rays_through(T: np.ndarray, n: int = 24) -> Rays:
    """Rays from 3 m in front of the pelvis through the torso and legs (all meet the body's box)."""
    pelvis = torch.tensor(T[0, :3, 3], dtype=torch.float32)
    g = torch.Generator().manual_seed(1)
    targets = pelvis + torch.stack([torch.zeros(n), 0.1 * torch.randn(n, generator=g),
                                    torch.linspace(-0.6, 0.4, n)], -1)
    origins = (pelvis + torch.tensor([3.0, 0.0, 0.0])).expand(n, 3).contiguous()
    d = targets - origins
    return Rays(origins, d / d.norm(dim=-1, keepdim=True), torch.full((n,), 0.05), torch.full((n,), 8.0))


def scene_samples(n: int, s: int = 40) -> RaySamples:
    """A hazy scene from 0.5 m to 8 m (overlapping the person in depth) with a dense wall at 5 m."""
    g = torch.Generator().manual_seed(2)
    edges = torch.linspace(0.5, 8.0, s + 1).expand(n, s + 1)
    t0, t1 = edges[:, :-1].contiguous(), edges[:, 1:].contiguous()
    mid = 0.5 * (t0 + t1)
    sigma = 0.2 * torch.rand(n, s, generator=g) + torch.where((mid > 4.9) & (mid < 5.3), 30.0, 0.0)
    return RaySamples(t0, t1, sigma, torch.rand(n, s, 3, generator=g))


def render_with_people(monkeypatch, m, T, rays: Rays, scene: RaySamples, bg: torch.Tensor):
    """The renderer's merge (``HumanSet.composite``) of ``scene``'s samples (standing in for the scene
    NeRF's ``render_rays``) and the person's."""

    def fake_render_rays(model, r, *args, return_samples=False, **kwargs):
        n = len(r)
        return RenderOutput(torch.zeros(n, 3), torch.zeros(n), torch.zeros(n), torch.zeros(n), None,
                            samples=scene, background=bg)

    monkeypatch.setattr("nsim.rendering.renderer.render_rays", fake_render_rays)
    cfg = SimpleNamespace(method="proposal", march=None, chunk_rays=1024, culling=True)
    people = [PersonView(k=0, joint_transforms=T, model=m, ray_mask=torch.ones(len(rays), dtype=torch.bool))]
    return HumanSet([m], {}, "cpu").composite(None, None, rays, people, cfg)


def test_training_and_rendering_merge_agree(person, monkeypatch):
    m, T = person
    rays = rays_through(T)
    scene = scene_samples(len(rays))
    bg = torch.rand(len(rays), 3, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():  # the person's samples exactly as HumanSet.composite casts them
        human = m.render_samples(rays.origins, rays.dirs, torch.as_tensor(T, dtype=torch.float32), rays.near,
                                 rays.far, box_test=True)
    assert bool((human.t_ends > human.t_starts).any(-1).all())  # every ray reaches the person
    train = render_merged(human, scene, background_rgb=bg)  # the trainer: the person's set, then the scene's
    out, instance = render_with_people(monkeypatch, m, T, rays, scene, bg)  # the renderer: the scene's first
    # the sets really interleave: some rays are the person's, some see past it
    assert float(train.alpha[0].max()) > 0.55 and float(train.alpha[0].min()) < 0.45 and float(train.alpha[1].min()) > 0
    # the same pixels, bit for bit, whichever order the sets come in (no two samples start at the same t here)
    assert torch.equal(out.rgb, train.rgb)
    assert torch.equal(out.accumulation, train.accumulation)
    assert torch.equal(out.depth, train.depth)
    # the instance mask is the trainer's person mask above one half
    assert np.array_equal(instance, np.where(train.alpha[0].numpy() > 0.5, 1, 0).astype(np.uint16))
    assert 0 < int(instance.sum()) < len(rays)


# ---------------------------------------------------------------------- the previous code, as plain twins
def _previous_model_composite(samples: RaySamples, background_rgb=None):
    """``nsim.rendering.model.composite`` before it moved here (what rendering used)."""
    order = torch.argsort(samples.t_starts, dim=-1, stable=True)
    t0 = torch.gather(samples.t_starts, -1, order)
    t1 = torch.gather(samples.t_ends, -1, order)
    sigma = torch.gather(samples.sigma, -1, order)
    rgb = torch.gather(samples.rgb, 1, order[..., None].expand(-1, -1, 3))
    weights, _ = quadrature.render_weights(sigma, t1 - t0)
    acc = weights.sum(-1)
    out = quadrature.accumulate(weights, rgb)
    if background_rgb is not None:
        out = out + (1.0 - acc)[:, None] * background_rgb
    mid = 0.5 * (t0 + t1)
    return out, quadrature.expected_depth(weights, mid, acc), quadrature.median_depth(weights, mid), acc, weights


def _previous_render_merged(*sets: RaySamples, background_rgb=None):
    """``nsim.human.nerf.render_merged`` before it used the compositor (what training used):
    rgb, accumulation, depth (not clamped), alpha."""
    t0 = torch.cat([s.t_starts for s in sets], dim=1)
    t1 = torch.cat([s.t_ends for s in sets], dim=1)
    sigma = torch.cat([s.sigma for s in sets], dim=1)
    rgb = torch.cat([s.rgb for s in sets], dim=1)
    source = torch.cat([torch.full_like(s.t_starts, k, dtype=torch.long) for k, s in enumerate(sets)], dim=1)
    order = torch.argsort(t0, dim=1, stable=True)
    t0, t1, sigma, source = (torch.gather(x, 1, order) for x in (t0, t1, sigma, source))
    rgb = torch.gather(rgb, 1, order[..., None].expand(-1, -1, 3))
    weights, _ = quadrature.render_weights(sigma, t1 - t0)
    acc = weights.sum(-1)
    out = quadrature.accumulate(weights, rgb)
    if background_rgb is not None:
        out = out + (1.0 - acc)[:, None] * background_rgb
    mid = 0.5 * (t0 + t1)
    depth = (weights * mid).sum(-1) / acc.clamp(min=quadrature.EPS)
    alpha = torch.stack([(weights * (source == k)).sum(-1) for k in range(len(sets))])
    return out, acc, depth, alpha


def random_sets(n: int = 64, sizes=(7, 5, 3), seed: int = 0) -> list[RaySamples]:
    """Unsorted, overlapping sets on the same rays, some rays empty (sigma 0)."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for s in sizes:
        t0 = 10.0 * torch.rand(n, s, generator=g)
        t1 = t0 + torch.rand(n, s, generator=g)
        sigma = 3.0 * torch.rand(n, s, generator=g) * (torch.arange(n) % 5 != 0)[:, None]
        out.append(RaySamples(t0, t1, sigma, torch.rand(n, s, 3, generator=g)))
    return out


def test_composite_is_bit_identical_to_the_previous_renderer():
    sets = random_sets()
    both = RaySamples(*(torch.cat([getattr(s, f) for s in sets], dim=1) for f in ("t_starts", "t_ends", "sigma", "rgb")))
    bg = torch.rand(len(both.sigma), 3, generator=torch.Generator().manual_seed(5))
    out = composite(both, bg)
    rgb, depth, median, acc, weights = _previous_model_composite(both, bg)
    for new, old in ((out.rgb, rgb), (out.depth, depth), (out.depth_median, median), (out.accumulation, acc),
                     (out.weights, weights)):
        assert torch.equal(new, old)
    assert torch.equal(out.background, bg)
    assert torch.equal(out.samples.t_starts, torch.sort(both.t_starts, dim=-1, stable=True).values)


def test_render_merged_keeps_colour_and_masks_and_clamps_depth():
    """Training's colour, opacity and masks are bit-identical to before. Its depth is now the renderer's
    (``quadrature.expected_depth``: clamped to the first and last samples' midpoints): a ray with no weight
    moves from 0 to its first midpoint, and where the merged midpoints are not in order (overlapping
    intervals) the clamp bites; elsewhere it is unchanged. Nothing published reads it (``HumanModel.render``
    zeroes depth where the opacity is below 1e-4, and the stages keep only its colour)."""
    sets = random_sets()
    bg = torch.tensor([0.2, 0.4, 0.6])
    new = render_merged(*sets, background_rgb=bg)
    rgb, acc, depth, alpha = _previous_render_merged(*sets, background_rgb=bg)
    assert torch.equal(new.rgb, rgb) and torch.equal(new.accumulation, acc) and torch.equal(new.alpha, alpha)
    merged, _ = merge_samples(*sets)
    mid = 0.5 * (merged.t_starts + merged.t_ends)
    assert torch.equal(new.depth, torch.clamp(depth, mid[:, 0], mid[:, -1]))  # exactly the clamp, nothing else
    empty = acc == 0
    assert bool(empty.any()) and bool((depth[empty] == 0).all())
    assert torch.equal(new.depth[empty], mid[empty, 0])  # moved: 0 -> the first midpoint
    assert not bool((mid[:, 1:] >= mid[:, :-1]).all())  # the random sets do exercise unordered midpoints
    # one field's samples in order along each ray (midpoints ascending): a lit ray's depth does not move
    t0 = sets[0].t_starts.sort(dim=1).values
    single = RaySamples(t0, t0 + 0.1, sets[0].sigma, sets[0].rgb)
    now, (_, acc1, before, _) = render_merged(single), _previous_render_merged(single)
    lit = acc1 > 1e-4
    assert bool(lit.any())
    assert float((now.depth[lit] - before[lit]).abs().max()) <= 1e-6 * float(before[lit].abs().max())


def test_set_weights_split_the_accumulation():
    sets = random_sets(seed=3)
    out, source = composite_sets(*sets)
    per = set_weights(out.weights, source, len(sets))
    assert per.shape == (len(sets), len(out.accumulation))
    torch.testing.assert_close(per.sum(0), out.accumulation)
    # a set's share is the weight of its own samples: the first set alone in front of nothing else
    alone, _ = composite_sets(sets[0])
    far = [RaySamples(s.t_starts + 100.0, s.t_ends + 100.0, s.sigma, s.rgb) for s in sets[1:]]
    front, src = composite_sets(sets[0], *far)
    torch.testing.assert_close(set_weights(front.weights, src, len(sets))[0], alone.accumulation)


def test_merge_needs_a_set():
    with pytest.raises(ValueError, match="at least one"):
        merge_samples()
