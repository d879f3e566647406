"""``RecordingTruth``: a robot's recording as ground truth (``nsim.evaluation.truth``).

A recording-mode render (``nsim render --recording``) renders the recorded sensors frame for frame;
its ``render.json`` names them::

    {"mode": "recording", "recording": ID, "registration": ID, "scene": ID,
     "streams": [{"name", "kind": camera | depth | lidar,
                  "frames": [{"index", "stamp_ns", "odom_time_ns", "sensor_to_world"}, ...]}, ...]}

and its files mirror the recording's (``nsim.stages.import_log``): ``camera/<name>/NNNNNN.png``,
``depth/<name>/NNNNNN.exr`` (channel Z, metres; inf: no return, NaN: invalid) and
``lidar/<name>/NNNNNN.exr`` (one row of the recorded cloud's N points, in its order: X, Y, Z in the
sensor's frame and ``range``; inf/NaN: no return). ``index`` is the frame's index in its topic, the
file name of both sides. Each rendered frame is checked against the recording: its stream is
recorded, its index was kept, its stamp is the recorded one, and both files exist.

Real readings: the recorded images (8-bit or 16-bit, grey replicated to three channels; 8-bit
values), depth images on the real sensor's valid pixels (finite, > 0: ``nsim.metrics.depth``'s
valid range applies on top; simulated NaN at such a pixel is left out and counted), and LiDAR
points (range = |XYZ|; a point with a non-finite coordinate is no return). The SLAM ground truth
is the camera's pose at each frame's odometry time (``odom_time_ns``) on the registration's
``trajectory_world.tum`` (body_to_world, interpolated: ``nsim.rendering.recording.sensor_poses``)
through the recorded extrinsic ``sensor_to_body``; frames outside that trajectory's span are left
out.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from nsim.errors import InputError, NsimError
from nsim.evaluation.evaluate_config import Config
from nsim.evaluation.inputs import EvaluationInputs
from nsim.evaluation.renders import ArtifactReader, RenderData, as_captured, read_depth, read_rgb, uint8_rgb
from nsim.evaluation.truth import FramePair, GroundTruth, SensorFrames, SlamSequence, lidar_rows
from nsim.rendering.recording import RegisteredTrajectory, read_registration

KINDS = ("camera", "depth", "lidar")


@dataclasses.dataclass(frozen=True, eq=False)
class Recording:
    """A recording artifact (``nsim import-log``): its folder and ``recording.json``."""

    id: str
    path: Path
    doc: dict[str, Any]

    @property
    def short(self) -> str:
        return self.id[:12]

    def stream(self, kind: str, name: str) -> dict[str, Any]:
        return self.doc["streams"][f"{kind}/{name}"]

    def stamps_ns(self, kind: str, name: str) -> np.ndarray:
        return np.load(self.file(f"{kind}/{name}/stamps_ns.npy"), allow_pickle=False)

    def file(self, rel: str) -> Path:
        p = self.path / rel
        if not p.is_file():
            raise InputError(f"recording {self.short}: has no file {rel}")
        return p


def _artifact(artifacts: ArtifactReader, art_id: Any, kind: str, what: str):
    """The artifact ``art_id`` of ``kind`` that ``what`` names, or one line saying why not."""
    if not isinstance(art_id, str) or not art_id:
        raise InputError(f"{what} names no {kind}")
    try:
        art = artifacts.get(art_id)
    except (NsimError, ValueError):
        raise InputError(f"{what} names {kind} {art_id[:12]}, which is not in the workspace") from None
    if art.kind != kind:
        raise InputError(f"{what} names {art_id[:12]} as its {kind}, but it is a {art.kind} artifact")
    return art


def _json(path: Path, what: str) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(f"{what}: {err}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{what}: not a JSON object")
    return doc


def load_recording(artifacts: ArtifactReader, r: RenderData) -> Recording:
    art = _artifact(artifacts, r.meta.get("recording"), "recording", f"render {r.short}: render.json")
    return Recording(art.id, art.path, _json(art.file("recording.json"), f"recording {art.id[:12]}: recording.json"))


def load_registration(artifacts: ArtifactReader, r: RenderData, recording: Recording) -> RegisteredTrajectory:
    art = _artifact(artifacts, r.meta.get("registration"), "registration", f"render {r.short}: render.json")
    reg = read_registration(art.path, art.id[:12])
    registered = reg.doc.get("inputs", {}).get("recording")
    if registered != recording.id:
        raise InputError(f"render {r.short}: its registration {art.id[:12]} registers recording "
                         f"{str(registered)[:12]}, not the render's recording {recording.short}")
    return reg


def read_recorded_rgb(path: Path) -> np.ndarray:
    """A recorded image as (H, W, 3) float in [0, 1] with 8-bit values (16-bit grey scaled down)."""
    from nsim.io.images import read_image

    image = np.asarray(read_image(path))
    if image.dtype == np.uint16:
        return as_captured(image.astype(np.float32) / np.float32(65535.0))
    if image.dtype != np.uint8:
        raise InputError(f"{path}: expected an 8- or 16-bit image, got {image.dtype}")
    return as_captured(image.astype(np.float32) / np.float32(255.0))


def read_points(path: Path, what: str) -> dict[str, np.ndarray]:
    from nsim.io.exr import read_points_exr

    try:
        points = read_points_exr(path)
    except InputError:
        raise
    except Exception as err:  # OpenEXR raises plain exceptions for damaged files
        raise InputError(f"{what}: cannot read points EXR ({err})") from None
    return {k: np.asarray(v).reshape(-1) for k, v in points.items()}


@dataclasses.dataclass(frozen=True, eq=False)
class _Stream:
    render: RenderData
    kind: str
    name: str
    frames: list[dict[str, Any]]  # render.json's frames of the stream
    entry: dict[str, Any]  # the recording's stream


class RecordingTruth(GroundTruth):
    """A robot's recording (module docstring)."""

    source = "recording"
    colour_correction = True

    def __init__(self, inputs: EvaluationInputs, cfg: Config) -> None:
        super().__init__(inputs, cfg)
        self.recordings: dict[str, Recording] = {}
        self.registrations: dict[str, RegisteredTrajectory] = {}
        for r in self.renders:
            rec = load_recording(self.artifacts, r)
            self.recordings[r.id] = rec
            self.registrations[r.id] = load_registration(self.artifacts, r, rec)
        self._skipped: dict[str, int] = {}

    # -- streams and frames
    def streams(self, kind: str, names: tuple[str, ...] = ()) -> Iterator[_Stream]:
        """The renders' streams of ``kind`` (those named, else ``cfg.cameras`` for cameras and depth, else
        all), each frame checked against the recording (module docstring)."""
        want = names or (self.cfg.cameras if kind != "lidar" else ())
        for r in self.renders:
            rec = self.recordings[r.id]
            streams = r.meta["streams"]
            if not isinstance(streams, list) or not all(isinstance(s, dict) for s in streams):
                raise InputError(f"render {r.short}: render.json streams: expected a list of objects")
            ours = [s for s in streams if s.get("kind") == kind]
            have = [str(s.get("name")) for s in ours]
            unknown = [n for n in want if n not in have]
            if unknown:
                raise InputError(f"render {r.short}: has no {kind} stream {', '.join(unknown)} "
                                 f"(has {', '.join(have) or 'none'})")
            ours = [s for s in ours if not want or s.get("name") in want]
            if not ours:
                raise InputError(f"render {r.short}: renders no {kind} stream of recording {rec.short}")
            for s in ours:
                name = str(s["name"])
                key = f"{kind}/{name}"
                if key not in rec.doc.get("streams", {}):
                    raise InputError(f"render {r.short}: stream {key} is not in recording {rec.short} (it has "
                                     f"{', '.join(sorted(rec.doc.get('streams', {}))) or 'none'})")
                entry = rec.stream(kind, name)
                frames = s.get("frames")
                if not isinstance(frames, list) or not frames:
                    raise InputError(f"render {r.short}: stream {key} lists no frames")
                kept = {int(i): k for k, i in enumerate(entry["frames"])}
                stamps = rec.stamps_ns(kind, name)
                for f in frames:
                    if not isinstance(f, dict) or "index" not in f or "stamp_ns" not in f:
                        raise InputError(f"render {r.short}: stream {key}: a frame without index and stamp_ns")
                    i = int(f["index"])
                    if i not in kept:
                        raise InputError(f"render {r.short}: stream {key} frame {i} is not among the "
                                         f"{len(kept)} frames recording {rec.short} kept")
                    if int(f["stamp_ns"]) != int(stamps[kept[i]]):
                        raise InputError(f"render {r.short}: stream {key} frame {i} is stamped {int(f['stamp_ns'])} "
                                         f"ns, the recording's {int(stamps[kept[i]])} ns")
                yield _Stream(r, kind, name, frames, entry)

    def _files(self, st: _Stream, f: dict[str, Any], suffix: str) -> tuple[Path, Path]:
        rel = f"{st.kind}/{st.name}/{int(f['index']):06d}.{suffix}"
        return st.render.file(rel), self.recordings[st.render.id].file(rel)

    def image_frames(self) -> Iterator[SensorFrames]:
        self._no_people()
        for st in self.streams("camera"):
            rows = []
            for f in st.frames:
                sim_path, real_path = self._files(st, f, "png")
                sim, real = as_captured(read_rgb(sim_path)), read_recorded_rgb(real_path)
                _same_size(st, f, sim.shape[:2], real.shape[:2])
                rows.append(FramePair(int(f["index"]), sim, real, extra={"stamp_ns": int(f["stamp_ns"])}))
            yield SensorFrames(st.render, st.name, rows, _extrinsic(st))

    def depth_frames(self) -> Iterator[SensorFrames]:
        from nsim.metrics.depth import valid_depth_mask

        self._no_people()
        depth_cfg = self.cfg.depth_config()
        self._sim_invalid_px = 0
        for st in self.streams("depth"):
            rows = []
            for f in st.frames:
                sim_path, real_path = self._files(st, f, "exr")
                sim, real = read_depth(sim_path), read_depth(real_path)
                _same_size(st, f, sim.shape, real.shape)
                with np.errstate(invalid="ignore"):
                    real_valid = np.isfinite(real) & (real > 0)
                sim_invalid = real_valid & np.isnan(sim)
                self._sim_invalid_px += int(sim_invalid.sum())
                mask = valid_depth_mask(real, depth_cfg) & real_valid & ~np.isnan(sim)
                rows.append(FramePair(int(f["index"]), sim, real, mask,
                                      {"stamp_ns": int(f["stamp_ns"]), "real_valid_px": int(real_valid.sum()),
                                       "sim_invalid_px": int(sim_invalid.sum()), "scored_px": int(mask.sum())}))
            yield SensorFrames(st.render, st.name, rows, _extrinsic(st))

    def lidar_frames(self) -> Iterator[SensorFrames]:
        for st in self.streams("lidar"):
            rows = []
            for f in st.frames:
                sim_path, real_path = self._files(st, f, "exr")
                sim = read_points(sim_path, f"render {st.render.short}: {sim_path.name}")
                real = read_points(real_path, f"recording {self.recordings[st.render.id].short}: {real_path.name}")
                n_sim, n_real = len(sim["X"]), len(real["X"])
                if n_sim != n_real:
                    raise InputError(f"render {st.render.short}: lidar/{st.name} frame {int(f['index'])} has {n_sim} "
                                     f"points, the recorded sweep {n_real} (the render keeps the recording's points)")
                rows.append(FramePair(int(f["index"]), _points(sim, "range" in sim), _points(real, False),
                                      extra={"stamp_ns": int(f["stamp_ns"])}))
            yield SensorFrames(st.render, st.name, rows, _extrinsic(st))

    def _slam_plan(self, st: _Stream):
        """``(frames, times_s, cam_to_world, inside)`` of a slam stream: its frames (stride, cap) inside the
        registered trajectory, their odometry times and true poses, and which of the picked frames lay inside;
        InputError when none does."""
        from nsim.rendering.recording import odometry_time_ns

        cfg = self.cfg.slam
        r = st.render
        reg = self.registrations[r.id]
        frames = st.frames[:: cfg.stride]
        if cfg.max_frames is not None:
            frames = frames[: cfg.max_frames]
        stamps = np.array([int(f["stamp_ns"]) for f in frames], dtype=np.int64)
        odom_ns = odometry_time_ns(stamps, reg.clock_offset_s, True)
        given = [f.get("odom_time_ns") is not None for f in frames]  # as the render moved them, when it says
        odom_ns[given] = [int(f["odom_time_ns"]) for f, g in zip(frames, given, strict=True) if g]
        inside, _, cam_to_world = reg.sensor_poses(odom_ns, _extrinsic(st))
        if not inside.any():
            raise InputError(f"render {r.short}: no frame of camera {st.name} lies in the time span of "
                             f"registration {reg.id[:12]}'s trajectory (odometry time "
                             f"{reg.stamps_ns[0] / 1e9:.3f}..{reg.stamps_ns[-1] / 1e9:.3f} s)")
        frames = [f for f, k in zip(frames, inside, strict=True) if k]
        return frames, odom_ns[inside] / 1e9, cam_to_world[inside], inside

    def check(self, table: str) -> None:
        """Every render's streams of ``table`` checked against their recordings (names, frames, stamps, the
        files on both sides; slam: frames inside the registered trajectory) for all renders before the first
        frame is read or scored (module docstring). ``scenes`` takes poses-mode renders (its own check)."""
        kind = {"spot-rgb": "camera", "spot-depth": "depth", "lidar": "lidar", "slam": "camera",
                "detection": "camera"}.get(table)
        if kind is None:
            return
        if table in ("spot-rgb", "spot-depth"):
            self._no_people()
        coco = table == "detection" and self.cfg.detection.detector == "coco"
        for st in self.streams(kind, (self.cfg.slam.camera,) if table == "slam" else ()):
            frames = self._slam_plan(st)[0] if table == "slam" else st.frames
            for f in frames if not coco else ():
                self._files(st, f, "png" if kind == "camera" else "exr")

    def slam_sequences(self) -> Iterator[SlamSequence]:
        from nsim.io.tum import Trajectory

        cfg = self.cfg.slam
        for st in self.streams("camera", (cfg.camera,)):
            r = st.render
            frames, times, cam_to_world, inside = self._slam_plan(st)
            truth = Trajectory.from_poses(times, cam_to_world)
            sim, real = [], []
            for f in frames:
                sim_path, real_path = self._files(st, f, "png")
                sim.append(uint8_rgb(read_rgb(sim_path)))
                real.append(uint8_rgb(read_recorded_rgb(real_path)))
                _same_size(st, f, sim[-1].shape[:2], real[-1].shape[:2])
            seq = st.name if len(self.renders) == 1 else f"{r.id[:8]}/{st.name}"
            yield SlamSequence(r, st.name, seq, times, sim, real, truth,
                               {"outside_trajectory": int((~inside).sum())})

    def detection_frames(self, coco: bool) -> Iterator[SensorFrames]:
        for st in self.streams("camera"):
            rows = []
            for f in st.frames:
                i = int(f["index"])
                key = f"camera/{st.name}/{i:06d}.png"
                if coco:
                    rows.append(FramePair(i, None, None, key=key))
                    continue
                sim_path, real_path = self._files(st, f, "png")
                sim, real = uint8_rgb(read_rgb(sim_path)), uint8_rgb(read_recorded_rgb(real_path))
                _same_size(st, f, sim.shape[:2], real.shape[:2])
                rows.append(FramePair(i, sim, real, key=key))
            yield SensorFrames(st.render, st.name, rows, _extrinsic(st))

    def _no_people(self) -> None:
        if self.cfg.region == "people":
            raise InputError("region=people: a recording has no person masks; score every pixel (region=all)")

    # -- what the ground truth was
    def _recs(self) -> str:
        return ", ".join(sorted({self.recordings[r.id].short for r in self.renders}))

    def notes(self, table: str, extras: list[dict[str, Any]]) -> list[str]:
        recs = self._recs()
        if table == "spot-rgb":
            return [f"ground truth: recording {recs}'s camera images at the rendered frames (as recorded, 8-bit; "
                    "grey replicated to three channels)"]
        if table == "spot-depth":
            left_out = sum(1 for e in extras if e.get("scored_px") == 0)
            return [f"ground truth: recording {recs}'s depth images at the rendered frames, on the real sensor's "
                    "valid pixels (finite, > 0)",
                    f"simulated readings invalid (NaN) where the real sensor's are valid are left out "
                    f"({self._sim_invalid_px} px)" + (f"; {left_out} frame(s) with no pixel to score left out"
                                                      if left_out else "")]
        if table == "lidar":
            return [f"ground truth: recording {recs}'s LiDAR sweeps, point for point (the render keeps each sweep's "
                    "points in order): real range = |XYZ| of the recorded point, simulated range = the render's "
                    "range channel; a non-finite range is no return"]
        if table == "slam":
            regs = ", ".join(sorted({self.registrations[r.id].id[:12] for r in self.renders}))
            out = [f"real frames: recording {recs}'s; ground truth: the camera's pose at each frame's odometry time on "
                   f"the recording's trajectory registered into the scene (registration {regs}: trajectory_world.tum) "
                   "through the camera's recorded extrinsic"]
            outside = sum(e.get("outside_trajectory", 0) for e in extras)
            if outside:
                out.append(f"{outside} frame(s) outside the registered trajectory's time span left out")
            return out
        if table == "detection":
            return [f"real frames: recording {recs}'s camera images at the rendered frames"]
        return []

    def described(self, table: str) -> dict[str, str]:
        return {r.id: f"recording {self.recordings[r.id].short} (registration {self.registrations[r.id].id[:12]})"
                for r in self.renders}


def _same_size(st: _Stream, f: dict[str, Any], sim_hw: tuple[int, ...], real_hw: tuple[int, ...]) -> None:
    if tuple(sim_hw) != tuple(real_hw):
        raise InputError(f"render {st.render.short}: {st.kind}/{st.name} frame {int(f['index'])} is "
                         f"{sim_hw[1]}x{sim_hw[0]} but the recorded one {real_hw[1]}x{real_hw[0]}")


def _extrinsic(st: _Stream) -> np.ndarray:
    return np.asarray(st.entry["sensor_to_body"], dtype=np.float64)


def _points(channels: dict[str, np.ndarray], has_range: bool) -> np.ndarray:
    """(N, 4): X, Y, Z and range (NaN: no return), from a sweep's channels (``truth.lidar_rows``)."""
    xyz = np.stack([channels[c] for c in "XYZ"], axis=-1)
    return lidar_rows(xyz, channels["range"] if has_range else None)
