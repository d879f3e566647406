"""The main job end to end on the built-in test room; ends by printing ``nsim ls``.

    python pipelines/demo.py [--workspace DIR] [--preset default|tiny] [--seed N]

Only chains stage ``run()`` calls; each later stage joins here when it lands. Re-running is
cheap: every stage whose action is in the run cache returns at once.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.cli import main as nsim_main  # noqa: E402
from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.crowd.scenario import load_scenario  # noqa: E402
from nsim.errors import NsimError  # noqa: E402
from nsim.stages import capture, reconstruct, render, simulate, train_scene  # noqa: E402
from nsim.workspace.store import Store, default_root  # noqa: E402


def step(name: str, fn):
    t0 = time.perf_counter()
    out = fn()
    print(f"[demo] {name:<28} {time.perf_counter() - t0:7.1f} s", flush=True)
    return out


def run_demo(workspace: Path, preset: str, seed: int, device: str) -> None:
    ctx = RunContext(store=Store(workspace), device_spec=device, seed=seed)
    captures = {}
    for camera in ("pinhole", "fisheye"):
        overrides = [f"camera={camera}"]
        if preset == "tiny" and camera == "pinhole":
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

    # The scene NeRF on those poses (the tiny demo trains a few hundred steps: it checks the path).
    ts_overrides = ["optim.steps=300"] if preset == "tiny" else []
    ts_cfg = load_config(train_scene.Config, stage="train_scene", preset=preset, overrides=ts_overrides)
    ts_inputs = train_scene.Inputs(poses=out.poses)
    out = step("train-scene", lambda: train_scene.run(ts_inputs, ts_cfg, ctx))
    ctx.store.set_ref("scene/demo", out.scene)
    scene_id = out.scene

    repo = Path(__file__).resolve().parents[1]
    sim_cfg = load_config(simulate.Config, stage="simulate", preset=preset)
    scenario = load_scenario(repo / "configs" / "scenarios" / "spot_run.json", store=ctx.store)
    out = step("simulate (spot_run)", lambda: simulate.run(simulate.Inputs(scenario), sim_cfg, ctx))
    ctx.store.set_ref("trajectory/demo-spot-run", out.trajectory)

    # Spot's five fisheye cameras (with depth) and its LiDAR along the run, in the trained scene.
    ren_cfg = load_config(render.Config, stage="render", preset="tiny" if preset == "tiny" else "cpu")
    ren_inputs = render.Inputs(trajectory=out.trajectory, scene=scene_id, rig=repo / "configs" / "robots" / "spot.yaml")
    out = step("render (spot rig)", lambda: render.run(ren_inputs, ren_cfg, ctx))
    ctx.store.set_ref("render/demo-spot-run", out.render)


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
    return nsim_main(["--workspace", str(args.workspace), "ls"])


if __name__ == "__main__":
    sys.exit(main())
