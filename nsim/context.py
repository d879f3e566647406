"""The run context: the one place that knows the workspace, the device and the seed.

The CLI builds a :class:`RunContext` once and passes it down; nothing else picks a device
or seeds a generator. Every random draw comes from :meth:`RunContext.rng` (numpy) or
:meth:`RunContext.torch_generator`, each seeded from ``(seed, name)`` so that adding a new
random draw in one place never shifts the numbers drawn in another.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import sys

import numpy as np

from nsim.errors import InputError
from nsim.workspace.store import Store

DEVICE_CHOICES = ("auto", "cpu", "cuda")


def resolve_device(spec: str) -> str:
    """``auto`` -> ``cuda`` when a CUDA device is usable, else ``cpu``; ``cuda[:N]`` is checked."""
    spec = spec.strip().lower()
    if spec == "cpu":
        return "cpu"
    if spec != "auto" and not (spec == "cuda" or (spec.startswith("cuda:") and spec[5:].isdigit())):
        raise InputError(f"--device: expected auto, cpu, cuda or cuda:N, got {spec!r}")
    import torch

    available = torch.cuda.is_available()
    if spec == "auto":
        return "cuda" if available else "cpu"
    if not available:
        raise InputError(f"--device {spec}: no CUDA device is available on this machine (use --device auto or cpu)")
    if ":" in spec and int(spec[5:]) >= torch.cuda.device_count():
        raise InputError(f"--device {spec}: only {torch.cuda.device_count()} CUDA device(s) present")
    return spec


def _name_seed(seed: int, name: str) -> list[int]:
    digest = hashlib.sha256(name.encode()).digest()
    return [seed & 0xFFFFFFFF, (seed >> 32) & 0xFFFFFFFF, *np.frombuffer(digest[:16], dtype=np.uint32).tolist()]


@dataclasses.dataclass(frozen=True)
class RunContext:
    """Frozen: code that needs another setting makes a new one, ``dataclasses.replace(ctx, force=True)``."""

    store: Store
    device_spec: str = "auto"
    seed: int = 0
    force: bool = False
    progress: bool | None = None  # None: show progress bars only on a terminal

    @functools.cached_property
    def device(self) -> str:
        """The resolved torch device string (resolved on first use, so CPU-only commands skip torch)."""
        return resolve_device(self.device_spec)

    @property
    def show_progress(self) -> bool:
        return sys.stderr.isatty() if self.progress is None else self.progress

    def rng(self, name: str) -> np.random.Generator:
        """A numpy generator seeded from the context seed and a purpose name."""
        return np.random.default_rng(np.random.SeedSequence(_name_seed(self.seed, name)))

    def torch_generator(self, name: str, device: str | None = None):
        import torch

        g = torch.Generator(device=device or "cpu")
        g.manual_seed(int(np.random.SeedSequence(_name_seed(self.seed, name)).generate_state(1, np.uint64)[0] >> 1))
        return g
