"""The walkable map of trained scenes against the test rooms' truth, and the crowd on each scene.

    python bench/walkable_map.py [--rooms robot-lab,kitchen,...] [--workspace DIR] [--preset cpu]
                                 [--steps N] [--set KEY=VALUE ...]
    python bench/walkable_map.py --quick

Per test-room preset (default: all five): ``nsim capture synth --room R`` (the default capture),
``nsim train-scene --preset cpu`` on its ground-truth poses, then

* the free-space IoU of the scene checkpoint's walkable map (``obstacle_cells.npy``: free /
  occupied / unknown) against the room's true free space at the robot's height band
  (``nsim.rendering.occupancy.room_free_space_iou``), with the fractions of true free space the
  map calls occupied or unknown;
* the nav2 map read back with a YAML reader and compared with the raster cell by cell;
* ``nsim simulate`` of a scenario on ``scene: {checkpoint: ...}``: the robot on the room's walk
  loop, four people between the map's most open free cells (chosen on the scene's own map, as a
  user would).

Every stage runs as the ``nsim`` command, so a rerun with ``--workspace`` is all cache hits.
``--quick``: two rooms at the tiny capture size and a 300-step tiny train-scene (a path check; the
IoU of such a scene is not the bar's). The last line is one JSON object with ``iou`` (per room),
``iou_min``, ``simulate_ok`` and ``nav2_match``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from real_capture import nsim  # noqa: E402  (one way to run a stage as a process)

from nsim.rendering.occupancy import ObstacleMap, room_free_space, room_free_space_iou  # noqa: E402
from nsim.synth.room import ROOM_PRESETS, RoomSpec, make_room  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def open_cells(om: ObstacleMap, n: int, min_sep_m: float = 1.0, avoid: np.ndarray | None = None,
               avoid_m: float = 1.5) -> list[list[float]]:
    """``n`` free cell centres of ``om``, most open first (distance to anything not free), ``min_sep_m``
    apart and ``avoid_m`` from the point ``avoid`` (the robot's start)."""
    from scipy.ndimage import distance_transform_edt

    clearance = distance_transform_edt(np.pad(om.free, 1))[1:-1, 1:-1] * om.cell_m
    xy = om.cell_centres_m()
    order = np.argsort(-clearance, axis=None, kind="stable")
    out: list[np.ndarray] = []
    for flat in order:
        i, j = np.unravel_index(flat, clearance.shape)
        if clearance[i, j] < 0.4:
            break
        p = xy[i, j]
        if avoid is not None and np.linalg.norm(p - avoid) < avoid_m:
            continue
        if all(np.linalg.norm(p - q) >= min_sep_m for q in out):
            out.append(p)
            if len(out) == n:
                break
    return [np.round(p, 3).tolist() for p in out]


def scenario_for(room: str, room_seed: int, scene_id: str, om: ObstacleMap, duration_s: float) -> dict:
    """Spot on the room's walk loop, four people walking between the map's most open cells."""
    cx, cy, rx, ry = make_room(room, room_seed).walk_loop_xy_m
    a = 2.0 * np.pi * np.arange(24) / 24
    loop = np.round(np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], -1), 4).tolist()
    spots = open_cells(om, 8, avoid=np.asarray(loop[0]))
    if len(spots) < 2:
        raise ValueError(f"{room}: the scene's map has fewer than 2 free cells 0.4 m from anything else")
    humans = []
    behaviours = ["regular", "impassive", "scared", "curious"]
    for k in range(min(4, len(spots) // 2)):
        start, goal = spots[2 * k], spots[2 * k + 1]
        humans.append({"id": f"p{k}", "behaviour": behaviours[k], "start_m": start, "waypoints_m": [goal, start],
                       "loop": True, "height_m": 1.7, "speed_mps": 1.1, "motion": "walk"})
    return {"format": 1, "name": f"walkable_{room}", "duration_s": duration_s, "dt_s": 0.05, "seed": 0,
            "scene": {"checkpoint": scene_id},
            "robot": {"name": "spot", "radius_m": 0.28, "half_length_m": 0.3, "body_height_m": 0.5,
                      "trajectory": {"waypoints_m": loop, "speed_mps": 1.0, "loop": True}},
            "humans": humans}


def nav2_matches(scene_dir: Path) -> bool:
    """map.yaml read with a YAML reader; map.pgm's trinary values equal obstacle_cells.npy (row 0 = max y)."""
    import cv2

    meta = yaml.safe_load((scene_dir / "map.yaml").read_text())
    img = cv2.imread(str(scene_dir / meta["image"]), cv2.IMREAD_UNCHANGED)
    cells = np.load(scene_dir / "obstacle_cells.npy", allow_pickle=False)
    doc = json.loads((scene_dir / "occupancy.json").read_text())
    occ = 1.0 - img.astype(np.float64) / 255.0 if meta.get("negate", 0) == 0 else img.astype(np.float64) / 255.0
    want = np.where(occ > meta["occupied_thresh"], 100, np.where(occ < meta["free_thresh"], 0, -1))
    return (img.shape == cells.shape[::-1] and np.array_equal(want, cells.T[::-1])
            and np.allclose(meta["origin"][:2], doc["origin_xy_m"]) and np.isclose(meta["resolution"], doc["cell_m"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", default=",".join(ROOM_PRESETS), help="comma-separated test-room presets")
    ap.add_argument("--workspace", type=Path, default=None, help="keep the workspace here (default: a temp dir)")
    ap.add_argument("--preset", default="cpu", help="train-scene preset")
    ap.add_argument("--steps", type=int, default=None, help="train-scene steps (default: the preset's)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="train-scene override KEY=VALUE")
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per room")
    ap.add_argument("--quick", action="store_true", help="two rooms, tiny sizes (a path check)")
    args = ap.parse_args()
    rooms = ["robot-lab", "kitchen"] if args.quick else [r for r in args.rooms.split(",") if r]
    for r in rooms:
        if r not in ROOM_PRESETS:
            ap.error(f"--rooms: {r!r} is not one of {', '.join(ROOM_PRESETS)}")
    cap_preset = "tiny" if args.quick else "default"
    preset, steps = ("tiny", args.steps or 300) if args.quick else (args.preset, args.steps)

    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        log = Path(tmp) / "nsim.log" if args.workspace is None else ws.with_suffix(".log")
        per_room: dict[str, dict[str, Any]] = {}
        for room in rooms:
            t0 = time.perf_counter()
            cap, _, _ = nsim(ws, "capture", "synth", "--preset", cap_preset, "--room", room,
                             "--tag", f"capture/{room}", log=log)
            sets = [x for kv in args.overrides for x in ("--set", kv)]
            step_args = ["--steps", str(steps)] if steps else []
            scene, ts_wall, ts_rss = nsim(ws, "train-scene", "--preset", preset, "--poses", cap, *step_args, *sets,
                                          "--tag", f"scene/{room}", log=log)
            store = Store(ws)
            cap_art, scene_art = store.get(cap), store.get(scene)
            spec = RoomSpec.from_dict(json.loads(cap_art.file("room.json").read_text())["spec"])
            om = ObstacleMap.load(scene_art.path)
            truth = room_free_space(spec, om)
            n_true = max(1, int(truth.sum()))
            row: dict[str, Any] = {
                "iou": round(room_free_space_iou(om, spec), 4),
                "true_free_called_occupied": round(float((truth & om.occupied & ~om.unknown).sum()) / n_true, 4),
                "true_free_called_unknown": round(float((truth & om.unknown).sum()) / n_true, 4),
                "train_scene_wall_s": round(ts_wall, 1), "train_scene_rss_gb": round(ts_rss, 2),
                "nav2_match": bool(nav2_matches(scene_art.path)),
            }
            scen_path = Path(tmp) / f"scenario_{room}.json"
            try:
                scen_path.write_text(json.dumps(scenario_for(room, 0, scene, om, 5.0 if args.quick else args.duration)))
                traj, sim_s, _ = nsim(ws, "simulate", "--scenario", str(scen_path), "--tag", f"trajectory/{room}",
                                      log=log)
                metrics = json.loads(store.get(traj).file("metrics.json").read_text())
                row.update(simulate_ok=True, simulate_s=round(sim_s, 1),
                           min_robot_human_m=metrics["hunav"]["minimum_distance_to_people_m"])
            except (SystemExit, ValueError) as exc:
                row.update(simulate_ok=False, simulate_error=str(exc).splitlines()[-1][:300])
            row["wall_s"] = round(time.perf_counter() - t0, 1)
            per_room[room] = row
            print(f"{room:14s} IoU {row['iou']:.3f}  occupied {row['true_free_called_occupied']:.3f}  "
                  f"unknown {row['true_free_called_unknown']:.3f}  nav2 {row['nav2_match']}  "
                  f"simulate {'ok' if row['simulate_ok'] else 'FAILED: ' + row['simulate_error']}", flush=True)

    ious = [r["iou"] for r in per_room.values()]
    print(json.dumps({"bench": "walkable_map", "quick": args.quick, "capture_preset": cap_preset,
                      "train_preset": preset, "steps": steps, "rooms": per_room,
                      "iou": {k: r["iou"] for k, r in per_room.items()}, "iou_min": min(ious),
                      "simulate_ok": sum(r["simulate_ok"] for r in per_room.values()),
                      "nav2_match": all(r["nav2_match"] for r in per_room.values())}))


if __name__ == "__main__":
    main()
