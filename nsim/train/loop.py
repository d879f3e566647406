"""What every nsim trainer shares: seeds per step, resumable state, and the training loop.

The scene and human trainers differ in their models, batches and losses; how they are driven does
not. A trainer (:class:`Trainer`) has a ``step``, ``train_seconds``, a ``history`` of logged rows
and a ``train_step()``; :class:`ResumableTrainer` gives it the checkpoint state (format, the run's
``meta`` that a checkpoint must match, step, seconds, model, optimiser, history, plus what a
trainer adds in ``_extra_state``), written and read through :mod:`nsim.train.checkpoint` (plain
weights-only files, so no code in a planted file runs). :func:`train_loop` runs the steps from
wherever the trainer is (fresh or resumed) to the end: a history row every ``log_every`` steps and
at the last, a checkpoint every ``checkpoint_every`` steps and at the last (its writing time counts
as training time), a progress bar or periodic log lines. Every random draw of a step comes from a
generator seeded by :func:`step_seed` ``(trainer, seed, step, purpose)``, so a run killed and
resumed from its checkpoint repeats an uninterrupted one exactly.

Threads. The loop sets torch's intra-op thread count once, to the trainer's ``loop_threads()``
(0: torch's own count is left alone, e.g. on a GPU), and restores what it was when the loop ends,
however it ends (:func:`torch_threads`); neither building a trainer nor a step changes it, so a
training leaves the process's thread count as it found it.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from nsim.errors import InputError
from nsim.metrics.image import psnr_from_mse
from nsim.train import checkpoint


def step_seed(namespace: str, seed: int, step: int, purpose: str = "batch") -> int:
    """A 63-bit seed for ``purpose`` at ``step`` of the run seeded ``seed`` in trainer ``namespace``
    (e.g. ``nsim.train.scene``): SHA-256 of the four, so seeds of different steps and purposes are unrelated."""
    digest = hashlib.sha256(f"{namespace}:{purpose}:{seed}:{step}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def spread(items: list[int], n: int) -> list[int]:
    """``n`` items spread evenly over ``items``, first and last included (all when n is 0 or too large)."""
    if n <= 0 or n >= len(items):
        return items
    return [items[int(round(k * (len(items) - 1) / max(1, n - 1)))] for k in range(n)]


@contextlib.contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """torch's intra-op thread count set to ``count`` while the body runs (0: left as it is), and what it
    was before put back afterwards, even when the body raises or changed it itself. With torch's OpenMP
    backend the count is the calling thread's: worker threads keep their own (see ``nsim.train.scene``'s
    batch parts)."""
    import torch

    before = torch.get_num_threads()
    if count > 0 and count != before:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


@dataclass
class StepStats:
    """One training step: the step count after it, its loss, the batch's PSNR, seconds, and extras."""

    step: int
    loss: float
    psnr: float
    seconds: float
    extra: dict[str, float] = field(default_factory=dict)


class Trainer(Protocol):
    step: int
    train_seconds: float
    history: list[dict[str, Any]]

    def train_step(self) -> StepStats: ...

    def loop_threads(self) -> int: ...

    def history_row(self, stats: StepStats) -> dict[str, Any]: ...

    def save_checkpoint(self, path: Path) -> None: ...


class ResumableTrainer:
    """The checkpoint state of a trainer with ``model``, ``optimizer``, ``step``, ``train_seconds``,
    ``history`` and ``device``. Subclasses give ``meta()`` (what identifies the run: a checkpoint of
    another run is refused) and may add state in ``_extra_state`` / ``_load_extra_state`` (loaded
    after the model, before the optimiser). Also shared: a step's start and end (:meth:`_begin_step`,
    :meth:`_finish_step`) and the learning-rate schedule (:meth:`lr_scale` of ``cfg.optim``'s ``steps``,
    ``warmup_steps`` and ``lr_final_factor``, times each group's ``base_lr``)."""

    checkpoint_format = 1

    def loop_threads(self) -> int:
        """torch's intra-op threads while :func:`train_loop` runs this trainer (0: leave torch's count)."""
        return 0

    def meta(self) -> dict[str, Any]:
        raise NotImplementedError

    def _extra_state(self) -> dict[str, Any]:
        return {}

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        """Apply what ``_extra_state`` saved."""

    def state_dict(self) -> dict[str, Any]:
        return {"format": self.checkpoint_format, "meta": self.meta(), "step": self.step,
                "train_seconds": self.train_seconds, "model": self.model.state_dict(),
                "optimizer": self.optimizer.state_dict(), "history": self.history, **self._extra_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != self.checkpoint_format:
            raise InputError(f"checkpoint format {state.get('format')} is not {self.checkpoint_format}")
        if state["meta"] != self.meta():
            raise InputError(f"checkpoint was made by another run ({state['meta']} != {self.meta()})")
        self.model.load_state_dict(state["model"])
        self._load_extra_state(state)
        self.optimizer.load_state_dict(state["optimizer"])
        self.step = int(state["step"])
        self.train_seconds = float(state["train_seconds"])
        self.history = list(state["history"])

    def save_checkpoint(self, path: Path) -> None:
        """Atomically write the full training state to ``path`` (``nsim.train.checkpoint``'s format)."""
        checkpoint.save_checkpoint(self.state_dict(), path)

    def lr_scale(self, step: int) -> float:
        """The learning rates' factor at ``step``: from 1 (after a linear warm-up over ``cfg.optim.warmup_steps``)
        down exponentially to ``cfg.optim.lr_final_factor`` at ``cfg.optim.steps``."""
        o = self.cfg.optim
        decay = o.lr_final_factor ** min(1.0, step / max(1, o.steps))
        warm = min(1.0, (step + 1) / o.warmup_steps) if o.warmup_steps > 0 else 1.0
        return decay * warm

    def _set_learning_rates(self) -> None:
        """Each optimiser group's rate: its base rate (``base_lr``) times ``lr_scale(step)``."""
        scale = self.lr_scale(self.step)
        for group, base in zip(self.optimizer.param_groups, self.base_lr, strict=True):
            group["lr"] = base * scale

    def _begin_step(self) -> float:
        """Start a step: its learning rates set, the model in training mode; returns its start time
        (``time.perf_counter``) for :meth:`_finish_step`."""
        t0 = time.perf_counter()
        self._set_learning_rates()
        self.model.train()
        return t0

    def _finish_step(self, t0: float, loss, mse, extra: dict[str, float]) -> StepStats:
        """Count the step begun at ``t0`` (``time.perf_counter``) and its seconds; its stats (PSNR from ``mse``)."""
        self.step += 1
        dt = time.perf_counter() - t0
        self.train_seconds += dt
        return StepStats(self.step, float(loss.detach()), psnr_from_mse(max(float(mse.detach()), 1e-12)), dt, extra)

    def load_checkpoint(self, path: Path) -> None:
        """Continue from the checkpoint at ``path``; read weights-only, so no code in it runs.
        Raises ``InputError`` if it is unreadable or another run's."""
        self.load_state_dict(checkpoint.load_checkpoint(path, map_location=self.device))


def train_loop(trainer: Trainer, steps: int, log_every: int, checkpoint_every: int, ckpt: Path, label: str,
               progress: bool = False, stop_after: int | None = None,
               on_log: Callable[[Any, Any], None] | None = None, logger: logging.Logger | None = None) -> None:
    """Run ``trainer`` from its current step to ``steps`` (or ``stop_after``: return there without a
    checkpoint, as if killed; tests). Every ``log_every`` steps and at the last, ``trainer.history_row(stats)``
    joins the history, the bar shows loss and PSNR, ``logger`` logs them and ``on_log(trainer, stats)`` is
    called; every ``checkpoint_every`` steps and at the last, the state goes to ``ckpt``. torch's thread
    count is ``trainer.loop_threads()`` throughout and is restored afterwards (module docstring)."""
    from nsim.progress import progress_bar

    logger = logger or logging.getLogger(__name__)
    end = steps if stop_after is None else min(steps, stop_after)
    with torch_threads(trainer.loop_threads()), progress_bar(steps, label, progress) as bar:
        bar.advance(trainer.step)
        while trainer.step < end:
            stats = trainer.train_step()
            step = trainer.step
            if step % log_every == 0 or step == steps:
                trainer.history.append(trainer.history_row(stats))
                bar.advance(0, loss=f"{stats.loss:.4f}", psnr=f"{stats.psnr:.2f}")
                logger.info("step %d loss %.5f psnr %.2f (%.1f s)", step, stats.loss, stats.psnr, trainer.train_seconds)
                if on_log is not None:
                    on_log(trainer, stats)
            if step % checkpoint_every == 0 or step == steps:
                t0 = time.perf_counter()
                trainer.save_checkpoint(ckpt)
                trainer.train_seconds += time.perf_counter() - t0
            bar.advance(1)


@dataclass
class TrainResult:
    """A finished (or stopped) training: the trainer, the step it resumed from (None: fresh), and
    what the export adds (``evaluation``)."""

    trainer: Any
    resumed_from: int | None
    evaluation: dict[str, Any] | None = None

    @property
    def model(self):
        return self.trainer.model


def resume_and_train(make_trainer: Callable[[], Any], work_dir: str | os.PathLike, steps: int, log_every: int,
                     checkpoint_every: int, label: str, progress: bool = False, stop_after: int | None = None,
                     on_log: Callable[[Any, Any], None] | None = None,
                     logger: logging.Logger | None = None) -> tuple[Any, int | None]:
    """A trainer from ``make_trainer()``, resumed from ``work_dir/last.pt`` when that is this run's
    (``nsim.train.checkpoint.resume``), trained by :func:`train_loop` with its checkpoints there.
    Returns ``(trainer, step resumed from or None)``."""
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    ckpt = work_dir / checkpoint.CHECKPOINT_NAME
    trainer, resumed = checkpoint.resume(make_trainer, ckpt)
    train_loop(trainer, steps, log_every, checkpoint_every, ckpt, label, progress, stop_after, on_log, logger)
    return trainer, resumed
