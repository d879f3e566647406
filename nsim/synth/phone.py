"""A phone camera on top of the test room's exact renders: what a handheld phone video adds.

Core only (arrays in, arrays out; ``encode_jpeg`` returns bytes). Every effect is off by
default (``PhoneConfig()`` changes nothing). Image formation of frame k, timestamp ``t_k``:

1. light: the oracle's colour (the room's baked shading, read as sRGB) decoded to linear.
   Motion blur (``exposure_time_s = T > 0``): the mean, in linear light, of
   ``motion_blur_samples`` renders at stratified times ``t + ((j + 1/2) / S - 1/2) T`` across the
   exposure, the camera on its own path (``nsim.synth.path.handheld_path_at``). Rolling shutter
   (``readout_time_s > 0``): row r is exposed around ``t_k + r * readout_time_s / H``, rendered in
   bands of ``rolling_shutter_rows_per_band`` rows at the time of the band's middle row.
2. lens: vignetting ``v(p) = (1 + a rho^2)^-2``, ``rho`` the distance from the principal point over
   that of the farthest pixel centre, ``a`` such that that corner pixel gets
   ``vignetting_corner_gain``. For a pinhole with ``a = (rho_max / f)^2`` this is the cos^4 law.
3. sensor: the auto-exposure gain ``g_k``, then Gaussian shot noise (variance
   ``shot_noise_std_at_white^2 * x``) and read noise (``read_noise_std^2``), then the white level
   (clip to [0, 1]). Signal, noise std and white level are in linear units of the white level.
4. ISP: white-balance gains ``wb_k = (r, 1, b)``, clip, the sRGB tone curve, 8 bits.
5. storage: JPEG at ``jpeg_quality`` (4:2:0 chroma, libjpeg via OpenCV) instead of PNG.

So ``pixel_linear = clip(wb_k * clip(g_k * v(p) * L(p) + noise))`` with ``L`` the light of step 1.
``g_k`` and ``wb_k`` drift smoothly over the frames (``smooth_drift``, in stops, around 0 stops);
they are returned per frame (the capture records them as ground truth).

Ground truth: the pose of frame k is the camera at ``t_k``: mid-exposure of row 0 (without
rolling shutter every row; without motion blur the instant of the frame). Its depth is rendered
at that pose with a global shutter and no appearance effect, exactly as without this model.

Randomness: the drifts from ``default_rng([seed, DRIFT_TAG])`` (all three drawn whether or not
they are on), frame k's noise from ``default_rng([seed, NOISE_TAG, k])``: turning one effect on or
off never changes another's realisation, and frames can be rendered in any order.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from nsim.config import param
from nsim.io.canonical import round_decimals

DRIFT_TAG = 0x9E0
NOISE_TAG = 0x9E1


@dataclasses.dataclass(frozen=True)
class PhoneConfig:
    """What a phone adds to the clean render (see the module docstring); the defaults add nothing."""

    exposure_drift_std_stops: float = param(0.0, ge=0.0, le=2.0, help="auto-exposure drift: std of log2 gain")
    white_balance_drift_std_stops: float = param(0.0, ge=0.0, le=1.0,
                                                 help="white-balance drift: std of log2 of the R and B gains (G = 1)")
    drift_timescale_s: float = param(2.0, gt=0.0, le=600.0, help="smoothing (Gaussian sigma) of both drifts")
    shot_noise_std_at_white: float = param(0.0, ge=0.0, le=0.5,
                                           help="shot-noise std at the white level (1 / sqrt(full-well electrons))")
    read_noise_std: float = param(0.0, ge=0.0, le=0.5, help="read-noise std, linear units of the white level")
    exposure_time_s: float = param(0.0, ge=0.0, le=1.0, help="motion blur over this exposure (0: none)")
    motion_blur_samples: int = param(5, ge=1, le=64, help="renders averaged over the exposure")
    readout_time_s: float = param(0.0, ge=0.0, le=1.0, help="rolling shutter: row 0 to row H (0: global shutter)")
    rolling_shutter_rows_per_band: int = param(8, ge=1, le=4096, help="rows rendered at one time")
    vignetting_corner_gain: float = param(1.0, gt=0.0, le=1.0, help="linear brightness of the corners (1: none)")
    jpeg_quality: int | None = param(None, ge=1, le=100, help="write JPEG at this quality (null: lossless PNG)")

    @property
    def any_effect(self) -> bool:
        """Whether the output differs from the clean capture at all."""
        return (self.moves or self.exposure_drift_std_stops > 0.0 or self.white_balance_drift_std_stops > 0.0
                or self.noisy or self.vignetting_corner_gain < 1.0 or self.jpeg_quality is not None)

    @property
    def moves(self) -> bool:
        """Whether the camera moves during a frame (motion blur or rolling shutter)."""
        return self.exposure_time_s > 0.0 or self.readout_time_s > 0.0

    @property
    def noisy(self) -> bool:
        return self.shot_noise_std_at_white > 0.0 or self.read_noise_std > 0.0


@dataclasses.dataclass(frozen=True, eq=False)
class PhonePlan:
    """Everything about a capture's frames decided before rendering (N frames, B row bands, S blur samples).

    bands: (B, 2) int row ranges ``[r0, r1)`` covering the image, top to bottom.
    offsets_s: (B, S) float64 time of each band's blur samples relative to the frame timestamp.
    poses: (N, B, S, 4, 4) cam_to_world (OpenCV axes) at those times; None when nothing moves.
    exposure_gain: (N,) float64 auto-exposure gain (linear); wb_gains_rgb: (N, 3) float64, G = 1.
    vignette: (H, W) float32 gain of each pixel.
    """

    config: PhoneConfig
    bands: np.ndarray
    offsets_s: np.ndarray
    poses: np.ndarray | None
    exposure_gain: np.ndarray
    wb_gains_rgb: np.ndarray
    vignette: np.ndarray


def smooth_drift(rng: np.random.Generator, n: int, std: float, timescale_frames: float) -> np.ndarray:
    """A smooth random drift ``(n,)`` around 0: white noise convolved with a Gaussian of sigma
    ``timescale_frames``, scaled to a stationary std of ``std``.

    Stationary (unlike a random walk, whose spread grows without bound over a long capture);
    the kernel runs over ``4 sigma`` of extra draws at both ends, so the ends are as random as the middle.
    Always draws ``n + 2 ceil(4 sigma)`` normals from ``rng``.
    """
    half = math.ceil(4.0 * timescale_frames)
    x = np.arange(-half, half + 1) / max(timescale_frames, 1e-9)
    kernel = np.exp(-0.5 * x * x)
    kernel /= np.sqrt(np.sum(kernel * kernel))  # unit variance out of unit-variance white noise
    white = rng.standard_normal(n + 2 * half)
    size = 1 << int(white.size + kernel.size - 1).bit_length()  # FFT: long timescales at high fps stay cheap
    full = np.fft.irfft(np.fft.rfft(white, size) * np.fft.rfft(kernel, size), size)
    return std * full[kernel.size - 1:white.size]  # the "valid" part: n values


def drift_gains(cfg: PhoneConfig, n_frames: int, fps: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Auto-exposure gains ``(N,)`` and white-balance gains ``(N, 3)`` (G = 1) of a capture, float64."""
    rng = np.random.default_rng([int(seed), DRIFT_TAG])
    sigma = cfg.drift_timescale_s * fps
    ev, log_r, log_b = (smooth_drift(rng, n_frames, std, sigma) for std in (
        cfg.exposure_drift_std_stops, cfg.white_balance_drift_std_stops, cfg.white_balance_drift_std_stops))
    wb = np.stack([np.exp2(log_r), np.ones(n_frames), np.exp2(log_b)], axis=-1)
    # to 1e-9 (nsim.io.canonical): numpy's exp2 differs in the last bits between CPUs; the frames and the
    # transforms.json that records the gains then do not
    return round_decimals(np.exp2(ev)), round_decimals(wb)


def vignetting(width: int, height: int, cx: float, cy: float, corner_gain: float) -> np.ndarray:
    """Vignetting gain ``(H, W)`` float32: ``(1 + a rho^2)^-2`` with ``rho = 1`` at the pixel centre
    farthest from the principal point ``(cx, cy)`` (OpenCV pixels), where the gain is ``corner_gain``."""
    if not 0.0 < corner_gain <= 1.0:
        raise ValueError(f"vignetting: corner_gain must be in (0, 1], got {corner_gain!r}")
    u = np.arange(width, dtype=np.float64) - cx
    v = np.arange(height, dtype=np.float64) - cy
    r2 = u[None, :] ** 2 + v[:, None] ** 2
    a = corner_gain**-0.5 - 1.0
    return ((1.0 + a * r2 / r2.max()) ** -2).astype(np.float32)


def exposure_times(height: int, cfg: PhoneConfig) -> tuple[np.ndarray, np.ndarray]:
    """Row bands ``(B, 2)`` and their sample times ``(B, S)`` relative to the frame timestamp (seconds).

    Band b covers rows ``[r0, r1)`` and is exposed around its middle row's time
    ``(r0 + r1 - 1) / 2 * readout_time_s / height``; its S samples spread over the exposure.
    """
    if cfg.readout_time_s > 0.0:
        starts = np.arange(0, height, cfg.rolling_shutter_rows_per_band)
        bands = np.stack([starts, np.minimum(starts + cfg.rolling_shutter_rows_per_band, height)], axis=-1)
    else:
        bands = np.array([[0, height]])
    band_t = (bands[:, 0] + bands[:, 1] - 1) / 2.0 * cfg.readout_time_s / height
    if cfg.exposure_time_s > 0.0:
        S = cfg.motion_blur_samples
        blur_t = ((np.arange(S) + 0.5) / S - 0.5) * cfg.exposure_time_s
    else:
        blur_t = np.zeros(1)
    return bands.astype(np.int64), band_t[:, None] + blur_t[None, :]


def plan_frames(cfg: PhoneConfig, camera: Any, times_s: np.ndarray, fps: float, seed: int,
                pose_at: Callable[[np.ndarray], np.ndarray]) -> PhonePlan:
    """The ``PhonePlan`` of a capture with frame timestamps ``times_s (N,)`` at ``fps`` and intrinsics
    ``camera`` (``width, height, cx, cy``); ``pose_at(t_s (M,)) -> cam_to_world (M, 4, 4)`` is the path
    (called only when the camera moves during a frame)."""
    times_s = np.asarray(times_s, dtype=np.float64)
    n = times_s.shape[0]
    bands, offsets = exposure_times(int(camera.height), cfg)
    poses = None
    if cfg.moves:
        at = (times_s[:, None, None] + offsets[None]).reshape(-1)
        poses = np.asarray(pose_at(at), dtype=np.float64).reshape(n, *offsets.shape, 4, 4)
    gain, wb = drift_gains(cfg, n, fps, seed)
    vig = vignetting(int(camera.width), int(camera.height), camera.cx, camera.cy, cfg.vignetting_corner_gain)
    return PhonePlan(config=cfg, bands=bands, offsets_s=offsets, poses=poses, exposure_gain=gain,
                     wb_gains_rgb=wb, vignette=vig)


def band_camera(camera: Any, r0: int, r1: int) -> Any:
    """The camera of rows ``[r0, r1)`` of ``camera`` (same rays): height ``r1 - r0``, ``cy - r0``."""
    if (r0, r1) == (0, camera.height):
        return camera
    if camera.model == "EQUIRECTANGULAR":  # its intrinsics follow from the size
        raise ValueError("band_camera: an equirectangular camera cannot be cut into row bands")
    return dataclasses.replace(camera, height=r1 - r0, cy=camera.cy - r0)


def render_light(oracle: Any, camera: Any, plan: PhonePlan, frame: int, supersample: int) -> np.ndarray:
    """Linear light ``(H, W, 3)`` float32 of ``frame``: each row band, the mean of its blur samples.

    Needs ``plan.poses`` (a plan where the camera moves).
    """
    from nsim.sensors.rig import _srgb_to_linear

    if plan.poses is None:
        raise ValueError("render_light: the plan has no sub-frame poses (neither motion blur nor rolling shutter)")
    H, W = int(camera.height), int(camera.width)
    light = np.zeros((H, W, 3), dtype=np.float32)
    S = plan.offsets_s.shape[1]
    for b, (r0, r1) in enumerate(plan.bands):
        cam = band_camera(camera, int(r0), int(r1))
        for j in range(S):
            light[r0:r1] += _srgb_to_linear(oracle.render_gt(cam, plan.poses[frame, b, j], supersample=supersample).rgb)
        light[r0:r1] /= np.float32(S)
    return light


def develop(light: np.ndarray, exposure_gain: float, wb_gains_rgb: np.ndarray, vignette: np.ndarray,
            cfg: PhoneConfig, rng: np.random.Generator) -> np.ndarray:
    """Steps 2-4: linear light ``(H, W, 3)`` -> display-referred colour ``(H, W, 3)`` float32 in [0, 1].

    ``rng`` gives the noise (``H * W * 3`` normals, drawn only when there is noise).
    """
    from nsim.sensors.rig import _linear_to_srgb

    x = np.asarray(light, dtype=np.float32) * (vignette[..., None] * np.float32(exposure_gain))
    if cfg.noisy:
        var = np.float32(cfg.shot_noise_std_at_white**2) * np.maximum(x, 0.0) + np.float32(cfg.read_noise_std**2)
        x = x + np.sqrt(var) * rng.standard_normal(x.shape, dtype=np.float32)
    x = np.clip(x, 0.0, 1.0)  # the white level (full well)
    x = np.clip(x * np.asarray(wb_gains_rgb, dtype=np.float32), 0.0, 1.0)
    return _linear_to_srgb(x).astype(np.float32)


def shoot(oracle: Any, camera: Any, plan: PhonePlan, frame: int, cam_to_world: np.ndarray, supersample: int,
          seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``frame`` as the phone records it: ``rgb (H, W, 3)`` float32 in [0, 1] (before JPEG) and
    the ground-truth ``depth_z (H, W)`` float32 at ``cam_to_world`` (the frame's GT pose)."""
    from nsim.sensors.rig import _srgb_to_linear

    cfg = plan.config
    if cfg.moves:
        depth_z = oracle.render_gt(camera, cam_to_world, supersample=1).depth_z  # depth: centre rays only
        light = render_light(oracle, camera, plan, frame, supersample)
    else:
        view = oracle.render_gt(camera, cam_to_world, supersample=supersample)
        depth_z, light = view.depth_z, _srgb_to_linear(view.rgb)
    rng = np.random.default_rng([int(seed), NOISE_TAG, int(frame)])
    rgb = develop(light, float(plan.exposure_gain[frame]), plan.wb_gains_rgb[frame], plan.vignette, cfg, rng)
    return rgb, depth_z


def frame_metadata(plan: PhonePlan, frame: int) -> dict[str, Any]:
    """Per-frame ground truth for transforms.json: ``exposure_gain`` and ``wb_gains_rgb`` (linear)."""
    return {"exposure_gain": float(plan.exposure_gain[frame]),
            "wb_gains_rgb": [float(g) for g in plan.wb_gains_rgb[frame]]}


def capture_metadata(cfg: PhoneConfig) -> dict[str, Any]:
    """What a reader of the capture needs to know about the phone model (transforms.json, top level)."""
    return {
        "config": dataclasses.asdict(cfg),
        "pose_time": "frame timestamp = mid-exposure of row 0; depth and poses are those of the camera then",
        "row_time_s": "row r is exposed around timestamp + r * readout_time_s / h",
        "pixel_model": "linear = clip(wb_gains_rgb * clip(exposure_gain * vignette * light + noise)), sRGB-encoded",
    }


def encode_jpeg(rgb_u8: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of an ``(H, W, 3)`` uint8 RGB image (4:2:0 chroma) or an ``(H, W)`` uint8 grey one (one
    component, as a grey camera's driver writes it) at ``quality`` (libjpeg scale)."""
    import cv2

    rgb_u8 = np.asarray(rgb_u8)
    if rgb_u8.dtype != np.uint8 or not (rgb_u8.ndim == 2 or (rgb_u8.ndim == 3 and rgb_u8.shape[2] == 3)):
        raise ValueError(f"encode_jpeg: expected (H, W, 3) or (H, W) uint8, got {rgb_u8.dtype} {rgb_u8.shape}")
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    if rgb_u8.ndim == 3 and hasattr(cv2, "IMWRITE_JPEG_SAMPLING_FACTOR"):
        params += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb_u8[..., ::-1] if rgb_u8.ndim == 3 else rgb_u8), params)
    if not ok:
        raise RuntimeError("OpenCV could not encode a JPEG")
    return buf.tobytes()
