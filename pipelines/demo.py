"""The main job end to end on the built-in test room; ends with ``nsim verify``, ``nsim gc --dry-run``, ``nsim ls``.

    python pipelines/demo.py [--workspace DIR] [--preset default|tiny] [--seed N]

Only chains stage ``run()`` calls; each later stage joins here when it lands. Re-running is
cheap: every stage whose action is in the run cache returns at once.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.cli import main as nsim_main  # noqa: E402
from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.errors import NsimError  # noqa: E402
from nsim.stages import (  # noqa: E402
    bake,
    capture,
    evaluate,
    export,
    import_log,
    reconstruct,
    render,
    simulate,
    train_human,
    train_scene,
)
from nsim.workspace.store import Store, default_root  # noqa: E402

STEP_SECONDS: dict[str, float] = {}
"""Each step's wall time by name, as printed (0 s-ish when its stage's action is in the run cache)."""


def step(name: str, fn):
    t0 = time.perf_counter()
    out = fn()
    STEP_SECONDS[name] = time.perf_counter() - t0
    print(f"[demo] {name:<28} {STEP_SECONDS[name]:7.1f} s", flush=True)
    return out


def run_demo(workspace: Path, preset: str, seed: int, device: str) -> None:
    ctx = RunContext(store=Store(workspace), device_spec=device, seed=seed)
    tiny = preset == "tiny"
    captures = {}
    for camera in ("pinhole", "fisheye"):
        overrides = [f"camera={camera}"]
        if tiny and camera == "pinhole":
            # SIFT cannot chain 40 frames at 96x72: the tiny demo reconstructs 100 frames at 160x120
            overrides += ["n_frames=100", "width=160", "height=120"]
        cfg = load_config(capture.Config, stage="capture", preset=preset, overrides=overrides)
        out = step(f"capture synth ({camera})", lambda cfg=cfg: capture.run(capture.Inputs(), cfg, ctx))
        ctx.store.set_ref(f"capture/demo-{camera}", out.capture)
        captures[camera] = out.capture

    # Poses from the pinhole capture's frames, made metric by its ground-truth trajectory as a
    # robot's odometry would be (a TUM file matched by timestamp).
    cap = ctx.store.get(captures["pinhole"])
    rec_cfg = load_config(reconstruct.Config, stage="reconstruct", preset=preset,
                          overrides=[f"frames={cap.manifest['config']['n_frames']}"])
    rec_inputs = reconstruct.Inputs(capture=cap.id, reference=cap.file("gt_trajectory.tum"))
    out = step("reconstruct (pinhole)", lambda: reconstruct.run(rec_inputs, rec_cfg, ctx))
    ctx.store.set_ref("poses/demo", out.poses)
    poses_id = out.poses

    # The scene NeRF on those poses (the tiny demo trains a few hundred steps: it checks the path).
    ts_overrides = ["optim.steps=300"] if tiny else []
    ts_cfg = load_config(train_scene.Config, stage="train_scene", preset=preset, overrides=ts_overrides)
    ts_inputs = train_scene.Inputs(poses=out.poses)
    out = step("train-scene", lambda: train_scene.run(ts_inputs, ts_cfg, ctx))
    ctx.store.set_ref("scene/demo", out.scene)
    scene_id = out.scene

    # What users take elsewhere: a coloured point cloud and mesh (PLY, GLB) in the scene's metric
    # frame; the scene checkpoint itself carries the walkable map (free/occupied/unknown, nav2 map.yaml).
    ex_cfg = load_config(export.Config, stage="export", preset=preset)
    ex = step("export (mesh, point cloud)", lambda: export.run(export.Inputs(scene=scene_id), ex_cfg, ctx))
    ctx.store.set_ref("export/demo", ex.export)
    for rel in ("points.ply", "mesh.ply", "mesh.glb", "preview.png"):
        print(f"[demo]   {ctx.store.get(ex.export).path / rel}", flush=True)
    for rel in ("map.yaml", "map.pgm", "obstacle_cells.png"):
        if (ctx.store.get(scene_id).path / rel).is_file():
            print(f"[demo]   {ctx.store.get(scene_id).path / rel}", flush=True)

    repo = Path(__file__).resolve().parents[1]
    sim_cfg = load_config(simulate.Config, stage="simulate", preset=preset)
    scenario = simulate.load_scenario(repo / "nsim" / "configs" / "scenarios" / "spot_run.json", store=ctx.store)
    out = step("simulate (spot_run)", lambda: simulate.run(simulate.Inputs(scenario), sim_cfg, ctx))
    ctx.store.set_ref("trajectory/demo-spot-run", out.trajectory)

    traj_id = out.trajectory

    # A robot's recording: Spot's sensors along the run as the test room's oracle sees them, with a
    # real robot's faults (noise, auto-exposure, JPEG, depth holes, LiDAR dropout, odometry drift, a
    # camera clock offset, an odometry frame offset), written as a ROS 2 bag and imported back.
    bag = Path(ctx.store.root) / "robot_logs" / f"spot_run-{traj_id[:12]}"
    if not bag.exists():
        bag.parent.mkdir(exist_ok=True)
        rl_cfg = load_config(capture.RobotLogConfig, stage="robot_log", preset="tiny")
        step("capture robot-log", lambda: capture.robot_log(traj_id, repo / "nsim" / "configs" / "robots" / "spot.yaml",
                                                              bag, rl_cfg, ctx))
    il_cfg = load_config(import_log.Config, stage="import_log", preset="default")
    rec = step("import-log (ROS 2 bag)", lambda: import_log.run(import_log.Inputs(log=(bag,)), il_cfg, ctx))
    ctx.store.set_ref("recording/demo-spot-run", rec.recording)
    print(f"[demo]   {ctx.store.get(rec.recording).path / 'preview.png'}", flush=True)

    # The people: an actor walking the room, filmed by a handheld camera, and the human NeRF
    # trained on it (a small capture: the demo shows the path; `make paper` has the larger one).
    actor = ["actor=true", "supersample=1", "video=false"] + ([] if tiny else ["width=160", "height=120", "n_frames=60"])
    act_cfg = load_config(capture.Config, stage="capture", preset="tiny", overrides=actor)
    act = step("capture synth --actor", lambda: capture.run(capture.Inputs(), act_cfg, ctx)).capture
    ctx.store.set_ref("capture/demo-actor", act)
    th_cfg = load_config(train_human.Config, stage="train_human", preset="tiny",
                         overrides=[] if tiny else ["optim.steps=600", "optim.num_threads=2"])
    human = step("train-human", lambda: train_human.run(train_human.Inputs(capture=act), th_cfg, ctx)).human
    ctx.store.set_ref("human/demo", human)
    ctx.store.set_ref("human/ana", human)  # the look spot_run.json names for its first person

    # Spot's five fisheye cameras (with depth) and its LiDAR along the run, in the trained scene, with the
    # scenario's people: ana drawn by the human NeRF (her scenario entry names human/ana), the four others,
    # whose looks this workspace lacks, with the default look (a warning line says so).
    ren_preset = "tiny" if tiny else "cpu"
    ren_cfg = load_config(render.Config, stage="render", preset=ren_preset)
    ren_inputs = render.Inputs(trajectory=traj_id, scene=scene_id, rig=repo / "nsim" / "configs" / "robots" / "spot.yaml")
    spot = step("render (spot rig, people)", lambda: render.run(ren_inputs, ren_cfg, ctx)).render
    ctx.store.set_ref("render/demo-spot-run", spot)

    # The scene's held-out capture frames, rendered at their own cameras (a few of them).
    held_cfg = load_config(render.Config, stage="render", preset=ren_preset,
                           overrides=["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=4"])
    held = step("render (held-out frames)", lambda: render.run(render.Inputs(poses=poses_id, scene=scene_id), held_cfg, ctx))
    ctx.store.set_ref("render/demo-heldout", held.render)

    # The scene baked (nsim bake): its density on a 10 cm lattice meshed, the mesh fitted to the NeRF's median
    # depths and textured from the training images (nsim/configs/bake/tiny.yaml: the default preset's surface, small),
    # and the same held-out frames rendered from it (--set method=baked).
    bake_cfg = load_config(bake.Config, stage="bake", preset="tiny")
    baked = step("bake (a surface fitted to the NeRF, 10 cm lattice)",
                 lambda: bake.run(bake.Inputs(scene=scene_id), bake_cfg, ctx)).baked
    ctx.store.set_ref("baked/demo", baked)
    hb_cfg = load_config(render.Config, stage="render", preset=ren_preset,
                         overrides=["frames=heldout", "tick_stride=1", "image_scale=1.0", "max_frames=4", "method=baked"])
    held_baked = step("render (held-out frames, baked scene)",
                      lambda: render.run(render.Inputs(poses=poses_id, scene=scene_id, baked=baked), hb_cfg, ctx))
    ctx.store.set_ref("render/demo-heldout-baked", held_baked.render)
    print(f"[demo]   {ctx.store.get(held_baked.render).path / 'preview' / 'contact_sheet.png'}", flush=True)
    # Spot's run again, the same people, from the baked scene (camera rays that miss its surface from the NeRF):
    # the render step's time beside the NeRF's above.
    sb_cfg = load_config(render.Config, stage="render", preset=ren_preset, overrides=["method=baked"])
    spot_baked = step("render (spot rig, baked scene)",
                      lambda: render.run(dataclasses.replace(ren_inputs, baked=baked), sb_cfg, ctx)).render
    nerf_s, baked_s = STEP_SECONDS["render (spot rig, people)"], STEP_SECONDS["render (spot rig, baked scene)"]
    ctx.store.set_ref("render/demo-spot-run-baked", spot_baked)
    print(f"[demo]   Spot's run rendered from the baked scene in {baked_s:.1f} s, from the NeRF in {nerf_s:.1f} s "
          f"(x{nerf_s / max(baked_s, 1e-9):.1f}; both 0 s when cached): {ctx.store.get(spot_baked).path}", flush=True)

    # How real it is: the paper's image and depth tables for these renders.
    for table, renders in (("scenes", (held.render,)), ("spot-rgb", (spot,)), ("spot-depth", (spot,))):
        ev_cfg = load_config(evaluate.Config, stage="evaluate", preset="tiny" if tiny else "default",
                             overrides=[f"table={table}"])
        ev = step(f"evaluate --table {table}", lambda c=ev_cfg, r=renders: evaluate.run(evaluate.Inputs(renders=r), c, ctx))
        ctx.store.set_ref(f"evaluation/demo-{table}", ev.evaluation)
        print(evaluate.load_table(ctx, ev.evaluation).to_markdown(), flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workspace", type=Path, default=default_root())
    ap.add_argument("--preset", default="default", help="stage presets to use (default, or tiny for a quick pass)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="auto")
    args = ap.parse_args()
    try:
        run_demo(args.workspace, args.preset, args.seed, args.device)
    except NsimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    # The workspace's own checks: every artifact re-hashed against its manifest, and what gc would
    # keep or remove (the grace period keeps a fresh demo whole).
    for cmd in (["verify"], ["gc", "--dry-run"], ["ls"]):
        print(f"[demo] nsim {' '.join(cmd)}", flush=True)
        code = nsim_main(["--workspace", str(args.workspace), *cmd])
        if code:
            return code
    return 0


if __name__ == "__main__":
    sys.exit(main())
