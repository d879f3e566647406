"""`nsim reconstruct --import transforms.json`: confined paths, decoded and size-checked images,
image bytes in the action key, and nothing published on bad input."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from nsim.geometry.cameras import Camera
from nsim.io.images import read_image, write_image
from nsim.io.transforms_json import Frame, TransformsData, read_transforms, write_transforms

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
    assert len(got.frames) == 3
    for i, (g, f) in enumerate(zip(got.frames, given.frames, strict=True)):
        np.testing.assert_array_equal(g.cam_to_world, f.cam_to_world)
        assert g.camera == f.camera and g.timestamp_s == f.timestamp_s
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
    assert sorted(p.name for p in (art.path / "images").iterdir()) == [f"frame_{i:05d}.png" for i in range(3)]
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
    np.testing.assert_array_equal(read_image(art.path / "images/frame_00001.png"), new)
    assert art.manifest["action_key"] != store.get(out.strip()).manifest["action_key"]
