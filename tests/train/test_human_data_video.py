"""``prepare_person_data`` (what ``train-human --video`` runs) with a scripted detector: the checks that need the
detector only run before a moving camera's SfM, and person_fit.json records how the camera was told static or
moving, with its numbers, and the walking speed."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.human.person_video import PersonVideoConfig
from nsim.train.human_data_video import PersonSource, prepare_person_data
from tests.human.test_train_human_video import FPS, HFOV, _Scripted, _video
from tests.stages.sentinel import ReachedWork, block_work


class _Crowded(_Scripted):
    """The scripted walk with someone else in view in every frame."""

    def __call__(self, rgb):
        ob = super().__call__(rgb)
        people = np.zeros_like(ob.person_mask)
        people[:10, :10] = 1.0  # a blob away from the person
        return ob if ob is None else type(ob)(ob.image_uv_px, ob.body_m, ob.visibility, ob.person_mask,
                                              np.maximum(people, ob.person_mask))


@pytest.mark.parametrize("case, message", [("short", "is too short"), ("crowded", "more than one person")])
def test_checks_on_the_detector_alone_run_before_sfm(tmp_path, monkeypatch, case, message):
    calls = block_work(monkeypatch, "nsim.train.human_data_video.camera_path", "nsim.train.human_data_video.fit_person")
    n = 15 if case == "short" else 36
    video = _video(tmp_path / "walk.mp4", n)
    source = PersonSource(video, person=PersonVideoConfig(hfov_deg=HFOV, camera="moving"))
    detector = _Crowded(n) if case == "crowded" else _Scripted(n)
    monkeypatch.setattr("nsim.human.landmarks.other_people", lambda person, people, *a, **k: 0 if people is None
                        or not (people[:10, :10] > 0.5).any() else 1)
    with pytest.raises(InputError, match=message):
        prepare_person_data(source, tmp_path / "out", detector=detector)
    assert calls == []
    with pytest.raises(ReachedWork):  # a good video gets there
        prepare_person_data(PersonSource(_video(tmp_path / "good.mp4", 36), person=source.person), tmp_path / "out",
                            detector=_Scripted(36))
    assert len(calls) == 1


def test_person_fit_records_the_camera_decision_and_the_walking_speed(tmp_path):
    n = 36
    video = _video(tmp_path / "walk.mp4", n)  # frames of noise: no background to track
    source = PersonSource(video, person=PersonVideoConfig(hfov_deg=HFOV, camera_height_m=1.5))
    report = prepare_person_data(source, tmp_path / "out", detector=_Scripted(n))
    decision = report["camera_decision"]
    assert report["camera"] == "static" and decision["by"] == "neither" and decision["background_px"] is None
    assert decision["steps"] >= 3 and decision["advance_per_step_m"] > 0.4  # it walks past the camera
    assert report["camera_path"] is None and report["scale_from"] is None
    assert report["walking_speed_mps"] == pytest.approx(1.3, rel=0.1)
    assert report["fps"] == pytest.approx(FPS)
