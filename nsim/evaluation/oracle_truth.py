"""``OracleTruth``: the test room's oracle as ground truth (``nsim.evaluation.truth``).

Renders of a scene trained on a test-room capture (``nsim capture synth``) are scored against the
room itself: ``RoomOracle`` rendered at each frame's camera and pose (``cameras/<sensor>.json`` of a
trajectory-mode render), through the sensor's model:

* images: the camera's exposure and grey model, 8-bit (``as_captured``), ``oracle_supersample``
  rays per pixel side;
* depth: the camera's depth kind and valid range, without noise or quantisation
  (``sensor_depth_gt``); simulated readings the sensor reports as NaN (nearer than its minimum
  range) at pixels where the ground truth is valid count as that minimum;
* people: the render's people as test-room actors (``actors``), posed as the render poses them
  and dressed like the actor each human checkpoint was trained from;
* SLAM: the oracle's frames at the camera's poses, the ground truth those poses.

The room is found through the render's lineage (render -> scene-checkpoint -> poses -> capture,
``nsim.evaluation.renders.lineage``); a render whose world is not the room's is one line.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Iterator
from typing import Any

import numpy as np

from nsim.errors import InputError
from nsim.evaluation.evaluate_config import Config
from nsim.evaluation.inputs import EvaluationInputs
from nsim.evaluation.renders import RenderData, as_captured, read_depth, read_rgb, require_mode, uint8_rgb
from nsim.evaluation.truth import FramePair, GroundTruth, SensorFrames, SlamSequence, lidar_rows
from nsim.rendering.default_look import DEFAULT_LOOK_NAME, DEFAULT_LOOK_SEED

log = logging.getLogger(__name__)

TRAJECTORY_HOW = "nsim render --trajectory RUN --rig nsim/configs/robots/spot.yaml"


def sensor_depth_gt(sensor, depth_range_m: np.ndarray) -> np.ndarray:
    """The sensor's exact depth for the oracle's ray ranges: its depth kind and valid range, no noise."""
    from nsim.sensors.depth_model import apply_depth_model

    exact = dataclasses.replace(sensor.depth, noise_abs_std_m=0.0, noise_rel_std=0.0, quantization_m=0.0)
    rng = np.nan_to_num(np.asarray(depth_range_m, dtype=np.float64), nan=np.inf)
    depth = apply_depth_model(sensor.depth_from_range(rng), exact, None)
    return np.where(np.isfinite(depth_range_m) | np.isinf(depth_range_m), depth, np.nan)


class OracleTruth(GroundTruth):
    """The test room's oracle (module docstring); for ``scenes`` also the captured frames."""

    source = "oracle"

    def __init__(self, inputs: EvaluationInputs, cfg: Config) -> None:
        super().__init__(inputs, cfg)
        self._oracles: dict[str, Any] = {}
        self._too_near_total = 0  # depth_frames: simulated px counted as the minimum range (for the notes)
        self._no_return: dict[str, tuple[int, int, list[float]]] = {}  # depth_frames: camera -> no-return px, px, depths

    # -- checks
    def require_room(self, r: RenderData) -> str:
        lin = r.lineage
        if lin.capture is None or not lin.aligned:
            raise InputError(f"render {r.short}: --table {self.cfg.table} needs the test room's ground truth, but "
                             f"{lin.note}")
        return lin.capture

    # -- the room
    def room_json(self, capture_id: str) -> dict[str, Any]:
        return json.loads(self.artifacts.get(capture_id).file("room.json").read_text())

    def environment(self, r: RenderData) -> str:
        if r.lineage.capture is not None:
            cap = self.artifacts.get(r.lineage.capture)
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

    # -- people
    def actor_seeds(self, r: RenderData) -> list[int | None]:
        """Per human checkpoint of the render: the appearance seed of the test-room actor it was trained
        from (its actor capture's ``poses.json`` meta ``actor_seed``), or None (trained from a data folder)."""
        seeds: list[int | None] = []
        for h in r.humans:
            cap = self.artifacts.get(h).manifest.get("inputs", {}).get("capture")
            seed = None
            if cap is not None:
                poses = self.artifacts.get(cap).path / "poses.json"
                if poses.is_file():
                    seed = json.loads(poses.read_text()).get("meta", {}).get("actor_seed")
            seeds.append(int(seed) if isinstance(seed, (int, float)) else None)
        return seeds

    def actors(self, r: RenderData):
        """``tick -> [PlacedActor]``: the render's people as test-room actors (None without people).

        Person k is posed exactly as the render poses it (``HumanSet.joint_transforms``: the run's
        position, heading, gait phase and height through the same skeleton and gait loop) and dressed
        like the actor its human checkpoint was trained from (the render's choice: its summary's
        ``people_checkpoints``; k mod M for renders from before it was recorded); a checkpoint trained from a
        data folder has no test-room actor: appearance seed k. A person drawn with the default look is that
        actor exactly (``nsim.rendering.default_look``: appearance seed ``DEFAULT_LOOK_SEED``)."""
        if not r.has_people:
            return None
        drew = r.manifest.get("summary", {}).get("people_checkpoints")  # what the render chose (person_checkpoints)
        from nsim.io.npz import read_npz
        from nsim.rendering.people import HumanSet, default_checkpoint
        from nsim.synth.actor import Actor
        from nsim.synth.oracle import PlacedActor

        traj = r.manifest["inputs"].get("trajectory")
        if traj is None:
            raise InputError(f"render {r.short}: has human checkpoints but no trajectory")
        arrays = read_npz(self.artifacts.get(traj).file("trajectory.npz"))
        people = HumanSet([], arrays, "cpu")
        seeds = self.actor_seeds(r) + [DEFAULT_LOOK_SEED]  # the default look: the last entry
        humans = list(r.humans)
        n = int(np.asarray(arrays["height_m"]).shape[0])
        chosen = ([len(humans) if h == DEFAULT_LOOK_NAME else humans.index(h) for h in drew] if drew
                  else [default_checkpoint(k, len(humans)) for k in range(n)])
        bodies: dict[int, Any] = {}

        def at(tick: int) -> list:
            placed = []
            for k, T in people.joint_transforms(tick):
                if k not in bodies:
                    seed = seeds[chosen[k]]
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
            raise InputError(f"region=people: render {r.short} has no person mask {rel} (its run has none, or it was rendered with --no-people)")
        mask = np.asarray(read_instance_mask(r.path / rel)) > 0
        if view is not None:
            if view.instance_mask.shape != mask.shape:
                raise InputError(f"render {r.short}: {rel} is {mask.shape}, the ground truth {view.instance_mask.shape}")
            mask |= view.instance_mask > 0
        return mask

    # -- every check the renders' files decide, for all renders before the first frame is scored
    def check(self, table: str) -> None:
        """What ``table`` needs of every render, checked for all renders before any ground truth is rendered or any
        frame scored (the tables score render after render; a second render's bad input used to fail after the
        first's scoring, or its SfM): the mode, the test room, the cameras or LiDARs (``cameras``, ``slam.camera``),
        each frame's camera record and file, ``robot.tum``; the same one-line errors the tables raise. ``scenes``
        checks its renders itself (``nsim.evaluation.evaluate_tables.table_scenes``)."""
        if table == "scenes":
            return
        if table == "detection":  # (the detection table's own words)
            require_mode(self.renders, "trajectory", table, TRAJECTORY_HOW + " --humans ...")
        self._require_trajectory()
        coco = self.cfg.detection.detector == "coco"
        if table == "detection" and self.detection_unavailable(coco) is not None:
            return  # the table is n/a: no frame is scored
        people = self.cfg.region == "people"
        for r in self.renders:
            if table == "slam":
                self._slam_plan(r)
                continue
            if not (table == "detection" and coco):
                self.require_room(r)
            if table == "lidar":
                lidars = r.rig().lidars
                if not lidars:
                    raise InputError(f"render {r.short}: its rig has no LiDAR to score (--table lidar)")
                from nsim.io.tum import read_tum

                body = read_tum(r.file("robot.tum")).poses_se3()
                if len(body) != len(r.frames):
                    raise InputError(f"render {r.short}: robot.tum has {len(body)} poses for its {len(r.frames)} "
                                     "frames")
                for s in lidars:
                    for f in r.frames:
                        r.file(f"{s.name}/scan/{int(f['index']):06d}.exr")
                continue
            want = "depth" if table == "spot-depth" else "image"
            for s in self.cameras(r, want):
                for f, cam in zip(r.frames, self.camera_frames(r, s.name), strict=True):
                    i = int(f["index"])
                    if table != "detection" and (cam.camera.height, cam.camera.width) != s.ray_shape:
                        raise InputError(f"render {r.short}: cameras/{s.name}.json frame {i} is "
                                         f"{cam.camera.width}x{cam.camera.height}, the rig's {s.name} "
                                         f"{s.ray_shape[1]}x{s.ray_shape[0]}")
                    r.file(f"{s.name}/depth/{i:06d}.exr" if want == "depth" else f"{s.name}/rgb/{i:06d}.png")
                    mask = f"{s.name}/mask/{i:06d}.png"
                    if table == "detection" and not coco:
                        r.file(mask)
                    elif people and table != "detection" and not (r.path / mask).is_file():
                        raise InputError(f"region=people: render {r.short} has no person mask {mask} (its run has "
                                         "none, or it was rendered with --no-people)")

    # -- the interface
    def _require_trajectory(self) -> None:
        require_mode(self.renders, "trajectory", self.cfg.table, TRAJECTORY_HOW)

    def _spot_frames(self, want: str) -> Iterator[SensorFrames]:
        """Per render and camera, ``FramePair(index, pred, gt, mask)`` of every frame."""
        self._require_trajectory()
        for r in self.renders:
            self.require_room(r)
            actors = self.actors(r)
            for s in self.cameras(r, want):
                rows = []
                for f, cam in zip(r.frames, self.camera_frames(r, s.name), strict=True):
                    i = int(f["index"])
                    if (cam.camera.height, cam.camera.width) != s.ray_shape:
                        raise InputError(f"render {r.short}: cameras/{s.name}.json frame {i} is "
                                         f"{cam.camera.width}x{cam.camera.height}, the rig's {s.name} "
                                         f"{s.ray_shape[1]}x{s.ray_shape[0]}")
                    view = self.oracle_view(r, cam, i, actors)
                    mask = self.people_mask(r, s.name, i, view) if self.cfg.region == "people" else None
                    if want == "image":
                        pred = read_rgb(r.file(f"{s.name}/rgb/{i:06d}.png"))
                        gt = as_captured(s.expose(view.rgb))
                    else:
                        pred = read_depth(r.file(f"{s.name}/depth/{i:06d}.exr"))
                        gt = sensor_depth_gt(s, view.depth_range)
                    if pred.shape != gt.shape:
                        raise InputError(f"render {r.short}: {s.name} frame {i} is {pred.shape[1]}x{pred.shape[0]} but "
                                         f"the ground truth {gt.shape[1]}x{gt.shape[0]}")
                    rows.append(FramePair(i, pred, gt, mask))
                yield SensorFrames(r, s.name, rows, np.asarray(s.sensor_to_body))

    def image_frames(self) -> Iterator[SensorFrames]:
        yield from self._spot_frames("image")

    def depth_frames(self) -> Iterator[SensorFrames]:
        self._too_near_total = 0
        self._no_return = {}
        lo, hi = self.cfg.depth_min_m, self.cfg.depth_max_m
        for group in self._spot_frames("depth"):
            s = group.render.rig()[group.sensor]
            rows = []
            for p in group.frames:
                pred = p.sim
                bad = np.isnan(pred) & np.isfinite(p.real)
                n_near = int(bad.sum())
                # no return (+inf: the scene model is empty along the ray) where the truth has a surface: scored as
                # the maximum depth; a hole in the scene, said in the notes per camera (issue 42's `left` camera)
                hole = np.isposinf(pred) & np.isfinite(p.real) & (p.real >= lo) & (p.real <= hi)
                n_hole = int(hole.sum())
                count, px, depths = self._no_return.get(group.sensor, (0, 0, []))
                self._no_return[group.sensor] = (count + n_hole, px + int(np.isfinite(p.real).sum()),
                                                 [*depths, *([float(np.median(p.real[hole]))] if n_hole else [])])
                if n_near and s.depth.min_m > 0.0:
                    pred = np.where(bad, np.float32(s.depth.min_m), pred)  # the sensor's "too near" reading
                    self._too_near_total += n_near
                rows.append(FramePair(p.index, pred, p.real, p.mask, {"too_near_px": n_near, "no_return_px": n_hole,
                                                                      "depth_kind": s.depth.kind}))
            yield dataclasses.replace(group, frames=rows)

    def lidar_frames(self) -> Iterator[SensorFrames]:
        """Per render and LiDAR, ``FramePair(index, sim (N, 4), real (N, 4))``: the rendered sweep
        (``<lidar>/scan/NNNNNN.exr``) and the oracle's exact one from the same sensor pose (the rig's extrinsic on
        ``robot.tum``'s body pose), same beams and order, with the render's people as actors; rows X, Y, Z in the
        sensor frame and range, NaN where there is no return."""
        from nsim.io.lidar_exr import read_lidar_exr
        from nsim.io.tum import read_tum

        self._require_trajectory()
        for r in self.renders:
            room = self.require_room(r)
            lidars = r.rig().lidars
            if not lidars:
                raise InputError(f"render {r.short}: its rig has no LiDAR to score (--table lidar)")
            body = read_tum(r.file("robot.tum")).poses_se3()
            if len(body) != len(r.frames):
                raise InputError(f"render {r.short}: robot.tum has {len(body)} poses for its {len(r.frames)} frames")
            actors = self.actors(r)
            for s in lidars:
                rows = []
                for f, T in zip(r.frames, body, strict=True):
                    i = int(f["index"])
                    scan = read_lidar_exr(r.file(f"{s.name}/scan/{i:06d}.exr"))
                    gt = self.oracle(room).lidar_gt(s.world_pose(T), s, actors=actors(i) if actors is not None else None)
                    if scan.range_m.shape != gt.ranges_m.shape:
                        raise InputError(f"render {r.short}: {s.name}/scan/{i:06d}.exr is {scan.range_m.shape[0]}x"
                                         f"{scan.range_m.shape[1]} beams, the rig's {s.name} {gt.ranges_m.shape[0]}x"
                                         f"{gt.ranges_m.shape[1]}")
                    rows.append(FramePair(i, lidar_rows(scan.xyz_m, scan.range_m),
                                          lidar_rows(gt.points_lidar_m, gt.ranges_m)))
                yield SensorFrames(r, s.name, rows, np.asarray(s.sensor_to_body))

    def _slam_plan(self, r: RenderData):
        """``(sensor, pairs, times, gt_times)`` of render ``r``'s slam sequence, checked: the camera, the frames'
        camera records and timestamps (no frame read)."""
        cfg = self.cfg.slam
        self.require_room(r)
        rig = r.rig()
        if cfg.camera not in rig.names or rig[cfg.camera].type != "camera" or not rig[cfg.camera].emits_image:
            raise InputError(f"slam.camera: render {r.short}'s rig has no image camera {cfg.camera!r} "
                             f"(has {', '.join(s.name for s in rig.cameras if s.emits_image)})")
        s = rig[cfg.camera]
        pairs = list(zip(r.frames, self.camera_frames(r, s.name), strict=True))[:: cfg.stride]
        if cfg.max_frames is not None:
            pairs = pairs[: cfg.max_frames]
        times = np.array([float(f["time_s"]) for f, _ in pairs])
        gt_times = np.array([c.timestamp_s if c.timestamp_s is not None else np.nan for _, c in pairs], dtype=float)
        if not np.isfinite(gt_times).any():
            raise InputError(f"render {r.short}: cameras/{s.name}.json has no timestamps: no ground-truth trajectory")
        common = np.abs(gt_times[:, None] - times[None, :]).min(axis=0) <= cfg.max_dt_s
        if not common.any():
            raise InputError(f"render {r.short}: the ground-truth poses of {s.name} (cameras/{s.name}.json, t = "
                             f"{np.nanmin(gt_times):g}..{np.nanmax(gt_times):g} s) share no timestamp with the "
                             f"frames (t = {times.min():g}..{times.max():g} s, within {cfg.max_dt_s:g} s)")
        for f, _ in pairs:
            r.file(f"{s.name}/rgb/{int(f['index']):06d}.png")
        return s, pairs, times, gt_times

    def slam_sequences(self) -> Iterator[SlamSequence]:
        from nsim.io.tum import Trajectory

        cfg = self.cfg.slam
        self._require_trajectory()
        for r in self.renders:
            s, pairs, times, gt_times = self._slam_plan(r)
            seq = cfg.camera if len(self.renders) == 1 else f"{self.environment(r)}/{cfg.camera} ({r.id[:8]})"
            ok = np.isfinite(gt_times)
            truth = Trajectory.from_poses(gt_times[ok], np.stack([c.cam_to_world for (_, c), k in zip(pairs, ok,
                                                                                                     strict=True) if k]))
            actors = self.actors(r)
            sim = [uint8_rgb(read_rgb(r.file(f"{s.name}/rgb/{int(f['index']):06d}.png"))) for f, _ in pairs]
            real = [uint8_rgb(s.expose(self.oracle_view(r, c, int(f["index"]), actors).rgb)) for f, c in pairs]
            yield SlamSequence(r, s.name, seq, times, sim, real, truth)

    def detection_unavailable(self, coco: bool) -> tuple[RenderData, str, list[str]] | None:
        no_people = [r for r in self.renders if not r.has_people]
        if coco or not no_people:
            return None
        r = no_people[0]
        reason = (f"render {r.short} has no people (its run has none, or it was rendered with --no-people): the detection experiment compares "
                  "person boxes on simulated and real frames")
        return r, reason, [s.name for s in self.cameras(r, "image")]

    def detection_frames(self, coco: bool) -> Iterator[SensorFrames]:
        from nsim.io.coco import read_instance_mask

        self._require_trajectory()
        for r in self.renders:
            actors = self.actors(r) if not coco else None
            for s in self.cameras(r, "image"):
                rows = []
                for f, cam in zip(r.frames, self.camera_frames(r, s.name), strict=True):
                    i = int(f["index"])
                    rel = f"{s.name}/rgb/{i:06d}.png"
                    if coco:
                        rows.append(FramePair(i, None, None, key=rel))
                        continue
                    sim = uint8_rgb(read_rgb(r.file(rel)))
                    view = self.oracle_view(r, cam, i, actors)
                    real = uint8_rgb(s.expose(view.rgb))
                    if sim.shape != real.shape:
                        raise InputError(f"render {r.short}: {rel} is {sim.shape[1]}x{sim.shape[0]} but the ground "
                                         f"truth {real.shape[1]}x{real.shape[0]}")
                    sim_mask = np.asarray(read_instance_mask(r.file(f"{s.name}/mask/{i:06d}.png"))) > 0
                    real_mask = view.instance_mask > 0
                    if sim_mask.shape != real_mask.shape:
                        raise InputError(f"render {r.short}: {s.name}/mask/{i:06d}.png is {sim_mask.shape[1]}x"
                                         f"{sim_mask.shape[0]} but the frame {real.shape[1]}x{real.shape[0]}")
                    union = int((sim_mask | real_mask).sum())
                    extra = {"people_px_sim": int(sim_mask.sum()), "people_px_real": int(real_mask.sum()),
                             "mask_iou": float((sim_mask & real_mask).sum() / union) if union else None}
                    rows.append(FramePair(i, sim, real, extra=extra, key=rel))
                yield SensorFrames(r, s.name, rows, np.asarray(s.sensor_to_body))

    def notes(self, table: str, extras: list[dict[str, Any]]) -> list[str]:
        cfg = self.cfg
        if table == "spot-rgb":
            return ["ground truth: the test room's oracle at each frame's camera and pose (cameras/<camera>.json), "
                    f"{cfg.oracle_supersample}x{cfg.oracle_supersample} supersampled, through the camera's exposure "
                    "and colour model, 8-bit"]
        if table == "spot-depth":
            total = self._too_near_total
            holes = sorted(((k, v) for k, v in self._no_return.items() if v[0]), key=lambda kv: -kv[1][0])
            per = ", ".join(f"{name} {n} px at a median {float(np.median(d)):.2f} m" for name, (n, _, d) in holes)
            for name, (n, px, d) in holes:
                if n > 0.002 * px:
                    log.warning("spot-depth: camera %s: %d px (%.2f %%) have no return where the ground truth has a "
                                "surface (median %.2f m); they count as %g m: the scene model has a hole there",
                                name, n, 100.0 * n / px, float(np.median(d)), self.cfg.depth_max_m)
            return ["ground truth: the test room's oracle depth (the camera's depth kind, z-depth for Spot) at each "
                    "frame's camera pose, inside the camera's valid range, without noise or quantisation",
                    "simulated readings reported invalid (NaN: nearer than the camera's minimum range) where the "
                    f"ground truth is valid count as that minimum ({total} px)",
                    "simulated readings with no return (+inf: the scene model is empty along the ray) where the "
                    f"ground truth has a surface count as the maximum depth ({per or 'none'})"]
        if table == "lidar":
            return ["ground truth: the test room's oracle scan of each LiDAR (the rig's beams, exact ranges, no noise "
                    "or dropout) from the body pose of robot.tum and the rig's extrinsic, with the render's people"]
        if table == "slam":
            return ["real frames: the test room's oracle at the same camera poses; ground truth: the camera's poses "
                    "(cameras/<camera>.json)"]
        if table == "detection":
            seeds = {h: seed for r in self.renders for h, seed in zip(r.humans, self.actor_seeds(r), strict=True)}
            dressed = [f"checkpoint {h[:12]}: actor seed {seed}" if seed is not None
                       else f"checkpoint {h[:12]}: seed = person index (no test-room actor)" for h, seed in seeds.items()]
            if any(DEFAULT_LOOK_NAME in r.manifest.get("summary", {}).get("people_checkpoints", ()) for r in self.renders):
                dressed.append(f"the default look: actor seed {DEFAULT_LOOK_SEED}, exactly as rendered")
            dressed = ", ".join(dressed)
            return ["real frames: the test room's oracle at the same camera poses with the simulated people as "
                    "test-room actors (nsim.synth.actor.Actor), posed like the render's (the run's positions, "
                    f"headings, gait phases and heights) and dressed like the actor each person's human checkpoint "
                    f"was trained from ({dressed})"]
        return []

    def described(self, table: str) -> dict[str, str]:
        what = {"spot-rgb": "test-room oracle at the rendered camera poses",
                "spot-depth": "test-room oracle depth at the rendered camera poses",
                "lidar": "test-room oracle LiDAR scans at the rendered body poses (robot.tum)",
                "slam": f"camera poses cameras/{self.cfg.slam.camera}.json; real frames from the test-room oracle"}
        return {r.id: what[table] for r in self.renders} if table in what else {}
