"""Volume rendering and the proposal-sampler losses against hand computation and plain twins."""

from __future__ import annotations

import math

import torch
from torch.testing import assert_close

from nsim.volume import quadrature
from nsim.volume.compositing import composite
from nsim.volume.samples import RaySamples
from tests.rendering.reference import distortion_quadratic, render_weights_loop


def test_two_samples_by_hand():
    sigma = torch.tensor([[2.0, 3.0]])
    delta = torch.tensor([[0.5, 0.25]])
    a0, a1 = 1 - math.exp(-1.0), 1 - math.exp(-0.75)
    w, trans = quadrature.render_weights(sigma, delta)
    assert_close(w, torch.tensor([[a0, (1 - a0) * a1]]))
    assert_close(trans, torch.tensor([[1.0, math.exp(-1.0)]]))
    rgb = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    assert_close(quadrature.accumulate(w, rgb), torch.tensor([[a0, (1 - a0) * a1, 0.0]]))
    t_mid = torch.tensor([[1.0, 2.0]])
    acc = w.sum(-1)
    assert_close(quadrature.expected_depth(w, t_mid), (w * t_mid).sum(-1) / acc)
    assert_close(quadrature.median_depth(w, t_mid), torch.tensor([1.0]))  # a0 = 0.63 > half of 0.81


def test_matches_loop_reference():
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(5, 17, generator=g, dtype=torch.float64) * 10
    delta = torch.rand(5, 17, generator=g, dtype=torch.float64) * 0.2
    w, _ = quadrature.render_weights(sigma, delta)
    assert_close(w, render_weights_loop(sigma, delta))
    assert (w.sum(-1) <= 1 + 1e-12).all()


def test_packed_weights_match_the_padded_layout():
    """Samples of rays of 0..6 samples (one empty) packed into one array, ray-major: the same weights and
    transmittance as ``render_weights`` of the padded ``(R, S)`` layout (zero-density padding at the end), whose
    optical depths are ``packed_optical_depth``'s."""
    g = torch.Generator().manual_seed(1)
    counts = torch.tensor([3, 0, 6, 1, 4, 2])
    k = int(counts.sum())
    sigma = torch.rand(k, generator=g) * 20
    delta = torch.rand(k, generator=g) * 0.1
    ray = torch.repeat_interleave(torch.arange(len(counts)), counts)
    slot = torch.arange(k) - (torch.cumsum(counts, 0) - counts)[ray]
    sigma_p = torch.zeros(len(counts), int(counts.max())).index_put((ray, slot), sigma)
    delta_p = torch.zeros_like(sigma_p).index_put((ray, slot), delta)
    w_p, trans_p = quadrature.render_weights(sigma_p, delta_p)
    w, trans = quadrature.packed_render_weights(sigma, delta, ray)
    assert w.dtype == trans.dtype == torch.float64 and w.shape == trans.shape == (k,)
    assert_close(w.float(), w_p[ray, slot], rtol=1e-5, atol=1e-6)
    assert_close(trans.float(), trans_p[ray, slot], rtol=1e-5, atol=1e-6)
    tau, before = quadrature.packed_optical_depth(sigma, delta, ray)
    assert_close(tau, (sigma * delta).double())
    assert_close(before[slot == 0], torch.zeros(int((counts > 0).sum()), dtype=torch.float64))
    empty = torch.zeros(0, dtype=torch.int64)
    assert quadrature.packed_render_weights(torch.zeros(0), torch.zeros(0), empty)[0].shape == (0,)


def test_opaque_wall_depths():
    t = torch.linspace(0, 10, 101)[None]
    sigma = torch.zeros(1, 100)
    sigma[0, 40:45] = 1e4  # an opaque slab from t = 4.0 to 4.5: everything lands in the first bin [4.0, 4.1]
    w, _ = quadrature.render_weights(sigma, t[:, 1:] - t[:, :-1])
    mid = 0.5 * (t[:, 1:] + t[:, :-1])
    assert abs(float(w.sum()) - 1.0) < 1e-6
    assert abs(float(quadrature.expected_depth(w, mid)) - 4.05) < 1e-4
    assert abs(float(quadrature.median_depth(w, mid)) - 4.05) < 1e-4


def test_distortion_loss_matches_quadratic_form():
    g = torch.Generator().manual_seed(1)
    w = torch.rand(6, 12, generator=g, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True) * 0.9
    bins = torch.sort(torch.rand(6, 13, generator=g, dtype=torch.float64), dim=-1).values
    assert_close(quadrature.distortion_loss(w, bins), distortion_quadratic(w, bins))


def test_distortion_prefers_compact_weights():
    bins = torch.linspace(0, 1, 11)[None]
    spread = torch.full((1, 10), 0.1)
    peak = torch.zeros(1, 10)
    peak[0, 4] = 1.0
    assert quadrature.distortion_loss(peak, bins) < quadrature.distortion_loss(spread, bins)


def test_interlevel_loss_zero_when_proposal_bounds_final():
    bins = torch.linspace(0, 1, 9)[None]
    final = torch.tensor([[0.0, 0.0, 0.1, 0.6, 0.2, 0.0, 0.0, 0.0]])
    # a coarser proposal (4 bins) that puts at least the final mass in every bin
    coarse_bins = torch.linspace(0, 1, 5)[None]
    coarse = torch.tensor([[0.0, 0.7, 0.2, 0.0]])
    assert abs(float(quadrature.interlevel_loss(final, bins, [coarse], [coarse_bins]))) < 1e-9
    too_low = torch.tensor([[0.0, 0.3, 0.1, 0.0]])
    loss = quadrature.interlevel_loss(final, bins, [too_low], [coarse_bins])
    # envelopes (coarse bins touching a final bin count): bin 2 [.25, .375] -> 0.3 >= 0.1; bin 3 [.375, .5]
    # -> 0.3 + 0.1 < 0.6; bin 4 [.5, .625] -> 0.1 < 0.2
    expected = (0.6 - 0.4) ** 2 / (0.6 + 1e-7) + (0.2 - 0.1) ** 2 / (0.2 + 1e-7)
    assert abs(float(loss) - expected) < 1e-5


def test_composite_sorts_merged_samples():
    # a scene sample behind a "human" sample: concatenated out of order, composited in depth order
    scene = RaySamples(torch.tensor([[3.0]]), torch.tensor([[3.1]]), torch.tensor([[100.0]]), torch.tensor([[[0.0, 0.0, 1.0]]]))
    human = RaySamples(torch.tensor([[1.0]]), torch.tensor([[1.1]]), torch.tensor([[100.0]]), torch.tensor([[[1.0, 0.0, 0.0]]]))
    merged = RaySamples(*(torch.cat([getattr(scene, k), getattr(human, k)], dim=1) for k in ("t_starts", "t_ends", "sigma", "rgb")))
    out = composite(merged)
    a = 1 - math.exp(-10.0)
    assert_close(out.rgb, torch.tensor([[a, 0.0, (1 - a) * a]]))
    assert_close(out.samples.t_starts, torch.tensor([[1.0, 3.0]]))
