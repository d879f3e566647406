"""The default look: a person with no appearance drawn as the test room's mannequin, through the human model's
rendering interface, composited in depth order with other samples."""

from __future__ import annotations

import numpy as np
import torch

from nsim.human.gait import default_clip
from nsim.human.motion import LocomotionLoop
from nsim.human.skeleton import forward_kinematics
from nsim.rendering.default_look import DEFAULT_LOOK, DefaultLook, people_models
from nsim.synth.actor import Actor


def posed(height: float = 1.7) -> np.ndarray:
    loop = LocomotionLoop.from_clip(default_clip("walk", height))
    root, quats = loop.pose_at(np.array([0.3]), np.array([[2.0, 1.0]]), np.array([0.4]))
    return forward_kinematics(loop.skeleton, quats[0], root[0])


def rays_at(T: np.ndarray, n: int = 64):
    """Rays from 3 m in front of the pelvis, fanned over the body's height and beyond it."""
    pelvis = T[0, :3, 3]
    origin = pelvis + np.array([3.0 * np.cos(0.4), 3.0 * np.sin(0.4), 0.0])
    targets = pelvis + np.stack([np.zeros(n), np.linspace(-0.8, 0.8, n), np.linspace(-1.2, 1.2, n)], axis=1)
    d = targets - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.repeat(origin[None], n, axis=0), d


def test_samples_are_opaque_at_the_mannequins_surface_and_empty_elsewhere():
    T = posed()
    look = DefaultLook(1.7)
    o, d = rays_at(T)
    s = look.render_samples(torch.as_tensor(o, dtype=torch.float32), torch.as_tensor(d, dtype=torch.float32),
                            torch.as_tensor(T, dtype=torch.float32), near=0.1, far=50.0)
    truth = Actor(1.7, seed=0).intersect(o, d, T)
    assert truth.hit.any() and (~truth.hit).any()  # the fan meets the body and misses it
    hit = s.sigma[:, 0].numpy() > 0
    np.testing.assert_array_equal(hit, truth.hit)
    np.testing.assert_allclose(s.t_starts[hit, 0].numpy(), truth.t[truth.hit], atol=1e-4)
    alpha = 1.0 - torch.exp(-s.sigma * (s.t_ends - s.t_starts))
    assert float(alpha[hit].min()) > 0.999
    np.testing.assert_allclose(s.rgb[hit, 0].numpy(), truth.rgb[truth.hit], atol=1e-4)  # rays given as float32
    assert (s.t_ends[~hit] == s.t_starts[~hit]).all()
    # the box holds every hit point
    lo, hi = look.posed_box(torch.as_tensor(T)).reshape(2, 3).numpy()
    pts = o[truth.hit] + truth.t[truth.hit, None] * d[truth.hit]
    assert (pts >= lo - 1e-6).all() and (pts <= hi + 1e-6).all()
    # a far limit in front of the body: nothing
    near_only = look.render_samples(torch.as_tensor(o, dtype=torch.float32), torch.as_tensor(d, dtype=torch.float32),
                                    torch.as_tensor(T, dtype=torch.float32), near=0.1, far=1.0)
    assert float(near_only.sigma.max()) == 0.0


def test_it_hides_what_lies_behind_it_in_a_merged_rendering():
    """Composited with a wall 10 m away (the scene's samples), a ray through the mannequin shows it, at its depth."""
    from nsim.volume.compositing import composite_sets
    from nsim.volume.samples import RaySamples

    T = posed()
    o, d = rays_at(T)
    ot, dt = torch.as_tensor(o, dtype=torch.float32), torch.as_tensor(d, dtype=torch.float32)
    person = DefaultLook(1.7).render_samples(ot, dt, torch.as_tensor(T, dtype=torch.float32))
    n = len(o)
    wall = RaySamples(torch.full((n, 1), 10.0), torch.full((n, 1), 10.1), torch.full((n, 1), 1e3),
                      torch.tensor([[[0.0, 0.0, 1.0]]]).expand(n, 1, 3))
    comp, _ = composite_sets(wall, person, background_rgb=torch.zeros(n, 3))
    hit = person.sigma[:, 0] > 0
    np.testing.assert_allclose(comp.depth[hit].numpy(), person.t_starts[hit, 0].numpy() + 0.001, atol=2e-3)
    np.testing.assert_allclose(comp.rgb[hit].numpy(), person.rgb[hit, 0].numpy(), atol=1e-4)
    np.testing.assert_allclose(comp.rgb[~hit].numpy(), np.tile([0.0, 0.0, 1.0], (int((~hit).sum()), 1)), atol=1e-4)


def test_people_models_give_one_mannequin_per_height_and_keep_checkpoint_indices():
    models, idx = people_models([], [DEFAULT_LOOK, DEFAULT_LOOK, DEFAULT_LOOK], [1.7, 1.8, 1.7], "cpu")
    assert len(models) == 2 and idx == [0, 1, 0]
    assert [m.height_m for m in models] == [1.7, 1.8]
    assert people_models([], None, [1.7], "cpu") == ([], None)
