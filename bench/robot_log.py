"""A robot's recording as the ground truth: the realistic robot log of the paper's Spot run, imported, registered,
rendered and scored, against the same sensors scored against the test room's oracle.

    python bench/robot_log.py [--quick] [--size tiny|small|default] [--workspace DIR] [--seed N] [--device auto]
                              [--sensors left,lidar] [--render-stride K]

The chain is ``pipelines/paper.py``'s ``--recording`` path (``spot_run`` then ``run_recording``): robot-lab's
capture and scene and the Spot run (simulate nsim/configs/scenarios/spot_run.json), the realistic robot log of that run
(``nsim capture robot-log``: Spot's five fisheye cameras at half size with auto-exposure drift, noise and JPEG,
their depth with holes and a minimum range, the LiDAR with dropout and range noise, drifting odometry, a camera
clock offset, the odometry frame rotated and shifted from the room's; its ``<bag>.truth.json``), ``import-log``,
``register-log`` into a metric map of robot-lab, ``render --recording`` in robot-lab's scene, and ``evaluate`` of
the five tables (spot-rgb raw and colour-corrected, spot-depth, lidar, slam, detection) against the recording.
The same cameras and LiDAR at the same ticks are also rendered from the true trajectory (the twin) and scored
against the oracle: the two sides differ only by the log's faults and the registration, which is what the agreement
table shows (per table, the mean over the sensors of sim-vs-oracle and sim-vs-recording, recording minus oracle,
and the stated tolerance, ``paper.AGREEMENT_TOLERANCE``, with its verdict).

Sizes are the paper's (``--size``; ``--quick`` is ``tiny``): at ``tiny`` a 4 s run, the log's 20 ticks every 0.2 s
at 320x240 (SIFT needs the pixels to localise), registered in a 100-frame 200x150 capture reconstructed by
pycolmap and made metric by its ground-truth trajectory, every second recorded frame rendered (10 per stream).
Only robot-lab is built (the other rooms and the people serve only the oracle pipeline's own tables), so the
quick run's steps summed to about 9 min from an empty workspace on 2 cores shared with other jobs (load 4):
the recording render 3.2-4.2 min, the twin 2.1 min, register-log 0.6 min, the rest under 2 min (a temporary one unless ``--workspace``). SLAM is n/a at ``--quick``: three frames of
the left camera 1.4 s apart, SfM registers none (on either side).

``--sensors`` renders and scores only the named streams on both sides (``left,lidar``: the SLAM camera and the
LiDAR, for the SLAM row at ``--size default`` without the other four cameras' hour of rendering); ``--render-stride K``
renders every K-th recorded frame of each stream instead of the size's choice.

Times are wall seconds; ``peak_rss_gb`` is the peak resident memory of this process and of its children
(``resource.getrusage``). The last line is one JSON object: ``register_err_m, register_err_deg, clock_err_s,
spot_rgb_psnr_mean, spot_rgb_psnr_cc_mean, spot_rgb_ssim_mean, spot_depth_absrel_mean, lidar_median_err_m,
lidar_chamfer_m, lidar_hit_agreement, slam_ate_real_m, slam_ate_sim_m, oracle`` (the twin's numbers against the
oracle: ``spot_rgb_psnr_mean, spot_depth_absrel_mean, lidar_median_err_m, lidar_hit_agreement, slam_ate_real_m,
slam_ate_sim_m``), ``agreement_within`` (per ``table/metric`` with a stated tolerance: true, false, or null where a
side has no number), ``na`` (why a metric is null), ``localised, tried, residual_median_m, size, wall_s, steps_s,
peak_rss_gb``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nsim.context import RunContext  # noqa: E402
from nsim.errors import NsimError  # noqa: E402
from nsim.metrics.results_table import NotAvailable  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402


def load_paper():
    spec = importlib.util.spec_from_file_location("paper_pipeline", REPO / "pipelines" / "paper.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def peak_rss_gb() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 2**20  # KiB on Linux


def column(table, name: str) -> tuple[float | None, str | None]:
    """The mean of a column's finite numbers over the table's body rows, or None and the n/a reason."""
    body = table.rows[: len(table.rows) - table.footer_rows]
    vals, reasons = [], []
    for row in body:
        v = row.get(name)
        if isinstance(v, NotAvailable):
            reasons.append(v.reason)
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v)):
            vals.append(float(v))
    if vals:
        return sum(vals) / len(vals), None
    return None, (reasons[0] if reasons else f"no finite {name!r} in the {table.title!r} table")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the tiny size (about 3 minutes on 2 cores)")
    ap.add_argument("--size", choices=("tiny", "small", "default"), default="small")
    ap.add_argument("--workspace", type=Path, default=None, help="default: a temporary workspace")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--sensors", default=None, metavar="A,B",
                    help="render and score only these recorded streams (e.g. left,lidar: the SLAM camera and the "
                         "LiDAR), on both the recording's and the twin's side; default: the size's (all)")
    ap.add_argument("--render-stride", type=int, default=None, metavar="K",
                    help="render every K-th recorded frame of each stream (default: the size's)")
    args = ap.parse_args()
    paper = load_paper()
    size = args.size
    if args.quick:
        # tiny, rendering and scoring two cameras (frontleft, left), their depth and the LiDAR only: at 320x240 a
        # scene frame costs seconds on 2 cores, and the recording render's frames count twice (colour, depth)
        size = "quick"
        paper.SIZES["quick"] = paper.SIZES["tiny"]
        paper.RECORDING["quick"] = {**paper.RECORDING["tiny"], "render": (
            "tiny", ["image_scale=1.0", "lidar_azimuth_scale=1.0", "sensors=[frontleft,left,lidar]", "tick_stride=7",
                     "max_frames=null"])}
    if args.sensors is not None or args.render_stride is not None:
        preset, overrides = paper.RECORDING[size]["render"]
        extra = []
        if args.sensors is not None:
            names = [n.strip() for n in args.sensors.split(",") if n.strip()]
            if not names:
                ap.error("--sensors: expected names separated by commas, e.g. left,lidar")
            extra.append(f"sensors=[{','.join(names)}]")
        if args.render_stride is not None:
            if args.render_stride < 1:
                ap.error(f"--render-stride: expected an integer >= 1, got {args.render_stride}")
            extra.append(f"tick_stride={args.render_stride}")
        keys = {e.split("=", 1)[0] for e in extra}
        paper.RECORDING[size] = {**paper.RECORDING[size], "render": (
            preset, [o for o in overrides if o.split("=", 1)[0] not in keys] + extra)}
    tmp = None
    if args.workspace is None:
        tmp = tempfile.TemporaryDirectory(prefix="nsim-bench-robot-log-")
        args.workspace = Path(tmp.name)
    ctx = RunContext(store=Store(args.workspace), device_spec=args.device, seed=args.seed)
    steps: dict[str, float] = {}
    t0 = time.perf_counter()
    try:
        t = time.perf_counter()
        spot = paper.spot_run(ctx, size)
        steps["scene_and_run_s"] = time.perf_counter() - t
        t = time.perf_counter()
        run = paper.run_recording(ctx, size, paper.RecordingRequest(), spot)
        steps["recording_s"] = time.perf_counter() - t
    except NsimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    wall = time.perf_counter() - t0

    for name, table in run.tables.items():
        print()
        print(f"== {name}: simulated vs the recording")
        print(table.to_text(), end="")
        if name in run.oracle:
            print(f"== {name}: the twin render vs the oracle")
            print(run.oracle[name].to_text(), end="")
    print()
    print(paper.registration_text(run), end="")
    print()
    print(paper.agreement_text(paper.agreement(run.oracle, run.tables)), end="")

    na: dict[str, str] = {}
    out: dict[str, Any] = {}

    def put(key: str, table: dict, name: str, col: str) -> None:
        if name not in table:
            out[key], na[key] = None, f"no {name} table"
            return
        out[key], why = column(table[name], col)
        if why is not None:
            na[key] = why

    err = run.error or {}
    out["register_err_m"] = err.get("position_m")
    out["register_err_deg"] = err.get("rotation_deg")
    out["clock_err_s"] = err.get("clock_s")
    put("spot_rgb_psnr_mean", run.tables, "spot-rgb", "PSNR")
    put("spot_depth_absrel_mean", run.tables, "spot-depth", "AbsRel")
    put("lidar_median_err_m", run.tables, "lidar", "range err median [m]")
    put("slam_ate_real_m", run.tables, "slam", "ATE real [m]")
    put("slam_ate_sim_m", run.tables, "slam", "ATE sim [m]")
    put("spot_rgb_psnr_cc_mean", run.tables, "spot-rgb", "PSNR cc")
    put("spot_rgb_ssim_mean", run.tables, "spot-rgb", "SSIM")
    put("lidar_chamfer_m", run.tables, "lidar", "Chamfer [m]")
    put("lidar_hit_agreement", run.tables, "lidar", "hit agreement")
    oracle: dict[str, Any] = {}
    for key, name, col in (("spot_rgb_psnr_mean", "spot-rgb", "PSNR"), ("spot_depth_absrel_mean", "spot-depth", "AbsRel"),
                           ("lidar_median_err_m", "lidar", "range err median [m]"),
                           ("lidar_hit_agreement", "lidar", "hit agreement"),
                           ("slam_ate_real_m", "slam", "ATE real [m]"), ("slam_ate_sim_m", "slam", "ATE sim [m]")):
        if name in run.oracle:
            oracle[key], why = column(run.oracle[name], col)
            if why is not None:
                na[f"oracle.{key}"] = why
    out["oracle"] = oracle
    # the stated tolerances (paper.AGREEMENT_TOLERANCE): per table/metric, within or not (None: a side has no number)
    out["agreement_within"] = {f"{r['table']}/{r['metric']}": r["within"]
                               for r in paper.agreement(run.oracle, run.tables) if r["tolerance"] is not None}
    out["na"] = na
    doc = run.registration_doc
    out["localised"] = doc.get("localised", {}).get("localised")
    out["tried"] = doc.get("localised", {}).get("tried")
    out["residual_median_m"] = doc.get("residual", {}).get("median_m")
    out["size"] = size
    out["wall_s"] = round(wall, 1)
    out["steps_s"] = {k: round(v, 1) for k, v in steps.items()}
    out["peak_rss_gb"] = round(peak_rss_gb(), 3)
    for key, why in na.items():
        print(f"n/a {key}: {why}")
    if tmp is not None:
        tmp.cleanup()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
