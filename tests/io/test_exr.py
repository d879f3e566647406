import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.exr import (
    read_depth_exr,
    read_exr,
    read_points_exr,
    read_rgb_exr,
    write_depth_exr,
    write_exr,
    write_points_exr,
    write_rgb_exr,
)

SHAPES = [(4, 6), (6, 4), (1, 7), (7, 1), (1, 1)]


def bits(a: np.ndarray) -> np.ndarray:
    """Raw bit patterns, so NaN payloads and -0.0 compare exactly."""
    return np.ascontiguousarray(a).view(f"u{a.dtype.itemsize}")


def assert_bit_equal(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.dtype == expected.dtype and actual.shape == expected.shape
    np.testing.assert_array_equal(bits(actual), bits(expected))


def random_depth(shape, rng) -> np.ndarray:
    depth = rng.uniform(0.1, 80.0, shape).astype(np.float32)
    flat = depth.reshape(-1)
    flat[0] = np.inf  # no hit
    flat[-1] = np.nan  # invalid
    if flat.size > 2:
        flat[1] = -0.0
    return depth


@pytest.mark.parametrize("shape", SHAPES)
def test_depth_roundtrip_bit_exact(tmp_path, shape):
    depth = random_depth(shape, np.random.default_rng(0))
    path = write_depth_exr(tmp_path / "depth.exr", depth)
    assert path == tmp_path / "depth.exr"
    assert_bit_equal(read_depth_exr(path), depth)
    assert list(read_exr(path)) == ["Z"]


def test_nan_payload_and_infinities_survive(tmp_path):
    depth = np.array([[np.inf, -np.inf, np.nan, 0.0]], dtype=np.float32)
    bits(depth)[0, 2] = 0x7FC00123  # a NaN with a payload
    assert_bit_equal(read_depth_exr(write_depth_exr(tmp_path / "d.exr", depth)), depth)


@pytest.mark.parametrize("compression", ["NONE", "RLE", "ZIPS", "ZIP", "PIZ"])
def test_mixed_channel_types_roundtrip(tmp_path, compression):
    rng = np.random.default_rng(1)
    channels = {
        "depth": random_depth((5, 3), rng),
        "half": rng.normal(size=(5, 3)).astype(np.float32),
        "already_half": rng.normal(size=(5, 3)).astype(np.float16),
        "label": rng.integers(0, 2**32, (5, 3), dtype=np.uint32),
    }
    path = write_exr(tmp_path / "m.exr", channels, half={"half"}, compression=compression)
    back = read_exr(path)
    assert sorted(back) == sorted(channels)
    assert_bit_equal(back["depth"], channels["depth"])
    assert_bit_equal(back["half"], channels["half"].astype(np.float16))
    assert_bit_equal(back["already_half"], channels["already_half"])
    assert_bit_equal(back["label"], channels["label"])


def test_half_true_stores_every_float_channel_as_half(tmp_path):
    a = np.linspace(-70000, 70000, 12, dtype=np.float32).reshape(3, 4)
    back = read_exr(write_exr(tmp_path / "h.exr", {"a": a, "b": a * 0.5}, half=True))
    with np.errstate(over="ignore"):
        assert_bit_equal(back["a"], a.astype(np.float16))  # beyond ±65504 -> ±inf, as documented
    assert np.isinf(back["a"][0, 0]) and back["b"].dtype == np.float16


def test_float64_and_small_uints_are_widened_or_rounded_as_documented(tmp_path):
    a64 = np.random.default_rng(2).normal(size=(2, 3))
    u8 = np.arange(6, dtype=np.uint8).reshape(2, 3)
    back = read_exr(write_exr(tmp_path / "w.exr", {"a": a64, "u": u8}))
    assert_bit_equal(back["a"], a64.astype(np.float32))
    assert_bit_equal(back["u"], u8.astype(np.uint32))


def test_non_contiguous_views_are_written_in_logical_order(tmp_path):
    base = np.arange(48, dtype=np.float32).reshape(4, 12)
    views = {"step": base[:, ::2], "F": np.asfortranarray(base[:, 6:])}
    views["T"] = np.ascontiguousarray(base[:, :6].T).T  # a transposed (F-ordered) view
    back = read_exr(write_exr(tmp_path / "v.exr", views))
    for name, view in views.items():
        np.testing.assert_array_equal(back[name], view)


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
@pytest.mark.parametrize("shape", [(3, 5), (1, 4)])
def test_rgb_roundtrip(tmp_path, dtype, shape):
    rgb = np.random.default_rng(3).uniform(0, 4, (*shape, 3)).astype(dtype)
    back = read_rgb_exr(write_rgb_exr(tmp_path / "rgb.exr", rgb, dtype=dtype))
    assert_bit_equal(back, rgb)
    assert sorted(read_exr(tmp_path / "rgb.exr")) == ["B", "G", "R"]


def test_points_roundtrip_rows_are_beams(tmp_path):
    rng = np.random.default_rng(4)
    beams, steps = 16, 9
    points = {c: rng.normal(size=(beams, steps)).astype(np.float32) for c in "XYZ"}
    points["range"] = np.sqrt(points["X"] ** 2 + points["Y"] ** 2 + points["Z"] ** 2)
    points["range"][3, 4] = np.inf
    points["intensity"] = rng.uniform(0, 1, (beams, steps)).astype(np.float32)
    points["ring"] = np.repeat(np.arange(beams, dtype=np.uint32)[:, None], steps, axis=1)
    back = read_points_exr(write_points_exr(tmp_path / "scan.exr", points))
    assert sorted(back) == sorted(points)
    for name, values in points.items():
        assert_bit_equal(back[name], values)


def test_successful_write_leaves_no_temporary_files_and_overwrites(tmp_path):
    write_depth_exr(tmp_path / "d.exr", np.zeros((2, 2), np.float32))
    write_depth_exr(tmp_path / "d.exr", np.ones((2, 2), np.float32))
    assert [p.name for p in tmp_path.iterdir()] == ["d.exr"]
    np.testing.assert_array_equal(read_depth_exr(tmp_path / "d.exr"), 1.0)


@pytest.mark.parametrize(
    "channels, kwargs",
    [
        ({}, {}),
        ({"a": np.zeros((2, 2)), "b": np.zeros((2, 3))}, {}),
        ({"a": np.zeros((2, 2, 3))}, {}),
        ({"a": np.zeros((0, 3))}, {}),
        ({"a": np.zeros((2, 2), np.int32)}, {}),
        ({"a": np.zeros((2, 2), np.uint32)}, {"half": True}),
        ({"a": np.zeros((2, 2))}, {"half": {"b"}}),
        ({"a": np.zeros((2, 2))}, {"compression": "DWAA"}),
    ],
)
def test_write_rejects_bad_arguments(tmp_path, channels, kwargs):
    with pytest.raises(ValueError):
        write_exr(tmp_path / "bad.exr", channels, **kwargs)
    assert not list(tmp_path.iterdir())


def test_points_require_xyz(tmp_path):
    with pytest.raises(ValueError, match="missing"):
        write_points_exr(tmp_path / "p.exr", {"X": np.zeros((2, 2)), "Y": np.zeros((2, 2))})


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError, match="nope.exr: no such file"):
        read_exr(tmp_path / "nope.exr")


@pytest.mark.parametrize("content", [b"", b"not an exr at all" * 8, "truncated"])
def test_corrupt_file_is_input_error(tmp_path, content):
    good = write_depth_exr(tmp_path / "good.exr", np.ones((8, 8), np.float32))
    if content == "truncated":
        content = good.read_bytes()[: good.stat().st_size // 2]
    bad = tmp_path / "bad.exr"
    bad.write_bytes(content)
    with pytest.raises(InputError, match="bad.exr") as err:
        read_depth_exr(bad)
    assert "\n" not in str(err.value)


def test_missing_channel_is_input_error(tmp_path):
    path = write_exr(tmp_path / "x.exr", {"A": np.zeros((2, 2))})
    with pytest.raises(InputError, match="x.exr: missing channel 'Z'"):
        read_depth_exr(path)
    with pytest.raises(InputError, match="missing channel 'R'"):
        read_rgb_exr(path)
    with pytest.raises(InputError, match="missing channel 'X'"):
        read_points_exr(path)


def test_integer_depth_channel_is_input_error(tmp_path):
    path = write_exr(tmp_path / "z.exr", {"Z": np.zeros((2, 2), np.uint32)})
    with pytest.raises(InputError, match="expected float"):
        read_depth_exr(path)
