"""File formats at nsim's edges: EXR, PNG, PLY, TUM (and transforms.json, COLMAP elsewhere).

Readers raise `nsim.errors.InputError` naming the file for bad input; writers write atomically.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a not-yet-existing temporary path next to `path` for the caller to write.

    On a clean exit the temporary file is fsynced and `os.replace`d onto `path`; on an exception it is
    removed. A crash never leaves a half-written file under the final name.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp{path.suffix}")
    try:
        yield tmp
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
