"""Ground truth of people per camera image: instance-mask PNGs and COCO-style box JSON.

Instance mask
    ``(H, W)`` uint16 PNG, single channel: 0 = no person, ``k >= 1`` = the pixels of instance
    ``k`` (the renderer's id for a human, e.g. its index in the trajectory + 1). Lossless, so ids
    survive exactly; written without timestamps, so the bytes repeat.
COCO JSON
    ``{"info", "images", "annotations", "categories"}`` as in the COCO detection format: one image
    entry per mask (``id`` from 1 in the order given, ``file_name``, ``width``, ``height``); one
    annotation per instance with ``bbox = [x, y, w, h]`` in COCO's pixel convention (pixel ``i``
    covers ``[i, i + 1)``, so columns ``c0..c1`` give ``x = c0, w = c1 - c0 + 1``; nsim's own pixel
    centres are at integers, see ``nsim.geometry.conventions``), ``area`` = the instance's pixel
    count, ``category_id`` 1 (``person``), ``iscrowd`` 0, ``segmentation`` as uncompressed RLE
    (column-major run lengths starting with background, what ``pycocotools`` reads), and
    ``instance_id`` = the mask id, so the same person can be followed across frames and cameras.
    Annotations are sorted by image, then instance id; ``id`` runs from 1.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from nsim.errors import InputError
from nsim.io import atomic_path
from nsim.io.images import _decode, _encode_atomic

PERSON_CATEGORY = {"id": 1, "name": "person", "supercategory": "person"}
MAX_INSTANCES = 65535


@dataclass(frozen=True)
class InstanceBox:
    """One instance in one image. bbox_xywh: COCO ``[x, y, w, h]`` (see the module docstring)."""

    instance_id: int
    bbox_xywh: tuple[float, float, float, float]
    area_px: int


def _check_mask(mask: np.ndarray) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.ndim != 2 or 0 in mask.shape:
        raise ValueError(f"instance mask: expected non-empty (H, W), got shape {mask.shape}")
    if mask.dtype.kind not in "ui":
        raise ValueError(f"instance mask: expected integer ids, got {mask.dtype}")
    if mask.size and (mask.min() < 0 or mask.max() > MAX_INSTANCES):
        raise ValueError(f"instance mask: ids must be in [0, {MAX_INSTANCES}], got [{mask.min()}, {mask.max()}]")
    return mask


def write_instance_mask(path: str | os.PathLike, mask: np.ndarray) -> Path:
    """Write ``mask (H, W)`` integer ids (0 = background) as a 16-bit PNG, atomically; returns ``path``."""
    return _encode_atomic(Path(path), _check_mask(mask).astype(np.uint16), ".png")


def read_instance_mask(path: str | os.PathLike) -> np.ndarray:
    """Read an instance-mask PNG as ``(H, W)`` uint16 ids (an 8-bit grey PNG is widened)."""
    path = Path(path)
    mask = _decode(path, cv2.IMREAD_UNCHANGED)
    if mask.ndim != 2 or mask.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{path}: expected a single-channel 8/16-bit instance mask, got {mask.dtype} {mask.shape}")
    return mask.astype(np.uint16)


def boxes_from_mask(mask: np.ndarray) -> list[InstanceBox]:
    """Every instance of ``mask (H, W)`` (ids > 0) with its COCO box and pixel area, by increasing id."""
    mask = _check_mask(mask)
    out = []
    for k in np.unique(mask):
        if k == 0:
            continue
        rows, cols = np.nonzero(mask == k)
        x0, y0 = int(cols.min()), int(rows.min())
        w, h = int(cols.max()) - x0 + 1, int(rows.max()) - y0 + 1
        out.append(InstanceBox(int(k), (float(x0), float(y0), float(w), float(h)), int(rows.size)))
    return out


def rle_from_binary(binary: np.ndarray) -> dict:
    """COCO uncompressed RLE of a ``(H, W)`` bool mask: ``{"size": [H, W], "counts": [...]}``,
    column-major run lengths starting with a (possibly empty) run of zeros."""
    flat = np.asarray(binary, dtype=bool).ravel(order="F")
    change = np.flatnonzero(np.diff(flat.astype(np.int8))) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    counts = np.diff(bounds).tolist()
    if flat.size and flat[0]:
        counts = [0] + counts
    return {"size": [int(binary.shape[0]), int(binary.shape[1])], "counts": [int(c) for c in counts]}


def binary_from_rle(rle: dict) -> np.ndarray:
    """Inverse of ``rle_from_binary``: ``(H, W)`` bool."""
    h, w = rle["size"]
    values = np.arange(len(rle["counts"])) % 2 == 1
    flat = np.repeat(values, rle["counts"])
    if flat.size != h * w:
        raise ValueError(f"RLE covers {flat.size} pixels, expected {h * w}")
    return flat.reshape((h, w), order="F")


def coco_dataset(images: Sequence[tuple[str, np.ndarray]], description: str = "nsim people") -> dict:
    """COCO detection dataset from ``(file_name, instance mask (H, W))`` pairs, in that order."""
    image_entries, annotations = [], []
    for image_id, (file_name, mask) in enumerate(images, start=1):
        mask = _check_mask(mask)
        h, w = mask.shape
        image_entries.append({"id": image_id, "file_name": str(file_name), "width": int(w), "height": int(h)})
        for box in boxes_from_mask(mask):
            annotations.append(
                {
                    "id": len(annotations) + 1,
                    "image_id": image_id,
                    "category_id": PERSON_CATEGORY["id"],
                    "instance_id": box.instance_id,
                    "bbox": list(box.bbox_xywh),
                    "area": box.area_px,
                    "iscrowd": 0,
                    "segmentation": rle_from_binary(mask == box.instance_id),
                }
            )
    return {
        "info": {"description": description, "version": "1.0"},
        "images": image_entries,
        "annotations": annotations,
        "categories": [dict(PERSON_CATEGORY)],
    }


def coco_from_mask_files(mask_paths: Sequence[str | os.PathLike], file_names: Sequence[str] | None = None) -> dict:
    """``coco_dataset`` of instance-mask PNGs; ``file_names`` (default: the masks' names) name the images."""
    if file_names is not None and len(file_names) != len(mask_paths):
        raise ValueError(f"file_names: {len(file_names)} names for {len(mask_paths)} masks")
    names = list(file_names) if file_names is not None else [Path(p).name for p in mask_paths]
    return coco_dataset([(n, read_instance_mask(p)) for n, p in zip(names, mask_paths, strict=True)])


def write_coco_json(path: str | os.PathLike, dataset: dict) -> Path:
    """Write a COCO dataset as JSON (sorted keys, stable bytes), atomically; returns ``path``."""
    path = Path(path)
    text = json.dumps(dataset, sort_keys=True, separators=(",", ":"), allow_nan=False)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")
    return path


def load_coco_boxes(path: str | os.PathLike) -> dict[str, list[InstanceBox]]:
    """Read a COCO JSON's person boxes: ``file_name -> [InstanceBox]`` (every image, possibly empty).

    Annotations without ``instance_id`` (other COCO files) get their annotation ``id``; other
    categories are skipped. A malformed file is an InputError naming the field.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: malformed JSON: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("images"), list) or not isinstance(
        data.get("annotations"), list
    ):
        raise InputError(f"{path}: expected a COCO object with 'images' and 'annotations' lists")
    names: dict[int, str] = {}
    out: dict[str, list[InstanceBox]] = {}
    for i, im in enumerate(data["images"]):
        try:
            names[int(im["id"])] = str(im["file_name"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: images[{i}]: needs 'id' and 'file_name'") from None
        out[names[int(im["id"])]] = []
    for i, ann in enumerate(data["annotations"]):
        try:
            if int(ann["category_id"]) != PERSON_CATEGORY["id"]:
                continue
            image = names[int(ann["image_id"])]
            x, y, w, h = (float(v) for v in ann["bbox"])
            box = InstanceBox(int(ann.get("instance_id", ann["id"])), (x, y, w, h), int(round(float(ann["area"]))))
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: annotations[{i}]: needs id, image_id (of a listed image), category_id, "
                             "bbox [x, y, w, h] and area") from None
        out[image].append(box)
    return out
