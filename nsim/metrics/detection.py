"""Detection on simulated vs real frames: box IoU, matching, detectors, COCO JSON.

The paper's detection experiment runs one detector on a simulated frame and on the matching real
frame and reports the IoU of the boxes that match between the two. Here the real frame's boxes are
the *reference* and the simulated frame's the *prediction*:

* ``box_iou(a_xyxy, b_xyxy) -> (N, M)``; boxes are ``(x0, y0, x1, y1)`` pixels, continuous
  coordinates (area ``(x1 - x0) * (y1 - y0)``, no +1); COCO's ``(x, y, w, h)`` converts with
  ``xywh_to_xyxy``.
* ``match_boxes``: one-to-one pairs with IoU >= ``iou_threshold``. ``"hungarian"`` maximises the
  summed IoU of the pairs (``scipy.optimize.linear_sum_assignment``); ``"greedy"`` takes pairs in
  descending IoU (ties: lower prediction index, then lower reference index). With
  ``class_aware`` only boxes of the same label can pair.
* Per frame: ``precision = matched / predictions``, ``recall = matched / references``,
  ``mean_iou`` over the matched pairs; ``nan`` where the denominator is 0. Over a sequence
  (``compare_detections``) the counts are summed first and the mean IoU is over every matched pair.

Detectors map an ``(H, W, 3)`` uint8 RGB image to ``Detections``: ``HogPeopleDetector`` (OpenCV's
Dalal-Triggs people detector, built in, offline; label ``PERSON_LABEL``), ``OnnxDetector`` (any
YOLO-style ONNX model through ``cv2.dnn``: letterboxed input, output decoded by ``decode_yolo``,
class-wise NMS), or detections read from COCO JSON (``read_coco_detections``).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from nsim.errors import InputError

MATCH_METHODS = ("hungarian", "greedy")
YOLO_FORMATS = ("yolov8", "yolov5", "end2end")
#: Label of HOG detections: "person" in the 80-class COCO order that YOLO models use.
PERSON_LABEL = 0


# --------------------------------------------------------------------------------------
# Boxes
# --------------------------------------------------------------------------------------


def _as_boxes(boxes: np.ndarray, what: str) -> np.ndarray:
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.size == 0:
        return np.zeros((0, 4))
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise InputError(f"{what}: expected (N, 4) boxes, got shape {boxes.shape}")
    if not np.isfinite(boxes).all():
        raise InputError(f"{what}: boxes contain NaN or inf")
    return boxes


def xywh_to_xyxy(boxes_xywh: np.ndarray) -> np.ndarray:
    """(N, 4) COCO ``(x, y, w, h)`` -> ``(x0, y0, x1, y1)``."""
    b = _as_boxes(boxes_xywh, "boxes")
    return np.column_stack([b[:, 0], b[:, 1], b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]])


def xyxy_to_xywh(boxes_xyxy: np.ndarray) -> np.ndarray:
    """(N, 4) ``(x0, y0, x1, y1)`` -> COCO ``(x, y, w, h)``."""
    b = _as_boxes(boxes_xyxy, "boxes")
    return np.column_stack([b[:, 0], b[:, 1], b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]])


def box_iou(a_xyxy: np.ndarray, b_xyxy: np.ndarray) -> np.ndarray:
    """(N, M) intersection over union of every pair; 0 where the union is empty.

    Raises InputError for boxes that are not (N, 4), are non-finite, or have x1 < x0 or y1 < y0.
    """
    a, b = _as_boxes(a_xyxy, "boxes a"), _as_boxes(b_xyxy, "boxes b")
    for what, boxes in (("boxes a", a), ("boxes b", b)):
        bad = (boxes[:, 2] < boxes[:, 0]) | (boxes[:, 3] < boxes[:, 1])
        if bad.any():
            raise InputError(f"{what}[{int(np.argmax(bad))}]: x1 < x0 or y1 < y0 in {boxes[bad][0].tolist()}")
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    w = np.clip(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0.0, None)
    h = np.clip(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0.0, None)
    inter = w * h
    union = area_a[:, None] + area_b[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0.0, inter / np.where(union > 0.0, union, 1.0), 0.0)


def box_iou_xywh(a_xywh: np.ndarray, b_xywh: np.ndarray) -> np.ndarray:
    """``box_iou`` for COCO ``(x, y, w, h)`` boxes."""
    return box_iou(xywh_to_xyxy(a_xywh), xywh_to_xyxy(b_xywh))


# --------------------------------------------------------------------------------------
# Detections and matching
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Detections:
    """The boxes found in one image.

    boxes_xyxy: (N, 4) float64 pixels; scores: (N,) float64 (1.0 where the source has none);
    labels: (N,) int64 class ids (the source's own: YOLO class index, COCO category_id, ...).
    """

    boxes_xyxy: np.ndarray
    scores: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        boxes = _as_boxes(self.boxes_xyxy, "Detections.boxes_xyxy")
        n = len(boxes)
        scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        labels = np.asarray(self.labels).reshape(-1)
        if scores.shape != (n,) or labels.shape != (n,):
            raise ValueError(f"Detections: {n} boxes but {scores.shape[0]} scores and {labels.shape[0]} labels")
        object.__setattr__(self, "boxes_xyxy", boxes)
        object.__setattr__(self, "scores", scores)
        object.__setattr__(self, "labels", labels.astype(np.int64))

    def __len__(self) -> int:
        return len(self.boxes_xyxy)

    @classmethod
    def empty(cls) -> Detections:
        return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64))


@dataclass(frozen=True, eq=False)
class FrameMatch:
    """Matches in one frame: ``pairs`` (K, 2) int (prediction index, reference index), ``ious`` (K,)."""

    pairs: np.ndarray
    ious: np.ndarray
    n_pred: int
    n_ref: int

    @property
    def n_matched(self) -> int:
        return len(self.ious)

    @property
    def precision(self) -> float:
        return self.n_matched / self.n_pred if self.n_pred else math.nan

    @property
    def recall(self) -> float:
        return self.n_matched / self.n_ref if self.n_ref else math.nan

    @property
    def mean_iou(self) -> float:
        return float(self.ious.mean()) if len(self.ious) else math.nan


@dataclass(frozen=True)
class MatchConfig:
    """How boxes pair up (module docstring)."""

    iou_threshold: float = 0.5
    method: str = "hungarian"
    class_aware: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.iou_threshold <= 1.0:
            raise ValueError(f"MatchConfig.iou_threshold: expected a value in (0, 1], got {self.iou_threshold!r}")
        if self.method not in MATCH_METHODS:
            raise ValueError(f"MatchConfig.method: expected one of {MATCH_METHODS}, got {self.method!r}")


def match_boxes(pred: Detections, ref: Detections, cfg: MatchConfig = MatchConfig()) -> FrameMatch:
    """One-to-one matches of ``pred`` to ``ref`` with IoU >= ``cfg.iou_threshold`` (module docstring)."""
    iou = box_iou(pred.boxes_xyxy, ref.boxes_xyxy)
    if cfg.class_aware and iou.size:
        iou = np.where(pred.labels[:, None] == ref.labels[None, :], iou, 0.0)
    ok = iou >= cfg.iou_threshold
    if not ok.any():
        return FrameMatch(np.zeros((0, 2), np.int64), np.zeros(0), len(pred), len(ref))
    if cfg.method == "hungarian":
        rows, cols = linear_sum_assignment(np.where(ok, iou, 0.0), maximize=True)
        keep = ok[rows, cols]
        pairs = np.column_stack([rows[keep], cols[keep]]).astype(np.int64)
    else:
        i, j = np.nonzero(ok)
        order = np.lexsort((j, i, -iou[i, j]))  # descending IoU, then prediction, then reference index
        used_i, used_j, pairs_list = set(), set(), []
        for k in order:
            if i[k] not in used_i and j[k] not in used_j:
                used_i.add(i[k])
                used_j.add(j[k])
                pairs_list.append((i[k], j[k]))
        pairs = np.array(sorted(pairs_list), dtype=np.int64).reshape(-1, 2)
    return FrameMatch(pairs, iou[pairs[:, 0], pairs[:, 1]], len(pred), len(ref))


@dataclass(frozen=True, eq=False)
class DetectionComparison:
    """Simulated (prediction) against real (reference) detections over a sequence of frames.

    frames: one ``FrameMatch`` per frame; the totals are sums over frames, ``mean_iou`` the mean
    over every matched pair, precision and recall from the summed counts (``nan`` for 0 / 0).
    """

    frames: tuple[FrameMatch, ...]
    config: MatchConfig

    @property
    def n_pred(self) -> int:
        return sum(f.n_pred for f in self.frames)

    @property
    def n_ref(self) -> int:
        return sum(f.n_ref for f in self.frames)

    @property
    def n_matched(self) -> int:
        return sum(f.n_matched for f in self.frames)

    @property
    def ious(self) -> np.ndarray:
        return np.concatenate([f.ious for f in self.frames]) if self.frames else np.zeros(0)

    @property
    def mean_iou(self) -> float:
        ious = self.ious
        return float(ious.mean()) if len(ious) else math.nan

    @property
    def precision(self) -> float:
        return self.n_matched / self.n_pred if self.n_pred else math.nan

    @property
    def recall(self) -> float:
        return self.n_matched / self.n_ref if self.n_ref else math.nan

    def records(self, scene: str, detector: str = "") -> list[dict[str, Any]]:
        """Per-frame records for ``nsim.metrics.paper_tables.detection_table``."""
        return [
            {"scene": scene, "detector": detector, "frame": k, "n_sim": f.n_pred, "n_real": f.n_ref,
             "ious": tuple(float(v) for v in f.ious)}
            for k, f in enumerate(self.frames)
        ]


def compare_detections(
    sim: Sequence[Detections], real: Sequence[Detections], cfg: MatchConfig = MatchConfig()
) -> DetectionComparison:
    """Match each simulated frame's boxes to its real frame's; InputError if the frame counts differ."""
    if len(sim) != len(real):
        raise InputError(f"detection: {len(sim)} simulated frames but {len(real)} real frames")
    return DetectionComparison(tuple(match_boxes(s, r, cfg) for s, r in zip(sim, real, strict=True)), cfg)


# --------------------------------------------------------------------------------------
# NMS and YOLO decoding
# --------------------------------------------------------------------------------------


def nms(boxes_xyxy: np.ndarray, scores: np.ndarray, iou_threshold: float,
        labels: np.ndarray | None = None) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression, in descending score order.

    A box is dropped when its IoU with a kept, higher-scoring box (of the same label, when
    ``labels`` is given) exceeds ``iou_threshold``. Equal scores keep the lower index first.
    """
    boxes = _as_boxes(boxes_xyxy, "nms boxes")
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    order = np.argsort(-scores, kind="stable")
    iou = box_iou(boxes, boxes)
    if labels is not None:
        labels = np.asarray(labels).reshape(-1)
        iou = np.where(labels[:, None] == labels[None, :], iou, 0.0)
    suppressed = np.zeros(len(boxes), bool)
    keep = []
    for i in order:
        if suppressed[i]:
            continue
        keep.append(i)
        suppressed |= iou[i] > iou_threshold
    return np.array(keep, dtype=np.int64)


@dataclass(frozen=True)
class Letterbox:
    """How an image was fitted into the network input: ``input = image * scale + (pad_x, pad_y)``."""

    scale: float
    pad_x: float
    pad_y: float

    def to_image(self, boxes_xyxy: np.ndarray) -> np.ndarray:
        """Boxes from network-input pixels back to image pixels."""
        b = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
        return (b - np.array([self.pad_x, self.pad_y, self.pad_x, self.pad_y])) / self.scale


def letterbox(image: np.ndarray, size_wh: tuple[int, int], fill: int = 114) -> tuple[np.ndarray, Letterbox]:
    """Resize keeping the aspect ratio and pad (centred) to ``size_wh``, as YOLO models expect."""
    h, w = image.shape[:2]
    W, H = size_wh
    scale = min(W / w, H / h)
    nw, nh = round(w * scale), round(h * scale)
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (w, h) else image
    pad_x, pad_y = (W - nw) // 2, (H - nh) // 2
    out = np.full((H, W, image.shape[2]), fill, dtype=image.dtype)
    out[pad_y : pad_y + nh, pad_x : pad_x + nw] = resized
    return out, Letterbox(scale, float(pad_x), float(pad_y))


@dataclass(frozen=True)
class YoloDecodeConfig:
    """How to read a YOLO-style output tensor.

    format: "yolov8" rows ``(cx, cy, w, h, class scores...)`` (the (1, 4 + C, N) layout is
    transposed automatically); "yolov5" rows ``(cx, cy, w, h, objectness, class scores...)``,
    score = objectness x class score; "end2end" rows ``(x0, y0, x1, y1, score, class)`` (NMS
    already done in the model, none applied here). layout: "rows" ``(N, K)``, "columns" ``(K, N)``
    (YOLOv8's export), or "auto": the longer axis holds the candidates (right for real models, which
    have thousands). score_threshold: boxes below are dropped; nms_iou: class-wise NMS threshold;
    classes: keep only these labels (None: all).
    """

    format: str = "yolov8"
    layout: str = "auto"
    score_threshold: float = 0.25
    nms_iou: float = 0.45
    classes: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if self.format not in YOLO_FORMATS:
            raise ValueError(f"YoloDecodeConfig.format: expected one of {YOLO_FORMATS}, got {self.format!r}")
        if self.layout not in ("auto", "rows", "columns"):
            raise ValueError(f"YoloDecodeConfig.layout: expected auto, rows or columns, got {self.layout!r}")
        if not 0.0 <= self.score_threshold <= 1.0:
            raise ValueError(f"YoloDecodeConfig.score_threshold: expected [0, 1], got {self.score_threshold!r}")
        if not 0.0 < self.nms_iou <= 1.0:
            raise ValueError(f"YoloDecodeConfig.nms_iou: expected (0, 1], got {self.nms_iou!r}")


def decode_yolo(output: np.ndarray, cfg: YoloDecodeConfig = YoloDecodeConfig(),
                box: Letterbox = Letterbox(1.0, 0.0, 0.0)) -> Detections:
    """Detections from one image's raw output ``(1, N, K)``, ``(1, K, N)`` or ``(N, K)`` (config doc),
    boxes mapped back through ``box``. Raises InputError for an output too narrow for the format.
    """
    out = np.asarray(output, dtype=np.float64)
    if out.ndim == 3:
        if out.shape[0] != 1:
            raise InputError(f"YOLO output: expected a batch of 1, got shape {out.shape}")
        out = out[0]
    if out.ndim != 2:
        raise InputError(f"YOLO output: expected (1, N, K) or (1, K, N), got shape {np.shape(output)}")
    min_k = {"yolov8": 5, "yolov5": 6, "end2end": 6}[cfg.format]
    if cfg.layout == "columns" or (cfg.layout == "auto" and out.shape[0] < out.shape[1]):
        out = out.T  # (K, N) -> (N, K)
    if out.shape[1] < min_k:
        raise InputError(f"YOLO output ({cfg.format}): rows need at least {min_k} values, got shape {out.shape}")
    if cfg.format == "end2end":
        boxes, scores, labels = out[:, :4], out[:, 4], np.rint(out[:, 5]).astype(np.int64)
    else:
        cls_scores = out[:, 4:] if cfg.format == "yolov8" else out[:, 5:] * out[:, 4:5]
        labels = np.argmax(cls_scores, axis=1)
        scores = cls_scores[np.arange(len(out)), labels]
        cx, cy, w, h = out[:, 0], out[:, 1], out[:, 2], out[:, 3]
        boxes = np.column_stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
    keep = scores >= cfg.score_threshold
    if cfg.classes is not None:
        keep &= np.isin(labels, cfg.classes)
    boxes, scores, labels = boxes[keep], scores[keep], labels[keep]
    if cfg.format != "end2end" and len(boxes):
        k = nms(boxes, scores, cfg.nms_iou, labels)
        boxes, scores, labels = boxes[k], scores[k], labels[k]
    return Detections(box.to_image(boxes), scores, labels)


# --------------------------------------------------------------------------------------
# Detectors
# --------------------------------------------------------------------------------------

#: A detector: (H, W, 3) uint8 RGB image -> Detections.
Detector = Callable[[np.ndarray], Detections]


def _check_rgb(image: np.ndarray, what: str = "image") -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"{what}: expected an (H, W, 3) uint8 RGB image, got {image.dtype} {image.shape}")
    return image


@dataclass(frozen=True)
class HogConfig:
    """``cv2.HOGDescriptor.detectMultiScale`` settings (pixels) and the NMS applied after it.

    hit_threshold: SVM margin below which windows are dropped (the score is the margin);
    upscale: images are enlarged by this factor first (the window is 64x128 px, so people
    shorter than about 128 / upscale px are missed); nms_iou: NMS on the raw windows.
    """

    win_stride_px: int = 8
    padding_px: int = 8
    scale: float = 1.05
    hit_threshold: float = 0.0
    upscale: float = 1.0
    nms_iou: float = 0.45

    def __post_init__(self) -> None:
        if self.win_stride_px < 1 or self.padding_px < 0:
            raise ValueError("HogConfig: win_stride_px must be >= 1 and padding_px >= 0")
        if not self.scale > 1.0 or not self.upscale > 0.0:
            raise ValueError(f"HogConfig: scale must be > 1 and upscale > 0, got {self.scale}, {self.upscale}")


class HogPeopleDetector:
    """OpenCV's default HOG + linear SVM people detector (no weights to download); label ``PERSON_LABEL``."""

    def __init__(self, cfg: HogConfig = HogConfig()) -> None:
        self.cfg = cfg
        self._hog = cv2.HOGDescriptor()
        self._hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def raw(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``detectMultiScale``'s windows (N, 4) xywh and margins (N,) before NMS, in input pixels."""
        cfg = self.cfg
        image = _check_rgb(image)
        if cfg.upscale != 1.0:
            image = cv2.resize(image, None, fx=cfg.upscale, fy=cfg.upscale, interpolation=cv2.INTER_LINEAR)
        win_w, win_h = self._hog.winSize
        if image.shape[0] < win_h or image.shape[1] < win_w:
            # OpenCV 5.0's detectMultiScale corrupts memory (segfaults) on images smaller than its window
            raise InputError(f"HOG: image is {image.shape[1]}x{image.shape[0]} px (after upscale), smaller than "
                             f"the {win_w}x{win_h} px detection window; raise HogConfig.upscale")
        s, p = (cfg.win_stride_px,) * 2, (cfg.padding_px,) * 2
        rects, weights = self._hog.detectMultiScale(
            np.ascontiguousarray(image[..., ::-1]), hitThreshold=cfg.hit_threshold, winStride=s, padding=p,
            scale=cfg.scale)
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4) / cfg.upscale
        return rects, np.asarray(weights, dtype=np.float64).reshape(-1)

    def __call__(self, image: np.ndarray) -> Detections:
        rects, weights = self.raw(image)
        boxes = xywh_to_xyxy(rects)
        keep = nms(boxes, weights, self.cfg.nms_iou)
        return Detections(boxes[keep], weights[keep], np.full(len(keep), PERSON_LABEL, np.int64))


@dataclass(frozen=True)
class OnnxConfig:
    """Input of an ONNX detector: ``input_wh`` network size (letterboxed), RGB scaled to [0, 1]
    (``swap_rb`` False for models trained on BGR); ``decode`` reads its output.
    """

    input_wh: tuple[int, int] = (640, 640)
    swap_rb: bool = True
    decode: YoloDecodeConfig = field(default_factory=YoloDecodeConfig)

    def __post_init__(self) -> None:
        if len(self.input_wh) != 2 or min(self.input_wh) < 1:
            raise ValueError(f"OnnxConfig.input_wh: expected (width, height) >= 1, got {self.input_wh!r}")


class OnnxDetector:
    """Any YOLO-style ONNX model through ``cv2.dnn`` (CPU). Raises InputError for a missing or
    unreadable weights file.
    """

    def __init__(self, weights_path: str | os.PathLike, cfg: OnnxConfig = OnnxConfig()) -> None:
        path = Path(weights_path)
        if not path.is_file():
            raise InputError(f"{path}: no such ONNX weights file")
        try:
            self._net = cv2.dnn.readNetFromONNX(str(path))
        except cv2.error as err:
            message = str(err).strip().splitlines()[-1] if str(err).strip() else "unknown error"
            raise InputError(f"{path}: OpenCV cannot read this ONNX model ({message})") from None
        self.path, self.cfg = path, cfg

    def raw(self, image: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """The network's first output for ``image`` and the letterbox that fitted it."""
        image = _check_rgb(image)
        fitted, box = letterbox(image if self.cfg.swap_rb else image[..., ::-1], self.cfg.input_wh)
        blob = cv2.dnn.blobFromImage(fitted, 1.0 / 255.0, self.cfg.input_wh, swapRB=False, crop=False)
        self._net.setInput(blob)
        try:
            out = self._net.forward()
        except cv2.error as err:
            raise InputError(f"{self.path}: inference failed ({str(err).strip().splitlines()[-1]})") from None
        return np.asarray(out), box

    def __call__(self, image: np.ndarray) -> Detections:
        out, box = self.raw(image)
        return decode_yolo(out, self.cfg.decode, box)


def _load_image(item: np.ndarray | str | os.PathLike, what: str) -> np.ndarray:
    if isinstance(item, (str, os.PathLike)):
        from nsim.io.images import read_image, to_uint8

        image = read_image(item)
        image = to_uint8(image) if image.dtype != np.uint8 else image
        if image.ndim == 2:
            image = np.repeat(image[..., None], 3, axis=2)
        return image[..., :3]
    return _check_rgb(item, what)


def detect_images(detector: Detector, images: Sequence[np.ndarray | str | os.PathLike]) -> list[Detections]:
    """Run ``detector`` on each image (arrays, or paths read with ``nsim.io.images.read_image``)."""
    return [detector(_load_image(im, f"image {k}")) for k, im in enumerate(images)]


# --------------------------------------------------------------------------------------
# COCO JSON
# --------------------------------------------------------------------------------------


def _coco_bbox(path: Path, where: str, bbox: object) -> list[float]:
    if (not isinstance(bbox, list) or len(bbox) != 4
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in bbox)):
        raise InputError(f"{path}: {where}.bbox: expected 4 numbers [x, y, w, h], got {bbox!r}")
    if not all(math.isfinite(v) for v in bbox) or bbox[2] < 0 or bbox[3] < 0:
        raise InputError(f"{path}: {where}.bbox: expected finite values with w, h >= 0, got {bbox!r}")
    return [float(v) for v in bbox]


def _coco_number(path: Path, where: str, value: object, name: str, integer: bool) -> Any:
    ok = isinstance(value, int if integer else (int, float)) and not isinstance(value, bool)
    if not ok or not math.isfinite(value):
        raise InputError(f"{path}: {where}.{name}: expected {'an int' if integer else 'a finite number'}, "
                         f"got {value!r}")
    return value


def read_coco_detections(path: str | os.PathLike) -> dict[str, Detections]:
    """Boxes per image from a COCO file: a dataset (``{"images", "annotations"}``, every listed
    image present, empty or not; keyed by ``file_name``) or a results list (``[{"image_id",
    "category_id", "bbox", "score"}]``, only images with a box; keyed by ``str(image_id)``).

    Scores default to 1.0 (ground truth has none); labels are the ``category_id``s. Raises
    InputError naming the file and entry for malformed JSON, missing or mistyped fields, boxes
    with negative size, duplicate image ids, or annotations of an unknown image.
    """
    return _read_coco(path)[0]


def _read_coco(path: str | os.PathLike) -> tuple[dict[str, Detections], bool]:
    """``read_coco_detections`` and whether the file is a dataset (True) or a results list."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read ({err})") from None
    except json.JSONDecodeError as err:
        raise InputError(f"{path}:{err.lineno}: not valid JSON ({err.msg})") from None
    if isinstance(data, dict):
        for key in ("images", "annotations"):
            if not isinstance(data.get(key), list):
                raise InputError(f"{path}: a COCO dataset needs a list '{key}'")
        names: dict[int, str] = {}
        for k, im in enumerate(data["images"]):
            where = f"images[{k}]"
            if not isinstance(im, dict):
                raise InputError(f"{path}: {where}: expected an object")
            image_id = _coco_number(path, where, im.get("id"), "id", True)
            name = im.get("file_name")
            if not isinstance(name, str) or not name:
                raise InputError(f"{path}: {where}.file_name: expected a non-empty string, got {name!r}")
            if image_id in names:
                raise InputError(f"{path}: {where}.id: duplicate image id {image_id}")
            if name in names.values():
                raise InputError(f"{path}: {where}.file_name: duplicate file name {name!r}")
            names[image_id] = name
        entries, list_name = data["annotations"], "annotations"
    elif isinstance(data, list):
        names, entries, list_name = {}, data, "results"
    else:
        raise InputError(f"{path}: expected a COCO dataset object or a list of results, got {type(data).__name__}")
    boxes: dict[str, list[tuple[list[float], float, int]]] = {name: [] for name in names.values()}
    for k, ann in enumerate(entries):
        where = f"{list_name}[{k}]"
        if not isinstance(ann, dict):
            raise InputError(f"{path}: {where}: expected an object")
        image_id = ann.get("image_id")
        if names:
            _coco_number(path, where, image_id, "image_id", True)
            if image_id not in names:
                raise InputError(f"{path}: {where}.image_id: {image_id} is not in 'images'")
            key = names[image_id]
        else:
            if not isinstance(image_id, (int, str)) or isinstance(image_id, bool):
                raise InputError(f"{path}: {where}.image_id: expected an int or a string, got {image_id!r}")
            key = str(image_id)
        label = _coco_number(path, where, ann.get("category_id"), "category_id", True)
        score = float(_coco_number(path, where, ann["score"], "score", False)) if "score" in ann else 1.0
        boxes.setdefault(key, []).append((_coco_bbox(path, where, ann.get("bbox")), score, label))
    out = {}
    for key, items in boxes.items():
        if items:
            xywh = np.array([b for b, _, _ in items])
            out[key] = Detections(xywh_to_xyxy(xywh), [s for _, s, _ in items], [c for _, _, c in items])
        else:
            out[key] = Detections.empty()
    return out, isinstance(data, dict)


def write_coco_results(path: str | os.PathLike, detections: Mapping[str | int, Detections]) -> Path:
    """Write detections as a COCO results list (``image_id`` as given), atomically."""
    from nsim.io import atomic_path

    results = []
    for image_id, det in detections.items():
        for box, score, label in zip(xyxy_to_xywh(det.boxes_xyxy), det.scores, det.labels, strict=True):
            results.append({"image_id": image_id, "category_id": int(label),
                            "bbox": [float(v) for v in box], "score": float(score)})
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(results, indent=1) + "\n")
    return path


# --------------------------------------------------------------------------------------
# The experiment
# --------------------------------------------------------------------------------------

#: Frames for one side of the experiment: images (arrays or paths) or a COCO JSON file.
DetectionSource = Sequence[np.ndarray | str | os.PathLike] | str | os.PathLike


def _image_key_order(key: str) -> tuple[int, int, str]:
    """Image ids in numeric order ("2" before "10"), then names in text order."""
    return (0, int(key), "") if key.isdigit() else (1, 0, key)


def _is_coco(source: object) -> bool:
    return isinstance(source, (str, os.PathLike)) and Path(source).suffix.lower() == ".json"


def evaluate_detection(
    sim: DetectionSource,
    real: DetectionSource,
    detector: Detector | None = None,
    cfg: MatchConfig = MatchConfig(),
) -> DetectionComparison:
    """The paper's detection experiment: detections on simulated frames against those on the real ones.

    Each side is a sequence of images (detected with ``detector``, default ``HogPeopleDetector()``)
    or a COCO JSON path. Two COCO files are paired by image key (a key missing on one side counts as
    no boxes there, except between two datasets, which must list the same images). A COCO file
    against images should be a dataset listing every frame; its images are taken in sorted order
    (numeric ids numerically). Raises InputError when the frame counts or a frame pair's image sizes
    differ.
    """
    if _is_coco(sim) and _is_coco(real):
        (s, s_dataset), (r, r_dataset) = _read_coco(sim), _read_coco(real)
        if s_dataset and r_dataset and set(s) != set(r):
            only = sorted(set(s) ^ set(r))
            raise InputError(f"detection: {sim} and {real} list different images (e.g. {only[0]!r})")
        keys = sorted(set(s) | set(r), key=_image_key_order)
        return compare_detections([s.get(k, Detections.empty()) for k in keys],
                                  [r.get(k, Detections.empty()) for k in keys], cfg)
    detector = detector if detector is not None else HogPeopleDetector()
    if _is_coco(sim) or _is_coco(real):
        coco, images = (sim, real) if _is_coco(sim) else (real, sim)
        by_key = read_coco_detections(coco)
        from_file = [by_key[k] for k in sorted(by_key, key=_image_key_order)]
        if len(from_file) != len(images):
            raise InputError(f"detection: {coco} has {len(from_file)} images but {len(images)} frames were given")
        detected = detect_images(detector, images)
        return compare_detections(*((from_file, detected) if _is_coco(sim) else (detected, from_file)), cfg)
    if len(sim) != len(real):
        raise InputError(f"detection: {len(sim)} simulated frames but {len(real)} real frames")
    sim_dets, real_dets = [], []
    for k, (a, b) in enumerate(zip(sim, real, strict=True)):
        a, b = _load_image(a, f"simulated frame {k}"), _load_image(b, f"real frame {k}")
        if a.shape != b.shape:
            raise InputError(f"detection: frame {k}: simulated image is {a.shape[1]}x{a.shape[0]} "
                             f"but real is {b.shape[1]}x{b.shape[0]}")
        sim_dets.append(detector(a))
        real_dets.append(detector(b))
    return compare_detections(sim_dets, real_dets, cfg)
