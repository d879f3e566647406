"""The mesh core on analytic fields: marching cubes finds a known sphere and box within a cell,
faces and normals point to the free side, small pieces go, seen-space cropping, probe colours."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nsim.volume import density_mesh as M

CENTRE = np.array([1.3, -0.4, 0.9])  # off the origin and off the lattice: no lucky alignment
RADIUS = 0.7


def sphere_density(x: torch.Tensor) -> torch.Tensor:
    """100/m inside a sphere, 0 outside, a 0.1 m linear ramp across the surface (level 50 is the sphere)."""
    r = torch.linalg.vector_norm(x - torch.as_tensor(CENTRE, dtype=x.dtype), dim=-1)
    return (100.0 * (0.5 - (r - RADIUS) / 0.1)).clamp(0.0, 100.0)


def box_density(lo, hi):
    lo_t, hi_t = torch.tensor(lo), torch.tensor(hi)

    def fn(x: torch.Tensor) -> torch.Tensor:
        inside = ((x >= lo_t) & (x <= hi_t)).all(-1)
        return torch.where(inside, 50.0, 0.0)

    return fn


def lattice_around(lo, hi, cell_m):
    return M.lattice_over(np.asarray(lo, float), np.asarray(hi, float), cell_m, 10**8)[0]


@pytest.mark.parametrize("cell_m", [0.1, 0.04])
def test_sphere_is_recovered_within_a_cell(cell_m):
    lat = lattice_around(CENTRE - 1.0, CENTRE + 1.0, cell_m)
    vol = M.sample_lattice(sphere_density, lat, chunk=5000)
    verts, faces = M.marching_cubes(vol, 50.0, lat)
    r = np.linalg.norm(verts - CENTRE, axis=-1)
    # the ramp is linear across the surface and wider than a cell, so linear interpolation is nearly exact
    assert np.abs(r - RADIUS).max() < 0.1 * cell_m
    area = M.face_areas(verts, faces).sum()
    assert area == pytest.approx(4 * np.pi * RADIUS**2, rel=0.03)
    # faces counter-clockwise seen from outside: face normals and vertex normals point away from the centre
    centroid = verts[faces].mean(1)
    assert ((M.face_normals(verts, faces) * (centroid - CENTRE)).sum(-1) > 0).all()
    n = M.vertex_normals(verts, faces)
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0)
    radial = (verts - CENTRE) / r[:, None]
    assert (n * radial).sum(-1).min() > 0.95


def test_box_faces_lie_on_its_planes():
    """A sharp box (density 50 inside, 0 outside) at level 25: every vertex within a cell of the box's
    surface, in world coordinates (the lattice's origin and spacing are applied)."""
    lo, hi = np.array([0.33, 1.12, -0.51]), np.array([1.47, 2.05, 0.26])
    cell = 0.05
    lat = lattice_around(lo - 0.2, hi + 0.2, cell)
    verts, faces = M.marching_cubes(M.sample_lattice(box_density(lo, hi), lat), 25.0, lat)
    outside = np.maximum(np.maximum(lo - verts, verts - hi), 0.0)
    inside_depth = np.minimum(verts - lo, hi - verts).min(-1)
    dist = np.where((outside > 0).any(-1), np.linalg.norm(outside, axis=-1), inside_depth)
    assert dist.max() <= cell + 1e-6
    assert np.allclose(verts.min(0), lo, atol=cell) and np.allclose(verts.max(0), hi, atol=cell)


def test_level_outside_the_data_raises_empty_surface():
    lat = lattice_around(CENTRE - 1.0, CENTRE + 1.0, 0.2)
    vol = M.sample_lattice(sphere_density, lat)
    with pytest.raises(M.EmptySurface) as e:
        M.marching_cubes(vol, 150.0, lat)
    assert e.value.high == pytest.approx(100.0) and e.value.low == 0.0


def test_lattice_grows_to_fit_the_node_budget():
    lat, grew = M.lattice_over([0, 0, 0], [10, 10, 10], 0.01, 1_000_000)
    assert grew and lat.n_nodes <= 1_000_000 and lat.cell_m > 0.09
    assert (lat.hi_m >= 10 - 1e-9).all()
    lat, grew = M.lattice_over([0, 0, 0], [1, 2, 3], 0.5, 1000)
    assert not grew and lat.shape == (3, 5, 7)


def test_need_mask_skips_nodes():
    lat = lattice_around(CENTRE - 1.0, CENTRE + 1.0, 0.1)
    calls = []

    def fn(x):
        calls.append(len(x))
        return sphere_density(x)

    full = M.sample_lattice(fn, lat)
    n_full = sum(calls)
    calls.clear()
    xs = np.asarray(lat.lo_m)[0] + np.arange(lat.shape[0]) * lat.cell_m
    need = np.broadcast_to((xs > CENTRE[0])[:, None, None], lat.shape)
    half = M.sample_lattice(fn, lat, need=need, chunk=100)
    assert sum(calls) == int(need.sum()) < 0.6 * n_full
    assert np.array_equal(half[xs > CENTRE[0]], full[xs > CENTRE[0]])
    assert (half[xs <= CENTRE[0]] == 0).all()


def test_nodes_in_cells_matches_a_per_node_lookup():
    """The separable lookup against the plain one: every node's cell by floor((x - lo) / cell)."""
    rng = np.random.default_rng(0)
    cells = rng.random((7, 5, 4)) > 0.5
    lo, cell = np.array([-0.3, 0.2, 1.0]), np.array([0.25, 0.3, 0.4])
    lat = lattice_around([-0.6, 0.0, 0.7], [1.6, 1.9, 3.0], 0.07)
    got = M.nodes_in_cells(cells, lo, cell, lat, outside=True)
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in lat.shape], indexing="ij"), -1).reshape(-1, 3)
    x = np.asarray(lat.lo_m) + ijk * lat.cell_m
    k = np.floor((x - lo) / cell).astype(int)
    inside = ((k >= 0) & (k < cells.shape)).all(-1)
    k = np.clip(k, 0, np.array(cells.shape) - 1)
    want = np.where(inside, cells[k[:, 0], k[:, 1], k[:, 2]], True).reshape(lat.shape)
    assert np.array_equal(got, want) and got.any() and not got.all()


def test_small_components_are_dropped():
    lat = lattice_around([-1.5, -1.5, -1.5], [1.5, 1.5, 1.5], 0.05)

    def two_spheres(x):
        big = 0.5 - torch.linalg.vector_norm(x - torch.tensor([-0.6, 0.0, 0.0]), dim=-1)
        small = 0.15 - torch.linalg.vector_norm(x - torch.tensor([0.9, 0.0, 0.0]), dim=-1)
        return 100.0 * torch.maximum(big, small).clamp(min=-0.5) + 50.0

    verts, faces = M.marching_cubes(M.sample_lattice(two_spheres, lat), 50.0, lat)
    assert len(np.unique(M.face_components(len(verts), faces))) == 2
    v, f, dropped = M.drop_small_components(verts, faces, min_area_m2=1.0)  # small: 0.28 m2, big: 3.1 m2
    assert dropped == 1 and len(np.unique(M.face_components(len(v), f))) == 1
    assert (v[:, 0] < 0).all() and f.max() == len(v) - 1
    v0, f0, d0 = M.drop_small_components(verts, faces, 0.0)
    assert d0 == 0 and len(f0) == len(faces)


def test_seen_cells_and_face_crop():
    """Rays along +x at y, z in the middle of a 10 x 4 x 4 grid of 1 m cells, stopping at x = 5.5: cells
    x 0..5 of the middle row seen, the rest not; faces are kept by their centroid's cell."""
    origins = torch.tensor([[0.0, 1.5, 1.5], [0.0, 2.5, 2.5]])
    dirs = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    seen = M.seen_cells(origins, dirs, torch.zeros(2), torch.tensor([5.5, 2.2]), [0, 0, 0], 1.0, (10, 4, 4))
    assert seen[:6, 1, 1].all() and not seen[6:, 1, 1].any()
    assert seen[:3, 2, 2].all() and not seen[3:, 2, 2].any()
    assert int(seen.sum()) == 9
    verts = np.array([[5.2, 1.2, 1.2], [5.4, 1.4, 1.2], [5.2, 1.4, 1.4], [7.2, 1.2, 1.2], [7.4, 1.4, 1.2], [7.2, 1.4, 1.4]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    keep = M.faces_in_cells(verts, faces, seen.numpy(), [0, 0, 0], 1.0)
    assert keep.tolist() == [True, False]
    v, f = M.keep_faces(verts, faces, keep)
    assert np.array_equal(v, verts[:3]) and f.tolist() == [[0, 1, 2]]


def test_probe_colours_see_the_surface_not_the_air():
    """Half-space z < 0 is red and dense, the air above is blue and empty: probing a vertex on z = 0
    along its normal (+z) gives red; with probe_m = 0 the colour at the vertex itself."""

    def radiance(x, d):
        dense = x[:, 2] < 0
        sigma = torch.where(dense, 200.0, 0.0)
        rgb = torch.where(dense[:, None], torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0]))
        return sigma, rgb

    p = torch.tensor([[0.3, 0.2, 0.0], [1.0, -2.0, 0.0]])
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    rgb = M.probe_colours(radiance, p, n, probe_m=0.1, samples=16)
    assert torch.allclose(rgb, torch.tensor([1.0, 0.0, 0.0]).expand(2, 3), atol=1e-3)
    at = M.probe_colours(radiance, p + torch.tensor([0.0, 0.0, 0.01]), n, probe_m=0.0, samples=16)
    assert torch.allclose(at, torch.tensor([0.0, 0.0, 1.0]).expand(2, 3))
