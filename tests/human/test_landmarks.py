"""The detector interface: stacking a detector's results, counting other people, and the optional extra."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.human.landmarks import (
    LANDMARK_BONES,
    LANDMARK_NAMES,
    MIRRORED_LANDMARKS,
    TRAINING_MASK_THRESHOLD,
    FrameObservation,
    MediaPipePoseDetector,
    average_looks,
    confirmed_person,
    observe,
    other_people,
    other_people_blobs,
    person_training_mask,
    track_outliers,
    unmirror,
)


class _Scripted:
    """A detector that finds the person in the frames whose top-left pixel is not black."""

    def __init__(self):
        self.calls = 0

    def __call__(self, rgb):
        self.calls += 1
        if rgb[0, 0].max() == 0:
            return None
        h, w = rgb.shape[:2]
        mask = np.zeros((h, w), np.float32)
        mask[2:6, 3:5] = 1.0
        return FrameObservation(np.full((33, 2), 4.0), np.zeros((33, 3)), np.full(33, 0.9), mask, None)

    def close(self):
        pass


def test_landmark_names():
    assert len(LANDMARK_NAMES) == 33 and len(set(LANDMARK_NAMES)) == 33
    assert LANDMARK_NAMES[0] == "nose" and LANDMARK_NAMES[23] == "left_hip" and LANDMARK_NAMES[32] == "right_foot_index"


def test_observe_stacks_frames_and_marks_misses():
    frames = [np.full((8, 10, 3), v, np.uint8) for v in (9, 0, 9)]
    det = _Scripted()
    obs = observe(frames, det)
    assert det.calls == 3
    assert obs.found.tolist() == [True, False, True]
    assert (obs.width, obs.height) == (10, 8)
    assert np.isnan(obs.image_uv_px[1]).all() and (obs.visibility[1] == 0).all()
    assert obs.person_masks.shape == (3, 8, 10) and obs.person_masks[0].sum() == 8 and obs.person_masks[1].sum() == 0
    with pytest.raises(InputError, match="frame 1 is 4x8"):
        observe([frames[0], np.zeros((8, 4, 3), np.uint8)], _Scripted())
    with pytest.raises(InputError, match="no frames"):
        observe([], _Scripted())


class _Counting:
    """A detector whose look at a frame puts every landmark at (its call number, the frame's value)."""

    def __init__(self):
        self.calls = 0

    def __call__(self, rgb):
        self.calls += 1
        if rgb[0, 0, 0] == 0:
            return None
        uv = np.column_stack([np.full(33, float(self.calls)), np.full(33, float(rgb[0, 0, 0]))])
        uv[[11, 12, 23, 24], 1] += (0.0, 0.0, 20.0, 20.0)  # a torso 20 px long
        return FrameObservation(uv, np.zeros((33, 3)), np.full(33, 0.9), np.full(rgb.shape[:2], 0.5, np.float32))


def test_observe_backward_averages_a_second_run_from_the_last_frame():
    frames = [np.full((8, 10, 3), v, np.uint8) for v in (5, 6, 0, 7)]
    fwd, back = _Counting(), _Counting()
    obs = observe(iter(frames), fwd, backward=back)
    assert fwd.calls == back.calls == 4 and obs.found.tolist() == [True, True, False, True]
    # forward calls 1, 2, 4 and backward calls 4, 3, 1 saw frames 0, 1, 3: each frame's mean is 2.5
    np.testing.assert_allclose(obs.image_uv_px[[0, 1, 3], :, 0], 2.5)
    np.testing.assert_allclose(obs.image_uv_px[[0, 1, 3], 0, 1], [5.0, 6.0, 7.0])
    assert np.isnan(obs.image_uv_px[2]).all()
    alone = observe(frames, _Counting())
    np.testing.assert_allclose(alone.image_uv_px[[0, 1, 3], 0, 0], [1.0, 2.0, 4.0])


def test_other_people_counts_separate_blobs():
    person = np.zeros((100, 160), np.float32)
    person[20:90, 30:50] = 1.0
    people = person.copy()
    assert other_people(person, people) == 0
    assert other_people(person, None) == 0
    people[25:85, 110:128] = 0.9  # someone else, as big, far away
    assert other_people(person, people) == 1
    people[10:14, 150:154] = 1.0  # a speck: not a person
    assert other_people(person, people) == 1
    touching = person.copy()
    touching[20:90, 50:70] = 1.0  # the tracked person's own halo
    assert other_people(person, touching) == 0


def _look(seed: int, w: int = 40, h: int = 30) -> FrameObservation:
    """A random look at an (h, w) frame: landmarks near a torso 10 px long, a random mask and people mask."""
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(10, 30, 33), rng.uniform(5, 25, 33)])
    names = {n: LANDMARK_NAMES.index(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")}
    uv[[names["left_shoulder"], names["right_shoulder"]]] = ((16.0, 8.0), (24.0, 8.0))
    uv[[names["left_hip"], names["right_hip"]]] = ((17.0, 18.0), (23.0, 18.0))
    return FrameObservation(uv, rng.normal(size=(33, 3)), rng.uniform(size=33),
                            rng.uniform(size=(h, w)).astype(np.float32), rng.uniform(size=(h, w)).astype(np.float32))


def test_mirrored_landmarks_swap_sides():
    order = np.asarray(MIRRORED_LANDMARKS)
    np.testing.assert_array_equal(order[order], np.arange(33))  # its own inverse
    for a, b in (("nose", "nose"), ("left_wrist", "right_wrist"), ("right_eye_outer", "left_eye_outer"),
                 ("mouth_left", "mouth_right"), ("left_foot_index", "right_foot_index")):
        assert LANDMARK_NAMES[order[LANDMARK_NAMES.index(a)]] == b


def test_unmirror_takes_a_mirrored_look_back_to_the_frame():
    ob = _look(0)
    back = unmirror(ob, 40)
    i, j = LANDMARK_NAMES.index("left_wrist"), LANDMARK_NAMES.index("right_wrist")
    assert back.image_uv_px[i, 0] == 39 - ob.image_uv_px[j, 0] and back.image_uv_px[i, 1] == ob.image_uv_px[j, 1]
    np.testing.assert_array_equal(back.body_m[i], ob.body_m[j] * np.array([-1.0, 1.0, 1.0]))
    assert back.visibility[i] == ob.visibility[j]
    np.testing.assert_array_equal(back.person_mask, ob.person_mask[:, ::-1])
    np.testing.assert_array_equal(back.people_mask, ob.people_mask[:, ::-1])
    twice = unmirror(back, 40)
    for name in ("image_uv_px", "body_m", "visibility", "person_mask", "people_mask"):
        np.testing.assert_allclose(getattr(twice, name), getattr(ob, name), rtol=0, atol=1e-12)


def test_average_looks_means_two_looks_that_agree_and_keeps_the_direct_one_otherwise():
    a, b = _look(1), _look(2)
    b = FrameObservation(a.image_uv_px + 1.0, b.body_m, b.visibility, b.person_mask, b.people_mask)
    m = average_looks(a, b)
    np.testing.assert_allclose(m.image_uv_px, a.image_uv_px + 0.5)
    np.testing.assert_allclose(m.body_m, 0.5 * (a.body_m + b.body_m))
    np.testing.assert_allclose(m.visibility, 0.5 * (a.visibility + b.visibility))
    np.testing.assert_allclose(m.person_mask, 0.5 * (a.person_mask + b.person_mask), rtol=1e-6)
    assert m.person_mask.dtype == np.float32 and m.people_mask is a.people_mask
    assert average_looks(a, None) is a and average_looks(None, b) is b and average_looks(None, None) is None
    # 6 px apart on a 10 px torso (more than half of it): another person; the first look stays
    far = FrameObservation(a.image_uv_px + np.array([6.0, 0.0]), b.body_m, b.visibility, b.person_mask)
    assert average_looks(a, far) is a
    assert average_looks(a, far, max_disagreement=0.7) is not a


def test_without_mediapipe_one_line_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import fails as if not installed
    with pytest.raises(InputError, match=r"nsim\[people\]") as err:
        MediaPipePoseDetector()
    assert "\n" not in str(err.value)


def test_mediapipe_without_models_is_refused(monkeypatch):
    """mediapipe 1.x has no ``solutions`` (no bundled pose models): the same one-line hint."""
    import types

    monkeypatch.setitem(sys.modules, "mediapipe", types.SimpleNamespace(__version__="1.2.2"))
    with pytest.raises(InputError, match=r"1\.2\.2 ships no pose models.*nsim\[people\]"):
        MediaPipePoseDetector()


@pytest.mark.slow
def test_mediapipe_finds_the_test_actor(tmp_path):
    """With ``nsim[people]`` installed: MediaPipe finds the test room's actor (human proportions, a face),
    its mask overlaps the true one and its joints project near the true joints (skipped without it)."""
    pytest.importorskip("mediapipe")
    from nsim.human.data import HumanData
    from nsim.human.skeleton import JOINT_NAMES
    from nsim.synth.actor_capture import ActorCaptureConfig, render_actor_capture

    render_actor_capture(tmp_path / "cap", ActorCaptureConfig(n_frames=4, fps=10.0, width=480, height=360,
                                                              supersample=1, video=False), seed=0)
    hd = HumanData.load(tmp_path / "cap")
    images, masks, _ = hd.read_all()
    with MediaPipePoseDetector() as det:
        obs = observe(list(images), det)
    assert obs.found.all()
    pred = obs.person_masks >= 0.5
    iou = (pred & masks).sum(axis=(1, 2)) / (pred | masks).sum(axis=(1, 2))
    assert iou.mean() > 0.8, iou
    # shoulders and hips (always in view) within 12 px of the true joints
    w2c = np.linalg.inv(hd.cam_to_world())
    joints = hd.joint_transforms()[..., :3, 3]
    cam_pts = np.einsum("fij,fkj->fki", w2c[:, :3, :3], joints) + w2c[:, None, :3, 3]
    uv, _ = hd.camera().project(cam_pts)
    names = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
    err = np.linalg.norm(obs.image_uv_px[:, [LANDMARK_NAMES.index(n) for n in names]]
                         - uv[:, [JOINT_NAMES.index(n) for n in names]], axis=-1)
    assert np.median(err) < 12.0, err
    # MediaPipe's body coordinates are in the camera's axes, y down: the nose above the hips
    assert (obs.body_m[:, 0, 1] < obs.body_m[:, 23, 1]).all()


def _stick_figure(h: int = 60, w: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A person's probabilities: a body column (0.95) with a soft halo (0.6) around it, a skirt attached to it
    (0.8), a detached blob beside it (0.9); its landmarks down the body's axis. Returns (prob, uv, body)."""
    prob = np.zeros((h, w), np.float32)
    prob[8:52, 14:26] = 0.6  # halo
    body = np.zeros((h, w), bool)
    body[10:50, 16:24] = True
    prob[body] = 0.95
    prob[30:40, 12:16] = 0.8  # the skirt: attached on the left
    prob[5:15, 32:38] = 0.9  # background the detector took for the person
    uv = np.stack([np.full(33, 20.0), np.linspace(12.0, 48.0, 33)], -1)  # (u, v): the body's axis
    return prob, uv, body


def test_training_mask_drops_the_halo_and_detached_blobs_and_keeps_what_is_attached():
    prob, uv, body = _stick_figure()
    mask = person_training_mask(prob, uv)
    expected = body.copy()
    expected[30:40, 12:16] = True
    np.testing.assert_array_equal(mask, expected)
    # a lower threshold takes the halo too; no skeleton in the frame keeps every blob at the threshold
    assert person_training_mask(prob, uv, 0.5).sum() == (prob[:, :30] >= 0.5).sum()
    np.testing.assert_array_equal(person_training_mask(prob, np.full((33, 2), np.nan)), prob >= TRAINING_MASK_THRESHOLD)
    # a skeleton beside the body (on the blob) keeps the blob instead
    blob = person_training_mask(prob, np.stack([np.full(33, 35.0), np.linspace(6.0, 13.0, 33)], -1))
    np.testing.assert_array_equal(blob, (prob >= 0.7) & (np.arange(40) >= 30)[None, :])


def test_training_mask_refuses_bad_input():
    prob, uv, _ = _stick_figure()
    with pytest.raises(ValueError, match="expected an"):
        person_training_mask(prob[None], uv)
    with pytest.raises(ValueError, match="landmarks"):
        person_training_mask(prob, uv[:10])
    with pytest.raises(ValueError, match="threshold"):
        person_training_mask(prob, uv, 1.0)
    assert all(a in LANDMARK_NAMES and b in LANDMARK_NAMES for a, b in LANDMARK_BONES)


def test_a_segmented_blob_is_a_person_only_where_a_body_is_found_on_it():
    rgb = np.zeros((100, 120, 3), np.uint8)
    blob = np.zeros((100, 120), bool)
    blob[20:60, 40:60] = True  # 40 x 20: its crop grows by 10 px up and down, 5 px left and right
    crops = []

    def body_at(u, v, vis=0.9):
        def find(crop):
            crops.append(crop.shape[:2])
            return np.column_stack([np.full(33, u), np.full(33, v), np.full(33, vis)])
        return find

    assert confirmed_person(rgb, blob, body_at(10.0, 20.0))  # crop (x0, y0) = (35, 10): (45, 30) on the blob
    assert crops[-1] == (60, 30)
    assert not confirmed_person(rgb, blob, body_at(80.0, 20.0))  # beside it
    assert not confirmed_person(rgb, blob, body_at(10.0, 20.0, vis=0.2))  # not seen
    assert not confirmed_person(rgb, blob, lambda crop: None)  # no body at all
    assert not confirmed_person(rgb, np.zeros_like(blob), body_at(10.0, 20.0))


def test_other_people_blobs_are_what_other_people_counts():
    person = np.zeros((60, 80), np.float32)
    person[10:50, 5:15] = 1.0
    people = person.copy()
    people[10:50, 50:60] = 0.9  # someone else, as big
    people[5:8, 70:72] = 0.9  # too small to count
    blobs = other_people_blobs(person, people)
    assert len(blobs) == 1 == other_people(person, people) and blobs[0].sum() == 400 and blobs[0][30, 55]
    assert other_people_blobs(person, None) == []


@pytest.mark.slow
def test_mediapipe_confirms_a_second_actor_and_the_frame_still_tracks_the_first(tmp_path):
    """With ``nsim[people]``: a second copy of the test actor pasted into a frame counts as another person
    (BlazePose finds a body on the segmenter's blob); the frame as rendered shows nobody else."""
    pytest.importorskip("mediapipe")
    from nsim.human.data import HumanData
    from nsim.synth.actor_capture import ActorCaptureConfig, render_actor_capture

    render_actor_capture(tmp_path / "cap", ActorCaptureConfig(n_frames=2, fps=10.0, width=480, height=360,
                                                              supersample=1, video=False), seed=0)
    images, masks, _ = HumanData.load(tmp_path / "cap").read_all()
    one = images[0]
    ys, xs = np.nonzero(masks[0])
    shift = (20 - xs.min()) if xs.min() > 240 else (460 - xs.max())  # to the far side of the frame
    two = one.copy()
    two[ys, xs + shift] = one[ys, xs]
    with MediaPipePoseDetector() as det:
        alone = det(one)
    with MediaPipePoseDetector() as det:
        pair = det(two)
    assert other_people(alone.person_mask, alone.people_mask) == 0
    assert other_people(pair.person_mask, pair.people_mask) == 1


@pytest.mark.slow
def test_mediapipe_mirrored_look_agrees_with_the_direct_one(tmp_path):
    """With ``nsim[people]``: BlazePose on the mirrored frames, taken back by ``unmirror``, finds the test actor
    where it does on the frames themselves: the same side's landmarks in the same pixels and body coordinates
    (checks the pixel flip, the left/right swap and the body's x sign against the model)."""
    pytest.importorskip("mediapipe")
    from nsim.human.data import HumanData
    from nsim.synth.actor_capture import ActorCaptureConfig, render_actor_capture

    render_actor_capture(tmp_path / "cap", ActorCaptureConfig(n_frames=3, fps=10.0, width=320, height=240,
                                                              supersample=1, video=False), seed=0)
    images, _, _ = HumanData.load(tmp_path / "cap").read_all()
    with MediaPipePoseDetector(find_others=False, mirror=False) as det:
        direct = [det(im) for im in images]
    with MediaPipePoseDetector(find_others=False, mirror=False) as det:
        back = [unmirror(det(np.ascontiguousarray(im[:, ::-1])), 320) for im in images]
    torso = [LANDMARK_NAMES.index(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")]
    for d, b in zip(direct, back, strict=True):
        assert np.linalg.norm(d.image_uv_px[torso] - b.image_uv_px[torso], axis=-1).max() < 8.0
        # x (the side the body's left lies on) and y agree; depth z is where the two looks differ most (up to 15 cm)
        assert np.abs(d.body_m[torso, :2] - b.body_m[torso, :2]).max() < 0.06
        assert np.mean((d.person_mask >= 0.5) == (b.person_mask >= 0.5)) > 0.98
    with MediaPipePoseDetector(find_others=False) as det:  # the default: both looks, averaged
        both = det(images[0])
    assert np.linalg.norm(both.image_uv_px[torso] - direct[0].image_uv_px[torso], axis=-1).max() < 8.0


def test_track_outliers_finds_a_jump_and_not_a_fast_smooth_swing():
    """A wrist swinging 0.45 torso lengths a frame on a smooth path is on its track; two frames 1.2 torso lengths
    off are not; frames at a run's ends (and at a gap, which starts a new run) are never called outliers."""
    F = 20
    uv = np.zeros((F, 33, 2))
    i = {n: LANDMARK_NAMES.index(n) for n in ("left_hip", "right_hip", "left_shoulder", "right_shoulder", "left_wrist")}
    t = np.arange(F)
    walk = np.stack([100.0 + 12.0 * t, np.full(F, 200.0)], axis=1)  # the hips' midpoint moves 12 px a frame
    uv[:] = walk[:, None]
    uv[:, i["left_hip"], 0] -= 10
    uv[:, i["right_hip"], 0] += 10
    uv[:, i["left_shoulder"]] += (-12, -100)
    uv[:, i["right_shoulder"]] += (12, -100)  # torso: 100 px
    uv[:, i["left_wrist"], 0] += 80.0 * np.sin(2 * np.pi * t / 11.0)  # up to 46 px a frame
    uv[:, i["left_wrist"], 1] -= 10.0
    assert not track_outliers(uv).any()
    bad = uv.copy()
    bad[[8, 9], i["left_wrist"]] += (100.0, 60.0)
    out = track_outliers(bad)
    assert sorted(zip(*np.nonzero(out), strict=True)) == [(8, i["left_wrist"]), (9, i["left_wrist"])]
    # a frame with fewer than two frames on a side is not judged, nor does a jump there make its neighbours
    # outliers: with frame 9 left out, the jump at frame 8 ends a run
    frames = np.ones(F, bool)
    frames[9] = False
    assert not track_outliers(bad, frames).any()
    one = uv.copy()
    one[12, i["left_wrist"]] += (100.0, 60.0)
    assert np.flatnonzero(track_outliers(one, frames)[:, i["left_wrist"]]).tolist() == [12]
    assert not track_outliers(bad, max_torsos=2.0).any()
    # unseen landmarks (NaN) are never outliers, nor do they make their neighbours ones
    gap = bad.copy()
    gap[10:12, i["left_wrist"]] = np.nan
    assert not track_outliers(gap)[10:12].any()
    with pytest.raises(ValueError, match="uv_px"):
        track_outliers(np.zeros((5, 33)))
    with pytest.raises(ValueError, match="window"):
        track_outliers(uv, window=0)
