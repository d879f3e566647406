"""``nsim evaluate`` against a robot's recording: every table recovers perturbations of known size.

The recording is a tiny Spot log of the test room (``nsim capture robot-log`` of a 2 s run, 5 ticks,
64x48 fisheye cameras with depth, a 16 x 180 LiDAR) imported by ``nsim import-log``. Its registration
(the odometry frame in the room: the log's truth) and a recording-mode render (``nsim render
--recording``'s contract: ``render.json`` with the recorded streams and frames, the recording's file
layout) are published here, the render's readings being the recorded ones with known perturbations:

* images: an affine colour change of real + noise, ``A (real + n) + b``, 8-bit (n: one Gaussian value
  per pixel, sigma ``NOISE_SIGMA``): raw PSNR is the PSNR of exactly those images (computed here with
  numpy), and the colour-corrected PSNR that of the noise alone: the frames mapped back by the true
  inverse, ``(sim - b) / A``, against the real ones;
* depth: every reading times ``DEPTH_SCALE`` (AbsRel = |1 - scale|), a few readings NaN (left out);
* LiDAR: every range ``RANGE_OFFSET_M`` longer along its ray, ``DROP_FRACTION`` of the returns lost.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from nsim.cli import main
from nsim.geometry.transforms import interpolate_poses
from nsim.io.exr import read_depth_exr, read_points_exr, write_depth_exr, write_points_exr
from nsim.io.images import read_image, write_image
from nsim.io.tum import Trajectory, read_tum, write_tum
from nsim.workspace.store import Store

COLOUR_GAIN = np.array([0.80, 0.90, 0.85])
COLOUR_OFFSET = np.array([0.10, 0.05, 0.08])
NOISE_SIGMA = 0.01
DEPTH_SCALE = 0.96
NAN_PX = 7  # simulated depth readings set to NaN per frame
RANGE_OFFSET_M = 0.05
DROP_FRACTION = 0.1
ROBOT_LOG = ["--preset", "tiny", "--set", "max_ticks=5"]
SCENE = "5c" * 32  # the scene a render names (not read by evaluate)


@dataclass
class World:
    ws: Path
    store: Store
    recording: str
    registration: str
    truth: dict

    @property
    def rec_dir(self) -> Path:
        return self.store.get(self.recording).path

    @property
    def doc(self) -> dict:
        return json.loads((self.rec_dir / "recording.json").read_text())


def _registration(store: Store, recording: str, truth: dict, name: str = "reg") -> str:
    """A registration artifact with the log's true odometry frame (what ``nsim register-log`` estimates)."""
    rec = store.get(recording).path
    odom = read_tum(rec / "trajectory.tum")
    stamps_ns = np.load(rec / "trajectory_ns.npy")
    world = np.asarray(truth["odom_to_world"]) @ odom.poses_se3()
    key = store.action_key("test_registration", 1, {"name": name}, {"recording": recording})
    with store.publish(kind="registration", stage="test_registration", version=1, key=key, config={},
                       inputs={"recording": recording}) as out:
        (out.dir / "registration.json").write_text(json.dumps({
            "inputs": {"recording": recording, "poses": SCENE}, "odom_to_world": truth["odom_to_world"],
            "clock_offset_s": truth["clock_offset_s"], "scale": 1.0}))
        write_tum(out.dir / "trajectory_world.tum", Trajectory.from_poses(stamps_ns / 1e9, world))
        np.save(out.dir / "trajectory_world_ns.npy", stamps_ns)
    return out.ref


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> World:
    root = tmp_path_factory.mktemp("recording_truth")
    ws = root / "ws"
    w = ["--workspace", str(ws)]
    assert main([*w, "simulate", "--scenario", "nsim/configs/scenarios/spot_run.json", "--preset", "tiny",
                 "--set", "max_duration_s=2.0", "--tag", "trajectory/run"]) == 0
    assert main([*w, "capture", "robot-log", "trajectory/run", *ROBOT_LOG, "--out", str(root / "run")]) == 0
    assert main([*w, "import-log", str(root / "run"), "--tag", "recording/run"]) == 0
    store = Store(ws)
    truth = json.loads((root / "run.truth.json").read_text())
    recording = store.resolve("recording/run")
    return World(ws, store, recording, _registration(store, recording, truth), truth)


# ---------------------------------------------------------------------------------- the perturbations
def _rgb(u8: np.ndarray) -> np.ndarray:
    return np.repeat(u8[..., None], 3, -1) if u8.ndim == 2 else u8


def image_noise(key: tuple[str, int], shape: tuple[int, ...]) -> np.ndarray:
    return np.random.default_rng([7, sum(map(ord, key[0])), key[1]]).normal(0.0, NOISE_SIGMA, shape)


def sim_image(real_u8: np.ndarray, key: tuple[str, int]) -> np.ndarray:
    """``A (real + n) + b``, 8-bit."""
    real = _rgb(real_u8) / 255.0
    sim = (real + image_noise(key, real.shape[:2] + (1,))) * COLOUR_GAIN + COLOUR_OFFSET
    return np.rint(np.clip(sim, 0, 1) * 255).astype(np.uint8)


def sim_depth(real: np.ndarray, key: tuple[str, int]) -> np.ndarray:
    sim = (real * DEPTH_SCALE).astype(np.float32)
    valid = np.flatnonzero(np.isfinite(real) & (real > 0))
    sim.reshape(-1)[valid[:NAN_PX]] = np.nan
    return sim


def dropped(key: tuple[str, int], n: int) -> np.ndarray:
    rng = np.random.default_rng([11, key[1]])
    return rng.permutation(n)[: int(round(DROP_FRACTION * n))]


def sim_lidar(real: dict[str, np.ndarray], key: tuple[str, int]) -> dict[str, np.ndarray]:
    xyz = np.stack([real[c][0].astype(np.float64) for c in "XYZ"], -1)
    rng = np.linalg.norm(xyz, axis=-1)
    far = rng + RANGE_OFFSET_M
    xyz = xyz * (far / rng)[:, None]
    lost = dropped(key, len(rng))
    xyz[lost], far[lost] = np.nan, np.inf
    return {**{c: xyz[None, :, k].astype(np.float32) for k, c in enumerate("XYZ")},
            "range": far[None].astype(np.float32)}


PERTURB = {"camera": sim_image, "depth": sim_depth, "lidar": sim_lidar}


def fake_render(w: World, tag: str, *, perturb: dict | None = None, recording: str | None = None,
                registration: str | None = None, edit=None) -> str:
    """A recording-mode render of ``w``'s recording: every recorded frame through ``perturb`` (kind ->
    fn(real, (stream, index)) -> sim); ``edit(render_dir, doc)`` may damage it before it is published."""
    perturb = PERTURB if perturb is None else perturb
    rec, doc = w.rec_dir, w.doc
    reg = w.store.get(w.registration).path
    world_ns = np.load(reg / "trajectory_world_ns.npy")
    body = read_tum(reg / "trajectory_world.tum").poses_se3()
    offset_ns = int(round(w.truth["clock_offset_s"] * 1e9))
    key = w.store.action_key("test_render", 1, {"tag": tag}, {})
    streams = []
    with w.store.publish(kind="render", stage="test_render", version=1, key=key, config={},
                         inputs={"recording": recording or w.recording, "scene": SCENE}) as out:
        for name, entry in doc["streams"].items():
            kind, sensor = name.split("/")
            stamps = np.load(rec / kind / sensor / "stamps_ns.npy")
            odom_ns = stamps - (offset_ns if kind == "camera" else 0)
            poses = interpolate_poses((world_ns - world_ns[0]) / 1e9, body, (odom_ns - world_ns[0]) / 1e9)
            poses = poses @ np.asarray(entry["sensor_to_body"])
            frames = []
            (out.dir / kind / sensor).mkdir(parents=True)
            for k, i in enumerate(entry["frames"]):
                src = rec / kind / sensor / f"{i:06d}"
                dst = out.dir / kind / sensor / f"{i:06d}"
                if kind == "camera":
                    write_image(dst.with_suffix(".png"), perturb[kind](read_image(src.with_suffix(".png")), (sensor, i)))
                elif kind == "depth":
                    write_depth_exr(dst.with_suffix(".exr"), perturb[kind](read_depth_exr(src.with_suffix(".exr")),
                                                                            (sensor, i)))
                else:
                    write_points_exr(dst.with_suffix(".exr"), perturb[kind](read_points_exr(src.with_suffix(".exr")),
                                                                             (sensor, i)))
                frames.append({"index": int(i), "stamp_ns": int(stamps[k]), "odom_time_ns": int(odom_ns[k]),
                               "sensor_to_world": poses[k].tolist()})
            streams.append({"name": sensor, "kind": kind, "frames": frames})
        meta = {"mode": "recording", "recording": recording or w.recording,
                "registration": registration or w.registration, "scene": SCENE, "streams": streams}
        if edit is not None:
            edit(out.dir, meta)
        (out.dir / "render.json").write_text(json.dumps(meta))
    w.store.set_ref(f"render/{tag}", out.ref)
    return out.ref


@pytest.fixture(scope="module")
def render(world) -> str:
    return fake_render(world, "perturbed")


def evaluate(w: World, table: str, render: str, *sets: str) -> int:
    args = ["--workspace", str(w.ws), "--device", "cpu", "evaluate", "--preset", "tiny", "--table", table,
            "--render", render, "--set", "lpips_net=none"]
    for s in sets:
        args += ["--set", s]
    return main(args)


def latest(w: World) -> tuple:
    art = w.store.get(w.store.resolve("evaluation/latest"))
    meta = json.loads(art.file("evaluation.json").read_text())
    table = json.loads(art.file(f"{meta['table']}.json").read_text())
    return art, meta, table


def cell(v):
    return v["float"] if isinstance(v, dict) and "float" in v else v


def recorded_frames(w: World, kind: str):
    """(stream, index, path in the recording) of every recorded frame of ``kind``."""
    for name, entry in w.doc["streams"].items():
        k, sensor = name.split("/")
        if k == kind:
            for i in entry["frames"]:
                yield sensor, i, w.rec_dir / k / sensor / f"{i:06d}.{'png' if k == 'camera' else 'exr'}"


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a - b) ** 2)))


# ---------------------------------------------------------------------------------- the tables
def test_spot_rgb_raw_and_colour_corrected(world, render):
    assert evaluate(world, "spot-rgb", render) == 0
    art, meta, table = latest(world)
    rows = {r["Camera"]: r for r in table["rows"]}
    raw, noise = {}, {}
    for sensor, i, path in recorded_frames(world, "camera"):
        real = _rgb(read_image(path)) / 255.0
        sim = sim_image(read_image(path), (sensor, i)) / 255.0
        raw.setdefault(sensor, []).append(psnr_db(sim, real))
        inverse = np.clip((sim - COLOUR_OFFSET) / COLOUR_GAIN, 0, 1)  # real + n and the 8-bit steps
        noise.setdefault(sensor, []).append(psnr_db(inverse, real))
    assert set(rows) == set(raw)
    for cam, row in rows.items():
        assert cell(row["PSNR"]) == pytest.approx(np.mean(raw[cam]), abs=1e-3), cam
        # corrected: the noise alone (the true inverse map applied to the 8-bit frames); the least-squares map
        # does as well or a little better, since it also fits the noise (regression dilution, measured 0.07-0.16 dB)
        assert np.mean(noise[cam]) - 0.02 <= cell(row["PSNR cc"]) <= np.mean(noise[cam]) + 0.25, cam
        assert cell(row["PSNR cc"]) > cell(row["PSNR"]) + 3 and cell(row["SSIM cc"]) > cell(row["SSIM"])
        assert row["frames"] == len(raw[cam])
    # the fitted maps invert the colour change: real = (sim - b) / A
    for cam, m in meta["details"]["colour_correction"]["maps"].items():
        m = np.array(m)
        np.testing.assert_allclose(np.diag(m[:, :3]), 1 / COLOUR_GAIN, rtol=0.05, err_msg=cam)
        np.testing.assert_allclose(m[:, 3], -COLOUR_OFFSET / COLOUR_GAIN, atol=0.02, err_msg=cam)
    assert meta["ground_truth"][render].startswith(f"recording {world.recording[:12]}")
    assert any("fitted on all the camera's scored frames" in n for n in table["notes"])
    assert (art.path / "plots" / "psnr_db_per_frame.png").is_file()


def test_spot_depth_scale_error(world, render):
    assert evaluate(world, "spot-depth", render) == 0
    art, meta, table = latest(world)
    n_frames = {}
    for sensor, _i, _p in recorded_frames(world, "depth"):
        n_frames[sensor] = n_frames.get(sensor, 0) + 1
    rows = {r["Camera"]: r for r in table["rows"]}
    assert set(rows) == set(n_frames)
    for cam, row in rows.items():
        assert cell(row["AbsRel"]) == pytest.approx(1 - DEPTH_SCALE, abs=1e-5), cam
        assert cell(row["δ<1.05"]) == 1.0 and row["frames"] == n_frames[cam]
    frames = json.loads(art.file("records.json").read_text())["frames"]
    assert all(f["sim_invalid_px"] == NAN_PX for f in frames)
    assert any(f"left out ({NAN_PX * len(frames)} px)" in n for n in table["notes"])


def test_lidar_range_offset_and_dropped_returns(world, render):
    assert evaluate(world, "lidar", render) == 0
    art, meta, table = latest(world)
    (row,) = table["rows"]
    n = sum(read_points_exr(p)["X"].size for *_, p in recorded_frames(world, "lidar"))
    lost = sum(len(dropped((s, i), read_points_exr(p)["X"].size)) for s, i, p in recorded_frames(world, "lidar"))
    assert row["LiDAR"] == "lidar" and row["points"] == n
    assert cell(row["range err median [m]"]) == pytest.approx(RANGE_OFFSET_M, abs=1e-5)
    assert cell(row["range err mean [m]"]) == pytest.approx(RANGE_OFFSET_M, abs=1e-5)
    assert cell(row["range bias [m]"]) == pytest.approx(RANGE_OFFSET_M, abs=1e-5)
    assert cell(row["real only"]) == pytest.approx(lost / n) and lost / n == pytest.approx(DROP_FRACTION, abs=0.01)
    assert cell(row["hit agreement"]) == pytest.approx(1 - lost / n) and cell(row["sim only"]) == 0.0
    # each simulated point lies RANGE_OFFSET_M from its real one; a lost return's real point is further from the rest
    assert RANGE_OFFSET_M / 2 < cell(row["Chamfer [m]"]) < 2 * RANGE_OFFSET_M


def test_slam_and_detection_run_on_real_and_simulated_frames(world, render):
    """At 64x48 SfM fails on both sides (n/a with the reason), and HOG finds nobody in the empty room:
    the tables say so instead of inventing numbers; the ground truth is the registered trajectory."""
    assert evaluate(world, "slam", render, "slam.camera=left") == 0
    art, meta, table = latest(world)
    (row,) = table["rows"]
    assert row["Sequence"] == "left" and "not_available" in row["ATE real [m]"]
    truth = read_tum(art.path / "slam" / "left" / "ground_truth.tum")
    entry = world.doc["streams"]["camera/left"]
    # the true poses at the ticks (frame k: tick k), up to the odometry's drift over 1 m (a few mm)
    body = np.asarray(world.truth["body_to_world"])
    want = body[: len(truth)] @ np.asarray(entry["sensor_to_body"])
    np.testing.assert_allclose(truth.poses_se3()[:, :3, 3], want[:, :3, 3], atol=0.02)
    np.testing.assert_allclose(truth.timestamps_s, np.asarray(world.truth["stamps_s"])[: len(truth)], atol=1e-6)
    assert "registration" in " ".join(table["notes"])
    assert evaluate(world, "detection", render) == 0
    art, meta, table = latest(world)
    total = table["rows"][-1]
    assert total["Scene"] == "all" and total["boxes sim"] == total["boxes real"] == 0
    assert "recording" in meta["ground_truth"][render]


# ---------------------------------------------------------------------------------- bad input
def _drop_frame(d: Path, meta: dict) -> None:
    (d / "camera" / "left" / "000002.png").unlink()


def _restamp(d: Path, meta: dict) -> None:
    next(s for s in meta["streams"] if s["kind"] == "depth")["frames"][1]["stamp_ns"] += 1000


@pytest.mark.parametrize("case, table, words", [
    ("no-recording", "spot-rgb", "which is not in the workspace"),
    ("frame-missing", "spot-rgb", "has no file camera/left/000002.png"),
    ("restamped", "spot-depth", "ns, the recording's"),
    ("scenes", "scenes", "needs poses-mode renders"),
])
def test_bad_input_is_one_line_and_exit_2(world, case, table, words, capsys):
    kw = {"no-recording": {"recording": "0f" * 32}, "frame-missing": {"edit": _drop_frame},
          "restamped": {"edit": _restamp}, "scenes": {}}[case]
    ident = lambda real, key: real  # noqa: E731
    ref = fake_render(world, f"bad-{case}", perturb={"camera": ident, "depth": ident, "lidar": ident}, **kw)
    before = sorted(p.name for p in (world.ws / "objects").glob("*/*"))
    capsys.readouterr()
    assert evaluate(world, table, ref) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and words in err[0], err
    assert sorted(p.name for p in (world.ws / "objects").glob("*/*")) == before


def test_colour_map_recovers_a_known_affine():
    """The core: an exact affine change (no noise) is inverted exactly, grey or colour."""
    from nsim.metrics.colour import apply_colour_affine, fit_colour_affine

    rng = np.random.default_rng(0)
    real = [rng.random((8, 9, 3)) for _ in range(3)]
    m = np.array([[0.9, 0.1, 0.0, 0.05], [0.0, 1.1, 0.0, -0.02], [0.05, 0.0, 0.8, 0.1]])
    sim = [x @ m[:, :3].T + m[:, 3] for x in real]
    fit = fit_colour_affine(sim, real)
    for s, x in zip(sim, real, strict=True):
        np.testing.assert_allclose(apply_colour_affine(s, fit), x, atol=1e-6)
    grey = [np.repeat(x[..., :1], 3, -1) for x in real]
    fit = fit_colour_affine([0.5 * g + 0.2 for g in grey], grey)
    np.testing.assert_allclose(apply_colour_affine(0.5 * grey[0] + 0.2, fit), grey[0], atol=1e-6)


# ---------------------------------------------------------------------------------- SLAM that works
@pytest.fixture(scope="module")
def slam_world(tmp_path_factory) -> World:
    """Spot's left camera alone at 256x192 (SIFT needs the pixels), 8 ticks 0.1 s apart."""
    root = tmp_path_factory.mktemp("recording_slam")
    ws = root / "ws"
    w = ["--workspace", str(ws)]
    assert main([*w, "simulate", "--scenario", "nsim/configs/scenarios/spot_run.json", "--preset", "tiny",
                 "--tag", "trajectory/run"]) == 0
    assert main([*w, "capture", "robot-log", "trajectory/run", "--preset", "tiny", "--set", "sensors=[left]",
                 "--set", "image_scale=0.4", "--set", "tick_stride=2", "--set", "max_ticks=8",
                 "--out", str(root / "run")]) == 0
    assert main([*w, "import-log", str(root / "run"), "--tag", "recording/run"]) == 0
    store = Store(ws)
    truth = json.loads((root / "run.truth.json").read_text())
    recording = store.resolve("recording/run")
    return World(ws, store, recording, _registration(store, recording, truth), truth)


def test_slam_on_real_and_simulated_frames(slam_world):
    """SfM registers every frame on both sides (the simulated ones: the real ones recoloured, with noise); both
    trajectories lie within a centimetre of the registered one after Sim(3) alignment (measured 0.6 / 0.7 mm)."""
    ref = fake_render(slam_world, "slam")
    assert evaluate(slam_world, "slam", ref, "slam.camera=left") == 0
    art, meta, table = latest(slam_world)
    (row,) = table["rows"]
    assert row["Sequence"] == "left" and row["registered real"] == 1.0 and row["registered sim"] == 1.0
    assert 0.0 < cell(row["ATE real [m]"]) < 0.01 and 0.0 < cell(row["ATE sim [m]"]) < 0.01
    assert cell(row["Δ sim−real [m]"]) == pytest.approx(cell(row["ATE sim [m]"]) - cell(row["ATE real [m]"]))
    trajs = {side: read_tum(art.path / "slam" / "left" / f"{side}.tum") for side in ("ground_truth", "real", "sim")}
    assert len(trajs["ground_truth"]) == len(trajs["real"]) == len(trajs["sim"]) == 8
