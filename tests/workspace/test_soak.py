"""The workspace under a short kill soak: writers, gc --grace 0 and SIGKILLs, then a full check.

Runs ``bench/workspace.py --quick`` (tiny throughput figures, then its 10 s soak) and
reads its last line; the bench itself checks refs, objects, lineage and a republish sample.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_soak_loses_nothing():
    r = subprocess.run([sys.executable, str(REPO / "bench" / "workspace.py"), "--quick"],
                       capture_output=True, text=True, timeout=1800, cwd=REPO)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert (out["lost"], out["tracebacks"], out["unrecoverable"]) == (0, 0, 0), r.stdout[-4000:]
    assert out["publishes"] > 0 and out["gc_runs"] > 0 and out["kills"] > 0, r.stdout[-4000:]
    assert out["soak_s"] < 10 + 120  # the loop ends at its deadline; a busy machine delays the last kill
