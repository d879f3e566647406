"""Rays: box intersection, camera rays, SE(3) exponential and pose refinement."""

from __future__ import annotations

import numpy as np
import torch
from scipy.linalg import expm
from torch.testing import assert_close

from nsim.geometry.cameras import Camera, dirs_to_world
from nsim.volume.rays import (
    PoseRefinement,
    camera_dirs,
    intersect_aabb,
    make_rays,
    se3_exp,
)


def test_intersect_aabb():
    aabb = torch.tensor([[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]])
    o = torch.tensor([[-1.0, 0.5, 0.5], [1.0, 0.5, 0.5], [-1.0, 5.0, 0.5]])
    d = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    t_in, t_out = intersect_aabb(o, d, aabb)
    assert_close(t_in[:2], torch.tensor([1.0, -0.5]))
    assert_close(t_out[:2], torch.tensor([3.0, 0.5]))
    assert t_out[2] < t_in[2]  # misses
    rays = make_rays(o, d, 0.05, 30.0, aabb)
    assert_close(rays.near, torch.tensor([1.0, 0.05, rays.near[2]]))
    assert_close(rays.far[:2], torch.tensor([3.0, 0.5]))
    assert rays.far[2] > rays.near[2]


def test_camera_rays_match_geometry_module():
    cam = Camera.pinhole_from_fov(16, 12, 70.0)
    c2w = np.eye(4)
    c2w[:3, :3] = expm(np.array([[0, -0.3, 0.2], [0.3, 0, -0.1], [-0.2, 0.1, 0]]))
    c2w[:3, 3] = [1.0, 2.0, 0.5]
    o_ref, d_ref = cam.pixel_rays(c2w)
    dirs = camera_dirs(cam).reshape(-1, 3)
    o, d = dirs_to_world(dirs, torch.tensor(c2w, dtype=torch.float32).expand(dirs.shape[0], 4, 4))
    assert_close(d.numpy(), d_ref.reshape(-1, 3).astype(np.float32), atol=1e-6, rtol=0)
    assert_close(o.numpy(), o_ref.reshape(-1, 3).astype(np.float32))


def test_se3_exp_matches_matrix_exponential():
    g = torch.Generator().manual_seed(0)
    xi = torch.randn(6, 6, generator=g, dtype=torch.float64) * 0.7
    xi[0] = 0.0
    xi[1, 3:] = 1e-9  # tiny rotation: the Taylor branch
    for k in range(xi.shape[0]):
        rho, w = xi[k, :3].numpy(), xi[k, 3:].numpy()
        twist = np.zeros((4, 4))
        twist[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
        twist[:3, 3] = rho
        assert_close(se3_exp(xi[k]), torch.tensor(expm(twist)), atol=1e-10, rtol=0)


def test_pose_refinement_starts_at_identity_and_has_gradients():
    ref = PoseRefinement(3)
    c2w = torch.eye(4).expand(4, 4, 4).clone()
    c2w[:, :3, 3] = torch.tensor([1.0, 2.0, 3.0])
    idx = torch.tensor([0, 1, 2, 1])
    out = ref(c2w, idx)
    assert_close(out, c2w)
    out[:, :3, 3].sum().backward()
    assert ref.twists.grad[:, :3].abs().sum() > 0
