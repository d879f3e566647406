"""Surface PLY and GLB writers: layout, comments, round trips through plyfile, read_ply and trimesh, same bytes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from plyfile import PlyData

from nsim.io.mesh import read_glb, read_ply_comments, write_glb, write_surface_ply
from nsim.io.ply import read_ply


@pytest.fixture
def sphere():
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    vertices = m.vertices + [3.0, -2.0, 1.5]  # world coordinates away from the origin: nothing re-centred
    rgb = np.random.default_rng(0).integers(0, 256, (len(vertices), 3), dtype=np.uint8)
    return vertices, np.asarray(m.faces), rgb, np.asarray(m.vertex_normals)


def test_point_cloud_ply_layout_and_round_trip(tmp_path, sphere):
    v, _, rgb, n = sphere
    path = write_surface_ply(tmp_path / "p.ply", v, rgb, n, comments=["frame: world, z up", "units: metres"])
    ply = PlyData.read(str(path))
    assert ply.header.startswith("ply\nformat binary_little_endian 1.0")
    assert [p.name for p in ply["vertex"].properties] == ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    assert "face" not in ply
    assert read_ply_comments(path) == ["frame: world, z up", "units: metres"]
    cloud = read_ply(path)
    assert np.array_equal(cloud.xyz, v.astype(np.float32)) and np.array_equal(cloud.rgb, rgb)
    assert np.array_equal(np.stack([cloud.fields[k] for k in ("nx", "ny", "nz")], 1), n.astype(np.float32))
    assert [p.name for p in tmp_path.iterdir()] == ["p.ply"]


def test_mesh_ply_loads_in_trimesh(tmp_path, sphere):
    v, f, rgb, n = sphere
    path = write_surface_ply(tmp_path / "m.ply", v, rgb, n, f, comments=["units: metres"])
    m = trimesh.load(str(path), process=False)
    assert np.allclose(m.vertices, v, atol=1e-6) and np.array_equal(m.faces, f)
    assert np.array_equal(m.visual.vertex_colors[:, :3], rgb)
    assert PlyData.read(str(path))["face"]["vertex_indices"].dtype == object


def test_glb_round_trip_metadata_and_same_bytes(tmp_path, sphere):
    v, f, rgb, n = sphere
    meta = {"frame": "world, z up", "units": "metres"}
    a = write_glb(tmp_path / "a.glb", v, f, rgb, n, meta)
    b = write_glb(tmp_path / "b.glb", v, f, rgb, n, meta)
    assert a.read_bytes() == b.read_bytes()
    mesh, asset = read_glb(a)
    assert asset["extras"] == meta and asset["version"] == "2.0"
    assert np.allclose(mesh.vertices, v, atol=1e-6) and np.array_equal(mesh.faces, f)
    assert mesh.visual.kind == "vertex" and np.array_equal(mesh.visual.vertex_colors[:, :3], rgb)
    assert np.allclose(mesh.vertex_normals, n, atol=1e-5)
    scene = trimesh.load(str(a))
    assert scene.metadata["units"] == "metres"


def test_bad_arrays_are_refused(tmp_path, sphere):
    v, f, rgb, n = sphere
    with pytest.raises(ValueError, match="rgb"):
        write_surface_ply(tmp_path / "x.ply", v, rgb.astype(np.float32))
    with pytest.raises(ValueError, match="faces"):
        write_surface_ply(tmp_path / "x.ply", v, rgb, n, f + len(v))
    with pytest.raises(ValueError, match="line break"):
        write_surface_ply(tmp_path / "x.ply", v, comments=["a\nb"])
    assert not list(tmp_path.iterdir())
