"""Paths and free space on the floor plan: the robot's waypoint poses, clearance from walls, legs that cross them.

Arrays in, arrays out (world x/y metres on the floor z = 0; walls are segments ``(M, 2, 2)``, as
``nsim.crowd.neighbours.segments_from_polygons`` makes them). Poses are body-to-world ``(S, 4, 4)``
with the body's x forward, y left, z up.
"""

from __future__ import annotations

import math

import numpy as np

from nsim.crowd.neighbours import closest_points_on_segments, segments_intersect

ROBOT_TURN_RATE_DPS = 90.0
"""Heading turn rate of a waypoint robot at a corner (the turn is centred on the corner)."""


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def yaw_poses_se3(xy_m: np.ndarray, yaw_rad: np.ndarray, z_m: float) -> np.ndarray:
    """Body-to-world poses ``(S, 4, 4)``: rotation about +z by ``yaw_rad (S,)``, at ``(x, y, z_m)``."""
    n = len(xy_m)
    poses = np.tile(np.eye(4), (n, 1, 1))
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s, s, c
    poses[:, :2, 3] = xy_m
    poses[:, 2, 3] = z_m
    return poses


def yaw_of_poses(poses_se3: np.ndarray) -> np.ndarray:
    """Heading ``(T,)``: the body x axis projected on the floor, angle from world +x about +z."""
    return np.arctan2(poses_se3[:, 1, 0], poses_se3[:, 0, 0])


def waypoint_poses(
    waypoints_m: np.ndarray, speed_mps: float, loop: bool, duration_s: float, body_height_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Timed poses ``(S,)``, ``(S, 4, 4)`` of a robot driving ``waypoints_m (K, 2)`` at ``speed_mps``.

    The robot faces along each leg; at a corner its heading turns from one leg's direction to the
    next over a window centred on the corner (at most ``ROBOT_TURN_RATE_DPS``, at most half of each
    adjacent leg), while its position stays on the polyline. A loop closes back to the first
    waypoint and repeats until ``duration_s``; otherwise the robot stops at the last waypoint.
    """
    pts = np.asarray(waypoints_m, dtype=np.float64)
    keep = np.r_[True, np.any(np.diff(pts, axis=0) != 0.0, axis=1)]  # drop repeated waypoints
    pts = pts[keep]
    if loop and len(pts) > 1 and np.array_equal(pts[0], pts[-1]):
        pts = pts[:-1]
    if len(pts) == 1 or (loop and len(pts) < 2):
        return np.zeros(1), yaw_poses_se3(pts[:1], np.zeros(1), body_height_m)
    if loop:
        lap = np.vstack([pts, pts[:1]])
        lap_len = float(np.linalg.norm(np.diff(lap, axis=0), axis=1).sum())
        laps = int(math.ceil(duration_s * speed_mps / lap_len)) + 1
        path = np.vstack([pts] * laps + [pts[:1]])
    else:
        path = pts
    seg = np.diff(path, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    seg_yaw = np.arctan2(seg[:, 1], seg[:, 0])
    t_corner = np.r_[0.0, np.cumsum(seg_len / speed_mps)]
    n_seg = len(seg)
    half = np.zeros(n_seg + 1)  # turn half-window at each waypoint
    turn = _wrap(seg_yaw[1:] - seg_yaw[:-1])  # at interior waypoints 1..n_seg-1
    durations = seg_len / speed_mps
    half[1:-1] = np.minimum(
        np.abs(turn) / (2.0 * np.deg2rad(ROBOT_TURN_RATE_DPS)),
        0.5 * np.minimum(durations[:-1], durations[1:]),
    )
    yaw_unwrapped = seg_yaw[0] + np.r_[0.0, np.cumsum(turn)]
    times, xy, yaw = [], [], []
    for k in range(n_seg + 1):
        times.append(t_corner[k])  # the corner: half-way through the turn
        xy.append(path[k])
        yaw.append(
            yaw_unwrapped[0] if k == 0 else yaw_unwrapped[k - 1] + 0.5 * (turn[k - 1] if k < n_seg else 0.0)
        )
        if k < n_seg:  # leg k -> k+1: constant heading between the two turn windows
            for t in (t_corner[k] + half[k], t_corner[k + 1] - half[k + 1]):
                times.append(t)
                xy.append(path[k] + seg[k] * ((t - t_corner[k]) / durations[k]))
                yaw.append(yaw_unwrapped[k])
    times_a = np.array(times)
    keep = np.r_[True, np.diff(times_a) > 1e-9]  # coinciding samples (no turn) are identical
    times_a, xy_a, yaw_a = times_a[keep], np.array(xy)[keep], _wrap(np.array(yaw)[keep])
    return times_a, yaw_poses_se3(xy_a, yaw_a, body_height_m)


def clearance_m(points_m: np.ndarray, walls_m: np.ndarray) -> np.ndarray:
    """Distance from each point ``(P, 2)`` to the nearest wall segment ``(M, 2, 2)``: ``(P,)`` (inf if none)."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if len(walls_m) == 0 or len(p) == 0:
        return np.full(len(p), np.inf)
    out = np.empty(len(p))
    chunk = max(1, 200_000 // len(walls_m))
    for s in range(0, len(p), chunk):
        q = p[s : s + chunk]
        rep = np.repeat(q, len(walls_m), axis=0)
        c = closest_points_on_segments(rep, np.tile(walls_m, (len(q), 1, 1)))
        out[s : s + chunk] = np.linalg.norm(rep - c, axis=1).reshape(len(q), -1).min(axis=1)
    return out


def enclosed(points_m: np.ndarray, walls_m: np.ndarray) -> np.ndarray:
    """Whether rays from each point along +x, -x, +y and -y all hit a wall: ``(P,)`` bool.

    A point outside the map (beyond its outer walls) has a ray that escapes.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if len(walls_m) == 0:
        return np.zeros(len(p), bool)
    lo, hi = walls_m.reshape(-1, 2).min(axis=0), walls_m.reshape(-1, 2).max(axis=0)
    reach = float(np.linalg.norm(hi - lo)) + 1.0 + float(np.abs(p).max(initial=0.0))
    ok = np.ones(len(p), bool)
    for d in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
        ok &= segments_intersect(p, p + reach * np.asarray(d), walls_m).any(axis=1)
    return ok


def leg_crossings(start_m: np.ndarray, waypoints_m: np.ndarray, loop: bool, walls_m: np.ndarray) -> list[int]:
    """Legs (0 = start -> waypoint 0, k = waypoint k-1 -> k, and the closing leg of a loop) that cross a wall."""
    pts = np.vstack([start_m[None], waypoints_m])
    if loop and len(waypoints_m) > 1:
        pts = np.vstack([pts, waypoints_m[:1]])
    if len(walls_m) == 0 or len(pts) < 2:
        return []
    hit = segments_intersect(pts[:-1], pts[1:], walls_m).any(axis=1)
    return [int(k) for k in np.flatnonzero(hit)]


def ring_problem(ring_m: np.ndarray) -> str | None:
    """What makes ``ring_m (K, 2)`` no closed polygon, or None.

    A closed ring repeats its first point at the end (as GeoJSON writes rings), has at least three
    distinct corners and encloses an area.
    """
    ring = np.asarray(ring_m, dtype=np.float64)
    if not np.array_equal(ring[0], ring[-1]):
        a, b = ring[0], ring[-1]
        return (
            f"not closed: a ring ends with its first point ({a[0]:g}, {a[1]:g}) again, "
            f"got ({b[0]:g}, {b[1]:g}) as its last of {len(ring)} points"
        )
    corners = np.unique(ring[:-1], axis=0)
    x, y = ring[:-1, 0], ring[:-1, 1]
    area = 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
    if len(corners) < 3 or area <= 0.0:
        return f"encloses no area ({len(corners)} distinct corners, area {area:g} m^2)"
    return None
