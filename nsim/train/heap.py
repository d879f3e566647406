"""Keep large CPU tensors on the heap instead of fresh ``mmap`` pages (glibc).

glibc serves an allocation above its mmap threshold (at most 32 MiB) with a fresh ``mmap``
and returns it to the kernel on ``free``. A training step on the CPU allocates and frees
gradient buffers the size of the hash tables (a 2^19-row, 2-feature table is 36 MiB), so with
large tables every step paid for tens of thousands of page faults, each a zero-filled page:
measured on the test room with ``log2_table_size`` 19 (the ``cpu`` preset, 2 cores), a step went
from 101.7 to 81.5 ms. With mmap off (``M_MMAP_MAX = 0``) such blocks come from the
heap and are reused step after step (free memory at the heap's top is kept up to 512 MiB
rather than returned at once). It changes no value, only where memory comes from.
"""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters: free memory at the heap's top kept, not returned
M_MMAP_MAX = -4  # the most blocks served by mmap at once
TRIM_THRESHOLD_BYTES = 512 * 1024 * 1024
_state: bool | None = None


def keep_large_blocks_on_heap() -> bool:
    """Ask glibc to serve every allocation from the heap; returns whether that is in effect.

    Process-wide and idempotent. A no-op (``False``) off Linux or on a C library without
    ``mallopt`` (musl).
    """
    global _state
    if _state is not None:
        return _state
    _state = False
    if sys.platform.startswith("linux"):
        try:
            mallopt = ctypes.CDLL(None).mallopt
        except (OSError, AttributeError):
            return _state
        mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
        mallopt.restype = ctypes.c_int
        # a freed block at the top of the heap would be handed back at once and faulted in again
        # next step: keep up to TRIM_THRESHOLD_BYTES of free top
        _state = bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)) and bool(mallopt(M_MMAP_MAX, 0))
        if not _state:
            log.debug("mallopt was refused; large blocks stay on mmap")
    return _state
