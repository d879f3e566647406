"""Crowd simulation speed: ms per step of nsim's social-force core beside PySocialForce, and robot controllers.

    python bench/simulate.py [--quick] [--sizes 100 300 1000 3000] [--psf-max-agents N] [--min-time-s S]

Two layouts, each size in both, in one run, nsim and PySocialForce alternating (``--rounds`` turns
each, the steps/s over all of them):

* ``fixed``: a 20 x 20 m room (perimeter walls, a square 0.6 m pillar every 6 m): density grows
  with N, so does each person's number of neighbours (the cost per step grows faster than N).
  A size whose starts cannot be laid out without touching (a lattice spacing under 0.52 m: about
  1,800 people here) is reported as not fitting.
* ``density``: a square plaza at 0.3 people/m² (side sqrt(N / 0.3) m, at least 8 m), same walls
  and pillars: the cost per step grows about linearly.

People walk from a jittered-lattice start to a random free goal, 0.05 s steps, no robot, no groups.
nsim runs ``nsim.crowd.step`` (anisotropic elliptical repulsion, walls through a segment grid,
KD-tree neighbours, fluctuation, the no-overlap projection); PySocialForce 1.1.2 runs its default
forces (desired, social, obstacle: all pairs, and every obstacle sample point for every agent)
with ``step_width = 0.05`` and ``agent_radius = 0.25`` at its config's top level, where 1.1.2 reads
them (under ``[scene]`` they are ignored), read back from the simulator before timing and printed
(``pysocialforce_effective``); a mismatch stops the bench. Each run is warmed up by one step.

``min_center_gap_m``: over every nsim step timed, the closest centre distance minus the sum of the
two radii (negative: bodies overlap; the no-overlap projection keeps it >= -1 mm). Its check is
timed apart and left out of nsim's ms/step.

``controllers``: the robot crossing the fixed room among 300 people (``--controller-people``) for
``--controller-duration-s``, once per controller (``replay``, ``social_force``, ``orca`` and the
user class ``tests.crowd.user_controllers:GoalSeeker``), through ``nsim.crowd.driver.simulate``:
the controller's ms per step (its ``command`` calls alone) and HuNavSim's summary metrics
(``nsim.crowd.run_output.SUMMARY_METRICS``).

``--quick``: 100 and 300 people, shorter timings and controller runs (under two minutes).

PySocialForce is not a dependency of nsim: install it (it needs numba) outside the project's
environment, e.g. ``pip install --target /tmp/psf pysocialforce numba`` and run with
``PYTHONPATH=/tmp/psf``. Without it its columns read n/a and the nsim side still runs. Prints tables,
then one JSON object on the last line (``ratio_1000``, ``nsim_ms_1000``, ``psf_ms_1000``: the fixed
room at 1,000 people; ``min_center_gap_m``; ``controllers``; every row).
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


FIXED_SIDE_M = 20.0
MIN_START_SPACING_M = 0.52
"""Starts at least this far apart (two 0.25 m radii and 2 cm): a size needing a tighter lattice does not fit."""


class DoesNotFit(Exception):
    pass


def plaza(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The constant-density layout: ``room`` with side ``sqrt(n / DENSITY_PER_M2)`` (at least 8 m)."""
    return room(n, max(8.0, math.sqrt(n / DENSITY_PER_M2)), seed)


def fixed_room(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The fixed layout: ``room`` with side ``FIXED_SIDE_M`` whatever n."""
    return room(n, FIXED_SIDE_M, seed)


def room(n: int, side: float, seed: int = 0) -> dict[str, np.ndarray]:
    """Starts (n, 2), goals (n, 2), obstacle polygons and their boundary segments (M, 2, 2) in a
    ``side`` x ``side`` m room with perimeter walls and a pillar every ``PILLAR_SPACING_M``.
    Raises ``DoesNotFit`` when the starts would be closer than ``MIN_START_SPACING_M``."""
    rng = np.random.default_rng(seed)
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
    spacing = side / k
    if spacing < MIN_START_SPACING_M:
        raise DoesNotFit(f"{n} people do not fit a {side:g} m room (start spacing {spacing:.2f} m)")
    jitter = min(0.15 * spacing, (spacing - MIN_START_SPACING_M) / 2.0)
    g = (np.arange(k) + 0.5) * spacing
    lattice = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    lattice += rng.uniform(-1.0, 1.0, lattice.shape) * jitter
    pillars = np.array([p.mean(axis=0) for p in polys[4:]]).reshape(-1, 2)
    free = np.ones(len(lattice), bool)
    if len(pillars):
        d = np.abs(lattice[:, None, :] - pillars[None]).max(axis=-1)
        free = d.min(axis=1) > h + 0.4
    free &= (lattice.min(axis=1) > 0.5) & (lattice.max(axis=1) < side - 0.5)
    starts = rng.permutation(lattice[free])[:n]
    if len(starts) < n:
        raise DoesNotFit(f"{n} people do not fit a {side:g} m room (room for {len(starts)})")
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


class Turns:
    """A simulator stepped in turns (``turn``), alternating with others: steps and seconds over all
    turns. ``check(state) -> float`` runs after every step, timed apart (not in ``steps_per_s``)."""

    def __init__(self, step_once, check=None):
        self.step_once, self.check = step_once, check
        self.steps, self.seconds, self.check_seconds = 0, 0.0, 0.0
        self.worst = math.inf

    def warm_up(self) -> None:
        self.step_once()

    def turn(self, min_time_s: float, max_steps: int) -> None:
        t0 = time.perf_counter()
        spent_checking = 0.0
        n = 0
        while n < max_steps:
            self.step_once()
            n += 1
            if self.check is not None:
                c0 = time.perf_counter()
                self.worst = min(self.worst, self.check())
                spent_checking += time.perf_counter() - c0
            if time.perf_counter() - t0 >= min_time_s:
                break
        self.steps += n
        self.seconds += time.perf_counter() - t0 - spent_checking
        self.check_seconds += spent_checking

    @property
    def steps_per_s(self) -> float:
        return self.steps / self.seconds


def alternate(runs: list[Turns], min_time_s: float, rounds: int, max_steps: int) -> None:
    """Warm each run up, then ``rounds`` turns of ``min_time_s / rounds`` each, in turn (so drifts
    of the machine's speed fall on all alike)."""
    for r in runs:
        r.warm_up()
    for _ in range(rounds):
        for r in runs:
            r.turn(min_time_s / rounds, max_steps)


def min_center_gap_m(position_m: np.ndarray, radius_m: np.ndarray) -> float:
    """The closest centre distance minus the sum of the two radii over every pair (inf for < 2 people)."""
    from nsim.crowd.neighbours import neighbour_pairs
    from nsim.crowd.social_force import pair_overlaps

    pairs = neighbour_pairs(position_m, 2.0 * float(radius_m.max()) + 0.5)
    if len(pairs) == 0:
        return math.inf
    depth, _ = pair_overlaps(position_m, radius_m, pairs)
    return float(-depth.max())


def nsim_run(s) -> Turns:
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

    return Turns(once, lambda: min_center_gap_m(state[0].position_m, state[0].radius_m))


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


def psf_run(psf, s, config: Path) -> Turns:
    state = np.concatenate([s["starts"], initial_velocity(s), s["goals"]], axis=1)
    # (x0, x1, y0, y1) lines, sampled by PySocialForce at 10 points/m; it cannot take the walls'
    # 0.1 m end caps (fewer than 2 samples), which no agent comes near
    obstacles = [(a[0], b[0], a[1], b[1]) for a, b in s["walls"] if np.linalg.norm(b - a) >= 0.2]
    sim = psf.Simulator(state, groups=None, obstacles=obstacles, config_file=str(config))
    got = psf_effective(sim)
    if got != PSF_WANTED:
        raise SystemExit(f"PySocialForce is not configured as meant: runs with {got}, wanted {PSF_WANTED}")
    return Turns(sim.step_once)


# ----------------------------------------------------------------------------------------------
# Robot controllers among people

CONTROLLERS = ("replay", "social_force", "orca", {"python": "tests.crowd.user_controllers:GoalSeeker"})
ROBOT_PATH_M = ((1.5, 12.0), (18.5, 12.0))
"""The robot crosses the fixed room between two rows of pillars."""


def controller_scenario(n: int, controller, duration_s: float, seed: int = 0):
    """The fixed room as a scenario of its own (``nsim.crowd.scenario``): n people walking between
    their start and a goal, the robot crossing it to a goal at 1 m/s, driven by ``controller``."""
    from nsim.crowd.scenario import parse_scenario, polygon_map, resolve_scenario

    s = fixed_room(n + 40, seed)
    robot0 = np.array(ROBOT_PATH_M[0])
    keep = np.linalg.norm(s["starts"] - robot0, axis=1) > 1.5
    starts, goals = s["starts"][keep][:n], s["goals"][keep][:n]

    def ring(p):
        return [[float(x), float(y)] for x, y in np.asarray(p)] + [[float(p[0][0]), float(p[0][1])]]

    side = FIXED_SIDE_M
    data = {
        "name": "bench_fixed_room",
        "duration_s": duration_s,
        "dt_s": DT_S,
        "seed": seed,
        "scene": {
            "polygons": [ring([[-0.1, -0.1], [side + 0.1, -0.1], [side + 0.1, side + 0.1], [-0.1, side + 0.1]])]
            + [ring(p) for p in s["polygons"][4:]],
            "holes": [[ring([[0.0, 0.0], [side, 0.0], [side, side], [0.0, side]])]] + [[] for _ in s["polygons"][4:]],
        },
        "robot": {"trajectory": {"waypoints_m": [list(p) for p in ROBOT_PATH_M], "speed_mps": 1.0}},
        "humans": [
            {"start_m": a.round(3).tolist(), "waypoints_m": [g.round(3).tolist(), a.round(3).tolist()], "loop": True}
            for a, g in zip(starts, goals, strict=True)
        ],
    }
    if controller != "replay":
        data["robot"]["controller"] = controller
    spec = parse_scenario(data, source="bench fixed room")
    return resolve_scenario(spec, polygon_map(spec.scene, spec.error))


class TimedController:
    """Wraps a controller: the seconds its ``command`` calls take."""

    def __init__(self, inner):
        self.inner, self.seconds, self.calls = inner, 0.0, 0

    def command(self, obs):
        t0 = time.perf_counter()
        out = self.inner.command(obs)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        return out


def bench_controllers(n: int, duration_s: float) -> dict[str, dict]:
    """Per controller: its ms per step (None for replay: nothing runs), the whole step's ms and
    HuNavSim's summary metrics, on the same people and seed."""
    import logging

    from nsim.crowd import driver
    from nsim.crowd.controllers import controller_label
    from nsim.crowd.run_output import SUMMARY_METRICS, run_metrics

    logging.getLogger("nsim").setLevel(logging.ERROR)  # the legs-cross-a-pillar warning
    forces, behaviours = ForceParams(), BehaviourParams()
    out = {}
    for c in CONTROLLERS:
        sc = controller_scenario(n, c, duration_s)
        timed = None
        t0 = time.perf_counter()
        if c == "replay":
            sim = driver.simulate(sc, forces, behaviours, DT_S, duration_s, 0)
        else:
            timed = TimedController(driver.make_controller(sc, forces))
            n_steps = max(1, int(round(duration_s / DT_S)))
            sim = driver.closed_loop(sc, timed, forces, behaviours, DT_S, n_steps, 0)
        total = time.perf_counter() - t0
        steps = len(sim.time_s) - 1
        hunav = run_metrics(sc, sim, forces)["hunav"]
        out[controller_label(c)] = {
            "controller_ms_per_step": None if timed is None else 1000.0 * timed.seconds / timed.calls,
            "step_ms": 1000.0 * total / steps,
            "people": len(sc.humans),
            "min_center_gap_m": min(
                min_center_gap_m(p, sim.crowd.radius_m) for p in sim.crowd.position_m
            ),
            **{k: hunav[k] for k in SUMMARY_METRICS},
        }
        print(f"  controller {controller_label(c)} done", file=sys.stderr, flush=True)
    return out


def growth_exponent(sizes: list[int], steps_per_s: list[float | None]) -> float | None:
    """Slope of log(cost per step) against log(agents) from 100 agents up (1 = linear)."""
    pts = [(n, v) for n, v in zip(sizes, steps_per_s, strict=True) if v and n >= 100]
    if len(pts) < 2:
        return None
    x = np.log([n for n, _ in pts])
    y = np.log([1.0 / v for _, v in pts])
    return float(np.polyfit(x, y, 1)[0])


def _fmt(v, spec=".2f") -> str:
    return "n/a" if v is None else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="100 and 300 people, short timings (under two minutes)")
    ap.add_argument("--sizes", type=int, nargs="+", default=None)
    ap.add_argument("--psf-max-agents", type=int, default=3000, help="skip PySocialForce above this size")
    ap.add_argument("--min-time-s", type=float, default=None, help="seconds of stepping per simulator and size")
    ap.add_argument("--rounds", type=int, default=None, help="turns each simulator takes, alternating")
    ap.add_argument("--controller-people", type=int, default=300)
    ap.add_argument("--controller-duration-s", type=float, default=None)
    args = ap.parse_args()
    sizes = args.sizes or ([100, 300] if args.quick else [100, 300, 1000, 3000])
    min_time = args.min_time_s if args.min_time_s is not None else (0.6 if args.quick else 4.0)
    rounds = args.rounds or (2 if args.quick else 4)
    ctrl_duration = args.controller_duration_s or (3.0 if args.quick else 20.0)
    try:
        import pysocialforce as psf
        from pysocialforce.utils import logger as psf_logger

        psf_logger.setLevel("ERROR")
        psf_version = getattr(psf, "__version__", "?")
        import logging

        logging.getLogger().setLevel(logging.WARNING)  # importing pysocialforce sets the root logger to DEBUG
    except Exception:  # noqa: BLE001 - any import failure means "not available"
        psf, psf_version = None, None
    if psf is None:
        print(f"PySocialForce: n/a (not importable), running the nsim side only: {PSF_HOWTO}", file=sys.stderr)
    rows = []
    worst_gap = math.inf
    with tempfile.TemporaryDirectory() as tmp:
        config = psf_config_file(Path(tmp))
        psf_settings = None
        if psf is not None:  # compile PySocialForce's numba kernels before timing anything
            psf_run(psf, plaza(10), config).warm_up()
            psf_settings = dict(PSF_WANTED)  # psf_run stops unless the simulator runs with exactly these
        for layout, make in (("fixed", fixed_room), ("density", plaza)):
            for n in sizes:
                try:
                    s = make(n)
                except DoesNotFit as exc:
                    rows.append({"layout": layout, "agents": n, "fits": False, "why": str(exc)})
                    continue
                runs = [nsim_run(s)]
                if psf is not None and n <= args.psf_max_agents:
                    runs.append(psf_run(psf, s, config))
                alternate(runs, min_time, rounds, 100_000)
                ours = runs[0]
                worst_gap = min(worst_gap, ours.worst)
                theirs = runs[1] if len(runs) > 1 else None
                rows.append(
                    {
                        "layout": layout,
                        "agents": n,
                        "fits": True,
                        "side_m": round(s["side"], 1),
                        "walls": len(s["walls"]),
                        "nsim_ms_per_step": 1000.0 / ours.steps_per_s,
                        "psf_ms_per_step": None if theirs is None else 1000.0 / theirs.steps_per_s,
                        "nsim_steps": ours.steps,
                        "psf_steps": None if theirs is None else theirs.steps,
                        "min_center_gap_m": ours.worst,
                    }
                )
                print(f"  {layout} {n} people done", file=sys.stderr, flush=True)
    controllers = bench_controllers(args.controller_people, ctrl_duration)
    for c in controllers.values():
        worst_gap = min(worst_gap, c["min_center_gap_m"])

    print(f"crowd step cost, dt {DT_S} s, {os.cpu_count()} CPUs, nsim and PySocialForce alternating ({rounds} turns each)")
    print(f"{'layout':>8} {'people':>7} {'side m':>7} {'nsim ms/step':>13} {'PSF ms/step':>12} {'PSF / nsim':>11} {'min gap mm':>11}")
    for r in rows:
        if not r["fits"]:
            print(f"{r['layout']:>8} {r['agents']:>7}  n/a: {r['why']}")
            continue
        a, b = r["nsim_ms_per_step"], r["psf_ms_per_step"]
        print(
            f"{r['layout']:>8} {r['agents']:>7} {r['side_m']:>7} {a:>13.2f} {_fmt(b):>12} "
            f"{('n/a' if b is None else f'{b / a:.1f}x'):>11} {1000 * r['min_center_gap_m']:>11.2f}"
        )
    exps = {}
    for layout in ("fixed", "density"):
        fit = [r for r in rows if r["layout"] == layout and r["fits"]]
        sz = [r["agents"] for r in fit]
        exps[layout] = {
            "nsim": growth_exponent(sz, [1000.0 / r["nsim_ms_per_step"] for r in fit]),
            "pysocialforce": growth_exponent(sz, [r["psf_ms_per_step"] and 1000.0 / r["psf_ms_per_step"] for r in fit]),
        }
        e = exps[layout]
        print(f"{layout}: per-step cost grows as N^{_fmt(e['nsim'])} (nsim), N^{_fmt(e['pysocialforce'])} (PySocialForce), from 100 people up")
    print(f"\nrobot controllers, {args.controller_people} people in the fixed room, {ctrl_duration:g} s")
    print(f"{'controller':>12} {'ctrl ms/step':>13} {'step ms':>8} {'completed':>10} {'min dist m':>11} {'intimate %':>11} {'personal %':>11}")
    for name, c in controllers.items():
        print(
            f"{name:>12} {_fmt(c['controller_ms_per_step']):>13} {c['step_ms']:>8.2f} {str(c['completed']):>10} "
            f"{_fmt(c['minimum_distance_to_people_m'], '.3f'):>11} {_fmt(c['intimate_space_intrusions_pct'], '.1f'):>11} "
            f"{_fmt(c['personal_space_intrusions_pct'], '.1f'):>11}"
        )
    if psf is None:
        print(f"PySocialForce: n/a (not importable; the nsim side ran alone): {PSF_HOWTO}")
    print(f"min_center_gap_m over every nsim step: {worst_gap * 1000:.3f} mm")
    at_1000 = next((r for r in rows if r["layout"] == "fixed" and r["agents"] == 1000 and r["fits"]), None)
    nsim_1000 = at_1000["nsim_ms_per_step"] if at_1000 else None
    psf_1000 = at_1000["psf_ms_per_step"] if at_1000 else None
    ratio_1000 = psf_1000 / nsim_1000 if nsim_1000 and psf_1000 else None
    if ratio_1000 is not None:
        print(f"at 1,000 people in the fixed room nsim takes {ratio_1000:.1f}x fewer seconds per step than PySocialForce")
    print(
        json.dumps(
            {
                "bench": "simulate",
                "rows": rows,
                "cost_exponent": exps,
                "pysocialforce": psf_version or f"n/a: {PSF_HOWTO}",
                "pysocialforce_effective": psf_settings,
                "dt_s": DT_S,
                "density_per_m2": DENSITY_PER_M2,
                "fixed_side_m": FIXED_SIDE_M,
                "ratio_1000": ratio_1000,
                "nsim_ms_1000": nsim_1000,
                "psf_ms_1000": psf_1000,
                "min_center_gap_m": worst_gap,
                "controllers": controllers,
            }
        )
    )


if __name__ == "__main__":
    main()
