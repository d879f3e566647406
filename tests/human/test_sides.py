"""Left and right limbs kept consistent over a video (``nsim.human.landmarks.consistent_sides``): a detector that
exchanges a walker's legs for a few frames after they cross is relabelled back, and nothing else is touched."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.human.fit import reference_body
from nsim.human.gait import walk_cycle
from nsim.human.landmarks import (
    LANDMARK_NAMES,
    LIMB_SIDES,
    Observations,
    consistent_sides,
    limb_side_switches,
)
from nsim.human.motion import LocomotionLoop
from nsim.human.skeleton import forward_kinematics

FPS = 10.0  # the test room's actor video: legs cross every 5-6 frames, a swinging foot moves 20-30 cm a frame


def _walk_landmarks(seconds: float = 4.0, noise_m: float = 0.015, seed: int = 0) -> np.ndarray:
    """Hip-centred landmarks ``(F, L, 3)`` of nsim's walk at ``FPS`` with noise, as a detector's ``body_m``."""
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, fps=FPS))
    root, quats = loop.sample(np.arange(int(round(seconds * FPS))) / FPS)
    body = reference_body(1.75)
    lm = body.landmarks(forward_kinematics(body.skeleton, quats, root))
    i, j = LANDMARK_NAMES.index("left_hip"), LANDMARK_NAMES.index("right_hip")
    lm = lm - 0.5 * (lm[:, i] + lm[:, j])[:, None]
    return lm + np.random.default_rng(seed).normal(0.0, noise_m, lm.shape)


def _exchange(lm: np.ndarray, frames, parts) -> np.ndarray:
    out = lm.copy()
    for p in parts:
        a, b = LANDMARK_NAMES.index(f"left_{p}"), LANDMARK_NAMES.index(f"right_{p}")
        out[frames, a], out[frames, b] = lm[frames, b], lm[frames, a]
    return out


def _after_crossings(lm: np.ndarray) -> list[int]:
    """The frames just after the ankles pass each other (along the walk), where a detector mixes them up."""
    a, b = LANDMARK_NAMES.index("left_ankle"), LANDMARK_NAMES.index("right_ankle")
    ahead = np.sign(lm[:, a, 0] - lm[:, b, 0])
    return [int(t) for t in np.flatnonzero(ahead[1:] != ahead[:-1]) + 1]


def test_a_clean_walk_is_left_alone():
    lm = _walk_landmarks()
    for parts in LIMB_SIDES.values():
        assert not limb_side_switches(lm, parts).any()


@pytest.mark.parametrize("length", [1, 2, 3])
def test_legs_exchanged_after_a_crossing_are_found(length):
    lm = _walk_landmarks(seed=length)
    crossings = _after_crossings(lm)
    assert len(crossings) >= 4
    wrong = [t for c in crossings[1:4:2] for t in range(c, c + length)]  # two stretches, each just after a crossing
    found = limb_side_switches(_exchange(lm, wrong, LIMB_SIDES["legs"]), LIMB_SIDES["legs"])
    assert np.flatnonzero(found).tolist() == wrong
    # the arms were labelled right throughout
    assert not limb_side_switches(_exchange(lm, wrong, LIMB_SIDES["legs"]), LIMB_SIDES["arms"]).any()


def test_a_labelling_wrong_from_start_to_end_is_kept():
    """Smoothness cannot tell a walk whose sides are exchanged in every frame: the detector's labelling stands."""
    lm = _exchange(_walk_landmarks(), slice(None), LIMB_SIDES["legs"])
    assert not limb_side_switches(lm, LIMB_SIDES["legs"]).any()


def test_consistent_sides_relabels_landmarks_positions_and_visibility_of_the_frames_given():
    lm = _walk_landmarks(seed=5)
    F, L = lm.shape[:2]
    crossing = _after_crossings(lm)[2]
    wrong = [crossing, crossing + 1]
    body = _exchange(lm, wrong, LIMB_SIDES["legs"])
    uv = np.stack([np.arange(L, dtype=float), np.zeros(L)], -1)[None].repeat(F, 0)  # u = the landmark's index
    vis = np.tile(np.linspace(0.2, 0.9, L), (F, 1))
    found = np.ones(F, dtype=bool)
    found[3] = False
    body[3], uv[3], vis[3] = np.nan, np.nan, 0.0
    obs = Observations(found, uv, body, vis, np.zeros((F, 4, 4), np.float32), np.zeros(F, np.int64), 4, 4)
    fixed, changed = consistent_sides(obs)
    assert changed == {"legs": wrong, "arms": []}
    np.testing.assert_array_equal(fixed.body_m[found], lm[found])
    knee_l, knee_r = LANDMARK_NAMES.index("left_knee"), LANDMARK_NAMES.index("right_knee")
    for t in wrong:  # the image positions and visibilities travel with their landmarks
        assert fixed.image_uv_px[t, knee_l, 0] == knee_r and fixed.visibility[t, knee_l] == vis[t, knee_r]
    assert fixed.image_uv_px[0, knee_l, 0] == knee_l
    assert np.isnan(fixed.body_m[3]).all()
    assert obs.body_m[wrong[0], knee_l, 0] == body[wrong[0], knee_l, 0]  # the input is not changed
    # frames left out of the sequence are not relabelled
    keep = found.copy()
    keep[wrong] = False
    assert consistent_sides(obs, keep)[1] == {"legs": [], "arms": []}
