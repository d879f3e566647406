import cv2
import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.images import (
    read_depth_png,
    read_image,
    to_float,
    to_uint8,
    write_depth_png_mm,
    write_image,
)

SHAPES = [(4, 6), (6, 4), (1, 7), (7, 1), (1, 1)]


def test_uint8_float_roundtrip_every_level():
    levels = np.arange(256, dtype=np.uint8)
    as_float = to_float(levels)
    assert as_float.dtype == np.float32 and as_float[0] == 0.0 and as_float[-1] == 1.0
    np.testing.assert_array_equal(to_uint8(as_float), levels)
    np.testing.assert_array_equal(to_uint8(as_float.astype(np.float16)), levels)


def test_to_uint8_rounds_to_nearest_and_clips():
    x = np.array([-0.5, 0.0, 0.4 / 255, 0.6 / 255, 127.4 / 255, 127.6 / 255, 1.0, 3.0])
    np.testing.assert_array_equal(to_uint8(x), [0, 0, 0, 1, 127, 128, 255, 255])


def test_conversions_reject_wrong_input():
    with pytest.raises(ValueError, match="NaN"):
        to_uint8(np.array([0.5, np.nan]))
    with pytest.raises(ValueError):
        to_uint8(np.zeros(3, np.uint8))
    with pytest.raises(ValueError):
        to_float(np.zeros(3, np.float32))


@pytest.mark.parametrize("shape", SHAPES)
def test_rgb_png_roundtrip_exact(tmp_path, shape):
    rgb = np.random.default_rng(0).integers(0, 256, (*shape, 3), dtype=np.uint8)
    path = write_image(tmp_path / "im.png", rgb)
    assert path == tmp_path / "im.png"
    back = read_image(path)
    assert back.dtype == np.uint8
    np.testing.assert_array_equal(back, rgb)
    assert [p.name for p in tmp_path.iterdir()] == ["im.png"]


def test_float_image_is_written_via_to_uint8(tmp_path):
    rgb = np.random.default_rng(1).uniform(-0.1, 1.1, (3, 5, 3))
    np.testing.assert_array_equal(read_image(write_image(tmp_path / "f.png", rgb)), to_uint8(rgb))


def test_channel_order_on_disk_is_standard(tmp_path):
    red = np.zeros((2, 3, 3), np.uint8)
    red[..., 0] = 255
    path = write_image(tmp_path / "red.png", red)
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)  # what any other tool sees
    np.testing.assert_array_equal(bgr[..., 2], 255)
    np.testing.assert_array_equal(bgr[..., :2], 0)
    np.testing.assert_array_equal(read_image(path), red)


def test_grey_is_replicated_and_alpha_dropped(tmp_path):
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    np.testing.assert_array_equal(read_image(write_image(tmp_path / "g.png", grey)), np.stack([grey] * 3, -1))
    rgba = np.random.default_rng(2).integers(0, 256, (3, 4, 4), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), rgba[..., [2, 1, 0, 3]])
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgba[..., :3])


@pytest.mark.parametrize("shape", SHAPES)
def test_depth_png_mm_roundtrip_exact(tmp_path, shape):
    depth_mm = np.random.default_rng(3).integers(0, 65536, shape, dtype=np.uint16)
    depth_m = np.where(depth_mm > 0, depth_mm / 1000.0, np.nan)
    path = write_depth_png_mm(tmp_path / "d.png", depth_m)
    back = read_depth_png(path, 1000.0)
    assert back.dtype == np.float32 and back.shape == shape
    np.testing.assert_array_equal(np.isnan(back), depth_mm == 0)
    np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), depth_mm)
    write_depth_png_mm(tmp_path / "again.png", back)  # metres read back -> the same millimetres
    assert (tmp_path / "again.png").read_bytes() == path.read_bytes()


def test_depth_png_mm_marks_unrepresentable_depth_as_zero(tmp_path):
    depth_m = np.array([[np.nan, np.inf, -1.0, 0.0004, 0.0006, 1.2344, 65.535, 65.536]])
    path = write_depth_png_mm(tmp_path / "d.png", depth_m)
    np.testing.assert_array_equal(
        cv2.imread(str(path), cv2.IMREAD_UNCHANGED), [[0, 0, 0, 0, 1, 1234, 65535, 0]]
    )


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError, match="nope.png: no such file"):
        read_image(tmp_path / "nope.png")


@pytest.mark.parametrize("content", [b"", b"\x89PNG\r\n\x1a\n garbage", "truncated"])
@pytest.mark.parametrize("reader", [read_image, lambda p: read_depth_png(p, 1000.0)])
def test_corrupt_png_is_input_error(tmp_path, content, reader):
    good = write_image(tmp_path / "good.png", np.full((16, 16, 3), 7, np.uint8))
    if content == "truncated":
        content = good.read_bytes()[:40]
    bad = tmp_path / "bad.png"
    bad.write_bytes(content)
    with pytest.raises(InputError, match="bad.png"):
        reader(bad)


def test_bit_depth_mismatch_is_input_error(tmp_path):
    rgb_path = write_image(tmp_path / "rgb.png", np.zeros((2, 2, 3), np.uint8))
    depth_path = write_depth_png_mm(tmp_path / "depth.png", np.ones((2, 2)))
    with pytest.raises(InputError, match="depth.png: expected an 8-bit image"):
        read_image(depth_path)
    with pytest.raises(InputError, match="rgb.png: expected a single-channel 16-bit"):
        read_depth_png(rgb_path, 1000.0)


@pytest.mark.parametrize(
    "name, image",
    [
        ("x.png", np.zeros((2, 2, 4), np.uint8)),
        ("x.png", np.zeros((0, 2, 3), np.uint8)),
        ("x.unknown", np.zeros((2, 2, 3), np.uint8)),
    ],
)
def test_write_image_rejects_bad_arguments(tmp_path, name, image):
    with pytest.raises(ValueError):
        write_image(tmp_path / name, image)
    assert not list(tmp_path.iterdir())
