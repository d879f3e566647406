"""Canonical numbers in the files nsim writes: the same result on every CPU, to the bit.

CPUs differ in their last bits: numpy's vectorised ``sin``, ``arctan2`` and sums take other paths with
AVX-512 than without (``NPY_DISABLE_CPU_FEATURES``), torch's kernels other paths per ``ATEN_CPU_CAPABILITY``.
A pose or a metric that differs in its 16th digit makes a different file, a different artifact id, a run
cache that misses on another cluster node and a CI check that fails for no reason a user can see. So what is
written is rounded to what it means first, and ``-0`` is written as ``0``:

* poses, positions and angles: ``POSE_DECIMALS`` decimals (nanometres, nanoradians; a unit quaternion's
  components to 1e-9), far below any sensor's resolution and far above float64's last bits for a room;
* metrics and other derived figures in JSON: ``METRIC_DIGITS`` significant digits.

A value a last-bit difference moves across a rounding boundary still differs; with a last-bit difference of
about 1e-15 against a step of 1e-9 that is about one value in a million (``bench/reproducible.py`` measures
what repeats). Integers, strings and non-finite values pass unchanged.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

#: Decimals for poses (metres, radians, quaternion components) written by nsim: 1e-9.
POSE_DECIMALS = 9
#: Significant digits for metrics and other derived floats written to JSON by nsim.
METRIC_DIGITS = 10


def round_decimals(values, decimals: int = POSE_DECIMALS):
    """``values`` as a float64 array rounded to ``decimals`` decimals, ``-0`` made ``0`` (NaN and inf unchanged)."""
    import numpy as np  # here: the workspace imports this module, and a failing command must start fast

    a = np.round(np.asarray(values, dtype=np.float64), decimals)
    return a + 0.0  # -0.0 + 0.0 == +0.0


def round_float(value: float, digits: int = METRIC_DIGITS) -> float:
    """``value`` to ``digits`` significant digits; ``-0`` made ``0``; NaN and inf unchanged."""
    v = float(value)
    if not math.isfinite(v):
        return v
    return float(f"{v:.{digits}g}") + 0.0


def canonical_floats(data: Any, digits: int | None = METRIC_DIGITS, decimals: int | None = None) -> Any:
    """A copy of JSON-like ``data`` (dicts, lists, tuples, numbers, strings, numpy scalars and arrays) with every
    float rounded: to ``decimals`` decimals when given (poses: ``POSE_DECIMALS``), else to ``digits``
    significant digits (:func:`round_float`); ints and bools stay as they are, tuples become lists."""
    if data is None or isinstance(data, (bool, str)):
        return data
    if type(data).__name__ == "bool_":  # numpy's bool
        return bool(data)
    if isinstance(data, numbers.Integral):
        return int(data)
    if isinstance(data, numbers.Real):
        v = float(data)
        if not math.isfinite(v):
            return v
        return float(round_decimals(v, decimals)) if decimals is not None else round_float(v, digits or METRIC_DIGITS)
    if isinstance(data, dict):
        return {k: canonical_floats(v, digits, decimals) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [canonical_floats(v, digits, decimals) for v in data]
    if hasattr(data, "tolist") and hasattr(data, "dtype"):  # a numpy array
        return canonical_floats(data.tolist(), digits, decimals)
    return data
