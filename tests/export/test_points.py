"""The point-cloud core: ray hits, colours without the background, density normals, orientation, the cap."""

from __future__ import annotations

import numpy as np
import torch

from nsim.export import points as P


def test_ray_hits_need_opacity_and_a_depth_before_far():
    o = torch.zeros(4, 3)
    d = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
    depth = torch.tensor([2.0, 3.0, 5.0, float("inf")])
    acc = torch.tensor([0.95, 0.4, 0.99, 0.99])
    far = torch.tensor([10.0, 10.0, 5.0, 10.0])
    hit, xyz = P.ray_hits(o, d, depth, acc, far, 0.9)
    assert hit.tolist() == [True, False, False, False]
    assert torch.allclose(xyz[0], torch.tensor([2.0, 0.0, 0.0]))
    assert torch.isfinite(xyz).all()


def test_surface_rgb_removes_the_background_share():
    c = torch.tensor([[0.2, 0.4, 0.6]])
    bg = torch.tensor([[1.0, 1.0, 0.0]])
    acc = torch.tensor([0.8])
    rendered = acc[:, None] * c + (1 - acc)[:, None] * bg
    assert torch.allclose(P.surface_rgb(rendered, acc, bg), c, atol=1e-6)


def test_density_normals_match_an_analytic_gradient():
    """sigma = exp(-|x - c|^2) rises towards c: the normal -grad/|grad| points away from c; a flat
    field has no normal."""
    c = torch.tensor([0.5, -1.0, 2.0])
    x = torch.tensor([[1.5, -1.0, 2.0], [0.5, 0.0, 2.0], [0.0, -1.5, 1.0]])
    n, ok = P.density_normals(lambda p: torch.exp(-((p - c) ** 2).sum(-1)), x, chunk=2)
    expect = (x - c) / torch.linalg.vector_norm(x - c, dim=-1, keepdim=True)
    assert ok.all() and torch.allclose(n, expect, atol=1e-6)
    n0, ok0 = P.density_normals(lambda p: torch.ones(p.shape[0]) + 0 * p.sum(-1), x)
    assert not ok0.any() and (n0 == 0).all()


def test_orientation_faces_the_camera():
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.6, 0.8]])
    out, flipped = P.orient_towards_viewer(n, d)
    assert flipped.tolist() == [False, True]
    assert torch.equal(out[1], torch.tensor([0.0, 0.0, -1.0]))


def test_cap_is_seeded_sorted_and_unique():
    a = P.cap_indices(1000, 100, np.random.default_rng(3))
    b = P.cap_indices(1000, 100, np.random.default_rng(3))
    assert np.array_equal(a, b) and len(np.unique(a)) == 100 and (np.diff(a) > 0).all()
    assert np.array_equal(P.cap_indices(5, 100, np.random.default_rng(0)), np.arange(5))


def test_no_hit_says_what_to_lower():
    import pytest

    from nsim.export.export_config import PointsConfig
    from nsim.export.extract import NoSurface, ViewRays, point_cloud

    n = 5
    rays = ViewRays(torch.zeros(n, 3), torch.tensor([[1.0, 0.0, 0.0]]).expand(n, 3), torch.zeros(n), torch.full((n,), 9.0),
                    torch.full((n,), 3.0), torch.full((n,), 0.3), torch.zeros(n, 3), torch.zeros(n, 3))
    with pytest.raises(NoSurface, match=r"lower points.min_accumulation \(e.g. --set points.min_accumulation=0.27\)"):
        point_cloud(None, rays, PointsConfig(min_accumulation=0.9), np.random.default_rng(0))
