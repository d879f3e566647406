"""The code fingerprint: which code produced an artifact.

It enters both the action key and the artifact id, so upgrading nsim or a numerical
dependency never serves a stale cached result. Versions are read from package metadata,
which does not import the (slow) packages themselves.
"""

from __future__ import annotations

import functools
from importlib import metadata

import nsim

FINGERPRINT_PACKAGES = ("torch", "pycolmap", "numpy")


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> dict[str, str]:
    """``{"nsim": "0.1.0", "torch": "2.13.0+cpu", ...}``; missing packages read ``"absent"``."""
    out = {"nsim": nsim.__version__}
    for name in FINGERPRINT_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out
