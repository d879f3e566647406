"""Stages: plain functions ``run(inputs, cfg, ctx) -> outputs`` over the workspace.

Each stage module defines ``STAGE`` (its name in manifests), ``VERSION`` (bumped when its
output would change for the same inputs), a frozen ``Config`` dataclass, an ``Inputs``
dataclass of artifact ids, ``run`` and ``rebuild``. ``rebuild(manifest, ctx)`` re-runs the
stage from what a manifest records; ``nsim verify --rebuild`` uses it to check that an
artifact is reproducible. ``BIT_STABLE`` below says which stages give the same bytes on every CPU.
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


# stage name -> (whether the same inputs give the same bytes on any CPU, why): measured by bench/reproducible.py
# under other CPU code paths (torch's ATEN_CPU_CAPABILITY, numpy's NPY_DISABLE_CPU_FEATURES, OpenCV's optimised
# paths off, one thread); the others are judged by nsim.workspace.compare's tolerances in `nsim verify --rebuild`
BIT_STABLE: dict[str, tuple[bool, str]] = {
    "capture": (True, "float64 ray casting; 8-bit images; poses written rounded (nsim.io.canonical)"),
    "simulate": (True, "float64 crowd; trajectory, TUM and metrics written rounded"),
    "import-log": (True, "a log's bytes decoded and written"),
    "register-log": (True, "trajectory alignment, written rounded"),
    "evaluate": (True, "metrics of the same renders, written rounded"),
    "reconstruct": (False, "SfM and its bundle adjustment (pycolmap, Ceres)"),
    "train_scene": (False, "training in torch"),
    "train_human": (False, "training in torch"),
    "bake": (False, "a mesh and texture fitted by gradient descent in torch"),
    "render": (False, "NeRF inference in torch"),
    "export": (False, "the NeRF read through torch: its last bits move vertices by ~0.1 mm"),
}


def bit_stable_stages() -> dict[str, bool]:
    """Stage name (as in manifests) -> whether its artifacts repeat bit for bit across CPUs (``BIT_STABLE``)."""
    return {stage: BIT_STABLE[stage][0] for stage in STAGE_MODULES}


def content_digest(files: dict) -> str:
    """One digest of an artifact's files (a manifest's ``files``: path -> sha256 and size): its content alone,
    without the code fingerprint, config or input ids that also enter the artifact id."""
    import hashlib

    from nsim.config import canonical_json

    return hashlib.sha256(canonical_json({k: v["sha256"] for k, v in sorted(files.items())})).hexdigest()


def stable_ids(store, refs: dict[str, str]) -> dict[str, dict[str, str]]:
    """``ref -> {stage, id, content}`` for the refs whose artifacts come from bit-stable stages (``BIT_STABLE``) on
    bit-stable inputs all the way up (an evaluation of a trained scene's render is not): what a fresh run on any
    machine must reproduce (``tests/data/demo_ids.json``, ``scripts/demo_ids.py``)."""
    stable = bit_stable_stages()
    memo: dict[str, bool] = {}

    def repeats(art_id: str) -> bool:  # its stage and every stage upstream of it bit-stable
        if art_id not in memo:
            m = store.get(art_id).manifest
            memo[art_id] = bool(stable.get(m["stage"])) and all(repeats(i) for i in m.get("inputs", {}).values())
        return memo[art_id]

    out = {}
    for name, art_id in sorted(refs.items()):
        if repeats(art_id):
            m = store.get(art_id).manifest
            out[name] = {"stage": m["stage"], "id": art_id, "content": content_digest(m["files"])}
    return out
