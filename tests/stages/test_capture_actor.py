"""`nsim capture synth --actor`: a person walking through the test room, training data for train-human."""

from __future__ import annotations

import numpy as np

from nsim.human.data import HumanData
from nsim.workspace.store import Store


def test_capture_with_actor(tmp_path):
    from nsim.cli import main

    ws = tmp_path / "ws"
    args = ["--workspace", str(ws), "capture", "synth", "--preset", "tiny", "--actor", "--set", "n_frames=12",
            "--tag", "capture/actor"]
    assert main(args) == 0
    store = Store(ws)
    art = store.get(store.resolve("capture/actor"))
    assert art.manifest["summary"]["actor"] is True and art.manifest["summary"]["frames_with_person"] >= 10
    data = HumanData.load(art.path)
    assert data.num_frames == 12 and np.mean([data.mask(i).any() for i in range(12)]) >= 0.8
    assert main(args) == 0 and store.resolve("capture/actor") == art.id
