"""numpy or torch: what kind of array a value is, without importing torch.

The geometry helpers take numpy arrays or torch tensors and give back the same kind. A tensor can only
exist once torch is loaded, so the check reads ``sys.modules`` and never imports torch itself: a command
that touches only numpy (``nsim import-log``, a failing argument check) starts without torch's seconds.
"""

from __future__ import annotations

import contextlib
import sys
from types import ModuleType
from typing import Any

import numpy as np


def is_tensor(x: Any) -> bool:
    """True for a torch tensor (torch loaded and ``x`` one of its tensors)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def namespace(x: Any) -> ModuleType:
    """``torch`` for a tensor, else ``numpy``: the module whose functions keep ``x``'s kind."""
    return sys.modules["torch"] if is_tensor(x) else np


def no_grad(x: Any) -> contextlib.AbstractContextManager:
    """``torch.no_grad()`` for a tensor, a no-op for numpy."""
    return sys.modules["torch"].no_grad() if is_tensor(x) else contextlib.nullcontext()
