"""Visibility culling: where the paper's corner test fails, and the corrected bounds against brute force."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nsim.geometry import Camera, invert_se3, look_at
from nsim.rendering.culling import (
    OrientedBox,
    bounds_to_pixel_box,
    camera_box_bounds,
    lidar_ray_box_mask,
    naive_corner_bounds,
    naive_corner_test,
    pixels_in_bounds,
    ray_box_intervals,
)
from nsim.sensors import Rig

ROBOTS = Path(__file__).resolve().parents[2] / "nsim" / "configs" / "robots"
PINHOLE = Camera.pinhole_from_fov(160, 120, 60.0)
CAMERAS = {
    "pinhole": PINHOLE,
    "opencv": Camera("OPENCV", 160, 120, 110.0, 108.0, 81.0, 58.5, (-0.25, 0.06, 0.001, -0.001, 0.0)),
    "fisheye": Camera.fisheye_spot_like(160, 120),
    "equirect": Camera.equirect(160, 80),
}
IDENTITY = np.eye(4)  # world_to_cam: the camera at the origin looking along +z (OpenCV axes)


def box(center, half, yaw_deg=0.0) -> OrientedBox:
    a = math.radians(yaw_deg)
    R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return OrientedBox(np.asarray(center, float), np.asarray(half, float), R)


def brute_force_bounds(camera: Camera, world_to_cam: np.ndarray, b: OrientedBox, n: int = 41):
    """Extent of the pixels of a dense grid through the box's volume that project into the image."""
    g = np.linspace(-1.0, 1.0, n)
    local = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * b.half_extents
    world = b.center + local @ b.rotation.T
    uv, ok = camera.project(world @ world_to_cam[:3, :3].T + world_to_cam[:3, 3])
    if not ok.any():
        return None, uv[ok]
    uv = uv[ok]
    return (uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()), uv


def contains(bounds, uv, tol=1e-6) -> bool:
    u0, v0, u1, v1 = bounds
    return bool(np.all((uv[:, 0] >= u0 - tol) & (uv[:, 0] <= u1 + tol) & (uv[:, 1] >= v0 - tol) & (uv[:, 1] <= v1 + tol)))


FULL = (-0.5, -0.5, 159.5, 119.5)


# ------------------------------------------------------------------ the cases where corner-only testing is wrong


def test_box_surrounding_the_camera():
    b = box([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])  # a person's box that the camera is inside of
    assert not naive_corner_test(PINHOLE, IDENTITY, b.corners())  # every corner is outside the view
    truth, uv = brute_force_bounds(PINHOLE, IDENTITY, b)
    assert truth == pytest.approx(FULL, abs=1.0)  # yet the box fills the image
    assert camera_box_bounds(PINHOLE, IDENTITY, b) == pytest.approx(FULL)


def test_box_larger_than_the_image():
    b = box([0.0, 0.0, 1.0], [3.0, 3.0, 0.2])  # right in front of the lens, all corners outside the image
    uv = PINHOLE.project(b.corners())[0]
    assert not np.any((uv[:, 0] >= 0) & (uv[:, 0] < 160) & (uv[:, 1] >= 0) & (uv[:, 1] < 120))
    assert not naive_corner_test(PINHOLE, IDENTITY, b)
    truth, uv = brute_force_bounds(PINHOLE, IDENTITY, b)
    assert truth == pytest.approx(FULL, abs=1.0)
    assert camera_box_bounds(PINHOLE, IDENTITY, b) == pytest.approx(FULL)


def test_box_behind_the_camera_is_not_visible():
    b = box([0.0, 0.0, -2.0], [0.3, 0.3, 0.3])  # projects through K with a flipped sign into the image
    assert naive_corner_test(PINHOLE, IDENTITY, b)  # false positive
    assert brute_force_bounds(PINHOLE, IDENTITY, b)[0] is None
    for camera in ("pinhole", "opencv", "fisheye"):
        assert camera_box_bounds(CAMERAS[camera], IDENTITY, b) is None, camera


def test_box_straddling_the_image_plane():
    b = box([0.3, 0.0, 0.0], [0.2, 0.3, 2.0])  # from 2 m behind to 2 m in front, to the right
    naive = naive_corner_bounds(PINHOLE, IDENTITY, b)
    truth, uv = brute_force_bounds(PINHOLE, IDENTITY, b)
    assert naive is not None and not contains(naive, uv)  # the naive bound misses visible parts
    corrected = camera_box_bounds(PINHOLE, IDENTITY, b)
    assert contains(corrected, uv)
    assert corrected[0] == pytest.approx(truth[0], abs=1e-9)  # the near edge is exact
    assert corrected[1:] == pytest.approx((-0.5, 159.5, 119.5))  # reaches the image's edges


def test_spot_person_right_in_front_of_a_fisheye():
    cam = Rig.load(ROBOTS / "spot.yaml")["frontleft"]
    body_to_world = np.eye(4)
    body_to_world[2, 3] = 0.5
    cam_to_world = cam.world_pose(body_to_world)
    forward = cam_to_world[:3, 2] * [1.0, 1.0, 0.0]
    ahead = cam_to_world[:3, 3] + 0.2 * forward / np.linalg.norm(forward)  # a person 0.2 m from the lens
    human_to_world = np.eye(4)
    human_to_world[:2, 3] = ahead[:2]
    b = OrientedBox.from_min_max([-0.3, -0.3, 0.0], [0.3, 0.3, 1.8], human_to_world)
    w2c = invert_se3(cam_to_world)
    truth, uv = brute_force_bounds(cam.camera, w2c, b, n=31)
    naive = naive_corner_bounds(cam.camera, w2c, b)
    assert naive is None or not contains(naive, uv)  # the corner bound cuts the person off
    bounds = camera_box_bounds(cam.camera, w2c, b)
    assert contains(bounds, uv) and bounds == pytest.approx((-0.5, -0.5, 639.5, 479.5))


# ------------------------------------------------------------------ brute force: the bound holds every visible point


def _random_cases(seed: int, n: int):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        center = rng.uniform([-3, -3, -3], [3, 3, 6])
        half = rng.uniform(0.05, 1.5, size=3)
        yield box(center, half, rng.uniform(0, 360))


@pytest.mark.parametrize("name", list(CAMERAS))
def test_bounds_contain_every_visible_point(name):
    camera = CAMERAS[name]
    eye = np.array([0.2, -0.1, 0.3])
    w2c = invert_se3(look_at(eye, eye + [0.3, 0.2, 1.0], up=[0.0, -1.0, 0.0]))
    seen = 0
    for b in _random_cases(7, 30):
        truth, uv = brute_force_bounds(camera, w2c, b, n=25)
        bounds = camera_box_bounds(camera, w2c, b)
        if truth is None:
            continue  # a box can be visible between the grid points; the bound may then be non-None
        seen += 1
        assert bounds is not None and contains(bounds, uv), (name, b.center, b.half_extents)
        u0, v0, u1, v1 = bounds
        assert -0.5 <= u0 <= u1 <= camera.width - 0.5 and -0.5 <= v0 <= v1 <= camera.height - 0.5
        # tight: no more than the grid spacing's image plus the sampling margin larger
        slack = 12.0 if name != "pinhole" else 8.0
        assert u0 >= truth[0] - slack and v0 >= truth[1] - slack, (name, bounds, truth)
        assert u1 <= truth[2] + slack and v1 <= truth[3] + slack, (name, bounds, truth)
    assert seen >= 10


def test_pinhole_bounds_are_exact_for_a_box_in_view():
    b = box([0.4, -0.2, 5.0], [0.3, 0.9, 0.25], yaw_deg=30.0)
    uv, ok = PINHOLE.project(b.corners())
    assert ok.all()
    assert camera_box_bounds(PINHOLE, IDENTITY, b) == pytest.approx(
        (uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()), abs=1e-9
    )
    assert naive_corner_test(PINHOLE, IDENTITY, b)  # the easy case, where the paper is right


def test_box_outside_the_field_of_view():
    b = box([8.0, 0.0, 1.0], [0.3, 0.3, 0.9])  # far to the right of a 60 deg camera
    assert camera_box_bounds(PINHOLE, IDENTITY, b) is None
    assert camera_box_bounds(CAMERAS["fisheye"], IDENTITY, b) is not None  # a 180 deg fisheye sees it


def test_fisheye_sees_beside_and_slightly_behind():
    cam = CAMERAS["fisheye"]
    b = box([3.0, 0.0, -0.2], [0.2, 0.2, 0.2])  # ~94 deg off-axis: outside a pinhole's half-space
    truth, uv = brute_force_bounds(cam, IDENTITY, b)
    bounds = camera_box_bounds(cam, IDENTITY, b)
    if truth is None:
        assert bounds is None or bounds[2] >= cam.width - 0.5 - 2  # only at the image's right edge
    else:
        assert contains(bounds, uv)


def test_pixel_box_covers_the_bound():
    assert bounds_to_pixel_box(PINHOLE, None) is None
    assert bounds_to_pixel_box(PINHOLE, FULL) == (0, 0, 160, 120)
    assert bounds_to_pixel_box(PINHOLE, (10.2, 3.7, 20.6, 4.4)) == (10, 4, 22, 5)  # pixel 4 covers [3.5, 4.5]


def test_world_to_cam_is_applied():
    cam_to_world = look_at([5.0, 5.0, 1.0], [5.0, 10.0, 1.0])
    b = box([5.0, 8.0, 1.0], [0.3, 0.3, 0.9])
    bounds = camera_box_bounds(PINHOLE, invert_se3(cam_to_world), b)
    assert bounds is not None and bounds[0] < 79.5 < bounds[2] and bounds[1] < 59.5 < bounds[3]
    assert camera_box_bounds(PINHOLE, invert_se3(look_at([5.0, 5.0, 1.0], [5.0, 0.0, 1.0])), b) is None


# ------------------------------------------------------------------ boxes and rays


def test_oriented_box_corners_round_trip():
    b = box([1.0, 2.0, 3.0], [0.1, 0.2, 0.3], yaw_deg=40.0)
    again = OrientedBox.from_corners(b.corners())
    np.testing.assert_allclose(again.corners(), b.corners(), atol=1e-12)
    posed = OrientedBox.from_min_max([-0.3, -0.2, 0.0], [0.3, 0.2, 1.8], look_at([1, 1, 0], [2, 1, 0]))
    np.testing.assert_allclose(posed.half_extents, [0.3, 0.2, 0.9])
    with pytest.raises(ValueError, match="not the corners of a box"):
        OrientedBox.from_corners(b.corners()[[1, 0, 2, 3, 4, 5, 6, 7]])


@pytest.mark.parametrize("name", ["pinhole", "opencv", "fisheye"])
def test_every_camera_ray_that_meets_the_box_is_in_the_bound(name):
    """pixels_in_bounds keeps every pixel whose ray meets the box (pixel centres are whole numbers,
    the bound's coordinates), and few others; a box at the image's right and bottom edges too."""
    camera = CAMERAS[name]
    # the last: a box square to the camera, its right edge 0.137 px right of a pixel centre (the old u + 0.5
    # test culled that column and the bottom row: 59 rays through the box)
    for b in (box([0.4, -0.2, 5.0], [0.3, 0.9, 0.25], yaw_deg=30.0), box([1.6, 1.1, 4.0], [0.5, 0.4, 0.3], yaw_deg=10.0),
              box([0.3, 0.1, 5.0], [0.4, 0.6, 0.3])):
        bounds = camera_box_bounds(camera, IDENTITY, b)
        assert bounds is not None
        keep = pixels_in_bounds(camera, bounds)
        origins, dirs = camera.pixel_rays(np.eye(4))
        ok = np.isfinite(dirs).all(-1).reshape(-1)
        hits = np.zeros(ok.shape, dtype=bool)
        hits[ok] = lidar_ray_box_mask(origins.reshape(-1, 3)[ok], dirs.reshape(-1, 3)[ok], b, 0.0, 100.0)
        assert hits.sum() > 20
        assert np.all(keep[hits])  # no ray through the box is culled
        col0, row0, col1, row1 = bounds_to_pixel_box(camera, bounds)
        assert keep.sum() <= (col1 - col0) * (row1 - row0)  # nothing outside the bound's pixels


def test_ray_box_slab_against_marching():
    rng = np.random.default_rng(2)
    b = box([1.0, 0.5, 0.2], [0.4, 0.8, 1.0], yaw_deg=35.0)
    origins = rng.uniform(-3, 3, size=(1500, 3))
    dirs = b.center + rng.normal(scale=0.9, size=(1500, 3)) - origins  # aimed near the box
    dirs[::2] *= -1.0  # half pointing away: the box is behind their origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    mask = lidar_ray_box_mask(origins, dirs, b, t_min=0.0, t_max=5.0)
    t = np.linspace(0.0, 5.0, 1001)
    marched = b.contains(origins[:, None, :] + t[None, :, None] * dirs[:, None, :]).any(axis=1)
    assert np.all(mask[marched])  # every ray that visibly enters the box is kept
    assert (mask & ~marched).sum() <= 0.01 * mask.sum()  # and little else (grazing rays between samples)
    assert 200 < mask.sum() < 750


def test_ray_box_special_cases():
    b = box([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    o = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [5.0, 0.0, 0.0], [5.0, 2.0, 0.0], [5.0, 1.0, 0.0], [5.0, 0.0, 0.0]])
    d = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    t0, t1 = ray_box_intervals(o, d, b)
    np.testing.assert_allclose([t0[0], t1[0]], [-1.0, 1.0])  # starts inside
    np.testing.assert_allclose([t0[1], t1[1]], [4.0, 6.0])
    mask = lidar_ray_box_mask(o, d, b, t_max=4.5)
    np.testing.assert_array_equal(mask, [True, True, False, False, True, True])  # behind; parallel miss; on a face
    assert not lidar_ray_box_mask(o[1:2], d[1:2], b, t_max=3.9)[0]  # the LiDAR's max range stops short


def test_lidar_culling_with_the_spot_rig():
    lidar = Rig.load(ROBOTS / "spot.yaml")["lidar"]
    body_to_world = np.eye(4)
    body_to_world[2, 3] = 0.5
    origins, dirs = lidar.rays(body_to_world)
    person = OrientedBox.from_min_max([-0.3, -0.3, 0.0], [0.3, 0.3, 1.8],
                                      np.block([[np.eye(3), np.array([[3.0], [0.0], [0.0]])], [np.zeros((1, 3)), 1.0]]))
    mask = lidar_ray_box_mask(origins, dirs, person, lidar.config.min_range_m, lidar.config.max_range_m)
    hit = mask.reshape(lidar.ray_shape)
    cols = np.flatnonzero(hit.any(axis=0))
    assert 0 < hit.sum() < hit.size // 10
    az = np.degrees(2 * np.pi * cols / 1800)
    az = np.where(az > 180, az - 360, az)
    assert np.all(np.abs(az) < 7.0)  # only beams towards +x, around the person (atan(0.3 / 2.7) = 6.3 deg)
