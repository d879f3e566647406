"""Motion files onto the nsim body: ``load_motion`` reads a BVH or DeepMimic clip and retargets it.

This lives apart from ``nsim.human.motion`` (the ``MotionClip`` data type) because the readers
(``bvh``, ``deepmimic``) and ``retarget`` import that type: keeping the loader there would make
the data-type module depend on its own readers.
"""

from __future__ import annotations

import os
from pathlib import Path

from nsim.errors import InputError
from nsim.human.bvh import read_bvh
from nsim.human.deepmimic import read_deepmimic_nsim
from nsim.human.motion import MotionClip
from nsim.human.retarget import retarget
from nsim.human.skeleton import REFERENCE_HEIGHT_M, nsim_skeleton


def load_motion(path: str | os.PathLike[str], height_m: float = REFERENCE_HEIGHT_M, joint_map=None,
                unit: str | float = "auto") -> MotionClip:
    """Read a BVH (``.bvh``) or DeepMimic (``.txt`` / ``.json``) clip and retarget it to ``nsim_skeleton(height_m)``.

    joint_map: for BVH, a ``JointMap`` (or a mapping nsim joint -> source name(s)); None uses
    ``default_joint_map()`` (nsim's own names, CMU, Mixamo).
    unit: for BVH, the file's length unit (``nsim.human.bvh.UNITS_M`` names, or metres per file
    unit); "auto" measures it from the skeleton. Retargeting scales the root motion by leg
    length, so the unit changes only whether the file can be read, not the clip it gives.
    DeepMimic files are in metres: only "auto" is accepted for them.
    Bad files, and skeletons too few of whose joints map, raise ``InputError``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        return retarget(read_bvh(path, unit=unit), nsim_skeleton(height_m), joint_map)
    if suffix in (".txt", ".json"):
        if not (isinstance(unit, str) and unit == "auto"):
            raise ValueError(f"load_motion: unit applies to BVH files only; {path} is a DeepMimic clip (metres)")
        return read_deepmimic_nsim(path, height_m)
    raise InputError(f"{path}: unknown motion file type {path.suffix!r} (expected .bvh, or .txt/.json DeepMimic)")
