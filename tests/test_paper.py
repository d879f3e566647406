"""The paper pipeline (`make paper`), a subset end to end.

``pipelines/paper.py --size tiny`` takes several minutes on 2 CPU cores (five rooms, each trained),
over the 3 minutes a test may take, so this runs the same ``run_paper`` chain on one room with
the stages cut further (30 training steps, two held-out frames, a 12-frame actor capture and 60
steps of train-human, three Spot ticks by three cameras, rendered with the run's people) and checks
that every table comes out, the detection table with people on both sides, from the artifacts the
pipeline tags.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

from nsim.workspace.store import Store

REPO = Path(__file__).resolve().parents[1]

MICRO_TRAIN = [
    "optim.steps=30", "optim.rays_per_batch=128", "field.hash_levels=4", "field.hash_log2_table_size=10",
    "field.hidden_dim=16", "field.color_hidden_dim=16", "sampler.proposal_samples=[16,8]",
    "sampler.proposal_hash_levels=3", "sampler.proposal_hash_log2_table_size=10",
    "sampler.proposal_hash_max_resolutions=[32,64]", "sampler.proposal_hidden_dim=8", "output.occupancy_cell_m=0.3",
    "output.obstacle_cell_m=0.25",
]


def load_paper():
    spec = importlib.util.spec_from_file_location("paper_pipeline", REPO / "pipelines" / "paper.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_paper_subset_prints_every_table(tmp_path, monkeypatch):
    paper = load_paper()
    tiny = paper.SIZES["tiny"]
    micro = {
        **tiny,
        "capture": ("tiny", ["width=64", "height=48", "n_frames=24", "supersample=1", "video=false"]),
        "train_scene": ("tiny", MICRO_TRAIN),
        "heldout": ("tiny", ["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=2"]),
        "simulate": ("tiny", ["max_duration_s=2.0", "video=false"]),
        "actor": ("tiny", ["actor=true", "n_frames=12", "supersample=1", "video=false"]),
        "train_human": ("tiny", ["optim.steps=60"]),
        "spot": ("tiny", ["sensors=[frontleft,left,back]"]),
        "detection": None,
        "evaluate": ("tiny", ["lpips_net=none"]),
        "evaluate_detection": ("tiny", ["lpips_net=none"]),
    }
    monkeypatch.setitem(paper.SIZES, "micro", micro)
    monkeypatch.setattr(paper, "ROOMS", ("robot-lab",))
    out = tmp_path / "tables"
    tables = paper.run_paper(tmp_path / "ws", "micro", seed=0, device="cpu", out_dir=out)
    assert list(tables) == ["scenes", "spot-rgb", "spot-depth", "slam", "detection"]
    scenes = tables["scenes"]
    assert [r["Environment"] for r in scenes.rows] == ["robot-lab"] and scenes.rows[0]["frames"] == 2
    assert math.isfinite(scenes.rows[0]["PSNR"])
    assert [r["Camera"] for r in tables["spot-rgb"].rows] == ["frontleft", "left", "back"]
    assert [r["Camera"] for r in tables["spot-depth"].rows] == ["frontleft", "left", "back"]
    assert tables["slam"].rows[0]["Sequence"] == "left"
    detection = tables["detection"]
    assert [r["Scene"] for r in detection.rows] == ["frontleft", "left", "back", "all"]
    assert all(isinstance(r["boxes sim"], int) and isinstance(r["boxes real"], int) for r in detection.rows)
    seen = paper.people_in_view(Store(tmp_path / "ws"), "render/paper-spot-run")
    assert seen[0] > 0 and seen[1] == 9
    notes = " ".join(detection.notes)
    assert "people in view" in notes and "dressed like the actor" in notes
    for name in tables:
        assert (out / f"{name}.md").read_text().startswith("### ")
    store = Store(tmp_path / "ws")
    ids = json.loads((out / "artifacts.json").read_text())
    assert {store.get(i).kind for i in ids.values()} == {"evaluation"}
    for ref in ("capture/paper-robot-lab", "scene/paper-robot-lab", "render/paper-heldout-robot-lab",
                "capture/paper-actor-robot-lab", "human/paper-robot-lab", "render/paper-spot-run",
                "evaluation/paper-slam", "evaluation/paper-detection"):
        assert store.resolve(ref)
    # a rerun is all cache hits
    before = store.all_ids()
    paper.run_paper(tmp_path / "ws", "micro", seed=0, device="cpu", out_dir=None)
    assert store.all_ids() == before
