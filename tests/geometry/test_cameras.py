"""Camera models: agreement with OpenCV, round trips on every pixel, numpy/torch twins, gradients."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import torch

from nsim.geometry.cameras import Camera

CAMERAS = {
    "pinhole": Camera("PINHOLE", 64, 48, 55.0, 57.0, 31.7, 23.2),
    "opencv": Camera("OPENCV", 64, 48, 50.0, 51.0, 32.3, 23.6, (-0.28, 0.07, 1e-3, -5e-4, -0.005)),
    "opencv_strong": Camera("OPENCV", 192, 108, 100.0, 100.0, 95.5, 53.5, (-0.3, 0.1, 1e-3, -5e-4, -0.01)),
    "opencv4": Camera("OPENCV", 80, 60, 70.0, 70.0, 39.5, 29.5, (0.1, -0.02, -2e-3, 1e-3)),
    # OpenCV's rational model, as a wide lens calibrates (the k4..k6 denominator tames the polynomial)
    "full_opencv": Camera("FULL_OPENCV", 64, 48, 50.0, 51.0, 32.3, 23.6,
                          (0.3, -0.05, 1e-3, -5e-4, 0.002, 0.6, -0.02, 0.005)),
    "fisheye": Camera.fisheye_spot_like(64, 48),
    "equirect": Camera.equirect(64, 32),
}
ALL = list(CAMERAS)


def _pixel_grid(cam: Camera) -> np.ndarray:
    return np.stack(np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float)), -1)


def _angle_rad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1))


def _random_points(n: int, seed: int = 0) -> np.ndarray:
    """Points in front of a camera at 0.2..5 m, up to ~70 deg off axis."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.2, 5.0, n)
    xy = rng.uniform(-2.5, 2.5, (n, 2)) * z[:, None]
    return np.column_stack([xy, z])


@pytest.mark.parametrize("name", ["pinhole", "opencv", "opencv_strong", "opencv4", "full_opencv"])
def test_project_matches_cv2(name):
    cam = CAMERAS[name]
    p = _random_points(2000)
    uv, _ = cam.project(p)
    dist = np.array(cam.dist) if cam.dist else None
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, dist)
    np.testing.assert_allclose(uv, ref[:, 0], rtol=0, atol=1e-6)


def test_project_matches_cv2_fisheye():
    cam = CAMERAS["fisheye"]
    p = _random_points(2000)
    uv, valid = cam.project(p)
    ref, _ = cv2.fisheye.projectPoints(p[:, None], np.zeros(3), np.zeros(3), cam.K, np.array(cam.dist))
    np.testing.assert_allclose(uv, ref[:, 0], rtol=0, atol=1e-6)
    assert valid.any() and not valid.all()


@pytest.mark.parametrize("name", ALL)
def test_project_unproject_every_pixel(name):
    cam = CAMERAS[name]
    grid = _pixel_grid(cam)
    dirs = cam.unproject(grid)
    assert dirs.shape == (cam.height, cam.width, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)
    uv, valid = cam.project(dirs * 3.0)
    assert valid.all()
    assert np.abs(uv - grid).max() < 1e-9


def test_project_unproject_every_pixel_full_size_spot():
    cam = Camera.fisheye_spot_like()
    uv, valid = cam.project(cam.pixel_dirs_cam())
    assert valid.all()
    assert np.abs(uv - _pixel_grid(cam)).max() < 1e-9


@pytest.mark.parametrize("name", ALL)
def test_unproject_project_points(name):
    cam = CAMERAS[name]
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(5000, 3))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    uv, valid = cam.project(dirs * rng.uniform(0.1, 10.0, (5000, 1)))
    assert valid.sum() > 100
    back = cam.unproject(uv[valid])
    assert _angle_rad(back, dirs[valid]).max() < 1e-7


@pytest.mark.parametrize("name", ALL)
def test_numpy_torch_agree(name):
    cam = CAMERAS[name]
    p = _random_points(500, seed=2)
    uv_np, valid_np = cam.project(p)
    uv_t, valid_t = cam.project(torch.from_numpy(p))
    np.testing.assert_allclose(uv_t.numpy(), uv_np, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(valid_t.numpy(), valid_np)
    grid = _pixel_grid(cam)
    np.testing.assert_allclose(cam.unproject(torch.from_numpy(grid)).numpy(), cam.unproject(grid), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ALL)
def test_gradcheck(name):
    cam = CAMERAS[name]
    p = torch.tensor([[0.1, 0.2, 1.0], [-0.3, 0.1, 0.8], [0.05, -0.2, 2.0]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda q: cam.project(q)[0], (p,))
    uv = torch.tensor([[3.3, 4.1], [40.2, 20.7], [60.0, 30.5]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(cam.unproject, (uv,))


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.gpu)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("name", ALL)
def test_torch_keeps_dtype_and_device(name, dtype, device):
    cam = CAMERAS[name]
    p = torch.tensor(_random_points(10), dtype=dtype, device=device)
    uv, valid = cam.project(p)
    assert uv.dtype == dtype and uv.device == p.device and valid.dtype == torch.bool and valid.device == p.device
    dirs = cam.unproject(uv)
    assert dirs.dtype == dtype and dirs.device == p.device and dirs.shape == (10, 3)
    c2w = torch.eye(4, dtype=dtype, device=device).expand(2, 4, 4)
    origins, dirs = cam.pixel_rays(c2w)
    assert origins.shape == dirs.shape == (2, cam.height, cam.width, 3)
    assert dirs.dtype == dtype and dirs.device == p.device


def test_valid_flags():
    pin, fish, eq = CAMERAS["pinhole"], CAMERAS["fisheye"], CAMERAS["equirect"]
    behind = np.array([[0.0, 0.0, -1.0], [0.01, 0.0, -1.0]])
    outside = np.array([[10.0, 0.0, 1.0], [0.0, -10.0, 1.0]])
    assert not pin.project(behind)[1].any()
    assert not pin.project(outside)[1].any()
    assert not pin.project(np.zeros(3))[1]
    t, phi = math.radians(100), math.atan2(fish.height, fish.width)  # 100 deg off axis, towards a corner
    assert fish.project(np.array([math.sin(t) * math.cos(phi), math.sin(t) * math.sin(phi), math.cos(t)]))[1]
    assert eq.project(behind)[1].all()
    assert not eq.project(np.zeros(3))[1]


def test_opencv_fold_is_invalid():
    """Past the radius where strong barrel distortion folds back, points must not count as visible."""
    cam = Camera("OPENCV", 640, 480, 300.0, 300.0, 319.5, 239.5, (-0.4, 0.0, 0.0, 0.0, 0.0))
    r_fold = math.sqrt(1 / 1.2)  # d/dr [r (1 - 0.4 r^2)] = 0
    assert cam.max_angle_rad == pytest.approx(math.atan(r_fold))
    _, valid = cam.project(np.array([[1.5 * r_fold, 0.0, 1.0], [0.9 * r_fold, 0.0, 1.0]]))
    assert valid.tolist() == [False, True]


@pytest.mark.parametrize("shape", [(), (7,), (2, 3)])
def test_shapes(shape):
    cam = CAMERAS["opencv"]
    uv, valid = cam.project(np.ones(shape + (3,)))
    assert uv.shape == shape + (2,) and valid.shape == shape
    assert cam.unproject(np.ones(shape + (2,))).shape == shape + (3,)
    with pytest.raises(ValueError, match="points_cam"):
        cam.project(np.ones(shape + (2,)))


def test_pixel_rays():
    cam = Camera("PINHOLE", 65, 49, 40.0, 40.0, 32.0, 24.0)
    rng = np.random.default_rng(3)
    from scipy.spatial.transform import Rotation

    c2w = np.tile(np.eye(4), (2, 3, 1, 1))
    c2w[..., :3, :3] = Rotation.random(6, random_state=rng).as_matrix().reshape(2, 3, 3, 3)
    c2w[..., :3, 3] = rng.normal(size=(2, 3, 3))
    origins, dirs = cam.pixel_rays(c2w)
    assert origins.shape == dirs.shape == (2, 3, 49, 65, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(origins, np.broadcast_to(c2w[..., None, None, :3, 3], origins.shape))
    np.testing.assert_allclose(dirs[..., 24, 32, :], c2w[..., :3, 2], atol=1e-15)  # centre pixel: camera +z
    np.testing.assert_allclose(cam.pixel_dirs_cam()[24, 32], [0.0, 0.0, 1.0])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(model="KB8"), "unknown camera model"),
        (dict(width=0), "width"),
        (dict(height=-4), "height"),
        (dict(width=64.0), "width"),
        (dict(fx=0.0), "fx"),
        (dict(fy=-1.0), "fy"),
        (dict(cx=float("nan")), "cx"),
        (dict(fx=float("inf")), "fx"),
        (dict(dist=(0.1,)), "dist"),
        (dict(dist=(0.1, 0.0, 0.0, 0.0, 0.0, 0.0)), "dist"),
        (dict(dist=(0.1, float("nan"), 0.0, 0.0)), "dist"),
        (dict(model="PINHOLE", dist=(0.1, 0.0, 0.0, 0.0)), "dist"),
        (dict(model="OPENCV_FISHEYE", dist=(0.1, 0.0, 0.0, 0.0, 0.0)), "dist"),
        (dict(model="FULL_OPENCV", dist=(0.1, 0.0, 0.0, 0.0, 0.0)), r"FULL_OPENCV takes \(k1, k2, p1, p2, k3, k4, k5, k6\)"),
        (dict(dist="abcd"), "dist"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    args = dict(model="OPENCV", width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, dist=(0.0,) * 4) | kwargs
    with pytest.raises(ValueError, match=match):
        Camera(**args)


def test_normalises_types():
    cam = Camera("OPENCV", np.int64(64), 48, 50, np.float32(50.0), 31.5, 23.5, [0.1, 0, 0, 0])
    assert type(cam.width) is int and type(cam.fx) is float and type(cam.fy) is float
    assert cam.dist == (0.1, 0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("name", ALL)
def test_dict_round_trip(name):
    cam = CAMERAS[name]
    assert Camera.from_dict(json.loads(json.dumps(cam.to_dict()))) == cam
    with pytest.raises(ValueError, match="unknown keys"):
        Camera.from_dict(cam.to_dict() | {"fov": 1.0})
    with pytest.raises(ValueError, match="missing keys"):
        Camera.from_dict({k: v for k, v in cam.to_dict().items() if k != "fx"})


@pytest.mark.parametrize("name", ["pinhole", "opencv", "full_opencv", "fisheye"])
def test_scaled_keeps_image_edges(name):
    cam = CAMERAS[name]
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (cam.width // 2, cam.height // 2)
    p = _random_points(200, seed=4)
    uv, _ = cam.project(p)
    uv_half, _ = half.project(p)
    np.testing.assert_allclose(uv_half, (uv + 0.5) * 0.5 - 0.5, atol=1e-9)
    with pytest.raises(ValueError):
        cam.scaled(0.0)


def test_equirect_intrinsics_follow_size():
    cam = Camera("EQUIRECTANGULAR", 200, 100, 1.0, 1.0, 0.0, 0.0)
    assert cam == Camera.equirect(200, 100) == Camera.equirect(100, 50).scaled(2.0)
    assert cam.fx == pytest.approx(200 / (2 * math.pi)) and cam.cy == 49.5
    uv, _ = cam.project(np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(uv, [[99.5, 49.5], [99.5, -0.5], [49.5, 49.5]], atol=1e-12)


def test_fov_and_factories():
    assert Camera.pinhole_from_fov(640, 480, 90.0).fov_deg[0] == pytest.approx(90.0)
    assert Camera.pinhole_from_fov(640, 480, 90.0).fov_deg[1] == pytest.approx(2 * math.degrees(math.atan(0.75)))
    spot = Camera.fisheye_spot_like()
    assert spot.model == "OPENCV_FISHEYE" and all(k != 0.0 for k in spot.dist)
    assert spot.fov_deg[0] == pytest.approx(180.0)
    assert CAMERAS["equirect"].fov_deg == (360.0, 180.0)
    with pytest.raises(ValueError):
        Camera.pinhole_from_fov(640, 480, 180.0)


def test_K():
    cam = CAMERAS["opencv"]
    np.testing.assert_array_equal(cam.K, [[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])


def test_full_opencv_matches_cv2_rational_flag():
    """The 8-coefficient vector is cv2's rational model: same pixels as cv2.projectPoints, also strong terms."""
    dist = (-0.4, 0.15, 2e-3, -1e-3, -0.02, -0.1, 0.05, 0.01)
    cam = Camera("FULL_OPENCV", 640, 480, 300.0, 310.0, 319.2, 241.7, dist)
    p = _random_points(3000, seed=9)
    uv, valid = cam.project(p)
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, np.array(dist))
    np.testing.assert_allclose(uv, ref[:, 0], rtol=0, atol=1e-6)
    # round trip away from the fold, where Newton has a well-conditioned Jacobian (as for OPENCV)
    inner = valid & (_angle_rad(p, np.array([0.0, 0.0, 1.0])) < 0.95 * cam.max_angle_rad)
    assert inner.sum() > 100 and _angle_rad(cam.unproject(uv[inner]), p[inner]).max() < 1e-9


def test_full_opencv_without_rational_terms_is_opencv():
    k = (-0.28, 0.07, 1e-3, -5e-4, -0.005)
    plain = Camera("OPENCV", 64, 48, 50.0, 51.0, 32.3, 23.6, k)
    full = Camera("FULL_OPENCV", 64, 48, 50.0, 51.0, 32.3, 23.6, k + (0.0, 0.0, 0.0))
    assert full.max_angle_rad == pytest.approx(plain.max_angle_rad, rel=1e-12)
    p = _random_points(500, seed=3)
    np.testing.assert_allclose(full.project(p)[0], plain.project(p)[0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(full.project(p)[1], plain.project(p)[1])
    grid = _pixel_grid(plain)
    np.testing.assert_allclose(full.unproject(grid), plain.unproject(grid), rtol=0, atol=1e-12)


def test_full_opencv_max_angle():
    """Where r_d(r) = r radial(r^2) stops increasing (found numerically), or at a pole of the denominator."""
    cam = Camera("FULL_OPENCV", 640, 480, 300.0, 300.0, 319.5, 239.5, (-0.4, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0))
    r = np.linspace(0.0, 3.0, 300_001)
    r_d = r * (1 - 0.4 * r**2) / (1 + 0.3 * r**2)
    r_fold = r[np.argmax(np.diff(r_d) < 0)]
    assert cam.max_angle_rad == pytest.approx(math.atan(r_fold), abs=1e-4)
    _, valid = cam.project(np.array([[1.2 * r_fold, 0.0, 1.0], [0.9 * r_fold, 0.0, 1.0]]))
    assert valid.tolist() == [False, True]
    pole = Camera("FULL_OPENCV", 640, 480, 300.0, 300.0, 319.5, 239.5, (0.0,) * 5 + (-1.0, 0.0, 0.0))
    assert pole.max_angle_rad == pytest.approx(math.pi / 4)  # 1 - r^2 = 0 at r = 1; r / (1 - r^2) rises until then
    tame = CAMERAS["full_opencv"]
    assert 0.0 < tame.max_angle_rad < math.pi / 2
