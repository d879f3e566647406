"""bench/simulate.py configures PySocialForce 1.1.2 where it reads its settings (its pedestrians get the
whole config, so step_width and agent_radius belong at the top level; under [scene] they are ignored)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "simulate.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_simulate", BENCH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_simulate", mod)
    spec.loader.exec_module(mod)
    return mod


def test_psf_settings_sit_where_pysocialforce_reads_them(tmp_path):
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    bench = _bench()
    doc = tomllib.loads(bench.psf_config_file(tmp_path).read_text())
    for key in ("step_width", "agent_radius", "tau", "max_speed_multiplier"):
        assert doc[key] == bench.PSF_WANTED[key], key  # top level: PedState(state, groups, self.config)
    assert doc["step_width"] == bench.DT_S
    assert doc["scene"] == {"enable_group": False}  # the only setting 1.1.2 reads under [scene]


class _Peds:
    step_width, agent_radius, max_speed_multiplier, default_tau = 0.4, 0.35, 1.3, 0.5


class _Sim:
    peds = _Peds()

    @staticmethod
    def scene_config(key):
        return {"enable_group": False}[key]


def test_a_misconfigured_peer_is_caught():
    bench = _bench()
    got = bench.psf_effective(_Sim())
    assert got == {"step_width": 0.4, "agent_radius": 0.35, "max_speed_multiplier": 1.3, "tau": 0.5, "enable_group": False}
    assert got != bench.PSF_WANTED  # what the bench compares before timing: this would stop it
