"""What a simulated run leaves behind: its metrics record, the trajectory files, a top-down
picture and a video (``nsim simulate``'s artifact; the stage reads inputs, runs, and calls these),
and a sweep's summary table.

``robot_goal_m(sc)``: the robot's goal for the metrics; ``run_metrics(sc, sim, forces)``: metrics.json's
content; ``sweep_table_markdown(rows)``: the sweep's table, every metric of every cell;
``controller_table_markdown(rows)``: the controllers side by side (means over their cells).

``write_trajectory(out_dir, sc, sim, metrics, cfg)``: ``trajectory.npz`` (byte-identical across runs; with the
people's recorded clips, ``nsim.human.person_motion.person_clip_arrays``),
TUM files of the robot and each human, ``scenario.json``, ``occupancy.json``, ``metrics.json``,
``topdown.png`` and, when ``cfg.video``, ``run.mp4`` (``cfg``: the stage's config, read for
``video``, ``video_fps`` and the like). ``sc``: the scenario; ``sim``: ``nsim.crowd.scenario.simulate``'s run.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from nsim.crowd.behaviours import BEHAVIOUR_NAMES
from nsim.human.person_motion import person_clip_arrays
from nsim.io.npz import save_npz_deterministic

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

SUMMARY_METRICS = (
    "completed",
    "time_to_reach_goal_s",
    "minimum_distance_to_people_m",
    "intimate_space_intrusions_pct",
    "personal_space_intrusions_pct",
    "social_work_integral",
    "avg_pedestrian_velocity_mps",
)
"""The metrics copied into the artifact's summary (all of them are in metrics.json)."""


def robot_goal_m(sc) -> np.ndarray | None:
    """Where the scenario sends the robot: its last waypoint, or its last pose's position for a
    timed trajectory; None for a waypoint loop (no goal). ``(2,)``."""
    traj = sc.data["robot"]["trajectory"]
    if "waypoints_m" in traj:
        return None if traj.get("loop", False) else np.array(traj["waypoints_m"][-1], dtype=np.float64)
    return np.array(traj["poses"][-1]["position_m"][:2], dtype=np.float64)


def _json_value(v: Any) -> Any:
    """A metric for JSON: bools and counts as they are, non-finite floats (undefined) as null."""
    if v is None or isinstance(v, (bool, np.bool_)):
        return None if v is None else bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    return float(v) if math.isfinite(v) else None


def _json_metrics(m) -> dict[str, Any]:
    return {k: _json_value(v) for k, v in m.as_dict().items()}


def run_metrics(sc, sim, forces) -> dict[str, Any]:
    """metrics.json: the run's metrics (``nsim.crowd.metrics``; undefined -> null), the robot's goal
    from the scenario (``robot_goal_m``), all people (``hunav``) and, as HuNavSim's evaluator
    also reports, the people of each behaviour alone (``hunav_by_behaviour``), and the run's size.

    forces: the simulation's ``ForceParams`` (for nsim's own force sums).
    """
    from nsim.crowd.metrics import crowd_metrics_breakdown

    everyone, by_behaviour = crowd_metrics_breakdown(
        sim.crowd, walls_m=sim.walls_m, forces=forces, robot_goal_m=robot_goal_m(sc)
    )
    run = {
        "scenario": sc.name,
        "humans": len(sc.humans),
        "ticks": len(sim.time_s),
        "dt_s": sim.dt_s,
        "duration_s": float(sim.time_s[-1]),
        "humans_reacting_at_some_tick": int(np.any(sim.crowd.behaviour_state == 1, axis=0).sum()),
    }
    if sim.robot_command_body is not None:  # a controller drove the robot (replay runs keep their bytes)
        from nsim.crowd.controllers import controller_label

        clamped = np.linalg.norm(sim.robot_command_body - sim.robot_executed_body, axis=1) > 1e-9
        run["controller"] = controller_label(sc.robot.controller)
        run["ticks_command_not_executed"] = int(clamped.sum())
    return {
        "hunav": _json_metrics(everyone),
        "hunav_by_behaviour": {name: _json_metrics(m) for name, m in by_behaviour.items()},
        "run": run,
    }


def sweep_table_markdown(rows: list[dict[str, Any]]) -> str:
    """The summary table of a sweep, as Markdown: one row per cell (``simulate.run_sweep_item``'s
    rows), its grid cell then every metric of metrics.json's ``hunav`` (HuNavSim's, then nsim's)."""
    from nsim.crowd.metrics import CrowdMetrics

    keys = [f.name for f in dataclasses.fields(CrowdMetrics)]
    head = ["seed", "extra", "behaviours", "controller", "humans", "trajectory", *keys]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]

    def cell(v: Any) -> str:
        if v is None:
            return "n/a"
        if isinstance(v, bool):
            return "yes" if v else "no"
        return str(v) if isinstance(v, int) else format(v, ".4g")

    for r in rows:
        m, g = r["metrics"], r["grid"]
        grid = [
            str(g["seed"]),
            str(g["extra_people"]),
            ",".join(g["behaviours"]),
            g.get("controller", "replay"),
            str(r["humans"]),
        ]
        lines.append("| " + " | ".join([*grid, r["trajectory"][:12], *(cell(m[k]) for k in keys)]) + " |")
    return "\n".join(lines) + "\n"


def controller_table_markdown(rows: list[dict[str, Any]]) -> str:
    """Controllers side by side, as Markdown: one column per controller (grid order), one row per
    metric of metrics.json's ``hunav``, each the mean over that controller's cells (the same seeds
    and crowds for all; yes/no metrics as the fraction of cells with yes; undefined values left
    out, ``n/a`` when no cell defines it), and the number of cells."""
    from nsim.crowd.metrics import CrowdMetrics

    names: list[str] = []
    for r in rows:
        c = r["grid"].get("controller", "replay")
        if c not in names:
            names.append(c)
    keys = [f.name for f in dataclasses.fields(CrowdMetrics)]
    lines = ["| metric | " + " | ".join(names) + " |", "|---|" + "|".join("---" for _ in names) + "|"]
    by_name = {c: [r["metrics"] for r in rows if r["grid"].get("controller", "replay") == c] for c in names}
    lines.append("| cells | " + " | ".join(str(len(by_name[c])) for c in names) + " |")
    for k in keys:
        cells = []
        for c in names:
            values = [float(m[k]) for m in by_name[c] if m.get(k) is not None]
            cells.append(format(sum(values) / len(values), ".4g") if values else "n/a")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# Writing


def write_trajectory(out_dir: Path, sc, sim, metrics: dict[str, Any], cfg) -> None:
    from nsim.crowd.paths import yaw_poses_se3
    from nsim.io.canonical import canonical_floats, round_decimals
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
            # recorded clips (BVH files, checkpoints' motions), so render draws them without the scenario's files
            **person_clip_arrays([None if h.clip is None else (h.clip_id, h.clip) for h in sc.humans]),
        }
    )
    if sim.robot_command_body is not None:
        arrays["robot_command_body"] = sim.robot_command_body
        arrays["robot_executed_body"] = sim.robot_executed_body
    # floats rounded to 1e-9 (m, rad, m/s, s: nsim.io.canonical), so that numpy's other SIMD paths on another
    # CPU (its arctan2 and sin differ in the last bits) write the same bytes
    arrays = {k: round_decimals(v) if np.asarray(v).dtype.kind == "f" else v for k, v in arrays.items()}
    save_npz_deterministic(out_dir / "trajectory.npz", arrays)
    write_tum(out_dir / "robot.tum", Trajectory.from_poses(sim.time_s, sim.robot_pose_se3))
    (out_dir / "humans").mkdir()
    for i, h in enumerate(sc.humans):
        poses = yaw_poses_se3(crowd.position_m[:, i], crowd.heading_rad[:, i], 0.0)
        write_tum(out_dir / "humans" / f"{h.id}.tum", Trajectory.from_poses(sim.time_s, poses))
    (out_dir / "metrics.json").write_text(
        json.dumps(canonical_floats(metrics), indent=1, sort_keys=True, allow_nan=False) + "\n"
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

    from nsim.crowd.metrics import people_gap_m

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
        k, i = np.unravel_index(np.argmin(people_gap_m(crowd)), (len(sim.time_s), len(sc.humans)))
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


def write_video(path: Path, sc, sim, cfg) -> None:
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


