"""Affine colour correction: the 3 x 4 map that best turns simulated colours into real ones.

Real cameras expose and white-balance differently from a simulator, so image metrics against a
real recording are also reported after each camera's colours are mapped onto the real ones, as
NeRF-in-the-wild evaluations do. The map is affine in the image's values (8-bit sRGB scaled to
[0, 1], no linearisation)::

    real[i] ~= M @ [sim_r[i], sim_g[i], sim_b[i], 1]       M: (3, 4)

fitted by least squares over every valid pixel of a set of frames (one camera's), through the
normal equations accumulated frame by frame in float64 (exact for any number of pixels, no copy of
the whole set). ``apply_colour_affine`` maps an image and clips to [0, 1].
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from nsim.errors import InputError

IDENTITY = np.hstack([np.eye(3), np.zeros((3, 1))])


def _pixels(image: np.ndarray, name: str) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise InputError(f"colour correction: {name} must be (H, W, 3), got {image.shape}")
    return image.reshape(-1, 3).astype(np.float64)


def fit_colour_affine(sims: Sequence[np.ndarray], reals: Sequence[np.ndarray],
                      masks: Sequence[np.ndarray | None] | None = None) -> np.ndarray:
    """The (3, 4) least-squares map from ``sims`` to ``reals`` ((H, W, 3) each, frame for frame) over
    the pixels where both are finite and the mask (if any) is set. Raises InputError for differing
    counts or sizes, or fewer than 4 pixels."""
    if len(sims) != len(reals) or (masks is not None and len(masks) != len(sims)):
        raise InputError(f"colour correction: {len(sims)} simulated frames, {len(reals)} real"
                         + (f", {len(masks)} masks" if masks is not None else ""))
    xtx = np.zeros((4, 4))
    xty = np.zeros((4, 3))
    n = 0
    for k, (sim, real) in enumerate(zip(sims, reals, strict=True)):
        if np.shape(sim) != np.shape(real):
            raise InputError(f"colour correction: frame {k}: sim {np.shape(sim)} vs real {np.shape(real)}")
        x, y = _pixels(sim, "sim"), _pixels(real, "real")
        keep = np.isfinite(x).all(1) & np.isfinite(y).all(1)
        if masks is not None and masks[k] is not None:
            keep &= np.asarray(masks[k], dtype=bool).reshape(-1)
        x, y = x[keep], y[keep]
        xh = np.hstack([x, np.ones((len(x), 1))])
        xtx += xh.T @ xh
        xty += xh.T @ y
        n += len(x)
    if n < 4:
        raise InputError(f"colour correction: {n} valid pixels, at least 4 needed")
    sol, *_ = np.linalg.lstsq(xtx, xty, rcond=None)  # (4, 3); lstsq: a grey camera's rank-2 system has a solution
    return sol.T


def apply_colour_affine(image: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``image (H, W, 3)`` through ``m (3, 4)``, clipped to [0, 1], float32."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape != (3, 4):
        raise InputError(f"colour correction: the map must be (3, 4), got {m.shape}")
    x = np.asarray(image, dtype=np.float64)
    out = x @ m[:, :3].T + m[:, 3]
    return np.clip(out, 0.0, 1.0).astype(np.float32)
