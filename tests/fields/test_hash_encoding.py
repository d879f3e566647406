"""Hash encoding: layout, forward against the loop reference, gradients (table and positions)."""

from __future__ import annotations

import pytest
import torch
from torch.testing import assert_close

from nsim.fields import hash_encoding
from nsim.fields.hash_encoding import HashEncoding, grid_layout, hash_grid_encode
from tests.fields.reference import expected_resolutions, hash_encode_loop


def _encoding(dtype=torch.float32, **kw) -> HashEncoding:
    g = torch.Generator().manual_seed(0)
    args = {"levels": 6, "features_per_level": 2, "log2_table_size": 10, "base_resolution": 2, "max_resolution": 40}
    args.update(kw)
    enc = HashEncoding(**args, init_scale=1.0, generator=g)
    return enc.to(dtype)


def test_layout_dense_then_hashed():
    layout = grid_layout(6, 10, 2, 40)
    assert list(layout.resolutions) == expected_resolutions(6, 2, 40)
    assert layout.n_dense == 3  # (R + 1)^3 <= 1024 for R = 2, 3, 6
    assert layout.sizes[:3] == (27, 64, 343) and set(layout.sizes[3:]) == {1024}
    assert layout.offsets[1:] == tuple(sum(layout.sizes[: k + 1]) for k in range(5))


def test_layout_rejects_bad_sizes():
    with pytest.raises(ValueError):
        grid_layout(4, 10, 64, 16)


@pytest.mark.parametrize("features", [1, 2, 4])
@pytest.mark.parametrize("dense_via_grid_sample", [True, False])
def test_matches_loop_reference(features, dense_via_grid_sample):
    enc = _encoding(features_per_level=features)
    enc.dense_via_grid_sample = dense_via_grid_sample
    x = torch.rand(64, 3, generator=torch.Generator().manual_seed(1))
    x[0] = 0.0
    x[1] = 1.0  # the far corner: clamped into the last cell
    x[2] = torch.tensor([0.5, 0.25, 1.0])
    assert_close(enc(x), hash_encode_loop(x, enc.table, enc.layout), rtol=1e-5, atol=1e-6)


def test_shapes_and_clamping():
    enc = _encoding()
    x = torch.rand(5, 7, 3)
    assert enc(x).shape == (5, 7, enc.n_output_dims) == (5, 7, 12)
    inside = torch.tensor([[0.0, 1.0, 0.5]])
    outside = torch.tensor([[-0.3, 1.7, 0.5]])
    assert_close(enc(outside), enc(inside))


@pytest.mark.parametrize("dense_via_grid_sample", [True, False])
def test_table_gradient_matches_reference(dense_via_grid_sample):
    enc = _encoding(dtype=torch.float64)
    enc.dense_via_grid_sample = dense_via_grid_sample
    x = torch.rand(40, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    w = torch.randn(40, enc.n_output_dims, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    (enc(x) * w).sum().backward()
    fast = enc.table.grad.clone()
    table = enc.table.detach().clone().requires_grad_(True)
    (hash_encode_loop(x, table, enc.layout) * w).sum().backward()
    assert_close(fast, table.grad)


@pytest.mark.parametrize("dense_via_grid_sample", [True, False])
def test_position_gradient_gradcheck(dense_via_grid_sample):
    enc = _encoding(dtype=torch.float64, levels=4, max_resolution=12)
    table = enc.table.detach().clone().requires_grad_(True)
    # keep points away from cell faces, where the trilinear interpolant has kinks
    x = (torch.rand(6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(4)) * 0.8 + 0.1).requires_grad_(True)
    def fn(x, table):
        return hash_grid_encode(x, table, enc.layout, dense_via_grid_sample=dense_via_grid_sample)
    assert torch.autograd.gradcheck(fn, (x, table), eps=1e-7, atol=1e-5)


def test_deterministic_backward():
    enc = _encoding(levels=8, log2_table_size=8, max_resolution=200)
    x = torch.rand(5000, 3, generator=torch.Generator().manual_seed(5))
    grads = []
    for _ in range(2):
        enc.table.grad = None
        enc(x).square().sum().backward()
        grads.append(enc.table.grad.clone())
    assert torch.equal(grads[0], grads[1])


def test_tcnn_backend_is_optional():
    assert HashEncoding.resolve_backend("auto", "cpu") == "torch"
    try:
        import tinycudann  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError):
            HashEncoding(backend="tcnn")


def test_compiled_indices_match_eager():
    """torch.compile'd corner arithmetic: the same rows, the same weights, the same gradients."""
    eager = _encoding(levels=8, log2_table_size=9, max_resolution=300)
    fast = _encoding(levels=8, log2_table_size=9, max_resolution=300)
    fast.compile_indices = True
    assert eager.layout.n_dense >= 1 and eager.layout.n_dense < eager.layout.levels  # both row formulas
    consts = hash_encoding._level_constants(eager.layout, torch.device("cpu"))
    for n in (257, 1000):  # two batch sizes: one dynamic-shape kernel serves both
        x = torch.rand(n, 3, generator=torch.Generator().manual_seed(n))
        for sl in (slice(0, eager.layout.n_dense), slice(eager.layout.n_dense, eager.layout.levels)):
            with torch.no_grad():
                ref = hash_encoding.corner_indices_weights(x, eager.layout, consts, sl)
                got = hash_encoding.corner_indices_weights(x, eager.layout, consts, sl, compiled=True)
            assert torch.equal(ref[0], got[0])
            assert_close(got[1], ref[1], rtol=1e-6, atol=1e-7)
            assert_close(got[2], ref[2], rtol=1e-6, atol=1e-7)
        w = torch.randn(n, eager.n_output_dims, generator=torch.Generator().manual_seed(7))
        for enc in (eager, fast):
            enc.table.grad = None
            (enc(x) * w).sum().backward()
        assert_close(fast(x), eager(x), rtol=1e-6, atol=1e-7)
        assert_close(fast.table.grad, eager.table.grad, rtol=1e-6, atol=1e-7)


def test_compile_failure_falls_back_to_eager(monkeypatch, caplog):
    def broken_compile(fn, **kw):
        def run(*a, **k):
            raise RuntimeError("no C++ compiler found")
        return run

    monkeypatch.setattr(hash_encoding, "_compiled_corner_terms", None)
    monkeypatch.setattr(hash_encoding, "_compile_failed", False)
    monkeypatch.setattr(torch, "compile", broken_compile)
    enc = _encoding()
    x = torch.rand(50, 3, generator=torch.Generator().manual_seed(8))
    expected = enc(x)
    enc.compile_indices = True
    with caplog.at_level("WARNING"):
        got = enc(x)
    assert torch.equal(got, expected)
    assert hash_encoding._compile_failed
    assert "torch.compile failed (no C++ compiler found)" in caplog.text
