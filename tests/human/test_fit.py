"""Skeleton fitting: landmarks synthesised from known poses of nsim's own motion (with noise) are fitted
back onto the nsim body; the fit must recover the joints (MPJPE after Procrustes <= 6 cm) with bone
lengths fixed across frames and joint limits kept."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.human.fit import (
    BONE_GROUPS,
    JOINT_LIMITS_RAD,
    FitConfig,
    IKProblem,
    ImageLandmarks,
    bone_lengths_m,
    estimate_body,
    fit_poses,
    mpjpe_m,
    reference_body,
    scaled_body,
)
from nsim.human.gait import idle_cycle, turn, walk_cycle
from nsim.human.landmarks import LANDMARK_NAMES
from nsim.human.motion import LocomotionLoop
from nsim.human.skeleton import JOINT_NAMES, forward_kinematics

# a person unlike the reference body: longer thighs, shorter forearms, broader shoulders, smaller head
PERSON = {"thigh": 1.06, "shin": 0.97, "forearm": 0.93, "upper_arm": 1.02, "shoulder_width": 1.08,
          "hip_width": 0.95, "torso": 1.03, "head": 0.95, "foot": 1.0, "hand": 1.0}


def _walk(seconds: float, fps: float, speed: float = 1.3) -> tuple[np.ndarray, np.ndarray]:
    """Root positions (F, 3) and local rotations (F, J, 4) of a walk lasting ``seconds``."""
    loop = LocomotionLoop.from_clip(walk_cycle(speed, fps=fps))
    return loop.sample(np.arange(int(round(seconds * fps))) / fps)


def _camera_pose(seed: int = 0) -> np.ndarray:
    """A rigid transform (4, 4) to an arbitrary frame (the fit must not depend on the frame)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = (0.4, -1.1, 3.5)
    return T


def _synthesise(body, root, quats, noise_m: float, occluded: float, seed: int):
    """GT joints (F, J, 3) and noisy landmarks (F, L, 3) + visibility (F, L) in an arbitrary frame."""
    rng = np.random.default_rng(seed)
    T = _camera_pose(seed) @ forward_kinematics(body.skeleton, quats, root)
    lm = body.landmarks(T) + rng.normal(0.0, noise_m, (T.shape[0], len(LANDMARK_NAMES), 3))
    vis = np.where(rng.random(lm.shape[:2]) < occluded, 0.0, 1.0)
    lm[vis == 0] = np.nan
    return T[..., :3, 3], lm, vis


def test_nsim_motion_within_joint_limits():
    """Every local rotation of nsim's own walks, idle and turn lies inside the fit's joint limits."""
    clips = [walk_cycle(v) for v in (0.8, 1.3, 1.8)] + [idle_cycle(), turn(1.0, 45.0, 2.0)]
    lo, hi = JOINT_LIMITS_RAD[1:, :, 0], JOINT_LIMITS_RAD[1:, :, 1]
    for clip in clips:
        rv = Rotation.from_quat(clip.local_rotations_wxyz[:, 1:].reshape(-1, 4)[:, [1, 2, 3, 0]]).as_rotvec()
        rv = rv.reshape(clip.num_frames, -1, 3)
        outside = (rv < lo) | (rv > hi)
        where = [JOINT_NAMES[1 + j] for j in np.unique(np.nonzero(outside)[1])]
        assert not outside.any(), f"{clip.name}: outside the limits at {where}"


def test_reference_body_landmarks_are_the_joints_where_attached():
    body = reference_body(1.75)
    rest = body.rest_landmarks()
    joints = body.skeleton.rest_positions_m()
    for name in ("left_shoulder", "right_elbow", "left_wrist", "right_hip", "left_knee", "right_ankle"):
        np.testing.assert_allclose(rest[LANDMARK_NAMES.index(name)], joints[JOINT_NAMES.index(name)], atol=1e-12)
    # heels and toe tips sit on the soles (3 cm at 1.75 m); the nose is the highest face point in front
    for name in ("left_heel", "right_foot_index"):
        assert rest[LANDMARK_NAMES.index(name), 2] == pytest.approx(0.03, abs=1e-9)
    assert rest[LANDMARK_NAMES.index("nose"), 0] > 0.1


def test_estimate_body_recovers_bone_lengths():
    """Bone lengths from noisy landmarks over frames: within 1 cm of the person's, every group."""
    truth = scaled_body(PERSON)
    root, quats = _walk(1.2, 30.0)
    _, lm, vis = _synthesise(truth, root, quats, noise_m=0.01, occluded=0.05, seed=1)
    est = estimate_body(lm, vis)
    true_len = np.linalg.norm(truth.skeleton.offsets_m[1:], axis=1)
    est_len = np.linalg.norm(est.skeleton.offsets_m[1:], axis=1)
    err = np.abs(est_len - true_len)
    assert err.max() < 0.01, f"worst bone {JOINT_NAMES[1 + int(err.argmax())]}: {err.max():.4f} m"
    assert est.height_m == pytest.approx(truth.height_m, abs=0.02)
    assert set(BONE_GROUPS) == set(PERSON)


def test_fit_recovers_joints_with_fixed_bones_and_limits():
    """The issue's check: MPJPE after Procrustes <= 6 cm on a noisy walk; bone lengths constant."""
    truth = scaled_body(PERSON)
    root, quats = _walk(1.0, 30.0)
    gt, lm, vis = _synthesise(truth, root, quats, noise_m=0.01, occluded=0.05, seed=2)
    body = estimate_body(lm, vis)
    fit = fit_poses(lm, body, vis)
    pa = mpjpe_m(fit.joint_positions_m, gt, procrustes=True)
    raw = mpjpe_m(fit.joint_positions_m, gt, procrustes=False)
    assert pa.mean() <= 0.06 and raw.mean() <= 0.06, (pa.mean(), raw.mean())
    assert pa.mean() <= 0.03, f"PA-MPJPE {pa.mean():.4f} m"  # what this fit achieves (about 1.5-2 cm)
    lengths = bone_lengths_m(body.skeleton, fit.joint_positions_m)  # (F, J - 1)
    assert np.ptp(lengths, axis=0).max() < 1e-9
    np.testing.assert_allclose(lengths[0], np.linalg.norm(body.skeleton.offsets_m[1:], axis=1), atol=1e-9)
    rv = Rotation.from_quat(fit.local_rotations_wxyz[:, 1:].reshape(-1, 4)[:, [1, 2, 3, 0]]).as_rotvec()
    rv = rv.reshape(fit.local_rotations_wxyz.shape[0], -1, 3)
    assert np.all(rv >= JOINT_LIMITS_RAD[1:, :, 0] - 1e-6) and np.all(rv <= JOINT_LIMITS_RAD[1:, :, 1] + 1e-6)
    # residuals: the landmarks the fit explains lie within a few noise sigmas
    assert np.nanmedian(fit.landmark_error_m) < 0.03
    assert np.isnan(fit.landmark_error_m[vis == 0]).all()


def test_smoothness_reduces_jitter():
    """With the smoothness term the fitted joints accelerate less than without, and are no less accurate."""
    truth = reference_body(1.75)
    root, quats = _walk(0.7, 30.0)
    gt, lm, vis = _synthesise(truth, root, quats, noise_m=0.02, occluded=0.0, seed=3)
    body = estimate_body(lm, vis)
    rough = fit_poses(lm, body, vis, cfg=FitConfig(smooth_weight=0.0))
    smooth = fit_poses(lm, body, vis, cfg=FitConfig(smooth_weight=1.0))

    def jitter(p):
        return np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1).mean()

    assert jitter(smooth.joint_positions_m) < 0.7 * jitter(rough.joint_positions_m)
    assert mpjpe_m(smooth.joint_positions_m, gt).mean() <= mpjpe_m(rough.joint_positions_m, gt).mean() + 0.002


def test_smoothness_does_not_link_a_gap():
    """Frames that do not follow each other (frame_index jumps) are not pulled together."""
    truth = reference_body(1.75)
    root, quats = _walk(0.5, 30.0)
    gt, lm, vis = _synthesise(truth, root, quats, noise_m=0.0, occluded=0.0, seed=4)
    F = lm.shape[0]
    # the second half is moved 1 m away: with the gap declared, the fit follows it
    lm[F // 2:] += (1.0, 0.0, 0.0)
    gt[F // 2:] += (1.0, 0.0, 0.0)
    index = np.r_[np.arange(F // 2), np.arange(F // 2, F) + 100]
    fit = fit_poses(lm, estimate_body(lm, vis), vis, frame_index=index, cfg=FitConfig(smooth_weight=2.0))
    assert mpjpe_m(fit.joint_positions_m, gt, procrustes=False).max() < 0.02


@pytest.mark.parametrize("with_image", [False, True])
def test_ik_jacobian_matches_finite_differences(with_image):
    """The closed-form Jacobian against central differences of the residuals, at a random pose."""
    body = scaled_body(PERSON)
    rng = np.random.default_rng(5)
    F, J = 4, len(JOINT_NAMES)
    lm = rng.normal(size=(F, len(LANDMARK_NAMES), 3))
    sqrt_w = rng.uniform(0.0, 1.0, lm.shape[:2])
    image = None
    if with_image:
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.random(random_state=3).as_matrix()
        w2c[:3, 3] = (0.2, -0.1, 12.0)
        uv = rng.uniform(0, 400, lm.shape[:2] + (2,))
        uv[0, 3] = np.nan  # unseen in the image
        image = ImageLandmarks(uv, w2c, 500.0, 480.0, 200.0, 150.0, sigma_px=3.0)
    problem = IKProblem(body, lm, sqrt_w, np.array([[0, 1, 2], [1, 2, 3]]), smooth=0.7, rest_weight=0.05,
                        image=image, sqrt_weights_3d=0.5 * sqrt_w)
    x = np.concatenate([rng.normal(size=(F, 3)), rng.uniform(-1.2, 1.2, (F, 3 * J))], axis=1).reshape(-1)
    x[3 + 3 * 5:6 + 3 * 5] = (1e-6, 0.0, 0.0)  # one rotation near zero (the small-angle branch)
    jac = problem.jacobian(x).toarray()
    eps = 1e-6
    fd = np.empty_like(jac)
    for c in range(x.size):
        d = np.zeros_like(x)
        d[c] = eps
        fd[:, c] = (problem.residuals(x + d) - problem.residuals(x - d)) / (2 * eps)
    np.testing.assert_allclose(jac, fd, atol=2e-6 * (1 + 100 * with_image), rtol=1e-6)
    assert np.count_nonzero(jac) > 0.5 * np.count_nonzero(np.abs(fd) > 1e-9)
    # what the solver uses: the exact gradient and the frames' diagonal blocks of J^T J
    r = problem.residuals(x)
    g, blocks = problem.normal_blocks(x, r)
    np.testing.assert_allclose(g, jac.T @ r, atol=1e-9, rtol=1e-9)
    full = jac.T @ jac
    P = problem.P
    for f in range(F):
        np.testing.assert_allclose(blocks[f], full[f * P:(f + 1) * P, f * P:(f + 1) * P], atol=1e-9, rtol=1e-9)


def test_mpjpe_procrustes_ignores_similarity():
    rng = np.random.default_rng(0)
    true = rng.normal(size=(3, 24, 3))
    R = Rotation.random(random_state=1).as_matrix()
    moved = 1.3 * true @ R.T + (1.0, 2.0, 3.0)
    np.testing.assert_allclose(mpjpe_m(moved, true, procrustes=True), 0.0, atol=1e-9)
    assert mpjpe_m(moved, true, procrustes=False).min() > 1.0
    shifted = true.copy()
    shifted[:, 0] += (0.0, 0.0, 0.24)  # one joint of 24 off by 24 cm: 1 cm mean
    np.testing.assert_allclose(mpjpe_m(shifted, true, procrustes=False), 0.01, atol=1e-12)


def test_hidden_but_placed_landmarks_still_guide_the_fit():
    """MediaPipe places a landmark it calls hidden (visibility 0.1-0.3) close to right: the default
    ``min_visibility`` (0.1) fits it at its small weight; at 0.3 the left arm is left to the priors."""
    truth = scaled_body(PERSON)
    root, quats = _walk(0.6, 30.0)
    gt, lm, vis = _synthesise(truth, root, quats, noise_m=0.01, occluded=0.0, seed=4)
    arm = [LANDMARK_NAMES.index(n) for n in ("left_elbow", "left_wrist", "left_pinky", "left_index", "left_thumb")]
    vis[:, arm] = 0.2
    body = estimate_body(lm, vis)
    wrist = JOINT_NAMES.index("left_wrist")
    errs = {}
    for mv in (FitConfig().min_visibility, 0.3):
        fit = fit_poses(lm, body, vis, cfg=FitConfig(min_visibility=mv))
        s_err = [np.linalg.norm(fit.joint_positions_m[f] - gt[f], axis=-1) for f in range(len(gt))]
        errs[mv] = float(np.mean([e[wrist] for e in s_err]))
    assert FitConfig().min_visibility == 0.1
    assert errs[0.1] < 0.03 and errs[0.3] > 2 * errs[0.1], errs
