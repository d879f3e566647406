"""Ground truth as an interface: what the simulator's readings are scored against.

A ``GroundTruth`` pairs each simulated reading of the renders with the real one; the table
functions (``nsim.evaluation.evaluate_tables``) only compute metrics over those pairs and never ask where
the real readings came from. Two implementations:

``OracleTruth`` (``nsim.evaluation.oracle_truth``)
    The test room's oracle (``nsim.synth.oracle.RoomOracle``) rendered at exactly the rendered
    cameras' poses, through each sensor's model (exposure, depth kind and range), with the
    render's people as test-room actors; for ``scenes`` also the frames a scene was trained from.
    Scores ``poses``- and ``trajectory``-mode renders.
``RecordingTruth`` (``nsim.evaluation.recording_truth``)
    A robot's recording (``nsim import-log``) that a recording-mode render (``nsim render
    --recording``) renders sensor for sensor and frame for frame: the recorded camera images,
    depth images and LiDAR sweeps, and the recording's trajectory registered into the scene's
    world (``nsim register-log``). Real exposure differs from the simulator's, so image tables are
    also scored after a per-camera affine colour correction (``colour_correction``).

``nsim.evaluation.evaluate_tables.truth_for`` picks the implementation from the renders' mode (all
renders of one evaluation share one). Each method yields the pairs of one table, reading and checking
every file as it goes (bad input: ``InputError``, before anything is published); ``notes`` and
``described`` say, in the table's notes and in ``evaluation.json``, what the ground truth was.

Pairs (``FramePair.sim`` / ``.real``) per table:

* images (``image_frames``): (H, W, 3) float in [0, 1], 8-bit values; mask: (H, W) bool or None.
* depth (``depth_frames``): (H, W) metres in the sensor's depth kind (NaN/inf: no valid reading on
  the real side); mask: the pixels that may be scored (None: all).
* LiDAR (``lidar_frames``): (N, 4) float64 per point, the same points in the same order on both
  sides: X, Y, Z in the sensor's frame and range (metres; NaN for no return).
* detection (``detection_frames``): (H, W, 3) uint8 frames (None when detections come from COCO
  files) and ``key``, the frame's name in those files.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

if TYPE_CHECKING:
    from nsim.evaluation.evaluate_config import Config
    from nsim.evaluation.inputs import EvaluationInputs
    from nsim.evaluation.renders import RenderData


@dataclasses.dataclass(frozen=True, eq=False)
class FramePair:
    """One frame of one sensor: the simulated and the real reading (module docstring for shapes)."""

    index: int
    sim: Any
    real: Any
    mask: np.ndarray | None = None
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)
    key: str = ""


@dataclasses.dataclass(frozen=True, eq=False)
class SensorFrames:
    """The frames of one sensor of one render. sensor_to_body: (4, 4), the sensor's mount (None: unknown)."""

    render: RenderData
    sensor: str
    frames: list[FramePair]
    sensor_to_body: np.ndarray | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class SlamSequence:
    """One SLAM sequence: the frames (uint8 (H, W, 3)) at ``times_s (N,)`` on each side, and the
    camera's true trajectory (``nsim.io.tum.Trajectory``, cam_to_world) on the same clock."""

    render: RenderData
    camera: str
    name: str
    times_s: np.ndarray
    sim: list[np.ndarray]
    real: list[np.ndarray]
    truth: Any
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)


class GroundTruth(abc.ABC):
    """The interface (module docstring) over what the stage resolved (``inputs``: the loaded renders, the
    artifacts they name) and the evaluation's settings (``cfg``)."""

    #: "oracle" or "recording"
    source: ClassVar[str]
    #: real exposure differs from the simulator's: image tables also report colour-corrected metrics
    colour_correction: ClassVar[bool] = False

    def __init__(self, inputs: EvaluationInputs, cfg: Config) -> None:
        self.cfg = cfg
        self.artifacts = inputs.artifacts
        self.renders = inputs.renders

    def check(self, table: str) -> None:
        """Every check of ``table`` that the renders' and the ground truth's files decide, for all renders, before
        any frame is read or scored (``compute`` calls it first); InputError (one line) on a problem."""
        return None

    @abc.abstractmethod
    def image_frames(self) -> Iterator[SensorFrames]: ...

    @abc.abstractmethod
    def depth_frames(self) -> Iterator[SensorFrames]: ...

    @abc.abstractmethod
    def lidar_frames(self) -> Iterator[SensorFrames]: ...

    @abc.abstractmethod
    def slam_sequences(self) -> Iterator[SlamSequence]: ...

    def detection_unavailable(self, coco: bool) -> tuple[RenderData, str, list[str]] | None:
        """A render the detection experiment cannot score, why, and its cameras (None: all can)."""
        return None

    @abc.abstractmethod
    def detection_frames(self, coco: bool) -> Iterator[SensorFrames]: ...

    @abc.abstractmethod
    def notes(self, table: str, extras: list[dict[str, Any]]) -> list[str]:
        """What the ground truth of ``table`` was, as lines for the table's notes (extras: the
        per-frame extras the table collected)."""

    @abc.abstractmethod
    def described(self, table: str) -> dict[str, str]:
        """Per render id, its ground truth in a few words (``evaluation.json``'s ``ground_truth``)."""


def lidar_rows(xyz_m: np.ndarray, range_m: np.ndarray | None = None) -> np.ndarray:
    """A sweep's points ``(..., 3)`` (sensor frame) and ranges ``(...)`` (None: the points' norms) as the LiDAR
    pairs' rows ``(N, 4)``: X, Y, Z and range, the range NaN where there is no return (a non-finite point or
    range)."""
    xyz = np.asarray(xyz_m, np.float64).reshape(-1, 3)
    hit = np.isfinite(xyz).all(axis=-1)
    rng = (np.linalg.norm(np.where(hit[:, None], xyz, 0), axis=-1) if range_m is None
           else np.asarray(range_m, np.float64).reshape(-1))
    rng = np.where(hit & np.isfinite(rng), rng, np.nan)
    return np.concatenate([xyz, rng[:, None]], axis=-1)

