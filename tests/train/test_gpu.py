"""CPU and CUDA agree (skipped without a CUDA device)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.testing import assert_close

from nsim.train.scene import SceneTrainer
from tests.train.test_scene import micro_cfg


@pytest.mark.gpu
def test_cpu_and_cuda_agree_on_a_fixed_batch(tiny_data):
    cfg = micro_cfg(optim={"mixed_precision": False})
    cpu = SceneTrainer(tiny_data, cfg, device="cpu", seed=0)
    gpu = SceneTrainer(tiny_data, cfg, device="cuda", seed=0)
    gpu.model.load_state_dict(cpu.model.state_dict())
    rays_c, target_c, _ = cpu.batch(7)
    rays_g, target_g, _ = gpu.batch(7)
    assert_close(rays_g.origins.cpu(), rays_c.origins)
    assert_close(target_g.cpu(), target_c)
    with torch.no_grad():
        out_c = cpu.model.render_proposal(rays_c)
        out_g = gpu.model.render_proposal(rays_g)
    assert_close(out_g.rgb.cpu(), out_c.rgb, atol=1e-4, rtol=1e-4)
    assert_close(out_g.depth.cpu(), out_c.depth, atol=1e-3, rtol=1e-4)
    # one training step each from the same weights: the same loss
    loss_c = cpu.train_step().loss
    loss_g = gpu.train_step().loss
    assert abs(loss_c - loss_g) < 1e-4 * max(1.0, abs(loss_c))


@pytest.mark.gpu
def test_mixed_precision_trains(tiny_data):
    cfg = micro_cfg(optim={"mixed_precision": True, "steps": 3})
    tr = SceneTrainer(tiny_data, cfg, device="cuda", seed=0)
    assert tr.amp
    losses = [tr.train_step().loss for _ in range(3)]
    assert all(np.isfinite(losses))
