"""How close a rebuilt artifact is to the original: file by file, in the terms of each file.

Training on another CPU or a GPU does not give identical bits, so ``nsim verify --rebuild`` asks
how far the rebuild is from the original and checks it against the tolerances of the artifact's
kind (:data:`TOLERANCES`, one table). Files with equal digests are counted, not read. Each other
file gives one :class:`FileDelta`:

=====================================  ===========================================================
file                                   figure (measure)
=====================================  ===========================================================
8-bit image (.png .jpg .pgm)           PSNR in dB (``psnr_db``; identical pixels: inf)
8-bit mask (grey, values {0, 255})     share of pixels that differ (``changed_share``)
16-bit PNG                             in a ``mask(s)/`` folder: share of pixels whose instance id
                                       differs; else PSNR over the 16-bit range
depth / LiDAR EXR                      max and median |difference| in metres over pixels finite in
                                       both (``max_abs_m``, ``median_abs_m``) and the share of
                                       pixels finite in one only (``invalid_share``); other float
                                       channels by ``max_rel``, integer channels by
                                       ``changed_share``
.npy / .npz arrays                     float: max |difference| / max |value| (``max_rel``);
                                       integer, bool, text: share of elements that differ
JSON, YAML, CSV                        same structure, keys and strings; numeric leaves by
                                       |difference| against ``abs + rel * |value|`` (``max_abs``,
                                       naming the worst key path); 4x4 rigid matrices as poses
TUM trajectory (.tum), 4x4 poses       max position difference in m, max rotation difference in
                                       degrees (``position_m``, ``rotation_deg``)
PLY                                    same vertex count: max and median position difference
                                       (``max_abs_m``, ``median_abs_m``); else the count change
                                       (``count_rel``) and the chamfer distance (``chamfer_m``)
torch checkpoint (.pt)                 read with ``weights_only=True`` (no code runs); per entry
                                       ``|a - b|_2 / |a|_2``, the worst reported (``rel_l2``)
anything else                          opaque: size change only (``bytes``)
=====================================  ===========================================================

Derived files (:data:`DERIVED_PATTERNS`) are pictures or other encodings of files that *are*
compared (previews, plots, videos, the Markdown/LaTeX renderings of a CSV table, the glTF twin of
a PLY mesh, the COLMAP binaries beside ``transforms.json`` and ``sparse_points.ply``, the COCO
``boxes.json`` of the instance masks): they are
reported as "not compared" and never fail a rebuild. An opaque file that is not derived and
differs fails it, as does a file on one side only, and a file that cannot be read (the note
says why). Nothing read is executed: no pickles, torch checkpoints only as weights, YAML with the
safe loader; paths must stay inside the artifact and files over :data:`MAX_COMPARE_BYTES` are not
read.
"""

from __future__ import annotations

import csv
import dataclasses
import fnmatch
import io
import json
import math
import re
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import torch
import yaml

from nsim.errors import InputError
from nsim.geometry.transforms import rotation_angle_deg
from nsim.io.coco import read_instance_mask
from nsim.io.exr import read_exr
from nsim.io.images import read_image, to_float
from nsim.io.npz import read_npz
from nsim.io.ply import read_ply
from nsim.io.tum import read_tum
from nsim.metrics.image import psnr
from nsim.metrics.lidar_realism import chamfer_distance
from nsim.workspace.store import safe_relpath


# ------------------------------------------------------------------------------- tolerances
@dataclass(frozen=True)
class KindTolerance:
    """How far a rebuilt file may be from the original, per measure (see the module docstring).

    min_psnr_db: 8-bit images: PSNR of the rebuild against the original, at least this.
    max_changed_share: masks, integer arrays / channels / tensors: share of elements that differ.
    max_depth_m: depth, range and point coordinates (EXR channels Z, X, Y, range) and PLY vertex
        positions: largest |difference| in metres over values finite in both (``inf`` where single
        pixels at depth edges may jump).
    max_depth_median_m: the same, median |difference|; also bounds a PLY's chamfer distance when
        the vertex counts differ.
    max_invalid_share: depth, arrays: share of values finite in one file and not in the other.
    max_position_m, max_rotation_deg: poses (TUM rows, 4x4 matrices in JSON): largest position
        difference in metres and geodesic rotation difference in degrees.
    max_metric_abs, max_metric_rel: JSON/YAML/CSV numbers a, b agree when
        ``|a - b| <= max_metric_abs + max_metric_rel * max(|a|, |b|)``.
    max_array_rel: float arrays and float EXR channels that are not metres:
        ``max |a - b| / max(|a|, |b|)``.
    max_param_rel: torch checkpoints: relative L2 difference of each float tensor.
    max_count_rel: PLY: relative change of the vertex count.
    metric_keys: when not empty, only JSON/YAML/CSV numbers under these keys (fnmatch patterns on the
        last key of their path) decide; the others are reported, not judged (a retrained model's loss curve
        and fitting diagnostics follow another path; what it scores must stay close).
    derived: more fnmatch patterns (on the path) of this kind's files that re-encode compared files and are
        not compared (see :data:`DERIVED_PATTERNS`).
    """

    min_psnr_db: float
    max_changed_share: float
    max_depth_m: float
    max_depth_median_m: float
    max_invalid_share: float
    max_position_m: float
    max_rotation_deg: float
    max_metric_abs: float
    max_metric_rel: float
    max_array_rel: float
    max_param_rel: float
    max_count_rel: float
    metric_keys: tuple[str, ...] = ()
    derived: tuple[str, ...] = ()


DETERMINISTIC = KindTolerance(
    min_psnr_db=40.0, max_changed_share=0.001, max_depth_m=0.01, max_depth_median_m=0.001,
    max_invalid_share=0.001, max_position_m=0.001, max_rotation_deg=0.05, max_metric_abs=1e-6,
    max_metric_rel=1e-6, max_array_rel=1e-5, max_param_rel=1e-5, max_count_rel=0.0,
)
"""Stages that compute in float64 numpy or copy data (the synthetic oracle, simulation, log
import, evaluation): another CPU changes last bits only; 8-bit images may move a level or two."""

SAME_MODEL = dataclasses.replace(
    DETERMINISTIC, min_psnr_db=35.0, max_changed_share=0.01, max_depth_m=math.inf,
    max_depth_median_m=0.01, max_invalid_share=0.01, max_metric_abs=1e-3, max_metric_rel=0.01,
    max_array_rel=0.01, max_count_rel=0.01,
)
"""Stages that evaluate a trained field (render, bake, export) on another device: float32 sums in
another order; a pixel on a depth edge can jump, so the depth bound is on the median."""

SFM = dataclasses.replace(
    DETERMINISTIC, max_position_m=0.005, max_rotation_deg=0.1, max_metric_abs=1e-3, max_metric_rel=0.05,
    max_depth_m=math.inf, max_depth_median_m=0.01, max_count_rel=0.02,
)
"""SfM (reconstruct, register-log): an optimisation (bundle adjustment) whose optimum moves with the last bits:
the tiny demo's 100-frame 160x120 reconstruction rebuilt under ATEN_CPU_CAPABILITY=default moved its cameras by
up to 1.2 mm and 0.012 deg and its distortion k1 by 1e-4; poses within 5 mm and 0.1 deg, numbers within 1e-3 + 5 %."""

QUALITY_KEYS = ("psnr", "psnr_half", "psnr_half_mean_embedding", "ssim", "ssim_half", "lpips", "lpips_half",
                "mask_iou", "psnr_box", "texture_psnr_fit", "depth_rel_error_median", "abs_rel", "nerf_fallback_share")
"""What a trained model scores (eval.json, baked.json): the numbers that decide a retrained artifact."""

RETRAINED = dataclasses.replace(
    SAME_MODEL, min_psnr_db=25.0, max_changed_share=0.1, max_depth_median_m=0.05,
    max_invalid_share=0.05, max_metric_rel=0.05, max_array_rel=0.05,
    max_param_rel=0.5, max_count_rel=0.05, metric_keys=QUALITY_KEYS,
    derived=("history.json", "obstacles.json", "occupancy.json"),
)
"""Stages that train or fit (scene, human, bake): the weights follow another path, so what they render and
score is held close (renders >= 25 dB, the scores of ``QUALITY_KEYS`` within 5 %, the walkable map's cells within
10 %: the tiny demo's 300-step scene retrained under ATEN_CPU_CAPABILITY=default moved 6.3 % of them), the
weights loosely; the loss curve (history.json) and the map's polygons (traced from obstacle_cells.npy) are not
judged."""

TOLERANCES: dict[str, KindTolerance] = {
    "capture": DETERMINISTIC,
    "poses": SFM,
    "scene-checkpoint": RETRAINED,
    "human-checkpoint": RETRAINED,
    # social forces integrated over hundreds of steps: last-bit differences grow a little
    "trajectory": dataclasses.replace(DETERMINISTIC, max_metric_rel=1e-4, max_array_rel=1e-4),
    "render": SAME_MODEL,
    "evaluation": dataclasses.replace(DETERMINISTIC, max_metric_abs=1e-4, max_metric_rel=1e-4),
    "export": SAME_MODEL,
    "recording": DETERMINISTIC,
    "registration": SFM,  # localised by SfM's matching and absolute poses
    "baked-scene": RETRAINED,  # a mesh and a texture fitted by gradient descent
}
"""The tolerance of each artifact kind (``nsim.workspace.store.KINDS``); re-tuned from measured rebuilds."""

DERIVED_PATTERNS = (
    "*.mp4", "*.gif", "*.md", "*.tex", "*.glb",  # videos, table renderings, the glTF twin of mesh.ply
    "*/preview/*", "preview/*", "*/plots/*", "plots/*",
    "sparse/*.bin",  # the COLMAP model behind transforms.json and sparse_points.ply
    "boxes.json", "*/boxes.json",  # COCO boxes and run-length encodings of the instance masks beside them
)
"""Files that are pictures or other encodings of compared files (fnmatch patterns on the path);
besides these, every picture at the artifact's top level (``preview.png``, ``curves.png``...),
as frames always live in folders."""

MAX_COMPARE_BYTES = 2 << 30
"""Files (and .npz members, uncompressed) larger than this are not read: reported as not compared."""

MAX_NESTING = 200
"""Deepest JSON/YAML nesting walked; deeper documents are reported as malformed."""

MAX_NODES = 20_000_000
"""Most values walked in one document (YAML aliases can make a small file a huge tree)."""

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm")
_METRE_CHANNELS = frozenset({"Z", "X", "Y", "range"})
_TIMESTAMP_ATOL_S = 1e-6


# ------------------------------------------------------------------------------- results
# measure -> (label, unit, higher is better); shares print as percentages
_MEASURES: dict[str, tuple[str, str, bool]] = {
    "psnr_db": ("PSNR", "dB", True),
    "changed_share": ("changed", "%", False),
    "max_abs_m": ("max |diff|", "m", False),
    "median_abs_m": ("median |diff|", "m", False),
    "invalid_share": ("valid in one only", "%", False),
    "max_rel": ("max |diff|/scale", "", False),
    "rel_l2": ("relative L2", "", False),
    "max_abs": ("|diff|", "", False),
    "position_m": ("max position diff", "m", False),
    "rotation_deg": ("max rotation diff", "deg", False),
    "count_rel": ("vertex count change", "%", False),
    "chamfer_m": ("chamfer", "m", False),
    "bytes": ("size change", "bytes", False),
}


def _fmt(measure: str, value: float) -> str:
    unit = _MEASURES.get(measure, ("", "", False))[1]
    if math.isinf(value):
        return f"{'-' if value < 0 else ''}inf {unit}".rstrip()
    if unit == "%":
        return f"{100.0 * value:.3g}%"
    if measure == "psnr_db":
        return f"{value:.1f} dB"
    if measure == "bytes":
        return f"{value:+.0f} bytes"
    return f"{value:.3g} {unit}".rstrip()


@dataclass(frozen=True)
class FileDelta:
    """How one differing file of a rebuild compares with the original.

    measure: the figure that decided (a key of the module's measure table, e.g. ``psnr_db``,
    ``max_abs_m``; ``bytes`` for files not compared; ``presence`` / ``structure`` / ``unreadable``
    when there is no figure). value, tolerance: the figure and its bound (None when there is none);
    ``psnr_db`` must be at least the tolerance, every other measure at most. within: inside the
    kind's tolerance. note: the other figures, or why there is no figure.
    """

    file: str
    measure: str
    value: float | None
    tolerance: float | None
    within: bool
    note: str = ""

    @property
    def higher_is_better(self) -> bool:
        return _MEASURES.get(self.measure, ("", "", False))[2]

    def load(self) -> float:
        """The share of the tolerance used: 0 far inside, 1 at the bound, > 1 outside (inf without a figure)."""
        if self.value is None or self.tolerance is None:
            return 0.0 if self.within else math.inf
        v, t = float(self.value), float(self.tolerance)
        if self.higher_is_better:
            return 0.0 if math.isinf(v) and v > 0 else (math.inf if v <= 0 else t / v)
        if v == 0:
            return 0.0
        return math.inf if t == 0 else (0.0 if math.isinf(t) else v / t)

    def figure(self) -> str:
        """The figure and its bound, e.g. ``PSNR 52.1 dB (tolerance >= 40.0 dB)``; the note when there is none."""
        if self.value is None:
            return self.note or self.measure
        label = _MEASURES.get(self.measure, (self.measure, "", False))[0]
        text = f"{label} {_fmt(self.measure, self.value)}"
        if self.tolerance is not None:
            text += f" (tolerance {'>=' if self.higher_is_better else '<='} {_fmt(self.measure, self.tolerance)})"
        return text

    def __str__(self) -> str:
        note = f"; {self.note}" if self.note and self.value is not None else ""
        return f"{self.file}: {self.figure()} {'ok' if self.within else 'OUTSIDE'}{note}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; non-finite figures become the strings ``"inf"``, ``"-inf"``, ``"nan"``."""
        def num(x: float | None) -> float | str | None:
            return x if x is None or math.isfinite(x) else str(x)

        return {"file": self.file, "measure": self.measure, "value": num(self.value),
                "tolerance": num(self.tolerance), "within": self.within, "note": self.note}


@dataclass(frozen=True)
class ArtifactComparison:
    """A rebuilt artifact against the original: ``identical`` files with equal digests, and one
    :class:`FileDelta` per other file (sorted by path)."""

    kind: str
    tolerance: KindTolerance
    identical: int
    deltas: tuple[FileDelta, ...]

    @property
    def within(self) -> bool:
        return all(d.within for d in self.deltas)

    @property
    def outside(self) -> tuple[FileDelta, ...]:
        return tuple(d for d in self.deltas if not d.within)

    def worst(self) -> FileDelta | None:
        """The first file outside tolerance, else the compared file closest to its bound."""
        if self.outside:
            return self.outside[0]
        compared = [d for d in self.deltas if d.value is not None and d.tolerance is not None]
        return max(compared, key=FileDelta.load) if compared else None

    def summary(self) -> str:
        """One line: how many files differ and the verdict with its figure."""
        n = len(self.deltas)
        if n == 0:
            return f"all {self.identical} files identical (only the manifest differs)"
        head = f"{n} file{'s' if n != 1 else ''} differ{'s' if n == 1 else ''}"
        worst = self.worst()
        if not self.within:
            assert worst is not None
            return f"{head}, {len(self.outside)} outside tolerance: {worst.file}: {worst.figure()}"
        tail = f" (worst: {worst.file}: {worst.figure()})" if worst is not None else ""
        return f"{head}, all within tolerance{tail}"


# ------------------------------------------------------------------------------- entry point
def compare_artifacts(
    old_dir: Path, new_dir: Path, kind: str,
    old_files: Mapping[str, Mapping[str, Any]], new_files: Mapping[str, Mapping[str, Any]],
) -> ArtifactComparison:
    """Compare artifact folder ``new_dir`` (a rebuild) with ``old_dir`` (the original).

    ``old_files`` / ``new_files``: the manifests' ``files`` sections, path -> ``{"sha256", "size"}``.
    Files with equal digests are counted as identical and not read; every other file, including
    one present on a single side, gives a :class:`FileDelta` judged by ``TOLERANCES[kind]``.
    """
    if kind not in TOLERANCES:
        raise ValueError(f"no tolerances for artifact kind {kind!r} (known: {', '.join(TOLERANCES)})")
    tol = TOLERANCES[kind]
    identical = 0
    deltas = []
    for rel in sorted(set(old_files) | set(new_files)):
        old, new = old_files.get(rel), new_files.get(rel)
        if old is not None and new is not None and old.get("sha256") == new.get("sha256"):
            identical += 1
        elif new is None:
            deltas.append(FileDelta(rel, "presence", None, None, False, "missing from the rebuild"))
        elif old is None:
            deltas.append(FileDelta(rel, "presence", None, None, False, "only in the rebuild"))
        else:
            deltas.append(compare_file(old_dir, new_dir, rel, tol))
    return ArtifactComparison(kind, tol, identical, tuple(deltas))


def is_derived(rel: str, extra: tuple[str, ...] = ()) -> bool:
    """True for a file that pictures or re-encodes compared files (see :data:`DERIVED_PATTERNS`; ``extra``:
    a kind's own, ``KindTolerance.derived``)."""
    p = PurePosixPath(rel)
    if len(p.parts) == 1 and p.suffix.lower() in _IMAGE_SUFFIXES:
        return True
    return any(fnmatch.fnmatchcase(rel, pat) for pat in (*DERIVED_PATTERNS, *extra))


class _Unreadable(Exception):
    """A file that cannot be compared; the message says why."""


_UNREADABLE = (_Unreadable, InputError, ValueError, OSError, EOFError, zipfile.BadZipFile, yaml.YAMLError,
               RecursionError, UnicodeDecodeError)


def compare_file(old_dir: Path, new_dir: Path, rel: str, tol: KindTolerance) -> FileDelta:
    """One file present in both folders, judged by ``tol``; never raises for a bad file."""
    suffix = PurePosixPath(rel).suffix.lower()
    try:
        a, b = _member(old_dir, rel), _member(new_dir, rel)
        size_a, size_b = a.stat().st_size, b.stat().st_size
        if is_derived(rel, tol.derived):
            return FileDelta(rel, "bytes", float(size_b - size_a), None, True, "derived file, not compared")
        if max(size_a, size_b) > MAX_COMPARE_BYTES:
            return FileDelta(rel, "bytes", float(size_b - size_a), None, False,
                             f"over {MAX_COMPARE_BYTES >> 20} MiB, not compared")
        compare = _COMPARERS.get(suffix)
        if compare is None:
            return FileDelta(rel, "bytes", float(size_b - size_a), None, False,
                             f"opaque {suffix or 'file'} differs; no numeric comparison for it")
        return compare(rel, a, b, tol)
    except _UNREADABLE as exc:
        return FileDelta(rel, "unreadable", None, None, False, f"unreadable: {_one_line(exc)}")


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:300]


def _member(root: Path, rel: str) -> Path:
    """``root / rel`` when ``rel`` is a safe manifest path naming a regular file inside ``root``."""
    if not safe_relpath(rel):
        raise _Unreadable(f"{rel!r} is not a path inside the artifact")
    path = root / rel
    for parent in [path, *path.parents]:
        if parent == root:
            break
        if parent.is_symlink():
            raise _Unreadable(f"{parent.relative_to(root)} is a symbolic link")
    if not path.is_file():
        raise _Unreadable(f"{path}: not a regular file")
    return path


# ------------------------------------------------------------------------------- judging
@dataclass(frozen=True)
class _Check:
    measure: str
    value: float
    tolerance: float

    @property
    def passed(self) -> bool:
        if math.isnan(self.value):
            return False
        if _MEASURES[self.measure][2]:
            return self.value >= self.tolerance
        return self.value <= self.tolerance

    def delta(self, rel: str, note: str = "") -> FileDelta:
        return FileDelta(rel, self.measure, self.value, self.tolerance, self.passed, note)


def _verdict(rel: str, checks: list[_Check], notes: list[str]) -> FileDelta:
    """The first failing check (else the one closest to its bound) as the figure; the others into the note."""
    failing = [c for c in checks if not c.passed]
    decider = failing[0] if failing else max(checks, key=lambda c: (c.delta(rel).load(), math.isfinite(c.tolerance)))
    others = [f"{_MEASURES[c.measure][0]} {_fmt(c.measure, c.value)}" for c in checks if c is not decider]
    return FileDelta(rel, decider.measure, decider.value, decider.tolerance, all(c.passed for c in checks),
                     "; ".join([*others, *notes]))


def _mismatch(rel: str, measure: str, note: str) -> FileDelta:
    return FileDelta(rel, measure, None, None, False, note)


# ------------------------------------------------------------------------------- images
def _compare_image(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    try:
        img_a = read_image(a)
    except InputError as exc:
        if "8-bit" not in str(exc):
            raise
        return _compare_png16(rel, a, b, tol)
    img_b = read_image(b)
    if img_a.shape != img_b.shape:
        return _mismatch(rel, "psnr_db", f"size {_hw(img_a)} -> {_hw(img_b)}")
    if _is_mask(img_a) and _is_mask(img_b):
        share = float(np.mean(img_a[..., 0] != img_b[..., 0]))
        return _verdict(rel, [_Check("changed_share", share, tol.max_changed_share)], ["mask"])
    value = psnr(to_float(img_b), to_float(img_a))
    return _verdict(rel, [_Check("psnr_db", value, tol.min_psnr_db)], [])


def _hw(image: np.ndarray) -> str:
    return f"{image.shape[1]}x{image.shape[0]}"


def _is_mask(rgb: np.ndarray) -> bool:
    """A grey image (all channels equal) whose values are only 0 and 255."""
    grey = rgb[..., 0]
    return bool((rgb[..., 1] == grey).all() and (rgb[..., 2] == grey).all() and np.isin(grey, (0, 255)).all())


def _compare_png16(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    """A single-channel 16-bit PNG: instance ids in a ``mask``/``masks`` folder (share of pixels whose
    id changed), else a 16-bit camera frame (PSNR over the 16-bit range)."""
    img_a, img_b = read_instance_mask(a), read_instance_mask(b)
    if img_a.shape != img_b.shape:
        return _mismatch(rel, "psnr_db", f"size {_hw(img_a)} -> {_hw(img_b)}")
    if {"mask", "masks"} & set(PurePosixPath(rel).parts[:-1]):
        share = float(np.mean(img_a != img_b))
        return _verdict(rel, [_Check("changed_share", share, tol.max_changed_share)], ["instance mask"])
    scale = float(np.iinfo(np.uint16).max)
    value = psnr(img_b.astype(np.float64) / scale, img_a.astype(np.float64) / scale)
    return _verdict(rel, [_Check("psnr_db", value, tol.min_psnr_db)], ["16-bit"])


# ------------------------------------------------------------------------------- EXR and arrays
def _compare_exr(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    return _compare_channels(rel, read_exr(a), read_exr(b), tol)


def _compare_channels(rel: str, chans_a: Mapping[str, np.ndarray], chans_b: Mapping[str, np.ndarray],
                      tol: KindTolerance) -> FileDelta:
    """Named (H, W) channels: metres (``_METRE_CHANNELS``) as depth, other floats by ``max_rel``,
    integers by ``changed_share``."""
    if set(chans_a) != set(chans_b):
        return _mismatch(rel, "structure", f"channels {sorted(chans_a)} -> {sorted(chans_b)}")
    metres: list[tuple[str, np.ndarray, np.ndarray]] = []
    others: dict[str, np.ndarray] = {}
    others_b: dict[str, np.ndarray] = {}
    for name in sorted(chans_a):
        x, y = chans_a[name], chans_b[name]
        if x.shape != y.shape:
            return _mismatch(rel, "structure", f"channel {name}: shape {x.shape} -> {y.shape}")
        if name in _METRE_CHANNELS and x.dtype.kind == "f" and y.dtype.kind == "f":
            metres.append((name, x, y))
        else:
            others[name], others_b[name] = x, y
    checks: list[_Check] = []
    notes: list[str] = []
    if metres:
        worst_max = worst_median = worst_invalid = 0.0
        where = ""
        for name, x, y in metres:
            x, y = x.astype(np.float64), y.astype(np.float64)
            fx, fy = np.isfinite(x), np.isfinite(y)
            both = fx & fy
            diff = np.abs(x[both] - y[both])
            if diff.size:
                if float(diff.max()) > worst_max or not where:
                    where = name
                worst_max = max(worst_max, float(diff.max()))
                worst_median = max(worst_median, float(np.median(diff)))
            worst_invalid = max(worst_invalid, float(np.mean(fx != fy)))
        checks += [_Check("max_abs_m", worst_max, tol.max_depth_m),
                   _Check("median_abs_m", worst_median, tol.max_depth_median_m),
                   _Check("invalid_share", worst_invalid, tol.max_invalid_share)]
        if len(metres) > 1 and where:
            notes.append(f"largest in channel {where}")
    if others:
        stats = _array_stats(others, others_b)
        checks += stats.checks(tol)
        notes += stats.notes
    if not checks:
        return _mismatch(rel, "structure", "no channels")
    return _verdict(rel, checks, notes)


@dataclass
class _ArrayStats:
    """The worst figures over named arrays (floats: max_rel and invalid share; others: changed share)."""

    max_rel: float | None = None
    max_rel_at: str = ""
    max_abs: float = 0.0
    invalid: float = 0.0
    changed: float | None = None
    changed_at: str = ""

    def checks(self, tol: KindTolerance) -> list[_Check]:
        out = []
        if self.max_rel is not None:
            out += [_Check("max_rel", self.max_rel, tol.max_array_rel),
                    _Check("invalid_share", self.invalid, tol.max_invalid_share)]
        if self.changed is not None:
            out.append(_Check("changed_share", self.changed, tol.max_changed_share))
        return out

    @property
    def notes(self) -> list[str]:
        notes = []
        if self.max_rel is not None:
            notes.append(f"max |diff| {self.max_abs:.3g}" + (f" in {self.max_rel_at}" if self.max_rel_at else ""))
        if self.changed and self.changed_at:
            notes.append(f"most changed: {self.changed_at}")
        return notes


def _array_stats(arrays_a: Mapping[str, np.ndarray], arrays_b: Mapping[str, np.ndarray]) -> _ArrayStats:
    """Compare arrays of equal names, shapes and dtype kinds (else _Unreadable naming the difference)."""
    if set(arrays_a) != set(arrays_b):
        raise _Unreadable(f"arrays {sorted(arrays_a)} -> {sorted(arrays_b)}")
    stats = _ArrayStats()
    for name in sorted(arrays_a):
        x, y = np.asarray(arrays_a[name]), np.asarray(arrays_b[name])
        label = name or "array"
        if x.shape != y.shape:
            raise _Unreadable(f"{label}: shape {x.shape} -> {y.shape}")
        if x.dtype.kind in "fc" and y.dtype.kind in "fc":
            wide = np.complex128 if "c" in (x.dtype.kind, y.dtype.kind) else np.float64
            x, y = x.astype(wide), y.astype(wide)
            fx, fy = np.isfinite(x), np.isfinite(y)
            both = fx & fy
            max_abs = float(np.abs(x[both] - y[both]).max()) if both.any() else 0.0
            scale = max(float(np.abs(x[both]).max()), float(np.abs(y[both]).max())) if both.any() else 0.0
            rel = 0.0 if max_abs == 0 else (math.inf if scale == 0 else max_abs / scale)
            # non-finite values must match exactly (NaN where NaN, +inf where +inf)
            same_nonfinite = np.where(~fx & ~fy, (np.isnan(x) & np.isnan(y)) | (x == y), True)
            invalid = float(np.mean((fx != fy) | ~same_nonfinite)) if x.size else 0.0
            if stats.max_rel is None or rel > stats.max_rel:
                stats.max_rel, stats.max_rel_at, stats.max_abs = rel, name, max_abs
            stats.invalid = max(stats.invalid, invalid)
        elif x.dtype.kind in "fc" or y.dtype.kind in "fc":
            raise _Unreadable(f"{label}: dtype {x.dtype} -> {y.dtype}")
        else:
            share = float(np.mean(x != y)) if x.size else 0.0
            if stats.changed is None or share > stats.changed:
                stats.changed, stats.changed_at = share, name
    return stats


def _compare_npy(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    def load(p: Path) -> np.ndarray:
        try:
            return np.load(p, allow_pickle=False, mmap_mode="r")
        except (ValueError, OSError, EOFError) as exc:
            raise _Unreadable(f"{p.name}: not a readable .npy array ({_one_line(exc)})") from None

    return _compare_named_arrays(rel, {"": load(a)}, {"": load(b)}, tol)


def _compare_npz(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    for p in (a, b):
        try:
            with zipfile.ZipFile(p) as zf:
                total = sum(info.file_size for info in zf.infolist())
        except zipfile.BadZipFile as exc:
            raise _Unreadable(f"{p.name}: not a readable .npz archive ({exc})") from None
        if total > MAX_COMPARE_BYTES:
            raise _Unreadable(f"{p.name}: {total >> 20} MiB uncompressed, over the {MAX_COMPARE_BYTES >> 20} MiB limit")
    return _compare_named_arrays(rel, read_npz(a), read_npz(b), tol)


def _compare_named_arrays(rel: str, arrays_a: Mapping[str, np.ndarray], arrays_b: Mapping[str, np.ndarray],
                          tol: KindTolerance) -> FileDelta:
    try:
        stats = _array_stats(arrays_a, arrays_b)
    except _Unreadable as exc:
        return _mismatch(rel, "structure", str(exc))
    checks = stats.checks(tol)
    if not checks:
        return _mismatch(rel, "structure", "no arrays")
    return _verdict(rel, checks, stats.notes)


# ------------------------------------------------------------------------------- documents
@dataclass
class _TreeDiff:
    """What walking two documents in parallel found."""

    tol: KindTolerance
    mismatches: list[str] = dataclasses.field(default_factory=list)
    n_mismatches: int = 0
    worst_leaf: tuple[float, str, float, float, float, float] | None = None  # load, path, diff, allowed, a, b
    worst_position: tuple[float, str] | None = None
    worst_rotation: tuple[float, str] | None = None
    worst_info: tuple[float, str, float, float, float, float] | None = None  # numbers outside metric_keys
    nodes: int = 0

    def mismatch(self, path: str, what: str) -> None:
        self.n_mismatches += 1
        if len(self.mismatches) < 3:
            self.mismatches.append(f"{path or '(top)'}: {what}")

    def leaf(self, path: str, a: float, b: float) -> None:
        if a == b or (math.isnan(a) and math.isnan(b)):
            diff = 0.0
        elif not (math.isfinite(a) and math.isfinite(b)):
            self.mismatch(path, f"{a!r} -> {b!r}")
            return
        else:
            diff = abs(a - b)
        allowed = self.tol.max_metric_abs + self.tol.max_metric_rel * max(abs(a), abs(b))
        load = 0.0 if diff == 0 else (math.inf if allowed == 0 else diff / allowed)
        if self.tol.metric_keys:
            key = re.sub(r"\[\d+\]$", "", path).rsplit(".", 1)[-1].lower()
            if not any(fnmatch.fnmatchcase(key, pat) for pat in self.tol.metric_keys):
                if self.worst_info is None or load > self.worst_info[0]:
                    self.worst_info = (load, path, diff, allowed, a, b)
                return
        if self.worst_leaf is None or load > self.worst_leaf[0]:
            self.worst_leaf = (load, path, diff, allowed, a, b)

    def pose(self, path: str, a: np.ndarray, b: np.ndarray) -> None:
        position = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
        rotation = float(rotation_angle_deg(a[:3, :3], b[:3, :3]))
        if self.worst_position is None or position > self.worst_position[0]:
            self.worst_position = (position, path)
        if self.worst_rotation is None or rotation > self.worst_rotation[0]:
            self.worst_rotation = (rotation, path)


_KEY_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _as_pose(x: Any) -> np.ndarray | None:
    """A 4x4 rigid-looking matrix (nested lists, last row 0 0 0 1) as an array, else None."""
    if not (isinstance(x, list) and len(x) == 4
            and all(isinstance(r, list) and len(r) == 4 and all(_is_number(v) for v in r) for r in x)):
        return None
    m = np.asarray(x, dtype=np.float64)
    if not np.isfinite(m).all() or not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), atol=1e-9):
        return None
    return m


def _walk(a: Any, b: Any, path: str, diff: _TreeDiff, depth: int = 0) -> None:
    """Walk two parsed documents in parallel, recording structure, leaf and pose differences."""
    if depth > MAX_NESTING:
        raise _Unreadable(f"nested deeper than {MAX_NESTING} levels at {path}")
    diff.nodes += 1
    if diff.nodes > MAX_NODES:
        raise _Unreadable(f"more than {MAX_NODES} values")
    pose_a, pose_b = _as_pose(a), _as_pose(b)
    if pose_a is not None and pose_b is not None:
        diff.pose(path, pose_a, pose_b)
    elif isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            gone, new = sorted(map(str, a.keys() - b.keys())), sorted(map(str, b.keys() - a.keys()))
            diff.mismatch(path, "keys differ" + (f"; missing {gone[:5]}" if gone else "")
                          + (f"; new {new[:5]}" if new else ""))
        for k in a:
            if k in b:
                key = str(k)
                sub = (f"{path}.{key}" if path else key) if _KEY_RE.match(key) else f"{path}[{json.dumps(key)}]"
                _walk(a[k], b[k], sub, diff, depth + 1)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diff.mismatch(path, f"length {len(a)} -> {len(b)}")
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            _walk(x, y, f"{path}[{i}]", diff, depth + 1)
    elif _is_number(a) and _is_number(b):
        diff.leaf(path, float(a), float(b))
    elif type(a) is not type(b) or a != b:
        diff.mismatch(path, f"{_short(a)} -> {_short(b)}")


def _short(x: Any) -> str:
    text = json.dumps(x) if isinstance(x, (str, int, float, bool, type(None))) else type(x).__name__
    return text if len(text) <= 40 else text[:37] + "..."


def _compare_documents(rel: str, doc_a: Any, doc_b: Any, tol: KindTolerance) -> FileDelta:
    diff = _TreeDiff(tol)
    _walk(doc_a, doc_b, "", diff)
    if diff.n_mismatches:
        more = f" (and {diff.n_mismatches - len(diff.mismatches)} more)" if diff.n_mismatches > len(diff.mismatches) else ""
        return _mismatch(rel, "structure", "; ".join(diff.mismatches) + more)
    checks: list[_Check] = []
    notes: list[str] = []
    if diff.worst_leaf is not None:
        _, path, d, allowed, a, b = diff.worst_leaf
        checks.append(_Check("max_abs", d, allowed))
        if d > 0:
            notes.append(f"at {path}: {a:.6g} -> {b:.6g}")
    if diff.worst_info is not None and diff.worst_info[2] > 0:
        _, path, d, _, a, b = diff.worst_info
        notes.append(f"not judged: {path}: {a:.6g} -> {b:.6g}")
    if diff.worst_position is not None and diff.worst_rotation is not None:
        checks += [_Check("position_m", diff.worst_position[0], tol.max_position_m),
                   _Check("rotation_deg", diff.worst_rotation[0], tol.max_rotation_deg)]
        if diff.worst_position[0] > 0:
            notes.append(f"position worst at {diff.worst_position[1]}")
        if diff.worst_rotation[0] > 0:
            notes.append(f"rotation worst at {diff.worst_rotation[1]}")
    if not checks:  # equal content in different bytes (formatting, key order), or only numbers not judged
        return FileDelta(rel, "max_abs", 0.0, tol.max_metric_abs, True, "; ".join(notes) or "same content, other bytes")
    return _verdict(rel, checks, notes)


def _read_text(p: Path) -> str:
    try:
        return p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise _Unreadable(f"{p.name}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def _load_json(p: Path) -> Any:
    try:
        return json.loads(_read_text(p))
    except json.JSONDecodeError as exc:
        raise _Unreadable(f"{p.name}: malformed JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None


def _load_yaml(p: Path) -> Any:
    try:
        return yaml.safe_load(_read_text(p))
    except yaml.YAMLError as exc:
        raise _Unreadable(f"{p.name}: malformed YAML ({_one_line(exc)})") from None


def _load_csv(p: Path) -> Any:
    """Rows as ``[i].column`` (under a header of distinct names), cells as numbers where they parse."""
    rows = list(csv.reader(io.StringIO(_read_text(p))))
    cells = [[_cell(c) for c in row] for row in rows]
    header = rows[0] if rows else []
    if header and len(set(header)) == len(header) and all(len(r) == len(header) for r in rows[1:]):
        return {"header": header, "rows": [dict(zip(header, r, strict=True)) for r in cells[1:]]}
    return cells


def _documents(load: Callable[[Path], Any]) -> Callable[[str, Path, Path, KindTolerance], FileDelta]:
    """A comparer of two documents read by ``load`` (JSON, YAML, CSV), walked in parallel."""
    def compare(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
        return _compare_documents(rel, load(a), load(b), tol)

    return compare


_compare_json, _compare_yaml, _compare_csv = _documents(_load_json), _documents(_load_yaml), _documents(_load_csv)


def _cell(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text


# ------------------------------------------------------------------------------- poses, points, weights
def _compare_tum(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    ta, tb = read_tum(a), read_tum(b)
    if len(ta) != len(tb):
        return _mismatch(rel, "position_m", f"{len(ta)} poses -> {len(tb)}")
    dt = float(np.abs(ta.timestamps_s - tb.timestamps_s).max())
    if dt > _TIMESTAMP_ATOL_S:
        return _mismatch(rel, "position_m", f"timestamps differ by up to {dt:.3g} s")
    position = float(np.linalg.norm(ta.positions_xyz - tb.positions_xyz, axis=1).max())
    rotation = float(rotation_angle_deg(ta.poses_se3()[:, :3, :3], tb.poses_se3()[:, :3, :3]).max())
    return _verdict(rel, [_Check("position_m", position, tol.max_position_m),
                          _Check("rotation_deg", rotation, tol.max_rotation_deg)], [f"{len(ta)} poses"])


def _compare_ply(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    xyz_a, xyz_b = read_ply(a).xyz.astype(np.float64), read_ply(b).xyz.astype(np.float64)
    n_a, n_b = len(xyz_a), len(xyz_b)
    if n_a == n_b:
        both = np.isfinite(xyz_a).all(axis=1) & np.isfinite(xyz_b).all(axis=1)
        d = np.linalg.norm(xyz_a[both] - xyz_b[both], axis=1)
        checks = [_Check("max_abs_m", float(d.max()) if d.size else 0.0, tol.max_depth_m),
                  _Check("median_abs_m", float(np.median(d)) if d.size else 0.0, tol.max_depth_median_m)]
        return _verdict(rel, checks, [f"{n_a} vertices, positions only"])
    count_rel = abs(n_b - n_a) / max(n_a, 1)
    checks = [_Check("count_rel", count_rel, tol.max_count_rel)]
    try:
        checks.append(_Check("chamfer_m", chamfer_distance(xyz_a, xyz_b).chamfer_m, tol.max_depth_median_m))
    except InputError:  # a cloud with no finite point: the count decides
        pass
    return _verdict(rel, checks, [f"vertices {n_a} -> {n_b}"])


def _compare_torch(rel: str, a: Path, b: Path, tol: KindTolerance) -> FileDelta:
    """A checkpoint read as weights only (no code runs); one that is not one is opaque: not compared."""
    def load(p: Path) -> Any:
        try:
            return torch.load(p, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - an untrusted file: whatever fails makes it opaque
            raise _Unreadable(f"{p.name}: not a weights-only checkpoint, compared as opaque bytes "
                              f"({type(exc).__name__}: {_one_line(exc)[:120]})") from None

    flat_a, flat_b = _flatten(load(a)), _flatten(load(b))
    if flat_a.keys() != flat_b.keys():
        gone, new = sorted(flat_a.keys() - flat_b.keys()), sorted(flat_b.keys() - flat_a.keys())
        return _mismatch(rel, "structure", f"entries differ; missing {gone[:5]}; new {new[:5]}")
    worst_rel, worst_at = None, ""
    changed, changed_at = None, ""
    plain_a, plain_b = {}, {}
    for key in sorted(flat_a):
        x, y = flat_a[key], flat_b[key]
        if isinstance(x, torch.Tensor) and isinstance(y, torch.Tensor):
            if x.shape != y.shape:
                return _mismatch(rel, "structure", f"{key}: shape {tuple(x.shape)} -> {tuple(y.shape)}")
            if x.is_floating_point() and y.is_floating_point():
                x, y = x.detach().double(), y.detach().double()
                num, den = float(torch.linalg.vector_norm(x - y)), float(torch.linalg.vector_norm(x))
                r = 0.0 if num == 0 else (math.inf if den == 0 or not math.isfinite(num) else num / den)
                if worst_rel is None or r > worst_rel:
                    worst_rel, worst_at = r, key
            elif x.is_floating_point() or y.is_floating_point() or x.is_complex() or y.is_complex():
                return _mismatch(rel, "structure", f"{key}: dtype {x.dtype} -> {y.dtype}")
            else:
                share = float((x != y).double().mean()) if x.numel() else 0.0
                if changed is None or share > changed:
                    changed, changed_at = share, key
        elif isinstance(x, torch.Tensor) or isinstance(y, torch.Tensor):
            return _mismatch(rel, "structure", f"{key}: {type(x).__name__} -> {type(y).__name__}")
        else:
            plain_a[key], plain_b[key] = x, y
    checks: list[_Check] = []
    notes: list[str] = []
    if worst_rel is not None:
        checks.append(_Check("rel_l2", worst_rel, tol.max_param_rel))
        notes.append(f"worst entry {worst_at}")
    if changed is not None:
        checks.append(_Check("changed_share", changed, tol.max_changed_share))
        if changed:
            notes.append(f"most changed integer entry {changed_at}")
    if plain_a:
        plain = _compare_documents(rel, plain_a, plain_b, tol)
        if plain.value is None:
            return plain
        checks.append(_Check(plain.measure, plain.value, plain.tolerance if plain.tolerance is not None else 0.0))
        if plain.note:
            notes.append(plain.note)
    if not checks:
        return _mismatch(rel, "structure", "no entries")
    return _verdict(rel, checks, notes)


def _flatten(state: Any, prefix: str = "", out: dict[str, Any] | None = None, depth: int = 0) -> dict[str, Any]:
    """Nested dicts/lists/tuples of a checkpoint as ``{dotted path: leaf}``."""
    out = {} if out is None else out
    if depth > MAX_NESTING:
        raise _Unreadable(f"checkpoint nested deeper than {MAX_NESTING} levels at {prefix}")
    if isinstance(state, dict):
        for k, v in state.items():
            _flatten(v, f"{prefix}.{k}" if prefix else str(k), out, depth + 1)
    elif isinstance(state, (list, tuple)):
        for i, v in enumerate(state):
            _flatten(v, f"{prefix}[{i}]", out, depth + 1)
    else:
        out[prefix or "(top)"] = state
    return out


_COMPARERS: dict[str, Callable[[str, Path, Path, KindTolerance], FileDelta]] = {
    **dict.fromkeys(_IMAGE_SUFFIXES, _compare_image),
    ".exr": _compare_exr,
    ".npy": _compare_npy,
    ".npz": _compare_npz,
    ".json": _compare_json,
    ".yaml": _compare_yaml,
    ".yml": _compare_yaml,
    ".csv": _compare_csv,
    ".tum": _compare_tum,
    ".ply": _compare_ply,
    ".pt": _compare_torch,
    ".pth": _compare_torch,
}
"""File suffix (lower case) -> its comparison; any other suffix is opaque."""
