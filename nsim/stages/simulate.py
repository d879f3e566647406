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
import io
import json
import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import from_dict, param, to_dict
from nsim.context import RunContext
from nsim.crowd.behaviours import BEHAVIOUR_NAMES, BehaviourParams
from nsim.crowd.social_force import ForceParams

STAGE = "simulate"
VERSION = 2  # 2: run.mp4 in H.264 (was MPEG-4 Part 2), frames under a label strip

# behaviour -> BGR colour for the video, and the matching matplotlib colour
BEHAVIOUR_COLOURS = {
    "regular": (0.12, 0.47, 0.71),
    "impassive": (0.50, 0.50, 0.50),
    "surprised": (0.58, 0.40, 0.74),
    "scared": (0.17, 0.63, 0.17),
    "curious": (1.00, 0.50, 0.05),
    "threatening": (0.84, 0.15, 0.16),
}
ROBOT_COLOUR = (0.10, 0.10, 0.10)


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


SUMMARY_METRICS = (
    "minimum_distance_to_people_m",
    "intimate_space_intrusions_pct",
    "personal_space_intrusions_pct",
    "social_work_integral",
    "avg_pedestrian_speed_mps",
)


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def run_metrics(sc, sim, m) -> dict[str, Any]:
    """metrics.json: the HuNavSim metrics (non-finite -> null) and the run's size."""
    hunav = {k: _finite_or_none(v) for k, v in m.as_dict().items()}
    if sc.data["robot"]["trajectory"].get("loop", False):
        hunav["time_to_goal_s"] = None  # a looping robot has no goal
    return {
        "hunav": hunav,
        "run": {
            "scenario": sc.name,
            "humans": len(sc.humans),
            "ticks": len(sim.time_s),
            "dt_s": sim.dt_s,
            "duration_s": float(sim.time_s[-1]),
            "humans_reacting_at_some_tick": int(np.any(sim.crowd.behaviour_state == 1, axis=0).sum()),
        },
    }


# ----------------------------------------------------------------------------------------------
# Writing


def save_npz_deterministic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Like ``np.savez_compressed`` but byte-identical across runs (fixed zip entry timestamps)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())


def write_trajectory(out_dir: Path, sc, sim, metrics: dict[str, Any], cfg: Config) -> None:
    from nsim.crowd.scenario import yaw_poses_se3
    from nsim.io.tum import Trajectory, write_tum

    crowd = sim.crowd
    arrays = crowd.as_arrays()
    arrays.update(
        {
            "robot_pose_se3": sim.robot_pose_se3,
            "human_ids": np.array([h.id for h in sc.humans], dtype=str).reshape(-1),
            "height_m": np.array([h.height_m for h in sc.humans], dtype=np.float64),
            "motion": np.array([h.motion for h in sc.humans], dtype=str).reshape(-1),
            "appearance": np.array([h.appearance or "" for h in sc.humans], dtype=str).reshape(-1),
            "behaviour_names": np.array(BEHAVIOUR_NAMES, dtype=str),
        }
    )
    save_npz_deterministic(out_dir / "trajectory.npz", arrays)
    write_tum(out_dir / "robot.tum", Trajectory.from_poses(sim.time_s, sim.robot_pose_se3))
    (out_dir / "humans").mkdir()
    for i, h in enumerate(sc.humans):
        poses = yaw_poses_se3(crowd.position_m[:, i], crowd.heading_rad[:, i], 0.0)
        write_tum(out_dir / "humans" / f"{h.id}.tum", Trajectory.from_poses(sim.time_s, poses))
    (out_dir / "metrics.json").write_text(
        json.dumps(metrics, indent=1, sort_keys=True, allow_nan=False) + "\n"
    )
    (out_dir / "scenario.json").write_text(json.dumps(sc.data, indent=1, sort_keys=True) + "\n")
    occupancy = {
        "units": "m",
        "frame": "world, z up; polygons in the xy plane",
        "scene": sc.scene_label(),
        "polygons": [np.asarray(p, dtype=float).round(6).tolist() for p in sc.obstacles_m],
    }
    if any(sc.obstacle_holes_m):  # a scene checkpoint's map: free rooms inside rings of walls
        occupancy["holes"] = [[np.asarray(h, dtype=float).round(6).tolist() for h in hs] for hs in sc.obstacle_holes_m]
    (out_dir / "occupancy.json").write_text(json.dumps(occupancy, indent=1) + "\n")
    write_topdown(out_dir / "topdown.png", sc, sim, metrics)
    if cfg.video:
        write_video(out_dir / "run.mp4", sc, sim, cfg)


def capsule_outline(
    centre_m: np.ndarray, yaw_rad: float, half_length_m: float, radius_m: float, n: int = 12
) -> np.ndarray:
    """A capsule's outline ``(2n + 2, 2)``: the body axis ``+- half_length_m`` along ``yaw_rad`` grown by ``radius_m``."""
    a = np.linspace(-np.pi / 2, np.pi / 2, n + 1)
    front = np.stack([half_length_m + radius_m * np.cos(a), radius_m * np.sin(a)], axis=-1)
    back = np.stack([-half_length_m - radius_m * np.cos(a), -radius_m * np.sin(a)], axis=-1)
    local = np.concatenate([front, back])
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.asarray(centre_m) + local @ np.array([[c, s], [-s, c]])


def _map_bounds(sc, sim) -> tuple[np.ndarray, np.ndarray]:
    pts = [sim.robot_pose_se3[:, :2, 3]]
    if sc.obstacles_m:
        pts.append(np.concatenate([np.asarray(p) for p in sc.obstacles_m]))
    if sim.crowd.position_m.size:
        pts.append(sim.crowd.position_m.reshape(-1, 2))
    allp = np.concatenate(pts)
    return allp.min(axis=0) - 0.3, allp.max(axis=0) + 0.3


def write_topdown(path: Path, sc, sim, metrics: dict[str, Any]) -> None:
    """The run from above: obstacles, the robot's path and body at the closest approach, the humans' paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    from nsim.crowd.metrics import robot_distance_m

    crowd = sim.crowd
    lo, hi = _map_bounds(sc, sim)
    size = hi - lo
    fig, ax = plt.subplots(figsize=(8.0, max(3.0, 8.0 * size[1] / size[0]) + 0.6), dpi=80)
    for poly, holes in zip(sc.obstacles_m, sc.obstacle_holes_m, strict=True):
        p = np.asarray(poly)
        ax.fill(p[:, 0], p[:, 1], color="0.75", lw=0)
        for h in holes:
            h = np.asarray(h)
            ax.fill(h[:, 0], h[:, 1], color="white", lw=0)
    robot_xy = sim.robot_pose_se3[:, :2, 3]
    ax.plot(
        robot_xy[:, 0], robot_xy[:, 1], "--", color=ROBOT_COLOUR, lw=1.2, label=f"robot ({sc.robot.name})"
    )
    ax.plot(*robot_xy[0], "s", color=ROBOT_COLOUR, ms=6)
    seen = set()
    for i, h in enumerate(sc.humans):
        c = BEHAVIOUR_COLOURS[h.behaviour]
        label = h.behaviour if h.behaviour not in seen else None
        seen.add(h.behaviour)
        xy = crowd.position_m[:, i]
        ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=1.0, alpha=0.8, label=label)
        ax.plot(*xy[0], "o", color=c, ms=5)
        ax.plot(*xy[-1], "x", color=c, ms=6)
        if len(sc.humans) <= 30:
            ax.annotate(h.id, xy[0], fontsize=7, xytext=(3, 3), textcoords="offset points")
    if sc.humans:
        k, i = np.unravel_index(np.argmin(robot_distance_m(crowd)), (len(sim.time_s), len(sc.humans)))
        pose = sim.robot_pose_se3[k]
        outline = capsule_outline(
            pose[:2, 3], float(np.arctan2(pose[1, 0], pose[0, 0])), sc.robot.half_length_m, sc.robot.radius_m
        )
        ax.add_patch(Polygon(outline, closed=True, color=ROBOT_COLOUR, alpha=0.3, lw=0))
        ax.add_patch(Circle(crowd.position_m[k, i], sc.humans[i].radius_m, fill=False, color="red", lw=1.5))
    m = metrics["hunav"]
    min_d = m["minimum_distance_to_people_m"]
    ax.set_title(
        f"{sc.name}: {len(sc.humans)} humans, {sim.time_s[-1]:.1f} s; closest approach "
        f"{'n/a' if min_d is None else f'{min_d:.2f} m'} (circled), intimate {m['intimate_space_intrusions_pct']:.0f}% of ticks",
        fontsize=9,
    )
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=7, framealpha=0.8)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def _bgr(rgb: tuple[float, float, float], scale: float = 1.0) -> tuple[int, int, int]:
    return tuple(int(round(255 * min(1.0, c * scale))) for c in rgb[::-1])


def write_video(path: Path, sc, sim, cfg: Config) -> None:
    """The run from above at ``cfg.fps`` (every ``round(1 / (fps dt))`` ticks), H.264, each frame
    under a label strip (``nsim.io.labels``) with the scenario's name and the time."""
    import cv2

    from nsim.io.labels import add_label
    from nsim.io.video import open_mp4

    crowd = sim.crowd
    lo, hi = _map_bounds(sc, sim)
    s = cfg.px_per_m
    width = int(math.ceil((hi[0] - lo[0]) * s / 2.0)) * 2
    height = int(math.ceil((hi[1] - lo[1]) * s / 2.0)) * 2
    shift = 3
    sub = float(1 << shift)

    def px(xy: np.ndarray) -> np.ndarray:  # world (..., 2) -> fixed-point pixels
        xy = np.asarray(xy, dtype=np.float64)
        u = (xy[..., 0] - lo[0]) * s
        v = (hi[1] - xy[..., 1]) * s
        return np.round(np.stack([u, v], axis=-1) * sub).astype(np.int32)

    background = np.full((height, width, 3), 255, np.uint8)
    for poly, holes in zip(sc.obstacles_m, sc.obstacle_holes_m, strict=True):
        # one call with the holes: cv2 fills by the even-odd rule, so a hole stays white
        cv2.fillPoly(background, [px(poly), *[px(h) for h in holes]], (190, 190, 190), cv2.LINE_AA, shift)
    stride = max(1, int(round(1.0 / (cfg.fps * sim.dt_s))))
    fps = 1.0 / (stride * sim.dt_s)
    trail = max(1, int(round(3.0 / sim.dt_s)))
    colours = [_bgr(BEHAVIOUR_COLOURS[h.behaviour]) for h in sc.humans]
    light = [_bgr(BEHAVIOUR_COLOURS[h.behaviour], 1.6) for h in sc.humans]
    robot_xy = sim.robot_pose_se3[:, :2, 3]
    with open_mp4(path, fps) as writer:
        for k in range(0, len(sim.time_s), stride):
            frame = background.copy()
            cv2.polylines(
                frame, [px(robot_xy[max(0, k - trail) : k + 1])], False, (120, 120, 120), 1, cv2.LINE_AA, shift
            )
            for i in range(len(sc.humans)):
                cv2.polylines(
                    frame,
                    [px(crowd.position_m[max(0, k - trail) : k + 1, i])],
                    False,
                    light[i],
                    1,
                    cv2.LINE_AA,
                    shift,
                )
            pose = sim.robot_pose_se3[k]
            u = pose[:2, 0] * sc.robot.half_length_m
            body = px(np.stack([pose[:2, 3] - u, pose[:2, 3] + u]))
            thick = max(1, int(round(2 * sc.robot.radius_m * s)))
            cv2.line(frame, tuple(body[0]), tuple(body[1]), _bgr(ROBOT_COLOUR), thick, cv2.LINE_AA, shift)
            nose = px(pose[:2, 3] + pose[:2, 0] * (sc.robot.half_length_m + sc.robot.radius_m))
            cv2.line(frame, tuple(px(pose[:2, 3])), tuple(nose), (0, 200, 255), 2, cv2.LINE_AA, shift)
            for i, h in enumerate(sc.humans):
                c = crowd.position_m[k, i]
                r = int(round(h.radius_m * s * sub))
                cv2.circle(frame, tuple(px(c)), r, colours[i], -1, cv2.LINE_AA, shift)
                ring = (0, 0, 0) if crowd.behaviour_state[k, i] == 1 else (255, 255, 255)
                cv2.circle(
                    frame, tuple(px(c)), r, ring, 2 if crowd.behaviour_state[k, i] == 1 else 1, cv2.LINE_AA, shift
                )
                head = c + h.radius_m * np.array(
                    [math.cos(crowd.heading_rad[k, i]), math.sin(crowd.heading_rad[k, i])]
                )
                cv2.line(frame, tuple(px(c)), tuple(px(head)), (255, 255, 255), 1, cv2.LINE_AA, shift)
            writer.write(add_label(frame[..., ::-1], f"{sc.name}  t = {sim.time_s[k]:5.1f} s"))


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
