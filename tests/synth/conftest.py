"""Shared fixtures for the test-room tests: one baked oracle per preset for the whole session."""

from __future__ import annotations

import pytest

from nsim.synth.oracle import RoomOracle
from nsim.synth.room import ROOM_PRESETS, make_room


@pytest.fixture(scope="session")
def oracles() -> dict[str, RoomOracle]:
    """``{preset: RoomOracle(make_room(preset, seed=0))}``, built once (texture baking is the slow part)."""
    return {name: RoomOracle(make_room(name, seed=0)) for name in ROOM_PRESETS}
