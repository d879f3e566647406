"""The test-room actor: exact ray casting of its parts, textures that tell front from back, compositing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from nsim.geometry.transforms import look_at
from nsim.human.gait import walk_cycle
from nsim.human.skeleton import pose_aabb
from nsim.synth.actor import Actor, composite_actors


@pytest.fixture(scope="module")
def actor() -> Actor:
    return Actor(1.75, seed=0)


def _rays_towards(origin, targets):
    d = np.asarray(targets, dtype=np.float64) - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(np.asarray(origin, dtype=np.float64), d.shape).copy(), d


def test_hits_a_capsule_at_the_analytic_distance(actor):
    T = actor.skeleton.rest_transforms()
    k = actor.part_names.index("left_thigh")
    part = actor.parts[k]
    hip = T[part.joint, :3, 3]
    z = hip[2] - 0.2  # halfway down the thigh, on its axis line
    o = np.array([[2.0, hip[1], z], [hip[0], hip[1], z - 0.0]])
    o[1, 0] = -2.0
    d = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    hits = actor.intersect(o, d, T)
    assert hits.hit.all() and (hits.part_id == k).all()
    np.testing.assert_allclose(hits.t, [2.0 - hip[0] - part.radius_m, 2.0 + hip[0] - part.radius_m], atol=1e-12)
    np.testing.assert_allclose(hits.normal, [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], atol=1e-9)


def test_hits_the_head_ellipsoid_from_above(actor):
    T = actor.skeleton.rest_transforms()
    k = actor.part_names.index("head")
    part = actor.parts[k]
    centre = T[part.joint, :3, :3] @ np.asarray(part.a_m) + T[part.joint, :3, 3]
    hits = actor.intersect(np.array([[centre[0], centre[1], 3.0]]), np.array([[0.0, 0.0, -1.0]]), T)
    assert hits.part_id[0] == k
    assert hits.t[0] == pytest.approx(3.0 - centre[2] - part.axes_m[2], abs=1e-12)


def test_misses_are_reported_as_misses(actor):
    T = actor.skeleton.rest_transforms()
    hits = actor.intersect(np.array([[5.0, 5.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]), T)
    assert not hits.hit[0] and np.isinf(hits.t[0]) and hits.part_id[0] == -1 and not hits.rgb.any()


def _view(actor, T, eye, target, n=48, half=0.25):
    u, v = np.meshgrid(np.linspace(-half, half, n), np.linspace(-1.2 * half, 1.2 * half, n))
    eye = np.asarray(eye, dtype=np.float64)
    fwd = np.asarray(target, dtype=np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    side = np.cross([0.0, 0.0, 1.0], fwd)
    side /= np.linalg.norm(side)
    up = np.cross(fwd, side)
    d = fwd + u.reshape(-1, 1) * side + v.reshape(-1, 1) * up
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return actor.intersect(np.broadcast_to(eye, d.shape).copy(), d, T)


def test_front_and_back_look_different(actor):
    T = actor.skeleton.rest_transforms()
    for part, target_z, half in (("chest", 1.38, 0.25), ("head", 1.67, 0.08)):
        front = _view(actor, T, [2.0, 0.0, target_z], [0.0, 0.0, target_z], half=half)
        back = _view(actor, T, [-2.0, 0.0, target_z], [0.0, 0.0, target_z], half=half)
        k = actor.part_names.index(part)
        f, b = front.rgb[front.part_id == k], back.rgb[back.part_id == k]
        assert len(f) > 50 and len(b) > 50
        # the print and the face add colours the plain back does not have
        assert np.abs(f.mean(0) - b.mean(0)).max() > 0.03 or abs(f.std() - b.std()) > 0.03, part


def test_appearance_is_seeded(actor):
    T = actor.skeleton.rest_transforms()
    a = _view(actor, T, [2.0, 0.3, 1.2], [0.0, 0.0, 1.0])
    b = _view(Actor(1.75, seed=0), T, [2.0, 0.3, 1.2], [0.0, 0.0, 1.0])
    c = _view(Actor(1.75, seed=1), T, [2.0, 0.3, 1.2], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.rgb, c.rgb)


def test_hits_lie_inside_the_pose_box_and_rendering_is_fast(actor):
    T = walk_cycle(1.3).joint_transforms()[7]
    W, H = 320, 240
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    d_cam = np.stack([(jj - W / 2) / 200.0, (ii - H / 2) / 200.0, np.ones((H, W))], -1).reshape(-1, 3)
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    # camera 2.5 m in front of the walker, looking back at it
    eye = np.array([T[0, 0, 3] + 2.5, T[0, 1, 3], 1.0])
    R = look_at(eye, np.array([T[0, 0, 3], T[0, 1, 3], 0.9]))[:3, :3]
    d = d_cam @ R.T
    o = np.broadcast_to(eye, d.shape).copy()
    t0 = time.process_time()  # CPU time (all threads): a busy machine does not count; a per-pixel loop would
    hits = actor.intersect(o, d, T, lamp_xyz_m=np.array([2.0, 2.0, 2.6]))
    elapsed = time.process_time() - t0
    assert hits.hit.mean() > 0.03
    assert elapsed < 10.0, f"320x240 actor render took {elapsed:.2f} s of CPU time"
    pts = o[hits.hit] + hits.t[hits.hit, None] * d[hits.hit]
    lo, hi = pose_aabb(actor.skeleton, T)
    assert np.all(pts >= lo) and np.all(pts <= hi)
    blo, bhi = actor.bounding_box(T)
    assert np.all(pts >= blo - 1e-9) and np.all(pts <= bhi + 1e-9)
    assert (hits.rgb[hits.hit] > 0).any() and hits.rgb.max() <= 1.0


def test_composite_keeps_the_nearest_surface(actor):
    T = actor.skeleton.rest_transforms()
    o, d = _rays_towards(np.array([3.0, 0.0, 1.2]), [[0.0, 0.0, 1.2], [0.0, 3.0, 1.2]])
    hits = actor.intersect(o, d, T)
    assert hits.hit.tolist() == [True, False]
    room_t = np.array([10.0, 10.0])
    room_rgb = np.full((2, 3), 0.5, dtype=np.float32)
    comp = composite_actors(room_t, room_rgb, [hits])
    assert comp.actor_index.tolist() == [0, -1]
    assert comp.t[0] == hits.t[0] and comp.t[1] == 10.0
    np.testing.assert_array_equal(comp.rgb[1], room_rgb[1])
    near_room = composite_actors(np.array([0.5, 10.0]), room_rgb, [hits])
    assert near_room.actor_index.tolist() == [-1, -1]
