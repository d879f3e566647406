"""The scene trainer's data: shrunk training images with exact intrinsics, scoring sizes, scale."""

from __future__ import annotations

import dataclasses
import json
import shutil

import cv2
import numpy as np
import pytest

from nsim.config import from_dict
from nsim.io.images import read_image
from nsim.train.scene_config import TrainSceneConfig, in_scene_units
from nsim.train.scene_data import (
    ROOM_CAMERA_TO_POINT_M,
    SceneData,
    camera_to_point_median,
    poses_scale,
    units_per_metre,
)


def test_shrunk_images_and_exact_intrinsics(tiny_capture_dir, tiny_data):
    small = SceneData.load(tiny_capture_dir, max_image_side=32)
    assert small.images.shape == (32, 24, 32, 3) and small.images.dtype == np.uint8
    assert small.size_hw == (24, 32) and small.full_size_hw == (48, 64)
    full, cam = tiny_data.cameras[0], small.cameras[0]
    # a factor of 2: f halves, and the pixel-centre convention moves the principal point by a quarter pixel
    assert (cam.width, cam.height) == (32, 24)
    assert cam.fx == pytest.approx(full.fx / 2) and cam.fy == pytest.approx(full.fy / 2)
    assert cam.cx == pytest.approx((full.cx + 0.5) / 2 - 0.5) and cam.cy == pytest.approx((full.cy + 0.5) / 2 - 0.5)
    # a point seen at (u, v) in the full image is seen at ((u + 0.5) / 2 - 0.5, ...) in the small one
    p = np.array([[0.3, -0.2, 2.0]])
    (u, v), _ = full.project(p)[0][0], None
    us, vs = cam.project(p)[0][0]
    assert us == pytest.approx((u + 0.5) / 2 - 0.5) and vs == pytest.approx((v + 0.5) / 2 - 0.5)
    # INTER_AREA at a factor of 2 is the 2x2 block mean
    block = tiny_data.images[5, 10:12, 20:22].reshape(-1, 3).astype(np.float64).mean(0)
    assert np.abs(small.images[5, 5, 10] - block).max() <= 0.5 + 1e-9
    # the digest is the originals': the same data whatever size it trains at
    assert small.digest == tiny_data.digest


def test_with_max_image_side_reads_the_originals_again(tiny_capture_dir, tiny_data):
    small = SceneData.load(tiny_capture_dir, max_image_side=40)
    again = tiny_data.with_max_image_side(40)
    np.testing.assert_array_equal(again.images, small.images)
    assert again.cameras == small.cameras
    assert tiny_data.with_max_image_side(1600) is tiny_data  # already small enough: no copy
    back = small.with_max_image_side(0)
    np.testing.assert_array_equal(back.images, tiny_data.images)


def test_eval_images_at_any_size(tiny_capture_dir):
    small = SceneData.load(tiny_capture_dir, max_image_side=32)
    full_cam = small.eval_camera(8, 0)
    assert (full_cam.width, full_cam.height) == (64, 48)
    np.testing.assert_array_equal(small.eval_image(8, full_cam), read_image(small.image_paths[8]))
    assert np.shares_memory(small.eval_image(8, small.eval_camera(8, 32)), small.images)  # the training copy
    mid = small.eval_camera(8, 48)
    img = small.eval_image(8, mid)
    assert img.shape == (36, 48, 3)
    np.testing.assert_array_equal(img, cv2.resize(read_image(small.image_paths[8]), (48, 36), interpolation=cv2.INTER_AREA))
    assert small.eval_depth_z(8, mid).shape == (36, 48)


def _copy_capture(src, dst, extra=None, report=None):
    shutil.copytree(src, dst)
    if extra is not None:
        meta = json.loads((dst / "transforms.json").read_text())
        meta.update(extra)
        (dst / "transforms.json").write_text(json.dumps(meta))
    if report is not None:
        (dst / "report.json").write_text(json.dumps(report))
    return dst


def test_scale_comes_from_the_poses_artifact(tiny_capture_dir, tmp_path):
    assert SceneData.load(tiny_capture_dir).metric  # a capture: ground truth, metres
    arb = _copy_capture(tiny_capture_dir, tmp_path / "a", extra={"nsim_scale": "arbitrary"})
    data = SceneData.load(arb)
    assert not data.metric and data.scale_source == "arbitrary"
    assert SceneData.load(arb, scale="metric").metric  # the config may overrule it
    rep = _copy_capture(tiny_capture_dir, tmp_path / "r", report={"scale": {"source": "arbitrary"}})
    assert not SceneData.load(rep).metric
    assert SceneData.load(tiny_capture_dir, scale="arbitrary").metric is False
    # nsim_metric, when written, is the word
    assert poses_scale(tmp_path, {"nsim_scale": "import", "nsim_metric": False}) == ("import", False)
    assert poses_scale(tmp_path, {"nsim_scale": "known_distance"}) == ("known_distance", True)
    assert poses_scale(tmp_path / "nowhere", {}) == (None, True)


def _depth_points(data: SceneData, stride: int = 4) -> np.ndarray:
    """The capture's depth maps as a stand-in for sparse points (every stride-th pixel)."""
    pts = []
    for i in range(data.n_frames):
        z = data.read_depth_z(i)[::stride, ::stride]
        d = data.full_cameras[data.camera_index[i]].pixel_dirs_cam()[::stride, ::stride]
        ok = np.isfinite(z) & (z > 0)
        p = d[ok] / d[ok][:, 2:3] * z[ok][:, None]
        pts.append(p @ data.cam_to_world[i, :3, :3].T + data.cam_to_world[i, :3, 3])
    return np.concatenate(pts)


def test_room_measures_about_one_unit_per_metre(tiny_data):
    pts = _depth_points(tiny_data)
    arbitrary = dataclasses.replace(tiny_data, metric=False, points_xyz=pts)
    s, how = units_per_metre(arbitrary)
    assert s == pytest.approx(1.0, rel=0.15) and "sparse-point" in how
    assert camera_to_point_median(tiny_data.cam_to_world[:, :3, 3], pts) == pytest.approx(s * ROOM_CAMERA_TO_POINT_M)
    # the same scene in decimetres: ten units a metre
    c2w = tiny_data.cam_to_world.copy()
    c2w[:, :3, 3] *= 10.0
    s10, _ = units_per_metre(dataclasses.replace(arbitrary, cam_to_world=c2w, points_xyz=pts * 10.0))
    assert s10 == pytest.approx(10.0 * s)
    # without points: the camera path's spread
    s_cam, how_cam = units_per_metre(dataclasses.replace(arbitrary, points_xyz=None))
    assert s_cam == pytest.approx(1.0, rel=0.35) and "spread" in how_cam
    assert units_per_metre(tiny_data) == (1.0, "metric poses")


def _metre_fields(cfg, prefix=""):
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            yield from _metre_fields(v, f"{f.name}.")
        elif f.name.endswith("_m") and not f.name.startswith("aabb_"):
            yield prefix + f.name, v


def _get(cfg, dotted):
    for k in dotted.split("."):
        cfg = getattr(cfg, k)
    return cfg


def test_in_scene_units_scales_every_metre_length_and_density():
    cfg = from_dict(TrainSceneConfig, {"sampler": {"kind": "grid"}})
    assert in_scene_units(cfg, 1.0) is cfg
    scaled = in_scene_units(cfg, 0.25)
    names = dict(_metre_fields(cfg))
    assert {"sampler.near_m", "data.bounds_margin_m", "output.occupancy_cell_m", "output.obstacle_band_m"} <= set(names)
    for name, value in names.items():
        got = _get(scaled, name)
        want = tuple(x * 0.25 for x in value) if isinstance(value, tuple) else value * 0.25
        assert got == pytest.approx(want), name
    for name in ("output.occupancy_density", "output.obstacle_density", "sampler.grid_density_threshold"):
        assert _get(scaled, name) == pytest.approx(_get(cfg, name) / 0.25), name
    assert scaled.field.density_bias == pytest.approx(cfg.field.density_bias - np.log(0.25))


def test_rays_without_a_direction_table_are_the_same_rays(tiny_data, monkeypatch):
    """Many distinct cameras: pixel directions are unprojected per batch instead of tabled, bit for bit."""
    import torch

    import nsim.train.scene as scene
    from tests.train.test_scene import micro_cfg

    cfg = micro_cfg()
    tabled = scene.SceneTrainer(tiny_data, cfg, seed=3)
    monkeypatch.setattr(scene, "DIRS_TABLE_MAX_BYTES", 0)
    untabled = scene.SceneTrainer(tiny_data, cfg, seed=3)
    assert tabled.dirs_cam is not None and untabled.dirs_cam is None
    for step in (0, 5):
        (ra, ta, _), (rb, tb, _) = tabled.batch(step), untabled.batch(step)
        assert torch.equal(ra.dirs, rb.dirs) and torch.equal(ra.near, rb.near) and torch.equal(ta, tb)


def test_finest_hash_resolution_follows_the_pixel_footprint(tiny_data):
    """``field.hash_max_resolution: 0``: one finest cell per training pixel at the median depth, whatever the
    scene's units; finer images need a finer grid; clamped to the bounds; the trainer builds that grid."""
    from nsim.train.scene import SceneTrainer, finest_hash_resolution, scene_bounds
    from tests.train.test_scene import micro_cfg

    pts = _depth_points(tiny_data)
    data = dataclasses.replace(tiny_data, points_xyz=pts)
    aabb = scene_bounds(data, TrainSceneConfig().data)
    free = (2, 1 << 20)
    res, why = finest_hash_resolution(data, aabb, contract=True, bounds=free)
    d = camera_to_point_median(data.cam_to_world[:, :3, 3], pts)
    f = np.median([max(c.fx, c.fy) for c in data.cameras])
    need = float((aabb[1] - aabb[0]).max()) / (0.5 * d / f)  # the box fills half the contracted grid's side
    assert res == int(np.ceil(need / 64) * 64) and "sparse-point" in why
    # the box filling the whole grid: half the cells
    assert finest_hash_resolution(data, aabb, contract=False, bounds=free)[0] == int(np.ceil(need / 2 / 64) * 64)
    # the same scene in decimetres: the same grid
    c2w = data.cam_to_world.copy()
    c2w[:, :3, 3] *= 10.0
    dm = dataclasses.replace(data, cam_to_world=c2w, points_xyz=pts * 10.0)
    assert finest_hash_resolution(dm, aabb * 10.0, contract=True, bounds=free)[0] == res
    # cameras with four times the pixels across: four times the cells (to the rounding)
    sharp = dataclasses.replace(data, cameras=[c.scaled(4.0) for c in data.cameras])
    assert finest_hash_resolution(sharp, aabb, contract=True, bounds=free)[0] == int(np.ceil(4 * need / 64) * 64)
    # without points: the camera-to-box-centre distance; clamped to the bounds
    assert "box-centre" in finest_hash_resolution(tiny_data, aabb, True, free)[1]
    assert finest_hash_resolution(data, aabb, True, (res + 64, res + 640))[0] == res + 64
    assert finest_hash_resolution(data, aabb, True, (2, res - 64))[0] == res - 64
    # the trainer resolves 0 and builds (and saves: scene.json's field) the grid it names
    cfg = micro_cfg(field={"hash_max_resolution": 0})
    tr = SceneTrainer(data, cfg, seed=0)
    want = finest_hash_resolution(tr.data, tr.aabb, cfg.field.contract)[0]
    assert tr.cfg.field.hash_max_resolution == want == tr.model.field_cfg.hash_max_resolution
    assert abs(tr.model.field.encoding.layout.resolutions[-1] - want) <= 1
    assert tr.given_cfg.field.hash_max_resolution == 0


def test_hash_max_resolution_one_is_refused():
    from nsim.errors import ConfigError

    with pytest.raises(ConfigError, match=r"field.hash_max_resolution: expected 0 \(from the data\) or >= 2, got 1"):
        from_dict(TrainSceneConfig, {"field": {"hash_max_resolution": 1}})
