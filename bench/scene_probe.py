"""One train-scene configuration on the test room: held-out PSNR and depth at chosen steps.

    python bench/scene_probe.py [--quick] [--capture default|160] [--preset cpu] [--steps N]
                                [--evals 700,1400] [--threads 1] [--set key=value ...] [--tag NAME]

The side-by-side probes behind the ``cpu`` preset (batch size, threads, proposal schedule,
learning rate, contraction, table size, random background) were runs of this script, two
1-thread runs at a time on the 2 cores. It trains ``SceneTrainer`` on the default capture
(320x240, 150 frames, ground-truth poses; ``--capture 160``: the same room at 160x120) and
scores 6 held-out views at each step in ``--evals``: PSNR, the mean training-batch PSNR of the
last 100 steps, median-depth AbsRel, and the training seconds so far (evaluation not counted).
``--render-check``: after the last step, also the held-out rays' accumulation (mean, and the
fraction above 0.99: how opaque the surfaces are) and the marching renderer's speed and
fidelity with the baked occupancy grid (``bench/train_scene.py``'s ``render_speed``).
``--quick``: the tiny capture, 60 steps. Prints a line per evaluation and one JSON object last.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from train_scene import make_capture, render_speed  # noqa: E402  (bench/train_scene.py: the same capture)

from nsim.config import load_config  # noqa: E402
from nsim.train.loop import torch_threads  # noqa: E402
from nsim.train.scene import SceneData, SceneTrainer  # noqa: E402
from nsim.train.scene_config import TrainSceneConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--capture", choices=("default", "160"), default="default")
    ap.add_argument("--preset", default=None, help="train_scene preset (default cpu; tiny with --quick)")
    ap.add_argument("--steps", type=int, default=None, help="training steps (default 1400; 60 with --quick)")
    ap.add_argument("--evals", default=None, help="comma-separated steps to score at (default: the last step)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], help="config override key=value (repeatable)")
    ap.add_argument("--tag", default="probe")
    ap.add_argument("--render-check", action="store_true", help="accumulation and grid marching after the last step")
    ap.add_argument("--workspace", type=Path, default=None, help="reuse the capture here (default: a temp dir)")
    args = ap.parse_args()
    steps = args.steps or (60 if args.quick else 1400)
    evals = sorted({int(x) for x in args.evals.split(",")}) if args.evals else [steps]
    preset = args.preset or ("tiny" if args.quick else "cpu")
    with tempfile.TemporaryDirectory() as tmp:
        size = ("width=160", "height=120") if args.capture == "160" else ()
        data = SceneData.load(make_capture(args.workspace or Path(tmp) / "ws", args.quick, size))
        cfg = load_config(TrainSceneConfig, stage="train_scene", preset=preset,
                          overrides=[f"optim.steps={steps}", f"optim.num_threads={args.threads}", *args.set])
        trainer = SceneTrainer(data, cfg, device="cpu", seed=0)
        views = trainer.eval_ids[:: max(1, len(trainer.eval_ids) // 6)][:6].tolist()
        batch_psnr: list[float] = []
        out: dict = {"tag": args.tag, "capture": args.capture, "preset": preset, "set": args.set, "evals": {}}
        with torch_threads(trainer.loop_threads()):  # the thread count the training loop holds
            for _ in range(steps):
                batch_psnr.append(trainer.train_step().psnr)
                if trainer.step in evals:
                    ev = trainer.evaluate(views)["mean"]
                    row = {"heldout_psnr": round(ev["psnr"], 2), "train_batch_psnr_last100": round(float(np.mean(batch_psnr[-100:])), 2),
                           "abs_rel_median": round(ev.get("abs_rel_median", float("nan")), 3),
                           "train_seconds": round(trainer.train_seconds, 1)}
                    out["evals"][trainer.step] = row
                    print(f"{args.tag} step {trainer.step}: {row}", flush=True)
            if args.render_check:
                out["render"] = render_check(trainer, data, views)
                print(f"{args.tag} render: {out['render']}", flush=True)
    print(json.dumps(out))


def render_check(trainer: SceneTrainer, data: SceneData, views: list[int]) -> dict:
    import time

    import torch

    from nsim.rendering.renderer import camera_rays, render_rays
    from nsim.train.scene_export import bake_occupancy

    model = trainer.model.eval()
    rays = [camera_rays(model, data.cameras[0], data.cam_to_world[v])[0] for v in views]
    g = torch.Generator().manual_seed(0)
    acc = torch.cat([render_rays(model, r[torch.randperm(len(r), generator=g)[:500]], "proposal").accumulation
                     for r in rays])
    t0 = time.perf_counter()
    grid = bake_occupancy(trainer)
    bake_s = time.perf_counter() - t0
    speed = render_speed(model, grid, data, views[len(views) // 2], 1500 if len(data.names) > 40 else 300, 0.01)
    return {"acc_mean": round(float(acc.mean()), 4), "acc_above_0.99": round(float((acc > 0.99).float().mean()), 4),
            "occupied_fraction": round(grid.occupied_fraction, 4), "bake_s": round(bake_s, 1),
            **{k: round(v, 2) for k, v in speed.items()}}


if __name__ == "__main__":
    main()
