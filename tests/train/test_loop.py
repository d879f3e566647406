"""The trainers' shared pieces (nsim.train.loop): seeds, spreading, and the loop."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import pytest
import torch

from nsim.errors import InputError
from nsim.train.loop import ResumableTrainer, spread, step_seed, train_loop


def test_step_seed_is_sha256_of_namespace_purpose_seed_step():
    want = int.from_bytes(hashlib.sha256(b"nsim.train.scene:batch:3:17").digest()[:8], "little") >> 1
    assert step_seed("nsim.train.scene", 3, 17) == want
    assert 0 <= want < 2**63
    seeds = {step_seed(ns, 0, s, p) for ns in ("a", "b") for s in (0, 1) for p in ("batch", "init")}
    assert len(seeds) == 8  # namespace, step and purpose each change the seed


def test_spread_keeps_the_ends_and_spaces_evenly():
    assert spread(list(range(10)), 3) == [0, 4, 9]  # round(4.5) is 4
    assert spread(list(range(10)), 0) == list(range(10)) and spread([1, 2], 5) == [1, 2]
    assert spread([7, 8, 9], 1) == [7]


@dataclass
class _Stats:
    loss: float
    psnr: float


@dataclass
class _Toy(ResumableTrainer):
    """A trainer of one parameter: loss (w - 3)^2, one SGD step a step."""

    seed: int = 0
    step: int = 0
    train_seconds: float = 0.0
    history: list = field(default_factory=list)
    device: str = "cpu"

    def __post_init__(self):
        self.model = torch.nn.Linear(1, 1, bias=False)
        torch.nn.init.zeros_(self.model.weight)
        self.optimizer = torch.optim.SGD(self.model.parameters(), lr=0.1)

    def meta(self):
        return {"seed": self.seed}

    def train_step(self):
        loss = (self.model.weight[0, 0] - 3.0) ** 2
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        self.step += 1
        return _Stats(float(loss), 0.0)

    def history_row(self, stats):
        return {"step": self.step, "loss": stats.loss}


def test_loop_logs_checkpoints_and_resumes_to_the_same_state(tmp_path):
    ckpt = tmp_path / "last.pt"
    whole = _Toy()
    train_loop(whole, 10, log_every=3, checkpoint_every=4, ckpt=tmp_path / "whole.pt", label="toy")
    assert [r["step"] for r in whole.history] == [3, 6, 9, 10]  # every 3rd and the last
    killed = _Toy()
    train_loop(killed, 10, 3, 4, ckpt, "toy", stop_after=7)  # killed after step 7: last checkpoint at 4
    resumed = _Toy()
    resumed.load_checkpoint(ckpt)
    assert resumed.step == 4 and [r["step"] for r in resumed.history] == [3]
    train_loop(resumed, 10, 3, 4, ckpt, "toy")
    assert torch.equal(resumed.model.weight, whole.model.weight)
    assert resumed.history == whole.history
    with pytest.raises(InputError, match="checkpoint was made by another run"):
        _Toy(seed=1).load_checkpoint(ckpt)


@dataclass
class _Threaded(_Toy):
    """The toy, asking the loop for ``threads`` torch threads; it records the count each step saw, and
    raises at step ``fail_at`` (a crash mid-run)."""

    threads: int = 0
    fail_at: int = 0
    seen: list = field(default_factory=list)

    def loop_threads(self):
        return self.threads

    def train_step(self):
        self.seen.append(torch.get_num_threads())
        if self.fail_at and self.step + 1 == self.fail_at:
            raise RuntimeError("crash")
        return super().train_step()


@pytest.fixture
def one_thread():
    """torch at one thread for the test, and the process's own count afterwards."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_loop_sets_the_trainers_threads_once_and_restores_them(tmp_path, one_thread):
    trainer = _Threaded(threads=3)
    train_loop(trainer, 5, 2, 10, tmp_path / "a.pt", "toy")
    assert trainer.seen == [3] * 5 and torch.get_num_threads() == 1  # every step at 3; afterwards as before
    crashed = _Threaded(threads=3, fail_at=2)
    with pytest.raises(RuntimeError, match="crash"):
        train_loop(crashed, 5, 2, 10, tmp_path / "b.pt", "toy")
    assert crashed.seen == [3, 3] and torch.get_num_threads() == 1  # restored when a step raises too
    untouched = _Threaded(threads=0)  # 0: torch's count is left as it is (a GPU trainer)
    train_loop(untouched, 2, 2, 10, tmp_path / "c.pt", "toy")
    assert untouched.seen == [1, 1] and torch.get_num_threads() == 1
    assert _Toy().loop_threads() == 0  # the base class asks for nothing


def test_torch_threads_restores_what_the_body_changed(one_thread):
    from nsim.train.loop import torch_threads

    with torch_threads(2):
        assert torch.get_num_threads() == 2
        torch.set_num_threads(4)
    assert torch.get_num_threads() == 1
    with torch_threads(0):
        assert torch.get_num_threads() == 1
        torch.set_num_threads(3)
    assert torch.get_num_threads() == 1
