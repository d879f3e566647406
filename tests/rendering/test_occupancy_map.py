"""The 2D map: free / occupied / unknown from the training views, polygons with holes, scored against a test room."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch
import yaml

from nsim.crowd.neighbours import points_in_polygons
from nsim.geometry.cameras import Camera
from nsim.rendering.occupancy import (
    CELL_FREE,
    CELL_OCCUPIED,
    CELL_UNKNOWN,
    OBSTACLE_FILES,
    CameraViews,
    ObstacleMap,
    OccupancyGrid,
    free_space_iou,
    obstacle_map,
    regions_from_mask,
    room_free_space,
)
from nsim.synth.path import handheld_path
from nsim.synth.room import WALL_THICKNESS_M, make_room, walk_loop_points_xy

SIGMA = 200.0  # 1/m: opaque within a few millimetres


def room_density(spec):
    """The test room as a density field: walls, floor and ceiling slabs ``WALL_THICKNESS_M`` thick and every box."""
    X, Y, Z = spec.size_xyz_m
    t = WALL_THICKNESS_M
    boxes = [((-t, -t, -t), (0, Y + t, Z + t)), ((X, -t, -t), (X + t, Y + t, Z + t)),
             ((-t, -t, -t), (X + t, 0, Z + t)), ((-t, Y, -t), (X + t, Y + t, Z + t)),
             ((-t, -t, -t), (X + t, Y + t, 0)), ((-t, -t, Z), (X + t, Y + t, Z + t))]
    boxes += [(b.min_xyz_m, b.max_xyz_m) for b in spec.boxes]
    lo_hi = torch.tensor(boxes, dtype=torch.float32)

    def density(x):
        inside = ((x[:, None] >= lo_hi[None, :, 0]) & (x[:, None] <= lo_hi[None, :, 1])).all(-1).any(-1)
        return inside.float() * SIGMA

    return density


def room_views(spec, n=24):
    """A handheld capture's poses (an eye-height loop and a low loop, looking inwards) with a small pinhole."""
    cam = Camera.pinhole_from_fov(64, 48, 75.0)
    return CameraViews(handheld_path(spec, n, seed=0), (cam,), np.zeros(n, dtype=np.int64), 0.2, 30.0)


def room_map(spec, views, cell_m=0.1):
    X, Y, Z = spec.size_xyz_m
    aabb = np.array([[-1.5, -1.5, -0.5], [X + 1.5, Y + 1.5, Z + 0.5]])
    return obstacle_map(room_density(spec), aabb, (0.1, 1.0), cell_m, 0.05, samples_per_cell=4,
                        generator=torch.Generator().manual_seed(0), views=views)


@pytest.fixture(scope="module")
def lab():
    spec = make_room("robot-lab", 0)
    return spec, room_map(spec, room_views(spec))


# ---------------------------------------------------------------------------------- polygons with holes
def test_ring_of_walls_is_a_polygon_with_a_hole():
    mask = np.zeros((20, 16), dtype=bool)
    mask[2:18, 2:14] = True
    mask[4:16, 4:12] = False  # the room inside a ring of walls
    mask[7:9, 7:9] = True  # a pillar in the room
    mask[0, 0] = True  # a speck in a corner
    regions = regions_from_mask(mask, (10.0, -5.0), 0.5)
    rings = sorted(regions, key=lambda r: -len(r.holes_m))
    assert len(regions) == 3 and len(rings[0].holes_m) == 1 and rings[1].holes_m == rings[2].holes_m == ()

    def area(ring):
        return 0.5 * np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])

    assert all(area(r.outer_m) > 0 for r in regions) and area(rings[0].holes_m[0]) < 0  # ccw outside, cw holes
    # every cell centre is inside an obstacle exactly when its cell is in the mask (holes respected)
    centres = np.stack(np.meshgrid(10.0 + (np.arange(20) + 0.5) * 0.5, -5.0 + (np.arange(16) + 0.5) * 0.5,
                                   indexing="ij"), -1).reshape(-1, 2)
    inside = points_in_polygons(centres, [r.outer_m for r in regions], [r.holes_m for r in regions])
    assert (inside == mask.reshape(-1)).all()
    # the hole runs half-way between the walls' and the room's cell centres: on the cell edges
    hole = rings[0].holes_m[0]
    assert hole[:, 0].min() == pytest.approx(10.0 + 4 * 0.5) and hole[:, 0].max() == pytest.approx(10.0 + 16 * 0.5)


def test_diagonal_gaps_are_closed():
    mask = np.zeros((6, 6), dtype=bool)
    mask[1, 1] = mask[2, 2] = True  # touching at a corner only: one obstacle, nobody passes between
    regions = regions_from_mask(mask, (0.0, 0.0), 1.0)
    assert len(regions) == 1 and regions[0].holes_m == ()


# ---------------------------------------------------------------------------------- free / occupied / unknown
def test_room_map_matches_the_ground_truth(lab):
    spec, om = lab
    truth = room_free_space(spec, om)
    iou = free_space_iou(om.free, truth)
    assert iou >= 0.9, iou
    cells = om.cells()
    assert set(np.unique(cells).tolist()) == {CELL_UNKNOWN, CELL_FREE, CELL_OCCUPIED}
    X, Y, _ = spec.size_xyz_m
    xy = om.cell_centres_m()
    outside = (xy[..., 0] < -0.3) | (xy[..., 0] > X + 0.3) | (xy[..., 1] < -0.3) | (xy[..., 1] > Y + 0.3)
    assert (cells[outside] == CELL_UNKNOWN).all()  # behind the walls: never seen
    assert (~om.free[outside]).all()
    # the walls are seen from inside: occupied, not unknown
    wall_face = (np.abs(xy[..., 0] + 0.05) < 0.05) & (xy[..., 1] > 1.0) & (xy[..., 1] < Y - 1.0) & om.occupied
    assert np.mean(cells[wall_face] == CELL_OCCUPIED) > 0.5
    # polygons: the walls (with everything unknown around them) are one region whose hole is the room
    regions = om.regions()
    loop = walk_loop_points_xy(spec, 90)
    assert not points_in_polygons(loop, [r.outer_m for r in regions], [r.holes_m for r in regions]).any()
    assert points_in_polygons(loop, [r.outer_m for r in regions]).all()  # ... which a solid polygon would cover
    furniture = np.array([[(b.min_xyz_m[0] + b.max_xyz_m[0]) / 2, (b.min_xyz_m[1] + b.max_xyz_m[1]) / 2]
                          for b in spec.boxes if b.min_xyz_m[2] < 0.5])
    assert points_in_polygons(furniture, [r.outer_m for r in regions], [r.holes_m for r in regions]).all()


def test_unknown_is_not_walkable_unless_asked(lab):
    spec, om = lab
    assert (om.blocked() == ~om.free).all()
    loose = om.blocked(unknown_walkable=True)
    assert (loose == om.occupied).all() and loose.sum() < om.blocked().sum()
    doc = om.occupancy_doc(unknown_walkable=True)
    assert doc["unknown"] == "free"


def test_the_same_inputs_give_the_same_bytes(tmp_path):
    spec = make_room("kitchen", 1)
    om, again = (room_map(spec, room_views(spec, 6), cell_m=0.2) for _ in range(2))
    assert (again.cells() == om.cells()).all()
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    om.save(tmp_path / "a")
    assert again.save(tmp_path / "b") == list(OBSTACLE_FILES)
    for name in OBSTACLE_FILES:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_save_and_load(lab, tmp_path):
    spec, om = lab
    om.save(tmp_path)
    doc = json.loads((tmp_path / "occupancy.json").read_text())
    assert (tmp_path / "obstacles.json").read_text() == (tmp_path / "occupancy.json").read_text()
    assert len(doc["holes"]) == len(doc["polygons"]) and sum(len(h) for h in doc["holes"]) >= 1
    assert doc["unknown"] == "obstacle" and doc["shape"] == list(om.shape)
    # the nav2 map, read with yaml and OpenCV: the same cells
    nav = yaml.safe_load((tmp_path / "map.yaml").read_text())
    assert nav["resolution"] == om.cell_m and nav["origin"] == [*om.origin_xy_m, 0.0] and nav["mode"] == "trinary"
    pgm = cv2.imread(str(tmp_path / nav["image"]), cv2.IMREAD_UNCHANGED)
    want = np.select([om.cells() == CELL_FREE, om.cells() == CELL_OCCUPIED], [254, 0], 205)
    assert pgm.shape == om.shape[::-1] and (pgm == want.T[::-1]).all()
    assert (cv2.imread(str(tmp_path / "obstacle_cells.png"), cv2.IMREAD_UNCHANGED) == pgm).all()
    back = ObstacleMap.load(tmp_path)
    assert (back.cells() == om.cells()).all() and back.origin_xy_m == om.origin_xy_m and back.cell_m == om.cell_m
    assert free_space_iou(back.free, om.free) == 1.0


def test_free_space_iou():
    a = np.array([[True, True], [False, False]])
    b = np.array([[True, False], [True, False]])
    assert free_space_iou(a, b) == pytest.approx(1 / 3)
    assert free_space_iou(a, a) == 1.0 and free_space_iou(~(a | ~a), ~(a | ~a)) == 1.0
    with pytest.raises(ValueError):
        free_space_iou(a, np.zeros((3, 2), bool))


def test_a_camera_sees_only_its_frustum():
    """One camera in an empty box looking along +x: behind it and outside its field of view stays unknown."""
    cam = Camera.pinhole_from_fov(32, 24, 60.0)
    c2w = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0.5], [0, 0, 0, 1]], dtype=np.float64)  # +z_cam = +x
    views = CameraViews(c2w[None], (cam,), np.zeros(1, dtype=np.int64), 0.0, 30.0)
    om = obstacle_map(lambda x: torch.zeros(len(x)), np.array([[-3.0, -3.0, 0.0], [3.0, 3.0, 1.0]]), (0.1, 1.0),
                      0.1, 0.05, views=views)
    xy = om.cell_centres_m()
    ahead = (xy[..., 0] > 0.5) & (np.abs(xy[..., 1]) < 0.3 * xy[..., 0])  # well inside the 60 deg field of view
    beside = np.abs(xy[..., 1]) > 0.8 * xy[..., 0] + 0.2  # outside it (and behind)
    assert om.free[ahead].all() and om.unknown[beside].all()


def _box_views(n=12, heights=(0.9, 1.6)):
    """Cameras on circles of radius 2.5 m at ``heights`` looking at (0, 0, 0.45), pinhole 64 x 48."""
    cam = Camera.pinhole_from_fov(64, 48, 75.0)
    poses = []
    for a, z in [(a, z) for z in heights for a in np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)]:
        eye = np.array([2.5 * np.cos(a), 2.5 * np.sin(a), z])
        fwd = np.array([0.0, 0.0, 0.45]) - eye
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, down, fwd], axis=1)  # OpenCV: x right, y down, z forward
        c2w[:3, 3] = eye
        poses.append(c2w)
    return CameraViews(np.stack(poses), (cam,), np.zeros(len(poses), dtype=np.int64), 0.1, 30.0)


def _floor_and(extra):
    """An opaque floor (z < 0) under a density ``extra(x)``."""
    return lambda x: torch.where(x[:, 2] < 0.0, torch.full_like(x[:, 0], SIGMA), extra(x))


def test_a_table_top_that_stops_rays_is_an_obstacle_below_the_threshold():
    """A 5 cm slab at 0.70-0.75 m of 30/m (a table top as a trained NeRF draws it: a thin sheet that
    a cell's samples mostly miss, so the cells' density is low) under an obstacle threshold of 50/m:
    the density alone calls it free, yet the views' rays, crossing it obliquely, stop on it."""
    def slab(x):
        on = (x[:, :2].abs() < 0.4).all(-1) & (x[:, 2] > 0.70) & (x[:, 2] < 0.75)
        return on.float() * 30.0

    aabb = np.array([[-3.0, -3.0, -0.2], [3.0, 3.0, 1.2]])
    views = _box_views()
    g = torch.Generator().manual_seed(0)
    om = obstacle_map(_floor_and(slab), aabb, (0.1, 1.0), 0.1, 50.0, samples_per_cell=4, generator=g, views=views)
    xy = om.cell_centres_m()
    under = (np.abs(xy) < 0.3).all(-1)
    assert om.occupied[under].mean() > 0.9
    blind = obstacle_map(_floor_and(slab), aabb, (0.1, 1.0), 0.1, 50.0, samples_per_cell=4,
                         generator=torch.Generator().manual_seed(0))  # the density alone
    assert not blind.occupied[under].any()
    clear = (np.abs(xy) > 0.7).any(-1) & (np.linalg.norm(xy, axis=-1) < 2.0)
    assert om.free[clear].mean() > 0.95


def test_haze_that_rays_cross_is_carved_and_a_solid_block_is_not():
    """Haze of 0.1/m below 0.5 m, above the obstacle threshold (0.05/m), and a solid block: where the
    views' rays went through the haze and on, it is not an obstacle; the block stays one."""
    def haze_and_block(x):
        block = (x[:, :2].abs() < 0.3).all(-1) & (x[:, 2] < 0.8)
        haze = torch.where(x[:, 2] < 0.5, torch.full_like(x[:, 0], 0.1), torch.zeros_like(x[:, 0]))
        return torch.where(block, torch.full_like(x[:, 0], SIGMA), haze)

    aabb = np.array([[-3.0, -3.0, -0.2], [3.0, 3.0, 1.2]])
    views = _box_views()
    om = obstacle_map(_floor_and(haze_and_block), aabb, (0.1, 1.0), 0.1, 0.05, samples_per_cell=2,
                      generator=torch.Generator().manual_seed(0), views=views)
    xy = om.cell_centres_m()
    assert om.occupied[(np.abs(xy) < 0.2).all(-1)].all()
    ring = (np.linalg.norm(xy, axis=-1) > 0.8) & (np.linalg.norm(xy, axis=-1) < 2.0)
    assert om.free[ring].mean() > 0.9
    # without the views (density alone) the haze above 0.05/m fills the map
    blind = obstacle_map(_floor_and(haze_and_block), aabb, (0.1, 1.0), 0.1, 0.05, samples_per_cell=2,
                         generator=torch.Generator().manual_seed(0))
    assert blind.occupied[ring].all()


def test_the_soft_front_a_nerf_draws_before_a_surface_is_free():
    """A solid block (|x|, |y| < 0.3 m) in a 15 cm soft front of 3/m, below the obstacle threshold
    (50/m): rays that cross the front squarely go on to the block, and rays grazing the block, with
    a longer path through the front, stop in it; the front's cells, whose centres rays went through
    and on, are free, and the block stays an obstacle."""
    def block_with_front(x):
        r = x[:, :2].abs().amax(-1)
        low = x[:, 2] < 0.8
        front = torch.where((r < 0.45) & low, torch.full_like(r, 3.0), torch.zeros_like(r))
        return torch.where((r < 0.3) & low, torch.full_like(r, SIGMA), front)

    aabb = np.array([[-3.0, -3.0, -0.2], [3.0, 3.0, 1.2]])
    om = obstacle_map(_floor_and(block_with_front), aabb, (0.1, 1.0), 0.05, 50.0, samples_per_cell=4,
                      generator=torch.Generator().manual_seed(0), views=_box_views(n=24),
                      depth_pixels=128 * 96)
    r = np.abs(om.cell_centres_m()).max(-1)
    assert om.occupied[r < 0.25].all()
    front = (r > 0.35) & (r < 0.45)
    assert om.free[front].mean() > 0.9, om.free[front].mean()


def test_opaque_range_in_a_slab_keeps_stops_inside_it_and_drops_the_rest():
    """A wall (x > 1.5 m), a floor (z < -1 m) and a ceiling (z > 1.8 m), rays from (0, 0, 1): with ``z_range`` a ray's stop is the same where
    it lies inside the slab, inf where it lies beyond it, and a ray that never meets the slab is inf."""
    from nsim.rendering.occupancy import opaque_range

    shape = (40, 40, 40)
    lo, hi = torch.tensor([-2.0, -2.0, -2.0]), torch.tensor([2.0, 2.0, 2.0])
    centres = [lo[a] + (torch.arange(shape[a]) + 0.5) * (hi[a] - lo[a]) / shape[a] for a in range(3)]
    x, _, z = torch.meshgrid(*centres, indexing="ij")
    sigma = torch.where((x > 1.5) | (z < -1.0) | (z > 1.8), 100.0, 0.0)  # a wall, a floor and a ceiling
    origins = torch.tensor([[0.0, 0.0, 1.0]] * 4)
    dirs = torch.nn.functional.normalize(torch.tensor([
        [1.0, 0.0, 0.0],    # level: meets the wall at x = 1.5, z = 1 (inside the slab below)
        [0.0, 0.0, -1.0],   # straight down: meets the floor at z = -1 (outside the slab)
        [0.0, 0.0, 1.0],    # up: meets the ceiling at z = 1.8, never the slab
        [1.0, 0.0, -0.5],   # down and out: meets the wall at x = 1.5, z = 0.25 (inside)
    ]), dim=-1)
    full = opaque_range(sigma, lo, hi, origins, dirs, 0.0, 30.0, 0.05)
    slab = opaque_range(sigma, lo, hi, origins, dirs, 0.0, 30.0, 0.05, z_range=(0.0, 1.5))
    assert torch.isfinite(full).all()
    assert abs(float(full[0]) - 1.5) < 0.1 and abs(float(full[1]) - 2.0) < 0.1
    assert slab[0] == full[0] and slab[3] == full[3]
    assert torch.isinf(slab[1]) and torch.isinf(slab[2])


def test_skipping_the_occupancy_grids_empty_cells_gives_the_same_map():
    """obstacle_map(skip=grid): the field is not evaluated where the occupancy grid (baked from the same
    field at a far lower density) is empty; the map is the same, with fewer density evaluations."""
    spec = make_room("kitchen", 0)
    X, Y, Z = spec.size_xyz_m
    aabb = np.array([[-1.5, -1.5, -0.5], [X + 1.5, Y + 1.5, Z + 0.5]])
    dens = room_density(spec)
    calls = []

    def counted(x):
        calls.append(len(x))
        return dens(x)

    grid = OccupancyGrid.bake(dens, aabb, 0.2, 0.005, samples_per_cell=4, generator=torch.Generator().manual_seed(1))
    assert 0.05 < grid.occupied_fraction < 0.9
    views = room_views(spec)
    maps = {}
    for name, skip in (("all", None), ("skip", grid)):
        calls.clear()
        maps[name] = obstacle_map(counted, aabb, (0.1, 1.0), 0.1, 0.05, samples_per_cell=4,
                                  generator=torch.Generator().manual_seed(0), views=views, skip=skip)
        maps[name + "_points"] = sum(calls)
    np.testing.assert_array_equal(maps["all"].occupied, maps["skip"].occupied)
    np.testing.assert_array_equal(maps["all"].observed, maps["skip"].observed)
    assert maps["skip_points"] < 0.9 * maps["all_points"]
