"""``nsim train-human``: what the data folder's files and the config decide is checked before any image is read
(issue 44): hold-out settings that leave no training frame, or a single frame, used to be refused after every image
and mask was read (and the background scene loaded); with ``--video`` / ``--images``, ``data.holdout_every: 1``
after the person was found in every frame. Reading the frames and finding the person are replaced by sentinels."""

from __future__ import annotations

import json

import pytest

from nsim.cli import main
from tests.human.test_data import _dataset
from tests.stages.sentinel import ReachedWork, block_work


@pytest.fixture
def no_work(monkeypatch):
    return block_work(monkeypatch, "nsim.human.data.HumanData.read_all", "nsim.stages.train_human.prepare_person_data")


def _train(tmp_path, capsys, *args: str):
    capsys.readouterr()
    code = main(["--workspace", str(tmp_path / "ws"), "--device", "cpu", "train-human", "--preset", "tiny", *args])
    return code, capsys.readouterr().err.strip().splitlines()


def _published(tmp_path) -> list[str]:
    return [json.loads(m.read_text())["kind"] for m in (tmp_path / "ws" / "objects").glob("*/*/manifest.json")]


@pytest.mark.parametrize("n, sets, message", [
    (4, ["data.holdout_every=1"], "the hold-out settings leave no training frames"),
    (4, ["data.holdout_every=0", "data.holdout_last_fraction=0.9"], "the hold-out settings leave no training frames"),
    (1, [], "need at least 2 frames, got 1"),
])
def test_data_folder_checked_before_reading_images(tmp_path, no_work, capsys, n, sets, message):
    _dataset(tmp_path / "person", n)
    args = ["--data", str(tmp_path / "person")]
    for kv in sets:
        args += ["--set", kv]
    code, err = _train(tmp_path, capsys, *args)
    assert code == 2 and len(err) == 1, err
    assert message in err[0], err
    assert no_work == [] and _published(tmp_path) == []


def test_person_frames_holdout_every_frame_fails_before_finding_the_person(tmp_path, no_work, capsys):
    (tmp_path / "frames").mkdir()
    code, err = _train(tmp_path, capsys, "--images", str(tmp_path / "frames"), "--set", "data.holdout_every=1")
    assert code == 2 and len(err) == 1, err
    assert "data.holdout_every 1 holds out every frame" in err[0]
    assert no_work == []


def test_good_folder_reaches_the_images(tmp_path, no_work):
    _dataset(tmp_path / "person", 4)
    with pytest.raises(ReachedWork):
        main(["--workspace", str(tmp_path / "ws"), "--device", "cpu", "train-human", "--preset", "tiny", "--data",
              str(tmp_path / "person")])
    assert len(no_work) == 1
