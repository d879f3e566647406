"""What every stage does the same way: the run-cache check, the device in the key, rebuilding, the scene input.

Not a stage: the stages' shared plumbing, so that each stage file only reads, calls the core and publishes.

``cached(ctx, key)``
    The artifact already published under ``key`` (the run cache), unless the run is forced: a stage with a
    hit returns at once.
``device_kind(device)``
    ``"cuda"`` or ``"cpu"``: what a stage whose output depends on the device puts into its action key
    (``cuda:1`` and ``cuda:0`` give the same bytes, a CPU and a GPU may not).
``rerun(run, inputs, config_type, manifest, ctx)``
    A stage run again, forced, with the config its manifest records: the body of every stage's ``rebuild``
    (``nsim verify --rebuild``).
``SceneInputs`` and ``resolve_scene``
    The one input of the stages that read a trained scene (``bake``, ``export``): a scene-checkpoint id.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, TypeVar

from nsim.config import from_dict
from nsim.context import RunContext
from nsim.errors import InputError

O = TypeVar("O")  # noqa: E741  (a stage's Outputs)
I = TypeVar("I")  # noqa: E741  (a stage's Inputs)


def cached(ctx: RunContext, key: str) -> str | None:
    """The id of the artifact published under action ``key``, or None (none yet, or ``ctx.force``)."""
    if ctx.force:
        return None
    hit = ctx.store.lookup(key)
    return None if hit is None else hit.id


def device_kind(device: str) -> str:
    """``"cuda"`` for any CUDA device (``cuda``, ``cuda:1``), else ``"cpu"``."""
    return "cuda" if str(device).startswith("cuda") else "cpu"


def rerun(run: Callable[[I, Any, RunContext], O], inputs: I, config_type: type, manifest: dict[str, Any],
          ctx: RunContext) -> O:
    """``run(inputs, the manifest's config, ctx forced)``: the stage's work done again, the run cache bypassed."""
    return run(inputs, from_dict(config_type, manifest["config"]), dataclasses.replace(ctx, force=True))


@dataclasses.dataclass(frozen=True)
class SceneInputs:
    """scene: a scene-checkpoint id, prefix or ref."""

    scene: str

    def ids(self) -> dict[str, str]:
        return {"scene": self.scene}


def resolve_scene(spec: str, ctx: RunContext, stage: str, files: tuple[str, ...] = ()) -> str:
    """The id of the scene checkpoint ``spec`` names; InputError naming ``stage`` if it is another kind of artifact
    or lacks one of ``files``."""
    store = ctx.store
    art_id = store.resolve(spec)
    art = store.get(art_id)
    if art.kind != "scene-checkpoint":
        raise InputError(f"{stage} {spec}: a {art.kind} artifact; {stage} needs a scene-checkpoint (nsim train-scene)")
    for name in files:
        if not (art.path / name).is_file():
            raise InputError(f"{stage} {spec}: scene {art_id[:12]} has no {name} to {stage} over")
    return art_id
