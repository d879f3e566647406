"""The oracle with people: depth, masks and LiDAR against plain ray casting, occlusion both ways, no-op cases."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import look_at, make_se3
from nsim.human.gait import walk_cycle
from nsim.sensors.lidar import LidarConfig, beam_directions
from nsim.synth.actor import Actor
from nsim.synth.oracle import PlacedActor, RoomOracle
from tests.synth.simple_room import simple_spec

W, H = 49, 37  # odd: the centre pixel's ray is the optical axis
CAMERA = Camera.pinhole_from_fov(W, H, 60.0)


@pytest.fixture(scope="module")
def oracle() -> RoomOracle:
    return RoomOracle(simple_spec())


@pytest.fixture(scope="module")
def actor() -> Actor:
    return Actor(1.75, seed=3)


def _rest_at(actor: Actor, x: float, y: float) -> np.ndarray:
    T = actor.skeleton.rest_transforms().copy()
    T[:, 0, 3] += x
    T[:, 1, 3] += y
    return T


def _walking_at(actor: Actor, x: float, y: float, frame: int = 7, yaw_deg: float = 0.0) -> np.ndarray:
    """A walking pose with the pelvis over ``(x, y)``, heading turned by ``yaw_deg``."""
    T = walk_cycle(1.3, actor.height_m).joint_transforms()[frame]
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    place = make_se3(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), [x, y, 0.0])
    place[:2, 3] -= place[:2, :2] @ T[0, :2, 3]
    return place @ T


def _rays(camera: Camera, c2w: np.ndarray, offsets=((0.0, 0.0),)) -> tuple[np.ndarray, np.ndarray]:
    """World rays of every pixel (and sub-pixel offset), built like the oracle builds them: ``(H*W*k, 3)``."""
    jj, ii = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    uv = np.stack([jj, ii], axis=-1)[:, :, None, :] + np.asarray(offsets)[None, None]
    d = np.asarray(camera.unproject(uv), dtype=np.float64).reshape(-1, 3)
    d = np.einsum("ij,nj->ni", c2w[:3, :3], d)
    return np.broadcast_to(c2w[:3, 3], d.shape).copy(), d


def _plain(oracle: RoomOracle, actor: Actor, T: np.ndarray, o: np.ndarray, d: np.ndarray):
    """Reference: every ray cast at the room and at the actor, nearest wins. Returns (t, actor seen)."""
    room = oracle.cast_rays(o, d)
    hits = actor.intersect(o, d, T, oracle.lighting, oracle.lighting.lamp_xyz_m(oracle.spec))
    seen = hits.hit & (hits.t < room.t)
    return np.where(seen, hits.t, room.t), seen


def test_depth_and_mask_match_plain_ray_casting(oracle, actor):
    T = _walking_at(actor, 3.0, 2.0)
    c2w = look_at([5.5, 2.3, 1.4], [3.0, 2.0, 0.95])
    view = oracle.render_gt(CAMERA, c2w, actors=[(actor, T)])
    t, seen = _plain(oracle, actor, T, *_rays(CAMERA, c2w))
    assert 0.05 < seen.mean() < 0.6
    np.testing.assert_array_equal(view.instance_mask.ravel(), seen.astype(np.int32))
    np.testing.assert_allclose(view.depth_range.ravel(), t, rtol=1e-6)
    dirs_z = CAMERA.unproject(np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1).astype(float))[..., 2]
    np.testing.assert_allclose(view.depth_z, view.depth_range * dirs_z, rtol=1e-6)
    assert np.all(view.part_id[view.instance_mask == 0] == -1) and np.all(view.part_id[view.instance_mask == 1] >= 0)
    np.testing.assert_array_equal(view.soft_masks, (view.instance_mask == 1)[None].astype(np.float32))
    np.testing.assert_array_equal(view.room_rgb, oracle.render_gt(CAMERA, c2w).rgb)
    rgb, depth_z, depth_range = view  # still unpacks like the old 3-tuple
    assert rgb.shape == (H, W, 3) and depth_z is view.depth_z and depth_range is view.depth_range


def test_chest_depth_is_analytic(oracle, actor):
    """Facing the T-posed actor along -x at chest height: the centre pixel hits the chest ellipsoid's front."""
    T = _rest_at(actor, 3.0, 2.0)
    k = actor.part_names.index("chest")
    part = actor.parts[k]
    chest = T[part.joint, :3, 3] + np.asarray(part.a_m)  # rest pose: joint frames are world-aligned
    eye = np.array([5.2, chest[1], chest[2]])
    view = oracle.render_gt(CAMERA, look_at(eye, eye - [1.0, 0.0, 0.0]), actors=[PlacedActor(actor, T)])
    r, c = H // 2, W // 2
    assert view.instance_mask[r, c] == 1 and view.part_id[r, c] == k
    assert view.depth_z[r, c] == pytest.approx(eye[0] - chest[0] - part.axes_m[0], abs=1e-5)


def test_furniture_occludes_the_actor(oracle, actor):
    """Low camera, the actor behind the cube: its legs are hidden, its upper body is seen over the cube."""
    T = _walking_at(actor, 0.55, 1.5, yaw_deg=90.0)
    c2w = look_at([5.7, 1.5, 0.7], [0.5, 1.5, 1.0])
    tele = Camera.pinhole_from_fov(W, H, 22.0)
    view = oracle.render_gt(tele, c2w, actors=[(actor, T)])
    o, d = _rays(tele, c2w)
    hits = actor.intersect(o, d, T)
    room = oracle.cast_rays(o, d)
    hidden = hits.hit & (room.t < hits.t)
    assert hidden.sum() > 20  # the cube hides part of the person ...
    assert (view.instance_mask.ravel()[hidden] == 0).all()
    np.testing.assert_allclose(view.depth_range.ravel()[hidden], room.t[hidden], rtol=1e-6)
    assert (view.instance_mask == 1).sum() > 20  # ... and the rest is seen over it


def test_soft_masks_match_sub_pixel_rays(oracle, actor):
    """With supersampling the soft mask is the fraction of sub-pixel rays that see the actor (exact culling)."""
    T = _walking_at(actor, 3.0, 2.0, frame=20)
    c2w = look_at([5.0, 1.2, 1.5], [3.0, 2.0, 0.9])
    view = oracle.render_gt(CAMERA, c2w, supersample=2, actors=[(actor, T)])
    room_only = oracle.render_gt(CAMERA, c2w, supersample=2)
    np.testing.assert_array_equal(view.room_rgb, room_only.rgb)  # the background behind the person
    outside = (view.soft_masks[0] == 0)[..., None]
    np.testing.assert_array_equal(np.where(outside, view.rgb, 0), np.where(outside, room_only.rgb, 0))
    offsets = [(ox, oy) for oy in (-0.25, 0.25) for ox in (-0.25, 0.25)]
    _, seen = _plain(oracle, actor, T, *_rays(CAMERA, c2w, offsets))
    expected = seen.reshape(H, W, 4).mean(axis=-1).astype(np.float32)
    np.testing.assert_array_equal(view.soft_masks[0], expected)
    fractional = (expected > 0) & (expected < 1)
    assert fractional.sum() > 10  # the silhouette is anti-aliased
    # depth and the hard mask still come from the centre ray, as without supersampling
    one = oracle.render_gt(CAMERA, c2w, supersample=1, actors=[(actor, T)])
    np.testing.assert_array_equal(view.instance_mask, one.instance_mask)
    np.testing.assert_array_equal(view.depth_range, one.depth_range)


def test_no_actor_and_actor_behind_camera_change_nothing(oracle, actor):
    c2w = look_at([4.5, 2.0, 1.3], [1.0, 2.0, 1.0])
    plain = oracle.render_gt(CAMERA, c2w, supersample=2)
    behind = oracle.render_gt(CAMERA, c2w, supersample=2, actors=[(actor, _walking_at(actor, 5.5, 2.0))])
    empty = oracle.render_gt(CAMERA, c2w, supersample=2, actors=[])
    for view in (behind, empty):
        for a, b in zip(plain, view, strict=True):
            np.testing.assert_array_equal(a, b)
    assert not behind.instance_mask.any() and (behind.part_id == -1).all()
    assert behind.soft_masks.shape == (1, H, W) and not behind.soft_masks.any()
    assert plain.soft_masks.shape == (0, H, W) and not plain.instance_mask.any() and plain.room_rgb is plain.rgb
    np.testing.assert_array_equal(behind.room_rgb, plain.rgb)


def test_instance_ids_and_bad_actors(oracle, actor):
    c2w = look_at([5.5, 2.0, 1.4], [2.5, 2.0, 0.9])
    a = PlacedActor(actor, _rest_at(actor, 3.0, 1.3), instance_id=5)
    b = PlacedActor(Actor(1.6, seed=1), _rest_at(Actor(1.6), 3.5, 2.9), instance_id=9)
    view = oracle.render_gt(CAMERA, c2w, actors=[a, b])
    assert set(np.unique(view.instance_mask)) == {0, 5, 9}
    assert view.soft_masks.shape == (2, H, W)
    np.testing.assert_array_equal(view.soft_masks[0] > 0, view.instance_mask == 5)
    with pytest.raises(ValueError, match="unique"):
        oracle.render_gt(CAMERA, c2w, actors=[a, PlacedActor(actor, a.joint_transforms, 5)])
    with pytest.raises(ValueError, match=r"actors\[0\].joint_transforms"):
        oracle.render_gt(CAMERA, c2w, actors=[(actor, np.eye(4))])
    with pytest.raises(ValueError, match="instance_id"):
        oracle.render_gt(CAMERA, c2w, actors=[PlacedActor(actor, a.joint_transforms, 0)])


def test_lidar_returns_from_the_actor(oracle, actor):
    T = _walking_at(actor, 3.0, 2.0)
    cfg = LidarConfig(channels=16, azimuth_samples=360, min_range_m=0.0)
    pose = make_se3(np.diag([-1.0, -1.0, 1.0]), np.array([5.0, 2.0, 1.0]))  # facing -x, at the actor
    plain = oracle.lidar_gt(pose, cfg)
    scan = oracle.lidar_gt(pose, cfg, actors=[(actor, T)])
    on = scan.instance_id == 1
    assert on.sum() > 10
    dirs = beam_directions(cfg).reshape(-1, 3) @ pose[:3, :3].T
    hits = actor.intersect(np.tile(pose[:3, 3], (len(dirs), 1)), dirs, T)
    np.testing.assert_allclose(scan.ranges_m[on], hits.t.reshape(on.shape)[on], rtol=1e-6)
    assert (scan.surface_id[on] == -1).all() and (scan.ranges_m[on] < plain.ranges_m[on]).all()
    np.testing.assert_array_equal(scan.ranges_m[~on], plain.ranges_m[~on])
    np.testing.assert_array_equal(scan.surface_id[~on], plain.surface_id[~on])
    assert not plain.instance_id.any()
