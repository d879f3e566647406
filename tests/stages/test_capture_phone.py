"""`nsim capture synth` through the phone model at tiny size: each effect measured against the clean
capture with the same seed, exact ground truth, determinism, and presets without it unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.config import from_dict, read_yaml
from nsim.io.exr import read_depth_exr
from nsim.io.images import read_image
from nsim.io.transforms_json import read_transforms
from nsim.workspace.store import Store
from tests.synth.phone_checks import (
    detail_energy,
    flow_px,
    jpeg_luma_table,
    luma_table_for_quality,
    srgb_to_linear,
    warp,
)

# 8 frames at 2 fps: the tiny preset's motion per second (two loops in 4 s) at a fifth of the frames
BASE = ("capture", "synth", "--preset", "tiny", "--set", "n_frames=8", "--set", "fps=2.0", "--set", "video=false")
EFFECTS = {
    "clean": {},
    "drift": {"exposure_drift_std_stops": 0.4, "white_balance_drift_std_stops": 0.1, "drift_timescale_s": 0.5},
    "noise": {"shot_noise_std_at_white": 0.05, "read_noise_std": 0.01},
    "blur": {"exposure_time_s": 0.03},
    "rolling": {"readout_time_s": 0.05},
    "vignette": {"vignetting_corner_gain": 0.5},
}


def phone_preset_settings() -> dict:
    from nsim.config import configs_dir

    return read_yaml(configs_dir() / "capture" / "phone.yaml")["phone"]


def _sets(settings: dict) -> list[str]:
    return [a for k, v in settings.items() for a in ("--set", f"phone.{k}={json.dumps(v)}")]


class Captures:
    """The captures of one workspace, made on first use: ``captures[name]`` is an artifact."""

    def __init__(self, root):
        self.root = root
        self.store = Store(root)
        self.made = {}

    def make(self, name: str, settings: dict, workspace=None) -> str:
        from nsim.cli import main

        ws = workspace or self.root
        assert main(["--workspace", str(ws), *BASE, *_sets(settings), "--tag", f"capture/{name}"]) == 0
        return Store(ws).resolve(f"capture/{name}")

    def __getitem__(self, name: str):
        if name not in self.made:
            settings = phone_preset_settings() if name == "phone" else EFFECTS[name]
            self.made[name] = self.store.get(self.make(name, settings))
        return self.made[name]


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> Captures:
    return Captures(tmp_path_factory.mktemp("phone") / "ws")


def smooth(image: np.ndarray, sigma_px: float = 1.0) -> np.ndarray:
    import cv2

    return cv2.GaussianBlur(np.asarray(image, dtype=np.float32), (0, 0), sigma_px)


def frames(art):
    return read_transforms(art.path / "transforms.json").frames


def linear(art, frame) -> np.ndarray:
    return srgb_to_linear(read_image(art.path / frame.file_path))


def pose_at(art, t_s: np.ndarray) -> np.ndarray:
    """The capture's camera path at times ``t_s (M,)``, rebuilt from its room and config."""
    from nsim.stages.capture import Config, path_config
    from nsim.synth.path import handheld_path_at
    from nsim.synth.room import RoomSpec

    cfg = from_dict(Config, art.manifest["config"])
    spec = RoomSpec.from_dict(json.loads((art.path / "room.json").read_text())["spec"])
    return handheld_path_at(spec, np.asarray(t_s) * cfg.fps / cfg.n_frames, seed=art.manifest["seed"],
                            cfg=path_config(cfg))


def test_phone_preset_at_tiny_size(captures, tmp_path):
    """Every effect on (the phone preset's values): JPEG at its quality, gains recorded, exact GT, determinism."""
    from nsim.stages.capture import Config
    from nsim.synth.phone import PhoneConfig, drift_gains

    clean, art = captures["clean"], captures["phone"]
    settings = phone_preset_settings()
    cfg = from_dict(Config, art.manifest["config"])
    assert cfg.phone == PhoneConfig(**settings) and cfg.phone.any_effect
    data = read_transforms(art.path / "transforms.json")
    assert data.extra["nsim_phone"]["config"] == settings
    gain, wb = drift_gains(cfg.phone, cfg.n_frames, cfg.fps, art.manifest["seed"])
    for k, (f, g) in enumerate(zip(data.frames, frames(clean), strict=True)):
        assert f.file_path == f"images/frame_{k:05d}.jpg"
        jpeg = (art.path / f.file_path).read_bytes()
        np.testing.assert_array_equal(jpeg_luma_table(jpeg), luma_table_for_quality(settings["jpeg_quality"]))
        assert f.extra["exposure_gain"] == gain[k] and f.extra["wb_gains_rgb"] == wb[k].tolist()
        assert f.extra["wb_gains_rgb"][1] == 1.0
        # ground truth: the clean capture's poses and depth, byte for byte
        np.testing.assert_array_equal(f.cam_to_world, g.cam_to_world)
        assert f.timestamp_s == g.timestamp_s and f.depth_file_path == g.depth_file_path
        assert (art.manifest["files"][f.depth_file_path]["sha256"]
                == clean.manifest["files"][g.depth_file_path]["sha256"])
        rms = np.sqrt(np.mean((linear(art, f) - linear(clean, g)) ** 2))
        assert rms > 0.01  # and the images are not the clean ones
    assert art.manifest["files"]["gt_trajectory.tum"] == clean.manifest["files"]["gt_trajectory.tum"]
    assert len(set(gain.round(6))) == len(gain)
    # deterministic: a fresh workspace computes the same artifact id
    assert captures.make("phone", settings, workspace=tmp_path / "again") == art.id


def test_presets_without_phone_are_unchanged(captures):
    """While phone is all defaults, neither the action key nor the manifest mention it (ids as before)."""
    from nsim.config import load_config
    from nsim.stages.capture import Config, recorded_config

    keys_before_phone = ["room", "room_seed", "camera", "width", "height", "hfov_deg", "n_frames", "fps",
                         "supersample", "video", "low_pass_height_m", "actor", "actor_height_m", "actor_speed_mps"]
    for preset in ("default", "tiny"):
        assert list(recorded_config(load_config(Config, stage="capture", preset=preset))) == keys_before_phone
    art = captures["clean"]
    assert "phone" not in art.manifest["config"]
    data = read_transforms(art.path / "transforms.json")
    assert set(data.extra) == {"nsim_capture"} and all(not f.extra for f in data.frames)
    assert all(f.file_path.endswith(".png") for f in data.frames)
    assert "phone" in recorded_config(load_config(Config, stage="capture", preset="phone"))


def test_exposure_and_white_balance_drift(captures):
    """Each frame is the clean one times its recorded exposure and white-balance gains (linear light)."""
    clean, art = captures["clean"], captures["drift"]
    gains = []
    for f, g in zip(frames(art), frames(clean), strict=True):
        expected = f.extra["exposure_gain"] * np.asarray(f.extra["wb_gains_rgb"])
        lin, ref = linear(art, f), linear(clean, g)
        for c in range(3):
            ok = (ref[..., c] > 0.05) & (ref[..., c] * expected[c] < 0.9)
            assert np.median(lin[..., c][ok] / ref[..., c][ok]) == pytest.approx(expected[c], rel=0.02)
        gains.append(expected)
    log_gain = np.log2(np.array(gains))
    assert log_gain[:, 1].std() > 0.15 and np.abs(log_gain[:, 1]).max() < 4 * 0.4  # exposure drifts (0.4 stops)
    assert (log_gain[:, 0] - log_gain[:, 1]).std() > 0.03  # and so does the colour balance


def test_sensor_noise(captures):
    """Linear residual against the clean capture: zero mean, variance shot^2 * x + read^2."""
    shot, read = EFFECTS["noise"]["shot_noise_std_at_white"], EFFECTS["noise"]["read_noise_std"]
    clean, art = captures["clean"], captures["noise"]
    z = []
    for f, g in zip(frames(art), frames(clean), strict=True):
        lin, ref = linear(art, f), linear(clean, g)
        ok = (ref > 0.05) & (ref < 0.7)
        z.append(((lin - ref) / np.sqrt(shot**2 * ref + read**2))[ok])
    z = np.concatenate(z)
    assert z.size > 50_000
    assert abs(z.mean()) < 0.03 and z.std() == pytest.approx(1.0, abs=0.06)


def test_motion_blur(captures):
    """Each frame is the mean of the sharp view moved along the path over the exposure (predicted from
    the exact depth), and loses fine detail as that motion predicts: the faster, the more."""
    from nsim.synth.phone import PhoneConfig, exposure_times

    clean, art = captures["clean"], captures["blur"]
    cfg = PhoneConfig(**EFFECTS["blur"])
    _, offsets = exposure_times(72, cfg)
    ratios, predicted_ratios, motion = [], [], []
    for f, g in zip(frames(art), frames(clean), strict=True):
        lin, ref = linear(art, f), linear(clean, g)
        depth = read_depth_exr(clean.path / g.depth_file_path)
        poses = pose_at(art, f.timestamp_s + offsets[0])
        flows = [flow_px(g.camera, depth, g.cam_to_world, np.repeat(p[None], 72, axis=0)) for p in poses]
        predicted = np.mean([warp(ref, fl) for fl in flows], axis=0)
        inner = (slice(6, -6), slice(6, -6))
        err_model = np.median(np.abs(lin - predicted)[inner])
        err_sharp = np.median(np.abs(lin - ref)[inner])
        assert err_model < 0.5 * err_sharp
        motion.append(np.median(np.linalg.norm(flows[-1] - flows[0], axis=-1)))
        ratios.append(detail_energy(lin) / detail_energy(ref))
        predicted_ratios.append(detail_energy(predicted) / detail_energy(ref))
    motion, ratios, predicted_ratios = map(np.array, (motion, ratios, predicted_ratios))
    assert motion.min() > 2.0  # px of motion during the exposure: the blur is there to see
    assert ratios.max() < 0.92
    np.testing.assert_allclose(ratios, predicted_ratios, atol=0.07)
    # proportional to speed: the faster frames lose more
    order = np.argsort(motion)
    assert ratios[order[-2:]].mean() < ratios[order[:2]].mean()


def test_rolling_shutter(captures):
    """Row v shows the view from the path at timestamp + v * readout / H: the rows shift with the motion
    (and not against it), the more the later they are read out."""
    readout = EFFECTS["rolling"]["readout_time_s"]
    clean, art = captures["clean"], captures["rolling"]
    shifts = []
    for f, g in zip(frames(art), frames(clean), strict=True):
        ref = linear(clean, g)
        depth = read_depth_exr(clean.path / g.depth_file_path)
        row_dt = np.arange(72) * readout / 72
        flow = flow_px(g.camera, depth, g.cam_to_world, pose_at(art, f.timestamp_s + row_dt))
        backwards = flow_px(g.camera, depth, g.cam_to_world, pose_at(art, f.timestamp_s - row_dt))
        # compared a little smoothed: the test's bilinear warp must not decide it
        lin, sharp, model, wrong = (smooth(x) for x in (linear(art, f), ref, warp(ref, flow), warp(ref, backwards)))
        for rows, factor in ((slice(4, 20), 0.7), (slice(28, 44), 0.5), (slice(52, 68), 0.5)):
            err = {k: np.median(np.abs(lin - x)[rows, 6:-6]) for k, x in (("model", model), ("sharp", sharp),
                                                                           ("wrong", wrong))}
            assert err["model"] < factor * err["sharp"] and err["wrong"] > 1.5 * err["model"], (rows, err)
        shifts.append([np.median(np.linalg.norm(flow[rows], axis=-1)) for rows in (slice(0, 4), slice(52, 68))])
    shifts = np.array(shifts)
    assert shifts[:, 1].min() > 2.0 and (shifts[:, 0] < 0.25 * shifts[:, 1]).all()  # px: row 0 hardly moves


def test_vignetting(captures):
    """Linear brightness over the clean capture is the cos^4-like falloff: 1 at the centre, the configured gain at the corners."""
    from nsim.synth.phone import vignetting

    corner_gain = EFFECTS["vignette"]["vignetting_corner_gain"]
    clean, art = captures["clean"], captures["vignette"]
    cam = frames(clean)[0].camera
    v = vignetting(cam.width, cam.height, cam.cx, cam.cy, corner_gain).astype(np.float64)
    ratio, corner = [], []
    for f, g in zip(frames(art), frames(clean), strict=True):
        lin, ref = linear(art, f), linear(clean, g)
        ok = ref > 0.08
        ratio.append((lin / np.where(ok, ref, 1.0) / v[..., None])[ok])
        for i, j in ((0, 0), (0, -1), (-1, 0), (-1, -1)):
            if (ref[i, j] > 0.08).all():
                corner.append(lin[i, j] / ref[i, j])
    assert np.median(np.abs(np.concatenate(ratio) - 1.0)) < 0.01
    assert len(corner) >= 4 and np.median(corner) == pytest.approx(corner_gain, rel=0.05)


@pytest.mark.parametrize(("sets", "message"), [
    (["phone.exposure_time_s=0.2"], "phone.exposure_time_s: expected <= 1 / fps = 0.1 s, got 0.2"),
    (["phone.readout_time_s=0.5"], "phone.readout_time_s: expected <= 1 / fps = 0.1 s"),
    (["phone.jpeg_quality=101"], "phone.jpeg_quality: expected int >= 1 and <= 100, got 101"),
    (["phone.vignetting_corner_gain=0"], "phone.vignetting_corner_gain: expected float > 0"),
    (["phone.exposure_time=0.01"], "phone.exposure_time: unknown key (did you mean 'exposure_time_s'?)"),
    (["actor=true", "phone.read_noise_std=0.01"], "phone: not supported with actor: true"),
])
def test_phone_config_errors(run_cli, sets, message):
    code, _, err = run_cli("capture", "synth", "--preset", "tiny", *[a for s in sets for a in ("--set", s)])
    assert code == 2 and message in err
