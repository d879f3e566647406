"""The default look: how ``nsim render`` draws a person whose scenario names no appearance.

A person of a run is drawn by a human checkpoint (``nsim train-human``) when the scenario's
``humans[k].appearance`` names one (or ``--humans`` gives them). One with no appearance, or a
name this workspace does not hold, is drawn as the test room's mannequin (``nsim.synth.actor.Actor``
with appearance seed ``DEFAULT_LOOK_SEED``, at the person's height), ray cast exactly and lit by the
test room's default lights without its lamp (``nsim.synth.raycast.DEFAULT_LIGHTING``). The render
says so in one warning line and records the people it drew this way (``render.json``'s summary).

``DefaultLook`` speaks the human checkpoint's rendering interface (``posed_box``, ``render_samples``,
``nsim.human.nerf.HumanModel``), so the compositor (``nsim.rendering.people``) merges it with the
scene like any person: each ray that meets the mannequin gets one thin, opaque sample at the hit
(``SHELL_M`` thick), in depth order with the scene's samples.

In a run's people, ``DEFAULT_LOOK`` (-1) stands for the default look where a person's checkpoint
index would be (``ShardJob.person_model``); ``people_models`` turns that into models.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

DEFAULT_LOOK = -1
"""A person's checkpoint index meaning "the default look" (``ShardJob.person_model``)."""
DEFAULT_LOOK_SEED = 0
"""The mannequin's appearance seed (``nsim.synth.actor.Actor``): its clothes, skin, hair and print."""
DEFAULT_LOOK_NAME = "default look"
"""How ``render.json``'s ``people_checkpoints`` names it."""
SHELL_M = 0.002
"""Thickness of the opaque sample each ray gets at the mannequin's surface."""
SHELL_OPTICAL_DEPTH = 30.0
"""``sigma * SHELL_M`` of that sample: its opacity is ``1 - exp(-30)``, i.e. 1."""


class DefaultLook:
    """The mannequin of height ``height_m`` (see the module docstring), drawn through the human model's interface."""

    def __init__(self, height_m: float, seed: int = DEFAULT_LOOK_SEED) -> None:
        from nsim.synth.actor import Actor

        self.actor = Actor(height_m, seed=seed)
        self.height_m = float(height_m)

    def posed_box(self, joint_transforms):
        """World box ``(1, 2, 3)`` (lo, hi) around every part at the pose ``(J, 4, 4)``."""
        import torch

        lo, hi = self.actor.bounding_box(_as_pose(joint_transforms))
        return torch.as_tensor(np.stack([lo, hi])[None], dtype=torch.float32)

    def render_samples(self, origins, dirs, joint_transforms, near=0.0, far=1e4, box_test: bool = True, **_):
        """One sample per ray ``(R, 1)``: opaque at the mannequin's surface where the ray meets it within
        ``[near, far]``, empty (``t_starts == t_ends == near``) elsewhere. ``box_test`` is accepted for the
        interface: the ray cast always culls by the box, which never changes the result."""
        import torch

        from nsim.volume.samples import RaySamples

        o = origins.detach().cpu().numpy().astype(np.float64)
        d = dirs.detach().cpu().numpy().astype(np.float64)
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        n = o.shape[0]
        near_t = np.broadcast_to(np.asarray(near.detach().cpu() if hasattr(near, "detach") else near,
                                            dtype=np.float64).reshape(-1), (n,))
        far_t = np.broadcast_to(np.asarray(far.detach().cpu() if hasattr(far, "detach") else far,
                                           dtype=np.float64).reshape(-1), (n,))
        hits = self.actor.intersect(o, d, _as_pose(joint_transforms))
        hit = hits.hit & (hits.t >= near_t) & (hits.t <= far_t)
        t0 = np.where(hit, hits.t, near_t)
        t1 = np.where(hit, hits.t + SHELL_M, near_t)
        sigma = np.where(hit, SHELL_OPTICAL_DEPTH / SHELL_M, 0.0)
        rgb = np.where(hit[:, None], hits.rgb, 0.0)
        dev, dt = origins.device, origins.dtype

        def col(a):
            return torch.as_tensor(np.ascontiguousarray(a), dtype=dt, device=dev)[:, None]

        return RaySamples(col(t0), col(t1), col(sigma), col(rgb))


def _as_pose(joint_transforms) -> np.ndarray:
    T = joint_transforms.detach().cpu().numpy() if hasattr(joint_transforms, "detach") else joint_transforms
    T = np.asarray(T, dtype=np.float64)
    return T.reshape(T.shape[-3:]) if T.ndim == 4 and T.shape[0] == 1 else T


def people_models(human_dirs: Sequence, person_model: Sequence[int] | None, heights_m: Sequence[float], device):
    """The models that draw a run's people and each person's index into them.

    human_dirs: the human checkpoints' folders; person_model: per person, an index into ``human_dirs`` or
    ``DEFAULT_LOOK`` (None: person k by checkpoint k mod M); heights_m: per person, its height. Returns
    ``(models, person_model)``: the checkpoints' models (in ``human_dirs`` order), then one ``DefaultLook``
    per height that needs one, and the indices into that list."""
    from nsim.human.nerf import load_human_model

    models: list = [load_human_model(d, device=device).eval() for d in human_dirs]
    if person_model is None:
        return models, None
    looks: dict[float, int] = {}
    out = []
    for k, m in enumerate(person_model):
        if int(m) != DEFAULT_LOOK:
            out.append(int(m))
            continue
        h = round(float(heights_m[k]), 3)
        if h not in looks:
            looks[h] = len(models)
            models.append(DefaultLook(h))
        out.append(looks[h])
    return models, out
