"""The paper's five tables, regenerated end to end on the built-in test room; prints them.

    python pipelines/paper.py [--size tiny|small|default] [--workspace DIR] [--seed N] [--device auto]
                              [--out DIR]

For each of the five room presets (robot-lab, common-room, kitchen, living-room, seminar-room):
capture synth -> poses (reconstruct, or the capture's ground-truth poses at ``tiny``) ->
train-scene -> render of the scene's held-out frames at their own cameras (poses mode). Then a
Spot run in robot-lab (simulate configs/scenarios/spot_run.json: five people walk around the
robot), a human checkpoint (capture synth --actor in robot-lab -> train-human over the capture's
background images) that draws every person of the run, and the run rendered along the robot's
path by configs/robots/spot.yaml in robot-lab's scene with its people (trajectory mode,
``--humans``; the pipeline prints in how many camera frames people are in view), and
``evaluate`` for each table:

    scenes      the five held-out renders against the captured frames (images and depth EXRs)
    spot-rgb    the Spot cameras against the test room's oracle at the same camera poses (with the
                people as test-room actors, posed like the rendered ones)
    spot-depth  the Spot depth cameras against the oracle's depth (people included)
    slam        SfM on Spot's left camera: simulated frames vs the oracle's frames at the same poses
                (at ``small``: a render of that camera alone, larger and without the people)
    detection   HOG people detections on the simulated frames vs on the oracle's frames at the same
                camera poses with the same people (test-room actors posed from the run, dressed like
                the actor the checkpoint was trained from), frames turned upright; from a render of
                the five cameras at 160x120 (the HOG window is 64x128 px: people are too small at 64x48)

Sizes and their expected wall time on 2 CPU cores (the reduced ``small`` run is the one in
docs/results.md; measured with the people: tiny 3.5 min, small 7.7 min, on 2 cores):

    tiny     96x72 captures of 40 frames, the capture's ground-truth poses (no SfM at this size),
             300 training steps, Spot cameras at 64x48 for 8 ticks of a 4 s run; a 96x72 actor
             capture of 40 frames and 300 train-human steps; detection on the five cameras at
             160x120 at the same 8 ticks: about 4 minutes (6 where the cores are shared)
    small    160x120 captures of 100 frames reconstructed by pycolmap (made metric and put in the
             room's frame by the capture's ground-truth trajectory, as a robot's odometry would),
             600 training steps, 4 held-out frames per room, a 6 s Spot run every 0.2 s (31 ticks)
             with the cameras at 64x48 and the SLAM camera (left) alone at 160x120; a 160x120 actor
             capture of 60 frames and 600 train-human steps; detection on the five cameras at
             160x120 every 0.5 s (13 ticks): about 8 minutes (measured 7 min 43 s)
    default  320x240 captures of 150 frames, reconstruct, the cpu training preset, every held-out
             frame, Spot cameras at 160x120 every 0.25 s of the full 30 s run (detection on them);
             the default actor capture (320x240, 150 frames) and train-human preset: about 2.5 hours
             (not measured)

Only chains stage ``run()`` calls; re-running is cheap (every cached action returns at once).
``--out DIR`` also writes every table there as Markdown (``<table>.md``) plus ``tables.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.crowd.scenario import load_scenario  # noqa: E402
from nsim.errors import NsimError  # noqa: E402
from nsim.stages import capture, evaluate, reconstruct, render, simulate, train_human, train_scene  # noqa: E402
from nsim.synth.room import ROOM_PRESETS  # noqa: E402
from nsim.workspace.store import Store, default_root  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROOMS = tuple(ROOM_PRESETS)
EXPECTED_MIN = {"tiny": 6, "small": 10, "default": 150}
CAMERAS = "frontleft,frontright,left,right,back"  # Spot's five body cameras (configs/robots/spot.yaml)

# Per size: preset and overrides of each stage. "reconstruct": None trains on ground-truth poses;
# "slam" / "detection": None scores the Spot render itself; "evaluate_detection": the detection table's.
SIZES: dict[str, dict[str, tuple[str, list[str]] | None]] = {
    "tiny": {
        "capture": ("tiny", ["supersample=1", "video=false"]),
        "reconstruct": None,
        "train_scene": ("tiny", ["optim.steps=300"]),
        "heldout": ("tiny", ["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=null"]),
        "simulate": ("tiny", ["video=false"]),
        "actor": ("tiny", ["actor=true", "supersample=1", "video=false"]),
        "train_human": ("tiny", []),
        "spot": ("tiny", ["max_frames=8"]),
        "slam": None,
        "detection": ("tiny", [f"sensors=[{CAMERAS}]", "image_scale=0.25", "max_frames=8"]),
        "evaluate": ("tiny", []),
        "evaluate_detection": ("tiny", ["detection.hog_upscale=4.0"]),
    },
    "small": {
        "capture": ("tiny", ["width=160", "height=120", "n_frames=100", "supersample=1", "video=false"]),
        "reconstruct": ("tiny", ["frames=100"]),
        "train_scene": ("tiny", ["optim.steps=600"]),
        "heldout": ("tiny", ["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=4"]),
        "simulate": ("default", ["max_duration_s=6.0", "video=false"]),
        "actor": ("tiny", ["actor=true", "width=160", "height=120", "n_frames=60", "supersample=1", "video=false"]),
        "train_human": ("tiny", ["optim.steps=600", "optim.num_threads=2"]),
        "spot": ("tiny", ["tick_stride=4", "max_frames=null"]),
        "slam": ("tiny", ["sensors=[left]", "image_scale=0.25", "tick_stride=4", "max_frames=null"]),
        "detection": ("tiny", [f"sensors=[{CAMERAS}]", "image_scale=0.25", "tick_stride=10", "max_frames=null"]),
        "evaluate": ("default", ["slam.max_features=2048", "slam.matcher=exhaustive"]),
        "evaluate_detection": ("default", ["detection.hog_upscale=4.0"]),
    },
    "default": {
        "capture": ("default", []),
        "reconstruct": ("default", ["frames=150"]),
        "train_scene": ("cpu", []),
        "heldout": ("cpu", ["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=null"]),
        "simulate": ("default", []),
        "actor": ("default", ["actor=true", "video=false"]),
        "train_human": ("default", []),
        "spot": ("cpu", ["tick_stride=5", "video=false"]),
        "slam": None,
        "detection": None,
        "evaluate": ("default", []),
        "evaluate_detection": ("default", ["detection.hog_upscale=4.0"]),
    },
}


def step(name: str, fn):
    t0 = time.perf_counter()
    out = fn()
    print(f"[paper] {name:<34} {time.perf_counter() - t0:7.1f} s", flush=True)
    return out


def cfg_of(cls, stage: str, size: str, key: str, extra: list[str] = ()):
    preset, overrides = SIZES[size][key]
    return load_config(cls, stage=stage, preset=preset, overrides=[*overrides, *extra])


def scene_of_room(ctx: RunContext, room: str, size: str) -> tuple[str, str, str]:
    """capture -> poses -> scene for one room; returns (capture id, scene id, held-out render id)."""
    cap_cfg = cfg_of(capture.Config, "capture", size, "capture", [f"room={room}"])
    cap = step(f"capture synth ({room})", lambda: capture.run(capture.Inputs(), cap_cfg, ctx)).capture
    ctx.store.set_ref(f"capture/paper-{room}", cap)
    poses = cap
    if SIZES[size]["reconstruct"] is not None:
        art = ctx.store.get(cap)
        rec_cfg = cfg_of(reconstruct.Config, "reconstruct", size, "reconstruct")
        rec_inputs = reconstruct.Inputs(capture=cap, reference=art.file("gt_trajectory.tum"))
        poses = step(f"reconstruct ({room})", lambda: reconstruct.run(rec_inputs, rec_cfg, ctx)).poses
        ctx.store.set_ref(f"poses/paper-{room}", poses)
    ts_cfg = cfg_of(train_scene.Config, "train_scene", size, "train_scene")
    scene = step(f"train-scene ({room})", lambda: train_scene.run(train_scene.Inputs(poses=poses), ts_cfg, ctx)).scene
    ctx.store.set_ref(f"scene/paper-{room}", scene)
    ren_cfg = cfg_of(render.Config, "render", size, "heldout")
    ren_inputs = render.Inputs(poses=poses, scene=scene)
    held = step(f"render held-out ({room})", lambda: render.run(ren_inputs, ren_cfg, ctx)).render
    ctx.store.set_ref(f"render/paper-heldout-{room}", held)
    return cap, scene, held


def human_of_room(ctx: RunContext, room: str, size: str) -> str:
    """actor capture -> train-human in ``room``; returns the human checkpoint id (the people of the run)."""
    cap_cfg = cfg_of(capture.Config, "capture", size, "actor", [f"room={room}"])
    cap = step(f"capture synth --actor ({room})", lambda: capture.run(capture.Inputs(), cap_cfg, ctx)).capture
    ctx.store.set_ref(f"capture/paper-actor-{room}", cap)
    th_cfg = cfg_of(train_human.Config, "train_human", size, "train_human")
    human = step(f"train-human ({room})", lambda: train_human.run(train_human.Inputs(capture=cap), th_cfg, ctx)).human
    ctx.store.set_ref(f"human/paper-{room}", human)
    return human


def people_in_view(store: Store, render_id: str) -> tuple[int, int]:
    """``(camera frames showing a person, camera frames)`` of a trajectory render with people (its masks)."""
    meta = json.loads(store.get(store.resolve(render_id)).file("render.json").read_text())
    px = [v["people_px"] for row in meta["per_frame"] for v in row.values()
          if isinstance(v, dict) and "people_px" in v]
    return sum(p > 0 for p in px), len(px)


def check_people(ctx: RunContext, render_id: str, what: str) -> None:
    seen, total = people_in_view(ctx.store, render_id)
    print(f"[paper] people in view in {seen} of {total} camera frames of the {what}", flush=True)
    if not seen:
        print(f"[paper] warning: no person in view in the {what}: the detection table compares frames without "
              "people", file=sys.stderr, flush=True)


def run_paper(workspace: Path, size: str, seed: int, device: str, out_dir: Path | None) -> dict:
    ctx = RunContext(store=Store(workspace), device_spec=device, seed=seed)
    heldout, scenes = [], {}
    for room in ROOMS:
        _, scene, held = scene_of_room(ctx, room, size)
        heldout.append(held)
        scenes[room] = scene

    # Spot's run in robot-lab (the scenario's room), rendered in robot-lab's trained scene with the
    # scenario's people, each drawn by a human checkpoint trained on an actor capture of robot-lab.
    sim_cfg = cfg_of(simulate.Config, "simulate", size, "simulate")
    scenario = load_scenario(REPO / "configs" / "scenarios" / "spot_run.json", store=ctx.store)
    traj = step("simulate (spot_run)", lambda: simulate.run(simulate.Inputs(scenario), sim_cfg, ctx)).trajectory
    ctx.store.set_ref("trajectory/paper-spot-run", traj)
    human = human_of_room(ctx, "robot-lab", size)
    spot_cfg = cfg_of(render.Config, "render", size, "spot")
    spot_inputs = render.Inputs(trajectory=traj, scene=scenes["robot-lab"], rig=REPO / "configs" / "robots" / "spot.yaml",
                                humans=(human,))
    spot = step("render (spot rig, robot-lab, people)", lambda: render.run(spot_inputs, spot_cfg, ctx)).render
    ctx.store.set_ref("render/paper-spot-run", spot)
    check_people(ctx, spot, "Spot render")

    slam = spot
    if SIZES[size]["slam"] is not None:
        # SfM needs larger frames than the other tables: the SLAM camera alone, at a higher resolution,
        # and without the people: the mapping experiment scores the room (people walking past the
        # camera of an under-trained scene dominate its features: 3 of 31 frames registered at `small`)
        slam_cfg = cfg_of(render.Config, "render", size, "slam")
        static = dataclasses.replace(spot_inputs, humans=())
        slam = step("render (slam camera, robot-lab)", lambda: render.run(static, slam_cfg, ctx)).render
        ctx.store.set_ref("render/paper-slam-camera", slam)

    detection = spot
    if SIZES[size]["detection"] is not None:
        # the HOG window is 64x128 px: people need larger frames than the image tables' (fewer ticks)
        det_cfg = cfg_of(render.Config, "render", size, "detection")
        detection = step("render (detection cameras, people)", lambda: render.run(spot_inputs, det_cfg, ctx)).render
        ctx.store.set_ref("render/paper-detection", detection)
        check_people(ctx, detection, "detection render")

    tables = {}
    for table, renders in (("scenes", heldout), ("spot-rgb", [spot]), ("spot-depth", [spot]), ("slam", [slam]),
                           ("detection", [detection])):
        key = "evaluate_detection" if table == "detection" else "evaluate"
        ev_cfg = cfg_of(evaluate.Config, "evaluate", size, key, [f"table={table}"])
        ev_inputs = evaluate.Inputs(renders=tuple(renders))
        out = step(f"evaluate --table {table}", lambda c=ev_cfg, i=ev_inputs: evaluate.run(i, c, ctx))
        ctx.store.set_ref(f"evaluation/paper-{table}", out.evaluation)
        tables[table] = evaluate.load_table(ctx, out.evaluation)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        for name, table in tables.items():
            (out_dir / f"{name}.md").write_text(table.to_markdown())
        (out_dir / "tables.md").write_text("\n".join(t.to_markdown() for t in tables.values()))
        (out_dir / "artifacts.json").write_text(json.dumps(
            {name: ctx.store.resolve(f"evaluation/paper-{name}") for name in tables}, indent=1) + "\n")
    return tables


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", choices=tuple(SIZES), default="small")
    ap.add_argument("--workspace", type=Path, default=default_root())
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables as Markdown here")
    args = ap.parse_args()
    print(f"[paper] size {args.size}: expected about {EXPECTED_MIN[args.size]} min on 2 CPU cores "
          f"(less where the run cache has the steps)", flush=True)
    t0 = time.perf_counter()
    try:
        tables = run_paper(args.workspace, args.size, args.seed, args.device, args.out)
    except NsimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for table in tables.values():
        print()
        print(table.to_text(), end="")
    print(f"\n[paper] five tables in {time.perf_counter() - t0:.0f} s (size {args.size}, workspace {args.workspace})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
