"""Canonical numbers: values one last bit apart write the same; -0 is written 0; ints, strings and NaN pass."""

from __future__ import annotations

import json
import math

import numpy as np

from nsim.io.canonical import POSE_DECIMALS, canonical_floats, round_decimals, round_float


def test_values_one_bit_apart_round_to_the_same():
    rng = np.random.default_rng(0)
    x = rng.uniform(-20.0, 20.0, 10_000)
    a, b = round_decimals(x), round_decimals(np.nextafter(x, np.inf))
    assert np.mean(a == b) > 0.9999  # a boundary between them is one value in about a million
    assert np.max(np.abs(a - x)) <= 0.5e-9 + 1e-15
    m = rng.uniform(0.0, 100.0, 1000)
    assert [round_float(v) for v in m] == [round_float(float(np.nextafter(v, 0.0))) for v in m]


def test_negative_zero_is_written_zero():
    assert math.copysign(1.0, round_decimals(-1e-12)) == 1.0
    assert math.copysign(1.0, round_float(-0.0)) == 1.0
    # significant digits keep a tiny value (it means something); only -0 itself becomes 0
    assert json.dumps(canonical_floats({"a": -0.0, "b": [-1e-300, 2.5e-12]})) == '{"a": 0.0, "b": [-1e-300, 2.5e-12]}'
    assert json.dumps(canonical_floats([-3e-10, 1.23456789012], decimals=POSE_DECIMALS)) == "[0.0, 1.23456789]"


def test_structure_and_other_types_pass_unchanged():
    data = {"n": 3, "ok": True, "s": "x", "none": None, "nan": float("nan"), "inf": float("inf"),
            "np": np.float32(0.1), "ni": np.int64(7), "t": (1.0, 2), "arr": np.array([1.0 / 3.0])}
    out = canonical_floats(data)
    assert out["n"] == 3 and out["ok"] is True and out["s"] == "x" and out["none"] is None
    assert math.isnan(out["nan"]) and out["inf"] == math.inf and out["ni"] == 7 and type(out["ni"]) is int
    assert out["t"] == [1.0, 2] and out["arr"] == [0.3333333333] and out["np"] == 0.1000000015
    assert round_float(123456.789012345, 10) == 123456.789
