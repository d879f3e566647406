"""Crowd simulation speed: steps/s of nsim's social-force core beside PySocialForce, 10 to 5,000 agents.

    python bench/simulate.py [--quick] [--sizes 10 100 1000 5000] [--psf-max-agents N]

The same scenario for both: N people on a square plaza at 0.3 people/m² (side sqrt(N / 0.3) m,
at least 8 m) with perimeter walls and a square 0.6 m pillar every 6 m, each walking from a
jittered-lattice start to a random free goal, 0.05 s steps, no robot, no groups. nsim runs
``nsim.crowd.step`` (anisotropic elliptical repulsion, walls through a segment grid, KD-tree
neighbours within 3 m, fluctuation); PySocialForce 1.1.2 runs its default forces (desired,
social, obstacle: all pairs, and every obstacle sample point for every agent) with
``step_width = 0.05`` and ``agent_radius = 0.25`` at its config's top level, where 1.1.2 reads them
(under ``[scene]`` they are ignored), read back from the simulator before timing and printed
(``pysocialforce_effective``); a mismatch stops the bench. Each size is warmed up, then stepped for at
least ``--min-time-s`` (one step at least). ``--quick``: 10 and 100 agents.

PySocialForce is not a dependency of nsim: install it (it needs numba) outside the project's
environment, e.g. ``pip install --target /tmp/psf pysocialforce numba`` and run with
``PYTHONPATH=/tmp/psf``. Without it its column reads n/a. Prints a table, then one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.crowd import BehaviourParams, CrowdState, ForceParams, make_walls, step  # noqa: E402
from nsim.crowd.neighbours import points_in_polygons, segments_from_polygons  # noqa: E402

DENSITY_PER_M2 = 0.3
PILLAR_SPACING_M = 6.0
PILLAR_SIZE_M = 0.6
DT_S = 0.05
SPEED_MPS = 1.3
PSF_HOWTO = "pip install pysocialforce (needs numba; e.g. pip install --target /tmp/psf pysocialforce numba, then PYTHONPATH=/tmp/psf)"


def plaza(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Starts (n, 2), goals (n, 2), obstacle polygons and their boundary segments (M, 2, 2)."""
    rng = np.random.default_rng(seed)
    side = max(8.0, math.sqrt(n / DENSITY_PER_M2))
    t = 0.1
    polys = [
        np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        for x0, y0, x1, y1 in (
            (-t, -t, 0.0, side + t),
            (side, -t, side + t, side + t),
            (-t, -t, side + t, 0.0),
            (-t, side, side + t, side + t),
        )
    ]
    h = PILLAR_SIZE_M / 2
    for cx in np.arange(PILLAR_SPACING_M / 2, side - 1.0, PILLAR_SPACING_M):
        for cy in np.arange(PILLAR_SPACING_M / 2, side - 1.0, PILLAR_SPACING_M):
            polys.append(np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h]]))
    # a jittered lattice at the target density keeps starts apart; drop points in or near pillars
    k = int(math.ceil(math.sqrt(n * 1.3)))
    g = (np.arange(k) + 0.5) * (side / k)
    lattice = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    lattice += rng.uniform(-0.15, 0.15, lattice.shape) * (side / k)
    pillars = np.array([p.mean(axis=0) for p in polys[4:]]).reshape(-1, 2)
    free = np.ones(len(lattice), bool)
    if len(pillars):
        d = np.abs(lattice[:, None, :] - pillars[None]).max(axis=-1)
        free = d.min(axis=1) > h + 0.4
    free &= (lattice.min(axis=1) > 0.5) & (lattice.max(axis=1) < side - 0.5)
    starts = rng.permutation(lattice[free])[:n]
    if len(starts) < n:
        raise RuntimeError(f"plaza: room for {len(starts)} of {n} agents")
    goals = rng.uniform(0.5, side - 0.5, (4 * n, 2))
    goals = goals[~points_in_polygons(goals, polys)][:n]
    return {
        "starts": starts,
        "goals": goals,
        "polygons": polys,
        "walls": segments_from_polygons(polys),
        "side": side,
    }


def initial_velocity(s: dict[str, np.ndarray]) -> np.ndarray:
    d = s["goals"] - s["starts"]
    return SPEED_MPS * d / np.linalg.norm(d, axis=1, keepdims=True)


def time_steps(step_once, min_time_s: float, max_steps: int) -> tuple[float, int]:
    """Steps/s over at least ``min_time_s`` (and at least one step)."""
    step_once()  # warm-up
    n = 0
    t0 = time.perf_counter()
    while n < max_steps:
        step_once()
        n += 1
        if time.perf_counter() - t0 >= min_time_s:
            break
    return n / (time.perf_counter() - t0), n


def bench_nsim(s, min_time_s: float, max_steps: int) -> float:
    forces, behaviours = ForceParams(), BehaviourParams()
    state = [
        CrowdState.create(
            s["starts"], s["goals"], velocity_mps=initial_velocity(s), desired_speed_mps=SPEED_MPS
        )
    ]
    walls = make_walls(s["walls"], forces, state[0].radius_m)
    rng = np.random.default_rng(0)

    def once():
        state[0] = step(state[0], None, walls, forces, behaviours, DT_S, rng)

    return time_steps(once, min_time_s, max_steps)[0]


#: What PySocialForce must run with, read back from its simulator (``psf_effective``) before any timing.
PSF_WANTED = {"step_width": DT_S, "agent_radius": 0.25, "max_speed_multiplier": 1.3, "tau": 0.5, "enable_group": False}


def psf_config_file(tmp: Path) -> Path:
    """PySocialForce 1.1.2 hands its pedestrians the *whole* config (``PedState(state, groups, self.config)``),
    so ``step_width``, ``agent_radius``, ``tau`` and ``max_speed_multiplier`` are read at the top level; only
    ``enable_group`` is read under ``[scene]``. Under ``[scene]`` the others are ignored (0.4 s steps, 0.35 m)."""
    p = tmp / "psf.toml"
    w = PSF_WANTED
    p.write_text(
        f"step_width = {w['step_width']}\nagent_radius = {w['agent_radius']}\nmax_speed_multiplier = "
        f"{w['max_speed_multiplier']}\ntau = {w['tau']}\nresolution = 10\n\n[scene]\nenable_group = false\n"
    )
    return p


def psf_effective(sim) -> dict[str, float | bool]:
    """The settings a PySocialForce simulator actually runs with (read from its objects, not the file)."""
    return {"step_width": float(sim.peds.step_width), "agent_radius": float(sim.peds.agent_radius),
            "max_speed_multiplier": float(sim.peds.max_speed_multiplier), "tau": float(sim.peds.default_tau),
            "enable_group": bool(sim.scene_config("enable_group"))}


def bench_psf(psf, s, config: Path, min_time_s: float, max_steps: int) -> float:
    state = np.concatenate([s["starts"], initial_velocity(s), s["goals"]], axis=1)
    # (x0, x1, y0, y1) lines, sampled by PySocialForce at 10 points/m; it cannot take the walls'
    # 0.1 m end caps (fewer than 2 samples), which no agent comes near
    obstacles = [(a[0], b[0], a[1], b[1]) for a, b in s["walls"] if np.linalg.norm(b - a) >= 0.2]
    sim = psf.Simulator(state, groups=None, obstacles=obstacles, config_file=str(config))
    got = psf_effective(sim)
    if got != PSF_WANTED:
        raise SystemExit(f"PySocialForce is not configured as meant: runs with {got}, wanted {PSF_WANTED}")
    return time_steps(sim.step_once, min_time_s, max_steps)[0]


def growth_exponent(sizes: list[int], steps_per_s: list[float | None]) -> float | None:
    """Slope of log(cost per step) against log(agents) from 100 agents up (1 = linear)."""
    pts = [(n, v) for n, v in zip(sizes, steps_per_s, strict=True) if v and n >= 100]
    if len(pts) < 2:
        return None
    x = np.log([n for n, _ in pts])
    y = np.log([1.0 / v for _, v in pts])
    return float(np.polyfit(x, y, 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="10 and 100 agents only (under a minute)")
    ap.add_argument("--sizes", type=int, nargs="+", default=None)
    ap.add_argument("--psf-max-agents", type=int, default=5000, help="skip PySocialForce above this size")
    ap.add_argument("--min-time-s", type=float, default=None)
    args = ap.parse_args()
    sizes = args.sizes or ([10, 100] if args.quick else [10, 100, 1000, 5000])
    min_time = args.min_time_s if args.min_time_s is not None else (0.5 if args.quick else 2.0)
    try:
        import pysocialforce as psf
        from pysocialforce.utils import logger as psf_logger

        psf_logger.setLevel("ERROR")
        psf_version = getattr(psf, "__version__", "?")
    except Exception:  # noqa: BLE001 - any import failure means "not available"
        psf, psf_version = None, None
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        config = psf_config_file(Path(tmp))
        psf_settings = None
        if psf is not None:  # compile PySocialForce's numba kernels before timing anything
            bench_psf(psf, plaza(10), config, 0.0, 1)
            psf_settings = dict(PSF_WANTED)  # bench_psf stops unless the simulator runs with exactly these
        for n in sizes:
            s = plaza(n)
            ours = bench_nsim(s, min_time, 10_000)
            theirs = None
            if psf is not None and n <= args.psf_max_agents:
                theirs = bench_psf(psf, s, config, min_time, 10_000)
            rows.append(
                {
                    "agents": n,
                    "nsim_steps_per_s": ours,
                    "pysocialforce_steps_per_s": theirs,
                    "walls": len(s["walls"]),
                    "side_m": round(s["side"], 1),
                }
            )
            print(f"  {n} agents done", file=sys.stderr, flush=True)
    sizes_done = [r["agents"] for r in rows]
    exp_ours = growth_exponent(sizes_done, [r["nsim_steps_per_s"] for r in rows])
    exp_psf = growth_exponent(sizes_done, [r["pysocialforce_steps_per_s"] for r in rows])
    print(
        f"crowd step speed, {DENSITY_PER_M2} people/m2 plaza with pillars, dt {DT_S} s, {os.cpu_count()} CPUs"
    )
    print(
        f"{'agents':>7} {'walls':>6} {'nsim steps/s':>13} {'PySocialForce steps/s':>22} {'nsim / PSF':>11} {'nsim ms/step':>13} {'PSF ms/step':>12}"
    )
    for r in rows:
        a, b = r["nsim_steps_per_s"], r["pysocialforce_steps_per_s"]
        print(
            f"{r['agents']:>7} {r['walls']:>6} {a:>13.1f} {('n/a' if b is None else f'{b:.2f}'):>22} "
            f"{('n/a' if b is None else f'{a / b:.1f}x'):>11} {1000 / a:>13.2f} {('n/a' if b is None else f'{1000 / b:.1f}'):>12}"
        )
    at_1000 = next((r for r in rows if r["agents"] == 1000), None)
    ratio_1000 = (
        at_1000["nsim_steps_per_s"] / at_1000["pysocialforce_steps_per_s"]
        if at_1000 and at_1000["pysocialforce_steps_per_s"]
        else None
    )
    if psf is None:
        print(f"PySocialForce: n/a (not importable): {PSF_HOWTO}")
    if ratio_1000 is not None:
        print(f"at 1,000 agents nsim takes {ratio_1000:.1f}x fewer seconds per step than PySocialForce")

    def fmt_exp(e):
        return "n/a" if e is None else f"N^{e:.2f}"

    print(
        f"per-step cost grows as {fmt_exp(exp_ours)} (nsim), {fmt_exp(exp_psf)} (PySocialForce), fitted from 100 agents up"
    )
    print(
        json.dumps(
            {
                "bench": "simulate",
                "rows": rows,
                "ratio_at_1000": ratio_1000,
                "cost_exponent": {"nsim": exp_ours, "pysocialforce": exp_psf},
                "pysocialforce": psf_version or f"n/a: {PSF_HOWTO}",
                "pysocialforce_effective": psf_settings,
                "dt_s": DT_S,
                "density_per_m2": DENSITY_PER_M2,
            }
        )
    )


if __name__ == "__main__":
    main()
