"""The people of a simulated run in a render: posed from the trajectory, culled, composited with the scene.

``HumanSet`` holds the run's people (a ``trajectory`` of ``nsim simulate``: per tick and person
``position_m (T, P, 2)``, ``heading_rad (T, P)``, ``gait_phase (T, P)``, per person ``height_m (P,)``
and optionally ``motion (P,)`` and ``appearance (P,)``) and the human checkpoints that draw them
(``person_checkpoints``: the one a person's scenario entry names, else checkpoint k mod M). Per frame:

1. ``joint_transforms`` / ``joint_transforms_at``: each person still in the run posed by its gait
   loop (``nsim.human.person_motion.person_loop``: nsim's clip its ``motion`` names, or the recorded clip
   the run's arrays hold for it, ``person_clips``) and skeleton, at a tick or between ticks;
2. ``visible``: the paper's Algorithm 1, corrected (``nsim.rendering.culling``): the people whose
   posed box the sensor's rays can see, with the rays to cast their samples on (``PersonView``);
3. ``composite`` (settings: ``CompositeConfig``): the scene's samples and every visible person's merged in
   depth order, one volume
   rendering over both (``nsim.volume.compositing``, the human trainer's compositing too); the
   instance id of a ray is the person holding more than half its weight.

Used by ``nsim.rendering.shard`` (``nsim render``) and, for the ground truth of the same poses,
``nsim.evaluation.oracle_truth``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.errors import InputError, NsimError

if TYPE_CHECKING:
    from torch import Tensor

    from nsim.human.nerf import HumanModel
    from nsim.rendering.march_config import MarchConfig

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, eq=False)
class PersonView:
    """One person a sensor's rays can see (``HumanSet.visible``), as ``HumanSet.composite`` draws it."""

    k: int
    """The person's index in the trajectory (its column in ``position_m``); its instance id is ``k + 1``."""
    joint_transforms: np.ndarray
    """``(J, 4, 4)`` joint-to-world transforms of the posed skeleton (``HumanSet.joint_transforms``)."""
    model: HumanModel
    """The human checkpoint that draws the person (``HumanSet.model_index``)."""
    ray_mask: Tensor
    """``(N,)`` bool: the rays the person's samples are cast on (all N rays of the sensor)."""


@dataclasses.dataclass(frozen=True)
class CompositeConfig:
    """What ``HumanSet.composite`` needs of the render's settings (``nsim.rendering.render_plan.RenderConfig``
    holds these fields under the same names)."""

    method: str
    """How the scene is rendered along the rays: ``proposal``, ``march`` (or ``baked``, given ``scene_out``)."""
    march: MarchConfig
    """``method: march``: its step and early termination."""
    chunk_rays: int
    """Rays rendered per batch."""
    culling: bool
    """A person's samples only where the ray meets its posed box (the same images, faster)."""


def default_checkpoint(k: int, n_models: int) -> int:
    """The checkpoint that draws person ``k`` when no scenario names one: ``k mod M``."""
    return k % n_models


def person_checkpoints(appearance, human_ids, find, source: str = "trajectory") -> list[int]:
    """Which of a render's human checkpoints draws each person: ``(P,)`` indices into ``human_ids``.

    appearance: per person, the scenario's ``humans[k].appearance`` (a human-checkpoint ref or id; ``""`` or
    None: none named); human_ids: the render's checkpoints (ids, in ``--humans`` order); find: a name -> its
    artifact id, or None when the workspace has nothing of that name (``Store.find``; raising ``NsimError`` for
    an ambiguous or dangling one). A person whose name is found is drawn by that checkpoint, which must be among
    ``human_ids``; the others by checkpoint ``k mod M``. A name the workspace does not have is only a warning
    (scenario files travel between workspaces: ``nsim tag ID human/ana`` gives it a meaning here). A
    checkpoint not among ``human_ids``, or a bad name, is one ``InputError`` line naming ``source`` and the
    person."""
    ids = list(human_ids)
    if not ids:
        raise InputError(f"{source}: people need at least one human checkpoint (--humans)")
    out, unknown = [], []
    for k, name in enumerate(appearance):
        name = "" if name is None else str(name)
        try:
            hid = find(name) if name else None
        except NsimError as err:  # ambiguous, a ref to a missing artifact, another kind
            raise InputError(f"{source}: humans[{k}].appearance {name!r}: {err}") from None
        if hid is None:
            if name:
                unknown.append(f"humans[{k}] {name!r}")
            out.append(default_checkpoint(k, len(ids)))
            continue
        if hid not in ids:
            raise InputError(f"{source}: humans[{k}].appearance {name!r} is human checkpoint {hid[:12]}, which is "
                             f"not among the render's --humans ({', '.join(i[:12] for i in ids)}): add it")
        out.append(ids.index(hid))
    if unknown:
        log.warning("%s: no human checkpoint in this workspace is named %s: drawn by checkpoint k mod %d instead "
                    "(nsim tag ID NAME names one)", source, ", ".join(unknown), len(ids))
    return out


class HumanSet:
    """The trajectory's people, each drawn by a human checkpoint: person k by ``models[person_model[k]]``
    (``person_checkpoints``; None: checkpoint k mod M)."""

    def __init__(self, models: list, arrays: dict[str, np.ndarray], device, person_model=None) -> None:
        self.models = models
        self.arrays = arrays
        self.device = device
        self.person_model = None if person_model is None else [int(m) for m in person_model]
        self._loops: dict[tuple[str, int, float], Any] = {}
        self._clips: list | None = None  # per person: its recorded clip or None (read from the arrays once)

    @classmethod
    def load(cls, human_dirs: Sequence[str | Path], trajectory_file: str | Path | None, device,
             person_model: Sequence[int] | None = None) -> HumanSet:
        from nsim.human.nerf import load_human_model

        if trajectory_file is None:
            raise InputError("render: human checkpoints need a trajectory (people come from nsim simulate)")
        from nsim.io.npz import read_npz

        arrays = read_npz(Path(trajectory_file))
        return cls([load_human_model(d, device=device).eval() for d in human_dirs], arrays, device, person_model)

    def model_index(self, k: int) -> int:
        """The checkpoint (index into the render's human checkpoints) that draws person ``k``."""
        return self.person_model[k] if self.person_model is not None else default_checkpoint(k, len(self.models))

    def _loop(self, k: int, height: float):
        """The gait loop that poses person ``k`` (``height`` m tall): its recorded clip from the run's arrays, else
        nsim's clip its ``motion`` names (a name this nsim does not draw: the walk, with a warning)."""
        from nsim.human.gait import DEFAULT_CLIPS
        from nsim.human.person_motion import person_clips, person_loop

        a = self.arrays
        if self._clips is None:
            self._clips = person_clips(a, int(np.asarray(a["height_m"]).shape[0]))
        clip = self._clips[k]
        motion = str(a["motion"][k]) if "motion" in a else "walk"
        key = (motion, -1 if clip is None else int(a["motion_clip"][k]), round(height, 3))
        if key not in self._loops:
            name = motion if clip is not None or motion in DEFAULT_CLIPS else "walk"
            if name != motion:  # a run simulated before scenarios refused unknown motions
                log.warning("people: motion %r is not one of %s; drawn with the walk", motion, ", ".join(DEFAULT_CLIPS))
            self._loops[key] = person_loop(name, clip, height)
        return self._loops[key]

    def joint_transforms(self, tick: int) -> list[tuple[int, np.ndarray]]:
        """``[(person k, joint_transforms (J, 4, 4))]`` at a tick, for people still in the run."""
        a = self.arrays
        return self._posed(a["position_m"][tick], a["heading_rad"][tick], a["gait_phase"][tick])

    def joint_transforms_at(self, time_s: float) -> list[tuple[int, np.ndarray]]:
        """``[(person k, joint_transforms (J, 4, 4))]`` at simulation time ``time_s``, between ticks too
        (``nsim.rendering.recording.people_states_at``; on a tick: ``joint_transforms(tick)``); nobody
        outside the run's span."""
        from nsim.rendering.recording import people_states_at

        a = self.arrays
        present, pos, head, phase = people_states_at(a["time_s"], a["position_m"], a["heading_rad"], a["gait_phase"],
                                                     time_s)
        return self._posed(pos, head, phase)

    def _posed(self, position_m: np.ndarray, heading_rad: np.ndarray, gait_phase: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Every person with a finite ``position_m (P, 2)`` posed by its gait loop at ``heading_rad (P,)`` and
        ``gait_phase (P,)``: ``[(person k, joint_transforms (J, 4, 4))]``."""
        from nsim.human.skeleton import forward_kinematics

        a = self.arrays
        out = []
        for k in range(len(position_m)):
            pos = position_m[k]
            if not np.isfinite(pos).all():
                continue
            loop = self._loop(k, float(a["height_m"][k]))
            root, quats = loop.pose_at(np.array([gait_phase[k]]), pos[None], np.array([heading_rad[k]]))
            T = forward_kinematics(loop.skeleton, quats[0], root[0])
            out.append((k, T))
        return out

    def visible(self, posed: list[tuple[int, np.ndarray]], origins: Tensor, dirs: Tensor, camera, cam_to_world,
                culling: bool, t_min: float = 0.0, t_max: float = math.inf, valid=None) -> list[PersonView]:
        """Of the ``posed`` people (``joint_transforms``), those whose posed box the rays ``origins, dirs (N, 3)``
        can see, with the ray mask to cast their samples on.

        With ``culling`` a person is dropped when the box's image rectangle misses a camera's frame
        (the cheap test, first), then when no ray meets the box within ``[t_min, t_max]`` m (the
        sensor's range) among the ``valid (N,)`` rays; the mask keeps the rays that meet it."""
        import torch

        from nsim.rendering.culling import (
            OrientedBox,
            camera_box_bounds,
            lidar_ray_box_mask,
            pixels_in_bounds,
        )

        people = []
        o = d = None
        for k, T in posed:
            model = self.models[self.model_index(k)]
            with torch.no_grad():
                lo, hi = model.posed_box(torch.as_tensor(T, dtype=torch.float32)).reshape(2, 3).cpu().numpy()
            box = OrientedBox.from_min_max(lo.astype(np.float64), hi.astype(np.float64), np.eye(4))
            inside = None
            if culling and camera is not None and cam_to_world is not None:
                bounds = camera_box_bounds(camera, np.linalg.inv(cam_to_world), box)
                if bounds is None:
                    continue
                inside = pixels_in_bounds(camera, bounds)
            if o is None:
                o = origins.cpu().numpy().astype(np.float64)
                d = dirs.cpu().numpy().astype(np.float64)
            mask = lidar_ray_box_mask(o, d, box, t_min, t_max)  # exact ray-box test within the sensor's range
            if valid is not None:
                mask &= np.asarray(valid, dtype=bool)
            if inside is not None:
                mask &= inside
            if culling and not mask.any():
                continue
            people.append(PersonView(k=k, joint_transforms=T, model=model,
                                     ray_mask=torch.as_tensor(mask if culling else np.ones_like(mask))))
        return people

    def composite(self, scene_model, grid, rays, people: list[PersonView], cfg: CompositeConfig, scene_out=None):
        """Scene samples + every person's samples on its rays, merged in depth order; one volume
        rendering over both. Returns (RenderOutput, instance ids (N,) uint16).

        rays: the sensor's N rays; people: ``visible``'s. cfg: ``method``, ``march``, ``chunk_rays`` (the
        scene's rendering) and ``culling`` (the people's box test). scene_out: the scene already rendered
        along ``rays`` with its samples (e.g. from a baked scene, ``nsim.rendering.baked.render_baked``);
        None renders ``scene_model`` here."""
        import torch

        from nsim.rendering.renderer import render_rays
        from nsim.volume.compositing import composite_sets, set_weights
        from nsim.volume.samples import RaySamples

        n = len(rays)
        if scene_out is None:
            scene_out = render_rays(scene_model, rays, cfg.method, grid, cfg.march, cfg.chunk_rays, return_samples=True)
        any_mask = torch.zeros(n, dtype=torch.bool)
        for p in people:
            any_mask |= p.ray_mask
        idx = torch.nonzero(any_mask, as_tuple=True)[0]
        out = scene_out
        instance = np.zeros(n, dtype=np.uint16)
        if len(idx):
            sub = rays[idx]
            parts = [RaySamples(*(getattr(scene_out.samples, f)[idx] for f in ("t_starts", "t_ends", "sigma", "rgb")))]
            live = torch.zeros(len(idx), dtype=torch.bool)  # rays where some person has a sample of non-zero length
            for p in people:
                m = p.ray_mask[idx]
                with torch.no_grad():  # the model's parameters require grad; rendering needs none
                    hs = p.model.render_samples(sub.origins, sub.dirs,
                                                torch.as_tensor(p.joint_transforms, dtype=torch.float32),
                                                sub.near, sub.far, box_test=cfg.culling)
                sig = torch.where(m[:, None], hs.sigma, 0.0)
                live |= m & (hs.t_ends > hs.t_starts).any(-1)
                parts.append(RaySamples(hs.t_starts, hs.t_ends, sig, hs.rgb))
            # a ray that no person's samples reach keeps the scene's own rendering, bit for bit (re-compositing
            # the same samples after a merge can round differently): culling on or off, the same image
            parts = [RaySamples(*(getattr(q, f)[live] for f in ("t_starts", "t_ends", "sigma", "rgb"))) for q in parts]
            idx = idx[live]
        if len(idx):
            # set 0 the scene's samples, set j + 1 person people[j]'s: the trainer's compositing (render_merged)
            comp, source = composite_sets(*parts, background_rgb=scene_out.background[idx])  # the scene's background
            # instance: the person holding the most weight on the ray, if they hold more than half
            per = set_weights(comp.weights, source, len(parts))  # (1 + people, R)
            per[0] = 0.0  # the scene is no instance
            best = per.argmax(0)
            strong = per.max(0).values > 0.5
            ids = torch.tensor([0] + [p.k + 1 for p in people])[best]
            instance[idx.numpy()] = torch.where(strong, ids, 0).numpy().astype(np.uint16)
            for f in ("rgb", "depth", "depth_median", "accumulation"):
                getattr(out, f)[idx] = getattr(comp, f)
        return out, instance
