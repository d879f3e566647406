"""Milliseconds per train-scene step on the test room, and the share of the gradient sum and Adam in it.

    python bench/step_time.py [--quick] [--preset cpu] [--warmup 850] [--steps 100] [--set key=value ...]
                              [--heap | --no-heap]

Builds ``SceneTrainer`` on the default capture (320x240, ground-truth poses; ``--quick``: the tiny
capture and preset, few steps), runs ``--warmup`` steps (past the proposal warm-up, so that the
proposal fields are updated every ``proposal_update_every`` steps as in the steady state), then
times ``--steps`` steps with the trainer's own clock. Also timed inside those steps: the sum of the
batch parts' gradients (``optim.batch_threads``) and the optimiser step. ``--no-heap`` leaves
glibc's mmap for large blocks on (``nsim/train/heap.py`` is then not called): the before/after of
that change. Run it alone on the machine. Prints one line and one JSON object last.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from train_scene import make_capture  # noqa: E402  (bench/train_scene.py: the same capture)

from nsim.config import load_config  # noqa: E402
from nsim.train import heap  # noqa: E402
from nsim.train import scene as scene_mod  # noqa: E402
from nsim.train.loop import torch_threads  # noqa: E402
from nsim.train.scene import SceneData, SceneTrainer  # noqa: E402
from nsim.train.scene_config import TrainSceneConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--preset", default=None, help="train_scene preset (default cpu; tiny with --quick)")
    ap.add_argument("--warmup", type=int, default=None, help="untimed steps first (default 850; 5 with --quick)")
    ap.add_argument("--steps", type=int, default=None, help="timed steps (default 100; 10 with --quick)")
    ap.add_argument("--set", action="append", default=[], help="config override key=value (repeatable)")
    ap.add_argument("--no-heap", action="store_true", help="do not keep large blocks on the heap")
    ap.add_argument("--workspace", type=Path, default=None, help="reuse the capture here (default: a temp dir)")
    args = ap.parse_args()
    warmup = args.warmup if args.warmup is not None else (5 if args.quick else 850)
    steps = args.steps or (10 if args.quick else 100)
    preset = args.preset or ("tiny" if args.quick else "cpu")
    if args.no_heap:
        heap._state = False  # as if mallopt were unavailable: the trainer's call is then a no-op
    with tempfile.TemporaryDirectory() as tmp:
        data = SceneData.load(make_capture(args.workspace or Path(tmp) / "ws", args.quick))
        cfg = load_config(TrainSceneConfig, stage="train_scene", preset=preset,
                          overrides=[f"optim.steps={max(warmup + steps, 1)}", *args.set])
        trainer = SceneTrainer(data, cfg, device="cpu", seed=0)
        with torch_threads(trainer.loop_threads()):  # the thread count the training loop holds
            for _ in range(warmup):
                trainer.train_step()
            spent = {"sum_s": 0.0, "optimizer_s": 0.0}
            real_sum, real_step = scene_mod._sum_in_order, trainer.optimizer.step

            def timed_sum(tensors):
                t = time.perf_counter()
                out = real_sum(tensors)
                spent["sum_s"] += time.perf_counter() - t
                return out

            def timed_step(*a, **k):
                t = time.perf_counter()
                out = real_step(*a, **k)
                spent["optimizer_s"] += time.perf_counter() - t
                return out

            scene_mod._sum_in_order = timed_sum
            trainer.optimizer.step = timed_step
            start = trainer.train_seconds
            for _ in range(steps):
                trainer.train_step()
            total = trainer.train_seconds - start
    params = sum(p.numel() for g in trainer.optimizer.param_groups for p in g["params"])
    res = {"preset": preset, "set": args.set, "heap": not args.no_heap and heap.keep_large_blocks_on_heap(),
           "parameters": params, "timed_steps": steps, "step_ms": 1e3 * total / steps,
           "grad_sum_ms": 1e3 * spent["sum_s"] / steps, "optimizer_ms": 1e3 * spent["optimizer_s"] / steps}
    print(f"{preset} {' '.join(args.set)}: {res['step_ms']:.1f} ms a step (gradient sum {res['grad_sum_ms']:.1f} ms, "
          f"optimiser {res['optimizer_ms']:.1f} ms), {params} parameters, heap {res['heap']}")
    print(json.dumps(res))


if __name__ == "__main__":
    main()
