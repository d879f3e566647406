"""Plain, loop-based twins of the vectorised crowd code, for agreement tests."""

from __future__ import annotations

import math

import numpy as np

from nsim.crowd.social_force import ForceParams


def closest_point(p, a, b):
    ab = b - a
    len2 = float(ab @ ab)
    t = 0.0 if len2 == 0.0 else min(max(float((p - a) @ ab) / len2, 0.0), 1.0)
    return a + t * ab


def all_pairs(position_m, cutoff_m):
    n = len(position_m)
    return sorted(
        (i, j)
        for i in range(n)
        for j in range(i + 1, n)
        if np.linalg.norm(position_m[i] - position_m[j]) < cutoff_m
    )


def potential(d, y, r_sum, params: ForceParams):
    """Helbing-Molnar / Johansson elliptical potential ``A B exp((r - b) / B)`` at offset d."""
    dn, dyn, yn = np.linalg.norm(d), np.linalg.norm(d - y), np.linalg.norm(y)
    b = 0.5 * math.sqrt(max((dn + dyn) ** 2 - yn**2, 0.0))
    return params.agent_strength_mps2 * params.agent_range_m * math.exp((r_sum - b) / params.agent_range_m)


def pair_force_numeric(d, y, r_sum, heading_unit, params: ForceParams, h=1e-6):
    """-grad_d of ``potential`` by central differences, times the anisotropy weight."""
    grad = np.zeros(2)
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        grad[k] = (potential(d + e, y, r_sum, params) - potential(d - e, y, r_sum, params)) / (2 * h)
    n = d / np.linalg.norm(d)
    w = params.anisotropy + (1 - params.anisotropy) * 0.5 * (1 + float(heading_unit @ -n))
    return -grad * w


def agent_repulsion_loop(position_m, velocity_mps, heading_rad, radius_m, params: ForceParams):
    n = len(position_m)
    out = np.zeros((n, 2))
    for i in range(n):
        hu = np.array([math.cos(heading_rad[i]), math.sin(heading_rad[i])])
        for j in range(n):
            if i == j or np.linalg.norm(position_m[i] - position_m[j]) >= params.agent_cutoff_m:
                continue
            d = position_m[i] - position_m[j]
            y = (velocity_mps[j] - velocity_mps[i]) * params.agent_lookahead_s
            out[i] += pair_force_numeric(d, y, radius_m[i] + radius_m[j], hu, params)
    return out


def obstacle_repulsion_loop(position_m, radius_m, segments_m, params: ForceParams):
    out = np.zeros((len(position_m), 2))
    for i, p in enumerate(position_m):
        seen = []
        for a, b in segments_m:
            q = closest_point(p, a, b)
            d = float(np.linalg.norm(p - q))
            if d >= params.obstacle_cutoff_m or any(np.allclose(q, s, atol=1e-9) for s in seen):
                continue
            seen.append(q)
            out[i] += (
                params.obstacle_strength_mps2
                * math.exp((radius_m[i] - d) / params.obstacle_range_m)
                * (p - q)
                / d
            )
    return out


def distance_to_segments(points_m, segments_m):
    """Brute-force distance from each point to the nearest segment: ``(N,)``."""
    return np.array(
        [min(np.linalg.norm(p - closest_point(p, a, b)) for a, b in segments_m) for p in points_m]
    )
