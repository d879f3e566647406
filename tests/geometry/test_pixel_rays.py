"""Every pixel-ray entry point gives the rays of ``Camera.pixel_rays`` (the one definition).

Pinhole, OPENCV-distorted and fisheye cameras; the fisheye marks the pixels beyond its model's
reach invalid (NaN from ``unproject``), so each caller's invalid-pixel handling is checked too:
NaN where the caller keeps NaN, ``FORWARD_DIR`` (and a mask) where it needs a finite ray.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nsim.geometry.cameras import FORWARD_DIR, Camera, dirs_to_world, fill_invalid_dirs
from nsim.rendering.renderer import camera_rays
from nsim.sensors.rig import CameraSensor
from nsim.train.scene import SceneTrainer
from nsim.train.scene_eval import ViewRays
from nsim.train.scene_eval import pixel_rays as eval_pixel_rays
from nsim.volume.rays import camera_dirs, se3_exp

F32_ATOL = 2e-6  # float32 entry points against the float64 reference


@dataclass(frozen=True)
class ReachFisheye(Camera):
    """A fisheye whose pixels beyond the model's reach (``theta > max_angle_rad``) unproject to NaN."""

    def unproject(self, uv):
        d = super().unproject(uv)
        xp = torch if isinstance(d, torch.Tensor) else np
        mx = (uv[..., 0] - self.cx) / self.fx
        my = (uv[..., 1] - self.cy) / self.fy
        beyond = xp.sqrt(mx * mx + my * my) > self._fisheye_distort(self.max_angle_rad)
        return xp.where(beyond[..., None], xp.nan, d)


CAMERAS = {
    "pinhole": Camera("PINHOLE", 16, 12, 14.0, 15.0, 7.3, 5.6),
    "opencv": Camera("OPENCV", 16, 12, 10.0, 11.0, 7.5, 5.5, dist=(-0.2, 0.05, 0.001, -0.002, 0.01)),
    "fisheye": ReachFisheye("OPENCV_FISHEYE", 16, 12, 4.0, 4.0, 7.5, 5.5, dist=(-0.5, 0.0, 0.0, 0.0)),
}
C2W = se3_exp(torch.tensor([0.3, -0.2, 1.1, 0.4, -0.7, 0.25], dtype=torch.float64)).numpy()


@pytest.fixture(params=sorted(CAMERAS))
def cam(request) -> Camera:
    return CAMERAS[request.param]


def reference(cam: Camera):
    """``Camera.pixel_rays`` flattened row-major: origins, dirs ``(H*W, 3)`` float64, valid ``(H*W,)``."""
    o, d = cam.pixel_rays(C2W)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    return o, d, np.isfinite(d).all(-1)


def all_pixels(cam: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows v and columns u ``(H*W,)`` int64, row-major."""
    v, u = torch.meshgrid(torch.arange(cam.height), torch.arange(cam.width), indexing="ij")
    return v.reshape(-1), u.reshape(-1)


def check_filled(cam: Camera, origins, dirs, valid=None, atol=F32_ATOL) -> None:
    """World rays of a caller that fills invalid pixels with ``FORWARD_DIR`` (and maybe returns a mask)."""
    o_ref, d_ref, v_ref = reference(cam)
    origins, dirs = np.asarray(origins, dtype=np.float64), np.asarray(dirs, dtype=np.float64)
    if valid is not None:
        np.testing.assert_array_equal(np.asarray(valid), v_ref)
    np.testing.assert_allclose(origins, o_ref, atol=atol, rtol=0)
    np.testing.assert_allclose(dirs[v_ref], d_ref[v_ref], atol=atol, rtol=0)
    forward = C2W[:3, :3] @ np.asarray(FORWARD_DIR)
    np.testing.assert_allclose(dirs[~v_ref], np.broadcast_to(forward, dirs[~v_ref].shape), atol=atol, rtol=0)


def test_cameras_cover_valid_and_invalid_pixels(cam):
    _, d, valid = reference(cam)
    assert valid.any()
    assert valid.all() == (cam.model != "OPENCV_FISHEYE")  # the fisheye's corners are beyond its reach
    np.testing.assert_allclose(np.linalg.norm(d[valid], axis=-1), 1.0, atol=1e-12)


def test_camera_entry_points_agree(cam):
    _, d_ref, valid = reference(cam)
    dirs_cam = cam.pixel_dirs_cam()
    uu, vv = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    uv = cam.pixel_centres()
    np.testing.assert_array_equal(uv, np.stack([uu, vv], -1))  # OpenCV: the top-left centre is (0, 0)
    np.testing.assert_array_equal(cam.pixel_centres(torch.zeros(())).numpy(), uv)
    np.testing.assert_array_equal(cam.dirs_through(uv), dirs_cam)
    np.testing.assert_array_equal(cam.unproject(uv), dirs_cam)
    like = torch.zeros((), dtype=torch.float64)
    np.testing.assert_array_equal(cam.pixel_dirs_cam(like).numpy(), cam.unproject(torch.as_tensor(uv)).numpy())
    filled = cam.pixel_dirs_cam(fill_invalid=True)
    assert np.isfinite(filled).all()
    np.testing.assert_array_equal(filled.reshape(-1, 3)[valid], dirs_cam.reshape(-1, 3)[valid])
    np.testing.assert_array_equal(filled.reshape(-1, 3)[~valid], np.broadcast_to(FORWARD_DIR, (int((~valid).sum()), 3)))
    # torch twin
    o_t, d_t = cam.pixel_rays(torch.as_tensor(C2W))
    np.testing.assert_allclose(d_t.reshape(-1, 3).numpy(), d_ref, atol=1e-12, rtol=0, equal_nan=True)
    o, d = dirs_to_world(dirs_cam.reshape(-1, 3), C2W, normalize=False)
    o_ref, _, _ = reference(cam)
    np.testing.assert_array_equal(o, o_ref)
    np.testing.assert_allclose(d, d_ref, atol=1e-12, rtol=0, equal_nan=True)


def test_fill_invalid_dirs_numpy_and_torch():
    d = np.array([[0.6, 0.0, 0.8], [np.nan, np.nan, np.nan], [np.inf, 0.0, 0.0]])
    for x in (d, torch.as_tensor(d, dtype=torch.float32)):
        filled, valid = fill_invalid_dirs(x)
        assert type(filled) is type(x)
        np.testing.assert_array_equal(np.asarray(valid), [True, False, False])
        np.testing.assert_allclose(np.asarray(filled), [[0.6, 0.0, 0.8], FORWARD_DIR, FORWARD_DIR], rtol=1e-7)
    assert np.isnan(d[1]).all()  # input untouched


def test_rig_camera_sensor(cam):
    o, d = CameraSensor(name="cam", sensor_to_body=np.eye(4), camera=cam).rays(C2W)
    o_ref, d_ref, _ = reference(cam)
    np.testing.assert_allclose(o, o_ref, atol=1e-12, rtol=0)
    np.testing.assert_allclose(d, d_ref, atol=1e-12, rtol=0, equal_nan=True)  # NaN kept, as the sensor models expect


def test_rendering_rays(cam):
    d = camera_dirs(cam).reshape(-1, 3)
    assert d.dtype == torch.float32
    n = d.shape[0]
    o, w = dirs_to_world(d, torch.as_tensor(C2W, dtype=torch.float32).expand(n, 4, 4))
    check_filled(cam, o, w)


def test_renderer_camera_rays(cam):
    cfg = SimpleNamespace(near_m=0.0, far_m=100.0, clip_rays_to_box=False)
    model = SimpleNamespace(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3]), sampler_cfg=cfg)
    rays, d, valid = camera_rays(model, cam, C2W)
    check_filled(cam, rays.origins, rays.dirs, valid)
    np.testing.assert_array_equal(d.numpy(), camera_dirs(cam).reshape(-1, 3).numpy())


def test_scene_eval_pixel_rays(cam):
    v, u = all_pixels(cam)
    view = ViewRays(cam, torch.as_tensor(C2W, dtype=torch.float32), 0.0, 100.0, None)
    rays, z = eval_pixel_rays(view, v, u, torch.device("cpu"))
    check_filled(cam, rays.origins, rays.dirs)
    np.testing.assert_array_equal(z.numpy(), camera_dirs(cam).reshape(-1, 3)[:, 2].numpy())


def test_scene_trainer_pixel_dirs_table_and_per_batch_agree(cam):
    v, u = all_pixels(cam)
    img = torch.zeros_like(v)
    stub = SimpleNamespace(camera_index=torch.zeros(1, dtype=torch.long), data=SimpleNamespace(cameras=[cam]),
                           device=torch.device("cpu"), dirs_cam=None)
    per_batch = SceneTrainer._pixel_dirs(stub, img, v, u)
    stub.dirs_cam = camera_dirs(cam)[None]
    table = SceneTrainer._pixel_dirs(stub, img, v, u)
    np.testing.assert_array_equal(per_batch.numpy(), table.numpy())
    o, d = dirs_to_world(per_batch, torch.as_tensor(C2W, dtype=torch.float32).expand(len(v), 4, 4))
    check_filled(cam, o, d)


def test_render_shard_pose_frame(cam, tmp_path):
    from nsim.rendering.render_job import PoseFrame
    from nsim.rendering.shard import ShardRenderer

    seen = {}

    class Stop(Exception):
        pass

    def capture(o, d, valid, *args):
        seen.update(o=o, d=d, valid=valid)
        raise Stop

    shard = object.__new__(ShardRenderer)
    shard._render_rays = capture
    with pytest.raises(Stop):
        shard._render_pose_frame(PoseFrame(index=0, time_s=None, name="000000.png", cam_to_world=C2W, camera=cam),
                                 tmp_path)
    assert seen["d"].dtype == np.float64
    check_filled(cam, seen["o"], seen["d"], seen["valid"], atol=1e-12)
