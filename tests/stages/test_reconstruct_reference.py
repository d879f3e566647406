"""``nsim reconstruct --reference``: the frames are matched to the reference before SfM, so a reference that cannot
match fails at once (issue 44: it used to fail after 806 s of SfM); images named by their timestamps (TUM RGB-D's
``1305031102.175304.png``) match a TUM reference by time."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.cli import main
from nsim.io.images import write_image


class ReachedSfm(Exception):
    pass


@pytest.fixture
def no_sfm(monkeypatch):
    """SfM replaced by a sentinel: reaching it means every input check passed."""

    def run_sfm(*args, **kwargs):
        raise ReachedSfm

    monkeypatch.setattr("nsim.sfm.colmap.run_sfm", run_sfm)


def _folder(tmp_path, names):
    d = tmp_path / "images"
    d.mkdir()
    rng = np.random.default_rng(0)
    for n in names:
        write_image(d / n, rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))
    return d


def _tum(tmp_path, stamps):
    path = tmp_path / "groundtruth.txt"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n"
                    + "".join(f"{s} {0.1 * i} 0 0 0 0 0 1\n" for i, s in enumerate(stamps)))
    return path


def test_unmatchable_reference_fails_before_sfm(tmp_path, no_sfm, capsys):
    images = _folder(tmp_path, [f"img_{i}.png" for i in range(4)])
    ref = _tum(tmp_path, ["1305031102.1", "1305031102.2", "1305031102.3", "1305031102.4"])
    code = main(["--workspace", str(tmp_path / "ws"), "reconstruct", str(images), "--reference", str(ref)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "groundtruth.txt: the reference has only timestamps, and the input frames have none" in err[0]
    assert not (tmp_path / "ws" / "objects").exists() or not any((tmp_path / "ws" / "objects").iterdir())


def test_images_named_by_timestamps_match_a_tum_reference(tmp_path, no_sfm):
    stamps = ["1305031102.175304", "1305031102.211214", "1305031102.243211", "1305031102.275326"]
    images = _folder(tmp_path, [f"{s}.png" for s in stamps])
    ref = _tum(tmp_path, stamps)
    with pytest.raises(ReachedSfm):  # matched by time: the checks pass and SfM is next
        main(["--workspace", str(tmp_path / "ws"), "reconstruct", str(images), "--reference", str(ref)])
    far = _tum(tmp_path, ["1305031200.0", "1305031200.1", "1305031200.2", "1305031200.3"])
    assert main(["--workspace", str(tmp_path / "ws"), "reconstruct", str(images), "--reference", str(far)]) == 2


def test_names_mixing_stamps_and_not_are_one_line(tmp_path, no_sfm, capsys):
    images = _folder(tmp_path, ["1305031102.175304.png", "1305031102.211214.png", "frame_3.png"])
    ref = _tum(tmp_path, ["1305031102.175304", "1305031102.211214", "1305031102.243211"])
    code = main(["--workspace", str(tmp_path / "ws"), "reconstruct", str(images), "--reference", str(ref)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "is named by its timestamp but frame_3.png is not" in err[0], err


def test_reference_poses_are_the_cameras(tmp_path, monkeypatch, capsys):
    """--reference-poses: SfM gets every frame's reference pose as a known pose (nothing is mapped); without
    --intrinsics it is one line, before anything runs."""
    seen = {}

    def run_sfm(*args, **kwargs):
        seen.update(kwargs)
        raise ReachedSfm

    monkeypatch.setattr("nsim.sfm.colmap.run_sfm", run_sfm)
    stamps = ["1305031102.175304", "1305031102.211214", "1305031102.243211", "1305031102.275326"]
    images = _folder(tmp_path, [f"{s}.png" for s in stamps])
    ref = _tum(tmp_path, stamps)
    code = main(["--workspace", str(tmp_path / "ws"), "reconstruct", str(images), "--reference", str(ref),
                 "--reference-poses"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--reference-poses: needs --reference" in err[0], err
    assert not seen
    intrinsics = tmp_path / "camera.yaml"
    intrinsics.write_text("{model: PINHOLE, width: 32, height: 24, fx: 30.0, fy: 30.0, cx: 16.0, cy: 12.0}\n")
    with pytest.raises(ReachedSfm):
        main(["--workspace", str(tmp_path / "ws"), "reconstruct", str(images), "--reference", str(ref),
              "--reference-poses", "--intrinsics", str(intrinsics)])
    known = seen["known_poses"]
    assert sorted(known) == [f"{s}.png" for s in stamps]
    np.testing.assert_allclose([known[f"{s}.png"][0, 3] for s in stamps], [0.0, 0.1, 0.2, 0.3])
