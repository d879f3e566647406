"""Samplers: spacing functions, stratified bins, PDF resampling against a loop reference."""

from __future__ import annotations

import pytest
import torch
from torch.testing import assert_close

from nsim.rendering.samplers import pdf_resample, spacing_to_t, uniform_bins
from tests.rendering.reference import inverse_cdf_loop


@pytest.mark.parametrize("spacing", ["linear", "lindisp"])
def test_spacing_maps_ends_and_is_monotone(spacing):
    near, far = torch.tensor([0.05, 0.5]), torch.tensor([8.0, 30.0])
    s = torch.linspace(0, 1, 33).expand(2, -1)
    t = spacing_to_t(s, near, far, spacing, 1.0)
    assert_close(t[:, 0], near)
    assert_close(t[:, -1], far, rtol=1e-5, atol=1e-5)
    assert (t[:, 1:] > t[:, :-1]).all()


def test_lindisp_is_uniform_in_disparity_beyond_break():
    near, far = torch.tensor([2.0]), torch.tensor([20.0])
    t = spacing_to_t(torch.linspace(0, 1, 11)[None], near, far, "lindisp", 1.0)
    disparity = 1.0 / t
    steps = disparity[:, 1:] - disparity[:, :-1]
    assert_close(steps, steps[:, :1].expand_as(steps), rtol=1e-4, atol=1e-6)


def test_uniform_bins_stratified():
    g = torch.Generator().manual_seed(0)
    b = uniform_bins(100, 8, g)
    assert b.shape == (100, 9)
    assert (b[:, 0] == 0).all() and (b[:, -1] == 1).all() and (b[:, 1:] >= b[:, :-1]).all()
    assert not torch.equal(b, uniform_bins(100, 8))
    assert torch.equal(uniform_bins(4, 8), torch.linspace(0, 1, 9).expand(4, -1))
    same = uniform_bins(100, 8, torch.Generator().manual_seed(0))
    assert torch.equal(b, same)


def test_pdf_resample_matches_reference_deterministic():
    g = torch.Generator().manual_seed(1)
    bins = torch.sort(torch.rand(5, 11, generator=g, dtype=torch.float64), dim=-1).values
    weights = torch.rand(5, 10, generator=g, dtype=torch.float64) ** 4
    out = pdf_resample(bins, weights, 16, histogram_padding=0.01)
    n = 17
    u = (torch.linspace(0.0, 1.0 - 1.0 / n, n, dtype=torch.float64) + 0.5 / n).expand(5, -1)
    assert_close(out, inverse_cdf_loop(bins, weights, u, 0.01))
    assert (out[:, 1:] >= out[:, :-1]).all()


def test_pdf_resample_concentrates_on_mass():
    bins = torch.linspace(0, 1, 11)[None]
    weights = torch.zeros(1, 10)
    weights[0, 6] = 1.0
    out = pdf_resample(bins, weights, 32, histogram_padding=1e-4)
    inside = ((out >= 0.6) & (out <= 0.7)).float().mean()
    assert inside > 0.9


def test_pdf_resample_jitter_is_seeded():
    bins = torch.linspace(0, 1, 11).expand(3, -1)
    w = torch.rand(3, 10, generator=torch.Generator().manual_seed(2))
    a = pdf_resample(bins, w, 8, torch.Generator().manual_seed(5))
    b = pdf_resample(bins, w, 8, torch.Generator().manual_seed(5))
    c = pdf_resample(bins, w, 8)
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert (a[:, 1:] >= a[:, :-1]).all()
