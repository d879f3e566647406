"""The demo pipeline end to end at tiny size (what `make demo` runs at default size)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from nsim.workspace.store import Store

REPO = Path(__file__).resolve().parents[1]
# Only a guard against a hung run, never a speed check: the tiny demo takes ~5 min on 2 quiet cores and over 10
# on a busy laptop; CI allows 90 min for everything.
DEMO_TIMEOUT_S = 3600
_spec = importlib.util.spec_from_file_location("demo_ids", REPO / "scripts" / "demo_ids.py")
demo_ids = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(demo_ids)


@pytest.mark.slow
def test_demo_runs_every_stage_and_ends_with_ls(tmp_path):
    ws = tmp_path / "ws"
    cmd = [sys.executable, str(REPO / "pipelines" / "demo.py"), "--preset", "tiny", "--workspace", str(ws)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=DEMO_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr
    assert "nsim workspace" in proc.stdout
    store = Store(ws)
    kinds = sorted({a.kind for a in store.artifacts()})
    assert kinds == ["baked-scene", "capture", "evaluation", "export", "human-checkpoint", "poses", "recording", "render",
                     "scene-checkpoint", "trajectory"]
    for art in store.artifacts():
        assert store.verify(art.id) == []
    # Spot's run twice, from the NeRF and from the baked scene: the same frames and sensors
    runs = [json.loads(store.get(store.resolve(f"render/{r}")).file("render.json").read_text())
            for r in ("demo-spot-run", "demo-spot-run-baked")]
    assert runs[0]["frames"] and [f["index"] for f in runs[0]["frames"]] == [f["index"] for f in runs[1]["frames"]]
    assert [sorted(p) for p in runs[0]["per_frame"]] == [sorted(p) for p in runs[1]["per_frame"]]
    assert "from the baked scene in" in proc.stdout
    # the bit-stable stages' artifacts are those committed in tests/data/demo_ids.json, on any machine (their
    # content always; their ids too under the same code fingerprint): scripts/demo_ids.py regenerates the file
    expected = json.loads((REPO / "tests" / "data" / "demo_ids.json").read_text())
    assert {r["stage"] for r in expected["refs"].values()} >= {"capture", "simulate", "import-log"}
    diff = demo_ids.differences(expected, demo_ids.collect(ws))
    assert not diff, "the tiny demo's bit-stable artifacts changed (scripts/demo_ids.py):\n" + "\n".join(diff)
    # a rerun is all cache hits and publishes nothing new
    before = store.all_ids()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=DEMO_TIMEOUT_S)
    assert proc.returncode == 0 and store.all_ids() == before
