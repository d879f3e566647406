"""A person filmed by a static camera, as a detector would report it, fitted end to end (no MediaPipe):
the skeleton within 6 cm of the truth, the camera's height, frames without the person dropped and
reported, and each kind of bad input refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.geometry.transforms import look_at, umeyama
from nsim.human.bvh import read_bvh, write_bvh
from nsim.human.fit import mpjpe_m, reference_body
from nsim.human.gait import walk_cycle
from nsim.human.landmarks import LANDMARK_NAMES, Observations
from nsim.human.monocular import static_camera
from nsim.human.motion import LocomotionLoop
from nsim.human.person_video import CROWDED, NO_PERSON, PersonVideoConfig, fit_person
from nsim.human.skeleton import JOINT_NAMES, forward_kinematics

FPS = 15.0
HIPS = [LANDMARK_NAMES.index("left_hip"), LANDMARK_NAMES.index("right_hip")]


def _filmed(seconds: float = 2.4, noise_m: float = 0.01, seed: int = 0):
    """What a detector reports of the reference body walking past a camera 1.5 m up; and the GT joints."""
    rng = np.random.default_rng(seed)
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, fps=FPS))
    n = int(round(seconds * FPS))
    root, quats = loop.sample(np.arange(n) / FPS)
    root = root + (-1.5, 0.0, 0.0)
    body = reference_body(1.75)
    T = forward_kinematics(body.skeleton, quats, root)
    c2w = look_at((0.3, -4.0, 1.5), (0.0, 0.0, 0.9))
    w2c = np.linalg.inv(c2w)
    lm = body.landmarks(T) @ w2c[:3, :3].T + w2c[:3, 3]
    cam = static_camera(480, 360, 70.0)
    uv, _ = cam.project(lm)
    hips = lm[:, HIPS].mean(axis=1, keepdims=True)
    body_m = lm - hips + rng.normal(0.0, noise_m, lm.shape)
    uv = uv + rng.normal(0.0, 1.0, uv.shape)
    masks = np.zeros((n, 360, 480), np.float32)
    masks[:, 100:300, 200:260] = 0.95
    obs = Observations(np.ones(n, bool), uv, body_m, np.ones((n, 33)), masks, np.zeros(n, np.int64), 480, 360)
    return obs, T[..., :3, 3], c2w


def _replace(obs: Observations, **kw) -> Observations:
    d = {k: getattr(obs, k).copy() if isinstance(getattr(obs, k), np.ndarray) else getattr(obs, k)
         for k in ("found", "image_uv_px", "body_m", "visibility", "person_masks", "other_people", "width", "height")}
    d.update(kw)
    return Observations(**d)


def test_fit_person_recovers_skeleton_and_camera(tmp_path):
    obs, gt, c2w = _filmed()
    fit = fit_person(obs, FPS, PersonVideoConfig(hfov_deg=70.0))
    assert fit.frames.tolist() == list(range(obs.num_frames)) and fit.dropped == ()
    assert fit.camera_height_m == pytest.approx(1.5, abs=0.1)
    pa = mpjpe_m(fit.poses.joint_positions_m, gt, procrustes=True)
    assert pa.mean() <= 0.06, f"PA-MPJPE {pa.mean():.4f} m"
    # the world the fit is in is the true one up to a turn about z and a shift along the floor: heights agree
    z_err = np.abs(fit.poses.joint_positions_m[..., 2] - gt[..., 2]).mean()
    assert z_err < 0.08, f"joint heights off by {z_err:.3f} m on average"
    assert fit.poses.body.height_m == pytest.approx(1.75, abs=0.05)
    assert fit.masks.shape == (obs.num_frames, 360, 480) and fit.masks.dtype == bool
    # the training masks: the person's pixels at the threshold, in the blob its skeleton crosses
    assert fit.masks[:, 100:300, 200:260].all() and fit.masks.sum() == obs.num_frames * 200 * 60
    halo = _replace(obs, person_masks=np.where(obs.person_masks > 0, obs.person_masks, 0.6).astype(np.float32))
    assert (fit_person(halo, FPS, PersonVideoConfig(hfov_deg=70.0)).masks == fit.masks).all()  # 0.6: below 0.7
    with pytest.raises(ValueError, match="mask_threshold"):
        PersonVideoConfig(mask_threshold=1.0)
    # the poses in the human data format, and the walk as a BVH the reader takes back
    poses = fit.human_poses()
    np.testing.assert_allclose(poses.joint_positions_m(), fit.poses.joint_positions_m, atol=1e-9)
    clip = fit.motion_clip()
    assert clip.num_frames == obs.num_frames and clip.fps == FPS
    back = read_bvh(write_bvh(tmp_path / "person.bvh", clip))  # joints in the file's (depth-first) order
    order = [back.joint_names.index(n) for n in clip.joint_names]
    np.testing.assert_allclose(back.joint_positions()[:, order], clip.joint_positions(), atol=1e-4)


def test_frames_without_the_person_are_dropped_and_reported():
    obs, gt, _ = _filmed(seconds=3.0)
    found = obs.found.copy()
    found[10:16] = False
    body_m = obs.body_m.copy()
    body_m[10:16] = np.nan
    others = obs.other_people.copy()
    others[30] = 1
    fit = fit_person(_replace(obs, found=found, body_m=body_m, other_people=others), FPS)
    assert [(d.first, d.last, d.reason) for d in fit.dropped] == [(10, 15, NO_PERSON), (30, 30, CROWDED)]
    assert 10 not in fit.frames and 30 not in fit.frames and fit.frames.size == obs.num_frames - 7
    assert "frames 10-15 (0.7-1.1 s, 6 frames): no person" == fit.dropped[0].describe(FPS)
    # the motion clip is the longest unbroken stretch
    assert fit.motion_clip().num_frames == 14  # frames 16-29 (or 31-44)


@pytest.mark.parametrize("case, message", [
    ("short", r"1\.0 s \(15 frames at 15 fps\) is too short"),
    ("nobody", "no person found in any of its 36 frames"),
    ("crowd", "more than one person in 12 of 36 frames"),
    ("leaves", r"in view for only 1\.3 s of 2\.4 s"),
])
def test_bad_videos_are_refused_in_one_line(case, message):
    obs, _, _ = _filmed()
    if case == "short":
        obs = _replace(obs, found=obs.found[:15], image_uv_px=obs.image_uv_px[:15], body_m=obs.body_m[:15],
                       visibility=obs.visibility[:15], person_masks=obs.person_masks[:15],
                       other_people=obs.other_people[:15])
    elif case == "nobody":
        obs = _replace(obs, found=np.zeros(obs.num_frames, bool))
    elif case == "crowd":
        others = obs.other_people.copy()
        others[:12] = 1
        obs = _replace(obs, other_people=others)
    else:
        found = obs.found.copy()
        found[5:22] = False
        obs = _replace(obs, found=found)
    with pytest.raises(InputError, match=message) as err:
        fit_person(obs, FPS, source="walk.mp4")
    assert str(err.value).startswith("walk.mp4: ") and "\n" not in str(err.value)


def test_a_wrist_off_its_track_is_left_out_of_the_fit():
    """A detector that puts the far wrist and hand half a metre off in two frames in a row (an arm hidden behind
    the body): those landmarks, and only those, are left out, and the wrist there comes out closer to the truth."""
    obs, gt, _ = _filmed()
    clean = fit_person(obs, FPS, PersonVideoConfig(hfov_deg=70.0))
    assert clean.track_outliers == ()
    hand = [LANDMARK_NAMES.index(n) for n in ("right_wrist", "right_pinky", "right_index", "right_thumb")]
    bad_frames = [14, 15]
    uv, body = obs.image_uv_px.copy(), obs.body_m.copy()
    for f in bad_frames:
        uv[f, hand] += (90.0, 70.0)
        body[f, hand] += (0.45, 0.35, 0.2)
    corrupt = _replace(obs, image_uv_px=uv, body_m=body)
    kept = fit_person(corrupt, FPS, PersonVideoConfig(hfov_deg=70.0, track_outlier_torsos=None))
    cut = fit_person(corrupt, FPS, PersonVideoConfig(hfov_deg=70.0))
    assert kept.track_outliers == ()
    assert sorted(cut.track_outliers) == sorted((f, LANDMARK_NAMES[k]) for f in bad_frames for k in hand)
    wrist = JOINT_NAMES.index("right_wrist")

    def wrist_error(fit) -> float:  # after each frame's Procrustes alignment (the fit's world is turned and shifted)
        out = []
        for f in bad_frames:
            s, R, t = umeyama(fit.poses.joint_positions_m[f], gt[f], with_scale=True)
            out.append(np.linalg.norm(s * R @ fit.poses.joint_positions_m[f, wrist] + t - gt[f, wrist]))
        return max(out)

    err = {name: wrist_error(f) for name, f in (("kept", kept), ("cut", cut), ("clean", clean))}
    assert err["cut"] < 0.5 * err["kept"], err
    assert err["cut"] < err["clean"] + 0.08, err
    with pytest.raises(ValueError, match="track_outlier_torsos"):
        PersonVideoConfig(track_outlier_torsos=0.0)
