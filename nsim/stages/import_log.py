"""``nsim import-log``: a robot's recording (a ROS 1 or ROS 2 bag, or a plain folder) in, a ``recording`` artifact out.

A bag is read with :class:`nsim.io.robot_log.RobotLog` (topics by a selection YAML or by
message type, see its docstring): every camera, depth camera and LiDAR stream with its
timestamps, its intrinsics (CameraInfo) and its extrinsic to the robot's body (/tf_static), and
the body's trajectory in the odometry frame (/tf or nav_msgs/Odometry). A directory without
``metadata.yaml`` is a recording folder, read with :class:`nsim.io.robot_folder.RobotFolder`
(its docstring has the layout: per-stream folders of frames with camera_info.yaml, trajectory.tum,
rig.yaml or rig.urdf); it has the same interface, so what follows is one code path. Inputs count
by content (their digests enter the action key), so a re-recorded log never serves a stale result.
Everything is checked before anything is written: bad input is one line naming the topic (and
message index) or the file, exit 2, nothing published.

A log with no camera, depth or LiDAR stream but a trajectory (a nav2 run's odometry and tf, a
PoseStamped topic, a folder holding trajectory.tum alone) is a **trajectory-only** recording
(``trajectory_only: true``): ``nsim simulate`` drives the robot along it (``robot.trajectory:
{recording: REF}``); ``register-log`` refuses it (nothing to register). ``--trajectory FILE.tum``
gives a bag's body trajectory from a TUM file on the bag's clock instead of its topics (a RealSense
bag has no tf): at least one frame must lie within ``max_gap_s`` of its poses.

Artifact layout (kind ``recording``)::

    recording.json       format, the bags (their names) or the folder (its name), body and odom frames,
                         the trajectory's source, trajectory_only (true: no streams), and per stream: kind (camera | depth | lidar), topic
                         (a folder's: the stream's folder, e.g. cameras/front), frame_id,
                         camera (nsim.geometry.Camera.to_dict), sensor_to_body (4 x 4), encoding,
                         the frames kept (indices into the topic) and how many lie inside the
                         trajectory's time span (within ``max_gap_s`` of a pose stamp); depth streams
                         also their unit (depth_m_per_unit, and depth_unit: who says so) and
                         median_depth_m (a warning when outside 0.1-20 m: a wrong unit lands there)
    trajectory.tum       body_to_odom at the trajectory's stamps (TUM: seconds, xyz, quaternion xyzw)
    trajectory_ns.npy    the same stamps as int64 nanoseconds (TUM's float seconds round them)
    <kind>/<name>/stamps_ns.npy          (N,) int64 header stamps of the frames kept
    camera/<name>/NNNNNN.png             colour (RGB) or grey, as recorded (16-bit grey stays 16-bit)
    depth/<name>/NNNNNN.exr              float32 metres, channel Z (inf: no return, NaN: invalid)
    lidar/<name>/NNNNNN.exr              one row of N points: X, Y, Z (metres, the sensor's frame),
                                         intensity, ring and time where the cloud has them
    preview.png          the trajectory from above with the stream stamps, and each camera's first frame

Stamps stay on the recording's own clocks (nanoseconds since the epoch, header stamps); the
odometry frame stays the robot's. Registering the recording into a scene's world (the odometry
frame's pose, the cameras' clock offset) is the next step's work.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from nsim.config import param
from nsim.context import RunContext
from nsim.errors import InputError, name_list
from nsim.io.recording_output import inside_trajectory, kept_frames, write_recording
from nsim.stages.runner import cached, rerun

STAGE = "import-log"
VERSION = 4  # 2: poses, trajectories and metrics written rounded (nsim.io.canonical: the same bytes on any CPU)
# 3: each depth stream records its unit (depth_m_per_unit, depth_unit) and median depth; a folder's 16-bit PNG depth
#    needs its unit stated (depth_m_per_unit, or TUM's depth.txt)
# 4: trajectory-only recordings (no streams); --trajectory FILE.tum; recording.json says trajectory_only
KINDS = ("camera", "depth", "lidar")
log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Config:
    trajectory: str = param("auto", choices=("auto", "tf", "odometry", "pose"),
                            help="the body's motion from /tf (odom -> body), the Odometry topic, the PoseStamped topic, "
                                 "or auto: tf when it has a path, else odometry, else pose")
    frame_stride: int = param(1, ge=1, help="keep every n-th frame of each stream")
    max_frames: int = param(0, ge=0, help="then at most this many frames per stream, evenly spaced (0: all)")
    max_gap_s: float = param(0.1, gt=0.0, help="a frame further than this from every trajectory stamp is counted as "
                                                "outside the trajectory")


@dataclasses.dataclass(frozen=True)
class Inputs:
    """log: one ROS 2 bag directory (or its .db3 / .mcap), one or more ROS 1 .bag files (a split
    recording), or one recording folder (``nsim.io.robot_folder``); selection: a YAML choosing a
    bag's topics (``nsim.io.topic_selection.Selection``); trajectory: a TUM file of the body's poses
    in the odometry frame on the bag's clock (seconds), instead of the bag's tf / odometry / pose
    topics (a RealSense bag has none)."""

    log: tuple[Path, ...]
    selection: Path | None = None
    trajectory: Path | None = None

    def validate(self) -> None:
        if not self.log:
            raise InputError("import-log: give the bag to import")
        for p in (*self.log, *([self.selection] if self.selection is not None else [])):
            if not Path(p).exists():
                raise InputError(f"{p}: no such file or directory")
        if self.selection is not None and not Path(self.selection).is_file():
            raise InputError(f"--selection {self.selection}: not a file")
        if self.trajectory is not None:
            if not Path(self.trajectory).is_file():
                raise InputError(f"--trajectory {self.trajectory}: no such file")
            from nsim.io.robot_folder import read_tum_ns

            stamps, _ = read_tum_ns(Path(self.trajectory))  # a bad file is one line now, before the bag is read
            if len(stamps) < 2:
                raise InputError(f"--trajectory {self.trajectory}: {len(stamps)} pose(s); a trajectory needs two")
        if self.is_folder():
            if len(self.log) > 1:
                raise InputError(f"{self.log[0]}: a recording folder is imported alone (got {len(self.log)} paths)")
            if self.selection is not None:
                raise InputError(f"--selection {self.selection}: chooses a bag's topics; {self.log[0]} is a recording "
                                 "folder, whose streams are its folders")
            if self.trajectory is not None:
                raise InputError(f"--trajectory {self.trajectory}: replaces a bag's trajectory; {self.log[0]} is a "
                                 "recording folder, whose trajectory is its trajectory.tum")

    def is_folder(self) -> bool:
        """A recording folder (a directory that is not a ROS 2 bag) rather than a bag."""
        from nsim.io.robot_folder import is_robot_folder

        return any(is_robot_folder(p) for p in self.log)


@dataclasses.dataclass(frozen=True)
class Outputs:
    recording: str
    cache_hit: bool = False


def log_digests(inputs: Inputs) -> dict[str, Any]:
    """The log's files by name and SHA-256 (and the selection's digest): what the action key counts."""
    from nsim.workspace.store import sha256_path

    files: dict[str, Any] = {"log": [[Path(p).name, sha256_path(Path(p))] for p in inputs.log]}
    if inputs.selection is not None:
        files["selection"] = sha256_path(Path(inputs.selection))
    if inputs.trajectory is not None:
        files["trajectory"] = [Path(inputs.trajectory).name, sha256_path(Path(inputs.trajectory))]
    return files


def action_key(inputs: Inputs, cfg: Config, ctx: RunContext) -> str:
    from importlib import metadata

    files = log_digests(inputs)
    extra = {"files": files} if inputs.is_folder() else {"files": files, "rosbags": metadata.version("rosbags")}
    return ctx.store.action_key(STAGE, VERSION, cfg, {}, seed=ctx.seed, extra=extra)


def open_log(inputs: Inputs):
    """The reader of the log: a :class:`~nsim.io.robot_folder.RobotFolder` for a recording folder, else a
    :class:`~nsim.io.robot_log.RobotLog`; both have the interface ``run`` uses (a context manager)."""
    from nsim.io.robot_folder import RobotFolder
    from nsim.io.robot_log import RobotLog
    from nsim.io.topic_selection import load_selection

    if inputs.is_folder():
        return RobotFolder(Path(inputs.log[0]))
    selection = load_selection(inputs.selection) if inputs.selection is not None else None
    return RobotLog([Path(p) for p in inputs.log], selection)


def _streams(rl) -> list[tuple[str, str, Any]]:
    """``(kind, name, stream)`` of every stream the log selected, in a fixed order."""
    out = [("camera", n, s) for n, s in sorted(rl.cameras.items())]
    out += [("depth", n, s) for n, s in sorted(rl.depth.items())]
    out += [("lidar", n, s) for n, s in sorted(rl.lidars.items())]
    return out


def body_trajectory(rl, inputs: Inputs, cfg: Config, streams: list):
    """The body's trajectory: ``--trajectory``'s TUM file (in the log's body and odometry frames), else the log's
    own (``cfg.trajectory``). A log with no stream and no trajectory is one line saying both."""
    from nsim.io.recording_streams import Trajectory

    if inputs.trajectory is not None:
        from nsim.io.robot_folder import read_tum_ns

        stamps, body_to_odom = read_tum_ns(Path(inputs.trajectory))
        body, odom = rl.body_frame or "body", rl.odom_frame or "odom"
        log.info("import-log: the body trajectory is %s (%d poses), %s -> %s; the log's own is not read",
                 inputs.trajectory, len(stamps), body, odom)
        return Trajectory(stamps, body_to_odom, odom, body, f"file {Path(inputs.trajectory).name}")
    try:
        return rl.body_trajectory(cfg.trajectory)
    except InputError as exc:
        if streams:
            raise
        why = str(exc).removeprefix(f"bag {rl.name}: ").removeprefix(f"{rl.name}: ")
        raise InputError(f"{rl.name}: no camera, depth or LiDAR stream and no trajectory ({why}; topics: "
                         f"{name_list(sorted(rl.topics))})") from None


def check_same_clock(plan: list, traj, max_gap_s: float, what: str) -> None:
    """A trajectory given apart from the log must share its clock: at least one kept frame inside it (one line
    with both spans otherwise)."""
    frames = [s.stamps_ns[keep] for _, _, s, _, keep in plan if len(keep)]
    if not frames or any(inside_trajectory(f, traj.stamps_ns, max_gap_s).any() for f in frames):
        return
    lo, hi = min(int(f[0]) for f in frames), max(int(f[-1]) for f in frames)
    raise InputError(f"{what}: its stamps span {traj.stamps_ns[0] / 1e9:.3f}-{traj.stamps_ns[-1] / 1e9:.3f} s, the "
                     f"log's frames {lo / 1e9:.3f}-{hi / 1e9:.3f} s: no frame lies within {max_gap_s:g} s of a pose "
                     "(not the log's clock?)")


def run(inputs: Inputs, cfg: Config, ctx: RunContext) -> Outputs:
    inputs.validate()
    store = ctx.store
    key = action_key(inputs, cfg, ctx)
    if (hit := cached(ctx, key)) is not None:
        return Outputs(recording=hit, cache_hit=True)
    t0 = time.perf_counter()
    with open_log(inputs) as rl:
        streams = _streams(rl)
        traj = body_trajectory(rl, inputs, cfg, streams)
        if len(traj.stamps_ns) < 2:
            raise InputError(f"{rl.name}: the body trajectory ({traj.source}) has {len(traj.stamps_ns)} pose(s); "
                             "registration needs the robot's motion")
        if not streams:
            log.info("import-log: %s has no camera, depth or LiDAR stream: a trajectory-only recording (%s, %d poses)",
                     rl.name, traj.source, len(traj.stamps_ns))
        # every check before the artifact is started: extrinsics, frames to keep
        plan = []
        for kind, name, s in streams:
            extrinsic = rl.sensor_to_body(s.frame_id)
            keep = kept_frames(len(s.stamps_ns), cfg.frame_stride, cfg.max_frames)
            plan.append((kind, name, s, extrinsic, keep))
        if inputs.trajectory is not None:
            check_same_clock(plan, traj, cfg.max_gap_s, f"--trajectory {inputs.trajectory}")
        t_read = time.perf_counter() - t0
        with store.publish(kind="recording", stage=STAGE, version=VERSION, key=key, config=cfg, inputs={},
                           seed=ctx.seed) as out:
            t1 = time.perf_counter()
            doc = write_recording(out.dir, rl, traj, plan, inputs.log, inputs.is_folder(), cfg.max_gap_s,
                                  ctx.show_progress)
            out.summary.update({
                "streams": {f"{k}/{n}": len(keep) for k, n, _, _, keep in plan},
                "trajectory_poses": int(len(traj.stamps_ns)),
                "trajectory_length_m": round(doc["trajectory"]["length_m"], 3),
                "duration_s": round(doc["trajectory"]["duration_s"], 3),
            })
            out.timing.update({"read_index_s": round(t_read, 2), "write_s": round(time.perf_counter() - t1, 2),
                               # where the log was read from (outside the id: the same bag at another path on
                               # another node gives the same artifact), for `nsim verify --rebuild`
                               "source": {"log": [str(Path(p).resolve()) for p in inputs.log],
                                          "selection": (str(Path(inputs.selection).resolve())
                                                        if inputs.selection is not None else None),
                                          "trajectory": (str(Path(inputs.trajectory).resolve())
                                                         if inputs.trajectory is not None else None),
                                          "files": log_digests(inputs)}})
    return Outputs(recording=out.ref)


def rebuild(manifest: dict[str, Any], ctx: RunContext) -> str:
    """Re-import the log the recording was imported from, where it was read (the manifest's ``timing.source``),
    if it is still there with the same content; the workspace does not hold the log itself."""

    source = manifest.get("timing", {}).get("source")
    if not isinstance(source, dict) or not source.get("log"):
        raise InputError("this recording was imported from a robot log (bag files or a folder) whose path it does not "
                         "record: rerun nsim import-log on it with --force to compare")
    paths = tuple(Path(str(p)) for p in source["log"])
    selection = Path(str(source["selection"])) if source.get("selection") else None
    trajectory = Path(str(source["trajectory"])) if source.get("trajectory") else None
    for p in (*paths, *(q for q in (selection, trajectory) if q is not None)):
        if not p.exists():
            raise InputError(f"{p}: the robot log this recording was imported from is no longer there: rerun nsim "
                             "import-log on it with --force to compare")
    inputs = Inputs(log=paths, selection=selection, trajectory=trajectory)
    if log_digests(inputs) != source.get("files"):
        raise InputError(f"{paths[0]}: the robot log has changed since this recording was imported from it")
    return rerun(run, inputs, Config, manifest, ctx).recording
