"""A real capture, end to end: poses, scene, held-out scores, memory and time, export.

    python bench/real_capture.py SOURCE [--reference REF] [--workspace DIR] [--preset cpu]
                                 [--steps N] [--set KEY=VALUE ...] [--export] [--score-side N]
    python bench/real_capture.py --workspace DIR --scene ID [--reference REF] --score-side N
    python bench/real_capture.py --quick

SOURCE is a folder of photos or a video (what a user brings), or ``--import transforms.json``
(``--import`` instead of SOURCE: the capture tool's own poses). REF, optional, holds reference
poses: a transforms.json (nerfstudio / instant-ngp) or a COLMAP model folder (``cameras.bin``
and ``images.bin`` or their ``.txt``); frames are matched by file stem. ``--quick`` runs on a
small test-room capture (the ``phone`` capture preset when it exists, else ``tiny``), with
ground-truth poses as the reference.

Every stage runs as the ``nsim`` command in its own process, so that each process's peak RSS is
its own (``os.wait4``). Reports:

* images given / used / registered (from reconstruct's report.json), reconstruct time;
* pose agreement with REF after a Sim(3) fit of the camera centres: median rotation error (deg)
  and median position error as % of the path's extent;
* train-scene: training seconds, peak RSS of the process, post-training seconds (the publish
  block: held-out renders, occupancy and obstacle bakes, writing; the manifest's ``wall_time_s``);
* held-out PSNR / SSIM / LPIPS as train-scene's eval.json gives them (mean appearance embedding,
  and the half-image protocol when the model reports it);
* with ``--export``: the sizes of ``nsim export``'s files;
* with ``--score-side N``: the held-out views scored again at N px on the longer side (0: as
  captured) with both protocols, by ``nsim.train.scene_eval.score_views`` on the published
  scene-checkpoint (its ``model.pt`` + ``scene.json``, the poses it trained on, the views, seeds and
  ``eval`` settings of its eval.json): ``heldout_psnr_full, heldout_ssim_full, heldout_lpips_full,
  heldout_psnr_half_full, heldout_ssim_half_full, heldout_lpips_half_full``, the scoring seconds
  ``score_full_s`` and the peak RSS of that process ``score_full_rss_gb`` (renders are chunked: memory
  stays bounded at any size). ``--scene ID`` (with ``--workspace``) takes an existing scene-checkpoint
  instead of reconstructing and training. At the size train-scene scored, the figures are eval.json's
  (``rescore_matches_eval_json``; ``--quick --score-side 0`` checks that, in some 30 s more).

Prints a table; the last line is one JSON object with at least ``images_used, images_given,
peak_rss_gb, post_train_s, train_s, heldout_psnr, heldout_psnr_half, rot_err_deg``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nsim.geometry.conventions import opengl_to_opencv_c2w  # noqa: E402
from nsim.sfm.align import pose_errors  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def nsim(workspace: Path, *args: str, log: Path | None = None) -> tuple[str, float, float]:
    """Run ``nsim -w WORKSPACE ARGS``; returns (stdout, wall seconds, peak RSS in GB of that process)."""
    cmd = [sys.executable, "-m", "nsim.cli", "-w", str(workspace), "--no-progress", *args]
    return run_process(cmd, f"nsim {' '.join(args)}", log)


def run_process(cmd: list[str], what: str, log: Path | None = None) -> tuple[str, float, float]:
    """Run ``cmd`` in the repository; returns (last line of stdout, wall seconds, peak RSS in GB of that
    process). Exits naming ``what`` (and the log's tail) when it fails."""
    t0 = time.perf_counter()
    err = open(log, "ab") if log is not None else subprocess.DEVNULL  # noqa: SIM115 - closed below
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, cwd=REPO)
        out = proc.stdout.read().decode()
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
    finally:
        if log is not None:
            err.close()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        tail = log.read_text()[-2000:] if log is not None else ""
        raise SystemExit(f"{what} failed with exit {proc.returncode}\n{tail}")
    return out.strip().splitlines()[-1] if out.strip() else "", wall, usage.ru_maxrss / 2**20


# ----------------------------------------------------------------------------------- reference poses
def reference_poses(ref: Path) -> dict[str, np.ndarray]:
    """Reference camera-to-world (OpenCV axes) by file stem, from a transforms.json or a COLMAP model."""
    if ref.is_file():
        doc = json.loads(ref.read_text())
        out = {}
        for f in doc.get("frames", []):
            c2w_gl = np.asarray(f["transform_matrix"], dtype=np.float64)
            out[Path(f["file_path"]).stem] = opengl_to_opencv_c2w(c2w_gl)
        return out
    import pycolmap

    rec = pycolmap.Reconstruction(ref)
    out = {}
    for image in rec.images.values():
        if image.has_pose:
            w2c = np.eye(4)
            w2c[:3, :] = image.cam_from_world().matrix()
            out[Path(image.name).stem] = np.linalg.inv(w2c)
    return out


def estimated_poses(store: Store, poses_id: str) -> dict[str, np.ndarray]:
    from nsim.io.transforms_json import read_transforms

    art = store.get(poses_id)
    data = read_transforms(art.file("transforms.json"))
    return {Path(f.file_path).stem: np.asarray(f.cam_to_world, dtype=np.float64) for f in data.frames}


def pose_agreement(est: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> dict[str, Any]:
    common = sorted(set(est) & set(ref))
    if len(common) < 3:
        return {"matched": len(common)}
    e = np.stack([est[k] for k in common])
    r = np.stack([ref[k] for k in common])
    rot, pos = pose_errors(e, r, robust=True)
    extent = float(np.linalg.norm(r[:, :3, 3].max(0) - r[:, :3, 3].min(0)))
    return {"matched": len(common), "rot_err_deg": float(np.median(rot)),
            "pos_err_pct_extent": float(100.0 * np.median(pos) / max(extent, 1e-12))}


# ----------------------------------------------------------------------------------- the run
def heldout_scores(store: Store, scene_id: str) -> dict[str, Any]:
    art = store.get(scene_id)
    ev = json.loads(art.file("eval.json").read_text())
    mean = ev.get("mean", {})
    out = {k: v for k, v in mean.items() if isinstance(v, int | float)}
    out["protocols"] = {k: v for k, v in ev.items() if "protocol" in k}
    return out


# ----------------------------------------------------------------------------------- scoring again
RESCORED = {"psnr": "heldout_psnr_full", "ssim": "heldout_ssim_full", "lpips": "heldout_lpips_full",
            "psnr_half": "heldout_psnr_half_full", "ssim_half": "heldout_ssim_half_full",
            "lpips_half": "heldout_lpips_half_full"}


def rescore(store: Store, scene_id: str, image_side: int) -> dict[str, Any]:
    """The held-out views of scene-checkpoint ``scene_id`` scored again at ``image_side`` (0: as
    captured), both protocols, as train-scene scored them: the published model on the poses artifact
    it trained on, the views of its eval.json, its ``eval`` settings but the side, its fit seeds, its
    chunk and threads (``nsim.train.scene_eval.score_views``). Runs in this process."""
    import torch

    from nsim.config import from_dict
    from nsim.rendering.model import load_model
    from nsim.train.heap import keep_large_blocks_on_heap
    from nsim.train.scene import _step_seed  # the trainer's seed of a frame's fit pixels
    from nsim.train.scene_data import SceneData
    from nsim.train.scene_eval import EvalConfig, score_views

    t0 = time.perf_counter()
    art = store.get(scene_id)
    m = art.manifest
    cfg = m["config"]
    ecfg = dataclasses.replace(from_dict(EvalConfig, cfg["eval"]), image_side=image_side)
    meta = json.loads(art.file("scene.json").read_text())
    # the ground truth is read again at the scored size: keep only tiny copies of the training images
    data = SceneData.load(store.get(m["inputs"]["poses"]).path, max_image_side=64, scale=cfg["data"]["scale"])
    if meta.get("images", data.names) != data.names:
        raise SystemExit(f"scene {scene_id[:12]}: its images are not those of its poses artifact")
    ev = json.loads(art.file("eval.json").read_text()) if (art.path / "eval.json").is_file() else None
    views = [int(r["frame"]) for r in ev["views"]] if ev else [int(i) for i in meta["eval_images"]]
    keep_large_blocks_on_heap()  # as the trainer: each chunk's large blocks reused, not page-faulted in again
    threads, parts = int(cfg["optim"]["num_threads"]), int(cfg["optim"].get("batch_threads", 1))
    if threads > 0:
        torch.set_num_threads(threads)
    pool = None
    if parts > 1:  # as the trainer: the chunks of a render on batch_threads threads of num_threads each
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor(parts, initializer=(lambda: torch.set_num_threads(threads)) if threads > 0 else None)
    model = load_model(art.path, "cpu")
    load_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = score_views(model, data, views, ecfg, int(cfg["output"]["render_chunk_rays"]),
                      lambda i: torch.Generator().manual_seed(_step_seed(int(m["seed"]), i, "eval-fit")), pool=pool)
    score_s = time.perf_counter() - t0
    if pool is not None:
        pool.shutdown()
    out: dict[str, Any] = {"score_side": image_side, "score_wh": res["resolution"]["scored_wh"],
                           "score_views": len(views), "score_full_s": round(score_s, 1),
                           "score_load_s": round(load_s, 1)}
    out.update({name: res["mean"].get(k) for k, name in RESCORED.items()})
    if ev is not None and ev["resolution"]["scored_wh"] == res["resolution"]["scored_wh"]:
        out["rescore_matches_eval_json"] = all(res["mean"].get(k) == ev["mean"].get(k) for k in RESCORED)
    return out


def rescore_in_process(ws: Path, scene_id: str, image_side: int, tmp: Path, log: Path) -> dict[str, Any]:
    """:func:`rescore` in a process of its own (this script with ``--score-worker``), so its peak RSS is its own."""
    out_json = tmp / f"rescore.{image_side}.json"
    cmd = [sys.executable, str(Path(__file__).resolve()), "--workspace", str(ws), "--scene", scene_id,
           "--score-side", str(image_side), "--score-worker", str(out_json)]
    _, wall, rss = run_process(cmd, f"scoring scene {scene_id[:12]} at side {image_side}", log)
    res = json.loads(out_json.read_text())
    res.update(score_full_rss_gb=round(rss, 2), score_full_wall_s=round(wall, 1))
    return res


def quick_capture(ws: Path, log: Path) -> tuple[list[str], Path | None]:
    """A small test-room capture; returns the reconstruct arguments and the reference (its GT poses)."""
    presets = {p.stem for p in (REPO / "nsim" / "configs" / "capture").glob("*.yaml")}
    preset = "phone" if "phone" in presets else "tiny"
    # SIFT needs about 100 frames of the two-loop path at 160x120 to chain them (as the tiny demo does)
    sets = ["--set", "n_frames=100", "--set", "width=160", "--set", "height=120", "--set", "video=false"]
    cap, _, _ = nsim(ws, "capture", "synth", "--preset", preset, *sets, "--tag", "capture/bench", log=log)
    cap_dir = Store(ws).get(cap).path
    return [str(cap_dir / "images")], cap_dir / "transforms.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", nargs="?", type=Path, help="a folder of photos or a video")
    ap.add_argument("--import", dest="import_json", type=Path, default=None, help="the capture tool's transforms.json")
    ap.add_argument("--poses", default=None,
                    help="reuse this poses artifact of --workspace instead of running reconstruct")
    ap.add_argument("--scene", default=None,
                    help="reuse this scene-checkpoint of --workspace (and its poses) instead of reconstructing and training")
    ap.add_argument("--reference", type=Path, default=None, help="reference poses: transforms.json or COLMAP model dir")
    ap.add_argument("--workspace", type=Path, default=None, help="keep the workspace here (default: a temp dir)")
    ap.add_argument("--preset", default="cpu", help="train-scene preset")
    ap.add_argument("--steps", type=int, default=None, help="train-scene steps (default: the preset's)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="train-scene override KEY=VALUE")
    ap.add_argument("--reconstruct-set", action="append", default=[], help="reconstruct override KEY=VALUE")
    ap.add_argument("--export", action="store_true", help="also run nsim export and report its sizes")
    ap.add_argument("--score-side", type=int, default=None, metavar="N",
                    help="score the held-out views again at N px on the longer side (0: as captured)")
    ap.add_argument("--quick", action="store_true", help="a small test-room capture (a minute or two)")
    ap.add_argument("--score-worker", type=Path, default=None, help=argparse.SUPPRESS)  # rescore_in_process
    args = ap.parse_args()
    if args.score_worker is not None:  # the scoring process: --workspace, --scene, --score-side
        res = rescore(Store(args.workspace, create=False), args.scene, args.score_side)
        args.score_worker.write_text(json.dumps(res) + "\n")
        return
    if args.scene is not None and (args.quick or args.source or args.import_json):
        ap.error("--scene takes the scene from --workspace: no SOURCE, --import or --quick")
    if not args.quick and args.poses is None and args.scene is None \
            and (args.source is None) == (args.import_json is None):
        ap.error("give SOURCE or --import (or --poses or --scene with --workspace, or --quick)")
    if (args.poses is not None or args.scene is not None) and args.workspace is None:
        ap.error("--poses and --scene need --workspace (the workspace that holds them)")
    if args.score_side is not None and args.score_side < 0:
        ap.error("--score-side: expected N >= 0 (0: as captured)")

    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "ws"
        log = Path(tmp) / "nsim.log" if args.workspace is None else ws.with_suffix(".log")
        row: dict[str, Any] = {"bench": "real_capture", "quick": args.quick}
        scene_id = None
        if args.scene is not None:
            store = Store(ws, create=False)
            scene_id = store.resolve(args.scene, kind="scene-checkpoint")
            trained_on = store.get(scene_id).manifest["inputs"]["poses"]
            if args.poses is not None and store.resolve(args.poses) != trained_on:
                ap.error(f"--scene {args.scene} was trained on poses {trained_on[:12]}, not --poses {args.poses}")
            args.poses = trained_on
        if args.quick:
            rec_args, reference = quick_capture(ws, log)
            preset, steps = "tiny", args.steps or 300
        else:
            rec_args = [str(args.source)] if args.source else ["--import", str(args.import_json)]
            reference, preset, steps = args.reference, args.preset, args.steps
        row["source"] = str(args.source or args.import_json or ("test room (quick)" if args.quick else ""))

        # poses
        rec_sets = [x for kv in args.reconstruct_set for x in ("--set", kv)]
        if args.poses is not None:
            store = Store(ws, create=False)
            poses_id, rec_s, rec_rss = store.resolve(args.poses), None, None
            row["source"] = f"poses artifact {poses_id[:12]}"
        else:
            poses_id, rec_s, rec_rss = nsim(ws, "reconstruct", *rec_args, *rec_sets, "--tag", "poses/bench", log=log)
        store = Store(ws)
        report = json.loads(store.get(poses_id).file("report.json").read_text())
        given = report.get("images_given", report.get("frames_given"))
        used = report.get("images_registered", report.get("frames", given))
        row.update(images_given=given, images_used=used,
                   reconstruct_s=round(rec_s, 1) if rec_s is not None else None,
                   reconstruct_rss_gb=round(rec_rss, 2) if rec_rss is not None else None,
                   scale_source=(report.get("scale") or {}).get("source", report.get("scale_source")),
                   principal_point_refined=(report.get("principal_point") or {}).get("refined"))
        if reference is not None:
            row.update(pose_agreement(estimated_poses(store, poses_id), reference_poses(Path(reference))))

        # scene
        if scene_id is None:
            sets = [x for kv in args.overrides for x in ("--set", kv)]
            step_args = ["--steps", str(steps)] if steps else []
            scene_id, ts_wall, ts_rss = nsim(ws, "train-scene", "--preset", preset, "--poses", poses_id, *step_args,
                                             *sets, "--tag", "scene/bench", log=log)
        else:  # trained before: its figures as published, nothing of this run's
            ts_wall = ts_rss = None
            row["source"] = f"scene artifact {scene_id[:12]} (poses {poses_id[:12]})"
        m = store.get(scene_id).manifest
        timing = m.get("timing", {})
        train_s = float(timing.get("train_seconds", float("nan")))
        post_s = float(timing.get("post_train_s", timing.get("wall_time_s", float("nan"))))
        scores = heldout_scores(store, scene_id)
        psnr_half = next((v for k, v in scores.items() if "psnr" in k and "half" in k), None)
        row.update(train_s=round(train_s, 1), post_train_s=round(post_s, 1),
                   post_train_fraction=round(post_s / train_s, 3) if train_s == train_s and train_s > 0 else None,
                   train_scene_wall_s=round(ts_wall, 1) if ts_wall is not None else None,
                   peak_rss_gb=round(ts_rss, 2) if ts_rss is not None else None,
                   heldout_psnr=scores.get("psnr"), heldout_ssim=scores.get("ssim"),
                   heldout_lpips=scores.get("lpips"), heldout_psnr_half=psnr_half,
                   heldout=scores, image_size=m.get("summary", {}).get("image_size"))

        if args.score_side is not None:
            row.update(rescore_in_process(ws, scene_id, args.score_side, Path(tmp), log))

        if args.export:
            export_id, ex_s, ex_rss = nsim(ws, "export", scene_id, log=log)
            art = store.get(export_id)
            row["export_s"] = round(ex_s, 1)
            row["export_mb"] = {k: round(v["size"] / 2**20, 2) for k, v in art.manifest["files"].items()
                                if v["size"] > 2**16}

    width = max(len(k) for k in row)
    for k, v in row.items():
        if k not in ("heldout",):
            print(f"{k:<{width}}  {v}")
    print(json.dumps(row))

if __name__ == "__main__":
    main()
