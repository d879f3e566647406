"""``nsim register-log``: a robot's recording placed in a scene's world, as a ``registration`` artifact.

Inputs: a ``recording`` (``nsim import-log``) and a ``poses`` artifact with a COLMAP model in
``sparse/`` (``nsim reconstruct``'s SfM, metric). Up to ``frames_per_camera`` frames of each chosen
camera, evenly spaced over the frames inside the odometry's time span, are localised in the
scene's sparse model (``nsim.sfm.localize``); the odometry trajectory is then registered to them
(``nsim.sfm.register.register_trajectory``): a robust rigid (or similarity) fit with the cameras'
clock offset, then, with ``refine_drift``, a pose graph that bends the odometry onto the localised
frames (``nsim.sfm.drift_refinement.refine_drift``). Everything cheap is checked before any image is
read: the artifacts' kinds, the sparse model, a metric scene, the camera names and models. A recording
that cannot be registered (too few frames localised, no agreement, a residual over the limits) is
one line saying why, exit 2, nothing published.

Artifact layout (kind ``registration``)::

    registration.json        the inputs; odom_to_world (4 x 4, the odometry frame's pose in the
                             scene's world: refined when the drift is, and the rigid fit's too),
                             scale, clock_offset_s (+ std), residual statistics (median / RMS in
                             m and deg, inliers / used), the drift taken up, per frame tried:
                             camera, index (in its topic), stamp_ns, localised, inliers, matches,
                             reprojection error (px), cam_to_world, residual m / deg and inlier
                             flag (rigid and refined); the options
    trajectory_world.tum     the body's poses in the scene's world (body_to_world, TUM) at the
                             recording's odometry stamps: the refined trajectory, else the rigid
                             fit's; what renders of the recorded sensors use
    trajectory_world_ns.npy  the same stamps, int64 nanoseconds on the odometry clock
    preview.png              top view: the scene's sparse points, the registered trajectory (rigid
                             and refined), the localised camera centres coloured by residual; a
                             residual histogram; the drift along the run
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import param
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.sfm import localize_settings as loc_defaults
from nsim.sfm.drift_refinement import DriftModel
from nsim.sfm.registration_output import write_registration
from nsim.sfm.registration_types import RegisterOptions
from nsim.stages.runner import cached, rerun

STAGE = "register-log"
VERSION = 2  # 2: poses, trajectories and metrics written rounded (nsim.io.canonical: the same bytes on any CPU)
log = logging.getLogger(__name__)

#: libraries whose version can change the result (the fingerprint has numpy's and pycolmap's)
LIBRARIES = ("scipy", "matplotlib")


@dataclasses.dataclass(frozen=True)
class LocalizeConfig:
    """``nsim.sfm.localize.localize``'s options (defaults: that module's constants)."""

    top_k: int = param(loc_defaults.TOP_K, ge=1, le=100, help="scene images matched in full after retrieval")
    ratio: float = param(loc_defaults.RATIO, gt=0.0, le=1.0, help="Lowe's ratio test")
    min_inliers: int = param(loc_defaults.MIN_INLIERS, ge=4, help="fewer RANSAC inliers: the frame is not localised")
    max_error_px: float | None = param(None, gt=0.0, help="RANSAC threshold (null: 1 % of the image size, >= 2 px)")
    max_features: int = param(loc_defaults.MAX_FEATURES, ge=16, le=65536, help="SIFT features per image (the "
                                                                                 "scene's and the frames')")


@dataclasses.dataclass(frozen=True)
class Config:
    cameras: tuple[str, ...] = param((), help="the recording's cameras to localise (empty: all)")
    frames_per_camera: int = param(40, ge=1, le=100_000, help="frames localised per camera, evenly spaced")
    localize: LocalizeConfig = LocalizeConfig()
    register: RegisterOptions = RegisterOptions()
    refine_drift: bool = param(True, help="bend the odometry onto the localised frames (a pose graph)")
    drift: DriftModel = DriftModel()
    preview_max_points: int = param(20000, ge=100, help="sparse points drawn in preview.png")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """recording: a recording artifact (id, prefix or ref); poses: a poses artifact with a sparse model."""

    recording: str
    poses: str

    def ids(self) -> dict[str, str]:
        return {"recording": self.recording, "poses": self.poses}


@dataclasses.dataclass(frozen=True)
class Outputs:
    registration: str
    cache_hit: bool = False


def resolve_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    """Both artifacts as ids, of the right kinds (one-line InputError otherwise)."""
    store = ctx.store
    out = {}
    for name, kind, how in (("recording", "recording", "nsim import-log"), ("poses", "poses", "nsim reconstruct")):
        spec = getattr(inputs, name)
        art_id = store.resolve(spec)
        actual = store.get(art_id).kind
        if actual != kind:
            raise InputError(f"register-log {'--poses ' if name == 'poses' else ''}{spec}: a {actual} artifact; "
                             f"expected a {kind} artifact ({how})")
        if name == "recording" and not json.loads(store.get(art_id).file("recording.json").read_text())["streams"]:
            raise InputError(f"register-log {spec}: a trajectory-only recording (no sensor streams): nothing to "
                             f"register; nsim simulate drives a robot along it (robot.trajectory: {{recording: {spec}}})")
        out[name] = art_id
    return Inputs(**out)


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    from importlib import metadata

    versions = {name: metadata.version(name) for name in LIBRARIES}
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra={"libraries": versions})


@dataclasses.dataclass(frozen=True)
class _Plan:
    """What will be localised: per camera its stream entry, Camera, and the frames (indices into its topic)."""

    doc: dict[str, Any]
    traj_ns: np.ndarray
    body_to_odom: np.ndarray
    cameras: dict[str, tuple[dict[str, Any], Any, np.ndarray, np.ndarray]]  # name -> (entry, camera, frames, stamps)


def check_inputs(inputs: Inputs, cfg: Config, ctx: RunContext) -> _Plan:
    """Every cheap check, before any image is read: the scene's model and scale, the cameras, the frames."""
    from nsim.geometry.cameras import Camera
    from nsim.io.transforms_json import declared_world, read_transforms
    from nsim.io.tum import read_tum
    from nsim.sfm.colmap import camera_to_colmap

    store = ctx.store
    poses = store.get(inputs.poses)
    if not any((poses.path / "sparse" / f"images.{ext}").is_file() for ext in ("bin", "txt")):
        raise InputError(f"register-log --poses {inputs.poses[:12]}: the poses artifact has no COLMAP model in sparse/ "
                         "(an --import); localising needs one from nsim reconstruct's SfM")
    transforms = poses.path / "transforms.json"
    if transforms.is_file():
        metric, _ = declared_world(transforms, read_transforms(transforms))
        if metric is None:
            raise InputError(f"register-log --poses {inputs.poses[:12]}: the scene's scale is arbitrary; registering "
                             "a robot needs a metric scene (nsim reconstruct --reference, --camera-height or "
                             "--known-distance)")
    rec = store.get(inputs.recording)
    doc = json.loads(rec.file("recording.json").read_text())
    traj_ns = np.load(rec.file("trajectory_ns.npy"), allow_pickle=False)
    body = read_tum(rec.file("trajectory.tum")).poses_se3()
    if len(traj_ns) != len(body) or len(traj_ns) < 2:
        raise InputError(f"recording {inputs.recording[:12]}: trajectory_ns.npy and trajectory.tum disagree or hold "
                         "fewer than 2 poses")
    streams = {k.split("/", 1)[1]: v for k, v in doc["streams"].items() if v["kind"] == "camera"}
    if not streams:
        raise InputError(f"recording {inputs.recording[:12]}: no camera stream to localise")
    if len(set(cfg.cameras)) < len(cfg.cameras):
        raise InputError(f"cameras: {list(cfg.cameras)} names a camera twice")
    unknown = [c for c in cfg.cameras if c not in streams]
    if unknown:
        raise InputError(f"cameras: no camera named {', '.join(map(repr, unknown))} in recording "
                         f"{inputs.recording[:12]} (it has: {', '.join(sorted(streams))})")
    # frames captured while the odometry runs (camera stamps are ahead of it by a given offset)
    shift = int(round((cfg.register.clock_offset_s or 0.0) * 1e9))
    lo, hi = traj_ns[0] + shift, traj_ns[-1] + shift
    cams = {}
    for name in cfg.cameras or tuple(sorted(streams)):
        entry = streams[name]
        camera = Camera.from_dict(entry["camera"])
        try:
            camera_to_colmap(camera)
        except ValueError:
            raise InputError(f"cameras: {name}: its {camera.model} camera cannot be localised (pinhole, OpenCV or "
                             "fisheye cameras can)") from None
        stamps = np.load(rec.file(f"{entry['dir']}/stamps_ns.npy"), allow_pickle=False)
        frames = np.asarray(entry["frames"], dtype=np.int64)
        inside = np.flatnonzero((stamps >= lo) & (stamps <= hi))
        pick = inside[np.unique(np.round(np.linspace(0, len(inside) - 1, min(len(inside), cfg.frames_per_camera)))
                                .astype(np.int64))] if len(inside) else inside
        cams[name] = (entry, camera, frames[pick], stamps[pick])
    if not any(len(f) for _, _, f, _ in cams.values()):
        raise InputError(f"recording {inputs.recording[:12]}: no frame of {', '.join(cams)} lies inside the odometry "
                         "trajectory's time span")
    return _Plan(doc, traj_ns, body, cams)


def _read_frame(path: Path) -> np.ndarray:
    """A recorded frame as uint8: (H, W) grey (16-bit scaled down) or (H, W, 3) RGB."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    return np.ascontiguousarray(image[..., ::-1]) if image.ndim == 3 else image


def localize_frames(plan: _Plan, rec_path: Path, poses_path: Path, cfg: Config, ctx: RunContext) -> list[dict]:
    """Localise the planned frames in the scene; one record per frame tried (``loc``: a Localization or None)."""
    from nsim.progress import progress_bar
    from nsim.sfm.localize import build_scene_index, localize

    t0 = time.perf_counter()
    index = build_scene_index(poses_path, max_features=cfg.localize.max_features)
    log.info("register-log: scene index of %d images, %d points (%.1f s)", len(index.images), index.num_points,
             time.perf_counter() - t0)
    todo = [(name, int(i), int(s)) for name, (_, _, frames, stamps) in plan.cameras.items()
            for i, s in zip(frames, stamps, strict=True)]
    records, found, last_log = [], 0, time.monotonic()
    with progress_bar(len(todo), "localising frames", ctx.show_progress) as bar:
        for n, (name, i, stamp) in enumerate(todo, start=1):
            entry, camera, *_ = plan.cameras[name]
            image = _read_frame(rec_path / entry["dir"] / f"{i:06d}.png")
            lc = cfg.localize
            loc = localize(image, camera, index, top_k=lc.top_k, ratio=lc.ratio, min_inliers=lc.min_inliers,
                           max_error_px=lc.max_error_px, max_features=lc.max_features, seed=ctx.seed)
            found += loc is not None
            records.append({"camera": name, "index": i, "stamp_ns": stamp, "loc": loc})
            bar.advance(localised=found)
            if time.monotonic() - last_log > 10.0 or n == len(todo):
                log.info("register-log: %d / %d frames tried, %d localised", n, len(todo), found)
                last_log = time.monotonic()
    return records


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    store = ctx.store
    inputs = resolve_inputs(inputs, ctx)
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(registration=hit, cache_hit=True)
    from nsim.sfm.register import register_trajectory  # scipy after the input checks
    plan = check_inputs(inputs, cfg, ctx)
    rec, poses = store.get(inputs.recording), store.get(inputs.poses)
    t0 = time.perf_counter()
    records = localize_frames(plan, rec.path, poses.path, cfg, ctx)
    t1 = time.perf_counter()
    ok = [r for r in records if r["loc"] is not None]
    per_camera = ", ".join(f"{c} {sum(r['camera'] == c for r in ok)}/{sum(r['camera'] == c for r in records)}"
                           for c in plan.cameras)
    if len(ok) < cfg.register.min_frames:
        why = ("localise more (frames_per_camera, cameras)" if len(records) < cfg.register.min_frames else
               f"the recording's images do not match poses {inputs.poses[:12]}'s scene")
        raise InputError(f"register-log: only {len(ok)} of {len(records)} frames localised in the scene ({per_camera}; "
                         f"need {cfg.register.min_frames}): {why}")
    mounts = {c: np.asarray(e["sensor_to_body"], dtype=np.float64) for c, (e, *_) in plan.cameras.items()}
    try:
        reg = register_trajectory(
            np.stack([r["loc"].cam_to_world for r in ok]), np.array([r["stamp_ns"] for r in ok], dtype=np.int64),
            np.stack([mounts[r["camera"]] for r in ok]), plan.body_to_odom, plan.traj_ns, cfg.register,
            drift=cfg.drift if cfg.refine_drift else None)
    except InputError as e:
        raise InputError(f"register-log: {len(ok)} of {len(records)} frames localised ({per_camera}), but {e}") from None
    t2 = time.perf_counter()
    body_to_world = reg.refined.body_to_world if reg.refined is not None else reg.to_world(plan.body_to_odom)
    with store.publish(kind="registration", stage=STAGE, version=VERSION, key=key, config=cfg, inputs=inputs.ids(),
                       seed=ctx.seed) as out:
        doc = write_registration(out.dir, inputs, cfg, plan, records, reg, body_to_world, poses.path)
        res = doc["residual"]
        out.summary.update({"localised": f"{len(ok)}/{len(records)}", "inliers": res["inliers"],
                            "median_residual_cm": round(res["median_m"] * 100, 2),
                            "median_residual_deg": round(res["median_deg"], 3),
                            "clock_offset_ms": round(doc["clock_offset_s"] * 1000, 2)})
        out.timing.update({"localize_s": round(t1 - t0, 2), "register_s": round(t2 - t1, 2),
                           "write_s": round(time.perf_counter() - t2, 2)})
    log.info("register-log: %s", (reg.refined or reg).summary())
    return Outputs(registration=out.ref)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    return rerun(run, Inputs(**manifest["inputs"]), Config, manifest, ctx).registration
