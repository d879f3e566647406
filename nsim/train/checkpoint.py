"""Training checkpoints on disk: written atomically, read back without running any code.

A resume checkpoint lives in the workspace (``<workspace>/tmp/train_*.<key>.resume/last.pt``),
so whoever can write there could plant a file in its place; reading it must therefore never
unpickle arbitrary objects. The format is ``torch.save`` of a *plain* state: nested dicts,
lists and tuples whose leaves are tensors, ``str``, ``int``, ``float``, ``bool`` or ``None``
(the trainers' model / optimiser / grad-scaler ``state_dict``s, step, history and RNG state
are all of this kind). :func:`save_checkpoint` refuses anything else, so that every
checkpoint written is one :func:`load_checkpoint` can read with ``torch.load(...,
weights_only=True)``, which rejects any other global instead of calling it.

:func:`resume` is the trainers' "continue from ``work_dir/last.pt`` if it is ours" step: a
checkpoint that cannot be read or applied (not a weights-only file, a refused global,
truncated, another run's, wrong keys or shapes) is logged as a warning and training starts
from scratch; the bad file is replaced by the next checkpoint written.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, TypeVar

import torch

from nsim.errors import InputError
from nsim.io import atomic_path

log = logging.getLogger(__name__)

CHECKPOINT_NAME = "last.pt"

_PLAIN_LEAVES = (str, int, float, bool, type(None))


class CheckpointError(InputError):
    """A checkpoint file that cannot be read as a plain (weights-only) training state."""


def check_plain(obj: Any, where: str = "state") -> None:
    """Raise ``TypeError`` (naming the dotted path) unless ``obj`` is a plain state (see the module docstring)."""
    if isinstance(obj, torch.Tensor) or type(obj) in _PLAIN_LEAVES:
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            if type(k) not in _PLAIN_LEAVES:
                raise TypeError(f"checkpoint {where}: key {k!r} is a {type(k).__name__}, not a plain value")
            check_plain(v, f"{where}.{k}")
        return
    if type(obj) in (list, tuple):
        for i, v in enumerate(obj):
            check_plain(v, f"{where}[{i}]")
        return
    raise TypeError(f"checkpoint {where}: a {type(obj).__module__}.{type(obj).__qualname__} is not a tensor or plain value")


def save_checkpoint(state: dict[str, Any], path: str | os.PathLike) -> None:
    """Atomically write ``state`` (a plain state, checked) to ``path``: temp file, fsync, rename."""
    check_plain(state)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device | None = None) -> dict[str, Any]:
    """The plain state stored at ``path``, read with ``weights_only=True`` (no code runs).

    Raises :class:`CheckpointError` (naming the file and the reason) when the file is not one.
    """
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # untrusted file: whatever fails while parsing it makes it unreadable
        raise CheckpointError(f"{path}: not a readable weights-only checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: holds a {type(state).__name__}, not a training state")
    return state


class _Resumable(Protocol):
    step: int

    def load_checkpoint(self, path: Path) -> None: ...


T = TypeVar("T", bound=_Resumable)


def resume(make_trainer: Callable[[], T], path: str | os.PathLike) -> tuple[T, int | None]:
    """A trainer from ``make_trainer()``, continued from the checkpoint at ``path`` when it exists and
    can be applied; else a fresh one (with a warning naming the file and the reason).

    Returns ``(trainer, step resumed from or None)``.
    """
    path = Path(path)
    trainer = make_trainer()
    if not path.is_file():
        return trainer, None
    try:
        trainer.load_checkpoint(path)
    except Exception as exc:  # a bad or foreign checkpoint must never stop (or steer) a new run
        log.warning("ignoring checkpoint %s, training from scratch: %s: %s", path, type(exc).__name__, exc)
        return make_trainer(), None  # the failed load may have applied part of the state
    log.info("resuming from %s at step %d", path, trainer.step)
    return trainer, trainer.step
