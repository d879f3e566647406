"""Stages: plain functions ``run(inputs, cfg, ctx) -> outputs`` over the workspace.

Each stage module defines ``STAGE`` (its name in manifests), ``VERSION`` (bumped when its
output would change for the same inputs), a frozen ``Config`` dataclass, an ``Inputs``
dataclass of artifact ids, ``run`` and ``rebuild``. ``rebuild(manifest, ctx)`` re-runs the
stage from what a manifest records; ``nsim verify --rebuild`` uses it to check that an
artifact is reproducible.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from nsim.errors import WorkspaceError

# stage name (as written in manifests) -> module
STAGE_MODULES: dict[str, str] = {
    "capture": "nsim.stages.capture",
    "reconstruct": "nsim.stages.reconstruct",
    "train_scene": "nsim.stages.train_scene",
    "train_human": "nsim.stages.train_human",
    "simulate": "nsim.stages.simulate",
    "render": "nsim.stages.render",
    "evaluate": "nsim.stages.evaluate",
    "export": "nsim.stages.export",
    "import-log": "nsim.stages.import_log",
    "register-log": "nsim.stages.register_log",
    "bake": "nsim.stages.bake",
}


def stage_module(stage: str) -> ModuleType:
    try:
        name = STAGE_MODULES[stage]
    except KeyError:
        raise WorkspaceError(f"no stage named {stage!r} in this version of nsim") from None
    return importlib.import_module(name)
