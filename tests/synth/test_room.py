"""Room specs: presets, determinism, validation, footprints and occupancy."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.synth.room import (
    FIRST_BOX_SURFACE_ID,
    LOOP_CLEARANCE_M,
    ROOM_PRESETS,
    Box,
    Material,
    Poster,
    RoomSpec,
    box_footprints_xy,
    clearance_xy_m,
    face_index,
    make_room,
    occupancy_grid,
    occupancy_polygons,
    room_diagonal_m,
    room_faces,
    walk_loop_points_xy,
)
from tests.synth.simple_room import MAT, simple_spec


def test_presets_build_for_many_seeds():
    for name in ROOM_PRESETS:
        for seed in range(8):
            spec = make_room(name, seed)
            assert spec.name == name and spec.seed == seed
            assert len(spec.boxes) >= 4 and len(spec.posters) >= 2


def test_same_seed_same_spec_and_seeds_differ():
    for name in ROOM_PRESETS:
        assert make_room(name, 3) == make_room(name, 3)
        assert make_room(name, 3) != make_room(name, 4)


def test_presets_look_different():
    specs = [make_room(name, 0) for name in ROOM_PRESETS]
    assert len({s.size_xyz_m for s in specs}) == len(specs)
    labels = [tuple(sorted({b.label.split(".")[0] for b in s.boxes})) for s in specs]
    assert len(set(labels)) == len(specs)
    assert len({(s.surfaces[0], s.surfaces[2]) for s in specs}) == len(specs)


def test_unknown_preset_lists_the_valid_names():
    with pytest.raises(ValueError, match="robot-lab.*seminar-room"):
        make_room("garage")
    with pytest.raises(ValueError, match="seed"):
        make_room("kitchen", -1)


def test_furniture_inside_room_and_pieces_do_not_interpenetrate():
    for name in ROOM_PRESETS:
        spec = make_room(name, 1)
        size = np.array(spec.size_xyz_m)
        lo = np.array([b.min_xyz_m for b in spec.boxes])
        hi = np.array([b.max_xyz_m for b in spec.boxes])
        assert np.all(lo >= 0) and np.all(hi <= size)
        overlap = np.minimum(hi[:, None], hi[None]) - np.maximum(lo[:, None], lo[None])  # (B, B, 3)
        volume = np.prod(np.clip(overlap, 0, None), axis=-1)
        np.fill_diagonal(volume, 0)
        assert volume.max() < 1e-9, name


def test_walk_loop_keeps_its_clearance():
    for name in ROOM_PRESETS:
        for seed in range(4):
            spec = make_room(name, seed)
            d = clearance_xy_m(spec, walk_loop_points_xy(spec, 2000))
            assert d.min() >= LOOP_CLEARANCE_M - 1e-6
            assert spec.walk_loop_xy_m[2] >= 0.8 and spec.walk_loop_xy_m[3] >= 0.8  # a real loop, not a spot


def test_clearance_matches_hand_computation():
    spec = simple_spec()
    pts = np.array([[0.5, 1.5], [1.5, 1.5], [3.0, 2.0], [2.5, 2.5], [-1.0, 1.0]])
    np.testing.assert_allclose(clearance_xy_m(spec, pts), [0.5, 0.0, 1.0, np.sqrt(0.5), -1.0])


def test_spec_validation():
    with pytest.raises(ValueError, match="leaves the room"):
        simple_spec(boxes=(Box((5.5, 1.0, 0.0), (6.5, 2.0, 1.0), MAT, "out"),))
    with pytest.raises(ValueError, match="walk_loop"):
        simple_spec(walk_loop_xy_m=(3.0, 2.0, 0.8, 0.6))  # passes 0.2 m from the cube
    with pytest.raises(ValueError, match="6 materials"):
        simple_spec(surfaces=(MAT,) * 5)
    with pytest.raises(ValueError, match="min < max"):
        Box((1.0, 1.0, 1.0), (1.0, 2.0, 2.0), MAT, "flat")
    with pytest.raises(ValueError, match="metres_per_texel"):
        Material("gravel", 0.0)
    with pytest.raises(ValueError, match="wall"):
        Poster(0, "coffee", 1.0, 1.0, 0.5, 0.5)
    with pytest.raises(ValueError, match="leaves its wall"):
        simple_spec(posters=(Poster(2, "coffee", 3.9, 1.5, 0.5, 0.5),))  # wall x = 0 is 4 m long


def test_dict_round_trip_through_json():
    for name in ROOM_PRESETS:
        spec = make_room(name, 2)
        again = RoomSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
        assert again == spec
    data = make_room("kitchen").to_dict()
    data["boxes"][0]["colour"] = "red"
    with pytest.raises(ValueError, match=r"boxes\[0\].*colour"):
        RoomSpec.from_dict(data)


def test_faces_texture_frames():
    spec = simple_spec()
    faces = room_faces(spec)
    assert len(faces) == 6 + 6 * len(spec.boxes)
    for k, f in enumerate(faces):
        assert face_index(f.surface_id, f.axis, f.side) == k
        n, u, v = (np.array(x) for x in (f.normal, f.u_dir, f.v_dir))
        if f.axis != 2:  # upright, unmirrored from the front: (u, v, -normal) like camera axes (x, y, z)
            np.testing.assert_array_equal(np.cross(u, v), -n)
            assert v[2] == -1
    wall_x0 = faces[2]
    assert wall_x0.normal == (1.0, 0.0, 0.0) and wall_x0.u_dir == (0.0, 1.0, 0.0)
    assert wall_x0.origin_xyz_m == (0.0, 0.0, 2.5) and wall_x0.size_uv_m == (4.0, 2.5)
    cube_top = faces[face_index(FIRST_BOX_SURFACE_ID, 2, 1)]
    assert cube_top.normal == (0.0, 0.0, 1.0) and cube_top.origin_xyz_m == (1.0, 1.0, 1.0)


def test_occupancy_polygons():
    spec = make_room("living-room")
    polys = occupancy_polygons(spec)
    assert len(polys) == 4 + len(spec.boxes)
    for p in polys:
        x, y = p[:, 0], p[:, 1]
        area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
        assert p.shape == (4, 2) and area > 0  # counter-clockwise
    np.testing.assert_allclose(polys[4], box_footprints_xy(spec)[0][[0, 1, 2, 1, 2, 3, 0, 3]].reshape(4, 2))


def test_occupancy_grid_origin_axes_and_content():
    spec = simple_spec()
    grid = occupancy_grid(spec, 0.25)
    assert grid.shape == (16, 24) and grid.dtype == bool  # rows along y (4 m), columns along x (6 m)
    expected = np.zeros((16, 24), dtype=bool)
    expected[4:8, 4:8] = True  # the cube covers x, y in [1, 2]
    np.testing.assert_array_equal(grid, expected)
    coarse = occupancy_grid(spec, 0.35)  # 6 / 0.35 and 4 / 0.35 are not whole: last row/column stick out
    assert coarse.shape == (12, 18) and coarse[-1].all() and coarse[:, -1].all() and not coarse[-2, :-1].any()
    for name in ROOM_PRESETS:
        s = make_room(name)
        g = occupancy_grid(s, 0.1)
        xy = walk_loop_points_xy(s, 500)
        assert not g[(xy[:, 1] / 0.1).astype(int), (xy[:, 0] / 0.1).astype(int)].any()
        x0, y0, x1, y1 = box_footprints_xy(s)[0]
        assert g[int((y0 + y1) / 2 / 0.1), int((x0 + x1) / 2 / 0.1)]
    with pytest.raises(ValueError):
        occupancy_grid(spec, 0.0)


def test_room_diagonal():
    assert room_diagonal_m(simple_spec()) == pytest.approx(np.sqrt(36 + 16 + 6.25))
