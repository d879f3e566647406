import numpy as np
import plyfile
import pytest

from nsim.errors import InputError
from nsim.io.ply import PointCloud, read_ply, write_ply


def bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(f"u{a.dtype.itemsize}")


def assert_bit_equal(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.dtype == expected.dtype and actual.shape == expected.shape
    np.testing.assert_array_equal(bits(actual), bits(expected))


def make_cloud(n: int, xyz_dtype=np.float32, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(scale=30.0, size=(n, 3)).astype(xyz_dtype)
    intensity = rng.uniform(0, 1, n).astype(np.float32)
    if n >= 3:
        intensity[:3] = [np.nan, np.inf, -0.0]
    fields = {
        "intensity": intensity,
        "ring": rng.integers(0, 2**16, n, dtype=np.uint16),
        "label": rng.integers(-128, 128, n, dtype=np.int8),
        "time_s": rng.uniform(0, 0.1, n),
    }
    return PointCloud(xyz, rng.integers(0, 256, (n, 3), dtype=np.uint8), fields)


def assert_cloud_equal(actual: PointCloud, expected: PointCloud) -> None:
    assert_bit_equal(actual.xyz, expected.xyz)
    if expected.rgb is None:
        assert actual.rgb is None
    else:
        assert_bit_equal(actual.rgb, expected.rgb)
    assert list(actual.fields) == list(expected.fields)
    for name, values in expected.fields.items():
        assert_bit_equal(actual.fields[name], values)


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("xyz_dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n", [0, 1, 257])
def test_roundtrip_exact(tmp_path, binary, xyz_dtype, n):
    cloud = make_cloud(n, xyz_dtype)
    path = write_ply(tmp_path / "c.ply", cloud.xyz, cloud.rgb, cloud.fields, binary=binary)
    assert path == tmp_path / "c.ply"
    back = read_ply(path)
    assert len(back) == n
    assert_cloud_equal(back, cloud)
    assert [p.name for p in tmp_path.iterdir()] == ["c.ply"]


@pytest.mark.parametrize("binary", [True, False])
def test_xyz_only_roundtrip(tmp_path, binary):
    xyz = np.arange(12, dtype=np.float32).reshape(4, 3)
    back = read_ply(write_ply(tmp_path / "c.ply", xyz, binary=binary))
    assert_cloud_equal(back, PointCloud(xyz))


def test_header_is_standard(tmp_path):
    cloud = make_cloud(2)
    path = write_ply(tmp_path / "c.ply", cloud.xyz, cloud.rgb, {"ring": cloud.fields["ring"]})
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "format binary_little_endian 1.0" in header
    for line in ["element vertex 2", "property float x", "property uchar red", "property ushort ring"]:
        assert line in header


def test_big_endian_file_reads_native(tmp_path):
    cloud = make_cloud(5)
    vertex = np.empty(5, dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("intensity", ">f4")])
    for i, c in enumerate("xyz"):
        vertex[c] = cloud.xyz[:, i]
    vertex["intensity"] = cloud.fields["intensity"]
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], byte_order=">").write(
        str(tmp_path / "be.ply")
    )
    back = read_ply(tmp_path / "be.ply")
    assert back.xyz.dtype.isnative and back.xyz.flags.c_contiguous
    assert_cloud_equal(back, PointCloud(cloud.xyz, None, {"intensity": cloud.fields["intensity"]}))


def test_float_colours_stay_fields_and_faces_are_ignored(tmp_path):
    vertex = np.zeros(
        3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "f4"), ("green", "f4"), ("blue", "f4")]
    )
    faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "O")])
    elements = [plyfile.PlyElement.describe(vertex, "vertex"), plyfile.PlyElement.describe(faces, "face")]
    plyfile.PlyData(elements).write(str(tmp_path / "mesh.ply"))
    back = read_ply(tmp_path / "mesh.ply")
    assert back.rgb is None and list(back.fields) == ["red", "green", "blue"]


@pytest.mark.parametrize("binary", [True, False])
def test_truncated_file_is_input_error(tmp_path, binary):
    cloud = make_cloud(50)
    path = write_ply(tmp_path / "c.ply", cloud.xyz, cloud.rgb, cloud.fields, binary=binary)
    data = path.read_bytes()
    cut = len(data) - 10 if binary else data.rstrip(b"\n").rfind(b"\n") + 1  # drop the last row
    path.write_bytes(data[:cut])
    with pytest.raises(InputError, match="c.ply: malformed PLY: .*row 49"):
        read_ply(path)


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "malformed PLY"),
        (b"hello", "malformed PLY"),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
            "lacks",
        ),
        (b"ply\nformat ascii 1.0\nelement face 0\nproperty float a\nend_header\n", "no 'vertex' element"),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            b"end_header\n1 2 oops\n",
            "malformed",
        ),
    ],
)
def test_bad_file_is_input_error(tmp_path, content, match):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(InputError, match=f"bad.ply: .*{match}") as err:
        read_ply(path)
    assert "\n" not in str(err.value)


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError, match="nope.ply: no such file"):
        read_ply(tmp_path / "nope.ply")


@pytest.mark.parametrize(
    "kwargs",
    [
        {"xyz": np.zeros((3, 2), np.float32)},
        {"xyz": np.zeros((3, 3), np.float16)},
        {"rgb": np.zeros((2, 3), np.uint8)},
        {"rgb": np.zeros((3, 3), np.float32)},
        {"fields": {"ring": np.zeros(2, np.uint16)}},
        {"fields": {"red": np.zeros(3, np.uint8)}},
        {"fields": {"has space": np.zeros(3, np.uint8)}},
        {"fields": {"big": np.zeros(3, np.int64)}},
    ],
)
def test_write_rejects_bad_arguments(tmp_path, kwargs):
    args = {"xyz": np.zeros((3, 3), np.float32)} | kwargs
    with pytest.raises(ValueError):
        write_ply(tmp_path / "c.ply", **args)
    assert not list(tmp_path.iterdir())


def test_failed_write_keeps_previous_file(tmp_path, monkeypatch):
    path = write_ply(tmp_path / "c.ply", np.zeros((2, 3), np.float32))
    before = path.read_bytes()

    def crash(self, stream):
        stream.write(b"ply\nformat")
        raise OSError("disk full")

    monkeypatch.setattr(plyfile.PlyData, "write", crash)
    with pytest.raises(OSError, match="disk full"):
        write_ply(path, np.ones((5, 3), np.float32))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["c.ply"]
