"""SLAM on simulated vs real frames: the paper's ORB-SLAM3 experiment, with pycolmap or any external SLAM.

The same camera path is recorded twice, by the real sensor and in the simulator. A visual SLAM (or
SfM) system estimates a camera trajectory from each frame sequence; both estimates are scored
against the ground truth with the absolute trajectory error (``nsim.metrics.trajectory.ate``), and
the simulator is as good as the difference ``ATE(sim) - ATE(real)`` is small.

* ``run_colmap_slam(frames, timestamps_s, work_dir)`` runs pycolmap incremental mapping
  (``nsim.sfm.colmap.run_sfm``: SIFT, sequential matching with loop detection, global bundle
  adjustment) on a folder of frames or a list of images, stamps each registered frame's
  ``cam_to_world`` with its timestamp and writes ``work_dir/trajectory.tum``. Frames COLMAP cannot
  register have no pose (``SlamRun.registered_fraction`` says how many did).
* An external SLAM's output is just its TUM file (``nsim.io.tum.read_tum``).
* ``compare_slam(ground_truth, real, sim)`` gives both ATEs and their difference.

Monocular estimates have no scale, so the default alignment is Sim(3) (``"sim3"``). The ground
truth must be the *camera's* poses (body = camera): a robot base trajectory differs from the camera's
by the mounting offset, which no alignment removes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from nsim.errors import InputError
from nsim.io.tum import Trajectory, read_tum, write_tum
from nsim.metrics.trajectory import DEFAULT_MAX_DT_S, AteResult, ate

if TYPE_CHECKING:  # pycolmap is imported only when SLAM runs (after cv2, see nsim.sfm.colmap)
    from nsim.sfm.colmap import SfmStats
    from nsim.sfm.options import SfmOptions

#: What a SLAM run starts from: a folder of frames, or the frames themselves ((H, W, 3) uint8 RGB).
Frames = str | os.PathLike | Sequence[np.ndarray]


@dataclass(frozen=True, eq=False)
class SlamRun:
    """One SLAM run: the camera trajectory (registered frames only), where it was written, and coverage.

    stats: the SfM statistics (``nsim.sfm.colmap.SfmStats``) of a pycolmap run.
    """

    trajectory: Trajectory
    tum_path: Path
    n_frames: int
    stats: SfmStats | None = None

    @property
    def n_registered(self) -> int:
        return len(self.trajectory)

    @property
    def registered_fraction(self) -> float:
        return self.n_registered / self.n_frames if self.n_frames else 0.0


def _frame_times(names: Sequence[str], timestamps_s: Sequence[float] | Mapping[str, float],
                 where: str) -> dict[str, float]:
    """Timestamp per frame name; InputError for a count mismatch, a missing name, NaN or a non-increasing time."""
    if isinstance(timestamps_s, Mapping):
        missing = [n for n in names if n not in timestamps_s]
        if missing:
            raise InputError(f"{where}: frame {missing[0]} has no timestamp ({len(missing)} of {len(names)} missing)")
        times = [float(timestamps_s[n]) for n in names]
    else:
        times = [float(t) for t in timestamps_s]
        if len(times) != len(names):
            raise InputError(f"{where}: {len(names)} frames but {len(times)} timestamps")
    t = np.asarray(times, dtype=np.float64)
    if not np.isfinite(t).all():
        raise InputError(f"{where}: timestamp of frame {names[int(np.argmax(~np.isfinite(t)))]} is not finite")
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if len(bad):
        raise InputError(f"{where}: timestamp of frame {names[bad[0] + 1]} ({t[bad[0] + 1]}) is not after "
                         f"the previous frame's ({t[bad[0]]})")
    return dict(zip(names, times, strict=True))


def _stage_frames(frames: Frames, work_dir: Path, image_names: Sequence[str] | None) -> tuple[Path, list[str]]:
    """The image folder and frame names to reconstruct (arrays are written as PNGs first)."""
    from nsim.sfm.frames import list_image_files

    if isinstance(frames, (str, os.PathLike)):
        image_dir = Path(frames)
        names = list(image_names) if image_names is not None else [p.name for p in list_image_files(image_dir)]
        missing = [n for n in names if not (image_dir / n).is_file()]
        if missing:
            raise InputError(f"{image_dir / missing[0]}: no such frame")
        return image_dir, names
    from nsim.io.images import write_image

    if image_names is not None:
        raise ValueError("run_colmap_slam: image_names only applies to a folder of frames")
    image_dir = work_dir / "images"
    image_dir.mkdir(parents=True, exist_ok=True)
    names = []
    for k, image in enumerate(frames):
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InputError(f"frame {k}: expected an (H, W, 3) uint8 RGB image, got {image.dtype} {image.shape}")
        names.append(f"frame_{k:05d}.png")
        write_image(image_dir / names[-1], image)
    return image_dir, names


def run_colmap_slam(
    frames: Frames,
    timestamps_s: Sequence[float] | Mapping[str, float],
    work_dir: str | os.PathLike,
    options: SfmOptions | None = None,
    image_names: Sequence[str] | None = None,
) -> SlamRun:
    """Camera trajectory of a frame sequence by pycolmap incremental mapping (module docstring).

    frames: a folder (every JPG/PNG in name order, or ``image_names``) or a list of (H, W, 3) uint8
    RGB images (written to ``work_dir/images``). timestamps_s: one per frame in that order, or a
    mapping frame name -> seconds. options: ``nsim.sfm.options.SfmOptions`` (default: its defaults).
    Writes ``work_dir/trajectory.tum`` (cam_to_world, OpenCV camera axes, the reconstruction's own
    frame and scale). Raises InputError for mismatched timestamps, unreadable frames, or too few
    registered frames (``options.min_registered_fraction``).
    """
    from nsim.sfm.colmap import run_sfm  # imports cv2 before pycolmap
    from nsim.sfm.options import SfmOptions

    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    image_dir, names = _stage_frames(frames, work_dir, image_names)
    times = _frame_times(names, timestamps_s, str(image_dir))
    result = run_sfm(image_dir, work_dir / "sfm", options if options is not None else SfmOptions(),
                     image_names=names)
    registered = result.registered_names
    trajectory = Trajectory.from_poses(np.array([times[n] for n in registered]), result.poses_se3(registered))
    tum_path = write_tum(work_dir / "trajectory.tum", trajectory)
    return SlamRun(trajectory, tum_path, len(names), result.stats)


def _trajectory(value: Trajectory | SlamRun | str | os.PathLike) -> Trajectory:
    if isinstance(value, Trajectory):
        return value
    if isinstance(value, SlamRun):
        return value.trajectory
    return read_tum(value)


@dataclass(frozen=True, eq=False)
class SlamComparison:
    """ATE of SLAM on real and on simulated frames against the same ground truth.

    registered_real / registered_sim: fraction of frames with a pose, when known (pycolmap runs).
    """

    real: AteResult
    sim: AteResult
    registered_real: float | None = None
    registered_sim: float | None = None

    @property
    def difference_m(self) -> float:
        """``ATE RMSE(sim) - ATE RMSE(real)`` in metres (positive: the simulation is worse)."""
        return self.sim.rmse_m - self.real.rmse_m

    def record(self, sequence: str) -> dict[str, object]:
        """A record for ``nsim.metrics.paper_tables.slam_table``."""
        return {"sequence": sequence, "ate_real_m": self.real.rmse_m, "ate_sim_m": self.sim.rmse_m,
                "registered_real": self.registered_real, "registered_sim": self.registered_sim}


def compare_slam(
    ground_truth: Trajectory | str | os.PathLike,
    real: Trajectory | SlamRun | str | os.PathLike,
    sim: Trajectory | SlamRun | str | os.PathLike,
    alignment: str = "sim3",
    max_dt_s: float = DEFAULT_MAX_DT_S,
) -> SlamComparison:
    """ATE of ``real`` and ``sim`` (trajectories, SLAM runs or TUM files) against ``ground_truth``.

    Raises InputError, saying which side, when a trajectory shares no timestamp with the ground
    truth or cannot be aligned.
    """
    gt = _trajectory(ground_truth)
    results = {}
    for side, est in (("real", real), ("simulated", sim)):
        try:
            results[side] = ate(gt, _trajectory(est), alignment, max_dt_s)
        except InputError as err:
            raise InputError(f"SLAM on {side} frames vs ground truth: {err}") from None
    fraction = [est.registered_fraction if isinstance(est, SlamRun) else None for est in (real, sim)]
    return SlamComparison(results["real"], results["simulated"], *fraction)


def evaluate_slam(
    ground_truth: Trajectory | str | os.PathLike,
    real_frames: Frames,
    sim_frames: Frames,
    timestamps_s: Sequence[float] | Mapping[str, float],
    work_dir: str | os.PathLike,
    options: SfmOptions | None = None,
    alignment: str = "sim3",
    max_dt_s: float = DEFAULT_MAX_DT_S,
) -> SlamComparison:
    """``run_colmap_slam`` on the real and on the simulated frames (same timestamps, written under
    ``work_dir/real`` and ``work_dir/sim``), then ``compare_slam``. Raises InputError when the two
    sequences differ in length.
    """
    counts = []
    for frames in (real_frames, sim_frames):
        if isinstance(frames, (str, os.PathLike)):
            from nsim.sfm.frames import list_image_files

            counts.append(len(list_image_files(frames)))
        else:
            counts.append(len(frames))
    if counts[0] != counts[1]:
        raise InputError(f"SLAM: {counts[0]} real frames but {counts[1]} simulated frames")
    work_dir = Path(work_dir)
    runs = [run_colmap_slam(frames, timestamps_s, work_dir / side, options)
            for side, frames in (("real", real_frames), ("sim", sim_frames))]
    return compare_slam(ground_truth, runs[0], runs[1], alignment, max_dt_s)


def median_ate(comparisons: Sequence[SlamComparison]) -> tuple[float, float, float]:
    """Median ATE RMSE over sequences (e.g. Spot's five cameras) of real, of sim, and their difference,
    as the paper reports it (median real 0.14 m, sim 0.24 m, difference 0.10 m).
    """
    if not comparisons:
        raise InputError("SLAM: no sequences to summarise")
    real = float(np.median([c.real.rmse_m for c in comparisons]))
    sim = float(np.median([c.sim.rmse_m for c in comparisons]))
    return real, sim, sim - real
