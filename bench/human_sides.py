"""The human NeRF from the sides its video never saw: trained on a capture that films the walker from the front,
scored from its side and from behind.

    python bench/human_sides.py [--quick] [--steps N] [--threads 2] [--preset P] [--set KEY=VALUE ...]
        [--workspace DIR] [--out bench/out/human_sides.png]

Three captures of the same walk (``nsim capture synth --actor --set actor_view_deg=A``: the same path, poses and
actor for the same seed, the camera kept on one side of the person): A = 0 (in front, the person walks towards the
camera), 90 (its left) and 180 (behind). ``nsim train-human`` trains on the A = 0 capture (its own hold-out:
``psnr_box``, ``iou``, the held-out frames' scores from its ``eval.json``); the trained model is then rendered at
every frame of the A = 90 and A = 180 captures with their true poses, over their background images, and scored as
the training scores held-out views (``nsim.train.human.score_model``: PSNR in the person's box, mask IoU):
``psnr_box_side``, ``iou_side``, ``psnr_box_back``, ``iou_back``. A labelled picture (front / side / back: render
beside the truth, one frame) goes to ``--out``, the trained model's turntable (rest pose all round) beside it.

Full run: 320x240 captures of 150 frames (bench/train_human.py's size), the ``default`` preset;
``train_s_default`` is the train-human stage's wall time (training, the held-out fit, previews and scores), with
``train_loop_s`` the training steps' share and ``held_out_fit_s`` the fit's. ``--quick``: 128x96 captures of 30 frames,
the ``tiny`` preset (``train_s``). ``--set`` overrides the train-human preset (e.g. ``--set loss.symmetry_weight=0``).
Prints a table; the last line is one JSON object (keys above, ``peak_rss_gb``: the process's peak resident memory).

``--ratio N``: no training to the end; the preset and the default preset as it was before issue 45 (``OLD_DEFAULT``)
are timed side by side on the front capture, N steps of each training phase interleaved, in CPU seconds
(``speed_ratio``), and each one's stage time is estimated from its steps: keys ``old``, ``new``, ``ratio``. On a
busy machine this is the number to trust (wall times there measure the other work too).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.config import load_config  # noqa: E402
from nsim.context import RunContext  # noqa: E402
from nsim.stages import capture, train_human  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402

SIDES = {"front": 0.0, "side": 90.0, "back": 180.0}  # actor_view_deg of each capture; training sees the front
OLD_DEFAULT = [  # the default preset before issue 45, as overrides of today's (--ratio compares against it)
    "optim.steps=2000", "model.samples_per_ray=40", "model.sample_bone_radius_m=null", "model.blend_background_m=0.2",
    "refine.every=1", "refine.held_out_steps=400", "loss.cross_section_weight=0", "loss.unseen_colour_weight=0",
]


class _TrainTimes(logging.Handler):
    """The training loop's seconds (its last ``step`` log line) and the held-out fit's (``held_out_fit_s``)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.loop_s = float("nan")
        self.fit_s = 0.0

    def emit(self, record: logging.LogRecord) -> None:
        if hasattr(record, "held_out_fit_s"):
            self.fit_s = float(record.held_out_fit_s)
        elif isinstance(record.msg, str) and record.msg.startswith("step %d") and record.args:
            self.loop_s = float(record.args[-1])


def picture(path: Path, rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, float]], height_px: int = 240) -> Path:
    """``rows``: (label, render rgb (H, W, 3) float, truth uint8 (H, W, 3), truth mask (H, W), PSNR in the box) -> one
    labelled image, a row each: render beside truth, both cut to the person's box (grown by a quarter) and scaled to
    ``height_px``."""
    import cv2

    from nsim.io.images import to_uint8, write_image
    from nsim.io.labels import add_label
    from nsim.train.human import mask_box

    tiles = []
    for label, rgb, gt, mask, psnr_box in rows:
        v0, v1, u0, u1 = mask_box(mask)
        m = max(v1 - v0, u1 - u0) // 4
        v0, v1, u0, u1 = max(0, v0 - m), min(mask.shape[0], v1 + m), max(0, u0 - m), min(mask.shape[1], u1 + m)
        pair = np.concatenate([to_uint8(rgb)[v0:v1, u0:u1], gt[v0:v1, u0:u1]], axis=1)
        scale = height_px / pair.shape[0]
        pair = cv2.resize(pair, (max(1, round(pair.shape[1] * scale)), height_px), interpolation=cv2.INTER_NEAREST)
        tiles.append(add_label(pair, [f"{label}: render {psnr_box:.1f} dB", "truth"]))
    width = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0)), constant_values=255) for t in tiles]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, np.concatenate(tiles, axis=1 if width < 400 else 0))
    return path


def speed_ratio(data, cfg_old, cfg_new, steps: int, fit_steps: int) -> dict:
    """Side by side in one process, interleaved step by step: the CPU seconds (``time.process_time``: what the
    process itself used, so a busy machine's other work counts little; with one thread, the wall time of a quiet
    core) of a training step before refinement starts and after (means over ``steps`` steps, the first of each
    phase left out), of a held-out fit step and of one held-out frame's render, for the old and the new preset;
    and each preset's estimated stage time from them (its steps in each phase, its held-out fit steps, its held-out
    frames rendered once, twice with the fit). Returns both and new / old."""
    from nsim.train import loop
    from nsim.train.human import HumanTrainer

    def fitting(cfg):
        return dataclasses.replace(cfg, refine=dataclasses.replace(cfg.refine, held_out_steps=fit_steps))

    trainers = [HumanTrainer(data, fitting(cfg)) for cfg in (cfg_old, cfg_new)]
    seconds = [dict.fromkeys(("train", "refine", "fit", "render"), 0.0) for _ in trainers]
    with loop.torch_threads(trainers[0].loop_threads()):
        for phase in ("train", "refine"):
            for t in trainers:
                t.step = t.refine_start if phase == "refine" else 0
            for k in range(steps + 1):
                for t, sec in zip(trainers, seconds, strict=True):
                    t0 = time.process_time()
                    t.train_step()
                    sec[phase] += (time.process_time() - t0) / steps if k else 0.0
        view = int(trainers[0].eval_ids[0])
        for t, sec in zip(trainers, seconds, strict=True):
            t0 = time.process_time()
            t.fit_held_out()
            sec["fit"] = (time.process_time() - t0) / fit_steps
            t0 = time.process_time()
            t.render_view(view)
            sec["render"] = time.process_time() - t0
    out = {}
    for name, cfg, sec in (("old", cfg_old, seconds[0]), ("new", cfg_new, seconds[1])):
        start = int(round(cfg.refine.start_fraction * cfg.optim.steps)) if cfg.refine.lr > 0 else cfg.optim.steps
        frames = len(trainers[0].eval_ids) * (2 if cfg.refine.held_out_steps > 0 else 1)
        total = (start * sec["train"] + (cfg.optim.steps - start) * sec["refine"]
                 + cfg.refine.held_out_steps * sec["fit"] + frames * sec["render"])
        out[name] = {**{f"{k}_s": round(v, 3) for k, v in sec.items()}, "stage_estimate_s": round(total, 1)}
    out["ratio"] = round(out["new"]["stage_estimate_s"] / out["old"]["stage_estimate_s"], 3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workspace", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default 2, 1 with --quick)")
    ap.add_argument("--preset", default=None, help="train-human preset (default: default; tiny with --quick)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="a train-human setting (repeatable)")
    ap.add_argument("--frames", type=int, default=None, help="frames per capture (default 150; 30 with --quick)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out" / "human_sides.png")
    ap.add_argument("--ratio", type=int, default=0, metavar="N",
                    help="only time the preset against the default before issue 45 (OLD_DEFAULT), N steps of each "
                         "phase interleaved on the front capture, in CPU seconds (speed_ratio; 1 thread unless "
                         "--threads), and print that")
    args = ap.parse_args()
    q = args.quick
    threads = args.threads or (1 if q or args.ratio else 2)
    preset = args.preset or ("tiny" if q else "default")
    frames = args.frames or (30 if q else 150)
    size = ["width=128", "height=96"] if q else ["width=320", "height=240"]
    th_over = [f"optim.num_threads={threads}"] + ([f"optim.steps={args.steps}"] if args.steps else []) + args.overrides
    times = _TrainTimes()
    logging.getLogger("nsim.train.human").addHandler(times)
    logging.getLogger("nsim.train.human").setLevel(logging.INFO)
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(args.workspace or Path(tmp) / "ws")
        ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
        t0 = time.perf_counter()
        caps = {name: capture.run(capture.Inputs(), load_config(
            capture.Config, stage="capture", preset="default",
            overrides=["actor=true", "video=false", f"n_frames={frames}", f"actor_view_deg={deg:g}", *size]), ctx).capture
            for name, deg in SIDES.items() if name == "front" or not args.ratio}
        cap_s = time.perf_counter() - t0
        cfg = load_config(train_human.Config, stage="train_human", preset=preset, overrides=th_over)
        if args.ratio:
            old = load_config(train_human.Config, stage="train_human", preset="default", overrides=OLD_DEFAULT + th_over)
            result = speed_ratio(train_human.load_data(store.get(caps["front"]).path), old, cfg, args.ratio,
                                 max(2, args.ratio // 2))
            print(json.dumps({"ratio_steps": args.ratio, "preset": preset, "frames": frames, **result}))
            return
        t0 = time.perf_counter()
        out = train_human.run(train_human.Inputs(capture=caps["front"]), cfg, dataclasses.replace(ctx, force=True))
        train_s = time.perf_counter() - t0
        art = store.get(out.human)
        held = json.loads(art.file("eval.json").read_text())
        turntable = args.out.with_name(args.out.stem + "_turntable.png")
        turntable.parent.mkdir(parents=True, exist_ok=True)
        turntable.write_bytes(art.file("turntable.png").read_bytes())

        from nsim.human.nerf import load_human_model
        from nsim.train.human import score_model

        model = load_human_model(art.path)
        # the picture's frame: the training capture's first held-out frame (a pose the model never trained on)
        shown = int(held["views"][0]["frame"])
        scores, rows = {}, []
        t0 = time.perf_counter()
        for name in ("side", "back"):
            data = train_human.load_data(store.get(caps[name]).path)
            ev = score_model(model, data, cfg, views=None, keep_images=False)
            pic = score_model(model, data, cfg, views=[shown], keep_images=True)
            scores[name] = ev
            rows.append((f"{name} ({SIDES[name]:g} deg)", pic["images"][shown]["rgb"], data.images[shown],
                         data.masks[shown], pic["views"][0].get("psnr_box", float("nan"))))
        score_s = time.perf_counter() - t0
        front = train_human.load_data(store.get(caps["front"]).path)
        pic = score_model(model, front, cfg, views=[shown], keep_images=True)
        rows.insert(0, ("front (0 deg, held out)", pic["images"][shown]["rgb"], front.images[shown], front.masks[shown],
                        pic["views"][0].get("psnr_box", float("nan"))))
    image = picture(args.out, rows)
    m = held["mean"]
    print(f"captures ({frames} frames, {size[0][6:]}x{size[1][7:]}, sides {list(SIDES.values())}) in {cap_s:.0f} s; "
          f"train-human ({preset} preset, {cfg.optim.steps} steps, {threads} threads) in {train_s:.0f} s wall "
          f"(training loop {times.loop_s:.0f} s, held-out fit {times.fit_s:.0f} s); scoring {score_s:.0f} s")
    print(f"{'views':>24} {'frames':>7} {'PSNR box':>9} {'IoU':>6} {'mean colour':>12} {'background':>11}")
    table = [("front, held out", len(held["views"]), m)] + [
        (f"{name} ({SIDES[name]:g} deg), all", len(ev["views"]), ev["mean"]) for name, ev in scores.items()]
    for label, n, s in table:
        print(f"{label:>24} {n:7d} {s.get('psnr_box', float('nan')):9.2f} {s['mask_iou']:6.3f} "
              f"{s.get('psnr_box_baseline', float('nan')):12.2f} {s.get('psnr_box_background', float('nan')):11.2f}")
    print(f"pictures: {image}, {turntable} (the rest pose all round)")
    result = {"quick": q, "preset": preset, "steps": cfg.optim.steps, "threads": threads, "frames": frames,
              "overrides": args.overrides,
              "psnr_box": round(m.get("psnr_box", float("nan")), 3), "iou": round(m["mask_iou"], 4),
              "psnr_box_side": round(scores["side"]["mean"].get("psnr_box", float("nan")), 3),
              "iou_side": round(scores["side"]["mean"]["mask_iou"], 4),
              "psnr_box_back": round(scores["back"]["mean"].get("psnr_box", float("nan")), 3),
              "iou_back": round(scores["back"]["mean"]["mask_iou"], 4),
              "psnr_box_side_background": round(scores["side"]["mean"].get("psnr_box_background", float("nan")), 3),
              "psnr_box_back_background": round(scores["back"]["mean"].get("psnr_box_background", float("nan")), 3),
              "train_s_default" if preset == "default" else "train_s": round(train_s, 1),
              "train_loop_s": round(times.loop_s, 1), "held_out_fit_s": round(times.fit_s, 1),
              "capture_s": round(cap_s, 1), "score_s": round(score_s, 1),
              "peak_rss_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3)}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
