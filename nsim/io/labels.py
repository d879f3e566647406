"""Labels on preview images: a white header strip with black text above an image, drawn by OpenCV.

Every contact sheet, preview video frame and held-out comparison nsim writes is labelled here, so
they all look alike and say what they show (camera, frame, time, "render | ground truth").

- :func:`add_label` puts a strip of :data:`LABEL_HEIGHT_PX` above an ``(H, W, 3)`` or ``(H, W)``
  uint8 image; the ``H x W`` pixels below it are the input's, unchanged. A list of texts splits the
  strip into that many equal columns, one text each, for images put side by side
  (``add_label(np.concatenate([render, truth], 1), ["render", "ground truth"])``).
- :func:`tile_grid` lays labelled tiles out as a contact sheet.

Deterministic (same input, same pixels): OpenCV's Hershey simplex font, anti-aliased. A text
too wide for its column is drawn smaller, down to :data:`MIN_SCALE` of the usual size, then cut
and ended with ``..``. The Hershey fonts have ASCII glyphs only: other characters become ``?``.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

LABEL_HEIGHT_PX = 20
"""Height of a label strip (even, so a labelled video frame keeps an even size)."""
MIN_SCALE = 0.65
"""A text that does not fit is shrunk to at most this fraction of its usual size before it is cut."""
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_SCALE_PER_PX = 0.45 / LABEL_HEIGHT_PX  # font scale per pixel of strip height
_PAD_PX = 4
_BACKGROUND = 255
_INK = 0


def _ascii(text: str) -> str:
    return "".join(c if 32 <= ord(c) < 127 else "?" for c in str(text))


def _fit(text: str, width_px: int, scale: float) -> tuple[str, float]:
    """``text`` and the font scale to draw it within ``width_px``: shrunk, then cut (``..``) if need be."""
    w = cv2.getTextSize(text, _FONT, scale, 1)[0][0]
    if w <= width_px:
        return text, scale
    small = max(scale * MIN_SCALE, 0.95 * scale * width_px / w)  # getTextSize is not quite linear in scale
    if cv2.getTextSize(text, _FONT, small, 1)[0][0] <= width_px:
        return text, small
    while text and cv2.getTextSize(text + "..", _FONT, small, 1)[0][0] > width_px:
        text = text[:-1]
    return (text + ".." if text else ""), small


def label_strip(width: int, texts: str | Sequence[str], height: int = LABEL_HEIGHT_PX) -> np.ndarray:
    """A ``(height, width, 3)`` uint8 strip: white, with each of ``texts`` in black at the left of its
    column (``len(texts)`` equal columns; one string: one column)."""
    if isinstance(texts, str):
        texts = [texts]
    if width < 1 or height < 1 or not texts:
        raise ValueError(f"label_strip: expected width, height >= 1 and at least one text, got {width}, {height}, "
                         f"{len(texts)} texts")
    strip = np.full((height, width, 3), _BACKGROUND, np.uint8)
    n = len(texts)
    edges = [round(k * width / n) for k in range(n + 1)]
    for k, text in enumerate(texts):
        x0, x1 = edges[k], edges[k + 1]
        room = x1 - x0 - 2 * _PAD_PX
        if room <= 0:
            continue
        text, scale = _fit(_ascii(text), room, _SCALE_PER_PX * height)
        if not text:
            continue
        (_, th), _ = cv2.getTextSize(text, _FONT, scale, 1)
        y = (height + th) // 2
        cv2.putText(strip, text, (x0 + _PAD_PX, y), _FONT, scale, (_INK,) * 3, 1, cv2.LINE_AA)
    return strip


def add_label(image: np.ndarray, texts: str | Sequence[str], height: int = LABEL_HEIGHT_PX) -> np.ndarray:
    """``image`` (``(H, W, 3)`` or ``(H, W)`` uint8) with a label strip of ``height`` rows on top:
    ``(height + H, W[, 3])``; the last ``H`` rows are ``image`` unchanged. See :func:`label_strip`."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)) \
            or 0 in image.shape:
        raise ValueError(f"add_label: expected a non-empty (H, W, 3) or (H, W) uint8 image, got {image.dtype} "
                         f"{image.shape}")
    strip = label_strip(image.shape[1], texts, height)
    if image.ndim == 2:
        strip = strip[..., 0]
    return np.concatenate([strip, image], axis=0)


def tile_grid(tiles: Sequence[np.ndarray], ncol: int, pad: int = 4, background: int = 255) -> np.ndarray:
    """Tiles (``(h, w, 3)`` uint8, e.g. labelled thumbnails) in rows of ``ncol``, ``pad`` pixels
    around and between them, on ``background``: cells are as large as the largest tile, tiles at
    their cell's top left. No tiles: one empty cell of ``pad`` pixels."""
    if ncol < 1:
        raise ValueError(f"tile_grid: ncol must be >= 1, got {ncol}")
    for t in tiles:
        if t.dtype != np.uint8 or t.ndim != 3 or t.shape[2] != 3:
            raise ValueError(f"tile_grid: expected (h, w, 3) uint8 tiles, got {t.dtype} {t.shape}")
    ch = max((t.shape[0] for t in tiles), default=0)
    cw = max((t.shape[1] for t in tiles), default=0)
    nrow = max(1, -(-len(tiles) // ncol))
    cols = min(ncol, max(1, len(tiles)))
    sheet = np.full((pad + nrow * (ch + pad), pad + cols * (cw + pad), 3), background, np.uint8)
    for k, t in enumerate(tiles):
        y, x = pad + (k // ncol) * (ch + pad), pad + (k % ncol) * (cw + pad)
        sheet[y:y + t.shape[0], x:x + t.shape[1]] = t
    return sheet
