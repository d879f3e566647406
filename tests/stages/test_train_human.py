"""`nsim train-human` through the CLI at tiny size: from an actor capture and from a data folder, bad input."""

from __future__ import annotations

import json
import shutil

import pytest

from nsim.cli import main
from nsim.workspace.store import Store


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    ws = tmp_path_factory.mktemp("th") / "ws"
    assert main(["--workspace", str(ws), "capture", "synth", "--preset", "tiny", "--actor", "--set", "n_frames=12",
                 "--tag", "capture/actor"]) == 0
    assert main(["--workspace", str(ws), "--device", "cpu", "train-human", "--capture", "capture/actor", "--preset",
                 "tiny", "--steps", "20", "--tag", "human/t"]) == 0
    return Store(ws)


def test_human_checkpoint_files(world):
    art = world.get(world.resolve("human/t"))
    m = json.loads(art.file("manifest.json").read_text())
    assert m["kind"] == "human-checkpoint" and m["inputs"] == {"capture": world.resolve("capture/actor")}
    assert m["summary"]["frames"] == 12 and m["summary"]["background"] == "images"
    for name in ("human.pt", "human.json", "turntable.png", "gait.gif", "eval.json"):
        assert art.file(name).is_file(), name
    from nsim.human.nerf import load_human_model

    model = load_human_model(art.path)
    assert len(model.skeleton.joint_names) == 24
    assert not list((world.root / "tmp").glob("train_human.*.resume"))


def test_folder_input_and_its_errors(world, tmp_path, capsys):
    cap = world.get(world.resolve("capture/actor"))
    folder = tmp_path / "person"
    shutil.copytree(cap.path, folder, ignore=shutil.ignore_patterns("manifest.json"))
    folder.chmod(0o755)
    for p in folder.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    ws = str(world.root)
    args = ["--workspace", ws, "--device", "cpu", "train-human", "--data", str(folder), "--preset", "tiny", "--steps", "5"]
    assert main(args) == 0
    # a missing mask
    masks = sorted((folder / "masks").iterdir())
    masks[3].unlink()
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert masks[3].name in err and err.count("\n") == 1
    # a capture without a person
    assert main(["--workspace", ws, "capture", "synth", "--preset", "tiny", "--set", "n_frames=4", "--tag", "capture/empty"]) == 0
    assert main(["--workspace", ws, "train-human", "--capture", "capture/empty"]) == 2
    assert "no person" in capsys.readouterr().err
    assert main(["--workspace", ws, "train-human", "--data", str(tmp_path / "nope")]) == 2
