"""Scene and proposal fields: shapes, activations, appearance embeddings, SH encoding."""

from __future__ import annotations

import pytest
import torch
from torch.testing import assert_close

from nsim.fields.encodings import spherical_harmonics
from nsim.fields.scene_field import ProposalField, ProposalFieldConfig, SceneField, SceneFieldConfig

AABB = torch.tensor([[0.0, 0.0, 0.0], [4.0, 3.0, 2.5]])
SMALL = SceneFieldConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16,
                         color_hidden_dim=16, color_hidden_layers=1, appearance_dim=4, sh_degree=3)


def test_spherical_harmonics_orthonormal():
    # Monte-Carlo check of orthonormality on the sphere: E[Y_i Y_j] * 4 pi == I
    g = torch.Generator().manual_seed(0)
    d = torch.nn.functional.normalize(torch.randn(400_000, 3, generator=g, dtype=torch.float64), dim=-1)
    y = spherical_harmonics(d, 4)
    gram = y.T @ y / d.shape[0] * 4 * torch.pi
    assert_close(gram, torch.eye(16, dtype=torch.float64), atol=0.03, rtol=0)
    for deg in (1, 2, 3):
        assert spherical_harmonics(d[:5], deg).shape == (5, deg**2)
    with pytest.raises(ValueError):
        spherical_harmonics(d[:5], 5)


def test_scene_field_shapes_and_ranges():
    g = torch.Generator().manual_seed(0)
    f = SceneField(SMALL, AABB, n_images=5, generator=g)
    x = torch.rand(32, 3) * 4
    sigma, geo = f.density(x)
    assert sigma.shape == (32,) and geo.shape == (32, SMALL.geo_feat_dim) and (sigma > 0).all()
    dirs = torch.nn.functional.normalize(torch.randn(32, 3), dim=-1)
    codes = f.appearance_codes(torch.arange(32) % 5, 32)
    rgb = f.color(geo, dirs, codes)
    assert rgb.shape == (32, 3) and ((rgb > 0) & (rgb < 1)).all()


def test_appearance_choices():
    f = SceneField(SMALL, AABB, n_images=5, generator=torch.Generator().manual_seed(0))
    table = f.appearance.weight
    mask = torch.tensor([True, False, True, True, False])
    assert_close(f.appearance_codes(None, 3, "mean", mask), table[mask].mean(0).expand(3, -1))
    assert_close(f.appearance_codes(None, 2, 4), table[4].expand(2, -1))
    assert (f.appearance_codes(None, 2, "zero") == 0).all()
    with pytest.raises(ValueError):
        f.appearance_codes(None, 2, 9)
    no_app = SceneField(SceneFieldConfig(**{**SMALL.__dict__, "appearance_dim": 0}), AABB, n_images=5)
    assert no_app.appearance_codes(None, 2, "mean") is None


def test_same_seed_same_field():
    a = SceneField(SMALL, AABB, 3, generator=torch.Generator().manual_seed(7))
    b = SceneField(SMALL, AABB, 3, generator=torch.Generator().manual_seed(7))
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert ka == kb and torch.equal(va, vb)


def test_proposal_field_gradients_flow():
    p = ProposalField(ProposalFieldConfig(hash_levels=3, hash_log2_table_size=10, hash_max_resolution=32, hidden_dim=8),
                      AABB, generator=torch.Generator().manual_seed(0))
    sigma = p(torch.rand(50, 3) * 3)
    assert sigma.shape == (50,)
    sigma.sum().backward()
    assert p.encoding.table.grad is not None and p.encoding.table.grad.abs().sum() > 0


def test_appearance_init_spread_follows_the_config():
    # 64 images x 8 dims: the table's standard deviation is the configured one (to sampling error)
    for std in (1.0, 0.01):
        cfg = SceneFieldConfig(**{**SMALL.__dict__, "appearance_dim": 8, "appearance_init_std": std})
        table = SceneField(cfg, AABB, n_images=64, generator=torch.Generator().manual_seed(0)).appearance.weight
        assert abs(float(table.std()) / std - 1.0) < 0.15
    zero = SceneFieldConfig(**{**SMALL.__dict__, "appearance_init_std": 0.0})
    assert (SceneField(zero, AABB, n_images=3).appearance.weight == 0).all()
