"""Resume checkpoints (``nsim.train.checkpoint``): weights-only, so a planted file runs no code."""

from __future__ import annotations

import logging
import pickle

import numpy as np
import pytest
import torch

from nsim.train.checkpoint import CheckpointError, load_checkpoint, resume, save_checkpoint

from .conftest import BAD_CHECKPOINTS


def test_planted_payload_is_live(plant_checkpoint, tmp_path):
    """The payload the other tests plant really runs code when unpickled the old way."""
    marker = tmp_path / "pwned"
    path = plant_checkpoint(tmp_path / "last.pt", "pickle_exec", marker)
    pickle.loads(path.read_bytes())
    assert marker.exists()
    marker.unlink()
    torch.load(plant_checkpoint(tmp_path / "last2.pt", "torch_save_exec", marker), weights_only=False)
    assert marker.exists()


@pytest.mark.parametrize("kind", BAD_CHECKPOINTS)
def test_bad_checkpoint_is_refused_without_running_code(plant_checkpoint, tmp_path, kind):
    marker = tmp_path / "pwned"
    path = plant_checkpoint(tmp_path / "last.pt", kind, marker)
    with pytest.raises(CheckpointError, match="last.pt"):
        load_checkpoint(path)
    assert not marker.exists()


def test_round_trip_and_atomic_write(tmp_path):
    state = {"format": 1, "step": 7, "t": torch.arange(4.0), "betas": (0.9, 0.999), "h": [{"loss": 0.5}], "none": None,
             "rng": torch.get_rng_state()}
    save_checkpoint(state, tmp_path / "d" / "last.pt")
    assert [p.name for p in (tmp_path / "d").iterdir()] == ["last.pt"]  # no temp file left
    back = load_checkpoint(tmp_path / "d" / "last.pt")
    assert back.keys() == state.keys() and back["betas"] == (0.9, 0.999) and back["h"] == [{"loss": 0.5}]
    assert torch.equal(back["t"], state["t"]) and torch.equal(back["rng"], state["rng"])


@pytest.mark.parametrize("bad", [np.zeros(3), np.float64(1.0), {1.5j: 1}, {"x": object()}])
def test_save_refuses_what_weights_only_cannot_read(tmp_path, bad):
    with pytest.raises(TypeError, match="checkpoint state"):
        save_checkpoint({"format": 1, "bad": bad}, tmp_path / "last.pt")
    assert not list(tmp_path.iterdir())


def test_resume_warns_and_starts_fresh(plant_checkpoint, tmp_path, caplog):
    class Trainer:
        step = 0

        def load_checkpoint(self, path):
            self.step = int(load_checkpoint(path)["step"])

    marker = tmp_path / "pwned"
    path = plant_checkpoint(tmp_path / "last.pt", "torch_save_exec", marker)
    with caplog.at_level(logging.WARNING, logger="nsim.train.checkpoint"):
        trainer, resumed = resume(Trainer, path)
    assert resumed is None and trainer.step == 0 and not marker.exists()
    assert any(r.levelno == logging.WARNING and str(path) in r.getMessage() for r in caplog.records)
    assert resume(Trainer, tmp_path / "absent.pt")[1] is None
