"""The evaluation's tables: metrics over the pairs a ground truth gives (``nsim.evaluation.truth``).

``Evaluation(inputs, cfg)`` holds what the stage resolved (``nsim.evaluation.inputs.EvaluationInputs``),
the settings, and the renders' ground truth, chosen by their mode (``truth_for``). ``compute(ev)`` runs ``TABLE_FUNCTIONS[ev.cfg.table]`` and returns a ``Result`` (the table, its
per-frame records and extras, and what to plot); ``nsim.evaluation.write.write_result`` writes it.
Every table function asks the evaluation's ground truth (``ev.truth``: the test room's oracle or a
robot's recording) for its pairs, and computes only metrics (``nsim.metrics``) and tables
(``nsim.metrics.paper_tables``):

``scenes`` (paper Table I)
    Poses-mode renders, one per environment: PSNR, SSIM, LPIPS, depth AbsRel, RMSE, delta<1.25 of
    every rendered frame against the frames the scene was trained from, or the oracle at the
    rendered cameras (``scenes_ground_truth``).
``spot-rgb`` (Table III)
    Per camera: PSNR, SSIM, LPIPS; against a recording also after a per-camera affine colour
    correction (``nsim.metrics.colour``: a 3x4 least-squares map from simulated to real colours,
    fitted on the camera's scored frames), columns ``PSNR cc``, ``SSIM cc``, ``LPIPS cc``.
``spot-depth`` (Table II)
    Per depth camera: AbsRel, SqRel, RMSE, logRMSE, delta thresholds (``nsim.metrics.depth``).
``lidar``
    Per LiDAR, point for point: range error median / mean / p95 and bias over the points both
    return (pooled over frames), Chamfer distance (mean over frames, sensor frame), hit agreement
    and the fractions that return in the simulation only and in reality only
    (``nsim.metrics.lidar_realism``).
``slam``
    One camera (``slam.camera``): pycolmap incremental SfM (``nsim.metrics.slam.run_colmap_slam``)
    on the simulated and on the real frames, the ATE of each against the camera's true poses; a
    side where SfM fails is n/a with the reason.
``detection``
    People detected (OpenCV HOG, an ONNX model, or COCO JSON given) on the simulated and on the real
    frames, turned upright first (``detection.upright``): matched-box IoU, precision, recall.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.errors import InputError
from nsim.evaluation.evaluate_config import Config
from nsim.evaluation.inputs import EvaluationInputs
from nsim.evaluation.oracle_truth import OracleTruth
from nsim.evaluation.recording_truth import RecordingTruth
from nsim.evaluation.renders import as_captured, read_depth, read_rgb, require_mode
from nsim.evaluation.truth import GroundTruth

if TYPE_CHECKING:
    from nsim.io.tum import Trajectory
    from nsim.metrics.paper_tables import DepthRecord, ImageRecord, SlamRecord
    from nsim.metrics.results_table import Table


@dataclasses.dataclass(frozen=True)
class LidarRecord:
    """One LiDAR sweep against the real one (``nsim.metrics.lidar_realism``; None: no point returned on both sides)."""

    group: str
    frame: int
    range_error_median_m: float | None
    range_error_mean_m: float | None
    range_bias_m: float | None
    chamfer_m: float | None
    hit_agreement: float
    n_points: int
    n_both_hit: int
    n_sim_only: int
    n_real_only: int


if TYPE_CHECKING:
    #: One per-frame record of a table: image and depth metrics, a LiDAR sweep, a SLAM sequence, or (detection)
    #: ``nsim.metrics.paper_tables.detection_table``'s input mapping.
    TableRecord = ImageRecord | DepthRecord | LidarRecord | SlamRecord | dict[str, Any]


@dataclasses.dataclass
class Result:
    """What a table function computed: the table, its per-frame records, extras and plots to draw.
    details: more for ``evaluation.json`` (e.g. the colour-correction maps; empty: none)."""

    table: Table
    records: list[TableRecord]
    extras: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    ground_truth: dict[str, str] = dataclasses.field(default_factory=dict)
    image_records: list[ImageRecord] = dataclasses.field(default_factory=list)
    depth_records: list[DepthRecord] = dataclasses.field(default_factory=list)
    error_maps: list[tuple[str, int, np.ndarray, np.ndarray, np.ndarray | None]] = dataclasses.field(
        default_factory=list)
    slam_files: dict[str, dict[str, Trajectory]] = dataclasses.field(default_factory=dict)
    details: dict[str, Any] = dataclasses.field(default_factory=dict)


def truth_for(inputs: EvaluationInputs, cfg: Config) -> GroundTruth:
    """The ground truth of the renders: ``RecordingTruth`` for recording-mode renders, else ``OracleTruth``."""
    modes = {r.mode for r in inputs.renders}
    if "recording" in modes:
        if len(modes) > 1:
            others = sorted(modes - {"recording"})
            raise InputError(f"evaluate: recording-mode renders are scored against their recording, {others[0]}-mode "
                             "renders against the test room: evaluate them separately")
        return RecordingTruth(inputs, cfg)
    return OracleTruth(inputs, cfg)


class Evaluation:
    """One evaluation: what the stage resolved (``inputs``: the loaded renders, the artifacts they name, device,
    seed, detector files), its settings (``cfg``) and the renders' ground truth (``truth``)."""

    def __init__(self, inputs: EvaluationInputs, cfg: Config) -> None:
        self.inputs, self.cfg = inputs, cfg
        self.renders = inputs.renders
        self.truth = truth_for(inputs, cfg)

    def require_mode(self, mode: str, how: str) -> None:
        require_mode(self.renders, mode, self.cfg.table, how)

    def lpips_net(self) -> str | None:
        return None if self.cfg.lpips_net == "none" else self.cfg.lpips_net


def compute(ev: Evaluation) -> Result:
    """``cfg.table`` over the renders; every input is read and checked here, before anything is published: what
    the files decide for every render first (``GroundTruth.check``), before any frame is scored."""
    ev.truth.check(ev.cfg.table)
    return TABLE_FUNCTIONS[ev.cfg.table](ev)


def _masked_frames(group: str, masks: list[np.ndarray | None], *seqs: list, why: str | None = None) -> tuple[list, ...]:
    """Drop frames whose mask is empty; InputError if that leaves none."""
    keep = [k for k, m in enumerate(masks) if m is None or m.any()]
    if not keep:
        raise InputError(f"{group}: {why or 'region=people, but the person mask is empty in every frame'}")
    return tuple([s[k] for k in keep] for s in (masks, *seqs))


def _with_notes(table, notes: list[str]):
    return dataclasses.replace(table, notes=(*table.notes, *notes))


def _image_notes(ev: Evaluation) -> list[str]:
    out = ["PSNR and SSIM on 8-bit sRGB images in [0, 1] (SSIM: 11x11 Gaussian window, sigma 1.5)"]
    if ev.cfg.lpips_net != "none":
        out.append(f"LPIPS: {ev.cfg.lpips_net} backbone (v0.1 linear heads)")
    return out


def _region_notes(ev: Evaluation) -> list[str]:
    return (["only pixels showing a person (render mask or ground truth); frames without one are left out"]
            if ev.cfg.region == "people" else [])


def _lineage_notes(ev: Evaluation) -> list[str]:
    return sorted({f"render {r.short}: {r.lineage.note}" for r in ev.renders})


# ---------------------------------------------------------------------------------- scenes
def table_scenes(ev: Evaluation) -> Result:
    from nsim.io.transforms_json import read_transforms
    from nsim.metrics.paper_tables import depth_records, image_records, scenes_table

    cfg = ev.cfg
    ev.require_mode("poses", "nsim render --poses CAPTURE_OR_POSES --scene SCENE --set frames=heldout")
    if cfg.region != "all":
        raise InputError("region=people: the scenes table scores captured frames, which show no people")
    oracle = ev.truth  # poses-mode renders: the test room's (nsim.evaluation.oracle_truth.OracleTruth)
    sources = [_scenes_source(ev, r) for r in ev.renders]  # every render checked before the first is scored
    images, depths, extras, maps, gt_notes = [], [], [], [], {}
    groups: list[str] = []
    for r, (src, frames_tf, scale) in zip(ev.renders, sources, strict=True):
        group = oracle.environment(r)
        if group in groups:
            group = f"{group} ({r.id[:8]})"
        groups.append(group)
        cap_depth: dict[str, Path] = {}
        if src.kind == "poses" and r.lineage.capture is not None:
            cap = ev.inputs.artifacts.get(r.lineage.capture)
            for f in read_transforms(cap.file("transforms.json")).frames:
                if f.depth_file_path:
                    cap_depth[Path(f.file_path).name] = cap.path / f.depth_file_path
        preds, gts, pdepths, gdepths, numbers, dnumbers = [], [], [], [], [], []
        for f in r.frames:
            i = int(f["index"])
            if not 0 <= i < len(frames_tf):
                raise InputError(f"render {r.short}: frame {i} of render.json is not among the {len(frames_tf)} frames "
                                 f"of {src.kind} {src.id[:12]}")
            frame = frames_tf[i]
            pred = read_rgb(r.file(f"frames/rgb/{i:06d}.png"))
            pdepth = read_depth(r.file(f"frames/depth/{i:06d}.exr"))
            if cfg.scenes_ground_truth == "oracle":
                cam = frame.camera.scaled(scale) if scale != 1.0 else frame.camera
                view = oracle.oracle(oracle.require_room(r)).render_gt(cam, frame.cam_to_world, cfg.oracle_supersample)
                gt, gdepth = as_captured(view.rgb), view.depth_z
                gt_notes[group] = "the test room's oracle at the rendered cameras and poses"
            else:
                gt = read_rgb(src.path / frame.file_path) if (src.path / frame.file_path).is_file() else None
                if gt is None:
                    raise InputError(f"{src.kind} {src.id[:12]}: frame {i} image {frame.file_path} is missing")
                if src.kind == "capture":
                    gdepth = read_depth(src.path / frame.depth_file_path) if frame.depth_file_path else None
                    gt_notes[group] = f"capture {src.id[:12]}: its own images and depth EXRs"
                else:
                    p = cap_depth.get(Path(frame.file_path).name)
                    gdepth = read_depth(p) if p is not None else None
                    gt_notes[group] = (f"poses {src.id[:12]}: its images" +
                                       (f"; depth: capture {r.lineage.capture[:12]}'s EXRs" if cap_depth else
                                        "; no ground-truth depth (real data)"))
            if pred.shape != gt.shape:
                raise InputError(f"{group} frame {i}: rendered image is {pred.shape[1]}x{pred.shape[0]} but the ground "
                                 f"truth {gt.shape[1]}x{gt.shape[0]} (render at image_scale 1, or use "
                                 "scenes_ground_truth=oracle)")
            preds.append(pred)
            gts.append(gt)
            numbers.append(i)
            if gdepth is not None:
                pdepths.append(pdepth)
                gdepths.append(gdepth)
                dnumbers.append(i)
            extras.append({"group": group, "frame": i, "render": r.id, "name": f.get("name"),
                           "gt_image": frame.file_path})
        images += image_records(group, preds, gts, ev.lpips_net(), frames=numbers, device=ev.inputs.device)
        if gdepths:
            depths += depth_records(group, pdepths, gdepths, ev.cfg.depth_config(), frames=dnumbers)
            maps += [(group, dnumbers[k], pdepths[k], gdepths[k], None) for k in range(min(cfg.error_maps, len(gdepths)))]
    table = scenes_table(images, depths, ev.cfg.depth_config())
    notes = [f"ground truth, {g}: {n}" for g, n in gt_notes.items()]
    notes += [f"{oracle.environment(r)}: {r.lineage.note}" for r in ev.renders]
    table = _with_notes(table, [*notes, *_image_notes(ev)])
    return Result(table, [*images, *depths], extras, gt_notes, images, depths, maps)


def _scenes_source(ev: Evaluation, r):
    """``(poses or capture artifact, its transforms.json frames, image_scale)`` of a poses-mode render, checked
    without reading an image: the test room (oracle ground truth), every rendered frame among the artifact's and
    its files present on both sides, and a rendered size that can match the captured frames'."""
    from nsim.io.transforms_json import read_transforms

    src = ev.inputs.artifacts.get(r.manifest["inputs"]["poses"])
    frames_tf = read_transforms(src.file("transforms.json")).frames
    scale = float(r.manifest.get("config", {}).get("image_scale", 1.0))
    captured = ev.cfg.scenes_ground_truth != "oracle"
    if not captured:
        ev.truth.require_room(r)
    for f in r.frames:
        i = int(f["index"])
        if not 0 <= i < len(frames_tf):
            raise InputError(f"render {r.short}: frame {i} of render.json is not among the {len(frames_tf)} frames "
                             f"of {src.kind} {src.id[:12]}")
        r.file(f"frames/rgb/{i:06d}.png")
        r.file(f"frames/depth/{i:06d}.exr")
        frame = frames_tf[i]
        if captured and not (src.path / frame.file_path).is_file():
            raise InputError(f"{src.kind} {src.id[:12]}: frame {i} image {frame.file_path} is missing")
        if captured and scale != 1.0:
            cam, small = frame.camera, frame.camera.scaled(scale)
            if (small.width, small.height) != (cam.width, cam.height):
                raise InputError(f"render {r.short} frame {i}: rendered image is {small.width}x{small.height} but the "
                                 f"ground truth {cam.width}x{cam.height} (render at image_scale 1, or use "
                                 "scenes_ground_truth=oracle)")
    return src, frames_tf, scale


# ---------------------------------------------------------------------------------- spot-rgb / spot-depth
CC = " cc"  # column and group suffix of the colour-corrected metrics


def table_spot_rgb(ev: Evaluation) -> Result:
    from nsim.metrics.colour import apply_colour_affine, fit_colour_affine
    from nsim.metrics.paper_tables import image_records, spot_rgb_table

    truth, people = ev.truth, ev.cfg.region == "people"
    records, corrected, extras, maps = [], [], [], {}
    for g in truth.image_frames():
        masks, numbers, preds, gts, more = _masked_frames(g.sensor, [p.mask for p in g.frames],
                                                          [p.index for p in g.frames], [p.sim for p in g.frames],
                                                          [p.real for p in g.frames], [p.extra for p in g.frames])
        masks = masks if people else None
        records += image_records(g.sensor, preds, gts, ev.lpips_net(), masks=masks, frames=numbers,
                                 device=ev.inputs.device)
        extras += [{"group": g.sensor, "frame": i, "render": g.render.id, **x} for i, x in zip(numbers, more,
                                                                                                 strict=True)]
        if truth.colour_correction:
            m = fit_colour_affine(preds, gts, masks)
            maps[f"{g.sensor} ({g.render.short})" if len(ev.renders) > 1 else g.sensor] = m.tolist()
            corrected += image_records(g.sensor + CC, [apply_colour_affine(p, m) for p in preds], gts, ev.lpips_net(),
                                       masks=masks, frames=numbers, device=ev.inputs.device)
    table = spot_rgb_table(records)
    notes = truth.notes("spot-rgb", extras)
    details: dict[str, Any] = {}
    if truth.colour_correction:
        table = _merge_corrected(table, spot_rgb_table(corrected))
        notes.append("cc: after a per-camera affine colour correction (real exposure and white balance differ): "
                     "real ~ M @ [r, g, b, 1], M a 3x4 least-squares map from simulated to real colours fitted on "
                     "all the camera's scored frames and pixels, then clipped to [0, 1] (12 parameters over every "
                     "pixel: fitted and scored on the same frames; the maps are in evaluation.json)")
        details["colour_correction"] = {"model": "real ~ M @ [r, g, b, 1] (8-bit values in [0, 1]), M (3, 4)",
                                        "maps": maps}
    notes += [*_region_notes(ev), *_image_notes(ev), *_lineage_notes(ev)]
    all_records = [*records, *corrected]
    return Result(_with_notes(table, notes), all_records, extras, truth.described("spot-rgb"),
                  image_records=all_records, details=details)


def _merge_corrected(raw, cc):
    """``raw``'s table with ``cc``'s metric columns beside each camera's raw ones (named ``<metric> cc``)."""
    from nsim.metrics.results_table import Column

    metrics = [c for c in raw.columns if c.direction]
    by_camera = {row["Camera"][: -len(CC)]: row for row in cc.rows}
    columns = [*raw.columns[:-1], *(Column(c.name + CC, c.direction, c.decimals) for c in metrics), raw.columns[-1]]
    rows = tuple({**row, **{c.name + CC: by_camera[row["Camera"]][c.name] for c in metrics}} for row in raw.rows)
    return dataclasses.replace(raw, columns=tuple(columns), rows=rows)


def table_spot_depth(ev: Evaluation) -> Result:
    from nsim.metrics.paper_tables import depth_records, spot_depth_table

    truth, people = ev.truth, ev.cfg.region == "people"
    records, extras, maps = [], [], []
    for g in truth.depth_frames():
        extras += [{"group": g.sensor, "frame": p.index, "render": g.render.id, **p.extra} for p in g.frames]
        why = None if people else "no frame has a pixel to score (a valid real reading the simulation also reads)"
        masks, numbers, preds, gts = _masked_frames(g.sensor, [p.mask for p in g.frames], [p.index for p in g.frames],
                                                    [p.sim for p in g.frames], [p.real for p in g.frames], why=why)
        scored = masks if any(m is not None for m in masks) else None
        records += depth_records(g.sensor, preds, gts, ev.cfg.depth_config(), masks=scored, frames=numbers)
        maps += [(g.sensor, numbers[k], preds[k], gts[k], masks[k]) for k in range(min(ev.cfg.error_maps, len(numbers)))]
    table = spot_depth_table(records, ev.cfg.depth_config())
    notes = [*truth.notes("spot-depth", extras), *_region_notes(ev), *_lineage_notes(ev)]
    return Result(_with_notes(table, notes), records, extras, truth.described("spot-depth"), depth_records=records,
                  error_maps=maps)


# ---------------------------------------------------------------------------------- lidar
LIDAR_COLUMNS = ("range err median [m]", "range err mean [m]", "range err p95 [m]", "range bias [m]", "Chamfer [m]",
                 "hit agreement", "sim only", "real only")


def lidar_table(groups: dict[str, tuple[Any, list[LidarRecord]]]) -> Any:
    """Per LiDAR: ``(pooled LidarRangeMetrics, per-frame records)`` -> the table (module docstring)."""
    from nsim.metrics.results_table import Column, NotAvailable, Table

    na_range = NotAvailable("no point returned in both the simulation and the recording")
    columns = (Column("LiDAR"), Column(LIDAR_COLUMNS[0], "lower", 3), Column(LIDAR_COLUMNS[1], "lower", 3),
               Column(LIDAR_COLUMNS[2], "lower", 3), Column(LIDAR_COLUMNS[3], None, 3),
               Column(LIDAR_COLUMNS[4], "lower", 3), Column(LIDAR_COLUMNS[5], "higher", 3),
               Column(LIDAR_COLUMNS[6], "lower", 3), Column(LIDAR_COLUMNS[7], "lower", 3), Column("points"),
               Column("frames"))
    rows = []
    for name, (m, recs) in groups.items():
        chamfers = [r.chamfer_m for r in recs if r.chamfer_m is not None]

        def value(v):
            return na_range if v is None else v

        rows.append({"LiDAR": name, LIDAR_COLUMNS[0]: value(m.range_error_median_m),
                     LIDAR_COLUMNS[1]: value(m.range_error_mean_m), LIDAR_COLUMNS[2]: value(m.range_error_p95_m),
                     LIDAR_COLUMNS[3]: value(m.range_bias_m),
                     LIDAR_COLUMNS[4]: float(np.mean(chamfers)) if chamfers else na_range,
                     LIDAR_COLUMNS[5]: m.hit_agreement, LIDAR_COLUMNS[6]: m.n_pred_only / m.n_beams,
                     LIDAR_COLUMNS[7]: m.n_gt_only / m.n_beams, "points": m.n_beams, "frames": len(recs)})
    notes = ("range errors |sim - real| (bias: mean of sim - real) over the points that return on both sides, "
             "pooled over the frames of each LiDAR",
             "Chamfer: mean over frames of (mean nearest-neighbour distance sim -> real + real -> sim) / 2, in the "
             "sensor's frame",
             "hit agreement: fraction of points that return on both sides or on neither; sim only / real only: "
             "fractions that return on one side alone")
    return Table("LiDAR: simulated vs real sweeps", columns, tuple(rows), notes, label="tab:lidar")


def table_lidar(ev: Evaluation) -> Result:
    from nsim.metrics.lidar_realism import chamfer_distance, lidar_range_metrics

    truth = ev.truth
    records, extras, groups = [], [], {}
    for g in truth.lidar_frames():
        recs = []
        for p in g.frames:
            m = lidar_range_metrics(p.sim[None, :, 3], p.real[None, :, 3])
            hit_s, hit_r = np.isfinite(p.sim[:, 3]), np.isfinite(p.real[:, 3])
            chamfer = chamfer_distance(p.sim[hit_s, :3], p.real[hit_r, :3]).chamfer_m if hit_s.any() and hit_r.any() \
                else None
            recs.append(LidarRecord(g.sensor, p.index, m.range_error_median_m, m.range_error_mean_m, m.range_bias_m,
                                    chamfer, m.hit_agreement, m.n_beams, m.n_both_hit, m.n_pred_only, m.n_gt_only))
            extras.append({"group": g.sensor, "frame": p.index, "render": g.render.id, **p.extra})
        name = g.sensor if g.sensor not in groups else f"{g.sensor} ({g.render.short})"
        pooled = lidar_range_metrics(np.concatenate([p.sim[:, 3] for p in g.frames])[None],
                                     np.concatenate([p.real[:, 3] for p in g.frames])[None])
        groups[name] = (pooled, recs)
        records += recs
    table = lidar_table(groups)
    notes = [*truth.notes("lidar", extras), *_lineage_notes(ev)]
    return Result(_with_notes(table, notes), records, extras, truth.described("lidar"))


# ---------------------------------------------------------------------------------- slam
def table_slam(ev: Evaluation) -> Result:
    from nsim.metrics.paper_tables import SlamRecord, slam_table
    from nsim.metrics.results_table import NotAvailable

    cfg = ev.cfg.slam
    records, extras, files = [], [], {}
    for seq in ev.truth.slam_sequences():
        runs = {side: _slam_side(frames, seq.times_s, cfg, ev.inputs.seed) for side, frames in (("real", seq.real),
                                                                                             ("sim", seq.sim))}
        ates: dict[str, Any] = {}
        for side, (traj, _fraction, reason) in runs.items():
            ates[side] = NotAvailable(reason) if traj is None else _ate_or_na(seq.truth, traj, cfg, side)
        records.append(SlamRecord(seq.name, ates["real"], ates["sim"], runs["real"][1], runs["sim"][1]))
        files[seq.name] = {"ground_truth": seq.truth, **{side: run[0] for side, run in runs.items() if run[0] is not None}}
        extras.append({"sequence": seq.name, "render": seq.render.id, "camera": seq.camera, "frames": len(seq.times_s),
                       **seq.extra, **{f"{side}_failure": run[2] for side, run in runs.items() if run[2]}})
    table = slam_table(records, cfg.alignment)
    every = "every rendered frame" if cfg.stride == 1 else f"every {cfg.stride}th rendered frame"
    notes = [f"camera {cfg.camera}, {every}"
             + (f", at most {cfg.max_frames}" if cfg.max_frames else "")
             + f"; pycolmap incremental SfM ({cfg.matcher} matching, {cfg.camera_model} intrinsics estimated)",
             *ev.truth.notes("slam", extras), *_lineage_notes(ev)]
    return Result(_with_notes(table, notes), records, extras, ev.truth.described("slam"), slam_files=files)


def _slam_side(frames: list[np.ndarray], times: np.ndarray, cfg, seed: int):
    """``(trajectory | None, registered fraction | None, failure reason | None)`` of SfM on one side."""
    from nsim.metrics.slam import run_colmap_slam
    from nsim.sfm.options import SfmOptions

    if len(frames) < 3:
        return None, None, f"SfM needs at least 3 frames, the sequence has {len(frames)}"
    options = SfmOptions(camera_model=cfg.camera_model, matcher=cfg.matcher, overlap=cfg.overlap,
                         loop_detection=cfg.matcher == "sequential" and len(frames) >= 20,
                         max_features=cfg.max_features, seed=seed, min_registered_fraction=cfg.min_registered_fraction)
    with tempfile.TemporaryDirectory(prefix="nsim-eval-slam-") as work:
        try:
            run = run_colmap_slam(frames, times.tolist(), work, options)
        except InputError as err:
            return None, None, f"SfM failed: {err}".replace(str(work), "<work>")
    return run.trajectory, run.registered_fraction, None


def _ate_or_na(truth, traj, cfg, side: str):
    from nsim.metrics.results_table import NotAvailable
    from nsim.metrics.trajectory import ate

    try:
        return ate(truth, traj, cfg.alignment, cfg.max_dt_s).rmse_m
    except InputError as err:
        return NotAvailable(f"ATE of SfM on {side} frames: {err}")


# ---------------------------------------------------------------------------------- detection
def _detection_columns():
    from nsim.metrics.paper_tables import detection_table

    return detection_table([{"scene": "-", "frame": 0, "n_sim": 0, "n_real": 0}]).columns


def _detector(ev: Evaluation):
    """``(name, image -> Detections)`` for hog / onnx; None for coco."""
    from nsim.metrics import detection as det

    cfg = ev.cfg.detection
    if cfg.detector == "hog":
        hog = det.HogPeopleDetector(det.HogConfig(upscale=cfg.hog_upscale, hit_threshold=cfg.hog_hit_threshold))
        return f"OpenCV HOG people detector (upscale {cfg.hog_upscale:g})", hog
    if cfg.detector == "onnx":
        if ev.inputs.onnx is None:
            raise InputError("detection.detector: onnx needs --onnx WEIGHTS")
        onnx = det.OnnxDetector(ev.inputs.onnx, det.OnnxConfig(decode=det.YoloDecodeConfig(classes=(det.PERSON_LABEL,))))
        return f"ONNX {ev.inputs.onnx.name} (person class)", onnx
    if ev.inputs.coco_sim is None or ev.inputs.coco_real is None:
        raise InputError("detection.detector: coco needs --coco-sim and --coco-real")
    return "COCO JSON given", None


def _coco_lookup(boxes: dict, name: str):
    from nsim.metrics.detection import Detections

    for key in (name, Path(name).name):
        if key in boxes:
            return boxes[key]
    return Detections.empty()


def upright_turns_of(sensor_to_body: np.ndarray) -> int:
    """Quarter turns (``np.rot90``'s k) that bring the world's up nearest to the image's up for a camera
    mounted ``sensor_to_body`` (4 x 4, OpenCV optical axes) on a level body (body z up): 0 for an upright
    camera; Spot's front cameras (rolled ~90 deg) 3, its right camera (mounted upside down) 2 -- how
    Spot's SDK rotates them for display."""
    up = np.asarray(sensor_to_body)[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # in the optical frame (y down)
    dx, dy = float(up[0]), float(up[1])
    best, score = 0, -math.inf
    for k in range(4):
        if -dy > score + 1e-9:
            best, score = k, -dy
        dx, dy = dy, -dx  # np.rot90(image, 1) turns the image direction (dx, dy) into (dy, -dx)
    return best


def upright_turns(sensor) -> int:
    """``upright_turns_of`` a rig sensor's mount."""
    return upright_turns_of(sensor.sensor_to_body)


def _people_notes(people: list[dict[str, Any]]) -> list[str]:
    """One line: in how many frames people are in view on each side, and how well the person masks agree."""
    if not people:
        return []
    n = len(people)
    sim = sum(p["people_px_sim"] > 0 for p in people)
    real = sum(p["people_px_real"] > 0 for p in people)
    ious = [p["mask_iou"] for p in people if p["mask_iou"] is not None]
    line = (f"people in view: {sim} of {n} simulated frames (render person masks), {real} of {n} real frames "
            f"(oracle actors)")
    if ious:
        line += f"; person mask IoU sim vs real {np.mean(ious):.3f} (mean over the {len(ious)} frames showing one)"
    return [line]


def table_detection(ev: Evaluation) -> Result:
    from nsim.metrics.detection import MatchConfig, compare_detections, read_coco_detections
    from nsim.metrics.paper_tables import detection_table
    from nsim.metrics.results_table import NotAvailable, Table

    cfg, truth = ev.cfg.detection, ev.truth
    if truth.source == "oracle":
        ev.require_mode("trajectory", "nsim render --trajectory RUN --rig nsim/configs/robots/spot.yaml --humans ...")
    name, detect = _detector(ev)
    coco = None
    if detect is None:
        coco = (read_coco_detections(ev.inputs.coco_sim), read_coco_detections(ev.inputs.coco_real))
    unavailable = truth.detection_unavailable(coco is not None)
    if unavailable is not None:
        r, reason, cams = unavailable
        columns = _detection_columns()
        rows = tuple({c.name: (cam if c.name == "Scene" else NotAvailable(reason)) for c in columns} for cam in cams)
        table = Table("Detection on simulated vs real frames", columns, rows, (f"detector: {name}",),
                      label="tab:detection")
        return Result(table, [], [{"render": r.id, "not_available": reason}], {r.id: "none (no people)"})
    records, extras, people = [], [], []
    turned: dict[str, int] = {}
    match = MatchConfig(iou_threshold=cfg.iou_threshold)
    for g in truth.detection_frames(coco is not None):
        turns = upright_turns_of(g.sensor_to_body) if cfg.upright and coco is None else 0
        if turns:
            turned[g.sensor] = turns
        sims, reals, numbers, frame_extras = [], [], [], []
        for p in g.frames:
            extra = {"group": g.sensor, "frame": p.index, "render": g.render.id, **p.extra}
            if coco is not None:
                sims.append(_coco_lookup(coco[0], p.key))
                reals.append(_coco_lookup(coco[1], p.key))
            else:
                extra["upright_turns"] = turns
                if "people_px_sim" in extra:
                    people.append(extra)
                sims.append(detect(np.ascontiguousarray(np.rot90(p.sim, turns))))
                reals.append(detect(np.ascontiguousarray(np.rot90(p.real, turns))))
            numbers.append(p.index)
            frame_extras.append(extra)
        comparison = compare_detections(sims, reals, match)
        for k, fm in enumerate(comparison.frames):
            records.append({"scene": g.sensor, "frame": numbers[k], "n_sim": fm.n_pred, "n_real": fm.n_ref,
                            "ious": tuple(float(v) for v in fm.ious), "detector": name})
            extras.append(frame_extras[k])
    table = detection_table(records, cfg.iou_threshold)
    if coco is None:
        notes = truth.notes("detection", extras)
        if turned:
            notes.append("frames turned upright before detecting (boxes in the turned frames): "
                         + ", ".join(f"{cam} {90 * k} deg counter-clockwise" for cam, k in turned.items()))
        notes += _people_notes(people)
    else:
        notes = [f"detections from {ev.inputs.coco_sim.name} (sim) and {ev.inputs.coco_real.name} (real)"]
    gt = {r.id: notes[0] for r in ev.renders}
    return Result(_with_notes(table, notes), records, extras, gt)


TABLE_FUNCTIONS = {"scenes": table_scenes, "spot-rgb": table_spot_rgb, "spot-depth": table_spot_depth,
                   "lidar": table_lidar, "slam": table_slam, "detection": table_detection}
