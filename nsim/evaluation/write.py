"""Writing an evaluation's ``Result`` (``nsim.evaluation.evaluate_tables``) into its artifact folder.

Layout::

    evaluation.json            table, renders, ground-truth source per render, lineage, notes, counts
                               (and ``details`` where the table has more, e.g. colour-correction maps)
    <table>.md/.tex/.csv/.json the table (``nsim.metrics.results_table.Table.write_all``)
    records.json               per-frame records (the table's inputs) and per-frame extras
    plots/*_per_frame.png      per-frame metric curves, one line per group
    plots/bars.png             per-group bars of every metric column
    plots/depth_error/*.png    depth error maps of the first ``error_maps`` frames per group
    slam/<sequence>/{ground_truth,real,sim}.tum   (slam) the trajectories scored
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.errors import InputError

if TYPE_CHECKING:
    from nsim.evaluation.evaluate_tables import Evaluation, Result

log = logging.getLogger(__name__)


def jsonable(value: Any) -> Any:
    from nsim.metrics.results_table import NotAvailable

    if isinstance(value, NotAvailable):
        return {"not_available": value.reason}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else {"float": str(v)}
    if isinstance(value, np.integer):
        return int(value)
    return value


def rounded(value: Any) -> Any:
    """``value`` with every float (in dataclasses, dicts, lists, tuples) to 10 significant digits, no -0
    (``nsim.io.canonical``): a table computed from the same renders on another CPU, whose numpy sums and
    SIMD functions differ in the last bits, writes the same bytes (its files, plots and id)."""
    from nsim.io.canonical import round_float

    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {f.name: rounded(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init}
        return dataclasses.replace(value, **fields)
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(rounded(v) for v in value)
    if isinstance(value, (float, np.floating)) and not isinstance(value, bool):
        return round_float(value)
    return value


def write_result(out_dir: Path, table_name: str, renders: tuple[str, ...], ev: Evaluation, result: Result) -> None:
    """Write ``result`` of the evaluation ``ev`` (``nsim.evaluation.evaluate_tables.Evaluation``) of
    ``renders``; every number rounded first (:func:`rounded`)."""
    from nsim.io.tum import write_tum
    from nsim.metrics import paper_tables as pt

    result = dataclasses.replace(result, table=rounded(result.table), records=rounded(result.records),
                                 extras=rounded(result.extras), image_records=rounded(result.image_records),
                                 depth_records=rounded(result.depth_records), details=rounded(result.details))
    table = result.table
    table.write_all(out_dir, table_name)
    (out_dir / "records.json").write_text(json.dumps(
        {"table": table_name, "records": jsonable(result.records), "frames": jsonable(result.extras)},
        indent=1, sort_keys=True, allow_nan=False) + "\n")
    meta = {"table": table_name, "renders": list(renders), "ground_truth": result.ground_truth,
            "lineage": {r.id: r.lineage.note for r in ev.renders}, "notes": list(table.notes),
            "records": len(result.records)}
    if result.details:
        meta["details"] = result.details
    (out_dir / "evaluation.json").write_text(json.dumps(jsonable(meta), indent=1, sort_keys=True) + "\n")
    plots = out_dir / "plots"
    for records, metrics in ((result.image_records, (("psnr_db", "PSNR [dB]"), ("ssim", "SSIM"), ("lpips", "LPIPS"))),
                             (result.depth_records, (("abs_rel", "AbsRel"), ("delta_1_25", "δ<1.25")))):
        for metric, label in metrics if records else ():
            if _all_finite(getattr(r, metric) for r in records):
                _try_plot(pt.plot_per_frame, plots / f"{metric}_per_frame.png", records, metric, label)
            else:
                log.info("plot %s skipped: a value is infinite (a frame equal to its ground truth)", metric)
    body = table.rows[: len(table.rows) - table.footer_rows]
    bars = [c.name for c in table.columns if c.direction and _all_finite(r.get(c.name) for r in body)]
    if bars and body:
        pt.plot_bars(plots / "bars.png", table, bars)
    for group, frame, pred, gt, mask in result.error_maps:
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in group)
        _try_plot(pt.plot_depth_error_map, plots / "depth_error" / f"{safe}_{frame:06d}.png", pred, gt,
                  ev.cfg.depth_config(), mask)
    for seq, trajs in result.slam_files.items():
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in seq)
        (out_dir / "slam" / safe).mkdir(parents=True, exist_ok=True)
        for side, traj in trajs.items():
            write_tum(out_dir / "slam" / safe / f"{side}.tum", traj)


def _all_finite(values) -> bool:
    """No value is +-inf (n/a and None are fine: the plots leave gaps for them)."""
    return not any(isinstance(v, (int, float)) and math.isinf(v) for v in values)


def _try_plot(fn, path: Path, *args) -> None:
    """A plot that has nothing to show (every value n/a) is skipped, not an error."""
    try:
        fn(path, *args)
    except InputError as err:
        log.info("plot %s skipped: %s", path.name, err)
