"""``nsim simulate``: a scenario's crowd reacting to the robot, as a ``trajectory`` artifact.

Input: a scenario (``nsim.crowd.scenario``; a file, not an artifact: its canonical resolved
content is stored in the artifact and its digest enters the action key), plus the scene
checkpoint it names, if any (an input artifact, so lineage reaches it). The run's random stream
is seeded from both the scenario's ``seed`` and the run's ``--seed``.

Artifact layout (``T`` ticks at ``t_k = k dt_s``, ``N`` humans)::

    trajectory.npz    per-tick arrays (below); deterministic bytes (fixed zip timestamps)
    robot.tum         the robot's body-to-world pose at every tick (body: x forward, y left, z up;
                      z = the body frame's height above the floor)
    humans/<id>.tum   each human's root at every tick: (x, y, 0) on the floor, rotated about +z by
                      its heading (x forward). The root is on the floor, not at the pelvis: the
                      human model places the pelvis at its own height above it.
    metrics.json      HuNavSim metrics (``nsim.crowd.metrics.crowd_metrics``; null where undefined,
                      e.g. time to goal for a looping robot) and the run's size
    scenario.json     the canonical resolved scenario (``load_scenario`` reads it back unchanged)
    occupancy.json    the 2D obstacle map used (the capture's layout)
    topdown.png       the run from above: obstacles, the robot's path, each human's path
    run.mp4           (video: true) the run from above, H.264 (``nsim.io.video``), ``fps`` frames per
                      second, each frame labelled with the scenario and the time

``trajectory.npz`` holds ``nsim.crowd.CrowdTrajectory.as_arrays()`` (so
``CrowdTrajectory.from_arrays(np.load(path))`` restores it: ``time_s (T,)``, ``position_m (T, N, 2)``,
``velocity_mps (T, N, 2)``, ``heading_rad (T, N)``, ``behaviour_state (T, N)`` int8 (0 navigating,
1 reacting, 2 done), ``gait_phase (T, N)`` in [0, 1), ``goal_index (T, N)``, ``radius_m (N,)``,
``behaviour (N,)`` int8 codes, ``group_id (N,)``, the robot as the crowd saw it) plus
``robot_pose_se3 (T, 4, 4)``, ``human_ids (N,)``, ``height_m (N,)``, ``motion (N,)``,
``appearance (N,)`` (``""`` = default look) and ``behaviour_names (6,)`` (code k at index k - 1).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from nsim.config import from_dict, param, to_dict
from nsim.context import RunContext
from nsim.crowd.behaviours import BEHAVIOUR_NAMES, BehaviourParams
from nsim.crowd.run_output import SUMMARY_METRICS, run_metrics, write_trajectory
from nsim.crowd.social_force import ForceParams

STAGE = "simulate"
VERSION = 2  # 2: run.mp4 in H.264 (was MPEG-4 Part 2), frames under a label strip

@dataclasses.dataclass(frozen=True)
class Config:
    dt_s: float = param(0.05, gt=0, le=0.5, help="simulation step (a scenario's own dt_s wins)")
    max_duration_s: float | None = param(None, gt=0, help="cut the scenario's duration to this (tests)")
    forces: ForceParams = ForceParams()
    behaviours: BehaviourParams = BehaviourParams()
    video: bool = param(True, help="write run.mp4")
    fps: float = param(
        10.0, gt=0, le=60, help="video frame rate (frames are every round(1 / (fps dt)) ticks)"
    )
    px_per_m: float = param(60.0, ge=10, le=400, help="video and top-down scale")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """A validated scenario (``nsim.crowd.scenario.load_scenario``)."""

    scenario: Any

    def ids(self) -> dict[str, str]:
        return {"scene": self.scenario.scene_id} if self.scenario.scene_id is not None else {}


@dataclasses.dataclass(frozen=True)
class Outputs:
    trajectory: str
    cache_hit: bool = False


def effective_times(sc, cfg: Config) -> tuple[float, float]:
    """``(dt_s, duration_s)`` of a run: the scenario's dt_s or else the config's; the duration capped."""
    dt = sc.dt_s if sc.dt_s is not None else cfg.dt_s
    duration = sc.duration_s if cfg.max_duration_s is None else min(sc.duration_s, cfg.max_duration_s)
    return float(dt), float(duration)


def rollout_seed(ctx: RunContext, sc) -> int:
    """The crowd's seed from the run's ``--seed`` and the scenario's ``seed``."""
    return int(ctx.rng(f"simulate.crowd.{sc.seed}").integers(2**63))


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    return ctx.store.action_key(
        STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra={"scenario": inputs.scenario.digest}
    )


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    from nsim.crowd.metrics import crowd_metrics
    from nsim.crowd.scenario import simulate

    store = ctx.store
    sc = inputs.scenario
    key = action_key(inputs, cfg, ctx)
    if not ctx.force and (hit := store.lookup(key)) is not None:
        return Outputs(trajectory=hit.id, cache_hit=True)

    dt_s, duration_s = effective_times(sc, cfg)
    sim = simulate(sc, cfg.forces, cfg.behaviours, dt_s, duration_s, rollout_seed(ctx, sc))
    metrics = run_metrics(sc, sim, crowd_metrics(sim.crowd, walls_m=sim.walls_m, forces=cfg.forces))
    with store.publish(
        kind="trajectory",
        stage=STAGE,
        version=VERSION,
        key=key,
        config=cfg,
        inputs=inputs.ids(),
        seed=ctx.seed,
    ) as out:
        write_trajectory(out.dir, sc, sim, metrics, cfg)
        out.summary.update(
            {
                "scenario": sc.name,
                "scenario_digest": sc.digest,
                "humans": len(sc.humans),
                "ticks": len(sim.time_s),
                "dt_s": dt_s,
                "duration_s": float(sim.time_s[-1]),
                **{k: metrics["hunav"][k] for k in SUMMARY_METRICS},
            }
        )
    return Outputs(trajectory=out.ref)


# ----------------------------------------------------------------------------------------------
# Sweeps


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A sweep file (YAML): a grid of seeds x crowd sizes x behaviour sets over one base scenario.

    scenario: the base scenario file, relative to the sweep file. seeds: scenario seeds.
    crowd_sizes: how many extra people to spawn in free space (0 = the scenario as it is).
    behaviours: behaviour sets the extra people's behaviours are drawn from; each a name or a list
    of names. keep_scenario_humans: false drops the scenario's own people.
    """

    scenario: str = param(help="base scenario file, relative to the sweep file")
    seeds: tuple[int, ...] = param((0,))
    crowd_sizes: tuple[int, ...] = param((0,))
    behaviours: tuple[str | tuple[str, ...], ...] = param(("regular",))
    keep_scenario_humans: bool = True


def load_sweep(path: str | Path) -> tuple[SweepSpec, Path]:
    """The sweep file, strictly checked (errors name the file and the key)."""
    from nsim.config import read_yaml
    from nsim.errors import ConfigError, InputError

    path = Path(path)
    data = read_yaml(path, what="sweep")
    try:
        spec = from_dict(SweepSpec, data)
    except ConfigError as exc:
        raise InputError(f"{path}: {exc}") from None
    for name, values in (("seeds", spec.seeds), ("crowd_sizes", spec.crowd_sizes)):
        if not values:
            raise InputError(f"{path}: {name}: expected at least one value")
        for k, v in enumerate(values):
            if v < 0:
                raise InputError(f"{path}: {name}[{k}]: expected int >= 0, got {v}")
    if not spec.behaviours:
        raise InputError(f"{path}: behaviours: expected at least one behaviour set")
    for k, b in enumerate(spec.behaviours):
        names = (b,) if isinstance(b, str) else b
        for name in names or ("[]",):
            if name not in BEHAVIOUR_NAMES:
                raise InputError(
                    f"{path}: behaviours[{k}]: {name!r} is not one of {', '.join(BEHAVIOUR_NAMES)}"
                )
    return spec, (path.parent / spec.scenario)


def sweep_items(spec: SweepSpec, scenario_path: Path, cfg: Config, ctx: RunContext) -> list[dict[str, Any]]:
    """One task per grid cell: plain, picklable data (``run_sweep_item`` runs one).

    The scenarios are built and validated here, in the driver, so a bad sweep fails before any
    work is sent out; workers only re-read the canonical content.
    """
    from nsim.crowd.scenario import load_scenario, scenario_from_data, spawn_extra_humans

    base = load_scenario(scenario_path, store=ctx.store)
    items = []
    for seed in spec.seeds:
        for size in spec.crowd_sizes:
            for b_idx, b in enumerate(spec.behaviours):
                names = (b,) if isinstance(b, str) else tuple(b)
                data = base.data
                data["seed"] = int(seed)
                if not spec.keep_scenario_humans:
                    data["humans"] = []
                # with no extra people the behaviour set plays no part: those cells share one scenario
                data["name"] = f"{base.name[:40]}.s{seed}.n{size}" + (f".b{b_idx}" if size else "")
                sc = scenario_from_data(data, source=f"{scenario_path} (seed {seed})", store=ctx.store)
                rng = ctx.rng(f"simulate.sweep.spawn.{seed}.{size}.{'+'.join(names)}")
                sc = spawn_extra_humans(sc, size, names, rng, store=ctx.store)
                items.append(
                    {
                        "workspace": str(ctx.store.root),
                        "seed": ctx.seed,
                        "force": ctx.force,
                        "config": to_dict(cfg),
                        "scenario": sc.data,
                        "source": sc.source,
                        "grid": {"seed": int(seed), "extra_people": int(size), "behaviours": list(names)},
                    }
                )
    return items


def run_sweep_item(item: dict[str, Any]) -> dict[str, Any]:
    """Run one sweep cell in this process (any worker): returns the artifact id, its metrics and the grid cell."""
    from nsim.crowd.scenario import scenario_from_data
    from nsim.workspace.store import Store

    store = Store(item["workspace"])
    ctx = RunContext(store=store, device_spec="cpu", seed=item["seed"], force=item["force"], progress=False)
    cfg = from_dict(Config, item["config"])
    sc = scenario_from_data(item["scenario"], source=item["source"], store=store)
    out = run(Inputs(sc), cfg, ctx)
    metrics = json.loads(store.get(out.trajectory).file("metrics.json").read_text())
    return {
        "grid": item["grid"],
        "scenario": sc.name,
        "humans": len(sc.humans),
        "trajectory": out.trajectory,
        "cache_hit": out.cache_hit,
        "metrics": metrics["hunav"],
    }


def sweep_table_markdown(rows: list[dict[str, Any]]) -> str:
    """The summary table of a sweep (one row per cell), as Markdown."""
    head = [
        "seed",
        "extra",
        "behaviours",
        "humans",
        "trajectory",
        "min dist (m)",
        "intimate %",
        "personal %",
        "social work",
        "ped speed (m/s)",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]

    def f(v, spec):
        return "n/a" if v is None else format(v, spec)

    for r in rows:
        m, g = r["metrics"], r["grid"]
        lines.append(
            "| "
            + " | ".join(
                [
                    str(g["seed"]),
                    str(g["extra_people"]),
                    ",".join(g["behaviours"]),
                    str(r["humans"]),
                    r["trajectory"][:12],
                    f(m["minimum_distance_to_people_m"], ".2f"),
                    f(m["intimate_space_intrusions_pct"], ".1f"),
                    f(m["personal_space_intrusions_pct"], ".1f"),
                    f(m["social_work_integral"], ".1f"),
                    f(m["avg_pedestrian_speed_mps"], ".2f"),
                ]
            )
            + " |"
        )
    return "\n".join(lines) + "\n"


def run_sweep(
    spec: SweepSpec,
    scenario_path: Path,
    cfg: Config,
    ctx: RunContext,
    *,
    engine: str = "local",
    address: str | None = None,
    workers: int = 1,
) -> list[dict[str, Any]]:
    """Every grid cell as its own artifact, through ``nsim.distributed.map_tasks``; rows in grid order."""
    from nsim.distributed import map_tasks

    items = sweep_items(spec, scenario_path, cfg, ctx)
    return map_tasks(run_sweep_item, items, engine=engine, address=address, workers=workers)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    from nsim.crowd.scenario import scenario_from_data

    art = ctx.store.get(manifest["id"])
    sc = scenario_from_data(
        json.loads(art.file("scenario.json").read_text()),
        source=f"artifact {art.short} scenario.json",
        store=ctx.store,
    )
    cfg = from_dict(Config, manifest["config"])
    ctx = dataclasses.replace(ctx, force=True)
    return run(Inputs(sc), cfg, ctx).trajectory
