"""The human NeRF on the actor capture: held-out poses' PSNR in the person's box, mask IoU, wall time.

    python bench/train_human.py [--quick] [--workspace DIR] [--steps N] [--threads 2]

Full run: ``nsim capture synth --actor`` at the capture's default size, 320x240 with 150 frames
(``--width/--height`` for a smaller run; ground-truth poses; the
camera follows a person walking through robot-lab), then ``nsim train-human`` with the
``default`` preset over the capture's background images. ``--quick``: 96x72, 24 frames, the
``tiny`` preset with 100 steps. Frames ``i % holdout_every == 0`` are held out: new poses from
another part of the gait, seen from new viewpoints. Prints a table and one JSON object last.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.stages import capture, train_human  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workspace", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--width", type=int, default=None, help="capture width (default: the capture's 320; 96 quick)")
    ap.add_argument("--height", type=int, default=None, help="capture height (default: the capture's 240; 72 quick)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default 2, 1 with --quick)")
    args = ap.parse_args()
    q = args.quick
    threads = args.threads or (1 if q else 2)
    cap_over = ["actor=true", "video=false"] + (["width=96", "height=72", "n_frames=24"] if q else ["n_frames=150"])
    cap_over += [f"width={args.width}"] if args.width else []
    cap_over += [f"height={args.height}"] if args.height else []
    steps = args.steps or (100 if q else None)
    th_over = [f"optim.num_threads={threads}"] + ([f"optim.steps={steps}"] if steps else [])
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(args.workspace or Path(tmp) / "ws")
        ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
        t0 = time.perf_counter()
        cap_id = capture.run(capture.Inputs(), load_config(capture.Config, stage="capture", preset="default",
                                                           overrides=cap_over), ctx).capture
        cap_s = time.perf_counter() - t0
        cfg = load_config(train_human.Config, stage="train_human", preset="tiny" if q else "default", overrides=th_over)
        ctx = dataclasses.replace(ctx, force=True)
        t0 = time.perf_counter()
        out = train_human.run(train_human.Inputs(capture=cap_id), cfg, ctx)
        wall = time.perf_counter() - t0
        art = store.get(out.human)
        ev = json.loads(art.file("eval.json").read_text())
        timing = art.manifest.get("timing", {})
    m = ev["mean"]
    print(f"actor capture {cap_over[2:]} in {cap_s:.0f} s; train-human ({'tiny' if q else 'default'} preset, "
          f"{cfg.optim.steps} steps, {threads} threads) in {wall:.0f} s wall")
    print(f"{'view':>6} {'IoU':>6} {'PSNR box':>9} {'mean colour':>12} {'background':>11}")
    for v in ev["views"]:
        print(f"{v['frame']:6d} {v['mask_iou']:6.3f} {v.get('psnr_box', float('nan')):9.2f} "
              f"{v.get('psnr_box_baseline', float('nan')):12.2f} {v.get('psnr_box_background', float('nan')):11.2f}")
    print(f"{'mean':>6} {m['mask_iou']:6.3f} {m.get('psnr_box', float('nan')):9.2f} "
          f"{m.get('psnr_box_baseline', float('nan')):12.2f} {m.get('psnr_box_background', float('nan')):11.2f}")
    print(json.dumps({"quick": q, "steps": cfg.optim.steps, "threads": threads, "capture_seconds": round(cap_s, 1),
                      "train_wall_seconds": round(wall, 1), "heldout_views": len(ev["views"]), "mean": m,
                      "checkpoint_publish_timing": timing}))


if __name__ == "__main__":
    main()
