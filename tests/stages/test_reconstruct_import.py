"""`nsim reconstruct --import transforms.json`: confined paths, decoded and size-checked images,
file bytes in the action key, nothing published on bad input; missing files, original names,
depth / mask / ply carried; scale and z-up from the same sources as SfM, or arbitrary."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.geometry.cameras import Camera
from nsim.geometry.transforms import look_at, rotation_angle_deg
from nsim.io.images import read_image, write_depth_png_mm, write_image
from nsim.io.ply import read_ply, write_ply
from nsim.io.transforms_json import Frame, TransformsData, read_transforms, write_transforms
from nsim.io.tum import Trajectory, write_tum
from nsim.sfm.align import apply_sim3_to_points, apply_sim3_to_poses, fit_sim3

CAMERA = Camera("PINHOLE", 40, 30, 35.0, 35.0, 19.5, 14.5)


def _export(folder: Path, n: int = 3, file_paths: list[str] | None = None, cameras: list[Camera] | None = None,
            **frame_keys) -> Path:
    """An exported scan: `folder/images/frame_i.png` (random pixels, CAMERA's size) and `folder/transforms.json`."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(len(str(folder)))
    file_paths = file_paths or [f"images/frame_{i}.png" for i in range(n)]
    cameras = cameras or [CAMERA] * n
    frames = []
    for i, (fp, cam) in enumerate(zip(file_paths, cameras, strict=True)):
        image = folder / f"images/frame_{i}.png"
        image.parent.mkdir(exist_ok=True)
        write_image(image, rng.integers(0, 256, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8))
        c2w = np.eye(4)
        c2w[:3, 3] = (0.1 * i, 0.0, 1.5)
        frames.append(Frame(fp, c2w, cam, timestamp_s=0.1 * i, **frame_keys))
    return write_transforms(folder / "transforms.json", TransformsData(frames=frames))


def _assert_refused(run_cli, store, args: tuple[str, ...], *messages: str) -> None:
    before = store.all_ids()
    code, out, err = run_cli("reconstruct", *args)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(m in lines[0] for m in messages), (messages, err)
    assert out == ""
    assert store.all_ids() == before  # nothing published
    tmp = store.root / "tmp"
    assert not tmp.exists() or list(tmp.iterdir()) == []


def test_import_publishes_images_and_poses(run_cli, store, tmp_path):
    path = _export(tmp_path / "scan")
    code, out, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0, err
    art = store.get(out.strip())
    got, given = read_transforms(art.file("transforms.json")), read_transforms(path)
    report = json.loads(art.file("report.json").read_text())
    world_from_import = np.asarray(report["world_from_import"])  # no scale source: rigid (z up)
    np.testing.assert_allclose(world_from_import[:3, :3] @ world_from_import[:3, :3].T, np.eye(3), atol=1e-12)
    assert len(got.frames) == 3
    for i, (g, f) in enumerate(zip(got.frames, given.frames, strict=True)):
        np.testing.assert_allclose(g.cam_to_world, world_from_import @ f.cam_to_world, atol=1e-12)
        assert g.camera == f.camera and g.timestamp_s == f.timestamp_s
        assert g.file_path == f"images/frame_{i}.png"  # the original names
        assert (art.path / g.file_path).read_bytes() == (path.parent / f.file_path).read_bytes(), i
    code, out2, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0 and out2 == out and "(cached)" in err


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink", "depth"])
def test_paths_outside_the_folder_refused(run_cli, store, tmp_path, how):
    secret = tmp_path / "private" / "secret.png"
    secret.parent.mkdir()
    write_image(secret, np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8))
    scan = tmp_path / "scan"
    paths = ["images/frame_0.png", "images/frame_1.png", "images/frame_2.png"]
    key, extra = "file_path", {}
    if how == "dotdot":
        paths[1] = "../private/secret.png"
    elif how == "absolute":
        paths[1] = str(secret)
    elif how == "symlink":
        (scan / "images").mkdir(parents=True)
        (scan / "images" / "link.png").symlink_to(secret)
        paths[1] = "images/link.png"
    else:
        key, extra = "depth_file_path", {"depth_file_path": "../private/secret.png"}
    path = _export(scan, file_paths=paths, **extra)
    where = "frames[0]" if how == "depth" else "frames[1]"
    _assert_refused(run_cli, store, ("--import", str(path)), f"{where}.{key}", "resolves outside", str(scan))


def test_images_root_allows_a_wider_folder(run_cli, store, tmp_path):
    scan = tmp_path / "scan"
    path = _export(scan, file_paths=[f"../images/frame_{i}.png" for i in range(3)])
    (scan / "images").rename(tmp_path / "images")
    _assert_refused(run_cli, store, ("--import", str(path)), "frames[0].file_path", "resolves outside")
    code, out, err = run_cli("reconstruct", "--import", str(path), "--images-root", str(tmp_path))
    assert code == 0, err
    art = store.get(out.strip())
    assert sorted(p.name for p in (art.path / "images").iterdir()) == [f"frame_{i}.png" for i in range(3)]
    # the root confines but does not move relative paths, and must be a folder
    _assert_refused(run_cli, store, ("--import", str(path), "--images-root", str(scan)), "resolves outside")
    _assert_refused(run_cli, store, ("--import", str(path), "--images-root", str(path)), "--images-root")


def test_truncated_image_refused(run_cli, store, tmp_path):
    path = _export(tmp_path / "scan")
    image = path.parent / "images/frame_2.png"
    image.write_bytes(image.read_bytes()[:-40])
    _assert_refused(run_cli, store, ("--import", str(path)), "frames[2].file_path: images/frame_2.png",
                    "not a readable image")


@pytest.mark.parametrize("where", ["global", "per_frame"])
def test_size_mismatch_refused(run_cli, store, tmp_path, where):
    small = dataclasses.replace(CAMERA, width=32, height=24)
    if where == "global":  # every frame (so w, h are top-level keys) says 32x24; the images are 40x30
        path = _export(tmp_path / "scan", cameras=[small] * 3)
        message = "frames[0].file_path: images/frame_0.png: image is 40x30, but w=32, h=24"
    else:  # one frame's own w, h
        path = _export(tmp_path / "scan", cameras=[CAMERA, small, CAMERA])
        message = "frames[1].file_path: images/frame_1.png: image is 40x30, but w=32, h=24"
    _assert_refused(run_cli, store, ("--import", str(path)), message)


def test_replaced_image_is_not_served_from_the_cache(run_cli, store, tmp_path):
    path = _export(tmp_path / "scan")
    code, out, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0, err
    image = path.parent / "images/frame_1.png"
    new = np.full((CAMERA.height, CAMERA.width, 3), 7, np.uint8)
    write_image(image, new)  # same name, same size, new content
    code, out2, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0 and "(published)" in err, err
    assert out2 != out
    art = store.get(out2.strip())
    np.testing.assert_array_equal(read_image(art.path / "images/frame_1.png"), new)
    assert art.manifest["action_key"] != store.get(out.strip()).manifest["action_key"]


# ---------------------------------------------------------------------------- missing files, names

def _move(scan: Path, moves: dict[str, str]) -> None:
    """Rename images written by `_export` (`images/frame_i.png`) to where a test's transforms.json looks."""
    for src, dst in moves.items():
        (scan / dst).parent.mkdir(parents=True, exist_ok=True)
        if Path(dst).suffix.lower() in (".jpg", ".jpeg"):
            write_image(scan / dst, read_image(scan / src))
            (scan / src).unlink()
        else:
            (scan / src).rename(scan / dst)


def test_missing_images_refused_or_skipped(run_cli, store, tmp_path, caplog):
    path = _export(tmp_path / "scan", n=5, depth_file_path="depth/none.png")
    for i in (1, 3):
        (path.parent / f"images/frame_{i}.png").unlink()
    _assert_refused(run_cli, store, ("--import", str(path)),
                    "7 of the files it names are missing (2 of 5 frames' images)",
                    "frames[0].depth_file_path: depth/none.png, frames[1].file_path: images/frame_1.png",
                    "and 4 more", "--skip-missing")
    with caplog.at_level(logging.WARNING):
        code, out, err = run_cli("reconstruct", "--import", str(path), "--skip-missing")
    assert code == 0, err
    notes = [r.getMessage() for r in caplog.records if "skipped" in r.getMessage()]
    assert len(notes) == 1 and "skipped 2 of 5 frames" in notes[0] and "dropped 3" in notes[0], notes
    art = store.get(out.strip())
    got = read_transforms(art.file("transforms.json"))
    assert [f.file_path for f in got.frames] == ["images/frame_0.png", "images/frame_2.png", "images/frame_4.png"]
    assert all(f.depth_file_path is None for f in got.frames)
    report = json.loads(art.file("report.json").read_text())
    assert report["skipped_frames"] == [{"index": 1, "file_path": "images/frame_1.png"},
                                        {"index": 3, "file_path": "images/frame_3.png"}]
    assert report["dropped_files"] == [{"field": f"frames[{i}].depth_file_path", "path": "depth/none.png"}
                                       for i in (0, 2, 4)]
    assert (report["images_given"], report["images_registered"]) == (5, 3)
    assert art.manifest["summary"]["images_skipped"] == 2


def test_extension_less_paths_resolve_like_nerfstudio(run_cli, store, tmp_path):
    scan = tmp_path / "scan"
    path = _export(scan, file_paths=["./train/r_0", "./train/r_1", "train/r_2"])
    _move(scan, {"images/frame_0.png": "train/r_0.png", "images/frame_1.png": "train/r_1.jpg",
                 "images/frame_2.png": "train/r_2.PNG"})
    write_image(scan / "train/r_0.jpg", np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8))  # .png comes first
    code, out, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0, err
    art = store.get(out.strip())
    got = [f.file_path for f in read_transforms(art.file("transforms.json")).frames]
    assert got == ["images/r_0.png", "images/r_1.jpg", "images/r_2.PNG"]
    for name in got:
        assert (art.path / name).read_bytes() == (scan / "train" / Path(name).name).read_bytes()


def test_original_names_kept_and_unique(run_cli, store, tmp_path):
    scan = tmp_path / "scan"
    path = _export(scan, file_paths=["left/x.png", "./right/x.png", "right/y.png"])
    _move(scan, {"images/frame_0.png": "left/x.png", "images/frame_1.png": "right/x.png",
                 "images/frame_2.png": "right/y.png"})
    code, out, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0, err
    art = store.get(out.strip())
    got = [f.file_path for f in read_transforms(art.file("transforms.json")).frames]
    assert got == ["images/left/x.png", "images/right/x.png", "images/right/y.png"]  # two x.png: paths kept
    for name in got:
        assert (art.path / name).read_bytes() == (scan / name.removeprefix("images/")).read_bytes()


# ---------------------------------------------------------------------------- scale and frame

#: The export's units per metre, its rotation and offset from the true (metric, z-up) world.
EXPORT_SCALE = 3.7
EXPORT_R = Rotation.from_rotvec([0.9, -1.7, 0.4]).as_matrix()
EXPORT_T = np.array([2.0, -1.0, 0.5])
#: nerfstudio's applied_transform for COLMAP exports (x, z, -y).
NERFSTUDIO_APPLIED = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]])


def _room(n: int = 16, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hand-held loop in a 6 x 6 m room, metric, z up, floor at z = 0: cam_to_world (n, 4, 4) and
    points (P, 3) on the floor and two walls with their colours (P, 3)."""
    rng = np.random.default_rng(seed)
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    eye = np.stack([1.5 * np.cos(a), 1.5 * np.sin(a), 1.4 + 0.1 * np.sin(3 * a)], axis=1)
    target = np.stack([3.0 * np.cos(a + 0.6), 3.0 * np.sin(a + 0.6), np.full(n, 1.1)], axis=1)
    floor = np.c_[rng.uniform(-3, 3, (400, 2)), np.zeros(400)]
    wall_x = np.c_[np.full(150, 3.0), rng.uniform(-3, 3, 150), rng.uniform(0, 2.5, 150)]
    wall_y = np.c_[rng.uniform(-3, 3, 150), np.full(150, -3.0), rng.uniform(0, 2.5, 150)]
    points = np.concatenate([floor, wall_x, wall_y])
    return look_at(eye, target), points, rng.integers(0, 256, (len(points), 3), dtype=np.uint8)


def _export_scene(scan: Path, cam_to_world: np.ndarray, points: np.ndarray, rgb: np.ndarray,
                  applied: np.ndarray | None = None, depth: bool = False, mask: bool = False) -> Path:
    """A scan whose poses and ply are `cam_to_world`, `points` in an export's world (scale, rotation,
    offset EXPORT_*; then `applied` on top, as nerfstudio's applied_transform), with images and
    optionally 16-bit millimetre depth PNGs and masks."""
    for folder in ("images", "depths", "masks"):
        (scan / folder).mkdir(parents=True)
    c2w = apply_sim3_to_poses(EXPORT_SCALE, EXPORT_R, EXPORT_T, cam_to_world)
    pts = apply_sim3_to_points(EXPORT_SCALE, EXPORT_R, EXPORT_T, points)
    if applied is not None:
        c2w = apply_sim3_to_poses(1.0, applied[:, :3], applied[:, 3], c2w)
        pts = apply_sim3_to_points(1.0, applied[:, :3], applied[:, 3], pts)
    write_ply(scan / "sparse_pc.ply", pts.astype(np.float32), rgb=rgb)
    rng = np.random.default_rng(1)
    frames = []
    for i, pose in enumerate(c2w):
        name = f"frame_{i:05d}.png"
        write_image(scan / "images" / name, rng.integers(0, 256, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8))
        keys = {}
        if depth:
            write_depth_png_mm(scan / "depths" / name, rng.uniform(0.5, 5.0, (CAMERA.height, CAMERA.width)))
            keys["depth_file_path"] = f"depths/{name}"
        if mask:
            write_image(scan / "masks" / name, np.full((CAMERA.height, CAMERA.width, 3), 255 * (i % 2), np.uint8))
            keys["mask_path"] = f"masks/{name}"
        frames.append(Frame(f"images/{name}", pose, CAMERA, timestamp_s=0.1 * i, **keys))
    data = TransformsData(frames, applied_transform=applied, extra={"ply_file_path": "sparse_pc.ply"})
    return write_transforms(scan / "transforms.json", data)


def _imported(store, out: str) -> tuple[np.ndarray, dict, dict, object]:
    art = store.get(out.strip())
    c2w = np.stack([f.cam_to_world for f in read_transforms(art.file("transforms.json")).frames])
    report, raw = (json.loads(art.file(name).read_text()) for name in ("report.json", "transforms.json"))
    return c2w, report, raw, art


def test_scaled_rotated_export_comes_back_metric_and_z_up_with_a_reference(run_cli, store, tmp_path):
    true_c2w, points, rgb = _room()
    path = _export_scene(tmp_path / "scan", true_c2w, points, rgb)
    tum = tmp_path / "odometry.tum"
    write_tum(tum, Trajectory.from_poses(0.1 * np.arange(len(true_c2w)), true_c2w))
    code, out, err = run_cli("reconstruct", "--import", str(path), "--reference", str(tum))
    assert code == 0, err
    c2w, report, raw, art = _imported(store, out)
    assert fit_sim3(c2w[:, :3, 3], true_c2w[:, :3, 3]).s == pytest.approx(1.0, rel=0.01)  # metric
    np.testing.assert_allclose(c2w[:, :3, 3], true_c2w[:, :3, 3], atol=0.01)  # the reference's world, z up
    assert rotation_angle_deg(c2w[:, :3, :3], true_c2w[:, :3, :3]).max() < 0.1
    assert report["scale"]["source"] == "reference" and report["scale"]["associated_by"] == "timestamp"
    assert report["scale"]["scale"] == pytest.approx(1.0 / EXPORT_SCALE, rel=1e-6)
    assert (raw["nsim_scale"], raw["nsim_metric"]) == ("reference", True)
    cloud = read_ply(art.file("sparse_points.ply"))  # the export's ply, in the same world as the poses
    assert raw["ply_file_path"] == "sparse_points.ply" and report["num_points3d"] == len(points)
    np.testing.assert_allclose(cloud.xyz, points, atol=1e-4)
    np.testing.assert_array_equal(cloud.rgb, rgb)


@pytest.mark.parametrize("source", ["camera_height", "known_distance"])
def test_scaled_rotated_export_comes_back_metric_and_z_up_without_a_reference(run_cli, store, tmp_path, source):
    true_c2w, points, rgb = _room()
    path = _export_scene(tmp_path / "scan", true_c2w, points, rgb)
    if source == "camera_height":
        args = ("--camera-height", str(float(np.median(true_c2w[:, 2, 3]))))
    else:  # two camera centres picked in the arbitrary-scale import, and their true distance
        code, out, err = run_cli("reconstruct", "--import", str(path))
        assert code == 0, err
        arbitrary = _imported(store, out)[0]
        d = float(np.linalg.norm(true_c2w[0, :3, 3] - true_c2w[5, :3, 3]))
        args = ("--known-distance", *map(str, arbitrary[0, :3, 3]), *map(str, arbitrary[5, :3, 3]), str(d))
    code, out, err = run_cli("reconstruct", "--import", str(path), *args)
    assert code == 0, err
    c2w, report, raw, art = _imported(store, out)
    fit = fit_sim3(c2w[:, :3, 3], true_c2w[:, :3, 3])
    assert fit.s == pytest.approx(1.0, rel=0.01)  # metric within 1 %
    assert np.degrees(np.arccos(np.clip(fit.R[2, 2], -1, 1))) < 0.5  # only a turn about z away from the truth
    np.testing.assert_allclose(c2w[:, 2, 3], true_c2w[:, 2, 3], rtol=0.01)  # floor at z = 0: true heights
    np.testing.assert_allclose(c2w[:, 2, :3], true_c2w[:, 2, :3], atol=0.01)  # each camera's tilt against +z
    assert report["scale"]["source"] == source and report["scale"]["floor_found"]
    assert (raw["nsim_scale"], raw["nsim_metric"], raw["nsim_z_up"]) == (source, True, True)
    assert np.abs(read_ply(art.file("sparse_points.ply")).xyz[:400, 2]).max() < 0.01  # the floor points


def test_no_scale_source_says_arbitrary(run_cli, store, tmp_path):
    true_c2w, points, rgb = _room()
    path = _export_scene(tmp_path / "scan", true_c2w, points, rgb)
    code, out, err = run_cli("reconstruct", "--import", str(path))
    assert code == 0, err
    c2w, report, raw, art = _imported(store, out)
    assert report["scale"]["source"] == "arbitrary" and "scale is arbitrary" in report["scale"]["message"]
    assert "assumed metric" not in art.file("report.json").read_text()
    assert (raw["nsim_scale"], raw["nsim_metric"], raw["nsim_z_up"]) == ("arbitrary", False, True)
    assert art.manifest["summary"]["scale_source"] == "arbitrary"
    assert fit_sim3(c2w[:, :3, 3], true_c2w[:, :3, 3]).s == pytest.approx(1.0 / EXPORT_SCALE, rel=0.01)
    np.testing.assert_allclose(c2w[:, 2, 3], EXPORT_SCALE * true_c2w[:, 2, 3], rtol=0.01)  # z up all the same
    # --metric takes the file's units as metres (here wrongly: they are 3.7 per metre)
    code, out, err = run_cli("reconstruct", "--import", str(path), "--metric")
    assert code == 0, err
    c2w_metric, report, raw, _ = _imported(store, out)
    assert (report["scale"]["source"], report["scale"]["scale"], raw["nsim_metric"]) == ("metric", 1.0, True)
    np.testing.assert_allclose(c2w_metric, c2w, atol=1e-9)


def test_depth_mask_and_ply_carried(run_cli, store, tmp_path):
    true_c2w, points, rgb = _room()
    scan = tmp_path / "scan"
    path = _export_scene(scan, true_c2w, points, rgb, depth=True, mask=True)
    height = float(np.median(true_c2w[:, 2, 3]))
    code, out, err = run_cli("reconstruct", "--import", str(path), "--camera-height", str(height))
    assert code == 0, err
    c2w, report, raw, art = _imported(store, out)
    frames = read_transforms(art.file("transforms.json")).frames
    for i, f in enumerate(frames):
        name = f"frame_{i:05d}.png"
        assert (f.depth_file_path, f.mask_path) == (f"depth/{name}", f"masks/{name}")
        assert (art.path / f.depth_file_path).read_bytes() == (scan / "depths" / name).read_bytes()
        assert (art.path / f.mask_path).read_bytes() == (scan / "masks" / name).read_bytes()
    # the depth PNGs store millimetres of the export's units: x 1e-3 / 3.7 gives metres
    assert raw["depth_unit_scale_factor"] == pytest.approx(1e-3 / EXPORT_SCALE, rel=0.01)
    assert report["depth_unit_scale_factor"] == raw["depth_unit_scale_factor"]
    cloud = read_ply(art.file("sparse_points.ply"))
    world = np.asarray(report["world_from_import"])
    export_pts = read_ply(scan / "sparse_pc.ply").xyz.astype(np.float64)
    np.testing.assert_allclose(cloud.xyz, export_pts @ world[:3, :3].T + world[:3, 3], atol=1e-4)
    assert fit_sim3(cloud.xyz.astype(np.float64), points).s == pytest.approx(1.0, rel=0.01)


def test_applied_transform_is_carried(run_cli, store, tmp_path):
    """The file's poses and ply are A x (COLMAP's world): the output's applied_transform maps COLMAP's
    world into the artifact's, so that the original coordinates can be recovered."""
    true_c2w, points, rgb = _room()
    path = _export_scene(tmp_path / "scan", true_c2w, points, rgb, applied=NERFSTUDIO_APPLIED)
    code, out, err = run_cli("reconstruct", "--import", str(path), "--camera-height", "1.4")
    assert code == 0, err
    c2w, report, raw, art = _imported(store, out)
    colmap_c2w = apply_sim3_to_poses(EXPORT_SCALE, EXPORT_R, EXPORT_T, true_c2w)  # before A
    applied = np.asarray(raw["applied_transform"])
    assert applied.shape == (3, 4) and report["applied_transform_given"] == NERFSTUDIO_APPLIED.tolist()
    np.testing.assert_allclose(c2w[:, :3, 3], colmap_c2w[:, :3, 3] @ applied[:, :3].T + applied[:, 3], atol=1e-9)
    colmap_pts = apply_sim3_to_points(EXPORT_SCALE, EXPORT_R, EXPORT_T, points)
    np.testing.assert_allclose(read_ply(art.file("sparse_points.ply")).xyz,
                               colmap_pts @ applied[:, :3].T + applied[:, 3], atol=1e-4)
    np.testing.assert_allclose(c2w[:, 2, 3], true_c2w[:, 2, 3] * 1.4 / np.median(true_c2w[:, 2, 3]), rtol=0.01)
    # an nsim poses artifact says it is metric and z up: imported again, its world is kept as it is
    code, out2, err = run_cli("reconstruct", "--import", str(art.file("transforms.json")))
    assert code == 0, err
    c2w_again, report, raw_again, _ = _imported(store, out2)
    assert (report["scale"]["source"], report["scale"]["frame"]) == ("metric", "as_given")
    np.testing.assert_allclose(c2w_again, c2w, atol=1e-12)
    np.testing.assert_allclose(raw_again["applied_transform"], applied, atol=1e-12)


@pytest.mark.parametrize("args, message", [
    (("--metric", "--camera-height", "1.5"), "at most one of --reference, --known-distance, --camera-height, "
                                             "--metric"),
    (("--camera-height", "1.5"), "no sparse points to find the floor among"),
])
def test_bad_scale_options_refused(run_cli, store, tmp_path, args, message):
    path = _export(tmp_path / "scan")  # no ply
    _assert_refused(run_cli, store, ("--import", str(path), *args), message)


@pytest.mark.parametrize("flag", ["--metric", "--skip-missing"])
def test_import_flags_need_an_import(run_cli, store, tmp_path, flag):
    _assert_refused(run_cli, store, (str(tmp_path), flag), f"{flag}: only with --import")
