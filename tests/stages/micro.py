"""What the stage tests share: a 64x48 test-room capture and a micro scene NeRF that trains in seconds."""

from __future__ import annotations

from nsim.config import read_preset

CAPTURE = ["width=64", "height=48", "n_frames=24", "supersample=1", "video=false"]

#: The micro scene NeRF: ``nsim/configs/train_scene/micro.yaml``, put over the tiny preset.
MICRO_SCENE = read_preset("train_scene", "micro")


def micro_scene(**sections) -> dict:
    """``MICRO_SCENE`` with some sections updated, e.g. ``micro_scene(optim={"steps": 40})``."""
    out = {k: dict(v) for k, v in MICRO_SCENE.items()}
    for k, v in sections.items():
        out.setdefault(k, {}).update(v)
    return out


def capture_and_micro_scene(root, ws) -> None:
    """Through the CLI: the micro capture tagged ``capture/t`` and a micro scene trained on it, ``scene/t``."""
    from nsim.cli import main
    from nsim.config import preset_path

    args = ["--workspace", str(ws), "capture", "synth"]
    for kv in CAPTURE:
        args += ["--set", kv]
    assert main([*args, "--tag", "capture/t"]) == 0
    micro = preset_path("train_scene", "micro")
    assert main(["--workspace", str(ws), "--device", "cpu", "train-scene", "--poses", "capture/t", "--preset", "tiny",
                 "--config", str(micro), "--tag", "scene/t"]) == 0
