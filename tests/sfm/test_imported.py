"""Imports from a transforms.json: the plan (missing files, names in the artifact, its digest)."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.geometry.cameras import Camera
from nsim.io.transforms_json import Frame, TransformsData, write_transforms
from nsim.sfm.imported import artifact_names, plan_import

CAMERA = Camera("PINHOLE", 8, 6, 7.0, 7.0, 3.5, 2.5)


def test_artifact_names_keep_basenames_unless_they_clash():
    assert artifact_names(["a/x.png", "b/y.png", "a/x.png"]) == {"a/x.png": "x.png", "b/y.png": "y.png"}
    assert artifact_names(["a/x.png", "b/x.png", "c.png"]) == {"a/x.png": "a/x.png", "b/x.png": "b/x.png",
                                                               "c.png": "c.png"}


def _scan(tmp_path, names: list[str], present: list[str]):
    tmp_path.joinpath("images").mkdir(parents=True)
    for name in present:
        (tmp_path / name).write_bytes(name.encode())
    frames = [Frame(n, np.eye(4), CAMERA) for n in names]
    return write_transforms(tmp_path / "transforms.json", TransformsData(frames))


def test_plan_missing_files(tmp_path):
    names = [f"images/{i}.png" for i in range(6)]
    path = _scan(tmp_path, names, names[:1])
    with pytest.raises(InputError) as info:
        plan_import(path)
    assert str(info.value) == (
        f"{path}: 5 of the files it names are missing (5 of 6 frames' images): frames[1].file_path: images/1.png, "
        "frames[2].file_path: images/2.png, frames[3].file_path: images/3.png and 2 more; give --skip-missing to "
        "import without them (frames without an image are skipped)")
    plan = plan_import(path, skip_missing=True)
    assert plan.kept == (0,) and [c.dest for c in plan.images] == ["images/0.png"]
    assert plan.skipped == [(i, f"images/{i}.png") for i in range(1, 6)]
    with pytest.raises(InputError, match="none of the images of its 6 frames exists"):
        plan_import(_scan(tmp_path / "empty", names, []), skip_missing=True)


def test_plan_digest_covers_content_names_and_missing(tmp_path):
    path = _scan(tmp_path, ["images/a.png", "images/b.png"], ["images/a.png", "images/b.png"])
    before = plan_import(path).digest()
    (tmp_path / "images/b.png").write_bytes(b"new")
    changed = plan_import(path).digest()
    (tmp_path / "images/b.png").unlink()
    skipped = plan_import(path, skip_missing=True).digest()
    assert len({before, changed, skipped}) == 3
