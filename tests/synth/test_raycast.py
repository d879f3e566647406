"""The analytic ray caster: hand-computed hits, a plain per-ray twin, batching invariance, shading."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.synth import raycast
from nsim.synth.raycast import Lighting, cast
from nsim.synth.room import ROOM_PRESETS
from nsim.synth.textures import bake_room_textures
from tests.synth.simple_room import simple_spec

SPEC = simple_spec()  # room 6 x 4 x 2.5, cube [1, 2] x [1, 2] x [0, 1] (surface 6)


def _one(o, d, spec=SPEC, **kwargs):
    d = np.asarray(d, dtype=np.float64)
    return cast(spec, np.array([o], dtype=np.float64), (d / np.linalg.norm(d))[None], **kwargs)


@pytest.mark.parametrize(
    ("origin", "direction", "t", "surface", "normal"),
    [
        ((4.0, 2.0, 1.0), (0, 0, -1), 1.0, 0, (0, 0, 1)),  # straight down onto the floor
        ((3.0, 2.0, 1.0), (0, 0, 1), 1.5, 1, (0, 0, -1)),  # up to the ceiling
        ((0.5, 1.5, 0.5), (1, 0, 0), 0.5, 6, (-1, 0, 0)),  # into the cube's x = 1 face
        ((1.5, 1.5, 2.0), (0, 0, -1), 1.0, 6, (0, 0, 1)),  # onto the cube's top
        ((0.5, 0.8, 0.5), (1, 1, 0), 0.5 * np.sqrt(2), 6, (-1, 0, 0)),  # diagonal, hits x = 1 at y = 1.3
        ((1.5, 1.5, 0.5), (1, 0, 0), 4.5, 3, (-1, 0, 0)),  # from inside the cube: it is invisible
        ((-1.0, 3.0, 2.0), (1, 0, 0), 7.0, 3, (-1, 0, 0)),  # from outside: through wall x = 0 to x = 6
        ((4.0, 2.0, 0.0), (0, 0, -1), 0.0, 0, (0, 0, 1)),  # on the floor, leaving the room
        ((4.0, 2.0, 0.0), (0, 0, 1), 2.5, 1, (0, 0, -1)),  # on the floor, into the room
        ((3.0, 0.5, 1.5), (0, -1, 0), 0.5, 4, (0, 1, 0)),  # wall y = 0
    ],
)
def test_hand_computed_hits(origin, direction, t, surface, normal):
    hits = _one(origin, direction)
    assert hits.t[0] == pytest.approx(t, abs=1e-12)
    assert hits.surface_id[0] == surface
    np.testing.assert_array_equal(hits.normal[0], normal)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    np.testing.assert_allclose(hits.point[0], np.asarray(origin) + t * d, atol=1e-12)


def test_misses():
    for origin, direction in [((-1.0, 2.0, 1.0), (-1, 0, 0)), ((-1.0, 5.0, 1.0), (1, 0, 0))]:
        hits = _one(origin, direction)
        assert np.isinf(hits.t[0]) and hits.surface_id[0] == -1 and hits.face[0] == -1
        assert np.all(hits.normal[0] == 0) and np.all(np.isnan(hits.point[0])) and np.all(hits.rgb[0] == 0)


def test_box_faces_and_snapping():
    hits = _one((1.5, 1.5, 2.0), (0, 0, -1))
    assert hits.face[0] == 6 + 2 * 2 + 1  # box 0, axis z, max side
    assert hits.point[0, 2] == 1.0  # exactly on the plane


def _reference_cast(spec, origins, dirs):
    """Plain per-ray twin: intersect every one-sided rectangle, keep the nearest. Returns t, surface, normal."""
    X, Y, Z = spec.size_xyz_m
    planes = []  # (axis, coordinate, normal sign, lo (3,), hi (3,), surface id)
    size = np.array([X, Y, Z])
    for sid, (axis, side) in enumerate(((2, 0), (2, 1), (0, 0), (0, 1), (1, 0), (1, 1))):
        planes.append((axis, side * size[axis], 1.0 if side == 0 else -1.0, np.zeros(3), size, sid))
    for k, b in enumerate(spec.boxes):
        lo, hi = np.array(b.min_xyz_m), np.array(b.max_xyz_m)
        for axis in range(3):
            planes.append((axis, lo[axis], -1.0, lo, hi, 6 + k))
            planes.append((axis, hi[axis], 1.0, lo, hi, 6 + k))
    t_out = np.full(len(origins), np.inf)
    sid_out = np.full(len(origins), -1)
    normal_out = np.zeros((len(origins), 3))
    for n, (o, d) in enumerate(zip(origins, dirs, strict=True)):
        for axis, c, sign, lo, hi, sid in planes:
            if d[axis] * sign >= 0:  # one-sided: seen only against its normal
                continue
            t = (c - o[axis]) / d[axis]
            if t < 0 or t >= t_out[n]:
                continue
            p = o + t * d
            others = [a for a in range(3) if a != axis]
            if all(lo[a] - 1e-9 <= p[a] <= hi[a] + 1e-9 for a in others):
                t_out[n], sid_out[n] = t, sid
                normal_out[n] = 0.0
                normal_out[n, axis] = sign
    return t_out, sid_out, normal_out


def _random_rays(spec, n, rng):
    size = np.array(spec.size_xyz_m)
    origins = rng.uniform(-0.3, 1.3, size=(n, 3)) * size  # some outside the room, some inside boxes
    dirs = rng.normal(size=(n, 3))
    dirs[: n // 4, rng.integers(3)] = 0.0  # zero components
    dirs[n // 4: n // 3] = np.eye(3)[rng.integers(3, size=n // 3 - n // 4)] * rng.choice([-1, 1], size=(n // 3 - n // 4, 1))
    return origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


@pytest.mark.parametrize("name", ROOM_PRESETS)
def test_matches_plain_twin(oracles, name):
    spec = oracles[name].spec
    origins, dirs = _random_rays(spec, 400, np.random.default_rng(ROOM_PRESETS.index(name)))
    hits = cast(spec, origins, dirs)
    t, sid, normal = _reference_cast(spec, origins, dirs)
    assert np.isinf(t).sum() > 10 and (sid >= 6).sum() > 10  # the batch exercises misses and boxes
    np.testing.assert_array_equal(hits.surface_id, sid)
    np.testing.assert_allclose(hits.t, t, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(hits.normal, normal)


def test_batching_and_shared_origin_do_not_change_results(monkeypatch):
    spec, tex = SPEC, bake_room_textures(SPEC)
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(500, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = np.tile([3.3, 2.1, 1.4], (500, 1))  # one shared origin: the camera fast path
    full = cast(spec, origins, dirs, tex, footprint_rad=0.01)
    mixed = cast(spec, np.vstack([origins, [[4.0, 3.0, 1.0]]]), np.vstack([dirs, [[0.0, 0.0, 1.0]]]), tex,
                 footprint_rad=0.01)  # general path
    monkeypatch.setattr(raycast, "CHUNK_RAYS", 37)
    small = cast(spec, origins, dirs, tex, footprint_rad=0.01)
    for name in ("t", "normal", "surface_id", "face", "point", "rgb"):
        np.testing.assert_array_equal(getattr(full, name), getattr(small, name))
        np.testing.assert_array_equal(getattr(full, name), getattr(mixed, name)[:500])


def test_shading_is_lambertian_and_view_independent():
    flat = Lighting(ambient=0.3, sun_intensity=0.0, lamp_intensity=0.0)
    hits = cast(SPEC, np.array([[4.0, 2.0, 1.0], [3.0, 2.0, 1.0]]), np.array([[0, 0, -1.0], [0, 0, 1.0]]),
                lighting=flat)
    np.testing.assert_allclose(hits.rgb, 0.3)  # no textures: albedo 1, only the ambient term
    sun = Lighting(ambient=0.2, sun_dir_xyz=(0.0, 0.6, 0.8), sun_intensity=0.5, lamp_intensity=0.0)
    hits = cast(SPEC, np.array([[4.0, 2.0, 1.0], [4.0, 2.0, 1.0]]), np.array([[0, 0, -1.0], [0, -1.0, 0]]),
                lighting=sun)
    np.testing.assert_allclose(hits.rgb[0], 0.2 + 0.5 * 0.8)  # floor, n = +z
    np.testing.assert_allclose(hits.rgb[1], 0.2 + 0.5 * 0.6)  # wall y = 0, n = +y
    # one floor point seen from two places: same colour (no view dependence)
    tex = bake_room_textures(SPEC)
    target = np.array([4.3, 2.7, 0.0])
    origins = np.array([[3.0, 1.0, 2.0], [5.5, 3.5, 0.7]])
    dirs = target - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = cast(SPEC, origins, dirs, tex)
    np.testing.assert_allclose(hits.point, np.tile(target, (2, 1)), atol=1e-12)
    np.testing.assert_allclose(hits.rgb[0], hits.rgb[1], atol=1e-5)
    assert hits.rgb.min() >= 0.0 and hits.rgb.max() <= 1.0


def test_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cast(SPEC, np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cast(SPEC, np.zeros((4, 2)), np.zeros((4, 2)))
