"""``nsim evaluate``: how real the simulation is, as one of the paper's tables (an ``evaluation`` artifact).

``--table`` picks the experiment; ``--render`` (repeatable) the render artifacts it scores. Each
table compares what the simulator rendered with a ground truth found through the render's lineage
(render -> scene-checkpoint -> poses -> capture):

``scenes`` (paper Table I)
    Poses-mode renders (``nsim render --poses ... --set frames=heldout``), one per environment.
    Per environment: PSNR, SSIM, LPIPS of every rendered frame and depth AbsRel, RMSE, delta<1.25.
    Ground truth (``scenes_ground_truth``): ``captured`` (default) -- the frames the scene was
    trained from: a capture's own images and depth EXRs; a poses artifact's images (real data),
    with depth from the capture it was reconstructed from (matched by file name) when there is
    one; ``oracle`` -- the test room's oracle rendered at exactly the render's cameras and poses.
``spot-rgb`` (Table III) / ``spot-depth`` (Table II)
    Trajectory-mode renders (``nsim render --trajectory ... --rig configs/robots/spot.yaml``). Per
    rig camera, every rendered frame against the test room's oracle rendered with that frame's
    camera and pose (``cameras/<sensor>.json``): colour passed through the sensor's exposure /
    grey model and 8-bit quantised like the sensor's PNGs; depth in the sensor's depth kind with
    its valid range (no noise, no quantisation). Simulated readings the sensor reports as NaN
    (nearer than its minimum range) at pixels where the ground truth is valid count as that minimum.
``slam``
    One camera of trajectory-mode renders (``slam.camera``, every ``slam.stride``-th frame):
    pycolmap incremental SfM (``nsim.metrics.slam.run_colmap_slam``) on the simulated frames and
    on the oracle's ("real") frames at the same poses; both ATEs against the camera's poses. A
    side where SfM fails is n/a with the reason.
``detection``
    Trajectory-mode renders with people (``--humans``). People detected (OpenCV HOG, an ONNX model,
    or COCO JSON given) on the simulated frames and on the oracle's frames at the same camera poses
    with the same people: test-room actors posed like the simulated ones (the run's positions,
    headings, gait phases and heights, through the render's skeleton and gait loop) and dressed
    like the actor each human checkpoint was trained from (its actor capture's ``actor_seed``).
    Frames are turned upright by quarter turns first (``detection.upright``: Spot's front cameras
    are rolled ~90 deg). Matched-box IoU, precision, recall; per frame (records.json) the person
    pixels of the render's mask and of the oracle's and their IoU, summed up in the notes. A render
    without people is n/a with the reason.

Artifact layout::

    evaluation.json            table, renders, ground-truth source per render, config notes, counts
    <table>.md/.tex/.csv/.json the table (``nsim.metrics.tables.Table.write_all``)
    records.json               per-frame records (the table's inputs) and per-frame extras
    plots/*_per_frame.png      per-frame metric curves, one line per group
    plots/bars.png             per-group bars of every metric column
    plots/depth_error/*.png    depth error maps of the first ``error_maps`` frames per group
    slam/<sequence>/{ground_truth,real,sim}.tum   (slam) the trajectories scored

Bad input is one line (``InputError``): a render of the wrong mode for the table, frames missing
or out of range (frame counts that do not match), images or depth maps of different sizes, NaN
depth at pixels where the ground truth is valid, an empty person mask, a trajectory with no
timestamps in common with the frames, or no test-room ground truth where the table needs it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from nsim.config import from_dict, param
from nsim.context import RunContext
from nsim.errors import InputError

STAGE = "evaluate"
VERSION = 1
TABLES = ("scenes", "spot-rgb", "spot-depth", "slam", "detection")
log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class SlamConfig:
    camera: str = param("left", help="the rig camera whose frames SfM runs on")
    stride: int = param(1, ge=1, help="use every k-th rendered frame")
    max_frames: int | None = param(None, ge=3, help="use at most this many frames")
    camera_model: str = param("OPENCV_FISHEYE", choices=("SIMPLE_RADIAL", "OPENCV", "OPENCV_FISHEYE", "PINHOLE"),
                              help="COLMAP model estimated for the camera")
    matcher: str = param("sequential", choices=("sequential", "exhaustive"))
    overlap: int = param(10, ge=1, help="sequential matching: each frame against this many next ones")
    max_features: int = param(4096, ge=64)
    min_registered_fraction: float = param(0.5, gt=0.0, le=1.0, help="fewer registered frames: SfM failed (n/a)")
    alignment: str = param("sim3", choices=("se3", "sim3"), help="ATE alignment (monocular SfM has no scale: sim3)")
    max_dt_s: float = param(0.01, gt=0.0, help="largest timestamp gap when associating poses")


@dataclasses.dataclass(frozen=True)
class DetectionConfig:
    detector: str = param("hog", choices=("hog", "onnx", "coco"),
                          help="hog: OpenCV's people detector; onnx: --onnx weights; coco: --coco-sim/--coco-real files")
    iou_threshold: float = param(0.5, gt=0.0, le=1.0, help="a simulated box matches a real one at this IoU")
    hog_upscale: float = param(2.0, gt=0.0, le=8.0, help="enlarge images first (the HOG window is 64x128 px)")
    hog_hit_threshold: float = param(0.0, help="HOG SVM margin below which windows are dropped")
    upright: bool = param(True, help="turn each camera's frames by quarter turns so the world's up is up before "
                                     "detecting (Spot's front cameras are rolled ~90 deg, its right one upside down)")


@dataclasses.dataclass(frozen=True)
class Config:
    table: str = param("scenes", choices=TABLES, help="which table to compute")
    cameras: tuple[str, ...] = param((), help="rig cameras to score (empty: all that apply)")
    lpips_net: str = param("alex", choices=("alex", "vgg", "none"), help="LPIPS backbone (none: not computed)")
    oracle_supersample: int = param(2, ge=1, le=8, help="sub-pixel rays per axis of the oracle's ground-truth images")
    scenes_ground_truth: str = param("captured", choices=("captured", "oracle"),
                                     help="scenes: the captured frames, or the oracle at the rendered cameras")
    region: str = param("all", choices=("all", "people"), help="score every pixel, or only the people's")
    depth_min_m: float = param(0.1, gt=0.0, help="ground-truth depths below this do not count")
    depth_max_m: float = param(10.0, gt=0.0, help="ground-truth depths above this do not count")
    median_scaling: bool = param(False, help="scale each predicted depth map by median(gt) / median(pred)")
    error_maps: int = param(2, ge=0, help="depth error map PNGs per group (first frames)")
    slam: SlamConfig = SlamConfig()
    detection: DetectionConfig = DetectionConfig()


@dataclasses.dataclass(frozen=True)
class Inputs:
    """renders: render artifact ids or refs (one per environment for ``scenes``); onnx: a detector's
    weights (``detection.detector: onnx``); coco_sim / coco_real: detections on the simulated and
    real frames, keyed by ``<camera>/rgb/NNNNNN.png`` (``detection.detector: coco``)."""

    renders: tuple[str, ...]
    onnx: Path | None = None
    coco_sim: Path | None = None
    coco_real: Path | None = None

    def ids(self) -> dict[str, str]:
        return {f"render{k}": r for k, r in enumerate(self.renders)}

    def files(self) -> dict[str, Path]:
        return {n: Path(p) for n in ("onnx", "coco_sim", "coco_real") if (p := getattr(self, n)) is not None}


@dataclasses.dataclass(frozen=True)
class Outputs:
    evaluation: str
    cache_hit: bool = False


# ---------------------------------------------------------------------------------- the stage
def _file_digests(inputs: Inputs) -> dict[str, str]:
    from nsim.workspace.store import sha256_file

    out = {}
    for name, path in inputs.files().items():
        if not path.is_file():
            raise InputError(f"--{name.replace('_', '-')} {path}: no such file")
        out[name] = sha256_file(path)[0]
    return out


def resolve_inputs(inputs: Inputs, ctx: RunContext) -> Inputs:
    if not inputs.renders:
        raise InputError("evaluate: give at least one --render")
    ids = tuple(ctx.store.resolve(r, kind="render") for r in inputs.renders)
    if len(set(ids)) != len(ids):
        raise InputError("evaluate: the same render is given twice")
    return dataclasses.replace(inputs, renders=ids)


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    extra: dict[str, Any] = {"files": _file_digests(inputs)}
    if cfg.lpips_net != "none" and cfg.table in ("scenes", "spot-rgb"):
        extra["device"] = "cuda" if str(ctx.device).startswith("cuda") else "cpu"
    return ctx.store.action_key(STAGE, VERSION, cfg, inputs.ids(), seed=ctx.seed, extra=extra)


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    """Compute ``cfg.table`` over the renders (or find it in the run cache)."""
    inputs = resolve_inputs(inputs, ctx)
    if cfg.depth_max_m <= cfg.depth_min_m:
        raise InputError(f"depth_max_m ({cfg.depth_max_m:g}) must be greater than depth_min_m ({cfg.depth_min_m:g})")
    key = action_key(inputs, cfg, ctx)
    if not ctx.force and (hit := ctx.store.lookup(key)) is not None:
        return Outputs(evaluation=hit.id, cache_hit=True)
    evaluator = Evaluator(inputs, cfg, ctx)
    result = TABLE_FUNCTIONS[cfg.table](evaluator)  # every input is read and checked before publishing
    with ctx.store.publish(kind="evaluation", stage=STAGE, version=VERSION, key=key, config=cfg,
                           inputs=inputs.ids(), seed=ctx.seed) as out:
        write_result(out.dir, cfg, inputs, evaluator, result)
        out.summary.update({"table": cfg.table, "rows": len(result.table.rows), "records": len(result.records),
                            "files": {k: str(v) for k, v in inputs.files().items()}})
    return Outputs(evaluation=out.ref)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    ids = manifest["inputs"]
    files = manifest.get("summary", {}).get("files", {})
    renders = tuple(ids[f"render{k}"] for k in range(len(ids)))
    inputs = Inputs(renders=renders, **{k: Path(v) for k, v in files.items()})
    ctx.force = True
    return run(inputs, from_dict(Config, manifest["config"]), ctx).evaluation


def load_table(ctx: RunContext, evaluation: str):
    """The ``nsim.metrics.tables.Table`` of an evaluation artifact."""
    from nsim.metrics.tables import Table

    art = ctx.store.get(ctx.store.resolve(evaluation, kind="evaluation"))
    meta = json.loads(art.file("evaluation.json").read_text())
    return Table.from_json(art.file(f"{meta['table']}.json").read_text())


# ---------------------------------------------------------------------------------- renders and lineage
@dataclasses.dataclass(frozen=True, eq=False)
class Lineage:
    """Where a render's world comes from. capture: the test-room capture (None: real data);
    aligned: the scene's world frame is the room's (ground-truth poses, or poses Sim(3)-fitted to the
    capture's ground-truth trajectory); note: that, in words."""

    capture: str | None
    aligned: bool
    note: str


@dataclasses.dataclass(frozen=True, eq=False)
class RenderData:
    id: str
    path: Path
    manifest: dict[str, Any]
    meta: dict[str, Any]
    lineage: Lineage

    @property
    def short(self) -> str:
        return self.id[:12]

    @property
    def mode(self) -> str:
        return self.meta["mode"]

    @property
    def frames(self) -> list[dict[str, Any]]:
        return self.meta["frames"]

    @property
    def humans(self) -> list[str]:
        """The human checkpoints in the render's order (person k is drawn by ``humans[k % len]``)."""
        ids = self.manifest["inputs"]
        keys = [k for k in ids if k.startswith("human") and k[5:].isdigit()]
        return [ids[k] for k in sorted(keys, key=lambda k: int(k[5:]))]

    def file(self, rel: str) -> Path:
        p = self.path / rel
        if not p.is_file():
            raise InputError(f"render {self.short}: has no file {rel} (render.json lists {len(self.frames)} frames)")
        return p

    def rig(self):
        from nsim.sensors.rig import Rig

        return Rig.from_resolved(json.loads(self.file("rig.json").read_text()))


def lineage(store, scene_id: str) -> Lineage:
    """Walk scene-checkpoint -> poses -> capture (see ``Lineage``)."""
    scene = store.get(scene_id)
    poses_id = scene.manifest.get("inputs", {}).get("poses")
    if poses_id is None:
        return Lineage(None, False, f"scene {scene_id[:12]} names no poses")
    src = store.get(poses_id)
    if src.kind == "capture":
        return Lineage(src.id, True, f"scene trained on capture {src.id[:12]} (ground-truth poses)")
    cap = src.manifest.get("inputs", {}).get("capture")
    if cap is None:
        return Lineage(None, False, f"scene trained on poses {src.id[:12]} of real data (no test-room ground truth)")
    summary = src.manifest.get("summary", {})
    ref = summary.get("file_inputs", {}).get("reference")
    gt_sha = store.get(cap).manifest["files"].get("gt_trajectory.tum", {}).get("sha256")
    # reconstruct records a file input as sha256 of the file's hex digest (nsim.workspace.store.sha256_path)
    gt_digests = {gt_sha, hashlib.sha256(gt_sha.encode()).hexdigest()} if gt_sha else set()
    aligned = summary.get("scale_source") == "reference" and ref in gt_digests
    how = ("Sim(3)-fitted to the capture's ground-truth trajectory" if aligned
           else "not fitted to the capture's ground-truth trajectory (its world frame is not the room's)")
    return Lineage(cap, aligned, f"scene trained on poses {src.id[:12]} reconstructed from capture {cap[:12]}, {how}")


def load_render(store, render_id: str) -> RenderData:
    art = store.get(render_id)
    try:
        meta = json.loads(art.file("render.json").read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"render {render_id[:12]}: render.json: {err}") from None
    manifest = art.manifest
    scene = manifest.get("inputs", {}).get("scene")
    if scene is None:
        raise InputError(f"render {render_id[:12]}: its manifest names no scene checkpoint")
    if not meta.get("frames"):
        raise InputError(f"render {render_id[:12]}: render.json lists no frames")
    return RenderData(render_id, art.path, manifest, meta, lineage(store, scene))


# ---------------------------------------------------------------------------------- reading frames
def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1]."""
    from nsim.io.images import read_image, to_float

    return to_float(read_image(path))


def read_depth(path: Path) -> np.ndarray:
    from nsim.io.exr import read_depth_exr

    try:
        return read_depth_exr(path)
    except InputError:
        raise
    except Exception as err:  # OpenEXR raises plain exceptions for damaged files
        raise InputError(f"{path}: cannot read depth EXR ({err})") from None


def as_captured(rgb: np.ndarray) -> np.ndarray:
    """A float image as a camera stores it: 8-bit, (H, W, 3) (grey replicated), back to float."""
    from nsim.io.images import to_float, to_uint8

    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=-1)
    return to_float(to_uint8(rgb))


def uint8_rgb(rgb: np.ndarray) -> np.ndarray:
    from nsim.io.images import to_uint8

    return to_uint8(as_captured(rgb))


def sensor_depth_gt(sensor, depth_range_m: np.ndarray) -> np.ndarray:
    """The sensor's exact depth for the oracle's ray ranges: its depth kind and valid range, no noise."""
    from nsim.sensors.depth import apply_depth_model

    exact = dataclasses.replace(sensor.depth, noise_abs_std_m=0.0, noise_rel_std=0.0, quantization_m=0.0)
    rng = np.nan_to_num(np.asarray(depth_range_m, dtype=np.float64), nan=np.inf)
    depth = apply_depth_model(sensor.depth_from_range(rng), exact, None)
    return np.where(np.isfinite(depth_range_m) | np.isinf(depth_range_m), depth, np.nan)


# ---------------------------------------------------------------------------------- the evaluator
@dataclasses.dataclass
class Result:
    """What a table function computed: the table, its per-frame records, extras and plots to draw."""

    table: Any
    records: list[Any]
    extras: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    ground_truth: dict[str, str] = dataclasses.field(default_factory=dict)
    image_records: list[Any] = dataclasses.field(default_factory=list)
    depth_records: list[Any] = dataclasses.field(default_factory=list)
    error_maps: list[tuple[str, np.ndarray, np.ndarray, np.ndarray | None]] = dataclasses.field(default_factory=list)
    slam_files: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)


class Evaluator:
    """Loaded renders, oracles (one per capture) and the helpers the table functions share."""

    def __init__(self, inputs: Inputs, cfg: Config, ctx: RunContext) -> None:
        self.inputs, self.cfg, self.ctx = inputs, cfg, ctx
        self.store = ctx.store
        self.renders = [load_render(self.store, r) for r in inputs.renders]
        self._oracles: dict[str, Any] = {}

    # -- checks
    def require_mode(self, mode: str, how: str) -> None:
        for r in self.renders:
            if r.mode != mode:
                raise InputError(f"render {r.short}: a {r.mode}-mode render; --table {self.cfg.table} needs "
                                 f"{mode}-mode renders ({how})")

    def require_room(self, r: RenderData) -> str:
        lin = r.lineage
        if lin.capture is None or not lin.aligned:
            raise InputError(f"render {r.short}: --table {self.cfg.table} needs the test room's ground truth, but "
                             f"{lin.note}")
        return lin.capture

    # -- the room
    def room_json(self, capture_id: str) -> dict[str, Any]:
        return json.loads(self.store.get(capture_id).file("room.json").read_text())

    def environment(self, r: RenderData) -> str:
        if r.lineage.capture is not None:
            cap = self.store.get(r.lineage.capture)
            room = self.room_json(cap.id)
            return str(room.get("preset") or cap.manifest.get("config", {}).get("room") or f"room {cap.id[:8]}")
        return f"render {r.id[:8]}"

    def oracle(self, capture_id: str):
        if capture_id not in self._oracles:
            from nsim.synth.oracle import RoomOracle
            from nsim.synth.room import RoomSpec

            self._oracles[capture_id] = RoomOracle(RoomSpec.from_dict(self.room_json(capture_id)["spec"]))
        return self._oracles[capture_id]

    # -- cameras of trajectory renders
    def camera_frames(self, r: RenderData, sensor: str) -> list:
        """Per rendered frame, the camera's ``transforms_json.Frame`` (intrinsics, cam_to_world, time)."""
        from nsim.io.transforms_json import read_transforms

        data = read_transforms(r.file(f"cameras/{sensor}.json"))
        by_path = {f.file_path: f for f in data.frames}
        out = []
        for f in r.frames:
            name = f"{sensor}/rgb/{f['index']:06d}.png"
            if name not in by_path:
                raise InputError(f"render {r.short}: cameras/{sensor}.json has {len(data.frames)} frames, and none for "
                                 f"frame {f['index']} of the {len(r.frames)} in render.json")
            out.append(by_path[name])
        return out

    def cameras(self, r: RenderData, want: str):
        """Rig cameras that emit ``want`` ("image" or "depth"), filtered by ``cfg.cameras``."""
        rig = r.rig()
        cams = [s for s in rig.cameras if (s.emits_image if want == "image" else s.emits_depth)]
        if self.cfg.cameras:
            unknown = [c for c in self.cfg.cameras if c not in [s.name for s in cams]]
            if unknown:
                raise InputError(f"cameras: render {r.short} has no {want} camera {', '.join(unknown)} "
                                 f"(has {', '.join(s.name for s in cams) or 'none'})")
            cams = [s for s in cams if s.name in self.cfg.cameras]
        if not cams:
            raise InputError(f"render {r.short}: its rig has no camera with {want} output")
        return cams

    def actor_seeds(self, r: RenderData) -> list[int | None]:
        """Per human checkpoint of the render: the appearance seed of the test-room actor it was trained
        from (its actor capture's ``poses.json`` meta ``actor_seed``), or None (trained from a data folder)."""
        seeds: list[int | None] = []
        for h in r.humans:
            cap = self.store.get(h).manifest.get("inputs", {}).get("capture")
            seed = None
            if cap is not None:
                poses = self.store.get(cap).path / "poses.json"
                if poses.is_file():
                    seed = json.loads(poses.read_text()).get("meta", {}).get("actor_seed")
            seeds.append(int(seed) if isinstance(seed, (int, float)) else None)
        return seeds

    def actors(self, r: RenderData):
        """``tick -> [PlacedActor]``: the render's people as test-room actors (None without people).

        Person k is posed exactly as the render poses it (``HumanSet.joint_transforms``: the run's
        position, heading, gait phase and height through the same skeleton and gait loop) and dressed
        like the actor its human checkpoint (``k mod M``) was trained from; a checkpoint trained from a
        data folder has no test-room actor: appearance seed k."""
        if not r.humans:
            return None
        from nsim.stages.render import HumanSet
        from nsim.synth.actor import Actor
        from nsim.synth.oracle import PlacedActor

        traj = r.manifest["inputs"].get("trajectory")
        if traj is None:
            raise InputError(f"render {r.short}: has human checkpoints but no trajectory")
        from nsim.io.npz import read_npz

        arrays = read_npz(self.store.get(traj).file("trajectory.npz"))
        people = HumanSet([], arrays, "cpu")
        seeds = self.actor_seeds(r)
        bodies: dict[int, Any] = {}

        def at(tick: int) -> list:
            placed = []
            for k, T in people.joint_transforms(tick):
                if k not in bodies:
                    seed = seeds[k % len(seeds)]
                    bodies[k] = Actor(float(arrays["height_m"][k]), seed=k if seed is None else seed)
                placed.append(PlacedActor(bodies[k], T, instance_id=k + 1))
            return placed

        return at

    def oracle_view(self, r: RenderData, frame, tick: int, actors):
        oracle = self.oracle(self.require_room(r))
        return oracle.render_gt(frame.camera, frame.cam_to_world, self.cfg.oracle_supersample,
                                actors=actors(tick) if actors is not None else None)

    def people_mask(self, r: RenderData, sensor: str, index: int, view) -> np.ndarray:
        """Pixels showing a person in the render's instance mask or in the ground truth."""
        from nsim.io.coco import read_instance_mask

        rel = f"{sensor}/mask/{index:06d}.png"
        if not (r.path / rel).is_file():
            raise InputError(f"region=people: render {r.short} has no person mask {rel} (rendered without --humans)")
        mask = np.asarray(read_instance_mask(r.path / rel)) > 0
        if view is not None:
            if view.instance_mask.shape != mask.shape:
                raise InputError(f"render {r.short}: {rel} is {mask.shape}, the ground truth {view.instance_mask.shape}")
            mask |= view.instance_mask > 0
        return mask

    def depth_cfg(self):
        from nsim.metrics.depth import DepthConfig

        return DepthConfig(self.cfg.depth_min_m, self.cfg.depth_max_m, self.cfg.median_scaling)

    def lpips_net(self) -> str | None:
        return None if self.cfg.lpips_net == "none" else self.cfg.lpips_net


def _masked_frames(group: str, masks: list[np.ndarray | None], *seqs: list) -> tuple[list, ...]:
    """Drop frames whose person mask is empty; InputError if that leaves none."""
    keep = [k for k, m in enumerate(masks) if m is None or m.any()]
    if not keep:
        raise InputError(f"{group}: region=people, but the person mask is empty in every frame")
    return tuple([s[k] for k in keep] for s in (masks, *seqs))


# ---------------------------------------------------------------------------------- scenes
def table_scenes(ev: Evaluator) -> Result:
    from nsim.io.transforms_json import read_transforms
    from nsim.metrics.paper_tables import depth_records, image_records, scenes_table

    cfg = ev.cfg
    ev.require_mode("poses", "nsim render --poses CAPTURE_OR_POSES --scene SCENE --set frames=heldout")
    if cfg.region != "all":
        raise InputError("region=people: the scenes table scores captured frames, which show no people")
    images, depths, extras, maps, gt_notes = [], [], [], [], {}
    groups: list[str] = []
    for r in ev.renders:
        group = ev.environment(r)
        if group in groups:
            group = f"{group} ({r.id[:8]})"
        groups.append(group)
        src = ev.store.get(r.manifest["inputs"]["poses"])
        frames_tf = read_transforms(src.file("transforms.json")).frames
        scale = float(r.manifest.get("config", {}).get("image_scale", 1.0))
        cap_depth: dict[str, Path] = {}
        if src.kind == "poses" and r.lineage.capture is not None:
            cap = ev.store.get(r.lineage.capture)
            for f in read_transforms(cap.file("transforms.json")).frames:
                if f.depth_file_path:
                    cap_depth[Path(f.file_path).name] = cap.path / f.depth_file_path
        preds, gts, pdepths, gdepths, numbers, dnumbers = [], [], [], [], [], []
        for f in r.frames:
            i = int(f["index"])
            if not 0 <= i < len(frames_tf):
                raise InputError(f"render {r.short}: frame {i} of render.json is not among the {len(frames_tf)} frames "
                                 f"of {src.kind} {src.id[:12]}")
            frame = frames_tf[i]
            pred = read_rgb(r.file(f"frames/rgb/{i:06d}.png"))
            pdepth = read_depth(r.file(f"frames/depth/{i:06d}.exr"))
            if cfg.scenes_ground_truth == "oracle":
                cam = frame.camera.scaled(scale) if scale != 1.0 else frame.camera
                view = ev.oracle(ev.require_room(r)).render_gt(cam, frame.cam_to_world, cfg.oracle_supersample)
                gt, gdepth = as_captured(view.rgb), view.depth_z
                gt_notes[group] = "the test room's oracle at the rendered cameras and poses"
            else:
                gt = read_rgb(src.path / frame.file_path) if (src.path / frame.file_path).is_file() else None
                if gt is None:
                    raise InputError(f"{src.kind} {src.id[:12]}: frame {i} image {frame.file_path} is missing")
                if src.kind == "capture":
                    gdepth = read_depth(src.path / frame.depth_file_path) if frame.depth_file_path else None
                    gt_notes[group] = f"capture {src.id[:12]}: its own images and depth EXRs"
                else:
                    p = cap_depth.get(Path(frame.file_path).name)
                    gdepth = read_depth(p) if p is not None else None
                    gt_notes[group] = (f"poses {src.id[:12]}: its images" +
                                       (f"; depth: capture {r.lineage.capture[:12]}'s EXRs" if cap_depth else
                                        "; no ground-truth depth (real data)"))
            if pred.shape != gt.shape:
                raise InputError(f"{group} frame {i}: rendered image is {pred.shape[1]}x{pred.shape[0]} but the ground "
                                 f"truth {gt.shape[1]}x{gt.shape[0]} (render at image_scale 1, or use "
                                 "scenes_ground_truth=oracle)")
            preds.append(pred)
            gts.append(gt)
            numbers.append(i)
            if gdepth is not None:
                pdepths.append(pdepth)
                gdepths.append(gdepth)
                dnumbers.append(i)
            extras.append({"group": group, "frame": i, "render": r.id, "name": f.get("name"),
                           "gt_image": frame.file_path})
        images += image_records(group, preds, gts, ev.lpips_net(), frames=numbers, device=ev.ctx.device)
        if gdepths:
            depths += depth_records(group, pdepths, gdepths, ev.depth_cfg(), frames=dnumbers)
            maps += [(group, dnumbers[k], pdepths[k], gdepths[k], None) for k in range(min(cfg.error_maps, len(gdepths)))]
    table = scenes_table(images, depths, ev.depth_cfg())
    notes = [f"ground truth, {g}: {n}" for g, n in gt_notes.items()]
    notes += [f"{ev.environment(r)}: {r.lineage.note}" for r in ev.renders]
    table = _with_notes(table, [*notes, *_image_notes(ev)])
    return Result(table, [*images, *depths], extras, gt_notes, images, depths, maps)


def _image_notes(ev: Evaluator) -> list[str]:
    out = ["PSNR and SSIM on 8-bit sRGB images in [0, 1] (SSIM: 11x11 Gaussian window, sigma 1.5)"]
    if ev.cfg.lpips_net != "none":
        out.append(f"LPIPS: {ev.cfg.lpips_net} backbone (v0.1 linear heads)")
    return out


def _with_notes(table, notes: list[str]):
    return dataclasses.replace(table, notes=(*table.notes, *notes))


# ---------------------------------------------------------------------------------- spot-rgb / spot-depth
def _spot_frames(ev: Evaluator, want: str):
    """Yield ``(render, sensor, [(index, pred, gt, mask)])`` per render and camera."""
    ev.require_mode("trajectory", "nsim render --trajectory RUN --rig configs/robots/spot.yaml")
    for r in ev.renders:
        ev.require_room(r)
        actors = ev.actors(r)
        for s in ev.cameras(r, want):
            rows = []
            for f, cam in zip(r.frames, ev.camera_frames(r, s.name), strict=True):
                i = int(f["index"])
                if (cam.camera.height, cam.camera.width) != s.ray_shape:
                    raise InputError(f"render {r.short}: cameras/{s.name}.json frame {i} is "
                                     f"{cam.camera.width}x{cam.camera.height}, the rig's {s.name} "
                                     f"{s.ray_shape[1]}x{s.ray_shape[0]}")
                view = ev.oracle_view(r, cam, i, actors)
                mask = ev.people_mask(r, s.name, i, view) if ev.cfg.region == "people" else None
                if want == "image":
                    pred = read_rgb(r.file(f"{s.name}/rgb/{i:06d}.png"))
                    gt = as_captured(s.expose(view.rgb))
                else:
                    pred = read_depth(r.file(f"{s.name}/depth/{i:06d}.exr"))
                    gt = sensor_depth_gt(s, view.depth_range)
                if pred.shape != gt.shape:
                    raise InputError(f"render {r.short}: {s.name} frame {i} is {pred.shape[1]}x{pred.shape[0]} but the "
                                     f"ground truth {gt.shape[1]}x{gt.shape[0]}")
                rows.append((i, pred, gt, mask))
            yield r, s, rows


def table_spot_rgb(ev: Evaluator) -> Result:
    from nsim.metrics.paper_tables import image_records, spot_rgb_table

    records, extras = [], []
    for r, s, rows in _spot_frames(ev, "image"):
        masks, numbers, preds, gts = _masked_frames(s.name, [m for *_, m in rows], [x[0] for x in rows],
                                                    [x[1] for x in rows], [x[2] for x in rows])
        records += image_records(s.name, preds, gts, ev.lpips_net(), masks=masks if ev.cfg.region == "people" else None,
                                 frames=numbers, device=ev.ctx.device)
        extras += [{"group": s.name, "frame": i, "render": r.id} for i in numbers]
    table = spot_rgb_table(records)
    notes = ["ground truth: the test room's oracle at each frame's camera and pose (cameras/<camera>.json), "
             f"{ev.cfg.oracle_supersample}x{ev.cfg.oracle_supersample} supersampled, through the camera's exposure "
             "and colour model, 8-bit", *_region_notes(ev), *_image_notes(ev),
             *sorted({f"render {r.short}: {r.lineage.note}" for r in ev.renders})]
    gt = {r.id: "test-room oracle at the rendered camera poses" for r in ev.renders}
    return Result(_with_notes(table, notes), records, extras, gt, image_records=records)


def _region_notes(ev: Evaluator) -> list[str]:
    return (["only pixels showing a person (render mask or ground truth); frames without one are left out"]
            if ev.cfg.region == "people" else [])


def table_spot_depth(ev: Evaluator) -> Result:
    from nsim.metrics.paper_tables import depth_records, spot_depth_table

    records, extras, maps = [], [], []
    too_near_total = 0
    for r, s, rows in _spot_frames(ev, "depth"):
        preds = []
        for i, pred, gt, _ in rows:
            bad = np.isnan(pred) & np.isfinite(gt)
            n_near = int(bad.sum())
            if n_near and s.depth.min_m > 0.0:
                pred = np.where(bad, np.float32(s.depth.min_m), pred)  # the sensor's "too near" reading
                too_near_total += n_near
            preds.append(pred)
            extras.append({"group": s.name, "frame": i, "render": r.id, "too_near_px": n_near,
                           "depth_kind": s.depth.kind})
        masks, numbers, preds, gts = _masked_frames(s.name, [m for *_, m in rows], [x[0] for x in rows], preds,
                                                    [x[2] for x in rows])
        records += depth_records(s.name, preds, gts, ev.depth_cfg(),
                                 masks=masks if ev.cfg.region == "people" else None, frames=numbers)
        maps += [(s.name, numbers[k], preds[k], gts[k], masks[k]) for k in range(min(ev.cfg.error_maps, len(numbers)))]
    table = spot_depth_table(records, ev.depth_cfg())
    notes = ["ground truth: the test room's oracle depth (the camera's depth kind, z-depth for Spot) at each frame's "
             "camera pose, inside the camera's valid range, without noise or quantisation",
             f"simulated readings reported invalid (NaN: nearer than the camera's minimum range) where the ground truth "
             f"is valid count as that minimum ({too_near_total} px)", *_region_notes(ev),
             *sorted({f"render {r.short}: {r.lineage.note}" for r in ev.renders})]
    gt = {r.id: "test-room oracle depth at the rendered camera poses" for r in ev.renders}
    return Result(_with_notes(table, notes), records, extras, gt, depth_records=records, error_maps=maps)


# ---------------------------------------------------------------------------------- slam
def table_slam(ev: Evaluator) -> Result:
    from nsim.io.tum import Trajectory
    from nsim.metrics.paper_tables import SlamRecord, slam_table
    from nsim.metrics.tables import NotAvailable

    cfg = ev.cfg.slam
    ev.require_mode("trajectory", "nsim render --trajectory RUN --rig configs/robots/spot.yaml")
    records, extras, files = [], [], {}
    for r in ev.renders:
        ev.require_room(r)
        rig = r.rig()
        if cfg.camera not in rig.names or rig[cfg.camera].type != "camera" or not rig[cfg.camera].emits_image:
            raise InputError(f"slam.camera: render {r.short}'s rig has no image camera {cfg.camera!r} "
                             f"(has {', '.join(s.name for s in rig.cameras if s.emits_image)})")
        s = rig[cfg.camera]
        seq = cfg.camera if len(ev.renders) == 1 else f"{ev.environment(r)}/{cfg.camera} ({r.id[:8]})"
        pairs = list(zip(r.frames, ev.camera_frames(r, s.name), strict=True))[:: cfg.stride]
        if cfg.max_frames is not None:
            pairs = pairs[: cfg.max_frames]
        times = np.array([float(f["time_s"]) for f, _ in pairs])
        gt_times = np.array([c.timestamp_s if c.timestamp_s is not None else np.nan for _, c in pairs], dtype=float)
        if not np.isfinite(gt_times).any():
            raise InputError(f"render {r.short}: cameras/{s.name}.json has no timestamps: no ground-truth trajectory")
        common = np.abs(gt_times[:, None] - times[None, :]).min(axis=0) <= cfg.max_dt_s
        if not common.any():
            raise InputError(f"render {r.short}: the ground-truth poses of {s.name} (cameras/{s.name}.json, t = "
                             f"{np.nanmin(gt_times):g}..{np.nanmax(gt_times):g} s) share no timestamp with the frames "
                             f"(t = {times.min():g}..{times.max():g} s, within {cfg.max_dt_s:g} s)")
        ok = np.isfinite(gt_times)
        truth = Trajectory.from_poses(gt_times[ok], np.stack([c.cam_to_world for (_, c), k in zip(pairs, ok, strict=True)
                                                               if k]))
        actors = ev.actors(r)
        sim = [uint8_rgb(read_rgb(r.file(f"{s.name}/rgb/{int(f['index']):06d}.png"))) for f, _ in pairs]
        real = [uint8_rgb(s.expose(ev.oracle_view(r, c, int(f["index"]), actors).rgb)) for f, c in pairs]
        runs = {side: _slam_side(frames, times, cfg, ev.ctx.seed) for side, frames in (("real", real), ("sim", sim))}
        ates: dict[str, Any] = {}
        for side, (traj, _fraction, reason) in runs.items():
            ates[side] = NotAvailable(reason) if traj is None else _ate_or_na(truth, traj, cfg, side)
        records.append(SlamRecord(seq, ates["real"], ates["sim"], runs["real"][1], runs["sim"][1]))
        files[seq] = {"ground_truth": truth, **{side: run[0] for side, run in runs.items() if run[0] is not None}}
        extras.append({"sequence": seq, "render": r.id, "camera": s.name, "frames": len(pairs),
                       **{f"{side}_failure": run[2] for side, run in runs.items() if run[2]}})
    table = slam_table(records, cfg.alignment)
    every = "every rendered frame" if cfg.stride == 1 else f"every {cfg.stride}th rendered frame"
    notes = [f"camera {cfg.camera}, {every}"
             + (f", at most {cfg.max_frames}" if cfg.max_frames else "")
             + f"; pycolmap incremental SfM ({cfg.matcher} matching, {cfg.camera_model} intrinsics estimated)",
             "real frames: the test room's oracle at the same camera poses; ground truth: the camera's poses "
             "(cameras/<camera>.json)", *sorted({f"render {r.short}: {r.lineage.note}" for r in ev.renders})]
    gt = {r.id: f"camera poses cameras/{cfg.camera}.json; real frames from the test-room oracle" for r in ev.renders}
    return Result(_with_notes(table, notes), records, extras, gt, slam_files=files)


def _slam_side(frames: list[np.ndarray], times: np.ndarray, cfg: SlamConfig, seed: int):
    """``(trajectory | None, registered fraction | None, failure reason | None)`` of SfM on one side."""
    from nsim.metrics.slam import run_colmap_slam
    from nsim.sfm.colmap import SfmOptions

    if len(frames) < 3:
        return None, None, f"SfM needs at least 3 frames, the sequence has {len(frames)}"
    options = SfmOptions(camera_model=cfg.camera_model, matcher=cfg.matcher, overlap=cfg.overlap,
                         loop_detection=cfg.matcher == "sequential" and len(frames) >= 20,
                         max_features=cfg.max_features, seed=seed, min_registered_fraction=cfg.min_registered_fraction)
    with tempfile.TemporaryDirectory(prefix="nsim-eval-slam-") as work:
        try:
            run = run_colmap_slam(frames, times.tolist(), work, options)
        except InputError as err:
            return None, None, f"SfM failed: {err}".replace(str(work), "<work>")
    return run.trajectory, run.registered_fraction, None


def _ate_or_na(truth, traj, cfg: SlamConfig, side: str):
    from nsim.metrics.tables import NotAvailable
    from nsim.metrics.trajectory import ate

    try:
        return ate(truth, traj, cfg.alignment, cfg.max_dt_s).rmse_m
    except InputError as err:
        return NotAvailable(f"ATE of SfM on {side} frames: {err}")


# ---------------------------------------------------------------------------------- detection
def _detection_columns():
    from nsim.metrics.paper_tables import detection_table

    return detection_table([{"scene": "-", "frame": 0, "n_sim": 0, "n_real": 0}]).columns


def _detector(ev: Evaluator):
    """``(name, image -> Detections)`` for hog / onnx; None for coco."""
    from nsim.metrics import detection as det

    cfg = ev.cfg.detection
    if cfg.detector == "hog":
        hog = det.HogPeopleDetector(det.HogConfig(upscale=cfg.hog_upscale, hit_threshold=cfg.hog_hit_threshold))
        return f"OpenCV HOG people detector (upscale {cfg.hog_upscale:g})", hog
    if cfg.detector == "onnx":
        if ev.inputs.onnx is None:
            raise InputError("detection.detector: onnx needs --onnx WEIGHTS")
        onnx = det.OnnxDetector(ev.inputs.onnx, det.OnnxConfig(decode=det.YoloDecodeConfig(classes=(det.PERSON_LABEL,))))
        return f"ONNX {ev.inputs.onnx.name} (person class)", onnx
    if ev.inputs.coco_sim is None or ev.inputs.coco_real is None:
        raise InputError("detection.detector: coco needs --coco-sim and --coco-real")
    return "COCO JSON given", None


def _coco_lookup(boxes: dict, name: str):
    from nsim.metrics.detection import Detections

    for key in (name, Path(name).name):
        if key in boxes:
            return boxes[key]
    return Detections.empty()


def upright_turns(sensor) -> int:
    """Quarter turns (``np.rot90``'s k) that bring the world's up nearest to the image's up for a camera
    on a level body (body z up): 0 for an upright camera; Spot's front cameras (rolled ~90 deg) 3, its
    right camera (mounted upside down) 2 -- how Spot's SDK rotates them for display."""
    up = np.asarray(sensor.sensor_to_body)[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # in the optical frame (y down)
    dx, dy = float(up[0]), float(up[1])
    best, score = 0, -math.inf
    for k in range(4):
        if -dy > score + 1e-9:
            best, score = k, -dy
        dx, dy = dy, -dx  # np.rot90(image, 1) turns the image direction (dx, dy) into (dy, -dx)
    return best


def _people_notes(people: list[dict[str, Any]]) -> list[str]:
    """One line: in how many frames people are in view on each side, and how well the person masks agree."""
    if not people:
        return []
    n = len(people)
    sim = sum(p["people_px_sim"] > 0 for p in people)
    real = sum(p["people_px_real"] > 0 for p in people)
    ious = [p["mask_iou"] for p in people if p["mask_iou"] is not None]
    line = (f"people in view: {sim} of {n} simulated frames (render person masks), {real} of {n} real frames "
            f"(oracle actors)")
    if ious:
        line += f"; person mask IoU sim vs real {np.mean(ious):.3f} (mean over the {len(ious)} frames showing one)"
    return [line]


def table_detection(ev: Evaluator) -> Result:
    from nsim.io.coco import read_instance_mask
    from nsim.metrics.detection import MatchConfig, compare_detections, read_coco_detections
    from nsim.metrics.paper_tables import detection_table
    from nsim.metrics.tables import NotAvailable, Table

    cfg = ev.cfg.detection
    ev.require_mode("trajectory", "nsim render --trajectory RUN --rig configs/robots/spot.yaml --humans ...")
    name, detect = _detector(ev)
    coco = None
    if detect is None:
        coco = (read_coco_detections(ev.inputs.coco_sim), read_coco_detections(ev.inputs.coco_real))
    no_people = [r for r in ev.renders if not r.humans]
    if coco is None and no_people:
        r = no_people[0]
        reason = (f"render {r.short} has no people (rendered without --humans): the detection experiment compares "
                  "person boxes on simulated and real frames")
        cams = [s.name for s in ev.cameras(r, "image")]
        columns = _detection_columns()
        rows = tuple({c.name: (cam if c.name == "Scene" else NotAvailable(reason)) for c in columns} for cam in cams)
        table = Table("Detection on simulated vs real frames", columns, rows, (f"detector: {name}",),
                      label="tab:detection")
        return Result(table, [], [{"render": r.id, "not_available": reason}], {r.id: "none (no people)"})
    records, extras, people = [], [], []
    turned: dict[str, int] = {}
    match = MatchConfig(iou_threshold=cfg.iou_threshold)
    for r in ev.renders:
        actors = ev.actors(r) if coco is None else None
        for s in ev.cameras(r, "image"):
            turns = upright_turns(s) if cfg.upright and coco is None else 0
            if turns:
                turned[s.name] = turns
            sims, reals, numbers, frame_extras = [], [], [], []
            for f, cam in zip(r.frames, ev.camera_frames(r, s.name), strict=True):
                i = int(f["index"])
                rel = f"{s.name}/rgb/{i:06d}.png"
                extra = {"group": s.name, "frame": i, "render": r.id}
                if coco is not None:
                    sims.append(_coco_lookup(coco[0], rel))
                    reals.append(_coco_lookup(coco[1], rel))
                else:
                    sim = uint8_rgb(read_rgb(r.file(rel)))
                    view = ev.oracle_view(r, cam, i, actors)
                    real = uint8_rgb(s.expose(view.rgb))
                    if sim.shape != real.shape:
                        raise InputError(f"render {r.short}: {rel} is {sim.shape[1]}x{sim.shape[0]} but the ground truth "
                                         f"{real.shape[1]}x{real.shape[0]}")
                    sim_mask = np.asarray(read_instance_mask(r.file(f"{s.name}/mask/{i:06d}.png"))) > 0
                    real_mask = view.instance_mask > 0
                    if sim_mask.shape != real_mask.shape:
                        raise InputError(f"render {r.short}: {s.name}/mask/{i:06d}.png is {sim_mask.shape[1]}x"
                                         f"{sim_mask.shape[0]} but the frame {real.shape[1]}x{real.shape[0]}")
                    union = int((sim_mask | real_mask).sum())
                    extra.update(people_px_sim=int(sim_mask.sum()), people_px_real=int(real_mask.sum()),
                                 mask_iou=float((sim_mask & real_mask).sum() / union) if union else None,
                                 upright_turns=turns)
                    people.append(extra)
                    sims.append(detect(np.ascontiguousarray(np.rot90(sim, turns))))
                    reals.append(detect(np.ascontiguousarray(np.rot90(real, turns))))
                numbers.append(i)
                frame_extras.append(extra)
            comparison = compare_detections(sims, reals, match)
            for k, fm in enumerate(comparison.frames):
                records.append({"scene": s.name, "frame": numbers[k], "n_sim": fm.n_pred, "n_real": fm.n_ref,
                                "ious": tuple(float(v) for v in fm.ious), "detector": name})
                extras.append(frame_extras[k])
    table = detection_table(records, cfg.iou_threshold)
    if coco is None:
        seeds = {h: seed for r in ev.renders for h, seed in zip(r.humans, ev.actor_seeds(r), strict=True)}
        dressed = ", ".join(f"checkpoint {h[:12]}: actor seed {seed}" if seed is not None
                            else f"checkpoint {h[:12]}: seed = person index (no test-room actor)"
                            for h, seed in seeds.items())
        notes = ["real frames: the test room's oracle at the same camera poses with the simulated people as test-room "
                 "actors (nsim.synth.actor.Actor), posed like the render's (the run's positions, headings, gait phases "
                 f"and heights) and dressed like the actor each person's human checkpoint was trained from ({dressed})"]
        if turned:
            notes.append("frames turned upright before detecting (boxes in the turned frames): "
                         + ", ".join(f"{cam} {90 * k} deg counter-clockwise" for cam, k in turned.items()))
        notes += _people_notes(people)
    else:
        notes = [f"detections from {ev.inputs.coco_sim.name} (sim) and {ev.inputs.coco_real.name} (real)"]
    gt = {r.id: notes[0] for r in ev.renders}
    return Result(_with_notes(table, notes), records, extras, gt)


TABLE_FUNCTIONS = {"scenes": table_scenes, "spot-rgb": table_spot_rgb, "spot-depth": table_spot_depth,
                   "slam": table_slam, "detection": table_detection}


# ---------------------------------------------------------------------------------- writing
def _jsonable(value: Any) -> Any:
    from nsim.metrics.tables import NotAvailable

    if isinstance(value, NotAvailable):
        return {"not_available": value.reason}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else {"float": str(v)}
    if isinstance(value, np.integer):
        return int(value)
    return value


def write_result(out_dir: Path, cfg: Config, inputs: Inputs, ev: Evaluator, result: Result) -> None:
    from nsim.io.tum import write_tum
    from nsim.metrics import paper_tables as pt

    table = result.table
    table.write_all(out_dir, cfg.table)
    (out_dir / "records.json").write_text(json.dumps(
        {"table": cfg.table, "records": _jsonable(result.records), "frames": _jsonable(result.extras)},
        indent=1, sort_keys=True, allow_nan=False) + "\n")
    meta = {"table": cfg.table, "renders": list(inputs.renders), "ground_truth": result.ground_truth,
            "lineage": {r.id: r.lineage.note for r in ev.renders}, "notes": list(table.notes),
            "records": len(result.records)}
    (out_dir / "evaluation.json").write_text(json.dumps(_jsonable(meta), indent=1, sort_keys=True) + "\n")
    plots = out_dir / "plots"
    for records, metrics in ((result.image_records, (("psnr_db", "PSNR [dB]"), ("ssim", "SSIM"), ("lpips", "LPIPS"))),
                             (result.depth_records, (("abs_rel", "AbsRel"), ("delta_1_25", "δ<1.25")))):
        for metric, label in metrics if records else ():
            if _all_finite(getattr(r, metric) for r in records):
                _try_plot(pt.plot_per_frame, plots / f"{metric}_per_frame.png", records, metric, label)
            else:
                log.info("plot %s skipped: a value is infinite (a frame equal to its ground truth)", metric)
    body = table.rows[: len(table.rows) - table.footer_rows]
    bars = [c.name for c in table.columns if c.direction and _all_finite(r.get(c.name) for r in body)]
    if bars and body:
        pt.plot_bars(plots / "bars.png", table, bars)
    for group, frame, pred, gt, mask in result.error_maps:
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in group)
        _try_plot(pt.plot_depth_error_map, plots / "depth_error" / f"{safe}_{frame:06d}.png", pred, gt,
                  ev.depth_cfg(), mask)
    for seq, trajs in result.slam_files.items():
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in seq)
        (out_dir / "slam" / safe).mkdir(parents=True, exist_ok=True)
        for side, traj in trajs.items():
            write_tum(out_dir / "slam" / safe / f"{side}.tum", traj)


def _all_finite(values) -> bool:
    """No value is +-inf (n/a and None are fine: the plots leave gaps for them)."""
    return not any(isinstance(v, (int, float)) and math.isinf(v) for v in values)


def _try_plot(fn, path: Path, *args) -> None:
    """A plot that has nothing to show (every value n/a) is skipped, not an error."""
    try:
        fn(path, *args)
    except InputError as err:
        log.info("plot %s skipped: %s", path.name, err)
