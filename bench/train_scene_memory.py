"""Peak memory and time of ``train-scene``: training against the work after it (held-out scoring,
occupancy bake, obstacle map, export).

    python bench/train_scene_memory.py --quick
    python bench/train_scene_memory.py PATH [--steps 200] [--preset cpu] [--set data.max_image_side=1600 ...]

PATH: a folder holding ``transforms.json`` and its images (a poses or capture artifact's folder, a
nerfstudio export) or that ``transforms.json``. ``--quick``: a synthetic phone-size capture of the
test room (16 frames at 1920x1080, made in a temporary workspace, or reused from ``--workspace``) and
30 steps of the ``cpu`` preset, in about a minute and a half. The post-training cost does not depend
on the number of steps, so a short run measures it; ``post_train_over_train`` is only meaningful with
the preset's own step count.

Measures, in this process: peak RSS (``resource.getrusage``'s maximum for the whole run, and a thread
sampling ``/proc/self/statm`` every 20 ms for the peak of each phase: load, train, post-train and,
inside it, held-out scoring, occupancy bake and obstacle map), wall seconds of each phase, and the
held-out PSNR from ``eval.json`` (mean appearance embedding, and the left-half fit / right-half score
where the code writes it). Runs the code it imports: ``PYTHONPATH=/path/to/other/checkout`` measures
another version on the same data. Prints a table and ends with one JSON object on the last line.
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path

if "PYTHONPATH" not in os.environ:  # run from a checkout: import this checkout's nsim
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

QUICK_CAPTURE = ["width=1920", "height=1080", "n_frames=16", "supersample=1", "video=false"]
QUICK_STEPS = 30
PAGE = os.sysconf("SC_PAGE_SIZE")


class RssSampler:
    """Samples this process's resident set every ``period_s`` and keeps the peak per phase label."""

    def __init__(self, period_s: float = 0.02):
        self.period_s = period_s
        self.phase = "start"
        self.peaks: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def rss() -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * PAGE

    def _run(self) -> None:
        while not self._stop.is_set():
            self.note()
            self._stop.wait(self.period_s)

    def note(self) -> None:
        r = self.rss()
        for label in (self.phase, self.phase.split(":")[0]):
            if r > self.peaks.get(label, 0):
                self.peaks[label] = r

    @contextlib.contextmanager
    def during(self, phase: str, seconds: dict[str, float]):
        before, self.phase = self.phase, phase
        self.note()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            seconds[phase] = seconds.get(phase, 0.0) + time.perf_counter() - t0
            self.note()
            self.phase = before

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def quick_capture(workspace: Path | None) -> Path:
    from nsim.config import load_config
    from nsim.context import RunContext
    from nsim.stages import capture
    from nsim.workspace.store import Store

    root = workspace or Path(tempfile.mkdtemp(prefix="nsim-bench-mem-"))
    store = Store(root)
    cfg = load_config(capture.Config, stage="capture", preset="default", overrides=QUICK_CAPTURE)
    ctx = RunContext(store=store, device_spec="cpu", seed=0, progress=False)
    return store.get(capture.run(capture.Inputs(), cfg, ctx).capture).path


def wrap(module, name: str, sampler: RssSampler, phase: str, seconds: dict[str, float], owner=None) -> None:
    """Replace ``module.name`` (or ``owner.name``) by a version that runs under ``phase``."""
    target = owner if owner is not None else module
    if not hasattr(target, name):
        return
    fn = getattr(target, name)

    def timed(*args, **kwargs):
        with sampler.during(phase, seconds):
            return fn(*args, **kwargs)

    setattr(target, name, timed)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("path", nargs="?", help="folder with transforms.json, or the transforms.json")
    ap.add_argument("--quick", action="store_true", help="synthetic 16-frame 1920x1080 capture, 30 steps")
    ap.add_argument("--workspace", type=Path, help="where --quick keeps its capture (default: a temporary folder)")
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--steps", type=int, default=None, help="training steps (default: 30 with --quick, else the preset's)")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="config override key=value")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if not args.quick and not args.path:
        ap.error("give a PATH or --quick")

    import torch

    import nsim.train.scene as scene
    from nsim.config import load_config

    try:  # export_scene and the grids it bakes: in nsim.train.scene before the trainer's module was split
        import nsim.train.scene_export as scene_export
    except ImportError:
        scene_export = scene

    root = quick_capture(args.workspace) if args.quick else Path(args.path)
    if root.is_file():
        root = root.parent
    steps = args.steps if args.steps is not None else (QUICK_STEPS if args.quick else None)
    # log every 10 steps: the steady step time (after the first log, past the first steps' compiling)
    overrides = ([f"optim.steps={steps}"] if steps else []) + ["output.log_every=10"] + list(args.sets)
    cfg = load_config(scene.TrainSceneConfig, stage="train_scene", preset=args.preset, overrides=overrides)
    load_kwargs = {}
    params = inspect.signature(scene.SceneData.load).parameters
    if "max_image_side" in params:  # this version trains on shrunk copies
        load_kwargs = {"max_image_side": cfg.data.max_image_side, "scale": cfg.data.scale}

    seconds: dict[str, float] = {}
    with RssSampler() as sampler, tempfile.TemporaryDirectory(prefix="nsim-bench-mem-") as tmp:
        wrap(scene_export, "bake_occupancy", sampler, "post:occupancy", seconds)
        wrap(scene_export, "bake_obstacles", sampler, "post:obstacles", seconds)
        wrap(scene, "evaluate", sampler, "post:heldout", seconds, owner=scene.SceneTrainer)
        with sampler.during("load", seconds):
            data = scene.SceneData.load(root, **load_kwargs)
        logs: list[tuple[int, float]] = []
        with sampler.during("train", seconds):
            result = scene.train_scene(data, cfg, Path(tmp) / "work", device="cpu", seed=args.seed,
                                       on_log=lambda tr, _: logs.append((tr.step, tr.train_seconds)))
        out = Path(tmp) / "out"
        with sampler.during("post", seconds):
            scene_export.export_scene(out, result)
        ev = json.loads((out / "eval.json").read_text()) if (out / "eval.json").is_file() else {}
        train_seconds = result.trainer.train_seconds
    peak_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB
    if len(logs) >= 2:
        steady_step_s = (logs[-1][1] - logs[0][1]) / (logs[-1][0] - logs[0][0])
    else:
        steady_step_s = train_seconds / max(1, result.trainer.step)
    mb = 1024.0 * 1024.0
    mean = ev.get("mean", {})
    res = ev.get("resolution", {})
    row = {
        "frames": data.n_frames,
        "image_size": list(getattr(data, "full_size_hw", data.size_hw))[::-1],
        "train_size": [int(data.size_hw[1]), int(data.size_hw[0])],
        "scored_size": res.get("scored_wh", list(getattr(data, "full_size_hw", data.size_hw))[::-1]),
        "heldout_views": len(ev.get("views", [])),
        "steps": result.trainer.step,
        "torch": torch.__version__,
        "peak_rss_mb": round(peak_self / mb, 1),
        "peak_rss_load_mb": round(sampler.peaks.get("load", 0) / mb, 1),
        "peak_rss_train_mb": round(sampler.peaks.get("train", 0) / mb, 1),
        "peak_rss_post_mb": round(sampler.peaks.get("post", 0) / mb, 1),
        "peak_rss_heldout_mb": round(sampler.peaks.get("post:heldout", 0) / mb, 1),
        "peak_rss_occupancy_mb": round(sampler.peaks.get("post:occupancy", 0) / mb, 1),
        "peak_rss_obstacles_mb": round(sampler.peaks.get("post:obstacles", 0) / mb, 1),
        "load_s": round(seconds.get("load", 0.0), 2),
        "train_s": round(seconds.get("train", 0.0), 2),
        "train_step_s": round(steady_step_s, 4),
        "post_train_s": round(seconds.get("post", 0.0), 2),
        "heldout_s": round(seconds.get("post:heldout", 0.0), 2),
        "occupancy_s": round(seconds.get("post:occupancy", 0.0), 2),
        "obstacles_s": round(seconds.get("post:obstacles", 0.0), 2),
        "heldout_psnr": mean.get("psnr"),
        "heldout_psnr_half": mean.get("psnr_half"),
        "heldout_psnr_half_mean_embedding": mean.get("psnr_half_mean_embedding"),
    }
    # the post-training work against what the preset's full training would take at this step time
    full_steps = load_config(scene.TrainSceneConfig, stage="train_scene", preset=args.preset,
                             overrides=list(args.sets)).optim.steps
    row["post_train_over_preset_train"] = round(row["post_train_s"] / (row["train_step_s"] * full_steps), 4)
    w = max(len(k) for k in row)
    for k, v in row.items():
        print(f"{k:<{w}}  {v}")
    print(json.dumps(row))
    return row


if __name__ == "__main__":
    main()
