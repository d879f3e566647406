"""Scene contraction (mip-NeRF 360) and the box normalisation around it."""

from __future__ import annotations

import math

import pytest
import torch
from torch.testing import assert_close

from nsim.fields.contraction import contract, normalise_to_box, unit_to_world, world_to_unit


@pytest.mark.parametrize("order", [2, math.inf])
def test_identity_inside_unit_ball(order):
    x = torch.rand(100, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    norm = torch.linalg.vector_norm(x, ord=order, dim=-1)
    inside = x[norm <= 1.0]
    assert inside.shape[0] > 10
    assert_close(contract(inside, order), inside)


@pytest.mark.parametrize("order", [2, math.inf])
def test_bounded_monotone_and_continuous(order):
    direction = torch.nn.functional.normalize(torch.randn(20, 3, generator=torch.Generator().manual_seed(1)), dim=-1)
    direction = direction / torch.linalg.vector_norm(direction, ord=order, dim=-1, keepdim=True)
    radii = torch.tensor([0.5, 0.999999, 1.0, 1.000001, 2.0, 10.0, 1e3, 1e8])
    y = contract(direction[:, None, :] * radii[None, :, None], order)
    ny = torch.linalg.vector_norm(y, ord=order, dim=-1)
    # 2 - 1e-8 rounds to 2 in float32, and the float32 norm of that point may come out a few ulps above 2 (by how
    # much depends on the CPU's kernels: ATEN_CPU_CAPABILITY=default gave 2.0000002)
    assert (ny <= 2.0 * (1 + 4 * torch.finfo(torch.float32).eps)).all() and (ny[:, :-1] < 2.0).all()
    assert (ny[:, 1:] >= ny[:, :-1]).all()  # radially monotone
    assert_close(ny[:, 1], ny[:, 3], atol=1e-5, rtol=0)  # continuous across the unit sphere
    assert_close(ny[:, 4], torch.full_like(ny[:, 4], 1.5))  # 2 - 1/2
    # direction is preserved
    assert_close(torch.nn.functional.normalize(y, dim=-1), torch.nn.functional.normalize(direction, dim=-1)[:, None, :].expand_as(y))


def test_derivative_continuous_at_boundary():
    d = torch.tensor([[0.6, 0.8, 0.0]])
    r = torch.tensor([1.0 - 1e-4, 1.0 + 1e-4], dtype=torch.float64)
    x = (d.double() * r[:, None]).requires_grad_(True)
    y = contract(x, 2.0)
    (grad,) = torch.autograd.grad(y[:, 0].sum(), x)
    assert_close(grad[0], grad[1], atol=1e-3, rtol=0)


def test_box_maps_to_unit_cube_centre_half():
    aabb = torch.tensor([[0.0, -1.0, 2.0], [4.0, 1.0, 3.0]])
    corners = torch.tensor([[0.0, -1.0, 2.0], [4.0, 1.0, 3.0], [2.0, 0.0, 2.5]])
    assert_close(normalise_to_box(corners, aabb), torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]))
    u = world_to_unit(corners, aabb)
    assert_close(u, torch.tensor([[0.25] * 3, [0.75] * 3, [0.5] * 3]))
    far = world_to_unit(torch.tensor([[1e6, 0.0, 2.5], [-50.0, 0.0, 2.5]]), aabb)
    assert ((far >= 0.0) & (far <= 1.0)).all()


def test_unit_to_world_inverts():
    aabb = torch.tensor([[0.0, 0.0, 0.0], [8.0, 6.0, 3.0]])
    x = torch.rand(200, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2)) * 40 - 15
    assert_close(unit_to_world(world_to_unit(x, aabb.double()), aabb.double()), x, rtol=1e-6, atol=1e-6)
