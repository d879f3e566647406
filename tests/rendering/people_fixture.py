"""A tiny opaque person for the tests that composite people over a scene (baked grid or surface)."""

from __future__ import annotations

import numpy as np
import torch


def opaque_person(xy: tuple[float, float]):
    """A tiny human NeRF whose density holds its rays, and its joint transforms ``(J, 4, 4)`` 0.3 s into a walk
    with its root at ``xy`` (metres)."""
    from nsim.human.gait import walk_cycle
    from nsim.human.motion import LocomotionLoop
    from nsim.human.nerf import HumanModel, HumanModelConfig
    from nsim.human.skeleton import forward_kinematics, nsim_skeleton

    cfg_h = HumanModelConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16,
                             color_hidden_dim=16, samples_per_ray=16)
    skeleton = nsim_skeleton(0.9)
    person = HumanModel(cfg_h, skeleton, torch.Generator().manual_seed(0))
    with torch.no_grad():
        person.field.density_mlp.layers[-1].bias.fill_(6.0)  # opaque: the person holds its rays
    person.eval()
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, 0.9))
    root, quats = loop.pose_at(np.array([0.3]), np.array([list(xy)]), np.array([0.0]))
    return person, forward_kinematics(skeleton, quats[0], root[0])
