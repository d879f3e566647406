"""Numpy ``.npz`` archives: read without pickles, every member loaded, damage as one line.

The writer that makes them byte-identical across runs is ``save_npz_deterministic`` in
``nsim.stages.simulate``; this is the one reader for archives found in a workspace or given by a user.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from nsim.errors import InputError


def read_npz(path: Path, required: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` (object arrays refused); InputError naming the file when damaged."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: not a readable .npz archive ({exc})") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        raise InputError(f"{path}: missing array(s) {', '.join(missing)}")
    return arrays
