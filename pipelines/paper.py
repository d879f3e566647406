"""The paper's five tables, regenerated end to end on the built-in test room; prints them.

    python pipelines/paper.py [--size tiny|small|default] [--workspace DIR] [--seed N] [--device auto]
                              [--out DIR] [--recording [LOG] [--poses REF --scene REF]]

For each of the five room presets (robot-lab, common-room, kitchen, living-room, seminar-room):
capture synth -> poses (reconstruct, or the capture's ground-truth poses at ``tiny``) ->
train-scene -> render of the scene's held-out frames at their own cameras (poses mode). Then a
Spot run in robot-lab (simulate nsim/configs/scenarios/spot_run.json: five people walk around the
robot), a human checkpoint (capture synth --actor in robot-lab -> train-human over the capture's
background images) that draws every person of the run, and the run rendered along the robot's
path by nsim/configs/robots/spot.yaml in robot-lab's scene with its people (trajectory mode,
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

``--recording``: the five Spot tables against a robot's recording as well (``run_recording``). Without LOG,
after the oracle tables, the realistic robot log of the Spot run is written under the workspace
(``robot_logs/paper-<digest>``, once: ``nsim capture robot-log``, Spot's five cameras at 320x240 (SIFT needs
the pixels), their depth, the LiDAR, with the realistic faults, and ``<log>.truth.json``); then ``import-log``
-> ``register-log`` (in a metric map of robot-lab: a 100-frame 200x150 capture reconstructed by pycolmap and
made metric by its ground-truth trajectory; at ``tiny`` 28 of 30 frames localise, 1.2 cm / 0.11 deg off the
truth, where in a 160x120 map such as ``small``'s scene poses 16 of 30 did, 3.0 cm / 0.45 deg; ``default``
registers in robot-lab's own 320x240 reconstruction) -> ``render --recording`` in robot-lab's scene -> ``evaluate`` of spot-rgb (raw and
colour-corrected), spot-depth, lidar, slam and detection against the recording. The same sensors at the same
ticks are also rendered from the true trajectory without people (the twin) and scored against the oracle:
the pipeline prints both, the registration's error against the truth, and per table the two sides' means
and their difference (the log's faults and the registration are all that separates them). With LOG (a ROS
bag or a recording folder) that log is imported instead and registered in robot-lab's map and rendered in
its scene, unless ``--poses`` (a metric poses artifact with a sparse model) and ``--scene`` (a scene
checkpoint of that world) name the user's own: then the test room is not built at all. Its truth is read
from ``<LOG>.truth.json`` when there is one; there is no twin. The log has no people: the recording render
has none, and the detection table counts boxes on frames without people.

    tiny     the log's 20 ticks every 0.2 s of the 4 s run, every 7th frame of each stream rendered (3 per
             stream: five cameras, their depth, the LiDAR); about 10 more minutes (not measured end to end:
             bench/robot_log.py --quick, the same with two cameras, took 6 min on 2 cores shared with
             other jobs, 5.4 of them rendering); SLAM is n/a on three frames (SfM registers none)
    small    the 6 s run's 30 ticks every 0.2 s, 10 frames per camera localised, every third frame of each
             stream rendered (10 per stream): about 15 more minutes (not measured)
    default  the full run every 0.25 s at 320x240, every frame rendered (not measured)

Only chains stage ``run()`` calls; re-running is cheap (every cached action returns at once).
``--out DIR`` also writes every table there as Markdown (``<table>.md``) plus ``tables.md``, and with
``--recording`` ``recording-<table>.md`` / ``twin-<table>.md`` and their ``artifacts.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.errors import NsimError  # noqa: E402
from nsim.stages import (  # noqa: E402
    capture,
    evaluate,
    import_log,
    reconstruct,
    register_log,
    render,
    simulate,
    train_human,
    train_scene,
)
from nsim.synth.room import ROOM_PRESETS  # noqa: E402
from nsim.workspace.store import Store, default_root  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROOMS = tuple(ROOM_PRESETS)
EXPECTED_MIN = {"tiny": 6, "small": 10, "default": 150}
EXPECTED_RECORDING_MIN = {"tiny": 10, "small": 15, "default": 120}
CAMERAS = "frontleft,frontright,left,right,back"  # Spot's five body cameras (nsim/configs/robots/spot.yaml)

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


# The --recording path, per size: the realistic robot log of the paper's Spot run (nsim capture robot-log: Spot's
# five cameras at half size, 320x240, which SIFT needs to localise them, their depth and the LiDAR), the map the
# log is registered in ("map": a capture reconstructed by pycolmap and made metric by its ground-truth
# trajectory; None: robot-lab's own poses, reconstructed at that size already), the render of the recorded
# streams ("render": every k-th recorded frame per stream; tiny: three per stream, about 10 s a 320x240 frame on
# 2 loaded cores), and a twin render of the same sensors at the same
# ticks from the true trajectory (trajectory mode, no people: the log has none), scored against the oracle, so
# that the two tables differ only by the log's faults and the registration.
RECORDING: dict[str, dict[str, tuple[str, list[str]] | None]] = {
    "tiny": {
        "robot_log": ("tiny", ["image_scale=0.5", "tick_stride=4", "max_ticks=20"]),
        "map_capture": ("tiny", ["width=200", "height=150", "n_frames=100", "supersample=1", "video=false"]),
        "map_reconstruct": ("tiny", ["frames=100"]),
        "import_log": ("default", []),
        "register_log": ("tiny", []),
        "render": ("tiny", ["image_scale=1.0", "lidar_azimuth_scale=1.0", "tick_stride=7", "max_frames=null"]),
        "evaluate": ("tiny", []),
        "evaluate_detection": ("tiny", ["detection.hog_upscale=2.0"]),
    },
    "small": {
        "robot_log": ("tiny", ["image_scale=0.5", "tick_stride=4", "max_ticks=0"]),
        "map_capture": ("tiny", ["width=200", "height=150", "n_frames=100", "supersample=1", "video=false"]),
        "map_reconstruct": ("tiny", ["frames=100"]),
        "import_log": ("default", []),
        "register_log": ("tiny", ["frames_per_camera=10"]),
        "render": ("tiny", ["image_scale=1.0", "lidar_azimuth_scale=1.0", "tick_stride=3", "max_frames=null"]),
        "evaluate": ("default", ["slam.max_features=2048", "slam.matcher=exhaustive"]),
        "evaluate_detection": ("default", ["detection.hog_upscale=2.0"]),
    },
    "default": {
        "robot_log": ("default", ["image_scale=0.5", "lidar_azimuth_scale=0.25", "tick_stride=5"]),
        "map_capture": None,
        "map_reconstruct": None,
        "import_log": ("default", []),
        "register_log": ("default", []),
        "render": ("cpu", ["image_scale=1.0", "lidar_azimuth_scale=1.0", "tick_stride=1", "max_frames=null",
                           "video=false"]),
        "evaluate": ("default", []),
        "evaluate_detection": ("default", ["detection.hog_upscale=2.0"]),
    },
}
RECORDING_TABLES = ("spot-rgb", "spot-depth", "lidar", "slam", "detection")

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


class SpotRun(NamedTuple):
    """What the oracle tables were computed from: the Spot run's trajectory and robot-lab's capture, poses and scene."""

    trajectory: str
    capture: str
    poses: str
    scene: str


def check_arguments(ctx: RunContext, out_dir: Path | None, request: RecordingRequest | None = None) -> None:
    """What the arguments alone decide, before the first stage: ``--out`` a folder (or not there yet), and for
    ``--recording LOG`` the log there (import-log's own input checks) and ``--poses`` / ``--scene`` artifacts of the
    right kinds. One-line NsimError otherwise."""
    if out_dir is not None and out_dir.exists() and not out_dir.is_dir():
        raise NsimError(f"--out {out_dir}: exists and is not a folder")
    if request is None:
        return
    if request.log is not None:
        import_log.Inputs(log=(request.log,)).validate()
    for option, spec, kind in (("--poses", request.poses, "poses"), ("--scene", request.scene, "scene-checkpoint")):
        if spec is not None and (actual := ctx.store.get(ctx.store.resolve(spec)).kind) != kind:
            raise NsimError(f"{option} {spec}: a {actual} artifact; expected a {kind} artifact")


def run_paper(workspace: Path, size: str, seed: int, device: str, out_dir: Path | None) -> dict:
    """The five oracle tables (``{name: Table}``), and with ``--out`` their Markdown."""
    ctx = RunContext(store=Store(workspace), device_spec=device, seed=seed)
    check_arguments(ctx, out_dir)
    tables, _ = paper_tables(ctx, size)
    if out_dir is not None:
        write_tables(ctx, tables, out_dir, "paper")
    return tables


def simulate_spot_run(ctx: RunContext, size: str) -> str:
    """The Spot run (nsim/configs/scenarios/spot_run.json in robot-lab); its trajectory id."""
    sim_cfg = cfg_of(simulate.Config, "simulate", size, "simulate")
    scenario = simulate.load_scenario(REPO / "nsim" / "configs" / "scenarios" / "spot_run.json", store=ctx.store)
    traj = step("simulate (spot_run)", lambda: simulate.run(simulate.Inputs(scenario), sim_cfg, ctx)).trajectory
    ctx.store.set_ref("trajectory/paper-spot-run", traj)
    return traj


def spot_run(ctx: RunContext, size: str) -> SpotRun:
    """Only what the --recording path needs of the oracle pipeline: robot-lab's scene and the Spot run."""
    cap, scene, _ = scene_of_room(ctx, "robot-lab", size)
    poses = ctx.store.resolve("poses/paper-robot-lab") if SIZES[size]["reconstruct"] else cap
    return SpotRun(trajectory=simulate_spot_run(ctx, size), capture=cap, poses=poses, scene=scene)


def paper_tables(ctx: RunContext, size: str) -> tuple[dict, SpotRun]:
    """The oracle pipeline (module docstring): the five tables and the Spot run they score."""
    heldout, scenes, run = [], {}, {}
    for room in ROOMS:
        cap, scene, held = scene_of_room(ctx, room, size)
        heldout.append(held)
        scenes[room] = scene
        if room == "robot-lab":
            run = {"capture": cap, "scene": scene,
                   "poses": ctx.store.resolve("poses/paper-robot-lab") if SIZES[size]["reconstruct"] else cap}

    # Spot's run in robot-lab (the scenario's room), rendered in robot-lab's trained scene with the
    # scenario's people, each drawn by a human checkpoint trained on an actor capture of robot-lab.
    traj = simulate_spot_run(ctx, size)
    human = human_of_room(ctx, "robot-lab", size)
    spot_cfg = cfg_of(render.Config, "render", size, "spot")
    spot_inputs = render.Inputs(trajectory=traj, scene=scenes["robot-lab"], rig=REPO / "nsim" / "configs" / "robots" / "spot.yaml",
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
    return tables, SpotRun(trajectory=traj, **run)


def write_tables(ctx: RunContext, tables: dict, out_dir: Path, prefix: str, stem: str = "") -> None:
    """``<stem><table>.md`` per table, ``<stem>tables.md`` and ``<stem>artifacts.json`` (the evaluation ids, by
    their refs ``evaluation/<prefix>-<table>``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, table in tables.items():
        (out_dir / f"{stem}{name}.md").write_text(table.to_markdown())
    (out_dir / f"{stem}tables.md").write_text("\n".join(t.to_markdown() for t in tables.values()))
    (out_dir / f"{stem}artifacts.json").write_text(json.dumps(
        {name: ctx.store.resolve(f"evaluation/{prefix}-{name}") for name in tables}, indent=1) + "\n")


# ---------------------------------------------------------------------------------------------- --recording
class RecordingRequest(NamedTuple):
    """``--recording [LOG]``: log, a ROS bag or a recording folder (None: write the realistic robot log of the
    paper's Spot run); poses: the map to register it in, a metric poses artifact with a sparse model; scene: the
    scene checkpoint to render it in (None: the test room's robot-lab ones of this size)."""

    log: Path | None = None
    poses: str | None = None
    scene: str | None = None


class RecordingRun(NamedTuple):
    """The --recording path's results: the log and its truth (``<log>.truth.json``, None without one), the
    artifacts, the tables against the recording, the twin tables against the oracle (empty for a log not written
    here), registration.json, and the registration's error against the truth (None without one)."""

    log: Path
    truth: dict[str, Any] | None
    recording: str
    registration: str
    render: str
    twin: str | None
    tables: dict
    oracle: dict
    registration_doc: dict[str, Any]
    error: dict[str, float] | None


def rec_cfg(cls, stage: str, size: str, key: str, extra: list[str] = ()):
    preset, overrides = RECORDING[size][key]
    return load_config(cls, stage=stage, preset=preset, overrides=[*overrides, *extra])


def robot_log_of_run(ctx: RunContext, size: str, trajectory: str) -> Path:
    """The realistic robot log of ``trajectory`` (``nsim capture robot-log``), written once under the workspace's
    ``robot_logs/``, named by a digest of the trajectory, the log's config, the rig and the seed."""
    import hashlib
    import shutil

    from nsim.config import to_dict
    from nsim.synth.faulty_robot_log import TRUTH_VERSION, truth_path

    cfg = rec_cfg(capture.RobotLogConfig, "robot_log", size, "robot_log")
    rig = REPO / "nsim" / "configs" / "robots" / "spot.yaml"
    digest = hashlib.sha256(json.dumps({"trajectory": trajectory, "config": to_dict(cfg), "seed": ctx.seed,
                                        "rig": hashlib.sha256(rig.read_bytes()).hexdigest(),
                                        "truth_version": TRUTH_VERSION}, sort_keys=True).encode()).hexdigest()
    bag = Path(ctx.store.root) / "robot_logs" / f"paper-{digest[:16]}"
    if not truth_path(bag).is_file():  # the truth is written last: without it the bag is incomplete
        if bag.exists():
            shutil.rmtree(bag)
        bag.parent.mkdir(parents=True, exist_ok=True)
        step("capture robot-log (spot run)", lambda: capture.robot_log(trajectory, rig, bag, cfg, ctx))
    return bag


def registration_map(ctx: RunContext, size: str, spot: SpotRun) -> str:
    """The poses artifact the log is registered in: robot-lab's own (reconstructed at this size), or a capture
    large enough for SIFT reconstructed and made metric by its ground-truth trajectory (``tiny``)."""
    if RECORDING[size]["map_capture"] is None:
        return spot.poses
    cap_cfg = rec_cfg(capture.Config, "capture", size, "map_capture", ["room=robot-lab"])
    cap = step("capture synth (map, robot-lab)", lambda: capture.run(capture.Inputs(), cap_cfg, ctx)).capture
    ctx.store.set_ref("capture/paper-map-robot-lab", cap)
    rc_cfg = rec_cfg(reconstruct.Config, "reconstruct", size, "map_reconstruct")
    rc_inputs = reconstruct.Inputs(capture=cap, reference=ctx.store.get(cap).file("gt_trajectory.tum"))
    poses = step("reconstruct (map, robot-lab)", lambda: reconstruct.run(rc_inputs, rc_cfg, ctx)).poses
    ctx.store.set_ref("poses/paper-map-robot-lab", poses)
    return poses


def registration_error(doc: dict[str, Any], truth: dict[str, Any]) -> dict[str, float]:
    """The registration's odometry frame and clock offset against the log's truth: position (m), rotation (deg),
    clock (s, absolute)."""
    import numpy as np

    from nsim.geometry.transforms import rotation_angle_deg

    got, want = np.asarray(doc["odom_to_world"], dtype=float), np.asarray(truth["odom_to_world"], dtype=float)
    return {"position_m": float(np.linalg.norm(got[:3, 3] - want[:3, 3])),
            "rotation_deg": float(rotation_angle_deg(got[:3, :3], want[:3, :3])),
            "clock_s": abs(float(doc["clock_offset_s"]) - float(truth["clock_offset_s"]))}


#: Spot's LiDAR (nsim/configs/robots/spot.yaml): the twin renders it as the log recorded it (its azimuth scale)
TWIN_LIDAR = "lidar"


def twin_overrides(size: str, truth: dict[str, Any]) -> list[str]:
    """Render overrides of the twin: the sensors the recording render draws (the LiDAR at the log's azimuth scale),
    at the log's size, at the ticks of its frames (every ``render.tick_stride``-th of the log's ticks, which are
    every ``robot_log.tick_stride``-th)."""
    log_cfg = rec_cfg(capture.RobotLogConfig, "robot_log", size, "robot_log")
    ren_cfg = rec_cfg(render.Config, "render", size, "render")
    ticks = math.ceil(len(truth["stamps_s"]) / ren_cfg.tick_stride)
    if ren_cfg.max_frames is not None:
        ticks = min(ticks, ren_cfg.max_frames)
    picked = [w.split("/", 1)[-1] for w in ren_cfg.sensors]  # <kind>/<name> or <name>; empty: every stream
    sensors = [c for c in (*CAMERAS.split(","), TWIN_LIDAR) if not picked or c in picked]
    return [f"sensors=[{','.join(sensors)}]", f"image_scale={log_cfg.image_scale}",
            f"lidar_azimuth_scale={log_cfg.lidar_azimuth_scale}", "start=0",
            f"tick_stride={log_cfg.tick_stride * ren_cfg.tick_stride}", f"max_frames={ticks}", "video=false"]


def run_recording(ctx: RunContext, size: str, request: RecordingRequest, spot: SpotRun | None,
                  out_dir: Path | None = None) -> RecordingRun:
    """import-log -> register-log -> render --recording -> evaluate (the five tables) of ``request``'s log, or of the
    realistic log of ``spot``'s run written here (then also the twin render and its oracle tables)."""
    from nsim.synth.faulty_robot_log import truth_path

    store = ctx.store
    if request.log is None and spot is None:
        raise NsimError("--recording: without a log, the log is written from the paper's Spot run")
    if spot is None and (request.poses is None or request.scene is None):
        raise NsimError("--recording: give --poses and --scene, or run the test room's pipeline for them")
    bag = Path(request.log) if request.log is not None else robot_log_of_run(ctx, size, spot.trajectory)
    truth = json.loads(truth_path(bag).read_text()) if truth_path(bag).is_file() else None

    il_cfg = rec_cfg(import_log.Config, "import_log", size, "import_log")
    rec = step("import-log", lambda: import_log.run(import_log.Inputs(log=(bag,)), il_cfg, ctx)).recording
    store.set_ref("recording/paper-robot-log", rec)

    poses = request.poses or registration_map(ctx, size, spot)
    rl_cfg = rec_cfg(register_log.Config, "register_log", size, "register_log")
    rl_inputs = register_log.Inputs(recording=rec, poses=poses)
    reg = step("register-log", lambda: register_log.run(rl_inputs, rl_cfg, ctx)).registration
    store.set_ref("registration/paper-robot-log", reg)
    doc = json.loads(store.get(reg).file("registration.json").read_text())
    error = registration_error(doc, truth) if truth is not None else None
    scene = request.scene or spot.scene

    ren_cfg = rec_cfg(render.Config, "render", size, "render")
    ren_inputs = render.Inputs(registration=reg, scene=scene)
    ren = step("render --recording", lambda: render.run(ren_inputs, ren_cfg, ctx)).render
    store.set_ref("render/paper-recording", ren)

    twin = None
    if request.log is None:  # the log is the Spot run's: the same sensors at the same ticks against the oracle
        tw_cfg = rec_cfg(render.Config, "render", size, "render", twin_overrides(size, truth))
        tw_inputs = render.Inputs(trajectory=spot.trajectory, scene=scene, rig=REPO / "nsim" / "configs" / "robots" / "spot.yaml",
                                  people=False)  # the log's twin: its sensors alone, as the oracle's log has them
        twin = step("render (twin of the log, oracle)", lambda: render.run(tw_inputs, tw_cfg, ctx)).render
        store.set_ref("render/paper-recording-twin", twin)

    tables, oracle = {}, {}
    for table in RECORDING_TABLES:
        key = "evaluate_detection" if table == "detection" else "evaluate"
        ev_cfg = rec_cfg(evaluate.Config, "evaluate", size, key, [f"table={table}"])
        for side, render_id, into in (("recording", ren, tables), ("twin", twin, oracle)):
            if render_id is None:
                continue
            ev_inputs = evaluate.Inputs(renders=(render_id,))
            out = step(f"evaluate --table {table} ({side})", lambda c=ev_cfg, i=ev_inputs: evaluate.run(i, c, ctx))
            store.set_ref(f"evaluation/paper-{side}-{table}", out.evaluation)
            into[table] = evaluate.load_table(ctx, out.evaluation)
    if out_dir is not None:
        write_tables(ctx, tables, out_dir, "paper-recording", "recording-")
        if oracle:
            write_tables(ctx, oracle, out_dir, "paper-twin", "twin-")
    return RecordingRun(bag, truth, rec, reg, ren, twin, tables, oracle, doc, error)


def _mean(table, column: str, rows: str = "body") -> float | None:
    """Mean of a column's finite numbers over the table's body rows (None: none)."""
    body = table.rows[: len(table.rows) - table.footer_rows] if rows == "body" else table.rows
    vals = [float(v) for r in body if isinstance(v := r.get(column), (int, float)) and not isinstance(v, bool)
            and math.isfinite(float(v))]
    return sum(vals) / len(vals) if vals else None


#: (table, metric shown, column of the oracle table, column of the recording's table)
AGREEMENT = (
    ("spot-rgb", "PSNR [dB]", "PSNR", "PSNR"),
    ("spot-rgb", "PSNR [dB], recording colour-corrected", "PSNR", "PSNR cc"),
    ("spot-rgb", "SSIM", "SSIM", "SSIM"),
    ("spot-rgb", "LPIPS", "LPIPS", "LPIPS"),
    ("spot-depth", "AbsRel", "AbsRel", "AbsRel"),
    ("spot-depth", "RMSE [m]", "RMSE [m]", "RMSE [m]"),
    ("spot-depth", "δ<1.25", "δ<1.25", "δ<1.25"),
    ("lidar", "range err median [m]", "range err median [m]", "range err median [m]"),
    ("lidar", "Chamfer [m]", "Chamfer [m]", "Chamfer [m]"),
    ("lidar", "hit agreement", "hit agreement", "hit agreement"),
    ("slam", "ATE sim [m]", "ATE sim [m]", "ATE sim [m]"),
    ("slam", "ATE real [m] (oracle: its frames)", "ATE real [m]", "ATE real [m]"),
    ("detection", "boxes sim", "boxes sim", "boxes sim"),
    ("detection", "boxes real (oracle: its frames)", "boxes real", "boxes real"),
)


#: How far the tables against the recording may be from the twin's against the oracle, per (table, metric):
#: ``("abs", x)``: |recording - oracle| <= x; ``("rel", x)``: <= x * |oracle|; ``("rel+abs", x, floor)``:
#: <= x * |oracle| + floor. The log's faults (noise, exposure, JPEG, depth holes and minimum range, LiDAR dropout
#: and range noise, odometry drift, the clock offset) and the registration are all that separates the two sides.
#: Raw PSNR (the colour-corrected one is meant to differ: it corrects the recording's exposure); depth AbsRel: the
#: two sides score different pixels (the recording's holes and minimum range), which moves AbsRel in proportion to
#: the scene's error (measured -22 % at --quick and -23 % at --size small on 30- and 300-step scenes), and the
#: recording's depth is noisy where the oracle's is exact, which adds up to the noise's own AbsRel whatever the
#: scene (|p - g - n| / g <= |p - g| / g + |n| / g): ``DEPTH_NOISE_ABSREL_FLOOR``, above the AbsRel of the log's
#: default depth noise (std 5 mm + 1 % of the depth) at the test room's depths, which is 0.014 on average and at
#: most 0.016 over Spot's 50 depth views along the room's walk loop (median depth 0.93 m; nearer walls raise it as
#: 5 mm / d; tests/synth/test_robot_log.py checks both stay below the floor). A scene as good as the default
#: size's (AbsRel 0.022 against the oracle) is otherwise held to a band narrower than the noise (measured +26 %).
#: The LiDAR's median range error and hit agreement (the log drops 2 % of the returns; -1.3 cm and -0.001 at
#: --quick); SLAM's ATE on the simulated frames (2.5 mm against the recording, 2.8 mm on the twin at --size
#: default). bench/robot_log.py prints them.
DEPTH_NOISE_ABSREL_FLOOR = 0.02
AGREEMENT_TOLERANCE = {
    ("spot-rgb", "PSNR [dB]"): ("abs", 1.0),
    ("spot-depth", "AbsRel"): ("rel+abs", 0.25, DEPTH_NOISE_ABSREL_FLOOR),
    ("lidar", "range err median [m]"): ("abs", 0.05),
    ("lidar", "hit agreement"): ("abs", 0.05),
    ("slam", "ATE sim [m]"): ("abs", 0.05),
}


def tolerance_bound(tol: tuple, oracle: float) -> float:
    """The largest |recording - oracle| a tolerance (``AGREEMENT_TOLERANCE``'s form) allows."""
    kind, x, *floor = tol
    if kind == "abs":
        return x
    if kind == "rel":
        return x * abs(oracle)
    if kind == "rel+abs":
        return x * abs(oracle) + floor[0]
    raise ValueError(f"unknown tolerance kind {kind!r}")


def agreement(oracle: dict, recording: dict) -> list[dict[str, Any]]:
    """Per table and metric: the mean over the table's rows against the oracle (the twin render) and against the
    recording, recording minus oracle (None where a side has no number), the tolerance on it
    (``AGREEMENT_TOLERANCE``: ``(kind, x[, floor])``, None: none stated) and whether the difference is within it
    (None: nothing to judge)."""
    out = []
    for table, metric, o_col, r_col in AGREEMENT:
        o = _mean(oracle[table], o_col) if o_col and table in oracle else None
        r = _mean(recording[table], r_col) if table in recording else None
        diff = r - o if o is not None and r is not None else None
        tol = AGREEMENT_TOLERANCE.get((table, metric))
        bound = None if tol is None or diff is None else tolerance_bound(tol, o)
        out.append({"table": table, "metric": metric, "oracle": o, "recording": r, "diff": diff, "tolerance": tol,
                    "within": None if bound is None else abs(diff) <= bound})
    return out


def agreement_text(rows: list[dict[str, Any]]) -> str:
    def cell(v):
        return "n/a" if v is None else f"{v:.4f}"

    def judged(r):
        if r["tolerance"] is None:
            return ""
        kind, x, *floor = r["tolerance"]
        verdict = {None: "n/a", True: "within", False: "OUTSIDE"}[r["within"]]
        text = "±" + format(x, "g") + (" x" if kind != "abs" else "") + (f"+{floor[0]:g}" if floor else "")
        return f"{text:>7} {verdict}"

    lines = [f"{'table':<11} {'metric':<40} {'sim vs oracle':>14} {'sim vs recording':>17} {'difference':>11} "
             f"{'tolerance':>9}"]
    lines += [f"{r['table']:<11} {r['metric']:<40} {cell(r['oracle']):>14} {cell(r['recording']):>17} "
              f"{cell(r['diff']):>11} {judged(r)}".rstrip() for r in rows]
    return "\n".join(lines) + "\n"


def registration_text(run: RecordingRun) -> str:
    doc = run.registration_doc
    res = doc.get("residual", {})
    loc = doc.get("localised", {})
    out = (f"registration {run.registration[:12]}: {loc.get('localised')} of {loc.get('tried')} frames localised, "
           f"residual median {res.get('median_m', float('nan')):.4f} m, clock offset {doc['clock_offset_s']:.4f} s")
    if run.error is not None:
        e = run.error
        out += (f"\nagainst the log's truth: odometry frame {e['position_m']:.4f} m, {e['rotation_deg']:.3f} deg; "
                f"clock offset {e['clock_s'] * 1e3:.1f} ms off")
    else:
        out += "\nno truth file beside the log (<log>.truth.json): the registration's error is unknown"
    return out + "\n"


def run_paper_recording(workspace: Path, size: str, seed: int, device: str, out_dir: Path | None,
                        request: RecordingRequest) -> tuple[dict, RecordingRun]:
    """The oracle tables (none when ``request`` names its own poses and scene: nothing of the test room is needed)
    and the --recording path."""
    ctx = RunContext(store=Store(workspace), device_spec=device, seed=seed)
    check_arguments(ctx, out_dir, request)
    tables, spot = {}, None
    if request.poses is None or request.scene is None or request.log is None:
        tables, spot = paper_tables(ctx, size)
        if out_dir is not None:
            write_tables(ctx, tables, out_dir, "paper")
    return tables, run_recording(ctx, size, request, spot, out_dir)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", choices=tuple(SIZES), default="small")
    ap.add_argument("--workspace", type=Path, default=default_root())
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables as Markdown here")
    ap.add_argument("--recording", nargs="?", const="", default=None, metavar="LOG",
                    help="also score the five tables against a robot's recording: LOG (a ROS bag or a recording "
                         "folder), or without LOG the realistic robot log of the paper's Spot run, written here")
    ap.add_argument("--poses", default=None, help="--recording LOG: the map to register LOG in (a metric poses "
                                                  "artifact with a sparse model; default: the test room's)")
    ap.add_argument("--scene", default=None, help="--recording LOG: the scene checkpoint to render LOG in (default: "
                                                  "the test room's robot-lab scene)")
    args = ap.parse_args()
    if (args.poses or args.scene) and not args.recording:
        ap.error("--poses / --scene go with --recording LOG")
    print(f"[paper] size {args.size}: expected about {EXPECTED_MIN[args.size]} min on 2 CPU cores "
          f"(less where the run cache has the steps)" + (f", plus about {EXPECTED_RECORDING_MIN[args.size]} min for "
                                                         "--recording" if args.recording is not None else ""),
          flush=True)
    t0 = time.perf_counter()
    run = None
    try:
        if args.recording is None:
            tables = run_paper(args.workspace, args.size, args.seed, args.device, args.out)
        else:
            request = RecordingRequest(log=Path(args.recording) if args.recording else None, poses=args.poses,
                                       scene=args.scene)
            tables, run = run_paper_recording(args.workspace, args.size, args.seed, args.device, args.out, request)
    except NsimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for table in tables.values():
        print()
        print(table.to_text(), end="")
    if run is not None:
        print(f"\n[paper] against the recording {run.log} (recording {run.recording[:12]}, render {run.render[:12]}):")
        for table in run.tables.values():
            print()
            print(table.to_text(), end="")
        print()
        print(registration_text(run), end="")
        if run.oracle:
            print("\n[paper] the same sensors at the same ticks, simulated vs the oracle and vs the recording (means "
                  f"over the cameras; twin render {run.twin[:12]}):")
            print(agreement_text(agreement(run.oracle, run.tables)), end="")
    n = len(tables) + (len(run.tables) if run else 0)
    print(f"\n[paper] {n} tables in {time.perf_counter() - t0:.0f} s (size {args.size}, workspace {args.workspace})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
