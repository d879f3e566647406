"""Gait phase: advances with distance walked (no foot sliding), stays put when standing."""

from __future__ import annotations

import numpy as np

from nsim.crowd import CrowdState, rollout
from nsim.human.gait_phase import advance_gait_phase, gait_phase, stride_length_m


def test_stride_length_relation():
    assert stride_length_m(1.4, 1.75) == np.float64(2 * 0.63 * np.sqrt(1.4))  # ~1.49 m: ~113 steps/min
    speeds = np.linspace(0.2, 2.0, 10)
    assert np.all(np.diff(stride_length_m(speeds)) > 0)
    np.testing.assert_allclose(stride_length_m(1.0, 1.5) / stride_length_m(1.0, 1.75), 1.5 / 1.75)
    assert stride_length_m(0.0) == stride_length_m(0.1) > 0  # held below the minimum speed


def test_gait_phase_wraps_in_unit_interval():
    d = np.linspace(0, 20, 1001)
    phase = gait_phase(d, 1.5)
    assert phase.min() >= 0.0 and phase.max() < 1.0
    np.testing.assert_allclose(gait_phase(np.array([0.75, 1.5, 2.25]), 1.5), [0.5, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(advance_gait_phase(np.array([0.9]), np.array([0.3]), 1.5), [0.1], atol=1e-12)


def test_phase_advances_with_distance_in_a_rollout():
    s = CrowdState.create([[0.0, 0.0], [0.0, 3.0]], [[8.0, 0.0], [0.0, 3.0]], desired_speed_mps=[1.3, 1.3])
    tr = rollout(s, 200, 0.05)
    step = np.linalg.norm(np.diff(tr.position_m[:, 0], axis=0), axis=-1)
    speed = np.linalg.norm(tr.velocity_mps[1:, 0], axis=-1)
    advance = np.mod(np.diff(tr.gait_phase[:, 0]), 1.0)
    # the planted foot moves exactly as far as the root: phase advance x stride = distance walked
    np.testing.assert_allclose(advance * stride_length_m(speed), step, atol=1e-9)
    cycles = np.sum(advance)
    assert 8.0 / 1.6 < cycles < 8.0 / 1.1  # 8 m: ~1.5 m strides cruising, shorter ones starting and stopping
    # the walker has stopped at its goal: the phase holds
    assert np.ptp(tr.gait_phase[-20:, 0]) < 0.01  # < 5 mm of walking in the last second
    assert np.ptp(tr.gait_phase[:, 1]) < 0.05  # the bystander barely moves its feet
