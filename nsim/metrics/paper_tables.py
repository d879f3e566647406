"""The paper's five tables and their plots, built from plain per-frame metric records.

Records are the dataclasses below or dicts with the same keys (unknown keys are an error, so a
typo never drops a value silently):

* ``ImageRecord(group, frame, psnr_db, ssim, lpips)``: one rendered frame against its ground truth;
  ``group`` is the environment (``scenes``) or the Spot camera (``spot-rgb``). ``lpips`` may be
  ``NotAvailable(reason)`` (no weights) or None (not computed).
* ``DepthRecord(group, frame, median_scaled, abs_rel=..., ...)``: the ``nsim.metrics.depth`` errors
  (``DepthErrors``) of one depth frame (``DepthRecord.from_metrics``).
* ``SlamRecord(sequence, ate_real_m, ate_sim_m, registered_real, registered_sim)``: one sequence
  (e.g. one Spot camera) of the SLAM experiment (``SlamComparison.record``).
* ``DetectionRecord(scene, frame, n_sim, n_real, ious, detector)``: one frame of the detection
  experiment (``DetectionComparison.records``).

Per group, image and depth metrics are means over frames (the convention of the NeRF and depth
benchmarks); SLAM rows end in the median over sequences, as the paper reports it; detection pools
every frame's boxes (mean IoU over matched pairs, precision and recall from summed counts).

``image_records`` and ``depth_records`` compute the records of one group from rendered and
ground-truth frames (checking that the frame counts agree).

Builders (``TABLE_BUILDERS`` by the names ``nsim evaluate --table`` uses): ``scenes_table``,
``spot_rgb_table``, ``spot_depth_table``, ``slam_table``, ``detection_table``, each returning a
``nsim.metrics.results_table.Table``. Plots (matplotlib, Agg canvas, no pyplot state), each written
atomically as a PNG and returning its path: ``plot_per_frame``, ``plot_bars``, ``plot_depth_error_map``
(of ``nsim.metrics.depth.depth_error_map``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.metrics.depth import DepthConfig, DepthErrors, DepthMetrics, depth_error_map, depth_metrics
from nsim.metrics.results_table import Column, NotAvailable, Table

# --------------------------------------------------------------------------------------
# Records
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageRecord:
    """Image metrics of one frame (module docstring)."""

    group: str
    frame: int
    psnr_db: float
    ssim: float
    lpips: float | NotAvailable | None = None


@dataclass(frozen=True)
class DepthRecord(DepthErrors):
    """Depth errors of one frame: ``group``, ``frame``, ``median_scaled`` and, by keyword, the fields of
    ``nsim.metrics.depth.DepthErrors`` (``abs_rel``, ..., ``delta_1_25_3``).
    """

    group: str
    frame: int
    median_scaled: bool = False

    @classmethod
    def from_metrics(cls, group: str, frame: int, metrics: DepthMetrics) -> DepthRecord:
        values = {f.name: getattr(metrics, f.name) for f in dataclasses.fields(cls) if hasattr(metrics, f.name)}
        return cls(group=group, frame=frame, **values)


@dataclass(frozen=True)
class SlamRecord:
    """ATE RMSE (metres) of SLAM on the real and on the simulated frames of one sequence; the
    registered fractions are optional (None: unknown).
    """

    sequence: str
    ate_real_m: float | NotAvailable
    ate_sim_m: float | NotAvailable
    registered_real: float | None = None
    registered_sim: float | None = None


@dataclass(frozen=True)
class DetectionRecord:
    """One frame of the detection experiment: box counts on each side and the IoU of each matched pair."""

    scene: str
    frame: int
    n_sim: int
    n_real: int
    ious: tuple[float, ...] = ()
    detector: str = ""


_NUMBER_FIELDS = {
    ImageRecord: ("psnr_db", "ssim", "lpips"),
    DepthRecord: tuple(f.name for f in dataclasses.fields(DepthErrors)),
    SlamRecord: ("ate_real_m", "ate_sim_m", "registered_real", "registered_sim"),
    DetectionRecord: (),
}
_LABEL_FIELD = {ImageRecord: "group", DepthRecord: "group", SlamRecord: "sequence", DetectionRecord: "scene"}


def _coerce(cls: type, record: object, table: str, k: int) -> Any:
    """``record`` as ``cls``: a dict is checked for unknown and missing keys; numbers must not be NaN."""
    where = f"{table} record {k}"
    if isinstance(record, Mapping):
        known = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(record) - set(known))
        if unknown:
            raise InputError(f"{where}: unknown field(s) {unknown}; expected {known}")
        required = [f.name for f in dataclasses.fields(cls)
                    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
        missing = [name for name in required if name not in record]
        if missing:
            raise InputError(f"{where}: missing field(s) {missing}")
        record = cls(**record)
    elif not isinstance(record, cls):
        raise InputError(f"{where}: expected a {cls.__name__} or a dict, got {type(record).__name__}")
    for name in _NUMBER_FIELDS[cls]:
        value = getattr(record, name)
        if value is None or isinstance(value, NotAvailable):
            continue
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise InputError(f"{where}: {name}: expected a number, got {value!r}")
        if math.isnan(value):
            raise InputError(f"{where}: {name} is NaN")
    label = _LABEL_FIELD[cls]
    if not isinstance(getattr(record, label), str):
        raise InputError(f"{where}: {label}: expected a string, got {getattr(record, label)!r}")
    if cls is DetectionRecord:
        for name in ("n_sim", "n_real"):
            value = getattr(record, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise InputError(f"{where}: {name}: expected an int, got {value!r}")
        if not isinstance(record.ious, (tuple, list, np.ndarray)):
            raise InputError(f"{where}: ious: expected a list of numbers, got {record.ious!r}")
        record = dataclasses.replace(record, ious=tuple(float(v) for v in record.ious))
        if min(record.n_sim, record.n_real) < 0 or len(record.ious) > min(record.n_sim, record.n_real):
            raise InputError(f"{where}: {len(record.ious)} matches but {record.n_sim} simulated and "
                             f"{record.n_real} real boxes")
        if not all(0.0 <= float(v) <= 1.0 for v in record.ious):
            raise InputError(f"{where}: ious must lie in [0, 1]")
    return record


def _records(cls: type, records: Iterable[object], table: str) -> list[Any]:
    out = [_coerce(cls, r, table, k) for k, r in enumerate(records)]
    if not out:
        raise InputError(f"{table}: no records")
    return out


def _groups(records: Sequence[Any], key: str) -> dict[str, list[Any]]:
    """Records by ``key``, groups in first-seen order."""
    out: dict[str, list[Any]] = {}
    for r in records:
        out.setdefault(getattr(r, key), []).append(r)
    return out


def _mean(values: Sequence[float | NotAvailable | None], what: str) -> float | NotAvailable:
    """Mean of a group's values; n/a (with the first reason) if any frame has none."""
    for v in values:
        if isinstance(v, NotAvailable):
            return v
        if v is None:
            return NotAvailable(f"{what} not computed")
    return float(np.mean(values))


def _nan_to_na(value: float, reason: str) -> float | NotAvailable:
    return NotAvailable(reason) if isinstance(value, float) and math.isnan(value) else value


# --------------------------------------------------------------------------------------
# Records from frames
# --------------------------------------------------------------------------------------


def _paired(group: str, preds: Sequence[np.ndarray], targets: Sequence[np.ndarray], masks: Sequence | None,
            frames: Sequence[int] | None, what: str) -> list[int]:
    if len(preds) != len(targets):
        raise InputError(f"{group}: {len(preds)} rendered {what} frames but {len(targets)} ground-truth frames")
    for name, seq in (("masks", masks), ("frame numbers", frames)):
        if seq is not None and len(seq) != len(preds):
            raise InputError(f"{group}: {len(preds)} {what} frames but {len(seq)} {name}")
    if not len(preds):
        raise InputError(f"{group}: no {what} frames")
    return list(frames) if frames is not None else list(range(len(preds)))


def image_records(
    group: str,
    preds: Sequence[np.ndarray],
    targets: Sequence[np.ndarray],
    lpips_net: str | None = "alex",
    masks: Sequence[np.ndarray | None] | None = None,
    frames: Sequence[int] | None = None,
    data_range: float = 1.0,
    device: str = "cpu",
) -> list[ImageRecord]:
    """PSNR, SSIM and LPIPS (``nsim.metrics.image`` / ``lpips``) of each rendered frame against its
    ground truth, (H, W, 3) float in [0, data_range]. lpips_net: "alex", "vgg" or None (not computed);
    missing weights give ``NotAvailable``. frames: frame numbers (default 0, 1, ...). Raises InputError,
    naming the group and frame, for differing frame counts or a bad pair.
    """
    from nsim.metrics.image import psnr, ssim
    from nsim.metrics.lpips import lpips_or_na

    numbers_ = _paired(group, preds, targets, masks, frames, "image")
    out = []
    for k, (pred, target) in enumerate(zip(preds, targets, strict=True)):
        mask = masks[k] if masks is not None else None
        try:
            lp = None
            if lpips_net is not None:
                scale = 1.0 / data_range
                lp = lpips_or_na(np.asarray(pred) * scale, np.asarray(target) * scale, lpips_net, mask, device=device)
            out.append(ImageRecord(group, numbers_[k], psnr(pred, target, mask, data_range),
                                   ssim(pred, target, mask, data_range), lp))
        except InputError as err:
            raise InputError(f"{group} frame {numbers_[k]}: {err}") from None
    return out


def depth_records(
    group: str,
    preds_m: Sequence[np.ndarray],
    gts_m: Sequence[np.ndarray],
    cfg: DepthConfig | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    frames: Sequence[int] | None = None,
) -> list[DepthRecord]:
    """``depth_metrics`` of each rendered depth frame against its ground truth (metres), as records.
    Raises InputError, naming the group and frame, for differing frame counts or a bad pair.
    """
    numbers_ = _paired(group, preds_m, gts_m, masks, frames, "depth")
    out = []
    for k, (pred, gt) in enumerate(zip(preds_m, gts_m, strict=True)):
        try:
            metrics = depth_metrics(pred, gt, cfg or DepthConfig(), masks[k] if masks is not None else None)
        except InputError as err:
            raise InputError(f"{group} frame {numbers_[k]}: {err}") from None
        out.append(DepthRecord.from_metrics(group, numbers_[k], metrics))
    return out


# --------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------

IMAGE_COLUMNS = (Column("PSNR", "higher", 2), Column("SSIM", "higher", 3), Column("LPIPS", "lower", 3))
DEPTH_COLUMNS = (
    Column("AbsRel", "lower", 3), Column("SqRel", "lower", 3), Column("RMSE [m]", "lower", 3),
    Column("logRMSE", "lower", 3),
    Column("δ<1.05", "higher", 3, r"$\delta_{1.05}$"), Column("δ<1.10", "higher", 3, r"$\delta_{1.10}$"),
    Column("δ<1.25", "higher", 3, r"$\delta_{1.25}$"), Column("δ<1.25²", "higher", 3, r"$\delta_{1.25^2}$"),
    Column("δ<1.25³", "higher", 3, r"$\delta_{1.25^3}$"),
)
#: Column name -> DepthErrors field (the columns list the errors in their order).
_DEPTH_FIELDS = dict(zip([c.name for c in DEPTH_COLUMNS], _NUMBER_FIELDS[DepthRecord], strict=True))
#: Depth columns of the scenes table (a summary; the spot-depth table has them all).
SCENE_DEPTH_COLUMNS = ("AbsRel", "RMSE [m]", "δ<1.25")
FRAMES = Column("frames")
DEFAULT_DEPTH_CFG = DepthConfig()


def _image_row(records: Sequence[ImageRecord]) -> dict[str, object]:
    return {"PSNR": float(np.mean([r.psnr_db for r in records])), "SSIM": float(np.mean([r.ssim for r in records])),
            "LPIPS": _mean([r.lpips for r in records], "LPIPS")}


def _depth_notes(records: Sequence[DepthRecord], cfg: DepthConfig | None, table: str) -> list[str]:
    scaled = {r.median_scaled for r in records}
    if len(scaled) > 1:
        raise InputError(f"{table}: records mix median-scaled and unscaled depth metrics")
    notes = ["depth metrics with median scaling (prediction x median(gt) / median(pred) per frame)"
             if scaled.pop() else "depth metrics without median scaling"]
    if cfg is not None:
        notes.append(f"depth over ground truth in [{cfg.min_depth_m:g}, {cfg.max_depth_m:g}] m")
    return notes


def scenes_table(
    image_records: Iterable[ImageRecord | Mapping[str, Any]],
    depth_records: Iterable[DepthRecord | Mapping[str, Any]] = (),
    depth_cfg: DepthConfig | None = None,
    title: str = "RGB image quality (and depth) per simulated environment",
) -> Table:
    """Per environment: PSNR ↑, SSIM ↑, LPIPS ↓ and, with depth records, AbsRel ↓, RMSE ↓, δ<1.25 ↑
    (means over frames; paper Table I). ``depth_cfg`` only adds its valid range to the notes.
    """
    images = _records(ImageRecord, image_records, "scenes")
    depths = [_coerce(DepthRecord, r, "scenes (depth)", k) for k, r in enumerate(depth_records)]
    by_image, by_depth = _groups(images, "group"), _groups(depths, "group")
    columns = [Column("Environment"), *IMAGE_COLUMNS]
    if depths:
        columns += [c for c in DEPTH_COLUMNS if c.name in SCENE_DEPTH_COLUMNS]
    columns.append(FRAMES)
    rows = []
    for group in [*by_image, *(g for g in by_depth if g not in by_image)]:
        row: dict[str, object] = {"Environment": group}
        if group in by_image:
            row.update(_image_row(by_image[group]))
            row["frames"] = len(by_image[group])
        else:
            row.update({c.name: NotAvailable("no image metrics for this environment") for c in IMAGE_COLUMNS})
            row["frames"] = len(by_depth[group])
        if depths:
            for name in SCENE_DEPTH_COLUMNS:
                row[name] = (float(np.mean([getattr(r, _DEPTH_FIELDS[name]) for r in by_depth[group]]))
                             if group in by_depth else NotAvailable("no depth metrics for this environment"))
        rows.append(row)
    notes = ["means over the frames of each environment"]
    if depths:
        notes += _depth_notes(depths, depth_cfg, "scenes")
    return Table(title, tuple(columns), tuple(rows), tuple(notes), label="tab:local-env")


def spot_rgb_table(records: Iterable[ImageRecord | Mapping[str, Any]],
                   title: str = "RGB image quality per simulated Spot camera") -> Table:
    """Per Spot camera (``group``): PSNR ↑, SSIM ↑, LPIPS ↓, means over frames (paper Table III)."""
    images = _records(ImageRecord, records, "spot-rgb")
    rows = [{"Camera": g, **_image_row(rs), "frames": len(rs)} for g, rs in _groups(images, "group").items()]
    return Table(title, (Column("Camera"), *IMAGE_COLUMNS, FRAMES), tuple(rows),
                 ("means over the frames of each camera",), label="tab:spot-sensors")


def spot_depth_table(records: Iterable[DepthRecord | Mapping[str, Any]], depth_cfg: DepthConfig | None = None,
                     title: str = "Depth error per simulated Spot depth camera") -> Table:
    """Per depth camera (``group``): AbsRel ↓, SqRel ↓, RMSE ↓, logRMSE ↓, δ<1.05 ... δ<1.25³ ↑, means
    over frames (paper Table II); the notes say whether predictions were median-scaled.
    """
    depths = _records(DepthRecord, records, "spot-depth")
    rows = []
    for group, rs in _groups(depths, "group").items():
        row: dict[str, object] = {"Camera": group}
        row.update({c.name: float(np.mean([getattr(r, _DEPTH_FIELDS[c.name]) for r in rs])) for c in DEPTH_COLUMNS})
        row["frames"] = len(rs)
        rows.append(row)
    notes = ["means over the frames of each camera", *_depth_notes(depths, depth_cfg, "spot-depth")]
    return Table(title, (Column("Camera"), *DEPTH_COLUMNS, FRAMES), tuple(rows), tuple(notes),
                 label="tab:spot_depth")


def slam_table(records: Iterable[SlamRecord | Mapping[str, Any]], alignment: str | None = "sim3",
               title: str = "SLAM on real vs simulated frames: absolute trajectory error") -> Table:
    """Per sequence: ATE real ↓, ATE sim ↓, Δ = sim − real, registered fractions when known; with two
    or more sequences a final ``median`` row (median real, median sim, their difference), as the
    paper reports it. ``alignment`` is stated in the notes.
    """
    slams = _records(SlamRecord, records, "slam")
    has_reg = any(r.registered_real is not None or r.registered_sim is not None for r in slams)
    columns = [Column("Sequence"), Column("ATE real [m]", "lower", 3), Column("ATE sim [m]", "lower", 3),
               Column("Δ sim−real [m]", None, 3)]
    if has_reg:
        columns += [Column("registered real", "higher", 2), Column("registered sim", "higher", 2)]

    def diff(real: object, sim: object) -> float | NotAvailable:
        for v in (real, sim):
            if isinstance(v, NotAvailable):
                return v
        return float(sim) - float(real)

    rows = []
    for r in slams:
        row: dict[str, object] = {"Sequence": r.sequence, "ATE real [m]": r.ate_real_m, "ATE sim [m]": r.ate_sim_m,
                                  "Δ sim−real [m]": diff(r.ate_real_m, r.ate_sim_m)}
        if has_reg:
            row["registered real"] = r.registered_real
            row["registered sim"] = r.registered_sim
        rows.append(row)
    notes = ["ATE: RMSE of camera positions after " + (f"{alignment.upper()} alignment" if alignment else
                                                        "alignment") + " to the ground truth"]
    footer = 0
    if len(slams) >= 2:
        medians = {}
        for side, name in (("ate_real_m", "ATE real [m]"), ("ate_sim_m", "ATE sim [m]")):
            values = [float(getattr(r, side)) for r in slams if not isinstance(getattr(r, side), NotAvailable)]
            medians[name] = float(np.median(values)) if values else NotAvailable("SLAM failed on every sequence")
            if 0 < len(values) < len(slams):
                notes.append(f"median of {name.split(' [')[0]} over the {len(values)} sequences with a result")
        rows.append({"Sequence": "median", **medians,
                     "Δ sim−real [m]": diff(medians["ATE real [m]"], medians["ATE sim [m]"])})
        footer = 1
    return Table(title, tuple(columns), tuple(rows), tuple(notes), footer_rows=footer, label="tab:slam")


def detection_table(records: Iterable[DetectionRecord | Mapping[str, Any]], iou_threshold: float | None = None,
                    title: str = "Detection on simulated vs real frames") -> Table:
    """Per scene (and detector, when records name more than one): mean IoU ↑ of the simulated boxes
    matched to the real ones, precision ↑ (matched / simulated boxes), recall ↑ (matched / real
    boxes), counts; with two or more rows a final ``all`` row pooling every frame.
    """
    dets = _records(DetectionRecord, records, "detection")
    detectors = list(dict.fromkeys(r.detector for r in dets))
    by_detector = len(detectors) > 1
    keys = list(dict.fromkeys((r.scene, r.detector) for r in dets))
    columns = [Column("Scene"), *([Column("Detector")] if by_detector else []), Column("IoU", "higher", 3),
               Column("precision", "higher", 3), Column("recall", "higher", 3), Column("matched"),
               Column("boxes sim"), Column("boxes real"), FRAMES]

    def pooled(rs: Sequence[DetectionRecord]) -> dict[str, object]:
        ious = [v for r in rs for v in r.ious]
        n_sim, n_real = sum(r.n_sim for r in rs), sum(r.n_real for r in rs)
        return {
            "IoU": float(np.mean(ious)) if ious else NotAvailable("no simulated box matched a real one"),
            "precision": len(ious) / n_sim if n_sim else NotAvailable("no box detected on the simulated frames"),
            "recall": len(ious) / n_real if n_real else NotAvailable("no box detected on the real frames"),
            "matched": len(ious), "boxes sim": n_sim, "boxes real": n_real, "frames": len(rs),
        }

    rows = []
    for scene, detector in keys:
        rs = [r for r in dets if (r.scene, r.detector) == (scene, detector)]
        rows.append({"Scene": scene, **({"Detector": detector} if by_detector else {}), **pooled(rs)})
    footer = 0
    if len(rows) >= 2:
        for detector in detectors:
            rs = [r for r in dets if r.detector == detector]
            rows.append({"Scene": "all", **({"Detector": detector} if by_detector else {}), **pooled(rs)})
            footer += 1
    notes = ["IoU: mean over matched box pairs; precision and recall from counts summed over frames"]
    if iou_threshold is not None:
        notes.append(f"a simulated box matches a real one at IoU >= {iou_threshold:g} (one-to-one)")
    if len(detectors) == 1 and detectors[0]:
        notes.append(f"detector: {detectors[0]}")
    return Table(title, tuple(columns), tuple(rows), tuple(notes), footer_rows=footer, label="tab:detection")


#: Table name (as ``nsim evaluate --table`` spells it) -> builder.
TABLE_BUILDERS: dict[str, Callable[..., Table]] = {
    "scenes": scenes_table,
    "spot-rgb": spot_rgb_table,
    "spot-depth": spot_depth_table,
    "slam": slam_table,
    "detection": detection_table,
}


# --------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------


def _save(fig: Any, path: str | os.PathLike) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from nsim.io import atomic_path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    return path


def _field(record: object, name: str) -> object:
    return record.get(name) if isinstance(record, Mapping) else getattr(record, name, None)


def _value(record: object, metric: str) -> float:
    value = _field(record, metric)
    if value is None or isinstance(value, NotAvailable):
        return math.nan
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"per-frame plot: {metric} is {value!r}, not a number")
    return float(value)


def plot_per_frame(path: str | os.PathLike, records: Iterable[object], metric: str, ylabel: str | None = None,
                   title: str | None = None) -> Path:
    """One line per group of ``metric`` against the frame index (records with ``group``, ``frame`` and
    the metric, as dataclasses or dicts; n/a values leave gaps). Raises InputError when no record
    has the metric.
    """
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    series: dict[str, list[tuple[float, float]]] = {}
    for k, r in enumerate(records):
        group, frame = _field(r, "group"), _field(r, "frame")
        if group is None or frame is None:
            raise InputError(f"per-frame plot: record {k} has no group or frame")
        series.setdefault(str(group), []).append((float(frame), _value(r, metric)))
    if not series or all(math.isnan(v) for pts in series.values() for _, v in pts):
        raise InputError(f"per-frame plot: no record has a value for {metric!r}")
    fig = Figure(figsize=(7.0, 3.5))
    ax = fig.add_subplot()
    for group, pts in series.items():
        pts.sort()
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=".", markersize=3, linewidth=1, label=group)
    ax.set_xlabel("frame")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel(ylabel or metric)
    ax.set_title(title or f"{metric} per frame")
    ax.grid(alpha=0.3)
    if len(series) > 1:
        ax.legend(fontsize="small")
    fig.tight_layout()
    return _save(fig, path)


def plot_bars(path: str | os.PathLike, table: Table, metrics: Sequence[str] | None = None,
              title: str | None = None) -> Path:
    """Grouped bars of a table's body rows (labels from its first column), one panel per metric
    (default: every column with a direction; the arrow is in the panel title). n/a bars are drawn
    as the text "n/a".
    """
    from matplotlib.figure import Figure

    directed = {c.name: c for c in table.columns}
    names = [c.name for c in table.columns if c.direction] if metrics is None else list(metrics)
    unknown = [m for m in names if m not in directed]
    if unknown or not names:
        raise ValueError(f"plot_bars: unknown or no metric column(s) {unknown or names} in {list(directed)}")
    body = table.rows[: len(table.rows) - table.footer_rows]
    labels = [str(r.get(table.columns[0].name)) for r in body]
    fig = Figure(figsize=(max(4.0, 2.8 * len(names)), 3.4))
    for k, name in enumerate(names):
        ax = fig.add_subplot(1, len(names), k + 1)
        values = [_value(r, name) for r in body]
        x = np.arange(len(labels))
        ok = ~np.isnan(values)
        ax.bar(x[ok], np.asarray(values)[ok], color="tab:blue")
        for xi in x[~ok]:
            ax.text(xi, 0.0, "n/a", ha="center", va="bottom", fontsize="small", color="0.4")
        ax.set_xlim(-0.6, len(labels) - 0.4)
        ax.set_xticks(x, labels, rotation=30, ha="right", fontsize="small")
        ax.set_title(directed[name].header)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title or table.title, fontsize="medium")
    fig.tight_layout()
    return _save(fig, path)


def plot_depth_error_map(path: str | os.PathLike, pred_m: np.ndarray, gt_m: np.ndarray,
                         cfg: DepthConfig = DEFAULT_DEPTH_CFG, mask: np.ndarray | None = None,
                         vmax: float | None = None, title: str | None = None) -> Path:
    """PNG of ``depth_error_map`` (colour map "magma", pixels that do not count in grey) with a colour
    bar labelled ``|pred − gt| / gt``; ``vmax`` defaults to the 99th percentile of the errors.
    """
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    err = depth_error_map(pred_m, gt_m, cfg, mask)
    finite = err[np.isfinite(err)]
    top = float(vmax) if vmax is not None else max(float(np.percentile(finite, 99)), 1e-6)
    cmap = colormaps["magma"].with_extremes(bad="0.6")
    h, w = err.shape
    fig = Figure(figsize=(min(10.0, 2.0 + 5.0 * w / max(h, w)), 5.0 * h / max(h, w) + 0.6))
    ax = fig.add_subplot()
    im = ax.imshow(np.ma.masked_invalid(err), cmap=cmap, vmin=0.0, vmax=top, interpolation="nearest")
    ax.set_axis_off()
    scaled = " (median-scaled)" if cfg.median_scaling else ""
    ax.set_title(title or f"relative depth error{scaled}, mean {float(finite.mean()):.3f}", fontsize="medium")
    fig.colorbar(im, ax=ax, label="|pred − gt| / gt", fraction=0.046, pad=0.04)
    fig.tight_layout()
    return _save(fig, path)
