"""nsim.train.heap: large blocks from the heap (glibc), with no change to any value."""

import subprocess
import sys

import pytest

CHILD = r"""
import ctypes, resource, sys
import torch
from nsim.train.heap import keep_large_blocks_on_heap
def faults(n=20):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(n):
        t = torch.zeros(12 * 1024 * 1024)  # 48 MiB: above glibc's largest mmap threshold
        t += 1.0
        del t
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
mmapped = faults()
on = keep_large_blocks_on_heap()
faults(2)  # the first heap block is faulted in once
heap = faults()
print(on, mmapped, heap)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_large_blocks_stop_faulting_in_fresh_pages():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True).stdout.split()
    on, mmapped, heap = out[0] == "True", int(out[1]), int(out[2])
    if not on:
        pytest.skip("this C library refused mallopt(M_MMAP_MAX, 0)")
    # 20 fresh 48 MiB blocks fault in about 20 x 12288 pages; reused heap blocks almost none
    assert mmapped > 20 * 6000
    assert heap < mmapped / 20


def test_idempotent():
    from nsim.train.heap import keep_large_blocks_on_heap

    assert keep_large_blocks_on_heap() == keep_large_blocks_on_heap()
