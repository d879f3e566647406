"""A person filmed by a moving camera: the camera's motion is told from the background or from the person
walking on the spot in the image, the person is placed in SfM's camera path in metres (scale from SfM's
floor, from the root's smoothness, or from the person's steps), and fitted end to end (no MediaPipe; SfM's
answer is the true path in another frame and scale, except in the end-to-end test on a rendered
following-camera capture, which runs SfM)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.geometry.transforms import look_at
from nsim.human.fit import mpjpe_m, reference_body
from nsim.human.gait import cadence_steps_per_min, idle_cycle, walk_cycle
from nsim.human.landmarks import LANDMARK_NAMES, Observations
from nsim.human.monocular import static_camera
from nsim.human.motion import LocomotionLoop
from nsim.human.moving_camera import (
    FOLLOWED_MAX_ADVANCE_M,
    KEYFRAME_FPS,
    KEYFRAMES_ALL_UP_TO,
    MAX_INTERPOLATION_GAP_S,
    MAX_PATH_SCALE_ERROR,
    CameraPath,
    background_motion_px,
    camera_moves,
    camera_path,
    count_steps,
    decide_camera,
    interpolate_path,
    keyframes,
    metric_scale,
    metric_scale_error,
    place_landmarks_moving,
    register_frames,
    rotation_between,
    rotation_path,
    speed_from_cadence,
    walking_speed_mps,
)
from nsim.human.person_video import PersonVideoConfig, fit_person
from nsim.human.skeleton import forward_kinematics

FPS = 15.0
HIPS = [LANDMARK_NAMES.index("left_hip"), LANDMARK_NAMES.index("right_hip")]
SFM_SCALE = 0.37  # SfM units per metre in the made-up reconstruction


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _followed(seconds: float = 2.4, seed: int = 0):
    """The reference body walking, filmed by a camera 1.5 m up that follows it on a curve; what a detector
    reports, SfM's path (the true one under a similarity) and its floor points; the true joints and cameras."""
    rng = np.random.default_rng(seed)
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, fps=FPS))
    n = int(round(seconds * FPS))
    time = np.arange(n) / FPS
    root, quats = loop.sample(time)
    root = root + (-1.5, 0.0, 0.0)
    body = reference_body(1.75)
    T = forward_kinematics(body.skeleton, quats, root)
    lm_world = body.landmarks(T)
    cam = static_camera(480, 360, 70.0)
    c2w = np.stack([look_at((root[f, 0] - 1.0 + 0.6 * np.sin(1.3 * time[f]), -3.5 + 0.4 * time[f] ** 2, 1.5),
                            (root[f, 0], root[f, 1], 0.9)) for f in range(n)])
    w2c = np.linalg.inv(c2w)
    lm = np.einsum("fij,flj->fli", w2c[:, :3, :3], lm_world) + w2c[:, None, :3, 3]
    uv, _ = cam.project(lm)
    hips = lm[:, HIPS].mean(axis=1, keepdims=True)
    body_m = lm - hips + rng.normal(0.0, 0.01, lm.shape)
    uv = uv + rng.normal(0.0, 1.0, uv.shape)
    masks = np.zeros((n, 360, 480), np.float32)
    obs = Observations(np.ones(n, bool), uv, body_m, np.ones((n, 33)), masks, np.zeros(n, np.int64), 480, 360)
    # SfM's world: the true one turned, shifted and scaled
    R, t = _rotation(rng), rng.normal(size=3)
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = SFM_SCALE * R, t
    sfm = np.einsum("ij,fjk->fik", S, c2w)
    sfm[:, :3, :3] /= SFM_SCALE
    floor = np.concatenate([rng.uniform(-4, 4, (400, 2)), np.zeros((400, 1))], axis=1)
    walls = np.concatenate([rng.uniform(-4, 4, (200, 1)), np.full((200, 1), 4.0), rng.uniform(0, 2.5, (200, 1))], 1)
    pts = np.concatenate([floor, walls]) @ S[:3, :3].T + S[:3, 3]
    return obs, T[..., :3, 3], c2w, CameraPath(sfm, cam, pts)


def test_background_motion_tells_a_moving_camera_from_a_static_one():
    rng = np.random.default_rng(1)
    room = (rng.uniform(0, 255, (60, 80)).repeat(8, 0).repeat(8, 1)).astype(np.uint8)  # blocky texture
    room = np.stack([room] * 3, axis=-1)
    masks = np.zeros((4, 360, 480), bool)
    masks[:, 100:300, 200:260] = True  # the person: left out
    static = [np.clip(room[:360, :480].astype(int) + rng.integers(-2, 3, (360, 480, 3)), 0, 255).astype(np.uint8)
              for _ in range(4)]
    moving = [room[3 * i:3 * i + 360, 5 * i:5 * i + 480].copy() for i in range(4)]  # 5.8 px a frame
    for frames in (static, moving):  # a "person" that moves on its own must not count
        for i, f in enumerate(frames):
            f[100:300, 200:260] = 40 * i
    m_static, m_moving = background_motion_px(static, masks), background_motion_px(moving, masks)
    assert np.nanmax(m_static) < 0.5 and np.allclose(m_moving, np.hypot(3, 5), atol=0.3)
    assert not camera_moves(m_static, 480) and camera_moves(m_moving, 480)
    assert not camera_moves(np.full(3, np.nan), 480)
    noise = [rng.integers(60, 200, (360, 480, 3), dtype=np.uint8) for _ in range(3)]  # nothing shared: no evidence
    assert np.isnan(background_motion_px(noise, masks[:3])).all()


def test_metric_scale_is_where_the_root_walks_straightest():
    rng = np.random.default_rng(2)
    n = 40
    time = np.arange(n) / 10.0
    root = np.stack([1.2 * time, 0.05 * np.sin(8 * time), 0.9 + 0.02 * np.sin(16 * time)], axis=1)
    centres = np.stack([1.2 * time - 1.0 + 0.5 * np.sin(2 * time), -3.0 + 0.3 * time ** 2, 1.5 + 0 * time], axis=1)
    rots = np.stack([_rotation(rng) for _ in range(n)])  # camera-to-world rotations
    root_cam = np.einsum("fji,fj->fi", rots, root - centres)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    c2w[:, :3, :3], c2w[:, :3, 3] = rots, centres / 2.5  # SfM units: 2.5 m each
    assert metric_scale(root_cam, c2w) == pytest.approx(2.5, rel=0.05)
    assert metric_scale(root_cam, c2w, times=time) == pytest.approx(2.5, rel=0.05)
    c2w[:, :3, 3] = np.linspace(0, 1, n)[:, None] * (1.0, 0.0, 0.0)  # constant velocity: cannot tell
    assert np.isnan(metric_scale(root_cam, c2w))


@pytest.mark.parametrize("with_floor", [True, False])
def test_person_placed_in_metres_in_the_moving_cameras_path(with_floor):
    obs, gt, c2w, path = _followed()
    points = path.points_xyz if with_floor else None
    placed = place_landmarks_moving(obs.body_m, obs.image_uv_px, obs.visibility, path.camera, path.cam_to_world,
                                    points)
    # metres per SfM unit, the cameras' height and the whole path's shape (up to a turn about z and a shift)
    assert placed.scale == pytest.approx(1 / SFM_SCALE, rel=0.08)
    assert placed.camera_height_m == pytest.approx(1.5, abs=0.12)
    got, true = placed.cam_to_world[:, :3, 3], c2w[:, :3, 3]
    d_got, d_true = got - got.mean(0), true - true.mean(0)
    assert np.linalg.norm(d_got, axis=1) == pytest.approx(np.linalg.norm(d_true, axis=1), abs=0.1)
    # the cameras' heights and the landmarks' heights are those of the true world
    assert np.abs(got[:, 2] - true[:, 2]).max() < 0.12
    up_true = np.einsum("fi,fi->f", c2w[:, :3, 1], np.broadcast_to((0, 0, 1.0), (len(c2w), 3)))
    np.testing.assert_allclose(placed.cam_to_world[:, 2, 1], up_true, atol=0.05)
    # a known camera height rescales everything to it
    fixed = place_landmarks_moving(obs.body_m, obs.image_uv_px, obs.visibility, path.camera, path.cam_to_world,
                                   points, camera_height_m=1.8)
    assert fixed.camera_height_m == pytest.approx(1.8) and fixed.scale == pytest.approx(placed.scale * 1.8
                                                                                        / placed.camera_height_m)


def test_fit_person_with_a_moving_camera():
    obs, gt, c2w, path = _followed()
    static = fit_person(obs, FPS, PersonVideoConfig(hfov_deg=70.0))  # a static camera's assumption: wrong here
    fit = fit_person(obs, FPS, PersonVideoConfig(hfov_deg=70.0, camera="moving"), camera_path=path)
    assert fit.cam_to_world.shape == (obs.num_frames, 4, 4)
    pa = mpjpe_m(fit.poses.joint_positions_m, gt).mean()
    assert pa <= 0.06, f"PA-MPJPE {pa:.4f} m"
    assert fit.poses.body.height_m == pytest.approx(1.75, abs=0.05)
    # the root's path in the world: true up to a turn about z and a shift along the floor
    def shape(p):
        return np.linalg.norm(p[:, :2] - p[:, :2].mean(0), axis=1)

    root_true, root_fit = gt[:, 0], fit.poses.joint_positions_m[:, 0]
    err = np.abs(shape(root_fit) - shape(root_true)).max()
    err_static = np.abs(shape(static.poses.joint_positions_m[:, 0]) - shape(root_true)).max()
    assert err < 0.1 and err_static > 3 * err, (err, err_static)
    np.testing.assert_allclose(root_fit[:, 2], root_true[:, 2], atol=0.06)
    # the camera of each frame in the human data format
    poses = fit.human_poses()
    assert poses.root_to_world.shape[0] == obs.num_frames


def test_camera_mode_is_checked():
    assert PersonVideoConfig(camera="static").camera == "static"
    with pytest.raises(ValueError, match="camera"):
        PersonVideoConfig(camera="handheld")


def _filmed(seconds: float, camera: str, speed: float = 1.3, seed: int = 3):
    """The reference body walking along +x at ``speed``, filmed by a camera 1.5 m up that stands still 4.5 m to the
    side ("static") or keeps 4 m behind it on a straight line ("following"); what a detector reports, the true
    cameras, joints and root path."""
    rng = np.random.default_rng(seed)
    loop = LocomotionLoop.from_clip(walk_cycle(speed, fps=FPS))
    n = int(round(seconds * FPS))
    root, quats = loop.sample(np.arange(n) / FPS)
    root = root + (-1.5, 0.0, 0.0)
    body = reference_body(1.75)
    T = forward_kinematics(body.skeleton, quats, root)
    lm_world = body.landmarks(T)
    if camera == "static":
        c2w = np.stack([look_at((0.3, -4.5, 1.5), (0.0, 0.0, 0.9))] * n)
    else:
        c2w = np.stack([look_at((r[0] - 4.0, 0.0, 1.5), (r[0], 0.0, 0.9)) for r in root])
    w2c = np.linalg.inv(c2w)
    lm = np.einsum("fij,flj->fli", w2c[:, :3, :3], lm_world) + w2c[:, None, :3, 3]
    cam = static_camera(480, 360, 70.0)
    uv = cam.project(lm)[0] + rng.normal(0.0, 1.0, (n, 33, 2))
    body_m = lm - lm[:, HIPS].mean(axis=1, keepdims=True) + rng.normal(0.0, 0.01, lm.shape)
    return body_m, uv, np.ones((n, 33)), cam, c2w, T[..., :3, 3], root


def test_steps_are_counted_in_a_walk_and_not_in_a_stand():
    for speed in (0.9, 1.3, 1.7):
        body_m = _filmed(4.0, "static", speed)[0]
        steps = count_steps(body_m, FPS)
        assert steps.walks and steps.count >= 6, steps
        assert steps.cadence_steps_s == pytest.approx(cadence_steps_per_min(speed) / 60.0, rel=0.08)
    idle = LocomotionLoop.from_clip(idle_cycle())
    root, quats = idle.sample(np.arange(60) / FPS)
    body = reference_body(1.75)
    lm = body.landmarks(forward_kinematics(body.skeleton, quats, root))
    standing = count_steps(lm - lm[:, HIPS].mean(axis=1, keepdims=True), FPS)
    assert not standing.walks, standing
    assert count_steps(np.full((10, 33, 3), np.nan), FPS).count == 0


def test_speed_from_cadence_inverts_nsims_stride():
    for speed, height in ((0.8, 1.6), (1.3, 1.75), (1.8, 1.9)):
        assert speed_from_cadence(cadence_steps_per_min(speed, height) / 60.0, height) == pytest.approx(speed)


def test_a_camera_that_follows_a_walker_is_told_moving_by_the_person():
    # a far background that hardly moves in the image: only the person tells the camera follows
    quiet = np.full(59, 0.6)
    body_m, uv, vis, cam, *_ = _filmed(4.0, "following")
    d = decide_camera(quiet, 480, body_m, uv, vis, cam, FPS)
    assert d.moving and d.by == "person" and d.advance_per_step_m < FOLLOWED_MAX_ADVANCE_M, d.describe()
    assert d.to_dict()["background_px"] == pytest.approx(0.6) and d.to_dict()["steps"] == d.steps.count
    assert "the camera follows the person" in d.describe() and "0.60 px" in d.describe()
    # a static camera watching the walk go by: the person advances a step's length per step
    body_m, uv, vis, cam, *_ = _filmed(4.0, "static")
    d = decide_camera(np.full(59, 0.05), 480, body_m, uv, vis, cam, FPS)
    assert not d.moving and d.by == "neither" and d.advance_per_step_m > 2 * FOLLOWED_MAX_ADVANCE_M, d.describe()
    # the background alone says so when it moves; the option overrides either
    assert decide_camera(np.full(59, 9.0), 480, body_m, uv, vis, cam, FPS).by == "background"
    forced = decide_camera(None, 480, body_m, uv, vis, cam, FPS, mode="moving")
    assert forced.moving and forced.by == "option" and forced.to_dict()["background_px"] is None


def test_keyframes_and_the_poses_between_them():
    keys = keyframes(61, 16.0)
    assert keys[0] == 0 and keys[-1] == 60 and set(np.diff(keys)) == {round(16.0 / KEYFRAME_FPS)}
    fast = keyframes(61, 16.0, motion_px=np.full(60, 10.0), width=400)  # 20 px (5 % of 400) every other frame
    assert set(np.diff(fast)) == {2}
    assert (keyframes(KEYFRAMES_ALL_UP_TO, 16.0) == np.arange(KEYFRAMES_ALL_UP_TO)).all()  # a short clip: all
    keys = keys[:8]
    rng = np.random.default_rng(4)
    key_c2w = np.stack([look_at(rng.normal(size=3) + (0.0, -5.0, 0.0), (0.0, 0.0, 0.0)) for _ in keys])
    key_c2w[2] = np.nan  # not registered: its neighbours (8 frames = 0.5 s apart) are interpolated across
    c2w = interpolate_path(keys, key_c2w, 29, 16.0)
    np.testing.assert_allclose(c2w[keys[[0, 1, 3]]], key_c2w[[0, 1, 3]], atol=1e-9)
    mid = (keys[1] + keys[3]) // 2
    np.testing.assert_allclose(c2w[mid, :3, 3], 0.5 * (key_c2w[1, :3, 3] + key_c2w[3, :3, 3]), atol=1e-9)
    assert np.isfinite(c2w).all()
    key_c2w[1:5] = np.nan  # a gap longer than MAX_INTERPOLATION_GAP_S: its frames are not placed
    assert (keys[5] - keys[0]) / 16.0 > MAX_INTERPOLATION_GAP_S
    c2w = interpolate_path(keys, key_c2w, 29, 16.0)
    assert np.isnan(c2w[keys[0] + 1:keys[5]]).all() and np.isfinite(c2w[keys[5]:]).all()


def test_frames_between_keyframes_are_placed_on_sfms_points():
    import cv2

    rng = np.random.default_rng(7)
    cam = static_camera(320, 240, 65.0)
    K = np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])
    texture = cv2.resize((rng.uniform(0, 255, (100, 150)).repeat(6, 0).repeat(6, 1)).astype(np.uint8), (1500, 1000))
    to_texture = np.array([[250.0, 0.0, 750.0], [0.0, 250.0, 500.0], [0.0, 0.0, 1.0]])  # the wall z = 4 m: 250 px/m
    # a handheld camera drifting and wobbling in front of a textured wall
    c2w = np.stack([look_at((0.1 * k, 0.06 * np.sin(2 * k), -0.03 * k), (0.1 * k + 0.05 * np.sin(2 * k), 0.0, 4.0),
                            up=(0.0, -1.0, 0.0)) for k in range(5)])
    frames = []
    for T in c2w:
        w2c = np.linalg.inv(T)
        H = K @ np.column_stack([w2c[:3, 0], w2c[:3, 1], w2c[:3, 2] * 4.0 + w2c[:3, 3]]) @ np.linalg.inv(to_texture)
        frames.append(np.stack([cv2.warpPerspective(texture, H, (320, 240))] * 3, axis=-1))
    # SfM's points seen by keyframes 0 and 4: corners of the wall, where they are in those frames
    seen = {}
    for k in (0, 4):
        grey = frames[k][..., 0]
        uv = cv2.goodFeaturesToTrack(grey, 200, 0.01, 5).reshape(-1, 2).astype(np.float64)
        rays = cam.unproject(uv) @ c2w[k][:3, :3].T
        depth = (4.0 - c2w[k][2, 3]) / rays[:, 2]
        seen[k] = (uv, c2w[k][:3, 3] + depth[:, None] * rays)
    start = interpolate_path(np.array([0, 4]), c2w[[0, 4]], 5, 16.0)
    got = register_frames(frames, cam, seen, start)
    for k in (1, 2, 3):
        assert np.linalg.norm(got[k][:3, 3] - c2w[k][:3, 3]) < 0.01
        assert np.linalg.norm(start[k][:3, 3] - c2w[k][:3, 3]) > 0.02  # the interpolated pose was off
        angle = np.degrees(np.arccos(np.clip((np.trace(got[k][:3, :3].T @ c2w[k][:3, :3]) - 1) / 2, -1, 1)))
        assert angle < 0.1


def test_a_camera_following_on_a_straight_line_takes_its_scale_from_the_steps():
    body_m, uv, vis, cam, c2w, joints, root = _filmed(4.0, "following")
    sfm = c2w.copy()
    sfm[:, :3, 3] *= SFM_SCALE  # SfM's units; no floor among its points
    time = np.arange(len(c2w)) / FPS
    t_cam = np.einsum("fji,fj->fi", c2w[:, :3, :3], joints[:, 0] - c2w[:, :3, 3])  # the root in each camera
    assert metric_scale_error(t_cam, sfm, time, metric_scale(t_cam, sfm, time)) > MAX_PATH_SCALE_ERROR
    with pytest.raises(ValueError, match="no scale"):
        place_landmarks_moving(body_m, uv, vis, cam, sfm, None, times=time)
    placed = place_landmarks_moving(body_m, uv, vis, cam, sfm, None, times=time, steps_speed_mps=1.3)
    assert placed.scale_from == "steps" and placed.scale == pytest.approx(1 / SFM_SCALE, rel=0.1)
    world_root = placed.landmarks_m[:, HIPS].mean(axis=1)
    assert walking_speed_mps(world_root, FPS) == pytest.approx(walking_speed_mps(root, FPS), rel=0.1)


def test_a_turning_cameras_rotations_from_the_background():
    rng = np.random.default_rng(6)
    # bearings of far points, 20 % of them moving on their own
    a = rng.normal(size=(200, 3)) + (0.0, 0.0, 3.0)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    R = Rotation.from_rotvec([0.02, -0.05, 0.01]).as_matrix()
    b = a @ R.T
    b[:40] += rng.normal(0.0, 0.05, (40, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(rotation_between(a, b), R, atol=1e-6)
    # a textured wall far away, filmed by a camera panning 0.8 deg a frame: frames are homographies K R K^-1
    cam = static_camera(320, 240, 65.0)
    K = np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])
    wall = (rng.uniform(0, 255, (60, 80)).repeat(8, 0).repeat(8, 1)).astype(np.uint8)
    wall = np.stack([wall] * 3, axis=-1)
    c2w = [Rotation.from_euler("y", 0.8 * k, degrees=True).as_matrix() for k in range(8)]
    big = static_camera(640, 480, 65.0 * 2.0)  # the wall seen wider than the camera: every frame inside it
    import cv2

    frames = []
    for Rk in c2w:
        Kb = np.array([[big.fx, 0.0, big.cx], [0.0, big.fy, big.cy], [0.0, 0.0, 1.0]])
        H = K @ Rk.T @ np.linalg.inv(Kb)  # wall pixel (seen by the wide camera at the origin) -> this frame
        frames.append(cv2.warpPerspective(cv2.resize(wall, (640, 480)), H, (320, 240)))
    masks = np.zeros((len(frames), 240, 320), bool)
    got, blind = rotation_path(frames, masks, cam)
    assert blind == 0
    for k in range(len(frames)):
        assert np.degrees(np.arccos(np.clip((np.trace(got[k].T @ c2w[k]) - 1) / 2, -1, 1))) < 0.05
    # SfM cannot start on a camera that only turns: camera_path falls back to the turns, centres at the origin
    path = camera_path(frames, masks, 4.0, hfov_deg=65.0)
    assert path.model == "rotation" and path.summary()["model"] == "rotation" and len(path.points_xyz) == 0
    np.testing.assert_allclose(path.cam_to_world[:, :3, :3], got, atol=1e-9)
    assert (path.cam_to_world[:, :3, 3] == 0).all()


def test_a_camera_only_turning_follows_the_walker_or_stands():
    # following on a straight line, its turns known but not its travel: the travel from the steps
    body_m, uv, vis, cam, c2w, joints, root = _filmed(4.0, "following")
    time = np.arange(len(c2w)) / FPS
    turns = c2w.copy()
    turns[:, :3, 3] = 0.0
    placed = place_landmarks_moving(body_m, uv, vis, cam, turns, None, times=time, steps_speed_mps=1.3,
                                    rotation_only=True)
    assert placed.scale_from == "steps"
    world_root = placed.landmarks_m[:, HIPS].mean(axis=1)
    assert walking_speed_mps(world_root, FPS) == pytest.approx(walking_speed_mps(root, FPS), rel=0.1)
    # a camera that stands and pans after the walk: the person's own travel, in the detector's metres
    body_m, uv, vis, cam, c2w, joints, root = _filmed(4.0, "static")
    placed = place_landmarks_moving(body_m, uv, vis, cam, c2w, None, times=time, steps_speed_mps=1.3,
                                    rotation_only=True)
    assert placed.scale_from == "standing"
    world_root = placed.landmarks_m[:, HIPS].mean(axis=1)
    assert walking_speed_mps(world_root, FPS) == pytest.approx(walking_speed_mps(root, FPS), rel=0.1)


@pytest.mark.slow
def test_a_following_actor_capture_is_told_moving_and_its_walking_speed_found(tmp_path):
    """A rendered capture whose camera follows behind the walker: the real SfM on its video; the detector is
    scripted from the capture's truth (landmarks with noise, its masks), so no MediaPipe."""
    from nsim.human.data import HumanData
    from nsim.human.landmarks import FrameObservation
    from nsim.synth.actor_capture import ActorCaptureConfig, render_actor_capture
    from nsim.train.human_data_video import PersonSource, prepare_person_data

    cap = tmp_path / "capture"
    render_actor_capture(cap, ActorCaptureConfig(width=320, height=240, n_frames=36, supersample=1, view_deg=180.0,
                                                 orbit_deg_s=0.0), seed=0)
    truth = HumanData.load(cap)
    w2c = np.linalg.inv(truth.cam_to_world())
    lm = reference_body(truth.poses.height_m).landmarks(truth.joint_transforms())
    lm = np.einsum("fij,flj->fli", w2c[:, :3, :3], lm) + w2c[:, None, :3, 3]
    uv = truth.camera().project(lm)[0]
    rng = np.random.default_rng(5)

    class Scripted:
        k = 0

        def __call__(self, rgb):
            k, self.k = self.k, self.k + 1
            body = lm[k] - lm[k, HIPS].mean(axis=0) + rng.normal(0.0, 0.01, (33, 3))
            return FrameObservation(uv[k] + rng.normal(0.0, 0.5, (33, 2)), body, np.ones(33),
                                    truth.mask(k).astype(np.float32))

        def close(self):
            pass

    source = PersonSource(cap / "video.mp4", person=PersonVideoConfig(body_height_m=truth.poses.height_m))
    report = prepare_person_data(source, tmp_path / "person", detector=Scripted())
    assert report["camera"] == "moving" and report["camera_decision"]["by"] == "background"
    assert report["camera_path"]["keyframes_registered"] >= 0.8 * report["camera_path"]["keyframes"]
    true_speed = walking_speed_mps(truth.poses.root_to_world[:, :3, 3], report["fps"])
    assert report["walking_speed_mps"] == pytest.approx(true_speed, rel=0.15), (report["walking_speed_mps"], true_speed)
    assert report["scale_from"] in ("floor", "path", "steps")
