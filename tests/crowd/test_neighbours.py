"""Neighbour searches: KD-tree pairs and the segment grid against brute force; polygon helpers."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.crowd.neighbours import (
    SegmentGrid,
    closest_points_on_segments,
    neighbour_pairs,
    points_in_polygons,
    segments_from_polygons,
    segments_intersect,
)
from tests.crowd.reference import all_pairs, closest_point


def test_neighbour_pairs_match_brute_force():
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 10, (300, 2))
    pairs = neighbour_pairs(pos, 1.5)
    assert pairs.dtype == np.int64 and pairs.shape[1] == 2
    assert [tuple(p) for p in pairs] == all_pairs(pos, 1.5)


def test_neighbour_pairs_degenerate_inputs():
    assert neighbour_pairs(np.zeros((0, 2)), 1.0).shape == (0, 2)
    assert neighbour_pairs(np.zeros((1, 2)), 1.0).shape == (0, 2)
    assert neighbour_pairs(np.array([[0.0, 0.0], [5.0, 0.0]]), 1.0).shape == (0, 2)


def test_segments_from_polygons_closes_rings_and_keeps_single_walls():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    wall = np.array([[2, 0], [2, 3]], dtype=float)
    segs = segments_from_polygons([square, wall])
    assert segs.shape == (5, 2, 2)
    np.testing.assert_array_equal(segs[3], [[0, 1], [0, 0]])  # the closing edge
    np.testing.assert_array_equal(segs[4], wall)
    with pytest.raises(ValueError, match=r"polygons\[0\]"):
        segments_from_polygons([np.zeros((1, 2))])


def test_points_in_polygons():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=float)
    l_shape = np.array([[3, 0], [6, 0], [6, 1], [4, 1], [4, 3], [3, 3]], dtype=float)
    pts = np.array([[1, 1], [2.5, 1], [5, 0.5], [5, 2], [3.5, 2.5], [-1, 1]], dtype=float)
    np.testing.assert_array_equal(
        points_in_polygons(pts, [square, l_shape]), [True, False, True, False, True, False]
    )


def test_closest_points_on_segments_matches_loop():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(50, 2))
    seg = rng.normal(size=(50, 2, 2))
    seg[0, 1] = seg[0, 0]  # zero-length segment
    q = closest_points_on_segments(p, seg)
    np.testing.assert_allclose(
        q, [closest_point(a, s[0], s[1]) for a, s in zip(p, seg, strict=True)], atol=1e-12
    )


def test_segments_intersect():
    wall = np.array([[[0, -1], [0, 1]]], dtype=float)
    p0 = np.array([[-1, 0], [-1, 0], [-1, 2]], dtype=float)
    p1 = np.array([[1, 0], [-0.5, 0], [1, 2]], dtype=float)
    np.testing.assert_array_equal(segments_intersect(p0, p1, wall)[:, 0], [True, False, False])


def test_segment_grid_candidates_cover_everything_within_reach():
    rng = np.random.default_rng(2)
    a = rng.uniform(0, 20, (80, 2))
    segs = np.stack([a, a + rng.normal(0, 2, (80, 2))], axis=1)
    grid = SegmentGrid.build(segs, reach_m=1.0)
    pts = rng.uniform(-3, 23, (400, 2))
    agent, seg = grid.candidates(pts)
    got = set(zip(agent.tolist(), seg.tolist(), strict=True))
    for i, p in enumerate(pts):
        for m, (s0, s1) in enumerate(segs):
            if np.linalg.norm(p - closest_point(p, s0, s1)) < 1.0:
                assert (i, m) in got
    # and it prunes: far fewer candidates than all pairs
    assert len(got) < 0.2 * len(pts) * len(segs)


def test_segment_grid_empty():
    grid = SegmentGrid.build(np.zeros((0, 2, 2)), reach_m=1.0)
    agent, seg = grid.candidates(np.zeros((3, 2)))
    assert len(agent) == len(seg) == 0
