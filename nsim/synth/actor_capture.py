"""The test room with a person in it: training data for a human model, with exact ground truth.

An articulated, textured ``nsim.synth.actor.Actor`` walks a seeded path through the room's
free space (a shortest-path walk between random waypoints on the room's clearance map,
smoothed), animated by the procedural gait (``nsim.human.gait.walk_cycle`` replayed along the
path by ``LocomotionLoop.pose_along_path``, so feet do not slide). A handheld camera follows
it: it orbits the person slowly (so front, sides and back are all filmed) at
``follow_distance_m``, keeps out of furniture and walls, prefers views the furniture does not
block, and looks at the (smoothed) pelvis with a walking bob and small hand wobbles. The
camera path is chosen for the whole capture at once (Viterbi over a ring of candidate
positions around the person per frame, penalising fast moves), then smoothed.

Core functions (arrays in, arrays out): ``plan_walk_path``, ``actor_motion``,
``follow_camera``. ``render_actor_capture`` renders and writes the files; it is deterministic
(same arguments, same bytes).

Output layout (the capture artifact of ``nsim.stages.capture`` plus the person)::

    transforms.json           nerfstudio convention, GT poses and intrinsics; per frame also
                              ``person_mask_path`` and ``background_path`` (``nsim.human.data``)
    images/frame_00000.png    RGB
    depth/frame_00000.exr     z-depth (channel Z, metres), person included
    masks/frame_00000.png     person mask, uint8 0 / 255 (the pixel-centre ray sees the person)
    background/frame_00000.png  the same view without the person (exact background, for training)
    poses.json                per-frame skeleton poses (``nsim.human.data``; docs/human_data.md)
    room.json                 the room specification (rebuilds the oracle)
    occupancy.json            2D obstacle polygons (walls + furniture footprints)
    gt_trajectory.tum         camera-to-world poses, TUM format
    video.mp4                 the frames as a video (when ``video``; H.264, ``nsim.io.video``)
    preview.png               contact sheet (mask outlines; frames labelled with index and time)
                              and a top-down view of both paths
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial.transform import Rotation

from nsim.geometry.transforms import look_at
from nsim.human.motion import LocomotionLoop, MotionClip
from nsim.human.skeleton import heading_yaw
from nsim.io.canonical import round_decimals
from nsim.synth.room import RoomSpec, clearance_xy_m

log = logging.getLogger(__name__)

CAMERAS = ("pinhole", "fisheye")
GRID_RES_M = 0.1
"""Cell size of the clearance map the walk is planned on."""
CAMERA_CLEARANCE_M = 0.35
"""Camera positions keep this far (2D) from walls and furniture footprints (the smoothed path 5 cm less)."""
_RING_ANGLES = 36
_RING_RADII = 5


@dataclass(frozen=True)
class ActorCaptureConfig:
    """What to film (lengths in metres, speeds in m/s).

    room, room_seed: the room preset (``nsim.synth.room.make_room``).
    camera: "pinhole" (``hfov_deg``) or "fisheye" (``Camera.fisheye_spot_like``); width, height in pixels.
    n_frames, fps: frames and frame rate (the person walks ``(n_frames - 1) / fps`` seconds).
    supersample: sub-pixel rays per axis for anti-aliasing.
    video: also write video.mp4.
    actor_height_m, actor_speed_mps: the person's height and walking speed.
    actor_seed: appearance (clothes, print); None uses the capture seed.
    follow_distance_m: (min, max) camera distance from the person.
    camera_height_m: mean camera height (handheld at chest or eye level).
    orbit_deg_s: how fast the camera goes round the person (relative to the person's heading;
        24 deg/s is one turn in 15 s).
    view_deg: where the camera starts, as an angle about the person relative to its heading (0: in front,
        the person walks towards the camera; 90: at the person's left; 180: behind, a camera that follows
        the walker); None: a seeded angle. With ``orbit_deg_s = 0`` the camera keeps that side.
    path_clearance_m: the walk keeps at least this far (2D) from walls and furniture.
    """

    room: str = "robot-lab"
    room_seed: int = 0
    camera: str = "pinhole"
    width: int = 320
    height: int = 240
    hfov_deg: float = 75.0
    n_frames: int = 150
    fps: float = 10.0
    supersample: int = 2
    video: bool = True
    actor_height_m: float = 1.75
    actor_speed_mps: float = 1.2
    actor_seed: int | None = None
    follow_distance_m: tuple[float, float] = (2.0, 4.0)
    camera_height_m: float = 1.5
    orbit_deg_s: float = 24.0
    path_clearance_m: float = 0.65
    view_deg: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "follow_distance_m", tuple(float(v) for v in self.follow_distance_m))
        checks = {
            "camera": self.camera in CAMERAS,
            "width": 16 <= self.width <= 4096,
            "height": 16 <= self.height <= 4096,
            "hfov_deg": 10.0 < self.hfov_deg < 170.0,
            "n_frames": 2 <= self.n_frames <= 100_000,
            "fps": 0.0 < self.fps <= 240.0,
            "supersample": 1 <= self.supersample <= 8,
            "actor_height_m": 0.5 <= self.actor_height_m <= 2.5,
            "actor_speed_mps": 0.3 <= self.actor_speed_mps <= 2.5,
            "follow_distance_m": len(self.follow_distance_m) == 2
            and 1.0 <= self.follow_distance_m[0] <= self.follow_distance_m[1] <= 10.0,
            "camera_height_m": 0.5 <= self.camera_height_m <= 2.2,
            "orbit_deg_s": math.isfinite(self.orbit_deg_s) and abs(self.orbit_deg_s) <= 180.0,
            "path_clearance_m": 0.3 <= self.path_clearance_m <= 2.0,
            "view_deg": self.view_deg is None or (math.isfinite(self.view_deg) and abs(self.view_deg) <= 360.0),
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"ActorCaptureConfig.{name}: out of range, got {getattr(self, name)!r}")


@dataclass(frozen=True, eq=False)
class ActorCapture:
    """What ``render_actor_capture`` wrote (N frames, J joints).

    out_dir: the folder. cam_to_world: (N, 4, 4) OpenCV axes. joint_transforms: (N, J, 4, 4).
    mask_fraction: (N,) share of each frame's pixels that show the person.
    """

    out_dir: Path
    cam_to_world: np.ndarray
    joint_transforms: np.ndarray
    mask_fraction: np.ndarray


def make_camera(cfg: ActorCaptureConfig):
    """The camera of ``cfg`` (same models as the capture stage)."""
    from nsim.geometry.cameras import Camera

    if cfg.camera == "pinhole":
        return Camera.pinhole_from_fov(cfg.width, cfg.height, cfg.hfov_deg)
    return Camera.fisheye_spot_like(cfg.width, cfg.height)


# ---------------------------------------------------------------------------------------------- the walk


def _polyline_length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def _resample(p: np.ndarray, step_m: float) -> np.ndarray:
    """The polyline ``p (P, 2)`` resampled at arc-length steps of ``step_m`` (end point kept)."""
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    s = np.r_[np.arange(0.0, arc[-1], step_m), arc[-1]]
    return np.stack([np.interp(s, arc, p[:, 0]), np.interp(s, arc, p[:, 1])], axis=1)


def plan_walk_path(spec: RoomSpec, length_m: float, seed: int = 0, clearance_m: float = 0.65) -> np.ndarray:
    """A smooth walk ``(P, 2)`` (metres, points every 5 cm) of at least ``length_m`` through the free space.

    Free space: cells of a ``GRID_RES_M`` grid at least ``clearance_m`` (2D) from walls and
    furniture. The walk starts on the room's walk loop (at a seeded angle) and goes along
    shortest paths (8-connected) to successive seeded waypoints at least 1.5 m away, preferring
    ones that do not make it turn back; the result is smoothed with a Gaussian (narrowed where
    smoothing would bring it closer than ``clearance_m - 0.2`` to an obstacle).
    Raises RuntimeError when the room has no free space at that clearance.
    """
    if not (math.isfinite(length_m) and length_m > 0.0):
        raise ValueError(f"plan_walk_path: length_m must be > 0, got {length_m!r}")
    rng = np.random.default_rng([int(seed), 0xAC7])
    X, Y, _ = spec.size_xyz_m
    W, H = math.ceil(X / GRID_RES_M - 1e-9), math.ceil(Y / GRID_RES_M - 1e-9)
    xs = (np.arange(W) + 0.5) * GRID_RES_M
    ys = (np.arange(H) + 0.5) * GRID_RES_M
    centres = np.stack(np.meshgrid(xs, ys), axis=-1)  # (H, W, 2), [i, j] -> (x_j, y_i)
    clear = clearance_xy_m(spec, centres)
    free = clear >= clearance_m
    if free.sum() < 2:
        raise RuntimeError(f"plan_walk_path: room {spec.name!r} has no free space {clearance_m} m from obstacles")
    node = np.full((H, W), -1, dtype=np.int64)
    node[free] = np.arange(int(free.sum()))
    cell_xy = centres[free]  # (n, 2)
    rows, cols, weights = [], [], []
    neighbours = (  # (a, b) node pairs: right, up, up-right, up-left (each undirected edge once)
        (node[:, :-1], node[:, 1:], GRID_RES_M), (node[:-1, :], node[1:, :], GRID_RES_M),
        (node[:-1, :-1], node[1:, 1:], GRID_RES_M * math.sqrt(2.0)),
        (node[:-1, 1:], node[1:, :-1], GRID_RES_M * math.sqrt(2.0)),
    )
    for a, b, step in neighbours:
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        weights.append(np.full(int(ok.sum()), step))
    n = cell_xy.shape[0]
    graph = coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()

    cx, cy, rx, ry = spec.walk_loop_xy_m
    a0 = rng.uniform(0.0, 2.0 * np.pi)
    start_xy = np.array([cx + rx * np.cos(a0), cy + ry * np.sin(a0)])
    current = int(np.argmin(np.linalg.norm(cell_xy - start_xy, axis=1)))
    dist0 = dijkstra(graph, directed=False, indices=current)
    reachable = np.isfinite(dist0)
    roomy = reachable & (clear[free] >= clearance_m + 0.25)
    pool = roomy if roomy.sum() >= 10 else reachable
    path = [cell_xy[current]]
    heading = None
    target = length_m
    for _ in range(1000):
        if _polyline_length(np.asarray(path)) >= target:
            smooth = _smooth_walk(spec, _resample(np.asarray(path), 0.05), clearance_m)
            missing = length_m - _polyline_length(smooth)
            if missing <= 0.0:
                return smooth
            target += missing + 1.0  # smoothing cut corners: walk on
        dist, pred = dijkstra(graph, directed=False, indices=current, return_predecessors=True)
        cand = np.nonzero(pool & (dist >= 1.5) & np.isfinite(dist))[0]
        if cand.size == 0:
            cand = np.nonzero(pool & (dist > 0) & np.isfinite(dist))[0]
        if cand.size == 0:
            raise RuntimeError(f"plan_walk_path: no waypoint reachable in room {spec.name!r}")
        weight = np.ones(cand.size)
        if heading is not None:
            d = cell_xy[cand] - cell_xy[current]
            turn = np.abs(np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - heading))))
            weight = np.exp(-((turn / 1.2) ** 2))
        nxt = int(rng.choice(cand, p=weight / weight.sum()))
        leg = [nxt]
        while leg[-1] != current:
            leg.append(int(pred[leg[-1]]))
        leg_xy = cell_xy[leg[::-1]]
        path.extend(leg_xy[1:])
        tail = leg_xy[-min(len(leg_xy), 6):]
        heading = float(np.arctan2(*(tail[-1] - tail[0])[::-1]))
        current = nxt
    raise RuntimeError(f"plan_walk_path: could not plan a walk of {length_m} m in room {spec.name!r}")


def _smooth_walk(spec: RoomSpec, raw: np.ndarray, clearance_m: float) -> np.ndarray:
    """Gaussian-smoothed ``raw (P, 2)``, as wide as keeps it ``clearance_m - 0.2`` from obstacles."""
    for sigma_m in (0.3, 0.2, 0.1, 0.05):
        smooth = gaussian_filter1d(raw, sigma_m / 0.05, axis=0, mode="nearest")
        if clearance_xy_m(spec, smooth).min() >= clearance_m - 0.2:
            return smooth
    return raw


def actor_motion(spec: RoomSpec, cfg: ActorCaptureConfig, seed: int) -> tuple[MotionClip, np.ndarray]:
    """The person's walk: a clip of exactly ``cfg.n_frames`` frames at ``cfg.fps`` and its path ``(P, 2)``."""
    from nsim.human.gait import walk_cycle

    duration_s = (cfg.n_frames - 1) / cfg.fps
    path = plan_walk_path(spec, cfg.actor_speed_mps * duration_s + 0.5, seed, cfg.path_clearance_m)
    loop = LocomotionLoop.from_clip(walk_cycle(cfg.actor_speed_mps, cfg.actor_height_m))
    start_phase = float(np.random.default_rng([int(seed), 0x9A1]).uniform())
    clip = loop.pose_along_path(path, cfg.actor_speed_mps, fps=cfg.fps, start_phase=start_phase)
    if clip.num_frames < cfg.n_frames:  # pragma: no cover - the path is longer than the walk
        raise RuntimeError(f"actor_motion: walk has {clip.num_frames} frames, needs {cfg.n_frames}")
    n = cfg.n_frames
    clip = MotionClip(clip.skeleton, clip.fps, clip.root_positions_m[:n], clip.local_rotations_wxyz[:n],
                      name="actor walk")
    return clip, path


# ---------------------------------------------------------------------------------------------- the camera


def _wobble(rng: np.random.Generator, t_s: np.ndarray, amplitude: float, lo_hz: float, hi_hz: float) -> np.ndarray:
    """Smooth pseudo-random signal ``(N,)`` over times ``t_s`` peaking at about ``amplitude``: three sinusoids."""
    freqs = rng.uniform(lo_hz, hi_hz, size=3)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    weights = np.array([0.5, 0.3, 0.2])
    return amplitude * np.sum(weights[:, None] * np.sin(2 * np.pi * freqs[:, None] * t_s[None] + phases[:, None]), axis=0)


def follow_camera(spec: RoomSpec, focus_xyz_m: np.ndarray, heading_rad: np.ndarray, fps: float, seed: int,
                  cfg: ActorCaptureConfig) -> np.ndarray:
    """``cam_to_world (N, 4, 4)`` (OpenCV axes) of a handheld camera filming a person.

    focus_xyz_m: (N, 3) the point to look at (the person's pelvis); heading_rad: (N,) the
    person's heading. Per frame the camera stands on a ring of candidates around the focus
    (``cfg.follow_distance_m``; at least ``CAMERA_CLEARANCE_M`` from obstacles); the sequence
    minimises, by dynamic programming, the distance from the wanted orbit angle (turning at
    ``cfg.orbit_deg_s`` relative to the heading), blocked views of the person and the
    camera's speed. It is then smoothed, and wobbles (height, yaw, pitch, roll) are added.
    Raises RuntimeError when some frame has no admissible camera position.
    """
    from nsim.synth.raycast import cast

    focus = np.asarray(focus_xyz_m, dtype=np.float64)
    heading = np.asarray(heading_rad, dtype=np.float64)
    N = focus.shape[0]
    rng = np.random.default_rng([int(seed), 0xCA3])
    lo, hi = cfg.follow_distance_m
    angles = 2.0 * np.pi * np.arange(_RING_ANGLES) / _RING_ANGLES
    radii = np.linspace(lo, hi, _RING_RADII)
    A, R = np.meshgrid(angles, radii, indexing="ij")
    A, R = A.ravel(), R.ravel()  # (S,)
    ring = np.stack([R * np.cos(A), R * np.sin(A)], axis=-1)  # (S, 2)
    cand = focus[:, None, :2] + ring[None]  # (N, S, 2)
    S = ring.shape[0]
    admissible = clearance_xy_m(spec, cand) >= CAMERA_CLEARANCE_M
    if not admissible.any(axis=1).all():
        bad = int(np.nonzero(~admissible.any(axis=1))[0][0])
        raise RuntimeError(f"follow_camera: no camera position {lo}-{hi} m from the person at frame {bad} "
                           f"keeps {CAMERA_CLEARANCE_M} m from obstacles in room {spec.name!r}")
    # views blocked by furniture: rays from each candidate to the pelvis and to the chest
    eye = np.concatenate([cand, np.full((N, S, 1), cfg.camera_height_m)], axis=-1).reshape(-1, 3)
    blocked = np.zeros(N * S, dtype=bool)
    for dz in (0.0, 0.45):
        target = np.repeat(focus + [0.0, 0.0, dz], S, axis=0)
        d = target - eye
        dist = np.linalg.norm(d, axis=1)
        hits = cast(spec, eye, d / dist[:, None])
        blocked |= hits.t < dist - 0.05
    blocked = blocked.reshape(N, S)
    # unary: orbit angle, preferred distance, blocked view
    t_s = np.arange(N) / fps
    phi0 = rng.uniform(0.0, 2.0 * np.pi)  # drawn in any case: the wobbles below come from the same generator
    if cfg.view_deg is not None:
        phi0 = math.radians(cfg.view_deg)
    wanted = heading + phi0 + np.radians(cfg.orbit_deg_s) * t_s  # (N,)
    r_pref = 0.5 * (lo + hi)
    unary = (3.0 * (1.0 - np.cos(A[None] - wanted[:, None])) + ((R[None] - r_pref) / max(hi - lo, 0.5)) ** 2
             + 20.0 * blocked)
    unary = np.where(admissible, unary, np.inf)
    # Viterbi; pairwise: squared camera speed (about 1.5 m/s costs 0.3)
    cost = unary[0].copy()
    back = np.zeros((N, S), dtype=np.int64)
    for k in range(1, N):
        step = np.linalg.norm(cand[k][:, None, :] - cand[k - 1][None, :, :], axis=-1) * fps  # (S now, S before)
        total = cost[None, :] + 0.3 * (step / 1.5) ** 2
        back[k] = np.argmin(total, axis=1)
        cost = total[np.arange(S), back[k]] + unary[k]
    state = np.empty(N, dtype=np.int64)
    state[-1] = int(np.argmin(cost))
    for k in range(N - 1, 0, -1):
        state[k - 1] = back[k, state[k]]
    # smooth the chosen offsets from the (smoothed) person in polar form, so distances stay in range
    centre = gaussian_filter1d(focus, 0.3 * fps, axis=0, mode="nearest")
    offset = cand[np.arange(N), state] - centre[:, :2]
    angle_raw = np.unwrap(np.arctan2(offset[:, 1], offset[:, 0]))
    radius_raw = np.linalg.norm(offset, axis=1)
    xy = centre[:, :2] + offset
    for sigma_s in (0.8, 0.5, 0.3, 0.15):
        a = gaussian_filter1d(angle_raw, sigma_s * fps, mode="nearest")
        r = np.clip(gaussian_filter1d(radius_raw, sigma_s * fps, mode="nearest"), lo, hi)
        smooth = centre[:, :2] + np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
        if clearance_xy_m(spec, smooth).min() >= CAMERA_CLEARANCE_M - 0.05:
            xy = smooth
            break
    # the handheld part: walking bob, slow height drift, look-at wobble
    walked = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    height = (cfg.camera_height_m + _wobble(rng, t_s, 0.08, 0.03, 0.15)
              + 0.015 * np.sin(2.0 * np.pi * walked / 0.7))
    eye = np.concatenate([xy, height[:, None]], axis=-1)
    cam_to_world = look_at(eye, centre)
    wobble_deg = np.stack([_wobble(rng, t_s, 1.5, 0.1, 1.2),  # about camera +x (pitch)
                           _wobble(rng, t_s, 2.5, 0.1, 1.2),  # about camera +y (yaw)
                           _wobble(rng, t_s, 1.5, 0.1, 1.0)], axis=-1)  # about +z (roll)
    cam_to_world[:, :3, :3] = cam_to_world[:, :3, :3] @ Rotation.from_rotvec(np.radians(wobble_deg)).as_matrix()
    return round_decimals(cam_to_world)  # to 1e-9: what is rendered is what transforms.json holds, on any CPU


# ---------------------------------------------------------------------------------------------- rendering


@dataclass(frozen=True, eq=False)
class _FrameTask:
    """Frames ``first .. first + len(cam_to_world) - 1`` to render and write (plain, picklable data)."""

    out_dir: str
    spec: RoomSpec
    cfg: ActorCaptureConfig
    actor_seed: int
    first: int
    cam_to_world: np.ndarray
    joint_transforms: np.ndarray


def _render_frames(task: _FrameTask, bar=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Render and write the task's images, depth and masks; returns ``(rgb uint8, mask uint8)`` per frame."""
    from nsim.io.exr import write_depth_exr
    from nsim.io.images import to_uint8, write_image
    from nsim.synth.actor import Actor
    from nsim.synth.oracle import PlacedActor, RoomOracle

    out_dir = Path(task.out_dir)
    cfg = task.cfg
    camera = make_camera(cfg)
    oracle = RoomOracle(task.spec)
    actor = Actor(cfg.actor_height_m, seed=task.actor_seed)
    out = []
    for k, (c2w, T) in enumerate(zip(task.cam_to_world, task.joint_transforms, strict=True)):
        view = oracle.render_gt(camera, c2w, supersample=cfg.supersample, actors=[PlacedActor(actor, T, 1)])
        rgb = to_uint8(view.rgb)
        mask = (view.instance_mask == 1).astype(np.uint8) * 255
        name = f"frame_{task.first + k:05d}"
        write_image(out_dir / "images" / f"{name}.png", rgb)
        write_depth_exr(out_dir / "depth" / f"{name}.exr", view.depth_z)
        write_image(out_dir / "masks" / f"{name}.png", mask)
        write_image(out_dir / "background" / f"{name}.png", to_uint8(view.room_rgb))
        out.append((rgb, mask))
        if bar is not None:
            bar.advance()
    return out


def render_actor_capture(out_dir: str | Path, cfg: ActorCaptureConfig = ActorCaptureConfig(), seed: int = 0,
                         spec: RoomSpec | None = None, show_progress: bool = False,
                         workers: int = 1) -> ActorCapture:
    """Render the capture described by ``cfg`` (walk, camera path and appearance from ``seed``) into ``out_dir``.

    spec: a room to use instead of ``make_room(cfg.room, cfg.room_seed)``. ``out_dir`` is
    created if needed and must not hold a previous capture. workers: processes that render
    frames (contiguous blocks, ``nsim.distributed.map_tasks``); the files do not depend on it.
    Returns ``ActorCapture``.
    """
    from nsim.distributed import map_tasks
    from nsim.human.data import HumanPoses, write_poses
    from nsim.io.transforms_json import Frame, TransformsData, write_transforms
    from nsim.io.tum import Trajectory, write_tum
    from nsim.io.video import write_mp4
    from nsim.progress import progress_bar
    from nsim.synth.path import timestamps_s
    from nsim.synth.room import make_room

    out_dir = Path(out_dir)
    if (out_dir / "transforms.json").exists():
        raise FileExistsError(f"{out_dir}: already holds a capture")
    preset = cfg.room if spec is None else None
    spec = make_room(cfg.room, cfg.room_seed) if spec is None else spec
    camera = make_camera(cfg)
    clip, walk_path = actor_motion(spec, cfg, seed)
    actor_seed = seed if cfg.actor_seed is None else cfg.actor_seed
    T = clip.joint_transforms()  # (N, J, 4, 4)
    heading = np.unwrap(heading_yaw(T[:, 0, :3, :3]))
    cam_to_world = follow_camera(spec, T[:, 0, :3, 3], heading, cfg.fps, seed, cfg)
    times = timestamps_s(cfg.n_frames, cfg.fps)

    for sub in ("images", "depth", "masks", "background"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    blocks = [b for b in np.array_split(np.arange(cfg.n_frames), max(1, int(workers))) if b.size]
    tasks = [_FrameTask(str(out_dir), spec, cfg, actor_seed, int(b[0]), cam_to_world[b], T[b]) for b in blocks]
    with progress_bar(cfg.n_frames, f"rendering {spec.name} with a person", show_progress) as bar:
        if len(tasks) == 1:
            rendered = _render_frames(tasks[0], bar)
        else:
            rendered = [frame for block in map_tasks(_render_frames, tasks, workers=len(tasks)) for frame in block]
            bar.advance(cfg.n_frames)
    fraction = np.array([float((mask > 0).mean()) for _, mask in rendered])
    if cfg.video:
        write_mp4(out_dir / "video.mp4", (rgb for rgb, _ in rendered), float(cfg.fps))
    names = [f"frame_{i:05d}" for i in range(cfg.n_frames)]
    frames = [Frame(file_path=f"images/{name}.png", cam_to_world=cam_to_world[i], camera=camera,
                    depth_file_path=f"depth/{name}.exr", timestamp_s=float(times[i]),
                    extra={"person_mask_path": f"masks/{name}.png", "background_path": f"background/{name}.png"})
              for i, name in enumerate(names)]
    write_transforms(out_dir / "transforms.json",
                     TransformsData(frames=frames, extra={"nsim_capture": "capture", "nsim_human_poses": "poses.json"}))
    local = clip.local_rotations_wxyz.copy()
    local[:, 0] = (1.0, 0.0, 0.0, 0.0)  # root_to_world carries the root's orientation
    appearance = _appearance(actor_seed, cfg.actor_height_m)
    poses = HumanPoses(clip.skeleton, cfg.actor_height_m, T[:, 0], local, times,
                       tuple(f"images/{n}.png" for n in names),
                       {"source": "nsim synthetic actor capture", "actor_seed": actor_seed,
                        "actor_height_m": cfg.actor_height_m, "actor_speed_mps": cfg.actor_speed_mps,
                        "appearance": appearance})
    write_poses(out_dir / "poses.json", poses)
    write_tum(out_dir / "gt_trajectory.tum", Trajectory.from_poses(times, cam_to_world))
    _write_room_files(out_dir, spec, preset, cfg.room_seed if preset is not None else spec.seed)
    step = max(1, cfg.n_frames // 8)
    thumbs = [(i, float(times[i]), *rendered[i]) for i in range(0, cfg.n_frames, step)][:8]
    _write_preview(out_dir / "preview.png", thumbs, spec, walk_path, T[:, 0, :3, 3], cam_to_world, cfg)
    log.info("actor capture: %d frames, person in %.0f%% of them", cfg.n_frames, 100 * (fraction > 0).mean())
    return ActorCapture(out_dir=out_dir, cam_to_world=cam_to_world, joint_transforms=T, mask_fraction=fraction)


def _appearance(actor_seed: int, height_m: float) -> dict[str, Any]:
    """The actor's chosen colours and print (JSON-ready)."""
    from nsim.synth.actor import Actor

    return {k: list(v) if isinstance(v, tuple) else v for k, v in Actor(height_m, seed=actor_seed).appearance.items()}


def _write_room_files(out_dir: Path, spec: RoomSpec, preset: str | None, room_seed: int) -> None:
    """``room.json`` and ``occupancy.json``, laid out as the capture stage writes them."""
    from nsim.synth.room import occupancy_polygons, room_diagonal_m

    (out_dir / "room.json").write_text(
        json.dumps({"preset": preset, "room_seed": room_seed, "spec": spec.to_dict()}, indent=1) + "\n")
    (out_dir / "occupancy.json").write_text(json.dumps({
        "units": "m",
        "frame": "world, z up; polygons in the xy plane (counter-clockwise)",
        "room_diagonal_m": room_diagonal_m(spec),
        "polygons": [np.asarray(p, dtype=float).round(6).tolist() for p in occupancy_polygons(spec)],
    }, indent=1) + "\n")


def _write_preview(path: Path, thumbs: list[tuple[int, float, np.ndarray, np.ndarray]], spec: RoomSpec,
                   walk_path: np.ndarray, pelvis_xyz: np.ndarray, cam_to_world: np.ndarray,
                   cfg: ActorCaptureConfig) -> None:
    """Contact sheet (person outlined in cyan; ``thumbs``: ``(index, time_s, rgb, mask)``, each labelled
    with its index and time) beside a top-down map: obstacles grey, planned walk dark grey, the
    person's pelvis red, the camera coloured by time (viridis) with view ticks; a title above.

    Drawn with OpenCV (fast, and the PNG bytes are the same every run).
    """
    import cv2

    from nsim.io.images import write_image
    from nsim.io.labels import add_label, tile_grid
    from nsim.synth.room import occupancy_polygons

    ncol, thumb_w, pad = 4, 240, 4
    h0, w0 = thumbs[0][2].shape[:2] if thumbs else (cfg.height, cfg.width)
    thumb_h = max(1, round(thumb_w * h0 / w0))
    tiles = []
    for i, t_s, rgb, mask in thumbs:
        interp = cv2.INTER_AREA if w0 > thumb_w else cv2.INTER_NEAREST
        im = np.ascontiguousarray(cv2.resize(rgb, (thumb_w, thumb_h), interpolation=interp))
        m = cv2.resize((mask > 0).astype(np.uint8), (thumb_w, thumb_h), interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(im, contours, -1, (0, 255, 255), 1)
        tiles.append(add_label(im, f"frame {i}  {t_s:.2f} s"))
    sheet = tile_grid(tiles, ncol, pad)
    sheet_h = sheet.shape[0]
    # top-down map, as tall as the sheet
    X, Y, _ = spec.size_xyz_m
    margin_m = 0.3
    scale = (sheet_h - 2 * pad) / (Y + 2 * margin_m)
    map_w = int(math.ceil((X + 2 * margin_m) * scale)) + 2 * pad
    top = np.full((sheet_h, map_w, 3), 255, dtype=np.uint8)

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        u = pad + (xy[:, 0] + margin_m) * scale
        v = sheet_h - pad - (xy[:, 1] + margin_m) * scale
        return np.rint(np.stack([u, v], axis=1)).astype(np.int32)

    for poly in occupancy_polygons(spec):
        cv2.fillPoly(top, [px(poly)], (160, 160, 160))
    cv2.polylines(top, [px(walk_path)], False, (90, 90, 90), 1, cv2.LINE_AA)
    cv2.polylines(top, [px(pelvis_xyz[:, :2])], False, (220, 40, 40), 2, cv2.LINE_AA)
    n = len(cam_to_world)
    colours = cv2.applyColorMap(np.linspace(0, 255, n).astype(np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)[:, 0, ::-1]
    pos = px(cam_to_world[:, :3, 3][:, :2])
    tips = px(cam_to_world[:, :3, 3][:, :2] + 0.35 * cam_to_world[:, :3, 2][:, :2])
    step = max(1, n // 30)
    for k in range(n):
        colour = tuple(int(c) for c in colours[k])
        if k % step == 0:
            cv2.line(top, tuple(int(c) for c in pos[k]), tuple(int(c) for c in tips[k]), colour, 1, cv2.LINE_AA)
        cv2.circle(top, tuple(int(c) for c in pos[k]), 2, colour, -1, cv2.LINE_AA)
    title = (f"{spec.name}: {n} frames {cfg.width}x{cfg.height} {cfg.camera}; person {cfg.actor_height_m} m at "
             f"{cfg.actor_speed_mps} m/s (red), camera by time (viridis), planned walk (grey)")
    out = add_label(np.concatenate([sheet, top], axis=1), title)
    write_image(path, out)
