"""``nsim register-log``: a robot's recording placed in a scene's world, as a ``registration`` artifact.

Inputs: a ``recording`` (``nsim import-log``) and a ``poses`` artifact with a COLMAP model in
``sparse/`` (``nsim reconstruct``'s SfM, metric). Up to ``frames_per_camera`` frames of each chosen
camera, evenly spaced over the frames inside the odometry's time span, are localised in the
scene's sparse model (``nsim.sfm.localize``); the odometry trajectory is then registered to them
(``nsim.sfm.register.register_trajectory``): a robust rigid (or similarity) fit with the cameras'
clock offset, then, with ``refine_drift``, a pose graph that bends the odometry onto the localised
frames (``nsim.sfm.register.refine_drift``). Everything cheap is checked before any image is read:
the artifacts' kinds, the sparse model, a metric scene, the camera names and models. A recording
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
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import from_dict, param
from nsim.context import RunContext
from nsim.errors import InputError
from nsim.sfm import localize as loc_defaults
from nsim.sfm.register import DriftModel, RegisterOptions

STAGE = "register-log"
VERSION = 1
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
    from nsim.sfm.register import register_trajectory

    store = ctx.store
    inputs = resolve_inputs(inputs, ctx)
    key = action_key(inputs, cfg, ctx)
    if not ctx.force and (hit := store.lookup(key)) is not None:
        return Outputs(registration=hit.id, cache_hit=True)
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


def _stats(fit) -> dict[str, Any]:
    return {"median_m": _num(fit.median_m), "rms_m": _num(fit.rms_m), "median_deg": _num(fit.median_deg),
            "rms_deg": _num(fit.rms_deg), "inliers": fit.num_inliers, "used": int(fit.used.sum())}


def write_registration(out_dir: Path, inputs: Inputs, cfg: Config, plan: _Plan, records: list[dict], reg,
                       body_to_world: np.ndarray, poses_path: Path) -> dict[str, Any]:
    """Write the artifact's files (module docstring); returns registration.json's content."""
    from nsim.config import to_dict
    from nsim.io.tum import Trajectory, write_tum

    np.save(out_dir / "trajectory_world_ns.npy", plan.traj_ns.astype(np.int64), allow_pickle=False)
    write_tum(out_dir / "trajectory_world.tum", Trajectory.from_poses(plan.traj_ns / 1e9, body_to_world))
    ref = reg.refined
    final = ref if ref is not None else reg
    rigid = {"odom_to_world": reg.odom_to_world.tolist(), "scale": reg.scale, "clock_offset_s": reg.clock_offset_s,
             "clock_offset_std_s": _num(reg.clock_offset_std_s), **_stats(reg)}
    frames, k = [], 0
    for r in records:
        loc, f = r["loc"], {"camera": r["camera"], "index": r["index"], "stamp_ns": r["stamp_ns"],
                            "localised": r["loc"] is not None}
        if loc is not None:
            f |= {"inliers": loc.num_inliers, "matches": loc.num_matches, "reprojection_error_px": loc.median_error_px,
                  "cam_to_world": loc.cam_to_world.tolist(), "used": bool(reg.used[k]),
                  "rigid": {"residual_m": _num(reg.residual_m[k]), "residual_deg": _num(reg.residual_deg[k]),
                            "inlier": bool(reg.inliers[k])}}
            if ref is not None:
                f["refined"] = {"residual_m": _num(ref.residual_m[k]), "residual_deg": _num(ref.residual_deg[k]),
                                "inlier": bool(ref.inliers[k])}
            k += 1
        frames.append(f)
    doc: dict[str, Any] = {
        "format": 1,
        "inputs": inputs.ids(),
        "world": "the poses artifact's scene world (metres, z up)",
        "odom_frame": plan.doc.get("odom_frame"), "body_frame": plan.doc.get("body_frame"),
        "odom_to_world": (ref.odom_to_world if ref is not None else reg.odom_to_world).tolist(),
        "odom_to_world_meaning": "maps odometry-frame points to world points; body_to_world = odom_to_world @ "
                                 "body_to_odom at the first pose (the refined trajectory's drift is zero there)",
        "scale": reg.scale,
        "clock_offset_s": final.clock_offset_s, "clock_offset_std_s": _num(final.clock_offset_std_s),
        "clock_offset_meaning": "camera stamp minus odometry time of capture",
        "residual": _stats(final),
        "rigid": rigid,
        "refined": None if ref is None else {
            "odom_to_world_std_m": _num(ref.odom_to_world_std_m), "odom_to_world_std_deg": _num(ref.odom_to_world_std_deg),
            "scale_error": ref.scale_error, "yaw_bias_deg_per_m": ref.yaw_bias_deg_per_m,
            "max_drift_m": float(ref.drift_m.max()), "max_drift_deg": float(ref.drift_deg.max()),
            "nodes": len(ref.nodes), "rounds": ref.rounds},
        "trajectory": {"file": "trajectory_world.tum", "stamps": "trajectory_world_ns.npy", "poses": len(plan.traj_ns),
                       "source": "refined" if ref is not None else "rigid",
                       "meaning": "body_to_world at the recording's odometry stamps"},
        "localised": {"tried": len(records), "localised": sum(r["loc"] is not None for r in records),
                      "per_camera": {c: {"tried": sum(r["camera"] == c for r in records),
                                         "localised": sum(r["camera"] == c and r["loc"] is not None for r in records)}
                                     for c in plan.cameras}},
        "frames": frames,
        "options": to_dict(cfg),
    }
    (out_dir / "registration.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    write_preview(out_dir / "preview.png", poses_path, plan, records, reg, body_to_world, cfg.preview_max_points)
    return doc


def _num(x: float) -> float | None:
    """JSON has no NaN or inf: those become null."""
    return float(x) if math.isfinite(x) else None


def write_preview(path: Path, poses_path: Path, plan: _Plan, records: list[dict], reg, body_to_world: np.ndarray,
                  max_points: int) -> None:
    """Top view (sparse points, trajectories, localised centres by residual), residual histogram, drift."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pycolmap

    from nsim.sfm.colmap import colmap_log_level

    with colmap_log_level():
        model = pycolmap.Reconstruction(poses_path / "sparse")
    xyz = np.array([p.xyz for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3) / 255.0
    if len(xyz) > max_points:
        keep = np.linspace(0, len(xyz) - 1, max_points).astype(np.int64)
        xyz, rgb = xyz[keep], rgb[keep]
    final = reg.refined if reg.refined is not None else reg
    ok = [r for r in records if r["loc"] is not None]
    centres = np.array([r["loc"].cam_to_world[:3, 3] for r in ok]).reshape(-1, 3)
    res_cm = final.residual_m * 100.0
    fig, axes = plt.subplots(1, 3, figsize=(15, 5), gridspec_kw={"width_ratios": [2, 1, 1]})
    ax = axes[0]
    ax.scatter(xyz[:, 0], xyz[:, 1], s=2, c=rgb, alpha=0.6, linewidths=0)
    rigid = reg.to_world(plan.body_to_odom)
    ax.plot(rigid[:, 0, 3], rigid[:, 1, 3], "--", color="0.4", lw=1, label="odometry, rigid fit")
    if reg.refined is not None:
        ax.plot(body_to_world[:, 0, 3], body_to_world[:, 1, 3], "-", color="k", lw=1.2, label="odometry, refined")
    inl = final.inliers
    sc = ax.scatter(centres[inl, 0], centres[inl, 1], c=res_cm[inl], s=14, cmap="viridis", label="localised (inlier)")
    ax.scatter(centres[~inl, 0], centres[~inl, 1], c="r", marker="x", s=14, label="localised (outlier or unused)")
    ax.plot(*body_to_world[0, :2, 3], "k^", label="start")
    fig.colorbar(sc, ax=ax, label="camera residual (cm)", fraction=0.046)
    # the view: the run and the bulk of the points (a few stray points would shrink everything else)
    span = np.concatenate([np.percentile(xyz[:, :2], [1, 99], axis=0) if len(xyz) else np.zeros((0, 2)),
                           body_to_world[:, :2, 3], rigid[:, :2, 3]])
    lo, hi = span.min(axis=0) - 0.5, span.max(axis=0) + 0.5
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m, scene world)")
    ax.set_ylabel("y (m, scene world)")
    ax.legend(fontsize=7, loc="best")
    ax.set_title(f"{len(ok)}/{len(records)} frames localised; residual median {final.median_m * 100:.1f} cm / "
                 f"{final.median_deg:.2f} deg\nclock offset {final.clock_offset_s * 1000:.1f} ms", fontsize=9)
    ax = axes[1]
    used = np.isfinite(res_cm)
    bins = np.linspace(0.0, max(float(np.nanmax(res_cm)) if used.any() else 1.0, 1e-3), 30)
    ax.hist([res_cm[inl], res_cm[used & ~inl]], bins=bins, stacked=True, color=["C0", "C3"],
            label=["inliers", "outliers"])
    ax.set_xlabel("camera centre residual (cm)")
    ax.set_ylabel("frames")
    ax.legend(fontsize=8)
    ax.set_title("residuals" + (" after the drift refinement" if reg.refined is not None else ""), fontsize=9)
    ax = axes[2]
    t = (plan.traj_ns - plan.traj_ns[0]) / 1e9
    if reg.refined is not None:
        ax.plot(t, reg.refined.drift_m * 100.0, label="position (cm)")
        ax.plot(t, reg.refined.drift_deg, label="heading and tilt (deg)")
        ax.legend(fontsize=8)
        ax.set_title("drift taken up: refined minus rigid", fontsize=9)
    else:
        ax.set_title("no drift refinement", fontsize=9)
    ax.set_xlabel("odometry time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=80, metadata={"Software": None})
    plt.close(fig)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    cfg = from_dict(Config, manifest["config"])
    ctx = dataclasses.replace(ctx, force=True)
    return run(Inputs(**manifest["inputs"]), cfg, ctx).registration
