"""What one ``nsim render`` is made of, as data: its input artifacts as folders, its frames, the recorded
streams and the job every shard worker gets.

The stage (``nsim.stages.render``) resolves the workspace into :class:`RenderSources`; the plan
(``nsim.rendering.render_plan``) reads those folders into frames and, in recording mode, a
:class:`RecordingPlan`; the shard renderers (``nsim.rendering.shard``) get a :class:`ShardJob`;
``nsim.rendering.render_output`` writes render.json from the same frames.

A frame is one of three kinds, by mode:

trajectory mode
    :class:`TickFrame`, one per selected tick of the run;
poses mode
    :class:`PoseFrame`, one per selected frame of the poses, with its own camera;
recording mode
    :class:`RecordedFrame`, one per kept frame of each recorded stream (:class:`RecordedStream`).

Everything here is plain, picklable data (paths, numbers, arrays, frozen dataclasses): a
``ShardJob`` crosses to Ray workers as it is, so local and Ray runs render the same bytes. Poses are
``(4, 4)`` float64 arrays, read-only.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nsim.errors import InputError

if TYPE_CHECKING:
    from nsim.geometry.cameras import Camera
    from nsim.sensors.rig import Rig


def _pose(value: Any, what: str) -> np.ndarray:
    """``value`` as a read-only ``(4, 4)`` float64 array (a copy)."""
    a = np.array(value, dtype=np.float64)
    if a.shape != (4, 4):
        raise ValueError(f"{what}: expected shape (4, 4), got {a.shape}")
    a.flags.writeable = False
    return a


# ---------------------------------------------------------------------------------- the inputs
@dataclasses.dataclass(frozen=True)
class ArtifactDir:
    """One input artifact as the core reads it: its folder, resolved (and held) by the stage."""

    id: str
    """The artifact id (its first 12 digits name it in messages)."""
    path: Path
    """The artifact's folder in the workspace."""

    def file(self, rel: str) -> Path:
        """``path / rel``; one ``InputError`` line when the artifact has no such file."""
        p = self.path / rel
        if not p.is_file():
            raise InputError(f"artifact {self.id[:12]}: has no file {rel}")
        return p


@dataclasses.dataclass(frozen=True)
class RenderSources:
    """The render's inputs as folders: which artifacts exist says the mode (trajectory: ``trajectory``
    and ``rig_file``; poses: ``poses``; recording: ``registration`` and ``recording``, with ``trajectory``
    only for the people)."""

    scene: ArtifactDir
    """The scene checkpoint (``model.pt``, ``occupancy_grid.npy``, ``scene.json``)."""
    trajectory: ArtifactDir | None = None
    """The ``nsim simulate`` run (``trajectory.npz``): the robot's poses and the people."""
    poses: ArtifactDir | None = None
    """Poses mode: a ``poses`` or ``capture`` artifact (``transforms.json``)."""
    registration: ArtifactDir | None = None
    """Recording mode: the registration (``nsim register-log``) of ``recording``."""
    recording: ArtifactDir | None = None
    """Recording mode: the recording (``nsim import-log``) whose sensors are rendered."""
    humans: tuple[ArtifactDir, ...] = ()
    """The human checkpoints that draw the people (``--humans``, or those the scenario's appearances name)."""
    people: bool = False
    """Whether the trajectory's people are drawn (by ``humans`` or the default look): masks and boxes come too."""
    baked: ArtifactDir | None = None
    """A baked scene of ``scene`` (``--baked``, ``nsim bake``)."""
    rig_file: Path | None = None
    """Trajectory mode: the rig file (``nsim/configs/robots/*.yaml``)."""


# ---------------------------------------------------------------------------------- the frames
@dataclasses.dataclass(frozen=True, eq=False)
class TickFrame:
    """Trajectory mode: one tick of the simulated run, seen by every sensor of the rig."""

    index: int
    """The tick's index in the trajectory (``NNNNNN`` in the file names)."""
    time_s: float
    """The tick's simulation time, seconds."""
    body_to_world: np.ndarray
    """``(4, 4)`` the robot's body pose (x forward, y left, z up)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "body_to_world", _pose(self.body_to_world, "TickFrame.body_to_world"))

    def to_json(self) -> dict[str, Any]:
        """The frame's entry in render.json's ``frames``."""
        return {"index": self.index, "time_s": self.time_s}


@dataclasses.dataclass(frozen=True, eq=False)
class PoseFrame:
    """Poses mode: one frame of the poses, rendered with its own camera."""

    index: int
    """The frame's index in ``transforms.json`` (``NNNNNN`` in the file names)."""
    time_s: float | None
    """The frame's ``timestamp``, seconds (None: the file has none)."""
    name: str
    """The captured image's file name."""
    cam_to_world: np.ndarray
    """``(4, 4)`` the camera's pose, OpenCV axes."""
    camera: Camera
    """The frame's camera, scaled by ``image_scale``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "cam_to_world", _pose(self.cam_to_world, "PoseFrame.cam_to_world"))

    def to_json(self) -> dict[str, Any]:
        """The frame's entry in render.json's ``frames``."""
        return {"index": self.index, "time_s": self.time_s, "name": self.name}


@dataclasses.dataclass(frozen=True, eq=False)
class RecordedFrame:
    """Recording mode: one kept frame of one recorded stream, at its recorded instant."""

    stream: str
    """The stream's key, ``<kind>/<name>`` (:class:`RecordedStream`)."""
    index: int
    """The recording's own frame index (``NNNNNN`` in the file names)."""
    stamp_ns: int
    """The recorded header stamp, ns."""
    odom_time_ns: int
    """The same instant on the odometry clock, ns (``nsim.rendering.recording.odometry_time_ns``)."""
    body_to_world: np.ndarray
    """``(4, 4)`` the body pose interpolated in the registration's trajectory at ``odom_time_ns``."""
    sensor_to_world: np.ndarray
    """``(4, 4)`` ``body_to_world @ sensor_to_body``."""
    people_time_s: float | None = None
    """With people: the run's simulation time whose people the frame shows
    (``nsim.rendering.recording.people_time_s``); None without people."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "body_to_world", _pose(self.body_to_world, "RecordedFrame.body_to_world"))
        object.__setattr__(self, "sensor_to_world", _pose(self.sensor_to_world, "RecordedFrame.sensor_to_world"))

    def to_json(self) -> dict[str, Any]:
        """The frame's entry in its stream's ``frames`` in render.json."""
        out = {"index": self.index, "stamp_ns": self.stamp_ns, "odom_time_ns": self.odom_time_ns,
               "sensor_to_world": self.sensor_to_world.tolist()}
        if self.people_time_s is not None:
            out["people_time_s"] = self.people_time_s
        return out


Frame = TickFrame | PoseFrame | RecordedFrame
"""A frame of any mode."""


@dataclasses.dataclass(frozen=True, eq=False)
class RecordedStream:
    """Recording mode: one recorded stream that is rendered."""

    key: str
    """``<kind>/<name>``: its folder in the recording and in the render."""
    kind: str
    """``camera``, ``depth`` or ``lidar`` (``nsim.rendering.recording.KINDS``)."""
    name: str
    """The stream's name."""
    sensor_to_body: np.ndarray
    """``(4, 4)`` the sensor's mount on the body."""
    camera: Camera | None
    """The recorded camera model (camera and depth streams); None for a LiDAR (its rays are its points)."""
    color: str
    """``rgb`` or ``gray``: as the stream's first recorded image (``rgb`` for depth and LiDAR)."""
    skipped_outside_trajectory: int
    """Selected frames dropped because they lie outside the registered trajectory."""
    people_outside_run: int | None = None
    """With people: kept frames whose ``people_time_s`` lies outside the run (drawn without people)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "sensor_to_body", _pose(self.sensor_to_body, "RecordedStream.sensor_to_body"))


@dataclasses.dataclass(frozen=True)
class PeopleClock:
    """Recording mode with people: the two ends of ``nsim.rendering.recording.people_time_s``."""

    run_start_s: float
    """The run's first tick, simulation seconds."""
    run_end_s: float
    """The run's last tick, simulation seconds."""
    first_odometry_ns: int
    """The recording's first odometry stamp, ns."""


@dataclasses.dataclass(frozen=True, eq=False)
class RecordingPlan:
    """Recording mode: what is rendered (``nsim.rendering.render_plan.plan_recording``)."""

    frames: tuple[RecordedFrame, ...]
    """The frames, stream by stream."""
    streams: tuple[RecordedStream, ...]
    """The streams rendered, in the order of ``sensors`` (else the recording's)."""
    people: PeopleClock | None
    """With people (``--trajectory``): the clock that poses them; None without."""


# ---------------------------------------------------------------------------------- the shard job
@dataclasses.dataclass(frozen=True, eq=False)
class ShardJob:
    """What every shard worker (``nsim.rendering.shard.ShardRenderer``) needs, the same in each."""

    scene_dir: Path
    """The scene checkpoint's folder: the model, its occupancy grid (and ``image_mean_rgb`` for ``fill``)."""
    human_dirs: tuple[Path, ...]
    """The human checkpoints' folders (empty: no people)."""
    person_model: tuple[int, ...] | None
    """Per person of the trajectory, the index into ``human_dirs`` of the checkpoint that draws it
    (``nsim.rendering.people.person_checkpoints``), or ``nsim.rendering.default_look.DEFAULT_LOOK`` (the
    default look); None: checkpoint k mod M."""
    trajectory_npz: Path | None
    """With people: the run's ``trajectory.npz`` (their positions, headings, gait phases, heights)."""
    rig: Rig | None
    """Trajectory mode: the adapted rig as the artifact's ``rig.json`` reads back; None otherwise."""
    recording_dir: Path | None
    """Recording mode: the recording's folder (the recorded LiDAR points give the LiDAR rays)."""
    streams: tuple[RecordedStream, ...] | None
    """Recording mode: the streams rendered; None otherwise."""
    seed: int
    """The run's seed: sensor noise is drawn from (seed, frame, sensor)."""
    device: str
    """The torch device the models load on (``cpu``, ``cuda:0``)."""
    shards: tuple[tuple[Frame, ...], ...]
    """The frames of each shard."""
    baked_dir: Path | None
    """``method: baked``: the baked scene's folder (``nsim.rendering.baked``); None otherwise."""
