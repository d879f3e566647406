"""The phone model's core: drifts, noise, vignetting, exposure timing, band cameras, blur, JPEG."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nsim.geometry.cameras import Camera
from nsim.synth.path import handheld_path_at
from nsim.synth.phone import (
    PhoneConfig,
    band_camera,
    develop,
    drift_gains,
    encode_jpeg,
    exposure_times,
    plan_frames,
    render_light,
    smooth_drift,
    vignetting,
)
from tests.synth.phone_checks import detail_energy, jpeg_luma_table, luma_table_for_quality

CAMERA = Camera.pinhole_from_fov(96, 72, 75.0)


def _linear(display: np.ndarray) -> np.ndarray:
    c = np.asarray(display, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_defaults_add_nothing():
    cfg = PhoneConfig()
    assert not cfg.any_effect and not cfg.moves and not cfg.noisy
    for name, value in (("exposure_time_s", 0.01), ("readout_time_s", 0.01), ("read_noise_std", 0.01),
                        ("exposure_drift_std_stops", 0.1), ("vignetting_corner_gain", 0.9), ("jpeg_quality", 90)):
        assert dataclasses.replace(cfg, **{name: value}).any_effect, name
    rgb = np.random.default_rng(0).uniform(0.0, 1.0, (8, 9, 3)).astype(np.float32)
    out = develop(_linear(rgb), 1.0, np.ones(3), np.ones((8, 9), np.float32), cfg, np.random.default_rng(1))
    assert out.dtype == np.float32 and out.shape == rgb.shape
    np.testing.assert_allclose(out, rgb, atol=1e-5)


def test_smooth_drift_is_stationary_with_the_configured_std_and_smoothness():
    sigma = 6.0
    x = smooth_drift(np.random.default_rng(0), 60_000, 0.3, sigma)
    assert x.shape == (60_000,)
    assert x.std() == pytest.approx(0.3, rel=0.05) and abs(x.mean()) < 0.03
    # Gaussian-smoothed white noise: autocorrelation exp(-lag^2 / (4 sigma^2))
    for lag in (1, 6, 12):
        rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
        assert rho == pytest.approx(np.exp(-lag**2 / (4 * sigma**2)), abs=0.04)
    assert x[:2000].std() == pytest.approx(x[-2000:].std(), rel=0.35)  # the ends are as random as the middle


def test_drift_gains_are_deterministic_and_independent():
    cfg = PhoneConfig(exposure_drift_std_stops=0.3, white_balance_drift_std_stops=0.1, drift_timescale_s=1.0)
    gain, wb = drift_gains(cfg, 50, 10.0, seed=3)
    assert gain.shape == (50,) and wb.shape == (50, 3) and (wb[:, 1] == 1.0).all()
    g2, wb2 = drift_gains(cfg, 50, 10.0, seed=3)
    np.testing.assert_array_equal(gain, g2)
    np.testing.assert_array_equal(wb, wb2)
    assert not np.allclose(gain, drift_gains(cfg, 50, 10.0, seed=4)[0])
    # turning white balance off leaves the exposure's realisation alone, and vice versa
    np.testing.assert_array_equal(gain, drift_gains(dataclasses.replace(cfg, white_balance_drift_std_stops=0.0),
                                                    50, 10.0, seed=3)[0])
    np.testing.assert_array_equal(wb, drift_gains(dataclasses.replace(cfg, exposure_drift_std_stops=0.0),
                                                  50, 10.0, seed=3)[1])
    off, wb_off = drift_gains(PhoneConfig(), 50, 10.0, seed=3)
    assert (off == 1.0).all() and (wb_off == 1.0).all()


@pytest.mark.parametrize(("shot", "read"), [(0.0, 0.01), (0.04, 0.0), (0.04, 0.01)])
def test_noise_on_a_flat_image(shot, read):
    """Before the tone curve, a flat grey of linear level x gets std sqrt(shot^2 x + read^2), zero mean."""
    x = 0.2
    cfg = PhoneConfig(shot_noise_std_at_white=shot, read_noise_std=read)
    light = np.full((256, 256, 3), x, np.float32)
    out = develop(light, 1.0, np.ones(3), np.ones((256, 256), np.float32), cfg, np.random.default_rng(0))
    lin = _linear(out)
    assert lin.std() == pytest.approx(np.sqrt(shot**2 * x + read**2), rel=0.02)
    assert lin.mean() == pytest.approx(x, abs=1e-3)


def test_gains_and_vignetting_multiply_linear_light():
    light = np.full((72, 96, 3), 0.3, np.float32)
    v = vignetting(96, 72, CAMERA.cx, CAMERA.cy, 0.5)
    out = _linear(develop(light, 1.5, np.array([1.1, 1.0, 0.9]), v, PhoneConfig(), np.random.default_rng(0)))
    np.testing.assert_allclose(out, 0.3 * 1.5 * v[..., None] * np.array([1.1, 1.0, 0.9]), rtol=1e-5)
    bright = _linear(develop(light, 5.0, np.ones(3), np.ones((72, 96), np.float32), PhoneConfig(),
                             np.random.default_rng(0)))
    assert bright.max() == pytest.approx(1.0)  # clipped at the white level


def test_vignetting_is_the_cos4_law_for_a_pinhole():
    dirs = CAMERA.pixel_dirs_cam()
    cos4 = dirs[..., 2] ** 4  # cos^4 of each pixel ray's angle to the optical axis
    v = vignetting(CAMERA.width, CAMERA.height, CAMERA.cx, CAMERA.cy, float(cos4[0, 0]))
    assert v.shape == (72, 96) and v.dtype == np.float32
    np.testing.assert_allclose(v, cos4, rtol=1e-5)
    v = vignetting(96, 72, CAMERA.cx, CAMERA.cy, 0.6)
    assert v[0, 0] == v[-1, -1] == pytest.approx(0.6) and v.max() == pytest.approx(1.0, abs=1e-3)
    assert (vignetting(96, 72, CAMERA.cx, CAMERA.cy, 1.0) == 1.0).all()


def test_exposure_times():
    bands, t = exposure_times(72, PhoneConfig())
    np.testing.assert_array_equal(bands, [[0, 72]])
    np.testing.assert_array_equal(t, [[0.0]])
    cfg = PhoneConfig(exposure_time_s=0.02, motion_blur_samples=4, readout_time_s=0.036, rolling_shutter_rows_per_band=8)
    bands, t = exposure_times(72, cfg)
    assert bands.shape == (9, 2) and t.shape == (9, 4)
    np.testing.assert_array_equal(bands[:, 0], np.arange(0, 72, 8))
    np.testing.assert_array_equal(bands[:-1, 1], bands[1:, 0])
    assert bands[-1, 1] == 72
    mid_row = bands.mean(axis=1) - 0.5
    np.testing.assert_allclose(t.mean(axis=1), mid_row * 0.036 / 72)  # each band at its middle row's time
    np.testing.assert_allclose(t[0] - t[0].mean(), [-0.0075, -0.0025, 0.0025, 0.0075])  # stratified over 0.02 s
    bands, _ = exposure_times(70, cfg)
    assert bands[-1].tolist() == [64, 70]


@pytest.mark.parametrize("camera", [CAMERA, Camera.fisheye_spot_like(96, 72)], ids=["pinhole", "fisheye"])
def test_band_camera_has_the_same_rays(camera):
    full = camera.pixel_dirs_cam()
    for r0, r1 in ((0, 8), (8, 16), (64, 72), (33, 34)):
        band = band_camera(camera, r0, r1)
        assert band.height == r1 - r0 and band.width == camera.width
        np.testing.assert_allclose(band.pixel_dirs_cam(), full[r0:r1], atol=1e-12)
    assert band_camera(camera, 0, 72) is camera


def _plan(cfg, pose_fn):
    return plan_frames(cfg, CAMERA, np.array([0.0, 0.5]), 2.0, 0, pose_fn)


def test_render_light_without_motion_is_the_clean_render(oracles):
    from nsim.synth.path import handheld_path

    oracle = oracles["robot-lab"]
    pose = handheld_path(oracle.spec, 8, seed=0)[3]
    cfg = PhoneConfig(exposure_time_s=0.02, readout_time_s=0.03)
    plan = _plan(cfg, lambda t: np.repeat(pose[None], len(t), axis=0))  # a camera that does not move
    light = render_light(oracle, CAMERA, plan, 0, supersample=2)
    clean = _linear(oracle.render_gt(CAMERA, pose, supersample=2).rgb)
    assert light.shape == (72, 96, 3) and light.dtype == np.float32
    diff = np.abs(light - clean)
    assert np.median(diff) < 1e-6 and diff.max() < 0.05  # band edges filter textures a little differently


def test_longer_exposure_blurs_more(oracles):
    """The blur length is speed x exposure time: doubling the exposure removes more fine detail."""
    oracle = oracles["robot-lab"]

    def pose_at(t_s):  # the 8-frame capture's path at 2 fps
        return handheld_path_at(oracle.spec, np.asarray(t_s) * 2.0 / 8, seed=0)

    clean = _linear(oracle.render_gt(CAMERA, pose_at(np.array([0.5]))[0], supersample=2).rgb)
    energy = [detail_energy(clean)]
    for exposure_s in (0.01, 0.02, 0.04, 0.08):
        plan = _plan(PhoneConfig(exposure_time_s=exposure_s, motion_blur_samples=9), pose_at)
        energy.append(detail_energy(render_light(oracle, CAMERA, plan, 1, supersample=2)))
    ratio = np.array(energy) / energy[0]
    assert (np.diff(ratio) < 0).all() and ratio[1] > 0.97 and ratio[-1] < 0.75, ratio


@pytest.mark.parametrize("quality", [85, 92])
def test_encode_jpeg_at_quality(quality):
    import cv2

    rgb = (np.random.default_rng(0).uniform(0, 1, (72, 96, 3)) * 80 + np.linspace(0, 170, 96)[None, :, None])
    rgb = cv2.GaussianBlur(rgb, (0, 0), 1.5).astype(np.uint8)
    data = encode_jpeg(rgb, quality)
    assert data[:3] == b"\xff\xd8\xff"
    np.testing.assert_array_equal(jpeg_luma_table(data), luma_table_for_quality(quality))
    back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR_RGB)
    assert back.shape == rgb.shape and 0 < np.abs(back.astype(float) - rgb).mean() < 3.0
    assert encode_jpeg(rgb, quality) == data
    with pytest.raises(ValueError, match="uint8"):
        encode_jpeg(rgb.astype(np.float32), quality)
