"""`nsim train-scene` through the CLI at micro size: artifact files, the cache, bad input, kill -9 + resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from nsim.cli import main
from nsim.workspace.store import Store
from tests.stages.micro import CAPTURE, micro_scene

MICRO = micro_scene(optim={"steps": 40}, output={"log_every": 2, "checkpoint_every": 2})


def _capture(ws: Path) -> str:
    args = ["--workspace", str(ws), "--seed", "0", "capture", "synth"]
    for kv in CAPTURE:
        args += ["--set", kv]
    assert main([*args, "--tag", "capture/t"]) == 0
    return Store(ws).resolve("capture/t")


@pytest.fixture(scope="module")
def micro_config(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("cfg") / "micro.yaml"
    p.write_text(yaml.safe_dump(MICRO))
    return p


@pytest.fixture(scope="module")
def trained(tmp_path_factory, micro_config):
    ws = tmp_path_factory.mktemp("ts") / "ws"
    cap = _capture(ws)
    args = ["--workspace", str(ws), "--device", "cpu", "train-scene", "--poses", cap, "--preset", "tiny",
            "--config", str(micro_config), "--tag", "scene/t"]
    assert main(args) == 0
    store = Store(ws)
    return store, store.get(store.resolve("scene/t")), args


def test_artifact_files_and_manifest(trained):
    store, art, _ = trained
    manifest = json.loads(art.file("manifest.json").read_text())
    assert manifest["kind"] == "scene-checkpoint" and manifest["stage"] == "train_scene"
    assert set(manifest["inputs"]) == {"poses"}
    for name in ("model.pt", "scene.json", "bounds.json", "occupancy_grid.npy", "obstacles.png", "obstacles.json",
                 "curves.png", "eval.json"):
        assert art.file(name).is_file(), name
    s = manifest["summary"]
    assert s["steps"] == 40 and s["device"] == "cpu" and s["source_kind"] == "capture"
    assert s["frames"] == 24 and s["eval_frames"] == 3 and s["train_frames"] == 21
    assert "train_seconds" in manifest["timing"]
    assert s["image_size"] == [64, 48] and s["train_image_size"] == [64, 48] and s["metric"] is True
    ev = json.loads(art.file("eval.json").read_text())
    assert ev["resolution"]["scored_wh"] == [64, 48]  # the tiny preset scores as captured
    assert "left-half" in ev["protocol"]["psnr_half, ssim_half, lpips_half"]
    assert {"psnr", "ssim", "lpips", "psnr_half", "ssim_half", "lpips_half"} <= set(ev["views"][0])
    scene = json.loads(art.file("scene.json").read_text())
    assert scene["metric"] is True and scene["units"] == "m"
    # the resume directory is gone once the artifact is published
    assert not list((store.root / "tmp").glob("train_scene.*.resume"))
    from nsim.rendering import load_model

    model = load_model(art.path)
    assert model.aabb.shape == (2, 3)


def test_cached_rerun_returns_the_same_id(trained, capsys):
    store, art, args = trained
    capsys.readouterr()
    assert main(args) == 0
    captured = capsys.readouterr()
    assert art.id in captured.out and "cached" in captured.err


def test_wrong_kind_and_missing_poses_exit_2(trained, capsys):
    store, art, _ = trained
    ws = str(store.root)
    assert main(["--workspace", ws, "train-scene", "--poses", art.id]) == 2
    assert "scene-checkpoint artifact" in capsys.readouterr().err
    assert main(["--workspace", ws, "train-scene", "--poses", "nope/none"]) == 2
    assert main(["--workspace", ws, "train-scene", "--poses", store.resolve("capture/t"), "--set", "optim.steps=-1"]) == 2


@pytest.mark.slow
def test_kill_9_then_rerun_publishes_the_same_artifact(tmp_path, micro_config):
    ws_a, ws_b = tmp_path / "a", tmp_path / "b"
    cap = _capture(ws_a)
    assert _capture(ws_b) == cap
    args = ["--device", "cpu", "--no-progress", "train-scene", "--poses", cap, "--preset", "tiny",
            "--config", str(micro_config), "--set", "optim.steps=60"]
    proc = subprocess.Popen([sys.executable, "-m", "nsim.cli", "--workspace", str(ws_a), *args],
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 1800  # a guard against a hang only: the loop breaks at step 10
    killed_at = None
    while time.time() < deadline and proc.poll() is None:
        ckpts = list((ws_a / "tmp").glob("train_scene.*.resume/last.pt"))
        if ckpts:
            try:
                step = torch.load(ckpts[0], weights_only=False)["step"]
            except Exception:  # noqa: BLE001 - mid-replace; try again
                step = 0
            if step >= 10:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait()
                killed_at = step
                break
        time.sleep(0.02)
    assert killed_at is not None and killed_at < 60, "the run ended before it could be killed"
    assert proc.returncode == -signal.SIGKILL
    assert all(a.kind != "scene-checkpoint" for a in Store(ws_a).artifacts())
    assert main(["--workspace", str(ws_a), *args, "--tag", "scene/r"]) == 0
    assert main(["--workspace", str(ws_b), *args, "--tag", "scene/r"]) == 0
    resumed, whole = Store(ws_a).resolve("scene/r"), Store(ws_b).resolve("scene/r")
    assert resumed == whole
    timing = json.loads(Store(ws_a).get(resumed).file("manifest.json").read_text())["timing"]
    assert timing["resumed_from_step"] >= 10
